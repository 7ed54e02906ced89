//! Scaling with the system size: McLachlan–Perlmutter particles for
//! `n = 5, 9, 17, 33, 65, 129` ([`scaling_systems`](super::scaling_systems)),
//! Gauss SPARK `s = 2` (and `s = 5` for the large-`D` end): time per step
//! with full Newton and with simplified Newton (one factorization per step),
//! the stepper's size and heap storage, and the arithmetic rate one step
//! reaches (operation count of the generated code plus the block LU of the
//! `D × D` Newton matrix, `D = s(n+1)+n`).
//!
//! The Newton matrix, its factors and the stage Jacobians live on the heap
//! (allocated once per stepper; the generated `stage_jacobians_into` writes
//! into them in place), so the stepper value is `O(s·D)` bytes and a step's
//! stack use is `O(D)`, not `O(n²)` or `O(D²)`. To show it, the whole
//! measurement runs on a thread with rayon's default 2 MiB stack
//! ([`WORKER_STACK`]), which the old stack-allocated matrices overflowed from
//! `D ≈ 250` on and the by-value stage Jacobians from `n ≈ 90`.

use super::sweep::unobserved;
use super::WorkPrecisionError;
use crate::report::clock::thread_cpu_seconds;
use crate::report::files::OutputDir;
use crate::report::format::duration;
use crate::report::plot::{Figure, Panel, Scale, Series};
use crate::systems::scaling::{
    McLachlanPerlmutter129, McLachlanPerlmutter17, McLachlanPerlmutter33, McLachlanPerlmutter5, McLachlanPerlmutter65,
    McLachlanPerlmutter9,
};
use spark_runtime::{
    Method, NewtonMode, NewtonOptions, NoObserver, NonholonomicSystem, Schedule, Stepper, Tableau, Vector,
};
use std::time::{Duration, Instant};

/// Stack size of the measuring thread: rayon's default worker stack.
pub const WORKER_STACK: usize = 2 << 20;

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
    /// Median CPU time of the measuring thread per step, full Newton, seconds.
    pub time_per_step: f64,
    /// Mean Newton iterations per step, full Newton.
    pub newton_iterations: f64,
    /// Median CPU time per step, simplified Newton (one factorization per step).
    pub time_per_step_simplified: f64,
    /// Mean Newton iterations per step, simplified Newton.
    pub newton_iterations_simplified: f64,
    /// Estimated floating-point operations per step, full Newton.
    pub flops_per_step: f64,
    /// `flops_per_step / time_per_step`, in GFLOP/s.
    pub gflops: f64,
}

/// Median thread-CPU time per step and mean iterations of `steps` steps.
fn timed<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    mode: NewtonMode,
    repeats: usize,
) -> Option<(f64, f64)>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let opts = NewtonOptions { mode, ..NewtonOptions::default() };
    let mut stepper =
        Stepper::<Sys, N, M, S, D>::new(Sys::default(), Tableau::new(Method::Gauss).ok()?).with_options(opts);
    let q0 = Vector::<N>::from_fn(|i, _| 0.5 + 0.3 * ((i + 1) as f64).sin());
    let v0 = Vector::<N>::zeros();
    let (h, steps) = (0.01, 200);
    let quiet = unobserved();
    let schedule = Schedule::Fixed { h, steps };
    // Timed without event location, like the peers: declared events are
    // for `spark section`.
    let traj = stepper
        .integrate_with_events(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents)
        .ok()?;
    let iterations = traj.report.newton_iterations_mean;
    let mut times = Vec::new();
    let start = Instant::now();
    while times.len() < repeats.max(1) || (start.elapsed() < Duration::from_millis(50) && times.len() < 200) {
        let c = thread_cpu_seconds();
        stepper
            .integrate_with_events(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents)
            .ok()?;
        times.push((thread_cpu_seconds() - c) / steps as f64);
    }
    times.sort_by(f64::total_cmp);
    Some((times[times.len() / 2], iterations))
}

