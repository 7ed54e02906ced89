//! `spark run`: one integration of one system, its trajectory files, figure
//! and report. Runs whose recorded samples would not fit are refused before
//! they start.

use super::{parse_method, parse_params, step_count, step_flag, Format, Newton};
use crate::catalog::{declared_events, lookup, systems_with_events};
use crate::report::files::{OutputDir, OutputError};
use crate::report::format::exact;
use crate::report::progress::Progress;
use crate::run::files::{
    json_trajectory_bytes, run_figure, write_events_csv, write_run_csv, write_run_json, MAX_JSON_TRAJECTORY_BYTES,
};
use crate::run::{run, run_report, RunError, RunSpec};
use clap::Args;
use spark_runtime::{ConsistencyPolicy, Tolerance, MAX_ABSOLUTE_TOLERANCE};
use std::path::PathBuf;

#[derive(Args, Debug)]
/// Arguments of `spark run`.
pub struct RunArgs {
    /// System to integrate, by name or type name, any case (see `spark list`).
    #[arg(value_name = "SYSTEM", required_unless_present = "system_flag")]
    pub system: Option<String>,
    /// The system, as a flag (same as the positional argument).
    #[arg(long = "system", short = 'y', conflicts_with = "system")]
    pub system_flag: Option<String>,
    /// Method: gauss, lobatto-iiia-b, lobatto-iiia-b-d, euler-1, euler-2,
    /// modified-lobatto-iiia-b or lobatto-iiib-a-lda.
    #[arg(long, short, default_value = "gauss")]
    pub method: String,
    /// Number of stages s.
    #[arg(long, short, default_value_t = 2, allow_hyphen_values = true)]
    pub stages: usize,
    /// Step size h (default: the system's, see `spark list`).
    #[arg(long = "h", visible_alias = "step", allow_hyphen_values = true)]
    pub h: Option<f64>,
    /// Final time (default: the system's). The interval t_end − t0 must be
    /// a whole number of steps of h (up to round-off); otherwise the run is
    /// refused with the nearest t_end and h that are.
    #[arg(long, short, allow_hyphen_values = true)]
    pub t_end: Option<f64>,
    /// Initial time (default: the system's, 0).
    #[arg(long, allow_hyphen_values = true)]
    pub t0: Option<f64>,
    /// Initial coordinates, comma-separated (default: the system's; the
    /// paper's for its systems).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub q0: Option<Vec<f64>>,
    /// Initial velocities, comma-separated; must satisfy the constraints
    /// (default: the system's).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub v0: Option<Vec<f64>>,
    /// Set a system parameter, e.g. --param beta=0.5 (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Record every this many steps (and always the endpoints). Runs whose
    /// recorded samples would not fit in memory (at most 4 GiB, or half the
    /// available memory), or whose JSON trajectory would exceed 64 MiB, are
    /// refused before they start, with the --every that fits.
    #[arg(long, default_value_t = 1, allow_hyphen_values = true)]
    pub every: usize,
    /// Trajectory file format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    pub format: Format,
    /// Output folder. It is created and locked before the run starts (a
    /// second run on the same folder is refused); the files appear together
    /// when the run has finished, so an interrupted run leaves the previous
    /// results in place.
    #[arg(long, short, default_value = "results/run")]
    pub out: PathBuf,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Full)]
    pub newton: Newton,
    /// A step whose Newton iteration fails (after a retry from the cold
    /// starting guess) is replaced by two half steps, nested at most this
    /// many levels deep, 0 to 60; the report counts them ("steps halved").
    /// 0 ends the run at the first step that fails, so that every step is
    /// one of h.
    #[arg(long, default_value_t = spark_runtime::DEFAULT_MAX_HALVINGS,
          value_parser = clap::value_parser!(u32).range(0..=spark_runtime::MAX_HALVINGS as i64))]
    pub max_halvings: u32,
    /// Skip the plot.
    #[arg(long)]
    pub no_plot: bool,
    /// Replace an initial velocity that violates the constraints by the
    /// closest one that satisfies them (in the kinetic-energy metric)
    /// instead of stopping with an error.
    #[arg(long)]
    pub project_v0: bool,
    /// Tolerance-driven steps: the relative tolerance of the local error
    /// (step-doubling estimate, PI controller), from t0 to --t-end, the last
    /// step landing on it (--h and --max-halvings do not apply). Without
    /// --atol the absolute tolerance is the same number.
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["h", "max_halvings"])]
    pub rtol: Option<f64>,
    /// Tolerance-driven steps: the absolute tolerance of the local error
    /// (without --rtol the relative tolerance is the same number).
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["h", "max_halvings"])]
    pub atol: Option<f64>,
    /// Magnitude of the first step of a tolerance-driven run (default:
    /// estimated from the initial velocity and acceleration).
    #[arg(long, allow_hyphen_values = true)]
    pub first_step: Option<f64>,
    /// Largest step magnitude of a tolerance-driven run (default: the whole
    /// interval).
    #[arg(long, allow_hyphen_values = true)]
    pub max_step: Option<f64>,
    /// Most step attempts (accepted and rejected) of a tolerance-driven run
    /// (default 1000000); a run that needs more ends with an error. The
    /// recorded samples are checked against memory at this count before the
    /// run starts.
    #[arg(long, allow_hyphen_values = true)]
    pub max_steps: Option<usize>,
    /// Record the state at t0 + k·DT for k = 1, 2, … up to --t-end, from
    /// the continuous extension of the steps (which are not shortened to
    /// land on these times), instead of at every --every-th step.
    #[arg(long, value_name = "DT", allow_hyphen_values = true, conflicts_with = "every")]
    pub sample_every: Option<f64>,
    /// Locate the events the system declares (see `spark list`) and write
    /// them to events.csv; a terminal event ends the run.
    #[arg(long)]
    pub events: bool,
}

