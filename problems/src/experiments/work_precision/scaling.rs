//! Scaling with the system size: McLachlan–Perlmutter particles for
//! `n = 5, 9, 17, 33, 65, 129` (`scaling_systems`),
//! Gauss SPARK `s = 2` (and `s = 5` for the large-`D` end): time per step on
//! the dense paths (full and simplified Newton on the exact `D × D`
//! Jacobian, `D = s(n+1)+n`) and on the structured one (the stage-decoupled
//! matrix: reciprocal mass diagonal and an `s × s` Schur complement), the
//! Newton work each counted step by step, the flops that work implies and
//! the rate reached, the fitted exponent of time against `n`, and the
//! stepper's size and heap storage.
//!
//! The Newton matrix, its factors and the stage Jacobians live on the heap
//! (allocated once per stepper; the generated `stage_jacobians_into` writes
//! into them in place), so the stepper value is `O(s·D)` bytes and a step's
//! stack use is `O(D)`, not `O(n²)` or `O(D²)`. To show it, the whole
//! measurement runs on a thread with rayon's default 2 MiB stack
//! ([`WORKER_STACK`]), which stack-allocated matrices would overflow from
//! `D ≈ 250` on and by-value stage Jacobians from `n ≈ 90`.

use super::flops::{flops_per_step, newton_work, NewtonPath};
use super::sweep::unobserved;
use super::WorkPrecisionError;
use crate::report::clock::thread_cpu_seconds;
use crate::report::files::OutputDir;
use crate::report::format::duration;
use crate::report::plot::{Figure, Panel, Scale, Series};
use crate::report::stats::{fit_line, LineFit};
use crate::systems::scaling::{
    McLachlanPerlmutter129, McLachlanPerlmutter17, McLachlanPerlmutter33, McLachlanPerlmutter5, McLachlanPerlmutter65,
    McLachlanPerlmutter9,
};
use spark_runtime::{Method, NoObserver, NonholonomicSystem, Schedule, State, Stepper, Tableau, Vector};
use std::time::{Duration, Instant};

/// Stack size of the measuring thread: rayon's default worker stack.
pub const WORKER_STACK: usize = 2 << 20;

/// One path of one row: its time, its counted Newton work and the flops
/// that work implies.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PathRun {
    /// Which solve.
    pub path: NewtonPath,
    /// Median CPU time of the measuring thread per step, seconds.
    pub time_per_step: f64,
    /// Mean Newton updates per step.
    pub iterations: f64,
    /// Mean factorizations per step.
    pub factorizations: f64,
    /// Floating-point operations per step by the count of [`flops_per_step`].
    pub flops_per_step: f64,
    /// `flops_per_step / time_per_step`, in GFLOP/s.
    pub gflops: f64,
}

/// One row of the scaling table.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScalingRow {
    /// Coordinates `n`.
    pub n: usize,
    /// Stages `s` (Gauss).
    pub stages: usize,
    /// Newton dimension `D = s(n+m)+n`.
    pub newton_dimension: usize,
    /// `size_of` the stepper value, bytes.
    pub stepper_bytes: usize,
    /// Heap bytes the stepper allocated once (Newton matrix, factors, stage Jacobians).
    pub heap_bytes: usize,
    /// Operations of the generated `stage_jacobians`.
    pub jacobian_operations: usize,
    /// Operations of the generated `stage_values`.
    pub value_operations: usize,
    /// The paths, in [`NewtonPath::ALL`] order.
    pub paths: Vec<PathRun>,
}

/// The run every path starts from: `q₀` spread over the coordinates, at rest.
fn start<const N: usize>() -> (Vector<N>, Vector<N>) {
    (Vector::<N>::from_fn(|i, _| 0.5 + 0.3 * ((i + 1) as f64).sin()), Vector::<N>::zeros())
}

/// Step size and steps of every run.
const STEP: (f64, usize) = (0.01, 200);

/// A Gauss stepper of `Sys` on `path`.
fn stepper<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    path: NewtonPath,
) -> Option<Stepper<Sys, N, M, S, D>>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    Some(Stepper::new(Sys::default(), Tableau::new(Method::Gauss).ok()?).with_options(path.options()))
}

/// Median thread-CPU time per step of the run on `path` through the driver.
fn timed<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    path: NewtonPath,
    repeats: usize,
) -> Option<f64>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let mut stepper = stepper::<Sys, N, M, S, D>(path)?;
    let (q0, v0) = start::<N>();
    let (h, steps) = STEP;
    let quiet = unobserved();
    let schedule = Schedule::Fixed { h, steps };
    // Timed without event location, like the peers: declared events are
    // for `spark section`.
    let mut run = || {
        stepper.integrate_with_events(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents).ok()
    };
    run()?;
    let mut times = Vec::new();
    let begin = Instant::now();
    while times.len() < repeats.max(1) || (begin.elapsed() < Duration::from_millis(50) && times.len() < 200) {
        let c = thread_cpu_seconds();
        run()?;
        times.push((thread_cpu_seconds() - c) / steps as f64);
    }
    times.sort_by(f64::total_cmp);
    Some(times[times.len() / 2])
}

