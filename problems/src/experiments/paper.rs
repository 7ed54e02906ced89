//! The paper's numerical experiments (§8, Figs. 8.1–8.4): their definitions,
//! a parallel run of all of them, the figures (PNG + SVG), the numbers behind
//! each figure (CSV) and a summary table (Markdown and JSON).
//!
//! [`PaperConfig::full`] is the paper's setup; [`PaperConfig::shortened`]
//! runs the same code path on shorter intervals (for tests and quick looks).
//!
//! Files written into [`PaperConfig::out`]:
//!
//! | file | content |
//! |---|---|
//! | `fig8_1.{png,svg,csv}` | Gauss SPARK s = 1, 2, 3, particle: `E − E0` per step |
//! | `fig8_2.{png,svg,csv}` | Lobatto IIIA-B s = 2, 3, 4, skate: `E − E0` per step |
//! | `fig8_3.{png,svg,csv}` | Lobatto IIIA-B-D s = 2, 3, 4, robot, paper's `v0`; beside it `v0 = (1, 0, 0.5, 1)` for IIIA-B and IIIA-B-D |
//! | `fig8_4.{png,svg}` | McLachlan–Perlmutter particles: `(1/h⁴)·mean_j (E_jk − E_j0)²` every 100 steps, three methods, both readings of the constraint (see below) |
//! | `fig8_4.csv`, `fig8_4_energy_errors.csv` | the statistic and every member's `E_jk − E_j0`, nonholonomic reading |
//! | `fig8_4_printed.csv`, `fig8_4_printed_energy_errors.csv` | the same for the constraint as printed |
//! | `summary.md`, `summary.json` | per figure and method: max `|E − E0|`, max constraint residual, steps, time, drift or growth fit |
//!
//! The folder is locked for the whole run and the files appear together at
//! its end, summaries last ([`crate::report::files::OutputDir`]).
//!
//! Fig. 8.4 runs two systems. §8.4 prints the constraint as
//! `v1 + Σ_{i=m+2}^{n} q_i v_i = 0`, which is holonomic (it is
//! `d/dt[q1 + ½ Σ q_i²] = 0`); on it Lobatto IIIA-B SPARK is RATTLE, a
//! symplectic method, and the energy error stays bounded. The reading
//! `v1 + Σ_{i=m+2}^{n} q_{i−m} v_i = 0` is nonholonomic, fits the paper's
//! initial values and description, and reproduces the paper's random walk.
//! The top row of Fig. 8.4 is that reading over the paper's interval; the
//! bottom row is the printed constraint over a twentieth of it
//! ([`PaperConfig::fig84_printed_t_end`]). Evidence: `docs/stress/chaos.md`.
//!
//! Each (reading, method) of Fig. 8.4 is one ensemble
//! ([`run_ensemble_with`]): its members run in SIMD lane groups through the
//! lane stepper of [`spark_runtime::integrate_ensemble`], in parallel (rayon)
//! with each other and with the other figures' runs.

use crate::catalog::SystemKind;
use crate::report::files::OutputDir;
use crate::report::format::{sci_digits, short};
use crate::report::plot::{Figure, Panel, PlotError, Scale, Series};
use crate::report::progress::Progress;
use crate::report::stats::{energy_drift, ensemble_quantity, fit_power, log_bin_means, Drift, PowerFit};
use crate::run::{run, run_ensemble_with, EnsembleError, RunError, RunResult, RunSpec};
use crate::systems::mp7_initial_values;
use rayon::prelude::*;
use spark_runtime::{Method, NewtonMode, NewtonOptions};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Which experiments to run and where to write them.
#[derive(Clone, Debug, PartialEq)]
pub struct PaperConfig {
    /// Output folder (created if missing).
    pub out: PathBuf,
    /// Final time of Fig. 8.1 (paper: 250).
    pub fig81_t_end: f64,
    /// Final time of Fig. 8.2 (paper: 100).
    pub fig82_t_end: f64,
    /// Final time of Fig. 8.3 (paper: 150).
    pub fig83_t_end: f64,
    /// Final time of Fig. 8.4 (paper: 50 000).
    pub fig84_t_end: f64,
    /// Ensemble size `J + 1` of Fig. 8.4 (paper: 10).
    pub fig84_members: usize,
    /// Fig. 8.4 samples every this many steps (paper: 100).
    pub fig84_sample_every: usize,
    /// Fig. 8.4's growth exponent is fitted on `t ≥ fig84_fit_from`.
    pub fig84_fit_from: f64,
    /// Final time of Fig. 8.4's bottom row, the constraint as printed
    /// (bounded from `t ≈ 20` on, so a twentieth of the interval shows it).
    pub fig84_printed_t_end: f64,
    /// Newton settings of every run.
    pub newton: NewtonOptions,
}