/// The default `--max-steps`: enough attempts for a million accepted steps
/// at a few rejections, and the recorded samples of that many fit in memory
/// for every registered system.
pub const DEFAULT_MAX_STEPS: usize = 1_000_000;

/// Most output times `--sample-every` makes.
const MAX_SAMPLE_TIMES: f64 = 1e8;

/// The number of output times `t0 + k·dt`, `k = 1, 2, …`, up to `t_end`
/// (a time within a millionth of `dt` of `t_end` is `t_end` itself): known
/// before any is made, so that a run recording too many is refused before
/// their list takes memory (10⁸ times are 800 MB).
fn sample_count(t0: f64, t_end: f64, dt: f64) -> Result<usize, String> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(format!("--sample-every must be a positive number, got {dt:.3e}"));
    }
    let count = ((t_end - t0) / dt * (1.0 + 1e-12) + 1e-6).floor();
    if count.is_nan() || count < 1.0 {
        return Err(format!(
            "--sample-every {} is longer than the interval from t0 = {} to t_end = {}; give a smaller DT",
            exact(dt),
            exact(t0),
            exact(t_end)
        ));
    }
    if count > MAX_SAMPLE_TIMES {
        return Err(format!(
            "--sample-every {dt:.3e} makes {count:.3e} output times, more than {MAX_SAMPLE_TIMES:.0e}; give a larger DT"
        ));
    }
    Ok(count as usize)
}

/// The `count` output times of [`sample_count`].
fn sample_times(t0: f64, t_end: f64, dt: f64, count: usize) -> Result<Vec<f64>, String> {
    let mut times: Vec<f64> = (1..=count).map(|k| (t0 + k as f64 * dt).min(t_end)).collect();
    if let Some(last) = times.last_mut() {
        if (t_end - *last).abs() <= 1e-6 * dt {
            *last = t_end;
        }
    }
    times.dedup();
    if times.windows(2).any(|w| w[1] <= w[0]) || times.first().is_some_and(|&t| t <= t0) {
        return Err(format!(
            "--sample-every {} is below the resolution of t near t0 = {}: the output times repeat; give a larger DT",
            exact(dt),
            exact(t0)
        ));
    }
    Ok(times)
}

