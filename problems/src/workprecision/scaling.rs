//! Scaling with the system size: McLachlan–Perlmutter particles for
//! `n = 5, 9, 17, 33, 65` ([`scaling_systems`](super::scaling_systems)),
//! Gauss SPARK `s = 2`: time per step, the stepper's size on the stack, and
//! the arithmetic rate one step reaches (operation count of the generated
//! code plus the dense LU of the `D × D` Newton matrix, `D = s(n+1)+n`).
//!
//! Every value of the stepper lives on the stack (nalgebra fixed-size
//! types); the Newton matrix and its LU factors alone take `2·8·D²` bytes.
//! The measurement runs on a thread with a 256 MiB stack so that the largest
//! sizes do not overflow; see `docs/performance/README.md` for where that
//! stops paying.

use super::scaling_systems::{
    McLachlanPerlmutter17, McLachlanPerlmutter33, McLachlanPerlmutter5, McLachlanPerlmutter65, McLachlanPerlmutter9,
};
use spark_runtime::{Method, NoObserver, NonholonomicSystem, Observe, RunOptions, Schedule, Stepper, Tableau, Vector};
use std::time::{Duration, Instant};

/// One row of the scaling table.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScalingRow {
    /// Coordinates `n`.
    pub n: usize,
    /// Newton dimension `D = s(n+m)+n`.
    pub newton_dimension: usize,
    /// `size_of` the stepper value, bytes.
    pub stepper_bytes: usize,
    /// Operations of the generated `stage_jacobians`.
    pub jacobian_operations: usize,
    /// Median CPU time of the measuring thread per step, seconds.
    pub time_per_step: f64,
    /// Mean Newton iterations per step.
    pub newton_iterations: f64,
    /// Estimated floating-point operations per step.
    pub flops_per_step: f64,
    /// `flops_per_step / time_per_step`, in GFLOP/s.
    pub gflops: f64,
}

const S: usize = 2;

fn row<Sys, const N: usize, const M: usize, const D: usize>(repeats: usize) -> Option<ScalingRow>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(Sys::default(), Tableau::new(Method::Gauss).ok()?);
    let q0 = Vector::<N>::from_fn(|i, _| 0.5 + 0.3 * ((i + 1) as f64).sin());
    let v0 = Vector::<N>::zeros();
    let (h, steps) = (0.01, 200);
    let quiet = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let schedule = Schedule::Fixed { h, steps };
    let traj = stepper.integrate(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver).ok()?;
    let iterations = traj.report.newton_iterations_mean;
    let mut times = Vec::new();
    let start = Instant::now();
    while times.len() < repeats.max(1) || (start.elapsed() < Duration::from_millis(50) && times.len() < 200) {
        let c = super::thread_cpu_time();
        stepper.integrate(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver).ok()?;
        times.push((super::thread_cpu_time() - c) / steps as f64);
    }
    times.sort_by(f64::total_cmp);
    let time_per_step = times[times.len() / 2];
    let ops = Sys::OPERATIONS.stage_jacobians;
    let d = D as f64;
    // Per Newton iteration: S+1 fused Jacobian evaluations, assembling the
    // matrix (~D² writes counted as flops of the chain rule), LU 2/3·D³, solve 2·D².
    let flops_per_step = iterations * ((S + 1) as f64 * ops as f64 + 2.0 / 3.0 * d * d * d + 3.0 * d * d);
    Some(ScalingRow {
        n: N,
        newton_dimension: D,
        stepper_bytes: std::mem::size_of::<Stepper<Sys, N, M, S, D>>(),
        jacobian_operations: ops,
        time_per_step,
        newton_iterations: iterations,
        flops_per_step,
        gflops: flops_per_step / time_per_step / 1e9,
    })
}

/// Measures every size on a thread with a 256 MiB stack; `Err` if the thread
/// could not be started or a run failed.
pub fn measure_scaling(repeats: usize) -> Result<Vec<ScalingRow>, String> {
    let handle = std::thread::Builder::new()
        .name("scaling".into())
        .stack_size(256 << 20)
        .spawn(move || -> Option<Vec<ScalingRow>> {
            Some(vec![
                row::<McLachlanPerlmutter5, 5, 1, { S * 6 + 5 }>(repeats)?,
                row::<McLachlanPerlmutter9, 9, 1, { S * 10 + 9 }>(repeats)?,
                row::<McLachlanPerlmutter17, 17, 1, { S * 18 + 17 }>(repeats)?,
                row::<McLachlanPerlmutter33, 33, 1, { S * 34 + 33 }>(repeats)?,
                row::<McLachlanPerlmutter65, 65, 1, { S * 66 + 65 }>(repeats)?,
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
        "| n | D | stepper on the stack | ops stage_jacobians | time per step | Newton its | est. flop/step | GFLOP/s |\n|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.1} KiB | {} | {} | {:.2} | {:.3e} | {:.2} |\n",
            r.n,
            r.newton_dimension,
            r.stepper_bytes as f64 / 1024.0,
            r.jacobian_operations,
            super::report::duration(r.time_per_step),
            r.newton_iterations,
            r.flops_per_step,
            r.gflops
        ));
    }
    s
}