fn row<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(repeats: usize) -> Option<ScalingRow>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let ops = Sys::OPERATIONS;
    let mut paths = Vec::with_capacity(NewtonPath::ALL.len());
    for path in NewtonPath::ALL {
        let (q0, v0) = start::<N>();
        let (h, steps) = STEP;
        let (iterations, factorizations) =
            newton_work(&mut stepper::<Sys, N, M, S, D>(path)?, State::new(0.0, q0, v0), h, steps).ok()?;
        let time_per_step = timed::<Sys, N, M, S, D>(path, repeats)?;
        let flops = flops_per_step::<Sys, N, M, S>(path, iterations, factorizations);
        paths.push(PathRun {
            path,
            time_per_step,
            iterations,
            factorizations,
            flops_per_step: flops,
            gflops: flops / time_per_step / 1e9,
        });
    }
    let f = std::mem::size_of::<f64>();
    let jacobian_bytes = std::mem::size_of::<spark_runtime::StageJacobians<N, M>>();
    Some(ScalingRow {
        n: N,
        stages: S,
        newton_dimension: D,
        stepper_bytes: std::mem::size_of::<Stepper<Sys, N, M, S, D>>(),
        heap_bytes: 2 * D * D * f + D * std::mem::size_of::<usize>() + (S + 2) * jacobian_bytes + S * N * M * f,
        jacobian_operations: ops.stage_jacobians,
        value_operations: ops.stage_values,
        paths,
    })
}

/// The fitted exponent `p` of `time per step ∝ n^p` for one path and stage
/// count, over the rows with `n ≥ n_min` (least squares in log–log).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ScalingFit {
    /// Which solve.
    pub path: NewtonPath,
    /// Stages.
    pub stages: usize,
    /// Smallest `n` in the fit.
    pub n_min: usize,
    /// Largest `n` in the fit.
    pub n_max: usize,
    /// The fit of `ln(time per step)` against `ln n`.
    pub fit: LineFit,
}

/// Smallest `n` of the exponent fits: below it a step is dominated by
/// costs that do not grow with `n` (the loop's bookkeeping, the Schur
/// complement of one multiplier), so the fit would mix two regimes.
pub const FIT_N_MIN: usize = 17;

/// The exponent of every path for every stage count with at least three
/// rows from [`FIT_N_MIN`] on.
pub fn scaling_fits(rows: &[ScalingRow]) -> Vec<ScalingFit> {
    let mut stages: Vec<usize> = rows.iter().map(|r| r.stages).collect();
    stages.dedup();
    let mut fits = Vec::new();
    for s in stages {
        let sel: Vec<&ScalingRow> = rows.iter().filter(|r| r.stages == s && r.n >= FIT_N_MIN).collect();
        if sel.len() < 3 {
            continue;
        }
        for (k, path) in NewtonPath::ALL.into_iter().enumerate() {
            let x: Vec<f64> = sel.iter().map(|r| (r.n as f64).ln()).collect();
            let y: Vec<f64> = sel.iter().map(|r| r.paths[k].time_per_step.ln()).collect();
            if let Some(fit) = fit_line(&x, &y) {
                let n_min = sel.iter().map(|r| r.n).min().unwrap_or(0);
                let n_max = sel.iter().map(|r| r.n).max().unwrap_or(0);
                fits.push(ScalingFit { path, stages: s, n_min, n_max, fit });
            }
        }
    }
    fits
}

/// Measures every size on a thread with a [`WORKER_STACK`] stack; `Err` if
/// the thread could not be started or a run failed.
pub fn measure_scaling(repeats: usize) -> Result<Vec<ScalingRow>, String> {
    let handle = std::thread::Builder::new()
        .name("scaling".into())
        .stack_size(WORKER_STACK)
        .spawn(move || -> Option<Vec<ScalingRow>> {
            Some(vec![
                row::<McLachlanPerlmutter5, 5, 1, 2, { 2 * 6 + 5 }>(repeats)?,
                row::<McLachlanPerlmutter9, 9, 1, 2, { 2 * 10 + 9 }>(repeats)?,
                row::<McLachlanPerlmutter17, 17, 1, 2, { 2 * 18 + 17 }>(repeats)?,
                row::<McLachlanPerlmutter33, 33, 1, 2, { 2 * 34 + 33 }>(repeats)?,
                row::<McLachlanPerlmutter65, 65, 1, 2, { 2 * 66 + 65 }>(repeats)?,
                row::<McLachlanPerlmutter129, 129, 1, 2, { 2 * 130 + 129 }>(repeats)?,
                row::<McLachlanPerlmutter17, 17, 1, 5, { 5 * 18 + 17 }>(repeats)?,
                row::<McLachlanPerlmutter33, 33, 1, 5, { 5 * 34 + 33 }>(repeats)?,
                row::<McLachlanPerlmutter65, 65, 1, 5, { 5 * 66 + 65 }>(repeats)?,
            ])
        })
        .map_err(|e| format!("could not start the measuring thread: {e}"))?;
    handle
        .join()
        .map_err(|_| "the scaling thread panicked".to_string())?
        .ok_or_else(|| "a scaling run failed (Newton did not converge)".to_string())
}