impl PaperConfig {
    /// The paper's experiments exactly as in §8, written to `out`.
    ///
    /// Newton runs in simplified mode (one Jacobian per step): it converges to
    /// the same tolerance as full Newton and takes about half the time.
    pub fn full(out: impl Into<PathBuf>) -> Self {
        PaperConfig {
            out: out.into(),
            fig81_t_end: 250.0,
            fig82_t_end: 100.0,
            fig83_t_end: 150.0,
            fig84_t_end: 50_000.0,
            fig84_members: 10,
            fig84_sample_every: 100,
            fig84_fit_from: 50.0,
            fig84_printed_t_end: 2_500.0,
            newton: NewtonOptions { mode: NewtonMode::Simplified, ..NewtonOptions::default() },
        }
    }

    /// The same experiments with every interval multiplied by `fraction`
    /// (and Fig. 8.4's fit window scaled alike); same code path as
    /// [`PaperConfig::full`].
    pub fn shortened(out: impl Into<PathBuf>, fraction: f64) -> Self {
        let full = PaperConfig::full(out);
        PaperConfig {
            fig81_t_end: full.fig81_t_end * fraction,
            fig82_t_end: full.fig82_t_end * fraction,
            fig83_t_end: full.fig83_t_end * fraction,
            fig84_t_end: full.fig84_t_end * fraction,
            fig84_fit_from: full.fig84_fit_from * fraction,
            fig84_printed_t_end: full.fig84_printed_t_end * fraction,
            ..full
        }
    }
}

/// Errors of the paper run.
#[derive(Debug, thiserror::Error)]
pub enum PaperError {
    /// A configuration value is unusable.
    #[error("invalid paper configuration: {0}")]
    Config(String),
    /// An integration failed.
    #[error("{figure}: {source}")]
    Run {
        /// The figure.
        figure: &'static str,
        /// What failed.
        source: RunError,
    },
    /// An ensemble (Fig. 8.4) failed.
    #[error("{figure}: {source}")]
    Ensemble {
        /// The figure.
        figure: &'static str,
        /// What failed, with the member.
        source: Box<EnsembleError>,
    },
    /// Writing a table failed.
    #[error(transparent)]
    Output(#[from] crate::report::files::OutputError),
    /// Drawing a figure failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// One line of the summary table.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SummaryRow {
    /// `Fig. 8.x`.
    pub figure: &'static str,
    /// System key.
    pub system: &'static str,
    /// Method and stage count, e.g. `Gauss s=2`.
    pub method: String,
    /// Which initial values (`paper v0`, `v0 = (1, 0, 0.5, 1)`, `10 members`).
    pub initial_values: String,
    /// Step size.
    pub h: f64,
    /// Final time.
    pub t_end: f64,
    /// Runs aggregated in this row (ensemble members).
    pub runs: usize,
    /// Steps, summed over the runs.
    pub steps: usize,
    /// Largest `|E − E0|` over every step of every run.
    pub max_energy_error: f64,
    /// Largest constraint residual `max_i |k_i|` over every step of every run.
    pub max_constraint_residual: f64,
    /// Fitted linear drift of `E − E0` (single runs only).
    pub drift: Option<Drift>,
    /// Integration wall time summed over the runs, seconds (runs execute in
    /// parallel; inflated when other processes compete for the cores).
    pub run_seconds: f64,
    /// CPU time of the integrations summed over the runs, seconds (`None`
    /// where the platform does not report per-thread CPU time).
    pub cpu_seconds: Option<f64>,
    /// Mean Newton iterations per step.
    pub newton_iterations_mean: f64,
}

/// Fitted growth of Fig. 8.4's quantity for one method and one reading of
/// the constraint.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GrowthFit {
    /// Method name.
    pub method: String,
    /// Which constraint (see [`Fig84Constraint`]).
    pub constraint: Fig84Constraint,
    /// `(1/h⁴)·mean_j (E_jk − E_j0)² ≈ C t^p` on `t ≥ fig84_fit_from`.
    pub fit: Option<PowerFit>,
    /// The same fit on the last decade of the run (`t ≥ t_end/10`), where a
    /// random walk has outgrown the bounded `O(h²)` oscillation.
    pub late_fit: Option<PowerFit>,
}

