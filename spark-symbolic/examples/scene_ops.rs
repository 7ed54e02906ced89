//! Prints a Markdown table of the operation counts of every scene of the
//! declarations with `scenes:` in a Rust file (and of the plain declarations
//! named on the command line), without compiling anything:
//!
//! ```text
//! cargo run -p spark-symbolic --example scene_ops -- problems/src/systems/scenes.rs Body Sleigh IceSkate SleighDrivenDampedByHand
//! ```
//!
//! Columns: `M`, whether `L` and `k` are autonomous, the operation counts of
//! `stage_values`, `stage_jacobians`, the CasADi bundle, and of the effect
//! methods `external_force_jacobians` and `nonideal_force_jacobians` (`—`
//! when the scene has no such effect).

use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((file, names)) = args.split_first() else {
        eprintln!("usage: scene_ops <file.rs> <StructName>...");
        return ExitCode::from(2);
    };
    match run(file, names) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(file: &str, names: &[String]) -> Result<(), String> {
    let source = std::fs::read_to_string(file).map_err(|e| format!("cannot read {file}: {e}"))?;
    println!("| type | M | autonomous | `stage_values` | `stage_jacobians` | CasADi bundle | f + Jacobians | N + Jacobians |");
    println!("|---|---|---|---|---|---|---|---|");
    for name in names {
        let tokens = spark_symbolic::dsl::find_declaration(&source, name).map_err(|e| format!("{file}: {e}"))?;
        let body: proc_macro2::TokenStream = tokens;
        let specs = match spark_symbolic::scenes::parse_with_scenes(&body).map_err(|e| e.message)? {
            Some((_, scenes)) => scenes,
            None => vec![spark_symbolic::dsl::parse(body).map_err(|e| e.message)?],
        };
        for spec in &specs {
            let a = spark_symbolic::analyze(spec).map_err(|e| format!("{}: {}", spec.name, e.message))?;
            let o = a.operations;
            let or_dash = |present: bool, x: usize| if present { x.to_string() } else { "—".to_string() };
            println!(
                "| `{}` | {} | {} | {} | {} | {} | {} | {} |",
                spec.name,
                a.m,
                if a.structure.lagrangian_autonomous && a.structure.constraints_autonomous { "yes" } else { "no" },
                o.stage_values,
                o.stage_jacobians,
                o.bundle,
                or_dash(!spec.external_force.is_empty(), o.external_force_jacobians),
                or_dash(!spec.nonideal_force.is_empty(), o.nonideal_force_jacobians),
            );
        }
    }
    Ok(())
}
