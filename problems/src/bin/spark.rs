//! `spark`: the command-line program. Lists the systems and methods, runs one
//! simulation, or reproduces the paper's experiments (§8) with one command.

use clap::{Args, Parser, Subcommand, ValueEnum};
use problems::output::{
    json_trajectory_bytes, run_figure, write_run_csv, write_run_json, OutputDir, MAX_JSON_TRAJECTORY_BYTES,
};
use problems::paper::{run_paper, PaperConfig, PaperReport};
use problems::progress::Progress;
use problems::registry::{list_json, list_table, lookup, nearest, MAX_DISPATCH_STAGES};
use problems::simulate::{run, run_report, RunError, RunSpec};
use spark_runtime::{ConsistencyPolicy, Method, NewtonMode};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Lagrange–d'Alembert SPARK integrators for nonholonomic mechanical systems.
///
/// Start with `spark list` to see what is available, `spark run skate`
/// to integrate one system, or `spark paper` to reproduce every figure and
/// table of the paper's §8 (L. O. Jay, "Lagrange–d'Alembert SPARK integrators
/// for nonholonomic Lagrangian systems") into the folder `results/`.
#[derive(Parser, Debug)]
#[command(name = "spark", version, about, long_about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Show the systems (name, N, M, structure, effects, parameters, default
    /// initial state) and integration methods this program knows.
    List(ListArgs),
    /// Integrate one system with one method; write the trajectory (CSV and/or
    /// JSON), a report (report.md, report.json: energy error, constraint
    /// residual, holonomic drift, Newton iterations) and a plot (PNG + SVG).
    ///
    /// Example: spark run robot --method lobatto-iiia-b-d --stages 3 --h 0.2 --t-end 150 --out results/robot
    Run(RunArgs),
    /// Reproduce the paper's experiments (Figs. 8.1–8.4): figures as PNG and
    /// SVG, the numbers behind each figure as CSV, and a summary table
    /// (printed, and written as summary.md / summary.json).
    ///
    /// The full run integrates 3 methods × 10 initial values × 10⁶ steps for
    /// Fig. 8.4; it uses every CPU core (set RAYON_NUM_THREADS to limit).
    Paper(PaperArgs),
    /// Work-precision diagrams: global error and energy error vs wall time for
    /// every method and stage count on any registered system (default: the
    /// paper's four), with peers (num-dual, finite differences, ode_solvers,
    /// CasADi-generated C, SciPy; the paper-only ones skipped elsewhere)
    /// measured in the same run.
    ///
    /// Example: spark work-precision --system skate --system driven-skate --out results/work-precision
    WorkPrecision(problems::workprecision::cli::WorkPrecisionArgs),
    /// Poincaré section: integrate an ensemble (in parallel) and record the
    /// states where it crosses one of the system's declared events; writes
    /// the points (CSV), a scatter figure (PNG + SVG) and section.json.
    ///
    /// Example: spark section mp7-nh --event section --members 10 --t-end 500 --out results/section
    Section(SectionArgs),
    /// Stress suite: hard cases with checks, figures and a report.
    ///
    /// Example: spark stress --full --out docs/stress
    Stress(problems::stress::cli::StressArgs),
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Format {
    Csv,
    Json,
    Both,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Newton {
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

#[derive(Args, Debug)]
struct ListArgs {
    /// Print the systems as JSON instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
struct RunArgs {
    /// System to integrate, by name or type name, any case (see `spark list`).
    #[arg(value_name = "SYSTEM", required_unless_present = "system_flag")]
    system: Option<String>,
    /// The system, as a flag (same as the positional argument).
    #[arg(long = "system", short = 'y', conflicts_with = "system")]
    system_flag: Option<String>,
    /// Method: gauss, lobatto-iiia-b, lobatto-iiia-b-d, euler-1, euler-2,
    /// modified-lobatto-iiia-b or lobatto-iiib-a-lda.
    #[arg(long, short, default_value = "gauss")]
    method: String,
    /// Number of stages s.
    #[arg(long, short, default_value_t = 2)]
    stages: usize,
    /// Step size h (default: the system's, see `spark list`).
    #[arg(long = "h", visible_alias = "step", allow_hyphen_values = true)]
    h: Option<f64>,
    /// Final time (default: the system's). The interval t_end − t0 must be
    /// a whole number of steps of h (up to round-off); otherwise the run is
    /// refused with the nearest t_end and h that are.
    #[arg(long, short, allow_hyphen_values = true)]
    t_end: Option<f64>,
    /// Initial time (default: the system's, 0).
    #[arg(long, allow_hyphen_values = true)]
    t0: Option<f64>,
    /// Initial coordinates, comma-separated (default: the system's; the
    /// paper's for its systems).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    q0: Option<Vec<f64>>,
    /// Initial velocities, comma-separated; must satisfy the constraints
    /// (default: the system's).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    v0: Option<Vec<f64>>,
    /// Set a system parameter, e.g. --param beta=0.5 (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// Record every this many steps (and always the endpoints). Runs whose
    /// recorded samples would not fit in memory (at most 4 GiB, or half the
    /// available memory), or whose JSON trajectory would exceed 64 MiB, are
    /// refused before they start, with the --every that fits.
    #[arg(long, default_value_t = 1)]
    every: usize,
    /// Trajectory file format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    format: Format,
    /// Output folder. It is created and locked before the run starts (a
    /// second run on the same folder is refused); the files appear together
    /// when the run has finished, so an interrupted run leaves the previous
    /// results in place.
    #[arg(long, short, default_value = "results/run")]
    out: PathBuf,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Full)]
    newton: Newton,
    /// Skip the plot.
    #[arg(long)]
    no_plot: bool,
    /// Replace an initial velocity that violates the constraints by the
    /// closest one that satisfies them (in the kinetic-energy metric)
    /// instead of stopping with an error.
    #[arg(long)]
    project_v0: bool,
}

#[derive(Args, Debug)]
struct SectionArgs {
    /// System, by name or type name, any case (see `spark list`); it must
    /// declare events.
    #[arg(value_name = "SYSTEM")]
    system: String,
    /// Name of the declared event whose crossings make the section.
    #[arg(long)]
    event: String,
    /// Ensemble size J (members 0..J; for the McLachlan–Perlmutter particles
    /// the paper's initial states j = 0..J−1).
    #[arg(long, default_value_t = 10)]
    members: usize,
    /// Method (as for `spark run`).
    #[arg(long, short, default_value = "gauss")]
    method: String,
    /// Number of stages s.
    #[arg(long, short, default_value_t = 2)]
    stages: usize,
    /// Step size h (default: the system's, see `spark list`).
    #[arg(long = "h", visible_alias = "step", allow_hyphen_values = true)]
    h: Option<f64>,
    /// Final time of every member (default: the system's); t_end − t0 must
    /// be a whole number of steps of h.
    #[arg(long, short, allow_hyphen_values = true)]
    t_end: Option<f64>,
    /// Set a system parameter, e.g. --param alpha=0.3 (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// Horizontal axis of the figure: q_NAME, v_NAME or a coordinate name
    /// (default: chosen per system).
    #[arg(long)]
    x: Option<String>,
    /// Vertical axis of the figure (as --x).
    #[arg(long)]
    y: Option<String>,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Full)]
    newton: Newton,
    /// Output folder (created and locked; files appear when the run ends).
    #[arg(long, short, default_value = "results/section")]
    out: PathBuf,
}

