//! The `spark` command line: the arguments of every subcommand and what each
//! does. Each subcommand returns the text to print (the binary prints it),
//! so nothing here writes to standard output; progress bars go to standard
//! error.
//!
//! [`Cli`] and [`Command`] are the grammar, [`run`](fn@run) the dispatch; the
//! subcommands live in [`list`], [`run`](mod@run), [`paper`], [`section`],
//! [`stress`] and [`work_precision`].

pub mod list;
pub mod paper;
pub mod run;
#[cfg(feature = "full")]
pub mod section;
#[cfg(feature = "full")]
pub mod stress;
#[cfg(feature = "full")]
pub mod work_precision;

use crate::catalog::nearest;
use crate::report::format::exact;
use clap::{Parser, Subcommand, ValueEnum};
use spark_runtime::{Method, NewtonMode};

/// Lagrange–d'Alembert SPARK integrators for nonholonomic mechanical systems.
///
/// Start with `spark list` to see what is available, `spark run skate`
/// to integrate one system, or `spark paper` to reproduce every figure and
/// table of the paper's §8 (L. O. Jay, "Lagrange–d'Alembert SPARK integrators
/// for nonholonomic Lagrangian systems") into the folder `results/`.
#[derive(Parser, Debug)]
#[command(name = "spark", version, about, long_about, propagate_version = true)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Show the systems (name, N, M, structure, effects, parameters, default
    /// initial state) and integration methods this program knows.
    List(list::ListArgs),
    /// Integrate one system with one method; write the trajectory (CSV and/or
    /// JSON), a report (report.md, report.json: energy error, constraint
    /// residual, holonomic drift, Newton iterations) and a plot (PNG + SVG).
    ///
    /// Example: spark run robot --method lobatto-iiia-b-d --stages 3 --h 0.2 --t-end 150 --out results/robot
    Run(run::RunArgs),
    /// Reproduce the paper's experiments (Figs. 8.1–8.4): figures as PNG and
    /// SVG, the numbers behind each figure as CSV, and a summary table
    /// (printed, and written as summary.md / summary.json).
    ///
    /// The full run integrates 3 methods × 10 initial values × 10⁶ steps for
    /// Fig. 8.4; it uses every CPU core (set RAYON_NUM_THREADS to limit).
    Paper(paper::PaperArgs),
    /// Work-precision diagrams: global error and energy error vs wall time for
    /// every method and stage count on any registered system (default: the
    /// paper's four), with peers (num-dual, finite differences, ode_solvers,
    /// CasADi-generated C, SciPy; the paper-only ones skipped elsewhere)
    /// measured in the same run.
    ///
    /// Example: spark work-precision --system skate --system driven-skate --out results/work-precision
    #[cfg(feature = "full")]
    WorkPrecision(work_precision::WorkPrecisionArgs),
    /// Poincaré section: integrate an ensemble (in parallel) and record the
    /// states where it crosses one of the system's declared events; writes
    /// the points (CSV), a scatter figure (PNG + SVG) and section.json.
    ///
    /// Example: spark section mp7-nh --event section --members 10 --t-end 500 --out results/section
    #[cfg(feature = "full")]
    Section(section::SectionArgs),
    /// Stress suite: hard cases with checks, figures and a report.
    ///
    /// Example: spark stress --full --out docs/stress
    #[cfg(feature = "full")]
    Stress(stress::StressArgs),
}

/// Trajectory file format of `spark run`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Format {
    /// CSV only.
    Csv,
    /// JSON only.
    Json,
    /// CSV and JSON.
    Both,
}

/// The Newton iteration flag.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Newton {
    /// Exact Jacobian every iteration.
    Full,
    /// One Jacobian per step (faster; same tolerance).
    Simplified,
}

impl From<Newton> for NewtonMode {
    fn from(n: Newton) -> Self {
        match n {
            Newton::Full => NewtonMode::Full,
            Newton::Simplified => NewtonMode::Simplified,
        }
    }
}

/// Runs the subcommand `cli` names and returns the text to print;
/// `progress` receives the work-precision study's progress lines.
pub fn run(cli: Cli, progress: &dyn Fn(&str)) -> Result<String, String> {
    #[cfg(not(feature = "full"))]
    let _ = progress;
    match cli.command {
        Command::List(args) => list::list(args),
        Command::Run(args) => run::run_command(args),
        Command::Paper(args) => paper::paper_command(args),
        #[cfg(feature = "full")]
        Command::WorkPrecision(args) => work_precision::run(args, progress),
        #[cfg(feature = "full")]
        Command::Section(args) => section::section_command(args),
        #[cfg(feature = "full")]
        Command::Stress(args) => stress::run(args),
    }
}

/// The method named `name` (its [`Method::key`] or an alias), or an error
/// with the nearest key.
pub fn parse_method(name: &str) -> Result<Method, String> {
    name.parse().map_err(|e: spark_runtime::TableauError| match nearest(name, Method::ALL.iter().map(|m| m.key())) {
        Some(s) => format!("{e} (did you mean `{s}`?)"),
        None => e.to_string(),
    })
}

