//! The `spark work-precision` subcommand's arguments and driver (the binary
//! only forwards to [`run`] and prints what it returns).

use crate::catalog::SystemKind;
use crate::experiments::work_precision::{
    run_work_precision, WorkPrecisionConfig, MAX_FINAL_TIME, MAX_REPEATS, MIN_FINAL_TIME,
};
use std::path::PathBuf;
use std::time::Duration;

/// Work-precision diagrams: error vs wall time for every SPARK method, with
/// peers (num-dual, finite differences, ode_solvers DOP853, CasADi C
/// Newton-QR and Newton-LU, SciPy) measured in the same run.
#[derive(clap::Args, Debug, Clone)]
pub struct WorkPrecisionArgs {
    /// System by name (see `spark list`), repeatable or comma-separated;
    /// `all` measures every registered system. Default: the paper's four
    /// (particle, skate, robot, mp7). Peers that exist only for the paper's
    /// systems (num-dual, finite differences, CasADi C) are skipped for the
    /// others, and the report says so; DOP853 and SciPy's Radau run on every
    /// system without external or non-ideal forces.
    #[arg(long, short = 'y', value_delimiter = ',', conflicts_with_all = ["scaling", "adaptive_energy"])]
    pub system: Vec<String>,
    /// Output folder (CSV, Markdown, PNG and SVG figures).
    #[arg(long, short, default_value = "results/work-precision")]
    pub out: PathBuf,
    /// Final time T (default 10; 1 with --quick), from 1e-15 to 1e4.
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["scaling", "per_step", "adaptive_energy"])]
    pub t_end: Option<f64>,
    /// Timed repeats per point, the median is reported (default 5; 1 with
    /// --quick), from 1 to 1000.
    #[arg(long, conflicts_with = "adaptive_energy")]
    pub repeats: Option<usize>,
    /// Largest step count of a sweep (default 131072; 64 with --quick).
    #[arg(long, conflicts_with_all = ["scaling", "per_step", "adaptive_energy"])]
    pub max_steps: Option<usize>,
    /// Python interpreter with casadi and scipy for the CasADi C and SciPy
    /// peers (set up by `bash casadi/peers/setup.sh`).
    #[arg(long, default_value = "casadi/.venv/bin/python")]
    pub python: PathBuf,
    /// Skip the CasADi C and SciPy peers.
    #[arg(long)]
    pub no_python: bool,
    /// Newton mode of the SPARK stepper series (generated, num-dual, finite
    /// differences): `full` (fresh Jacobian every iteration) or `simplified`
    /// (one Jacobian and factorization per step, the `paper` default).
    #[arg(long, value_parser = ["full", "simplified"], default_value = "full")]
    pub newton: String,
    /// Measure the McLachlan–Perlmutter scaling study (n = 5 … 129) instead.
    #[arg(long)]
    pub scaling: bool,
    /// Measure time per step at the paper's step sizes instead: SPARK (full
    /// and simplified Newton) against the CasADi C Newton-LU and Newton-QR
    /// peers, Gauss s = 1..4 and Lobatto IIIA-B s = 2..4 (writes
    /// per-step.md, per-step.json).
    #[arg(long, conflicts_with = "scaling")]
    pub per_step: bool,
    /// With --per-step: measure the whole table this many times, SPARK and
    /// the peers in every round, and give each entry's minimum over the
    /// rounds (and each round's geometric means in the summary).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100), requires = "per_step")]
    pub rounds: u32,
    /// Measure the energy over a 10⁶-step run on the `orbit` system with
    /// fixed, error-controlled and reversible steps instead (writes
    /// adaptive-energy.md, .json and the figure).
    #[arg(long, conflicts_with_all = ["scaling", "per_step"])]
    pub adaptive_energy: bool,
    /// A seconds-long smoke run of every code path (short T, few steps).
    #[arg(long)]
    pub quick: bool,
}

/// The systems named on the command line, in the order given, without
/// repeats; `all` stands for every registered system.
pub fn select_systems(names: &[String]) -> Result<Vec<SystemKind>, String> {
    let mut out: Vec<SystemKind> = Vec::new();
    for name in names.iter().map(|n| n.trim()).filter(|n| !n.is_empty()) {
        let kinds = if name.eq_ignore_ascii_case("all") {
            SystemKind::ALL.to_vec()
        } else {
            vec![SystemKind::parse(name).map_err(|e| e.to_string())?]
        };
        for k in kinds {
            if !out.contains(&k) {
                out.push(k);
            }
        }
    }
    if out.is_empty() {
        return Err("--system needs a name (see `spark list`) or `all`".into());
    }
    Ok(out)
}

