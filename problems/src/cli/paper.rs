//! `spark paper`: reproduce the paper's §8 experiments and print their
//! summary.

use super::Newton;
use crate::experiments::paper::{run_paper, PaperConfig, PaperReport};
use crate::report::progress::Progress;
use clap::Args;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug)]
/// Arguments of `spark paper`.
pub struct PaperArgs {
    /// Output folder for figures, CSV files and the summary.
    #[arg(long, short, default_value = "results")]
    pub out: PathBuf,
    /// Shorten every interval to this fraction of the paper's (e.g. 0.01 for a
    /// quick look); 1 reproduces the paper.
    #[arg(long, default_value_t = 1.0)]
    pub fraction: f64,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Simplified)]
    pub newton: Newton,
    /// Newton stopping tolerance on the scaled update, in (0, 1) (default
    /// 16ε ≈ 3.6e-15; looser values show what inexact solves do to the
    /// energy behaviour).
    #[arg(long)]
    pub newton_tol: Option<f64>,
}

/// `spark paper`: every figure and table of §8, and the summary to print.
pub fn paper_command(a: PaperArgs) -> Result<String, String> {
    if !(a.fraction.is_finite() && a.fraction > 0.0 && a.fraction <= 1.0) {
        return Err("--fraction must lie in (0, 1]".into());
    }
    let mut cfg =
        if a.fraction == 1.0 { PaperConfig::full(&a.out) } else { PaperConfig::shortened(&a.out, a.fraction) };
    cfg.newton.mode = a.newton.into();
    if let Some(tol) = a.newton_tol {
        if !(tol > 0.0 && tol < 1.0) {
            return Err(format!(
                "--newton-tol {tol:e}: write a number in (0, 1) (the largest update accepted, \
                 relative to 1 + |z|)"
            ));
        }
        cfg.newton.tolerance = tol;
        cfg.newton.stagnation_level = cfg.newton.stagnation_level.max(tol);
    }
    let start = Instant::now();
    let report = run_paper(&cfg, &Progress::on_terminal()).map_err(|e| e.to_string())?;
    let mut s = print_report(&report);
    let _ = writeln!(s, "\nTotal wall time: {:.1} s on {} thread(s).", start.elapsed().as_secs_f64(), report.threads);
    let _ = writeln!(s, "Wrote {} files into {}.", report.files.len(), a.out.display());
    Ok(s)
}

/// The summary table and the Fig. 8.4 fits, as printed.
fn print_report(report: &PaperReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<9} {:<7} {:<30} {:<22} {:>9} {:>10} {:>10} {:>12} {:>9} {:>8}",
        "figure",
        "system",
        "method",
        "initial values",
        "steps",
        "max|E-E0|",
        "max|k|",
        "drift slope",
        "drift/max",
        "cpu s"
    );
    for r in &report.rows {
        let (slope, frac) = match r.drift {
            Some(d) => (format!("{:.2e}", d.slope), format!("{:.3}", d.drift_fraction)),
            None => ("-".into(), "-".into()),
        };
        let _ = writeln!(
            s,
            "{:<9} {:<7} {:<30} {:<22} {:>9} {:>10.2e} {:>10.2e} {:>12} {:>9} {:>8.2}",
            r.figure,
            r.system,
            r.method,
            r.initial_values,
            r.steps,
            r.max_energy_error,
            r.max_constraint_residual,
            slope,
            frac,
            r.cpu_seconds.unwrap_or(r.run_seconds)
        );
    }
    let _ = writeln!(s, "\nFig. 8.4 growth (1/h⁴)·mean_j (E_jk − E0)² ≈ C·t^p:");
    for g in &report.growth {
        let late = g.late_fit.map_or(String::new(), |f| format!("; last decade p = {:.3}", f.exponent));
        let _ = match g.fit {
            Some(f) => writeln!(
                s,
                "  {:<36} {:<58} p = {:.3} ± {:.3}  (C = {:.3e}, t ≥ {}{late})",
                g.method,
                g.constraint.formula(),
                f.exponent,
                f.exponent_std_error,
                f.coefficient,
                f.t_min
            ),
            None => {
                writeln!(s, "  {:<36} {:<58} (not enough positive samples to fit)", g.method, g.constraint.formula())
            }
        };
    }
    s
}