/// The two readings of the §8.4 constraint that Fig. 8.4 compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Fig84Constraint {
    /// `v1 + Σ_{i=m+2}^{n} q_{i−m} v_i = 0` ([`crate::systems::McLachlanPerlmutter7Nonholonomic`]):
    /// nonholonomic; the paper's observation.
    Nonholonomic,
    /// `v1 + Σ_{i=m+2}^{n} q_i v_i = 0` as printed ([`crate::systems::McLachlanPerlmutter7`]):
    /// holonomic, bounded energy error.
    Printed,
}

impl Fig84Constraint {
    /// Both, in figure order (top row first).
    pub const ALL: [Fig84Constraint; 2] = [Fig84Constraint::Nonholonomic, Fig84Constraint::Printed];

    /// The system integrated.
    pub const fn system(self) -> SystemKind {
        match self {
            Fig84Constraint::Nonholonomic => SystemKind::McLachlanPerlmutter7Nonholonomic,
            Fig84Constraint::Printed => SystemKind::McLachlanPerlmutter7,
        }
    }

    /// The constraint written out.
    pub const fn formula(self) -> &'static str {
        match self {
            Fig84Constraint::Nonholonomic => "v1 + q2 v5 + q3 v6 + q4 v7 = 0 (nonholonomic reading)",
            Fig84Constraint::Printed => "v1 + q5 v5 + q6 v6 + q7 v7 = 0 (as printed; holonomic)",
        }
    }

    /// Stem of the CSV files (`fig8_4`, `fig8_4_printed`).
    const fn stem(self) -> &'static str {
        match self {
            Fig84Constraint::Nonholonomic => "fig8_4",
            Fig84Constraint::Printed => "fig8_4_printed",
        }
    }

    /// Which final time of `cfg` applies.
    fn t_end(self, cfg: &PaperConfig) -> f64 {
        match self {
            Fig84Constraint::Nonholonomic => cfg.fig84_t_end,
            Fig84Constraint::Printed => cfg.fig84_printed_t_end,
        }
    }
}

/// Everything one `paper` run produced.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PaperReport {
    /// The summary table.
    pub rows: Vec<SummaryRow>,
    /// Fig. 8.4's fitted exponents.
    pub growth: Vec<GrowthFit>,
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Wall-clock time of the whole run, seconds.
    pub wall_seconds: f64,
    /// Worker threads used.
    pub threads: usize,
}

/// The methods of Fig. 8.4, in plotting order.
pub const FIG84_METHODS: [Method; 3] = [Method::LobattoIIIAB, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda];

/// One integration of the experiment list (for Fig. 8.4 one member; the
/// members of one reading and method run together, see [`run_paper`]).
#[derive(Clone, Debug)]
struct Job {
    figure: usize,
    /// Index of the curve (or Fig. 8.4 method) within its figure.
    curve: usize,
    /// Ensemble member (Fig. 8.4) or 0.
    member: usize,
    /// Which constraint (Fig. 8.4 only).
    reading: Option<Fig84Constraint>,
    variant: &'static str,
    spec: RunSpec,
}

const FIGURES: [&str; 4] = ["Fig. 8.1", "Fig. 8.2", "Fig. 8.3", "Fig. 8.4"];
const PAPER_V0: &str = "paper v0";
const TURNING_V0: &str = "v0 = (1, 0, 0.5, 1)";

fn steps_for(t_end: f64, h: f64, what: &str) -> Result<usize, PaperError> {
    let n = t_end / h;
    if !(n.is_finite() && n >= 1.0) {
        return Err(PaperError::Config(format!(
            "{what}: final time {t_end:.3e} is shorter than one step of {h} (spark paper: raise --fraction)"
        )));
    }
    Ok(n.round() as usize)
}