/// The `--t-end` of a sweep, or an error that says why it cannot be
/// measured over and which values can.
pub fn final_time(t_end: f64) -> Result<f64, String> {
    let range = format!("use {MIN_FINAL_TIME:e} ≤ --t-end ≤ {MAX_FINAL_TIME:e}");
    if !(t_end.is_finite() && t_end > 0.0) {
        return Err(format!("--t-end must be a positive number, got {t_end:.3e}; {range}"));
    }
    if t_end < MIN_FINAL_TIME {
        return Err(format!(
            "--t-end {t_end:.3e} is shorter than the smallest step the sweep's reference solution can take \
             (4ε ≈ 8.9e-16, the resolution of t near 0), so no error can be measured over it; {range}"
        ));
    }
    if t_end > MAX_FINAL_TIME {
        return Err(format!(
            "--t-end {t_end:.3e} is longer than a sweep can measure: the reference solution gives up after 10^6 \
             step attempts (the skate reaches t ≈ 2e4 with them, the sleigh t ≈ 3e3), each a few to hundreds \
             of microseconds, so a longer interval runs for minutes to hours and then fails; {range}"
        ));
    }
    Ok(t_end)
}

/// Runs the measurement and returns the text to print.
pub fn run(a: WorkPrecisionArgs, progress: &dyn Fn(&str)) -> Result<String, String> {
    let mut cfg = if a.quick { WorkPrecisionConfig::quick(&a.out) } else { WorkPrecisionConfig::full(&a.out) };
    if !a.system.is_empty() {
        cfg.systems = select_systems(&a.system)?;
    }
    // Flags given explicitly apply with and without --quick.
    if let Some(t_end) = a.t_end {
        cfg.final_time = final_time(t_end)?;
    }
    if let Some(repeats) = a.repeats {
        if !(1..=MAX_REPEATS).contains(&repeats) {
            return Err(format!(
                "--repeats {repeats}: give 1 ≤ --repeats ≤ {MAX_REPEATS} (each repeat is a whole timed run; short \
                 runs already repeat until 20 ms of timing)"
            ));
        }
        cfg.repeats = repeats;
    }
    if let Some(max_steps) = a.max_steps {
        if max_steps < cfg.min_steps {
            return Err(format!(
                "--max-steps must be at least the smallest step count of the sweep, {}; got {max_steps}",
                cfg.min_steps
            ));
        }
        cfg.max_steps = max_steps;
    }
    cfg.python = if a.no_python { None } else { Some(a.python.clone()) };
    cfg.newton =
        if a.newton == "simplified" { spark_runtime::NewtonMode::Simplified } else { spark_runtime::NewtonMode::Full };
    if a.quick {
        cfg.max_run_time = Duration::from_millis(50);
    }
    if a.scaling {
        let mut out = crate::report::files::OutputDir::open(&cfg.out).map_err(|e| e.to_string())?;
        let rows = crate::experiments::work_precision::scaling::measure_scaling(cfg.repeats)?;
        let md = crate::experiments::work_precision::scaling::scaling_markdown(&rows);
        crate::experiments::work_precision::scaling::write_scaling_figure(&rows, &mut out)
            .map_err(|e| e.to_string())?;
        out.write_bytes("scaling.md", md.as_bytes()).map_err(|e| e.to_string())?;
        out.write_json("scaling.json", &rows).map_err(|e| e.to_string())?;
        out.commit().map_err(|e| e.to_string())?;
        return Ok(md);
    }
    if a.adaptive_energy {
        let mut out = crate::report::files::OutputDir::open(&cfg.out).map_err(|e| e.to_string())?;
        let md = crate::experiments::work_precision::adaptive_energy::run(&mut out, progress)?;
        out.commit().map_err(|e| e.to_string())?;
        return Ok(md);
    }
    if a.per_step {
        let mut out = crate::report::files::OutputDir::open(&cfg.out).map_err(|e| e.to_string())?;
        use crate::experiments::work_precision::per_step;
        let (rows, rounds) = per_step::measure_rounds(&cfg, a.rounds as usize, progress)?;
        let mut md = per_step::per_step_markdown(&rows);
        if rounds.len() > 1 {
            md = format!(
                "Each entry is the minimum over {} rounds of the whole table.\n\n{md}{}",
                rounds.len(),
                per_step::per_round_markdown(&rounds)
            );
            out.write_json("per-step-rounds.json", &rounds).map_err(|e| e.to_string())?;
        }
        out.write_json("per-step.json", &rows).map_err(|e| e.to_string())?;
        out.write_bytes("per-step.md", md.as_bytes()).map_err(|e| e.to_string())?;
        out.commit().map_err(|e| e.to_string())?;
        return Ok(md);
    }
    let all = run_work_precision(&cfg, progress).map_err(|e| e.to_string())?;
    let mut s = crate::experiments::work_precision::report::overall_ratio_table(&all, &cfg);
    for m in &all {
        s.push_str(&format!("\n{}: cheapest method per target error\n", m.problem.system));
        s.push_str(&crate::experiments::work_precision::report::cheapest_table(m, &cfg.targets));
        for miss in &m.missing {
            s.push_str(&format!("not measured: {miss}\n"));
        }
    }
    s.push_str(&format!("\nwrote CSV, Markdown (summary.md) and figures into {}\n", cfg.out.display()));
    Ok(s)
}