/// The tolerance of a run with `--rtol` and/or `--atol`, or `None`.
fn tolerance(a: &RunArgs, t_end: f64) -> Result<Option<Tolerance>, String> {
    // Checked as given: a lone --atol stands for --rtol too, but a message
    // about it names the flag the user typed.
    for (flag, x) in [("--rtol", a.rtol), ("--atol", a.atol)] {
        if let Some(x) = x.filter(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err(format!("{flag} must be a finite number ≥ 0, got {x:.3e}"));
        }
    }
    let (rtol, atol) = match (a.rtol, a.atol) {
        (None, None) => {
            // Each would be ignored by a run of fixed steps.
            let given = [
                ("--first-step", a.first_step.is_some()),
                ("--max-step", a.max_step.is_some()),
                ("--max-steps", a.max_steps.is_some()),
            ];
            for (flag, given) in given {
                if given {
                    return Err(format!("{flag} applies to tolerance-driven runs: give --rtol and/or --atol"));
                }
            }
            return Ok(None);
        }
        (Some(r), None) => (r, r),
        (None, Some(a)) => (a, a),
        (Some(r), Some(a)) => (r, a),
    };
    if rtol == 0.0 && atol == 0.0 {
        return Err("--rtol and --atol are both 0: make one of them positive".into());
    }
    if rtol > 0.0 && rtol < 1e-15 {
        return Err(format!("--rtol {rtol:.3e} is below 1e-15, the round-off of double precision; give 0 or ≥ 1e-15"));
    }
    if rtol >= 1.0 {
        // Without --rtol the relative tolerance is --atol's value.
        let given = if a.rtol.is_some() { "--rtol" } else { "--atol (without --rtol, the relative tolerance too)" };
        return Err(format!(
            "{given} {rtol:.3e}: a relative tolerance must lie below 1 (a relative error of 1 is as large as the \
             state, so no digit would be controlled); give --rtol in [1e-15, 1) or 0"
        ));
    }
    if atol > MAX_ABSOLUTE_TOLERANCE {
        return Err(format!(
            "--atol {atol:.3e} is above 1.34e154, the largest state with a finite kinetic energy, so it bounds \
             nothing; give --atol in [0, 1.34e154]"
        ));
    }
    for (flag, x) in [("--first-step", a.first_step), ("--max-step", a.max_step)] {
        if let Some(x) = x {
            if !(x.is_finite() && x > 0.0) {
                return Err(format!("{flag} must be a positive number, got {x:.3e}"));
            }
            // Below the smallest normal number 1/h overflows in a step.
            if x < f64::MIN_POSITIVE {
                return Err(format!("{flag} {x:.3e} is subnormal; give at least 2.2e-308"));
            }
        }
    }
    let max_steps = a.max_steps.unwrap_or(DEFAULT_MAX_STEPS);
    if max_steps == 0 {
        return Err("--max-steps must be at least 1".into());
    }
    Ok(Some(Tolerance { rtol, atol, first_step: a.first_step, max_step: a.max_step, max_steps, t_end }))
}

/// What a run records, for the advice of [`check_output_size`]: each mode
/// records fewer samples through other flags.
#[derive(Clone, Copy, Debug)]
enum Recording {
    /// Every `--every`-th fixed step.
    Steps,
    /// Every `--every`-th accepted step of a tolerance-driven run, counted
    /// at its step limit `--max-steps`.
    Tolerance,
    /// One sample per output time `t0 + k·DT` (`--sample-every DT`).
    Times {
        /// The DT given.
        dt: f64,
    },
}

impl Recording {
    /// How to record at most a `thin`-th of the samples.
    fn fewer(self, thin: u64) -> String {
        match self {
            Recording::Steps => format!("record fewer with --every {thin} or more, raise --h, or shorten --t-end"),
            Recording::Tolerance => format!(
                "record fewer with --every {thin} or more, or lower --max-steps (a tolerance-driven run is counted \
                 at its step limit)"
            ),
            Recording::Times { dt } => {
                format!("give a --sample-every of {:.3e} or more, or shorten --t-end", dt * thin as f64)
            }
        }
    }
}