/// The experiment list of §8 for `cfg`.
fn jobs(cfg: &PaperConfig) -> Result<Vec<Job>, PaperError> {
    let mut jobs = Vec::new();
    let with = |mut spec: RunSpec, every: usize| {
        spec.newton = cfg.newton;
        spec.record_every = every;
        spec
    };
    let n = steps_for(cfg.fig81_t_end, 0.2, "Fig. 8.1")?;
    for (curve, s) in [1, 2, 3].into_iter().enumerate() {
        let spec = with(RunSpec::paper(SystemKind::Particle, Method::Gauss, s, 0.2, n), 1);
        jobs.push(Job { figure: 0, curve, member: 0, reading: None, variant: PAPER_V0, spec });
    }
    let n = steps_for(cfg.fig82_t_end, 0.1, "Fig. 8.2")?;
    for (curve, s) in [2, 3, 4].into_iter().enumerate() {
        let spec = with(RunSpec::paper(SystemKind::Skate, Method::LobattoIIIAB, s, 0.1, n), 1);
        jobs.push(Job { figure: 1, curve, member: 0, reading: None, variant: PAPER_V0, spec });
    }
    let n = steps_for(cfg.fig83_t_end, 0.2, "Fig. 8.3")?;
    for (curve, s) in [2, 3, 4].into_iter().enumerate() {
        let spec = with(RunSpec::paper(SystemKind::Robot, Method::LobattoIIIABD, s, 0.2, n), 1);
        jobs.push(Job { figure: 2, curve, member: 0, reading: None, variant: PAPER_V0, spec });
    }
    for (k, (method, s)) in
        [Method::LobattoIIIAB, Method::LobattoIIIABD].into_iter().flat_map(|m| [2, 3, 4].map(|s| (m, s))).enumerate()
    {
        let mut spec = with(RunSpec::paper(SystemKind::Robot, method, s, 0.2, n), 1);
        spec.v0 = vec![1.0, 0.0, 0.5, 1.0];
        jobs.push(Job { figure: 2, curve: 3 + k, member: 0, reading: None, variant: TURNING_V0, spec });
    }
    if cfg.fig84_members == 0 || cfg.fig84_sample_every == 0 {
        return Err(PaperError::Config("Fig. 8.4 needs at least one member and a positive sampling interval".into()));
    }
    let big_j = cfg.fig84_members - 1;
    for reading in Fig84Constraint::ALL {
        let n = steps_for(reading.t_end(cfg), 0.05, "Fig. 8.4")?;
        for (curve, method) in FIG84_METHODS.into_iter().enumerate() {
            for j in 0..cfg.fig84_members {
                let mut spec = with(RunSpec::paper(reading.system(), method, 2, 0.05, n), cfg.fig84_sample_every);
                (spec.q0, spec.v0) = mp7_initial_values(j, big_j);
                jobs.push(Job { figure: 3, curve, member: j, reading: Some(reading), variant: "ensemble", spec });
            }
        }
    }
    Ok(jobs)
}

/// The runs of one unit of work of [`run_paper`] (its job indices first).
type UnitRuns<'a> = (&'a Vec<usize>, Result<Vec<RunResult>, PaperError>);