#[derive(Args, Debug)]
struct PaperArgs {
    /// Output folder for figures, CSV files and the summary.
    #[arg(long, short, default_value = "results")]
    out: PathBuf,
    /// Shorten every interval to this fraction of the paper's (e.g. 0.01 for a
    /// quick look); 1 reproduces the paper.
    #[arg(long, default_value_t = 1.0)]
    fraction: f64,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Simplified)]
    newton: Newton,
    /// Newton stopping tolerance on the scaled update (default 16ε ≈ 3.6e-15;
    /// looser values show what inexact solves do to the energy behaviour).
    #[arg(long)]
    newton_tol: Option<f64>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::List(args) => list(args),
        Command::Run(args) => run_command(args),
        Command::Paper(args) => paper_command(args),
        Command::WorkPrecision(args) => {
            problems::workprecision::cli::run(args, &|m| eprintln!("{m}")).map(|text| print!("{text}"))
        }
        Command::Section(args) => section_command(args),
        Command::Stress(args) => problems::stress::cli::run(args).map(|text| print!("{text}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Method command-line names, in listing order.
const METHODS: [(Method, &str); 7] = [
    (Method::Gauss, "gauss"),
    (Method::LobattoIIIAB, "lobatto-iiia-b"),
    (Method::LobattoIIIABD, "lobatto-iiia-b-d"),
    (Method::SymplecticEulerI, "euler-1"),
    (Method::SymplecticEulerII, "euler-2"),
    (Method::ModifiedLobattoIIIAB, "modified-lobatto-iiia-b"),
    (Method::LobattoIIIBALda, "lobatto-iiib-a-lda"),
];

fn list(a: ListArgs) -> Result<(), String> {
    if a.json {
        let text = serde_json::to_string_pretty(&list_json()).map_err(|e| e.to_string())?;
        println!("{text}");
        return Ok(());
    }
    println!("Systems (use the name with `spark run NAME` or `--system NAME`):\n");
    print!("{}", list_table());
    println!("\nMethods (use the name with --method, the stage count with --stages):\n");
    for (m, key) in METHODS {
        let (lo, hi) = m.stage_range();
        let hi = hi.min(MAX_DISPATCH_STAGES);
        let stages = if lo == hi { format!("s = {lo}") } else { format!("s = {lo}..{hi}") };
        let order = if lo == hi { format!("order {}", m.order(lo)) } else { "order ".to_string() + &order_formula(m) };
        println!("  {key:<24} {:<42} {stages:<10} {order}", m.name());
    }
    Ok(())
}

fn parse_method(name: &str) -> Result<Method, String> {
    name.parse().map_err(|e: spark_runtime::TableauError| match nearest(name, METHODS.iter().map(|m| m.1)) {
        Some(s) => format!("{e} (did you mean `{s}`?)"),
        None => e.to_string(),
    })
}

fn order_formula(m: Method) -> String {
    match m {
        Method::Gauss => "2s".into(),
        _ => "2s − 2".into(),
    }
}

fn parse_params(params: &[String]) -> Result<Vec<(String, f64)>, String> {
    params
        .iter()
        .map(|p| {
            let (name, value) =
                p.split_once('=').ok_or_else(|| format!("--param `{p}`: write NAME=VALUE, e.g. --param beta=0.5"))?;
            let v: f64 = value.trim().parse().map_err(|_| format!("--param `{p}`: `{value}` is not a number"))?;
            if !v.is_finite() {
                return Err(format!("--param `{p}`: the value must be a finite number"));
            }
            Ok((name.trim().to_string(), v))
        })
        .collect()
}

/// Every entry of `--q0` / `--v0` must be finite.
fn check_finite(flag: &str, values: &[f64]) -> Result<(), String> {
    match values.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(format!("{flag}: entry {} is {}, not a finite number", i + 1, values[i])),
        None => Ok(()),
    }
}

/// Relative tolerance within which `(t_end − t0)/h` counts as a whole number
/// of steps (round-off of the division, e.g. 150/0.2 = 749.999…).
const WHOLE_STEPS_TOLERANCE: f64 = 1e-9;

/// Most steps `spark run` takes: 2⁵³, beyond which step counts and the times
/// `t0 + k·h` are no longer exact in `f64`.
const MAX_STEPS: f64 = 9_007_199_254_740_992.0;

/// Fixed cap on the memory the recorded trajectory of `spark run` may take
/// (samples in the stepper's record, the result columns and the figure's
/// curves): 4 GiB, lowered to half the available memory when the system
/// reports it.
const MAX_TRAJECTORY_MEMORY: u64 = 4 << 30;

/// The number of steps from `t0` to `t_end` with step `h`, or an error naming
/// the flags when the interval is not a whole number of steps (the run would
/// end elsewhere than asked) or too many steps.
fn step_count(t0: f64, t_end: f64, h: f64) -> Result<usize, String> {
    let ratio = (t_end - t0) / h;
    if ratio.is_nan() || ratio > MAX_STEPS {
        return Err(format!(
            "(t_end − t0)/h = {ratio:.3e} steps is more than 2^53 = {MAX_STEPS:.3e}, the most a run can count; \
             raise --h or shorten the interval --t0 … --t-end"
        ));
    }
    let steps = ratio.round();
    if steps < 1.0 {
        return Err(format!(
            "the interval from t0 = {t0:.6e} to --t-end {t_end:.6e} is shorter than one step of --h {h:.6e}; \
             use a later --t-end or a smaller --h"
        ));
    }
    if (ratio - steps).abs() > WHOLE_STEPS_TOLERANCE * steps {
        let (below, above) = (ratio.floor().max(1.0), ratio.ceil());
        return Err(format!(
            "the interval from t0 = {t0:.6e} to --t-end {t_end:.6e} is {ratio:.6e} steps of --h {h:.6e}, not a whole \
             number; use --t-end {:.6e} or {:.6e}, or --h {:.6e} ({above:.0} steps)",
            t0 + below * h,
            t0 + above * h,
            (t_end - t0) / above,
        ));
    }
    Ok(steps as usize)
}

/// Half of `MemAvailable` from /proc/meminfo, when the system reports it.
fn half_available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024) / 2)
}

