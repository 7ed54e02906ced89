//! The stress suite: hard cases that try to break the SPARK
//! integrators, each measured, judged against a stated criterion, drawn, and
//! written up in a Markdown report by `spark stress --out DIR`.
//!
//! This module owns the suite's configuration ([`StressConfig`]), the per-case
//! record ([`CaseReport`]), running every case ([`run_all`]) and writing the
//! report ([`write_report`]). The cases live in [`long_runs`] (long time,
//! chaos), [`accuracy`] (high order near round-off, the exact rolling disk,
//! rheonomic/affine/nonlinear constraints against the reference solver) and
//! [`robustness`] (large steps, stiffness, near-singular constraints, a
//! non-reversible system, bad input); the extra systems in [`crate::systems::stress`].
//!
//! A case never aborts the suite: a failed run becomes a failed criterion
//! whose reason is the typed error's message. Only infrastructure (a
//! tableau that cannot be built, a figure that cannot be written) is an
//! [`StressError`]. Figures and the report are written only after every case
//! has run, so a failure leaves nothing half-written in the output folder.

pub mod accuracy;
pub mod long_runs;
pub mod robustness;

/// The suite's systems, declared in [`crate::systems::stress`].
pub use crate::systems::stress as systems;

use crate::report::files::{OutputDir, OutputError};
use crate::report::plot::{Figure, PlotError};
use spark_runtime::{
    IntegrationError, NewtonOptions, NoObserver, NonholonomicSystem, Observe, RunOptions, RunReport, Schedule, Stepper,
    TableauError, Vector,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How long the cases run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Scale {
    /// Seconds in total (the test suite and a quick look).
    Quick,
    /// As the issue asks: 10⁶ steps for the long runs, t ∈ [0, 50000] for
    /// the chaotic particles (minutes on 2 cores, release build).
    Full,
}

/// Configuration of a stress run.
#[derive(Clone, Debug)]
pub struct StressConfig {
    /// Run lengths.
    pub scale: Scale,
    /// Output folder of `report.md`, `summary.json` and the figures.
    pub out: PathBuf,
}

/// Infrastructure failures (not case failures).
#[derive(Debug, thiserror::Error)]
pub enum StressError {
    /// A tableau could not be built (a bug in the suite's choice of `s`).
    #[error("tableau: {0}")]
    Tableau(#[from] TableauError),
    /// A figure could not be drawn.
    #[error("figure: {0}")]
    Plot(#[from] PlotError),
    /// Writing the report failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Serializing the summary failed.
    #[error("summary: {0}")]
    Json(#[from] serde_json::Error),
    /// The output folder could not be opened or a file not written.
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// One checked criterion of a case.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Check {
    /// What was required.
    pub criterion: String,
    /// Whether it held.
    pub passed: bool,
    /// What was measured (or, on failure, why it failed).
    pub detail: String,
}

/// A measured figure of a case.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Metric {
    /// Name.
    pub name: String,
    /// Value, formatted.
    pub value: String,
}

/// What one hard case did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CaseReport {
    /// Short key (file stem of the figure).
    pub key: &'static str,
    /// Title.
    pub title: String,
    /// What was run, in a sentence or two.
    pub setup: String,
    /// Accepted steps over all runs of the case.
    pub steps: usize,
    /// Rejected steps (or sub-step attempts) over all runs.
    pub rejections: usize,
    /// Worst constraint residual `max |k|` seen.
    pub worst_residual: f64,
    /// Energy behaviour in words and numbers.
    pub energy: String,
    /// Criteria and their outcome.
    pub checks: Vec<Check>,
    /// Measured figures.
    pub metrics: Vec<Metric>,
    /// Warnings (e.g. an ill-conditioned saddle matrix).
    pub warnings: Vec<String>,
    /// Typed errors the runs returned, with their messages.
    pub errors: Vec<String>,
    /// Wall time of the case in seconds.
    pub seconds: f64,
    /// The figure (not serialized; rendered by [`write_report`]).
    #[serde(skip)]
    pub figure: Option<Figure>,
}

impl CaseReport {
    /// An empty record.
    pub fn new(key: &'static str, title: impl Into<String>, setup: impl Into<String>) -> Self {
        CaseReport {
            key,
            title: title.into(),
            setup: setup.into(),
            steps: 0,
            rejections: 0,
            worst_residual: 0.0,
            energy: String::new(),
            checks: Vec::new(),
            metrics: Vec::new(),
            warnings: Vec::new(),
            errors: Vec::new(),
            seconds: 0.0,
            figure: None,
        }
    }

    /// Records a criterion.
    pub fn check(&mut self, criterion: impl Into<String>, passed: bool, detail: impl Into<String>) {
        self.checks.push(Check { criterion: criterion.into(), passed, detail: detail.into() });
    }

    /// Records a measured figure.
    pub fn metric(&mut self, name: impl Into<String>, value: impl std::fmt::Display) {
        self.metrics.push(Metric { name: name.into(), value: value.to_string() });
    }

    /// The value of a metric by name.
    pub fn metric_value(&self, name: &str) -> Option<&str> {
        self.metrics.iter().find(|m| m.name == name).map(|m| m.value.as_str())
    }

    /// Whether every criterion held.
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.passed)
    }

    /// The failed criteria, each with its reason.
    pub fn failures(&self) -> Vec<&Check> {
        self.checks.iter().filter(|c| !c.passed).collect()
    }

    fn absorb(&mut self, r: &RunData) {
        self.steps += r.report.steps;
        self.rejections += r.report.rejected_steps;
        self.worst_residual = self.worst_residual.max(r.max_residual);
    }
}