/// Runs all four experiments in parallel (rayon), writes every file and
/// returns the summary. `progress` draws one bar per figure. The output
/// folder is created and locked before the experiments start.
pub fn run_paper(cfg: &PaperConfig, progress: &Progress) -> Result<PaperReport, PaperError> {
    let start = Instant::now();
    let jobs = jobs(cfg)?;
    let mut out = OutputDir::open(&cfg.out)?;
    let bars: Vec<_> = (0..FIGURES.len())
        .map(|f| {
            let total: usize = jobs.iter().filter(|j| j.figure == f).map(|j| j.spec.steps).sum();
            progress.bar(FIGURES[f], total as u64)
        })
        .collect();
    // The units of work: one job each for Figs. 8.1–8.3; for Fig. 8.4 the
    // members of one (reading, method), in member order, as one ensemble.
    let mut units: Vec<Vec<usize>> = Vec::new();
    for (i, job) in jobs.iter().enumerate() {
        let same = |u: &&mut Vec<usize>| {
            let first = &jobs[u[0]];
            job.reading.is_some() && first.reading == job.reading && first.curve == job.curve
        };
        match units.iter_mut().find(same) {
            Some(u) => u.push(i),
            None => units.push(vec![i]),
        }
    }
    // Longest first (in member steps), so the short ones fill the gaps at
    // the end.
    units.sort_by_key(|u| std::cmp::Reverse(u.iter().map(|&i| jobs[i].spec.steps).sum::<usize>()));
    let mut results: Vec<UnitRuns<'_>> = units
        .par_iter()
        .map(|u| {
            let first = &jobs[u[0]];
            let (figure, bar) = (FIGURES[first.figure], &bars[first.figure]);
            let tick = |n| {
                bar.inc(n);
                true
            };
            let result = if first.reading.is_none() {
                run(&first.spec, &tick).map(|r| vec![r]).map_err(|source| PaperError::Run { figure, source })
            } else {
                // Fig. 8.4's members in SIMD lane groups (`run_ensemble_with`).
                let members: Vec<(Vec<f64>, Vec<f64>)> =
                    u.iter().map(|&i| (jobs[i].spec.q0.clone(), jobs[i].spec.v0.clone())).collect();
                run_ensemble_with(&first.spec, &members, None, &tick)
                    .map_err(|source| PaperError::Ensemble { figure, source: Box::new(source) })
            };
            (u, result)
        })
        .collect();
    for bar in &bars {
        bar.finish();
    }
    // The first failure in job order is reported.
    results.sort_by_key(|r| r.0[0]);
    let mut by_job: Vec<Option<RunResult>> = vec![None; jobs.len()];
    for (u, result) in results {
        for (&i, r) in u.iter().zip(result?) {
            by_job[i] = Some(r);
        }
    }
    let runs: Vec<RunResult> = by_job
        .into_iter()
        .collect::<Option<Vec<RunResult>>>()
        .ok_or_else(|| PaperError::Config("an ensemble returned fewer runs than it has members".into()))?;

    let mut files = Vec::new();
    let mut rows = Vec::new();
    for f in 0..3 {
        let sel: Vec<(&Job, &RunResult)> = jobs.iter().zip(&runs).filter(|(j, _)| j.figure == f).collect();
        let (figure, table) = energy_figure(f, &sel);
        let stem = format!("fig8_{}", f + 1);
        let cols: Vec<(&str, &[f64])> = table.iter().map(|(n, c)| (n.as_str(), c.as_slice())).collect();
        files.push(out.write_columns(&format!("{stem}.csv"), &cols)?);
        files.extend(out.render(&figure, &stem)?);
        for (job, r) in &sel {
            rows.push(single_row(job, r));
        }
    }
    let sel: Vec<(&Job, &RunResult)> = jobs.iter().zip(&runs).filter(|(j, _)| j.figure == 3).collect();
    let (growth, fig84_rows, fig84_files) = figure_84(cfg, &sel, &mut out)?;
    rows.extend(fig84_rows);
    files.extend(fig84_files);

    let threads = rayon::current_num_threads();
    let mut report = PaperReport { rows, growth, files, wall_seconds: 0.0, threads };
    report.files.push(out.join("summary.md"));
    report.files.push(out.join("summary.json"));
    report.wall_seconds = start.elapsed().as_secs_f64();
    out.write_bytes("summary.md", summary_markdown(&report, cfg).as_bytes())?;
    out.write_json("summary.json", &report)?;
    out.commit()?;
    Ok(report)
}

/// Column name for a run in the figure tables, e.g. `gauss_s2`.
fn column_key(r: &RunResult) -> String {
    format!("{}_s{}", r.method.key().replace('-', "_"), r.stages)
}

fn energy_error(r: &RunResult) -> Vec<f64> {
    r.energy.iter().map(|e| e - r.stats.e0).collect()
}

fn single_row(job: &Job, r: &RunResult) -> SummaryRow {
    SummaryRow {
        figure: FIGURES[job.figure],
        system: r.system,
        method: r.method.label(r.stages),
        initial_values: job.variant.to_string(),
        h: r.h,
        t_end: r.t.last().copied().unwrap_or(0.0),
        runs: 1,
        steps: r.stats.steps,
        max_energy_error: r.stats.max_energy_error,
        max_constraint_residual: r.stats.max_constraint_residual,
        drift: energy_drift(&r.t, &energy_error(r)),
        run_seconds: r.stats.wall_time.as_secs_f64(),
        cpu_seconds: r.stats.cpu_time.map(|d| d.as_secs_f64()),
        newton_iterations_mean: r.stats.newton_iterations_mean,
    }
}

fn energy_panel(title: String, series: Vec<Series>) -> Panel {
    Panel {
        title,
        x_label: "t".into(),
        y_label: "E − E0".into(),
        x_scale: Scale::Linear,
        y_scale: Scale::Linear,
        series,
    }
}

fn curve(r: &RunResult, label: String) -> Series {
    Series::new(label, r.t.iter().copied().zip(energy_error(r)).collect())
}

