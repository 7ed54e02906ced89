//! Prints the code `nonholonomic_system!` generates for one declaration, and
//! its operation counts, without compiling anything:
//!
//! ```text
//! cargo run -p spark-symbolic --example expand -- problems/src/systems/paper.rs Skate
//! cargo run -p spark-symbolic --example expand -- problems/src/systems/paper.rs Skate --counts
//! ```
//!
//! The first argument is a Rust file, the second the name of the struct a
//! `nonholonomic_system!` invocation in it declares. `--counts` prints only
//! the structure facts and operation counts. The expanded code goes to stdout,
//! the counts to stderr (so `> file.rs` captures just the code).

use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let counts_only = args.iter().any(|a| a == "--counts");
    let positional: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let [file, name] = positional.as_slice() else {
        eprintln!("usage: expand <file.rs> <StructName> [--counts]");
        return ExitCode::from(2);
    };
    match run(file, name, counts_only) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(file: &str, name: &str, counts_only: bool) -> Result<(), String> {
    let source = std::fs::read_to_string(file).map_err(|e| format!("cannot read {file}: {e}"))?;
    let tokens = spark_symbolic::dsl::find_declaration(&source, name).map_err(|e| format!("{file}: {e}"))?;
    let spec = spark_symbolic::dsl::parse(tokens).map_err(|e| format!("{name}: {}", e.message))?;
    let analysis = spark_symbolic::analyze(&spec).map_err(|e| format!("{name}: {}", e.message))?;
    if !counts_only {
        let code = spark_symbolic::generate(&spec).map_err(|e| format!("{name}: {}", e.message))?;
        let file = syn::parse2::<syn::File>(code).map_err(|e| format!("generated code does not parse: {e}"))?;
        print!("{}", prettyplease::unparse(&file));
    }
    let ops = analysis.operations;
    eprintln!("{name}: N = {}, M = {}, {:?}", analysis.n, analysis.m, analysis.structure);
    eprintln!(
        "{name}: operations: stage_values {}, stage_jacobians {}, CasADi bundle {}",
        ops.stage_values, ops.stage_jacobians, ops.bundle
    );
    Ok(())
}