/// Refuses runs whose recorded trajectory would not fit in memory, or whose
/// JSON trajectory would be unreasonably large, before any computation.
fn check_output_size(
    steps: usize,
    n: usize,
    m: usize,
    holonomic: bool,
    format: Format,
    every: usize,
    recording: Recording,
) -> Result<(), String> {
    // Per sample: the run's record and columns, and the figure's points.
    let per_sample = crate::run::bytes_per_sample(n, m) + 16 * (2 * n as u64 + 3);
    if let Err(e) = spark_runtime::check_record_size(steps, every, 1, per_sample) {
        // `e.every` is the record interval that fits; with output times
        // (every = 1) it is also the factor by which DT has to grow.
        return Err(format!(
            "the run records {:.3e} samples ({:.3e} bytes in memory), more than the limit of {:.3e} bytes; {}",
            e.samples as f64,
            e.bytes,
            e.limit as f64,
            recording.fewer(e.every),
        ));
    }
    let samples = ((steps / every) as u64).saturating_add(2);
    let thin = |limit_samples: u64| (samples / limit_samples.max(1) + 1).saturating_mul(every as u64);
    if matches!(format, Format::Json | Format::Both) {
        let json = json_trajectory_bytes(samples, n, holonomic);
        if json > MAX_JSON_TRAJECTORY_BYTES {
            let per = json_trajectory_bytes(1, n, holonomic);
            return Err(format!(
                "the JSON trajectory would take about {:.3e} bytes, more than the limit of {:.3e}; write it as CSV \
                 (--format csv) or {}",
                json as f64,
                MAX_JSON_TRAJECTORY_BYTES as f64,
                recording.fewer(thin(MAX_JSON_TRAJECTORY_BYTES / per)),
            ));
        }
    }
    Ok(())
}

/// Every entry of `--q0` / `--v0` must be finite.
fn check_finite(flag: &str, values: &[f64]) -> Result<(), String> {
    match values.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(format!("{flag}: entry {} is {}, not a finite number", i + 1, values[i])),
        None => Ok(()),
    }
}