/// The whole suite's outcome.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StressReport {
    /// Run lengths used.
    pub scale: Scale,
    /// The cases in order.
    pub cases: Vec<CaseReport>,
    /// Wall time in seconds.
    pub seconds: f64,
}

/// A case function: runs at a scale, returns its record.
pub type CaseFn = fn(Scale) -> Result<CaseReport, StressError>;

/// Every case, in report order, with its key.
pub const CASES: &[(&str, CaseFn)] = &[
    ("long_time", long_runs::long_time),
    ("chaos", long_runs::chaos),
    ("high_order", accuracy::high_order),
    ("large_steps", robustness::large_steps),
    ("stiff", robustness::stiff_spring),
    ("near_singular", robustness::near_singular),
    ("non_reversible", robustness::non_reversible),
    ("rolling_disk", accuracy::rolling_disk),
    ("reference", accuracy::against_reference),
    ("bad_input", robustness::bad_input),
];

/// Runs the cases whose key is in `only` (all when empty), calling `progress`
/// with each key before it starts.
pub fn run_all(scale: Scale, only: &[String], progress: &dyn Fn(&str)) -> Result<StressReport, StressError> {
    let start = Instant::now();
    let mut cases = Vec::new();
    for (key, f) in CASES {
        if !only.is_empty() && !only.iter().any(|o| o == key) {
            continue;
        }
        progress(key);
        let t = Instant::now();
        let mut c = f(scale)?;
        c.seconds = t.elapsed().as_secs_f64();
        cases.push(c);
    }
    Ok(StressReport { scale, cases, seconds: start.elapsed().as_secs_f64() })
}

/// Writes `report.md`, `summary.json` and each case's figure (`<key>.png`,
/// `<key>.svg`) into `out` (created and locked, files renamed into place
/// together; see [`crate::report::files::OutputDir`]); returns the paths written.
pub fn write_report(report: &StressReport, out: &Path) -> Result<Vec<PathBuf>, StressError> {
    let mut dir = OutputDir::open(out)?;
    stage_report(report, &mut dir)?;
    Ok(dir.commit()?)
}

/// Stages the files of [`write_report`] in an open output folder; they
/// appear at [`OutputDir::commit`], the report and summary last.
pub fn stage_report(report: &StressReport, out: &mut OutputDir) -> Result<(), StressError> {
    for c in &report.cases {
        if let Some(fig) = &c.figure {
            out.render(fig, c.key)?;
        }
    }
    out.write_bytes("report.md", markdown(report).as_bytes())?;
    out.write_json("summary.json", report)?;
    Ok(())
}

/// The summary table of the report, with every failed criterion and its
/// reason below it (what `spark stress` prints).
pub fn markdown_summary(report: &StressReport) -> String {
    let full = markdown(report);
    let table_end = full.find("\n<a id=").unwrap_or(full.len());
    let mut s = full[..table_end].to_string();
    for c in &report.cases {
        for k in c.failures() {
            s.push_str(&format!("- FAIL {}: {} — {}\n", c.key, k.criterion, k.detail));
        }
    }
    s
}

