//! `spark`: the command-line program. Lists the systems and methods, runs one
//! simulation, or reproduces the paper's experiments (§8) with one command.

use clap::{Args, Parser, Subcommand, ValueEnum};
use problems::output::{create_dir, run_figure, write_run_csv, write_run_json};
use problems::paper::{run_paper, PaperConfig, PaperReport};
use problems::plot::render;
use problems::progress::Progress;
use problems::registry::{list_json, list_table, lookup, nearest, MAX_DISPATCH_STAGES};
use problems::simulate::{run, run_report, RunSpec};
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
    /// Stress suite (issue 7): hard cases with checks, figures and a report.
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
    /// Final time; the number of steps is (t_end − t0)/h, rounded (default:
    /// the system's).
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
    /// Record every this many steps.
    #[arg(long, default_value_t = 1)]
    every: usize,
    /// Trajectory file format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    format: Format,
    /// Output folder.
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
            Ok((name.trim().to_string(), v))
        })
        .collect()
}

fn run_command(a: RunArgs) -> Result<(), String> {
    let name = a.system.as_deref().or(a.system_flag.as_deref()).ok_or("name a system (see `spark list`)")?;
    let entry = lookup(name).map_err(|e| e.to_string())?;
    let method = parse_method(&a.method)?;
    let h = a.h.unwrap_or(entry.h);
    let t0 = a.t0.unwrap_or(entry.t0);
    let t_end = a.t_end.unwrap_or(t0 + entry.t_end);
    if !(h.is_finite() && h > 0.0) {
        return Err(format!("--h must be a positive number, got {h}"));
    }
    if !(t0.is_finite() && t_end.is_finite() && t_end > t0) {
        return Err(format!("--t-end must be a number greater than t0 = {t0}, got {t_end}"));
    }
    let steps = ((t_end - t0) / h).round().max(1.0) as usize;
    let mut spec = RunSpec::paper(entry.kind, method, a.stages, h, steps);
    spec.t0 = t0;
    if let Some(q0) = a.q0 {
        spec.q0 = q0;
    }
    if let Some(v0) = a.v0 {
        spec.v0 = v0;
    }
    spec.parameters = parse_params(&a.params)?;
    spec.record_every = a.every.max(1);
    spec.newton.mode = a.newton.into();
    if a.project_v0 {
        spec.consistency = ConsistencyPolicy::Project { tolerance: 1e-12 };
    }
    let progress = Progress::on_terminal();
    let bar = progress.bar(&format!("{} {} s={}", entry.name, method, a.stages), steps as u64);
    let result = run(&spec, &|n| bar.inc(n)).map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    create_dir(&a.out).map_err(|e| e.to_string())?;
    let stem = a.out.join(format!("{}_{}_s{}", entry.name, method_key(method), a.stages));
    let mut files = Vec::new();
    if matches!(a.format, Format::Csv | Format::Both) {
        let p = stem.with_extension("csv");
        write_run_csv(&result, &p).map_err(|e| e.to_string())?;
        files.push(p);
    }
    if matches!(a.format, Format::Json | Format::Both) {
        let p = stem.with_extension("json");
        write_run_json(&result, &p).map_err(|e| e.to_string())?;
        files.push(p);
    }
    let report = run_report(&result, &spec);
    let md = a.out.join("report.md");
    std::fs::write(&md, &report).map_err(|e| format!("could not write {}: {e}", md.display()))?;
    files.push(md);
    let json = a.out.join("report.json");
    let summary = serde_json::json!({
        "system": entry.name, "type": entry.type_name, "method": method.name(), "stages": a.stages,
        "h": h, "t0": t0, "q0": spec.q0, "v0": spec.v0, "parameters": spec.parameters, "stats": result.stats,
    });
    let text = serde_json::to_string_pretty(&summary).map_err(|e| e.to_string())?;
    std::fs::write(&json, text).map_err(|e| format!("could not write {}: {e}", json.display()))?;
    files.push(json);
    if !a.no_plot {
        files.extend(render(&run_figure(&result), &stem).map_err(|e| e.to_string())?);
    }
    print!("{report}");
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