fn row<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(repeats: usize) -> Option<ScalingRow>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let (time_per_step, iterations) = timed::<Sys, N, M, S, D>(NewtonMode::Full, repeats)?;
    let (time_simplified, iterations_simplified) = timed::<Sys, N, M, S, D>(NewtonMode::Simplified, repeats)?;
    let ops = Sys::OPERATIONS.stage_jacobians;
    let d = D as f64;
    // Per Newton iteration: S+1 fused Jacobian evaluations, assembling the
    // matrix (~D² writes counted as flops of the chain rule), LU 2/3·D³
    // (counted dense although the block elimination skips the v₁ columns
    // of the stage rows), solve 2·D².
    let flops_per_step = iterations * ((S + 1) as f64 * ops as f64 + 2.0 / 3.0 * d * d * d + 3.0 * d * d);
    let f = std::mem::size_of::<f64>();
    let jacobian_bytes = std::mem::size_of::<spark_runtime::StageJacobians<N, M>>();
    Some(ScalingRow {
        n: N,
        stages: S,
        newton_dimension: D,
        stepper_bytes: std::mem::size_of::<Stepper<Sys, N, M, S, D>>(),
        heap_bytes: 2 * D * D * f + D * std::mem::size_of::<usize>() + (S + 2) * jacobian_bytes + S * N * M * f,
        jacobian_operations: ops,
        time_per_step,
        newton_iterations: iterations,
        time_per_step_simplified: time_simplified,
        newton_iterations_simplified: iterations_simplified,
        flops_per_step,
        gflops: flops_per_step / time_per_step / 1e9,
    })
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

/// The scaling table as Markdown.
pub fn scaling_markdown(rows: &[ScalingRow]) -> String {
    let mut s = String::from(
        "| n | s | D | stepper value | heap (once) | ops stage_jacobians | time/step full Newton | its | time/step simplified Newton | its | est. flop/step (full) | GFLOP/s |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {:.1} KiB | {:.1} KiB | {} | {} | {:.2} | {} | {:.2} | {:.3e} | {:.2} |\n",
            r.n,
            r.stages,
            r.newton_dimension,
            r.stepper_bytes as f64 / 1024.0,
            r.heap_bytes as f64 / 1024.0,
            r.jacobian_operations,
            duration(r.time_per_step),
            r.newton_iterations,
            duration(r.time_per_step_simplified),
            r.newton_iterations_simplified,
            r.flops_per_step,
            r.gflops
        ));
    }
    s
}

/// Time per step and stepper size against `n` (log–log), staged in `out` as
/// `scaling.png` and `scaling.svg`.
pub fn write_scaling_figure(
    rows: &[super::scaling::ScalingRow],
    out: &mut OutputDir,
) -> Result<(), WorkPrecisionError> {
    let panel = |title: &str, y_label: &str, f: &dyn Fn(&super::scaling::ScalingRow) -> f64| Panel {
        title: title.into(),
        x_label: "n (coordinates)".into(),
        y_label: y_label.into(),
        x_scale: Scale::Log,
        y_scale: Scale::Log,
        series: [2, 5]
            .iter()
            .map(|&st| {
                let pts = rows.iter().filter(|r| r.stages == st).map(|r| (r.n as f64, f(r))).collect();
                Series::new(format!("Gauss s={st}"), pts)
            })
            .collect(),
    };
    let fig = Figure {
        title: "McLachlan–Perlmutter particles: cost against size".into(),
        panels: vec![
            panel("time per step (full Newton)", "seconds", &|r| r.time_per_step),
            panel("time per step (simplified Newton)", "seconds", &|r| r.time_per_step_simplified),
            panel("stepper value + heap", "bytes", &|r| (r.stepper_bytes + r.heap_bytes) as f64),
            panel("arithmetic rate", "GFLOP/s (estimated)", &|r| r.gflops),
        ],
        columns: 2,
        panel_size: (520, 420),
    };
    out.render(&fig, "scaling")?;
    Ok(())
}