/// `spark run`: one integration, its files and its report.
pub fn run_command(a: RunArgs) -> Result<String, String> {
    let name = a.system.as_deref().or(a.system_flag.as_deref()).ok_or("name a system (see `spark list`)")?;
    let entry = lookup(name).map_err(|e| e.to_string())?;
    let method = parse_method(&a.method)?;
    let h = a.h.unwrap_or(entry.h);
    let t0 = a.t0.unwrap_or(entry.t0);
    if !(h.is_finite() && h > 0.0) {
        return Err(format!("--h must be a positive number, got {h:.3e}"));
    }
    if !t0.is_finite() {
        return Err(format!("--t0 must be a finite number, got {t0:.3e}"));
    }
    let t_end = match a.t_end {
        Some(t_end) if !(t_end.is_finite() && t_end > t0) => {
            return Err(format!("--t-end must be a number greater than t0 = {}, got {}", exact(t0), exact(t_end)));
        }
        Some(t_end) => t_end,
        // Only a --t0 far from 0 makes the default end fall on t0 (or
        // overflow): name what was given and what it was compared with.
        None => match t0 + entry.t_end {
            t_end if t_end.is_finite() && t_end > t0 => t_end,
            t_end => {
                return Err(format!(
                    "--t0 {} leaves no interval to run: the default end, t0 + {} (the system's run length, see \
                     `spark list`), is {}, not after t0 at this magnitude; give a --t-end greater than --t0, or a \
                     --t0 nearer 0",
                    exact(t0),
                    exact(entry.t_end),
                    exact(t_end)
                ));
            }
        },
    };
    if a.stages == 0 {
        return Err("--stages must be at least 1".into());
    }
    if a.every == 0 {
        return Err("--every must be at least 1 (1 records every step)".into());
    }
    let tolerance = tolerance(&a, t_end)?;
    // Fixed steps cover the interval in whole steps of h; a tolerance-driven
    // run is counted at its step limit.
    let steps = match tolerance {
        None => {
            spark_runtime::check_step_size(t0, h)
                .map_err(|why| format!("{} from t0 = {t0:.3e}: {why}", step_flag(a.h, h)))?;
            step_count(t0, t_end, h)?
        }
        Some(_) => 1,
    };
    let sampled = a.sample_every.map(|dt| sample_count(t0, t_end, dt).map(|count| (dt, count))).transpose()?;
    let (recorded, every, recording) = match (sampled, &tolerance) {
        (Some((dt, count)), _) => (count, 1, Recording::Times { dt }),
        (None, Some(t)) => (t.max_steps, a.every, Recording::Tolerance),
        _ => (steps, a.every, Recording::Steps),
    };
    check_output_size(recorded, entry.n, entry.m, entry.effects.holonomic, a.format, every, recording)?;
    let times = sampled.map(|(dt, count)| sample_times(t0, t_end, dt, count)).transpose()?;
    let mut spec = RunSpec::paper(entry.kind, method, a.stages, h, steps);
    spec.t0 = t0;
    for (flag, what, given) in [("--q0", "q0", &a.q0), ("--v0", "v0", &a.v0)] {
        let Some(x) = given else { continue };
        if x.len() != entry.n {
            let coordinates = entry.coordinates.join(", ");
            let (got, expected, system) = (x.len(), entry.n, entry.name);
            return Err(RunError::Dimension { what, system, got, expected, coordinates }.to_string());
        }
        check_finite(flag, x)?;
    }
    if let Some(q0) = a.q0 {
        spec.q0 = q0;
    }
    if let Some(v0) = a.v0 {
        spec.v0 = v0;
    }
    spec.parameters = parse_params(&a.params)?;
    spec.record_every = a.every;
    spec.newton.mode = a.newton.into();
    spec.max_halvings = a.max_halvings;
    spec.tolerance = tolerance;
    spec.times = times;
    spec.events = a.events;
    if a.events && declared_events(entry.kind).is_empty() {
        return Err(format!(
            "system `{}` declares no events, so --events has nothing to locate; systems with events: {}",
            entry.name,
            systems_with_events().join(", ")
        ));
    }
    if a.project_v0 {
        spec.consistency = ConsistencyPolicy::Project { tolerance: 1e-12 };
    }
    // The folder is created and locked before the run, so an unwritable or
    // busy --out is reported at once.
    let mut out = OutputDir::open(&a.out).map_err(|e| e.to_string())?;
    let progress = Progress::on_terminal();
    let label = format!("{} {} s={}", entry.name, method, a.stages);
    let bar = if tolerance.is_some() { progress.counter(&label) } else { progress.bar(&label, steps as u64) };
    let result = run(&spec, &|n| {
        bar.inc(n);
        true
    })
    .map_err(|e| match e {
        // A step that failed after its halvings: the flag that set their
        // depth is the other thing to change.
        RunError::Integration { source: spark_runtime::IntegrationError::Step { .. }, .. } => format!(
            "{e}\n(a failing step is halved at most --max-halvings {} levels deep; a smaller --h, or a larger \
             --max-halvings up to {}, may get through)",
            a.max_halvings,
            spark_runtime::MAX_HALVINGS
        ),
        e => e.to_string(),
    })?;
    bar.finish_and_clear();
    let stem = format!("{}_{}_s{}", entry.name, method.key(), a.stages);
    let e = |e: OutputError| e.to_string();
    // A file of this stem that the run does not write belongs to an earlier
    // run and goes, so that every file of the stem describes this run.
    if matches!(a.format, Format::Csv | Format::Both) {
        write_run_csv(&result, &mut out, &format!("{stem}.csv")).map_err(e)?;
    } else {
        out.remove_stale(&format!("{stem}.csv"));
    }
    if matches!(a.format, Format::Json | Format::Both) {
        write_run_json(&result, &mut out, &format!("{stem}.json")).map_err(e)?;
    } else {
        out.remove_stale(&format!("{stem}.json"));
    }
    if a.events {
        write_events_csv(&result, &mut out, "events.csv").map_err(e)?;
    } else {
        out.remove_stale("events.csv");
    }
    if !a.no_plot {
        out.render(&run_figure(&result), &stem).map_err(e)?;
    } else {
        out.remove_stale(&format!("{stem}.png"));
        out.remove_stale(&format!("{stem}.svg"));
    }
    // The reports come last: they describe the files above.
    let report = run_report(&result, &spec);
    out.write_bytes("report.md", report.as_bytes()).map_err(e)?;
    let summary = serde_json::json!({
        "system": entry.name, "type": entry.type_name, "method": method.name(), "stages": a.stages,
        "h": h, "t0": t0, "q0": spec.q0, "v0": spec.v0, "v0_integrated": result.initial_velocity(),
        "parameters": spec.parameters, "stats": result.stats, "tolerance": spec.tolerance,
        "controller": result.controller, "events": result.events,
    });
    out.write_json("report.json", &summary).map_err(e)?;
    let files = out.commit().map_err(e)?;
    let mut text = report;
    for f in files {
        text.push_str(&format!("wrote {}\n", f.display()));
    }
    Ok(text)
}