/// Figure and CSV table of Figs. 8.1–8.3.
fn energy_figure(f: usize, sel: &[(&Job, &RunResult)]) -> (Figure, Vec<(String, Vec<f64>)>) {
    let first = sel[0].1;
    let mut table = vec![("t".to_string(), first.t.clone())];
    for (job, r) in sel {
        let prefix = if job.variant == TURNING_V0 { "turning_" } else { "" };
        table.push((format!("{prefix}energy_error_{}", column_key(r)), energy_error(r)));
    }
    let h = first.h;
    let t_end = short(first.t.last().copied().unwrap_or(0.0));
    let (title, panels, columns) = match f {
        0 => (
            format!("Fig. 8.1  Energy error of Gauss SPARK, nonholonomic particle, h = {h}, t ∈ [0, {t_end}]"),
            sel.iter()
                .map(|(_, r)| {
                    energy_panel(format!("Gauss SPARK s = {}", r.stages), vec![curve(r, r.method.label(r.stages))])
                })
                .collect(),
            1,
        ),
        1 => (
            format!(
                "Fig. 8.2  Energy error of Lobatto IIIA-B SPARK, skate on an inclined plane, h = {h}, t ∈ [0, {t_end}]"
            ),
            sel.iter()
                .map(|(_, r)| {
                    energy_panel(
                        format!("Lobatto IIIA-B SPARK s = {}", r.stages),
                        vec![curve(r, r.method.label(r.stages))],
                    )
                })
                .collect(),
            1,
        ),
        _ => {
            // Rows s = 2, 3, 4; left: the paper's v0 (IIIA-B-D), right: the
            // turning v0 with IIIA-B and IIIA-B-D together.
            let mut panels = Vec::new();
            for s in [2, 3, 4] {
                let paper: Vec<Series> = sel
                    .iter()
                    .filter(|(j, r)| j.variant == PAPER_V0 && r.stages == s)
                    .map(|(_, r)| curve(r, r.method.label(r.stages)))
                    .collect();
                panels.push(energy_panel(format!("Lobatto IIIA-B-D SPARK s = {s}, v0 = (1, 0, 0, 1) (paper)"), paper));
                let turning: Vec<Series> = sel
                    .iter()
                    .filter(|(j, r)| j.variant == TURNING_V0 && r.stages == s)
                    .map(|(_, r)| curve(r, r.method.label(r.stages)))
                    .collect();
                panels.push(energy_panel(format!("s = {s}, v0 = (1, 0, 0.5, 1): IIIA-B vs IIIA-B-D"), turning));
            }
            (format!("Fig. 8.3  Energy error, mobile robot, h = {h}, t ∈ [0, {t_end}]"), panels, 2)
        }
    };
    let panel_size = if columns == 1 { (1100, 300) } else { (760, 300) };
    (Figure { title, panels, columns, panel_size }, table)
}

/// What Fig. 8.4 contributes to the report: fits, summary rows, files.
type Fig84 = (Vec<GrowthFit>, Vec<SummaryRow>, Vec<PathBuf>);

