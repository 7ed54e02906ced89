//! The `spark stress` subcommand: its arguments and what it does (run the
//! cases, write the report, return a short summary for the terminal).

use crate::experiments::stress::{markdown_summary, run_all, stage_report, Scale, CASES};
use crate::report::files::OutputDir;
use crate::report::progress::Progress;
use std::path::PathBuf;

/// Run the stress suite: hard cases that try to break the
/// integrators — long runs, chaos, high order near round-off, large steps
/// with a step-rejection policy, stiffness, near-singular constraints, a
/// non-reversible system, an exact solution, rheonomic and velocity-nonlinear
/// constraints against a reference, bad input. Writes report.md, summary.json
/// and one figure per case (PNG + SVG) into the output folder.
///
/// Without --full the runs are shortened (about ten seconds in a release
/// build); --full runs the lengths the issue asks for: 10⁶ steps for the
/// long runs and the rolling disk, t ∈ [0, 50000] for the McLachlan–Perlmutter
/// ensemble (several minutes on 2 cores in a release build).
///
/// Example: spark stress --full --out docs/stress
#[derive(clap::Args, Debug, Clone)]
pub struct StressArgs {
    /// Run the full lengths (10⁶ steps, t ∈ [0, 50000]) instead of the quick versions.
    #[arg(long)]
    pub full: bool,
    /// Output folder for report.md, summary.json and the figures.
    #[arg(long, short, default_value = "results/stress")]
    pub out: PathBuf,
    /// Run only these cases (comma-separated): long_time, chaos, high_order,
    /// large_steps, stiff, near_singular, non_reversible, rolling_disk,
    /// reference, bad_input.
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Exit with an error when any criterion fails (the report is written first).
    #[arg(long)]
    pub strict: bool,
}

/// Runs the suite as `args` says and returns the summary to print.
pub fn run(args: StressArgs) -> Result<String, String> {
    let known: Vec<&str> = CASES.iter().map(|(k, _)| *k).collect();
    if let Some(bad) = args.only.iter().find(|o| !known.contains(&o.as_str())) {
        return Err(format!("unknown stress case `{bad}`; the cases are: {}", known.join(", ")));
    }
    let scale = if args.full { Scale::Full } else { Scale::Quick };
    // The folder is created and locked before the cases run, so an
    // unwritable or busy --out is reported at once.
    let mut out = OutputDir::open(&args.out).map_err(|e| e.to_string())?;
    let total = if args.only.is_empty() { CASES.len() } else { args.only.len() };
    let bar = Progress::on_terminal().bar("stress cases", total as u64);
    let report = run_all(scale, &args.only, &|key| {
        bar.set_message(key.to_string());
        bar.inc(1);
    })
    .map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    stage_report(&report, &mut out).map_err(|e| e.to_string())?;
    let written = out.commit().map_err(|e| e.to_string())?;
    let mut text = markdown_summary(&report);
    text.push_str(&format!("\nwrote {} files into {}\n", written.len(), args.out.display()));
    let failed: Vec<&str> = report.cases.iter().filter(|c| !c.passed()).map(|c| c.key).collect();
    if args.strict && !failed.is_empty() {
        return Err(format!("{text}\nfailed cases: {}", failed.join(", ")));
    }
    Ok(text)
}
