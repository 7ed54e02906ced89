//! Writes the JSON the CasADi cross-check (`casadi/crosscheck.py`) reads:
//! sample points with every trait output of every system, and whole SPARK
//! steps with their tableaux.
//!
//! `spark-casadi-export --out out/casadi/export.json [--seed 20260101]`

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use problems::crosscheck::Document;
use problems::report::files::replace_file;

#[path = "shared/signals.rs"]
mod signals;
// Its one line of output goes to standard error: `write_stdout` is spark's.
#[allow(dead_code)]
#[path = "shared/stdio.rs"]
mod stdio;

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

fn run(args: &Args) -> Result<String, String> {
    let document = Document::export(args.seed).map_err(|e| format!("exporting: {e}"))?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    }
    // Under a temporary name, then renamed: an interrupted or failed write
    // leaves an earlier export whole, never a truncated document under its name.
    replace_file(&args.out, |w| serde_json::to_writer_pretty(w, &document)).map_err(|e| e.to_string())?;
    Ok(format!(
        "spark-casadi-export: {} systems, {} steps -> {}",
        document.systems.len(),
        document.steps.len(),
        args.out.display()
    ))
}

fn main() -> ExitCode {
    let args = match stdio::parse::<Args>() {
        Ok(args) => args,
        Err(status) => return status,
    };
    signals::clean_up_on_signals();
    // The closing line goes to standard error: one that cannot take it
    // loses the line, not the export.
    match run(&args) {
        Ok(done) => {
            stdio::say(&done);
            ExitCode::SUCCESS
        }
        Err(e) => {
            stdio::say(&format!("spark-casadi-export: error: {e}"));
            ExitCode::FAILURE
        }
    }
}