/// Fig. 8.4: for each reading of the constraint, the ensemble statistic, its
/// fits, tables and summary rows; one figure with a row per reading.
fn figure_84(cfg: &PaperConfig, sel: &[(&Job, &RunResult)], out: &mut OutputDir) -> Result<Fig84, PaperError> {
    let mut files = Vec::new();
    let mut growth = Vec::new();
    let mut rows = Vec::new();
    let mut panels = Vec::new();
    let mut h = 0.05;
    for reading in Fig84Constraint::ALL {
        let mine: Vec<(&Job, &RunResult)> = sel.iter().copied().filter(|(j, _)| j.reading == Some(reading)).collect();
        let Some(first) = mine.first() else { continue };
        let t = first.1.t.clone();
        h = first.1.h;
        let t_end = t.last().copied().unwrap_or(0.0);
        let mut table: Vec<(String, Vec<f64>)> = vec![("t".into(), t.clone())];
        let mut members: Vec<(String, Vec<f64>)> = vec![("t".into(), t.clone())];
        let mut series = Vec::new();
        let first_growth = growth.len();
        for (curve, method) in FIG84_METHODS.into_iter().enumerate() {
            let mut members_of: Vec<(usize, &RunResult)> =
                mine.iter().filter(|(j, _)| j.curve == curve).map(|(j, r)| (j.member, *r)).collect();
            members_of.sort_by_key(|m| m.0);
            let runs: Vec<&RunResult> = members_of.iter().map(|m| m.1).collect();
            debug_assert!(runs.iter().all(|r| r.method == method));
            let energies: Vec<(&[f64], f64)> = runs.iter().map(|r| (r.energy.as_slice(), r.stats.e0)).collect();
            let quantity = ensemble_quantity(&energies, h);
            for (j, r) in &members_of {
                members.push((format!("{}_member{j}", column_key(r)), energy_error(r)));
            }
            let key = column_key(runs[0]);
            growth.push(GrowthFit {
                method: runs[0].method.label(runs[0].stages),
                constraint: reading,
                fit: fit_power(&t, &quantity, cfg.fig84_fit_from, 200),
                late_fit: fit_power(&t, &quantity, t_end / 10.0, 200),
            });
            series.push(Series::new(
                runs[0].method.label(runs[0].stages),
                t.iter().copied().zip(quantity.iter().copied()).collect(),
            ));
            table.push((format!("scaled_mean_square_energy_error_{key}"), quantity));
            let wall: Duration = runs.iter().map(|r| r.stats.wall_time).sum();
            rows.push(SummaryRow {
                figure: FIGURES[3],
                system: runs[0].system,
                method: runs[0].method.label(runs[0].stages),
                initial_values: format!("{} members on E0 = 3.06", runs.len()),
                h,
                t_end,
                runs: runs.len(),
                steps: runs.iter().map(|r| r.stats.steps).sum(),
                max_energy_error: runs.iter().map(|r| r.stats.max_energy_error).fold(0.0, f64::max),
                max_constraint_residual: runs.iter().map(|r| r.stats.max_constraint_residual).fold(0.0, f64::max),
                drift: None,
                run_seconds: wall.as_secs_f64(),
                cpu_seconds: runs.iter().map(|r| r.stats.cpu_time.map(|d| d.as_secs_f64())).sum(),
                newton_iterations_mean: runs.iter().map(|r| r.stats.newton_iterations_mean).sum::<f64>()
                    / runs.len() as f64,
            });
        }
        let cols: Vec<(&str, &[f64])> = table.iter().map(|(n, c)| (n.as_str(), c.as_slice())).collect();
        files.push(out.write_columns(&format!("{}.csv", reading.stem()), &cols)?);
        let cols: Vec<(&str, &[f64])> = members.iter().map(|(n, c)| (n.as_str(), c.as_slice())).collect();
        files.push(out.write_columns(&format!("{}_energy_errors.csv", reading.stem()), &cols)?);

        // Log–log panel: means over log-spaced bins of t (the raw statistic
        // fluctuates by a factor of ~10 from sample to sample), with a dashed
        // reference line ∝ t through the first method's late fit at t_end.
        let mut log_series: Vec<Series> = series
            .iter()
            .map(|s| Series::new(format!("{} (bin means)", s.label), log_bin_means(&s.points, LOG_BINS)))
            .collect();
        if let Some(fit) = growth[first_growth].late_fit {
            let t0 = t_end / 1000.0;
            let y1 = fit.coefficient * t_end.powf(fit.exponent);
            log_series.push(Series {
                label: "∝ t (reference slope 1)".into(),
                points: vec![(t0, y1 * t0 / t_end), (t_end, y1)],
                dashed: true,
            });
        }
        let y_label = "(1/h⁴)·mean_j (E_jk − E0)²";
        panels.push(Panel {
            title: format!("{}, linear axes", reading.formula()),
            x_label: "t".into(),
            y_label: y_label.into(),
            x_scale: Scale::Linear,
            y_scale: Scale::Linear,
            series,
        });
        panels.push(Panel {
            title: format!("{}, log–log, bin means", reading.formula()),
            x_label: "t".into(),
            y_label: y_label.into(),
            x_scale: Scale::Log,
            y_scale: Scale::Log,
            series: log_series,
        });
    }
    let figure = Figure {
        title: format!(
            "Fig. 8.4  McLachlan–Perlmutter particles (n = 7), {} initial values, h = {h}, every {} steps",
            cfg.fig84_members, cfg.fig84_sample_every
        ),
        panels,
        columns: 2,
        panel_size: (760, 480),
    };
    files.extend(out.render(&figure, "fig8_4")?);
    Ok((growth, rows, files))
}

/// Bins of the log–log panel of Fig. 8.4.
const LOG_BINS: usize = 40;