/// The scaling tables as Markdown: sizes and storage, time and counted work
/// per path, and the fitted exponents.
pub fn scaling_markdown(rows: &[ScalingRow]) -> String {
    let mut s = String::from(
        "| n | s | D | stepper value | heap (once) | ops stage_values | ops stage_jacobians |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {:.1} KiB | {:.1} KiB | {} | {} |\n",
            r.n,
            r.stages,
            r.newton_dimension,
            r.stepper_bytes as f64 / 1024.0,
            r.heap_bytes as f64 / 1024.0,
            r.value_operations,
            r.jacobian_operations,
        ));
    }
    s.push_str(
        "\nTime per step, Newton updates / factorizations per step, flops per step (counted, see `flops_per_step`) and the rate they imply:\n\n| n | s | D | path | time/step | updates / factorizations | flop/step | GFLOP/s | dense full / this path |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let dense = r.paths[0].time_per_step;
        for p in &r.paths {
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {:.2} / {:.2} | {:.3e} | {:.2} | {:.2} |\n",
                r.n,
                r.stages,
                r.newton_dimension,
                p.path.label(),
                duration(p.time_per_step),
                p.iterations,
                p.factorizations,
                p.flops_per_step,
                p.gflops,
                dense / p.time_per_step,
            ));
        }
    }
    s.push_str(&format!(
        "\nFitted exponents `p` of time per step ∝ n^p (least squares in log–log over n ≥ {FIT_N_MIN}):\n\n| path | s | n | p | standard error |\n|---|---|---|---|---|\n"
    ));
    for f in scaling_fits(rows) {
        s.push_str(&format!(
            "| {} | {} | {} … {} | {:.2} | {:.2} |\n",
            f.path.label(),
            f.stages,
            f.n_min,
            f.n_max,
            f.fit.slope,
            f.fit.slope_std_error
        ));
    }
    s
}

/// Time per step of each path against `n` (log–log, one panel per stage
/// count), the stepper's size and the arithmetic rate, staged in `out` as
/// `scaling.png` and `scaling.svg`.
pub fn write_scaling_figure(rows: &[ScalingRow], out: &mut OutputDir) -> Result<(), WorkPrecisionError> {
    let series = |s: usize, f: &dyn Fn(&PathRun) -> f64| -> Vec<Series> {
        NewtonPath::ALL
            .iter()
            .enumerate()
            .map(|(k, path)| {
                let pts = rows.iter().filter(|r| r.stages == s).map(|r| (r.n as f64, f(&r.paths[k]))).collect();
                Series::new(format!("{} (s={s})", path.label()), pts)
            })
            .collect()
    };
    let panel = |title: String, y_label: &str, series: Vec<Series>| Panel {
        title,
        x_label: "n (coordinates)".into(),
        y_label: y_label.into(),
        x_scale: Scale::Log,
        y_scale: Scale::Log,
        series,
    };
    let sizes = [2, 5]
        .iter()
        .map(|&st| {
            let pts = rows
                .iter()
                .filter(|r| r.stages == st)
                .map(|r| (r.n as f64, (r.stepper_bytes + r.heap_bytes) as f64))
                .collect();
            Series::new(format!("Gauss s={st}"), pts)
        })
        .collect();
    let mut rate = series(2, &|p| p.gflops);
    rate.extend(series(5, &|p| p.gflops));
    let fig = Figure {
        title: "McLachlan–Perlmutter particles: cost against size, dense and structured Newton".into(),
        panels: vec![
            panel("time per step, Gauss s=2".into(), "seconds", series(2, &|p| p.time_per_step)),
            panel("time per step, Gauss s=5".into(), "seconds", series(5, &|p| p.time_per_step)),
            panel("stepper value + heap".into(), "bytes", sizes),
            panel("arithmetic rate (counted flops)".into(), "GFLOP/s", rate),
        ],
        columns: 2,
        panel_size: (560, 440),
    };
    out.render(&fig, "scaling")?;
    Ok(())
}