/// The Markdown text of the report.
pub fn markdown(report: &StressReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let scale = match report.scale {
        Scale::Quick => "quick (shortened runs; `spark stress --full` runs the lengths the issue asks for)",
        Scale::Full => "full (10⁶ steps for the long runs, t ∈ [0, 50000] for the chaotic particles)",
    };
    let _ = writeln!(s, "# Stress suite report\n");
    let _ = writeln!(s, "Generated by `spark stress` — scale: {scale}; wall time {:.1} s.\n", report.seconds);
    let _ = writeln!(s, "| case | verdict | steps | rejections | worst residual | energy |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---|");
    for c in &report.cases {
        let verdict = if c.passed() { "pass".to_string() } else { format!("**FAIL** ({})", c.failures().len()) };
        let _ = writeln!(
            s,
            "| [{}](#{}) | {} | {} | {} | {:.2e} | {} |",
            c.title,
            c.key.replace('_', "-"),
            verdict,
            c.steps,
            c.rejections,
            c.worst_residual,
            c.energy.replace('|', "\\|")
        );
    }
    for c in &report.cases {
        let _ = writeln!(s, "\n<a id=\"{}\"></a>\n## {}\n", c.key.replace('_', "-"), c.title);
        let _ = writeln!(s, "{}\n", c.setup);
        if c.figure.is_some() {
            let _ = writeln!(s, "![{}]({}.png)\n", c.title, c.key);
        }
        let _ = writeln!(
            s,
            "Steps {}, rejections {}, worst constraint residual {:.3e}, {:.1} s. Energy: {}\n",
            c.steps, c.rejections, c.worst_residual, c.seconds, c.energy
        );
        if !c.checks.is_empty() {
            let _ = writeln!(s, "| criterion | result | measured |\n|---|---|---|");
            for k in &c.checks {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} |",
                    k.criterion.replace('|', "\\|"),
                    if k.passed { "pass" } else { "**FAIL**" },
                    k.detail.replace('|', "\\|").replace('\n', " ")
                );
            }
            s.push('\n');
        }
        if !c.metrics.is_empty() {
            let _ = writeln!(s, "| measured | value |\n|---|---|");
            for m in &c.metrics {
                let _ = writeln!(s, "| {} | {} |", m.name.replace('|', "\\|"), m.value.replace('|', "\\|"));
            }
            s.push('\n');
        }
        for w in &c.warnings {
            let _ = writeln!(s, "- warning: {w}");
        }
        if !c.errors.is_empty() {
            let _ = writeln!(s, "\nTyped errors returned by the library (expected ones included):\n");
            for e in &c.errors {
                let _ = writeln!(s, "- `{}`", e.replace('`', "'"));
            }
        }
    }
    s
}

/// Samples of one fixed-step run.
#[derive(Clone, Debug, Default)]
pub struct RunData {
    /// Recorded times.
    pub t: Vec<f64>,
    /// `E − E₀` at the recorded times.
    pub energy_error: Vec<f64>,
    /// `max |k|` at the recorded times.
    pub residual: Vec<f64>,
    /// Recorded coordinates (one vector per sample).
    pub q: Vec<Vec<f64>>,
    /// Recorded velocities.
    pub v: Vec<Vec<f64>>,
    /// Largest `max |k|` over every step (not only recorded ones).
    pub max_residual: f64,
    /// Largest `|E − E₀|` over every step.
    pub max_energy_error: f64,
    /// The driver's statistics.
    pub report: RunReport,
}

/// Runs `steps` fixed steps of size `h` with the driver, recording every
/// `record_every`-th step; the driver's report covers energy and residual
/// at every step.
#[allow(clippy::too_many_arguments)]
pub fn run_fixed<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    q0: &Vector<N>,
    v0: &Vector<N>,
    h: f64,
    steps: usize,
    record_every: usize,
    max_halvings: u32,
) -> Result<RunData, IntegrationError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let options = RunOptions {
        observe: Observe { energy: true, constraint_residual: true, multipliers: false },
        record_every,
        max_halvings,
        ..RunOptions::default()
    };
    let traj = stepper.integrate(0.0, q0, v0, Schedule::Fixed { h, steps }, &options, &mut NoObserver)?;
    let e0 = traj.samples.first().and_then(|s| s.energy).unwrap_or(f64::NAN);
    let report = traj.report;
    let mut d = RunData {
        max_residual: report.max_constraint_residual,
        max_energy_error: report.max_energy_error,
        report,
        ..RunData::default()
    };
    for s in &traj.samples {
        d.t.push(s.t);
        d.energy_error.push(s.energy.unwrap_or(f64::NAN) - e0);
        d.residual.push(s.constraint_residual.unwrap_or(f64::NAN));
        d.q.push(s.q.iter().copied().collect());
        d.v.push(s.v.iter().copied().collect());
    }
    Ok(d)
}

/// Newton options of the suite: the library defaults (full Newton, 16ε).
pub fn newton() -> NewtonOptions {
    NewtonOptions::default()
}