/// Refuses runs whose recorded trajectory would not fit in memory, or whose
/// JSON trajectory would be unreasonably large, before any computation.
fn check_output_size(
    samples: u64,
    n: usize,
    m: usize,
    holonomic: bool,
    format: Format,
    every: usize,
) -> Result<(), String> {
    // Per sample: the stepper's record (t, q, v, energy, residual,
    // multipliers, iterations), the result columns, and the figure's points.
    let per_sample = 8 * (1 + 2 * n as u64 + 4 + m as u64 + 2) + 8 * (2 * n as u64 + 4) + 16 * (2 * n as u64 + 3);
    let bytes = samples.saturating_mul(per_sample);
    let limit = half_available_memory().map_or(MAX_TRAJECTORY_MEMORY, |a| a.min(MAX_TRAJECTORY_MEMORY));
    let thin = |limit_samples: u64| (samples / limit_samples.max(1) + 1).saturating_mul(every as u64);
    if bytes > limit {
        return Err(format!(
            "the run records {samples:.3e} samples ({:.3e} bytes in memory), more than the limit of {:.3e} bytes; \
             record fewer with --every {} or more, raise --h, or shorten --t-end",
            bytes as f64,
            limit as f64,
            thin(limit / per_sample),
            samples = samples as f64,
        ));
    }
    if matches!(format, Format::Json | Format::Both) {
        let json = json_trajectory_bytes(samples, n, holonomic);
        if json > MAX_JSON_TRAJECTORY_BYTES {
            let per = json_trajectory_bytes(1, n, holonomic);
            return Err(format!(
                "the JSON trajectory would take about {:.3e} bytes, more than the limit of {:.3e}; write it as CSV \
                 (--format csv) or record fewer samples with --every {} or more",
                json as f64,
                MAX_JSON_TRAJECTORY_BYTES as f64,
                thin(MAX_JSON_TRAJECTORY_BYTES / per),
            ));
        }
    }
    Ok(())
}

