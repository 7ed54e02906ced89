//! The near-singular case: two nearly parallel constraint rows.

use super::integration_error_kind;
use crate::experiments::stress::{run_fixed, CaseReport, Scale, StressError};
use crate::report::format::sci;
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::systems::stress::{near_parallel_exact, NearParallel};
use spark_runtime::{IntegrationError, Method, NonholonomicSystem, StepError, Stepper, Tableau, Vector};

/// 2-norm condition number of `[[∇²_vv L, Kᵀ],[K, 0]]` at `(t, q, v)` (from
/// the singular values; infinite when the smallest is zero).
pub fn saddle_condition<Sys, const N: usize, const M: usize>(sys: &Sys, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let w = sys.mass_matrix(t, q, v);
    let k = sys.constraint_v(t, q, v);
    let a = nalgebra::DMatrix::<f64>::from_fn(N + M, N + M, |i, j| match (i < N, j < N) {
        (true, true) => w[(i, j)],
        (true, false) => k[(j - N, i)],
        (false, true) => k[(i - N, j)],
        (false, false) => 0.0,
    });
    let sv = a.singular_values();
    let (max, min) = sv.iter().fold((0.0f64, f64::INFINITY), |(a, b), &s| (a.max(s), b.min(s)));
    if min > 0.0 {
        max / min
    } else {
        f64::INFINITY
    }
}

/// Condition numbers above this are reported as a warning.
pub const CONDITION_WARNING: f64 = 1e10;

/// Two nearly parallel constraint rows (`ε → 0`), Gauss s = 2.
pub fn near_singular(_scale: Scale) -> Result<CaseReport, StressError> {
    let epss = [1.0, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-14, 0.0];
    let (h, t_end): (f64, f64) = (0.05, 10.0);
    let mut c = CaseReport::new(
        "near_singular",
        "Near-singular constraints: two nearly parallel rows",
        format!(
            "Nonholonomic particle with k = (v₃ − q₂v₁, v₃ − q₂v₁ + ε v₂), ε = {epss:?}; q0 = (1, 0.5, 0), \
             v0 = (0.3, 0, 0.15); Gauss s = 2, h = {h}, t ∈ [0, {t_end}]. The motion is known exactly for ε ≠ 0 \
             (q₂ stays 0.5); the multiplier of the second row grows like 1/ε. The condition number of \
             [[∇²_vv L, Kᵀ],[K, 0]] (2-norm, from its singular values) is estimated at the start of each run \
             and reported as a warning above {CONDITION_WARNING:e}."
        ),
    );
    let q0 = Vector::<3>::new(1.0, 0.5, 0.0);
    let v0 = Vector::<3>::new(0.3, 0.0, 0.15);
    let n = (t_end / h).round() as usize;
    let (mut cond_pts, mut err_pts) = (Vec::new(), Vec::new());
    let mut conds = Vec::new();
    let mut zero_outcome = String::new();
    let mut zero_typed = false;
    for &eps in &epss {
        let sys = NearParallel { eps };
        let cond = saddle_condition(&sys, 0.0, &q0, &v0);
        conds.push(cond);
        if cond > CONDITION_WARNING {
            c.warnings.push(format!(
                "ε = {eps:e}: [[∇²_vv L, Kᵀ],[K, 0]] nearly singular, condition ≈ {} (multipliers and the Newton \
                 matrix lose about log10(cond) digits)",
                sci(cond)
            ));
        }
        if eps > 0.0 {
            cond_pts.push((eps, cond.min(1e300)));
        }
        let mut st = <Stepper![NearParallel, 2]>::new(sys, Tableau::new(Method::Gauss)?);
        let desc = match run_fixed(&mut st, &q0, &v0, h, n, 1, 0) {
            Ok(d) => {
                c.absorb(&d);
                let t = *d.t.last().unwrap_or(&0.0);
                let (qe, ve) = near_parallel_exact([1.0, 0.5, 0.0], [0.3, 0.0, 0.15], t);
                let q = d.q.last().cloned().unwrap_or_default();
                let v = d.v.last().cloned().unwrap_or_default();
                let err = (0..3).map(|i| (q[i] - qe[i]).abs().max((v[i] - ve[i]).abs())).fold(0.0, f64::max);
                if eps > 0.0 {
                    err_pts.push((eps, err.max(1e-17)));
                } else {
                    zero_outcome = format!("ε = 0 completed (error {}), no singularity detected", sci(err));
                }
                format!(
                    "cond {}; completes: error vs exact {}, max |k| {}, max |E−E0| {}, mean Newton {:.2}",
                    sci(cond),
                    sci(err),
                    sci(d.max_residual),
                    sci(d.max_energy_error),
                    d.report.newton_iterations_mean
                )
            }
            Err(e) => {
                c.errors.push(format!("ε = {eps:e}: {e}"));
                if eps == 0.0 {
                    zero_typed = matches!(
                        e,
                        IntegrationError::Step {
                            source: StepError::SingularMatrix { .. } | StepError::DependentConstraints { .. },
                            ..
                        } | IntegrationError::Initial(
                            StepError::SingularMatrix { .. } | StepError::SingularInitialState { .. }
                        )
                    );
                    zero_outcome = format!("ε = 0: {} ({e})", integration_error_kind(&e));
                }
                format!("cond {}; fails: {}", sci(cond), integration_error_kind(&e))
            }
        };
        c.metric(format!("ε = {eps:e}"), desc);
    }
    // Condition ~ ε⁻² when the rows are close: check the ratio over two decades of ε.
    let ratio = conds[3] / conds[2];
    c.check(
        "condition number detected and growing like ε⁻² (cond(1e-6)/cond(1e-4) within 10^(4±0.5))",
        (ratio.log10() - 4.0).abs() <= 0.5,
        format!("cond(1e-4) = {}, cond(1e-6) = {}, ratio {}", sci(conds[2]), sci(conds[3]), sci(ratio)),
    );
    c.check("ill-conditioning reported as a warning", !c.warnings.is_empty(), format!("{} warnings", c.warnings.len()));
    c.check(
        "ε = 0 (parallel rows) is a typed SingularMatrix, SingularInitialState or DependentConstraints error",
        zero_typed,
        zero_outcome,
    );
    c.energy = "see per-ε max |E−E0|".into();
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![
            Panel {
                title: "condition of [[W, Kᵀ],[K, 0]]".into(),
                x_label: "ε".into(),
                y_label: "cond₂".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new("cond", cond_pts)],
            },
            Panel {
                title: "error at t = 10 against the exact solution".into(),
                x_label: "ε".into(),
                y_label: "max-norm error".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new("Gauss s=2, h=0.05", err_pts)],
            },
        ],
        columns: 2,
        panel_size: (600, 420),
    });
    Ok(c)
}
