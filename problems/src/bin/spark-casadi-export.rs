//! Writes the JSON the CasADi cross-check (`casadi/crosscheck.py`) reads:
//! sample points with every trait output of every system, and whole SPARK
//! steps with their tableaux.
//!
//! `spark-casadi-export --out out/casadi/export.json [--seed 20260101]`

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use problems::crosscheck::Document;

/// Export sample points and SPARK steps for the CasADi cross-check.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Where to write the JSON document (parent directories are created).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the sample points.
    #[arg(long, default_value_t = 20_260_101)]
    seed: u64,
}

fn run(args: &Args) -> Result<(), String> {
    let document = Document::export(args.seed).map_err(|e| format!("exporting: {e}"))?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    }
    let text = serde_json::to_string_pretty(&document).map_err(|e| format!("serializing: {e}"))?;
    std::fs::write(&args.out, text).map_err(|e| format!("writing {}: {e}", args.out.display()))?;
    eprintln!(
        "spark-casadi-export: {} systems, {} steps -> {}",
        document.systems.len(),
        document.steps.len(),
        args.out.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("spark-casadi-export: error: {e}");
            ExitCode::FAILURE
        }
    }
}