/// The `--param NAME=VALUE` flags as `(name, value)` pairs.
pub fn parse_params(params: &[String]) -> Result<Vec<(String, f64)>, String> {
    let mut parsed: Vec<(String, f64)> = Vec::with_capacity(params.len());
    for p in params {
        let (name, value) =
            p.split_once('=').ok_or_else(|| format!("--param `{p}`: write NAME=VALUE, e.g. --param beta=0.5"))?;
        let v: f64 = value.trim().parse().map_err(|_| format!("--param `{p}`: `{value}` is not a number"))?;
        if !v.is_finite() {
            return Err(format!("--param `{p}`: the value must be a finite number"));
        }
        let name = name.trim();
        if name.is_empty() {
            return Err(format!("--param `{p}`: no parameter name; write NAME=VALUE, e.g. --param beta=0.5"));
        }
        if let Some(i) = parsed.iter().position(|(n, _)| n == name) {
            let first = &params[i];
            return Err(format!("--param `{name}` is given twice (`{first}` and `{p}`); give each parameter once"));
        }
        parsed.push((name.to_string(), v));
    }
    Ok(parsed)
}

/// The step size as the user gave it: `--h 1.000e-1`, or, when `--h` was
/// not given, the system's default step (so that a message about it does
/// not name a flag the user did not pass).
pub fn step_flag(given: Option<f64>, h: f64) -> String {
    match given {
        Some(h) => format!("--h {h:.3e}"),
        None => format!("the system's default step h = {h:.3e} (see `spark list`; set one with --h)"),
    }
}

/// Relative tolerance within which `(t_end − t0)/h` counts as a whole number
/// of steps (round-off of the division, e.g. 150/0.2 = 749.999…).
pub const WHOLE_STEPS_TOLERANCE: f64 = 1e-9;

/// Most steps one `spark run` takes (and most member-steps of one `spark
/// section`): 10¹⁰, 10⁴ times the paper's longest run, 15 min to hours at
/// 0.1–1 µs per step. Beyond it a run cannot end in any sensible time (at
/// 2⁵³ steps, where step counts stop being exact in `f64`, it would take
/// decades).
pub const MAX_STEPS: f64 = 1e10;

/// The number of steps from `t0` to `t_end` with step `h`, or an error naming
/// the flags when the interval is not a whole number of steps (the run would
/// end elsewhere than asked) or too many steps.
pub fn step_count(t0: f64, t_end: f64, h: f64) -> Result<usize, String> {
    let ratio = (t_end - t0) / h;
    if ratio.is_nan() || ratio > MAX_STEPS {
        return Err(format!(
            "(t_end − t0)/h = {ratio:.3e} steps is more than {MAX_STEPS:.0e}, the most one run takes (hours at \
             0.1–1 µs per step); raise --h or shorten the interval --t0 … --t-end"
        ));
    }
    let steps = ratio.round();
    if steps < 1.0 {
        return Err(format!(
            "the interval from t0 = {} to --t-end {} is shorter than one step of --h {}; use a later --t-end or a \
             smaller --h",
            exact(t0),
            exact(t_end),
            exact(h)
        ));
    }
    // Relative to the step count, capped at a thousandth of a step: beyond
    // 10⁶ steps a relative tolerance alone would accept an interval half a
    // step longer or shorter, and the run would end elsewhere than asked.
    // The round-off of the division stays far below either (3e-16 × steps).
    let tolerance = (WHOLE_STEPS_TOLERANCE * steps).min((16.0 * f64::EPSILON * steps).max(1e-3));
    // Far from t = 0 the interval itself is rounded (t_end − t0 is a
    // multiple of the spacing of f64 there, up to 1/32 of a step): a
    // number of steps whose end t0 + k·h rounds to the given --t-end ends
    // the run exactly there, the time the driver gives its last step.
    let lands = |k: f64| k >= 1.0 && t0 + k * h == t_end;
    if let Some(k) = [steps, ratio.floor(), ratio.ceil()].into_iter().find(|&k| lands(k)) {
        return Ok(k as usize);
    }
    if (ratio - steps).abs() > tolerance {
        let (below, above) = (ratio.floor().max(1.0), ratio.ceil());
        // Below one step both neighbours are the one step.
        let (low, high) = (t0 + below * h, t0 + above * h);
        // Fifteen digits hide round-off noise, but far from t = 0 they can
        // print two different ends alike: then every digit.
        let ends = if below == above || low == high {
            if digits(high) == digits(t_end) {
                exact(high)
            } else {
                digits(high)
            }
        } else if digits(low) == digits(high) || digits(low) == digits(t_end) || digits(high) == digits(t_end) {
            format!("{} or {}", exact(low), exact(high))
        } else {
            format!("{} or {}", digits(low), digits(high))
        };
        let count = if above == 1.0 { "1 step".to_string() } else { format!("{above:.0} steps") };
        return Err(format!(
            "the interval from t0 = {} to --t-end {} is {} steps of --h {}, not a whole number; use --t-end {ends}, \
             or --h {} ({count})",
            // The values given, every digit: fifteen print t0 = 1e17 and
            // --t-end 1e17 + 16 alike.
            exact(t0),
            exact(t_end),
            digits(ratio),
            exact(h),
            digits((t_end - t0) / above),
        ));
    }
    Ok(steps as usize)
}

/// `x` rounded to 15 significant digits, written as [`exact`] writes
/// numbers (`0.3` for `0.30000000000000004`, `50000000.1`, `1e17`): as
/// many digits as tell nearby suggestions apart, without round-off noise.
fn digits(x: f64) -> String {
    exact(format!("{x:.14e}").parse().unwrap_or(x))
}