/// The summary as Markdown: the table, Fig. 8.4's fits and the conventions.
pub fn summary_markdown(report: &PaperReport, cfg: &PaperConfig) -> String {
    let mut s = String::new();
    s.push_str("# Paper experiments (§8): summary\n\n");
    s.push_str(&format!(
        "Wall time of the whole run: {:.1} s on {} worker thread(s); CPU time of all integrations: {}. \
         Newton: {:?} mode, tolerance {:.1e}.\n\n",
        report.wall_seconds,
        report.threads,
        report.rows.iter().map(|r| r.cpu_seconds).sum::<Option<f64>>().map_or("n/a".into(), |c| format!("{c:.1} s")),
        cfg.newton.mode,
        cfg.newton.tolerance
    ));
    s.push_str(
        "| figure | system | method | initial values | h | t_end | steps | max \\|E−E0\\| | max \\|k\\| | drift slope (E per unit t) | drift/max | wall (s) | CPU (s) | Newton it./step |\n",
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in &report.rows {
        let (slope, frac) = match r.drift {
            Some(d) => (
                format!("{} ± {}", sci_digits(d.slope, 2), sci_digits(d.slope_std_error, 2)),
                format!("{:.3}", d.drift_fraction),
            ),
            None => ("—".into(), "—".into()),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {} | {:.2} |\n",
            r.figure,
            r.system,
            r.method,
            r.initial_values,
            r.h,
            short(r.t_end),
            r.steps,
            sci_digits(r.max_energy_error, 2),
            sci_digits(r.max_constraint_residual, 2),
            slope,
            frac,
            r.run_seconds,
            r.cpu_seconds.map_or("n/a".into(), |c| format!("{c:.2}")),
            r.newton_iterations_mean
        ));
    }
    s.push_str(&format!(
        "\n## Fig. 8.4: growth of (1/h⁴)·mean_j (E_jk − E0)² ≈ C·t^p (log-spaced samples; p on t ≥ {}, \
         late p on the last decade t ≥ t_end/10)\n\n",
        cfg.fig84_fit_from
    ));
    s.push_str("| constraint | method | exponent p | C | late exponent p | points |\n|---|---|---|---|---|---|\n");
    for g in &report.growth {
        let fmt = |f: Option<PowerFit>| match f {
            Some(f) => format!("{:.3} ± {:.3}", f.exponent, f.exponent_std_error),
            None => "—".into(),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            g.constraint.formula(),
            g.method,
            fmt(g.fit),
            g.fit.map_or("—".into(), |f| sci_digits(f.coefficient, 2)),
            fmt(g.late_fit),
            g.fit.map_or(0, |f| f.points)
        ));
    }
    s.push_str(
        "\nThe constraint as printed in §8.4 is holonomic (d/dt[q1 + ½(q5² + q6² + q7²)] = 0): on it Lobatto \
         IIIA-B SPARK is RATTLE (symplectic) and the energy error stays bounded. The nonholonomic reading \
         v1 + Σ q_(i−m) v_i = 0 gives the random walk the paper reports. See docs/stress/chaos.md.\n",
    );
    s.push_str(
        "\n## Conventions\n\n\
         - max |E−E0| and max |k| are taken over **every** step (k = constraint residual, max over components), \
         the figures and CSVs show every step (Figs. 8.1–8.3) or every 100th step (Fig. 8.4).\n\
         - *drift slope*: least-squares slope of E−E0 against t; *drift/max* = |slope|·(t_end−t_0)/max|E−E0|. \
         Values well below 1 mean the energy error is a bounded oscillation without linear drift.\n\
         - Fig. 8.3 (right column): with the paper's v0 = (1, 0, 0, 1) the heading q3 stays 0 and Lobatto IIIA-B \
         and IIIA-B-D coincide; v0 = (1, 0, 0.5, 1) turns the robot so the two methods differ.\n\
         - Fig. 8.4: the paper prints six velocity entries (0, β_j, 0, 0, 0, 0) for n = 7; we use \
         v0 = (0, β_j, 0, 0, 0, 0, 0), which satisfies both readings of the constraint \
         (v1 + q5 v5 + q6 v6 + q7 v7 = 0 and v1 + q2 v5 + q3 v6 + q4 v7 = 0) and gives \
         E = β_j²/2 + α_j²/2 + 2.56 = 3.06 for every j. E0 in the statistic is each member's own initial energy \
         (3.06 up to rounding). The McLachlan–Perlmutter method is the runtime's `LobattoIIIBALda` (eq. 7.3).\n\
         - *wall* and *CPU* are the integration times summed over the runs of a row; runs execute in parallel, \
         so the wall time of the whole command is smaller than the sum of the walls. CPU is the integrating \
         thread's time on a core; wall exceeds it when other processes compete for the cores.\n",
    );
    s
}