fn run_command(a: RunArgs) -> Result<(), String> {
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
    let t_end = a.t_end.unwrap_or(t0 + entry.t_end);
    if !(t_end.is_finite() && t_end > t0) {
        return Err(format!("--t-end must be a number greater than t0 = {t0:.6e}, got {t_end:.3e}"));
    }
    if a.stages == 0 {
        return Err("--stages must be at least 1".into());
    }
    if a.every == 0 {
        return Err("--every must be at least 1 (1 records every step)".into());
    }
    let steps = step_count(t0, t_end, h)?;
    let samples = (steps / a.every) as u64 + 2;
    check_output_size(samples, entry.n, entry.m, entry.effects.holonomic, a.format, a.every)?;
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
    if a.project_v0 {
        spec.consistency = ConsistencyPolicy::Project { tolerance: 1e-12 };
    }
    // The folder is created and locked before the run, so an unwritable or
    // busy --out is reported at once.
    let mut out = OutputDir::open(&a.out).map_err(|e| e.to_string())?;
    let progress = Progress::on_terminal();
    let bar = progress.bar(&format!("{} {} s={}", entry.name, method, a.stages), steps as u64);
    let result = run(&spec, &|n| bar.inc(n)).map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    let stem = format!("{}_{}_s{}", entry.name, method_key(method), a.stages);
    let e = |e: problems::output::OutputError| e.to_string();
    if matches!(a.format, Format::Csv | Format::Both) {
        write_run_csv(&result, &mut out, &format!("{stem}.csv")).map_err(e)?;
    }
    if matches!(a.format, Format::Json | Format::Both) {
        write_run_json(&result, &mut out, &format!("{stem}.json")).map_err(e)?;
    }
    if !a.no_plot {
        out.render(&run_figure(&result), &stem).map_err(e)?;
    }
    // The reports come last: they describe the files above.
    let report = run_report(&result, &spec);
    out.write_bytes("report.md", report.as_bytes()).map_err(e)?;
    let summary = serde_json::json!({
        "system": entry.name, "type": entry.type_name, "method": method.name(), "stages": a.stages,
        "h": h, "t0": t0, "q0": spec.q0, "v0": spec.v0, "parameters": spec.parameters, "stats": result.stats,
    });
    out.write_json("report.json", &summary).map_err(e)?;
    let files = out.commit().map_err(e)?;
    print!("{report}");
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

fn section_command(a: SectionArgs) -> Result<(), String> {
    use problems::section::{default_axes, find_event, parse_axis, run_section, write_section, SectionSpec};
    let entry = lookup(&a.system).map_err(|e| e.to_string())?;
    // The event and the axes are checked before anything runs.
    find_event(entry.kind, &a.event).map_err(|e| e.to_string())?;
    let (dx, dy) = default_axes(entry.kind);
    let x = a.x.as_deref().map(|n| parse_axis(entry, "--x", n)).transpose().map_err(|e| e.to_string())?.unwrap_or(dx);
    let y = a.y.as_deref().map(|n| parse_axis(entry, "--y", n)).transpose().map_err(|e| e.to_string())?.unwrap_or(dy);
    let method = parse_method(&a.method)?;
    let h = a.h.unwrap_or(entry.h);
    let t0 = entry.t0;
    if !(h.is_finite() && h > 0.0) {
        return Err(format!("--h must be a positive number, got {h:.3e}"));
    }
    let t_end = a.t_end.unwrap_or(t0 + entry.t_end);
    if !(t_end.is_finite() && t_end > t0) {
        return Err(format!("--t-end must be a number greater than t0 = {t0:.6e}, got {t_end:.3e}"));
    }
    if a.stages == 0 {
        return Err("--stages must be at least 1".into());
    }
    if a.members == 0 || a.members > problems::section::MAX_SECTION_MEMBERS {
        return Err(format!("--members must lie in 1..={}, got {}", problems::section::MAX_SECTION_MEMBERS, a.members));
    }
    let steps = step_count(t0, t_end, h)?;
    let newton = spark_runtime::NewtonOptions { mode: a.newton.into(), ..spark_runtime::NewtonOptions::default() };
    let spec = SectionSpec {
        system: entry.kind,
        event: a.event.clone(),
        members: a.members,
        method,
        stages: a.stages,
        h,
        steps,
        t0,
        parameters: parse_params(&a.params)?,
        newton,
    };
    let mut out = OutputDir::open(&a.out).map_err(|e| e.to_string())?;
    let section = run_section(&spec).map_err(|e| e.to_string())?;
    if section.points.is_empty() {
        return Err(format!(
            "no member crossed `{}` ({} = 0, {:?}) by t = {t_end:.6e}: there is no crossing of the event to plot; \
             integrate longer with --t-end, or choose another event",
            section.event, section.source, section.direction
        ));
    }
    write_section(&section, &spec, (x, y), &mut out).map_err(|e| e.to_string())?;
    let files = out.commit().map_err(|e| e.to_string())?;
    println!(
        "{} {} ({}): {} crossings of {} = 0 in {} member(s) to t = {t_end}, max |g| = {:.3e}",
        entry.name,
        section.event,
        method.name(),
        section.points.len(),
        section.source,
        a.members,
        section.max_residual()
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

fn method_key(m: Method) -> &'static str {
    METHODS.iter().find(|x| x.0 == m).map_or("method", |x| x.1)
}

fn paper_command(a: PaperArgs) -> Result<(), String> {
    if !(a.fraction.is_finite() && a.fraction > 0.0 && a.fraction <= 1.0) {
        return Err("--fraction must lie in (0, 1]".into());
    }
    let mut cfg =
        if a.fraction == 1.0 { PaperConfig::full(&a.out) } else { PaperConfig::shortened(&a.out, a.fraction) };
    cfg.newton.mode = a.newton.into();
    if let Some(tol) = a.newton_tol {
        if !(tol.is_finite() && tol > 0.0) {
            return Err("--newton-tol must be a positive number".into());
        }
        cfg.newton.tolerance = tol;
        cfg.newton.stagnation_level = cfg.newton.stagnation_level.max(tol);
    }
    let start = Instant::now();
    let report = run_paper(&cfg, &Progress::on_terminal()).map_err(|e| e.to_string())?;
    print_report(&report);
    println!("\nTotal wall time: {:.1} s on {} thread(s).", start.elapsed().as_secs_f64(), report.threads);
    println!("Wrote {} files into {}.", report.files.len(), a.out.display());
    Ok(())
}

fn print_report(report: &PaperReport) {
    println!(
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
        println!(
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
    println!("\nFig. 8.4 growth (1/h⁴)·mean_j (E_jk − E0)² ≈ C·t^p:");
    for g in &report.growth {
        let late = g.late_fit.map_or(String::new(), |f| format!("; last decade p = {:.3}", f.exponent));
        match g.fit {
            Some(f) => println!(
                "  {:<36} {:<58} p = {:.3} ± {:.3}  (C = {:.3e}, t ≥ {}{late})",
                g.method,
                g.constraint.formula(),
                f.exponent,
                f.exponent_std_error,
                f.coefficient,
                f.t_min
            ),
            None => println!("  {:<36} {:<58} (not enough positive samples to fit)", g.method, g.constraint.formula()),
        }
    }
}
