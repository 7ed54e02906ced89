//! The checks of a step that starts cold, at a state no earlier step of the
//! stepper ended at: the constraints hold there, their rows are
//! independent, and the mass matrix is regular.

use crate::error::StepError;
use crate::initial::singular_mass_detail;
use crate::linalg::{column_scales, factor_in_place, solve_in_place, Lu};
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::State;

/// Largest condition number `κ₁(K W⁻¹ Kᵀ)` a cold start accepts: the
/// reciprocal of the relative pivot size (`64 ε`) below which the LU
/// factorizations of this crate call a matrix singular. Beyond it the
/// multipliers have no correct digit and a step's constraint force is
/// round-off amplified.
pub(crate) const CONSTRAINT_CONDITION_LIMIT: f64 = 1.0 / (64.0 * f64::EPSILON);

/// The bound of the first constraint row whose residual `k` at velocities
/// `v` exceeds `tolerance · max(1, Σ_j |K_ij v_j| + |k_i − (Kv)_i|)`, `K`
/// the rows `∂k/∂v`: the residual measured against the size of the terms
/// it is computed from (for `k = K(q)v + b` the second sum is `|b|`), so
/// that a state of large velocities consistent to round-off passes and an
/// inconsistent one does not, in any units. `None` when every row is
/// within its bound. The cold start's check and the run's
/// ([`consistent_velocity`](crate::consistent_velocity)) both use it.
pub(crate) fn inconsistent_row<const N: usize, const M: usize>(
    k: &Vector<M>,
    rows: &Matrix<M, N>,
    v: &Vector<N>,
    tolerance: f64,
) -> Option<f64> {
    let kv = rows * v;
    (0..M).find_map(|i| {
        let terms: f64 = (0..N).map(|j| (rows[(i, j)] * v[j]).abs()).sum::<f64>() + (k[i] - kv[i]).abs();
        let allowed = tolerance * terms.max(1.0);
        // Written so that a NaN bound fails the test.
        let within = k[i].abs() <= allowed;
        (!within).then_some(allowed)
    })
}

/// The checks of a step that starts cold, at a state no earlier step of the
/// stepper ended at: `(t, q, v)` satisfies the constraints, their rows
/// are independent there, and the mass matrix is regular.
///
/// - `|k_i(t,q,v)| ≤ tolerance · max(1, Σ_j |K_ij v_j| + |k_i − (Kv)_i|)`:
///   the constraint residual measured against the size of the terms it is
///   computed from (for `k = K(q)v + b` the second sum is `|b|`), so that a
///   state of large velocities that an earlier run left consistent to round
///   off passes, and an inconsistent one does not. A step from an
///   inconsistent state is solved with the end constraint `k(t₁,q₁,v₁) = 0`
///   enforced at once, which removes the inconsistent part of the velocity
///   with an impulse in one step (measured: energy 1.0 → 0.498).
/// - `κ₁(K W⁻¹ Kᵀ) ≤` [`CONSTRAINT_CONDITION_LIMIT`], `W = ∇²_vv L`, the
///   Schur complement of the saddle matrix `[[W, Kᵀ],[K, 0]]` that determines
///   the accelerations and multipliers (index 2 requires it regular).
/// - `W` is regular. When it is singular, `W + γKᵀK`,
///   `γ = max|W_ij| / max|K_ij|²`, tells the two cases apart: it is regular
///   exactly when the saddle is (for positive semi-definite `W`). A regular
///   saddle with a singular `W` (a velocity without inertia that a
///   constraint fixes, a zero mass the constraints make up for) determines
///   the motion but not a step: the momentum rows of the step along `W`'s
///   null space are dependent (for Gauss exactly when the momentum there is
///   constant or linear in `q`), so Newton fails or returns a wrong step as
///   solved (a Gauss s = 2 step of `L = ((ȧ + ḃ)² + ẏ²)/2 + (a + b)(ȧ − ḃ) − …`
///   ended 7e-4 off). That is [`StepError::SingularInitialState`]. When both
///   are singular the mass matrix is, and the Newton matrix reports it with
///   its column.
///
/// Costs one stage-Jacobian evaluation and `O(N³ + N²M + M³)` operations,
/// paid only by cold starts; `jac` and `vals` are scratch (heap, so no
/// `N × N` matrix goes on the stack) and are left overwritten.
pub(crate) fn check_cold_start<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    state: &State<N>,
    h: f64,
    tolerance: f64,
    vals: &mut StageValues<N, M>,
    jac: &mut StageJacobians<N, M>,
) -> Result<(), StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    if M == 0 {
        return Ok(());
    }
    let (t, q, v) = (state.t, &state.q, &state.v);
    let zero = Vector::<M>::zeros();
    sys.stage_jacobians_into(t, q, v, &zero, vals, jac);
    let k = vals.constraint;
    if !k.iter().all(|x| x.is_finite()) {
        return Err(StepError::NonFinite {
            t,
            h,
            stage: "constraints at the start of the step (check the parameters)",
            history: Box::default(),
        });
    }
    if let Some(allowed) = inconsistent_row(&k, &jac.constraint_v, v, tolerance) {
        return Err(StepError::InconsistentStart { t, residual: k.amax(), tolerance: allowed });
    }
    let kmax = jac.constraint_v.amax();
    let mut perm = [0usize; N];
    let scale = column_scales::<N>(jac.mass.as_slice());
    if let Err(singular) = factor_in_place::<N>(jac.mass.as_mut_slice(), &mut perm, &scale, &[N]) {
        // W is singular: the augmented W + γKᵀK (the evaluation is repeated,
        // the failed factorization overwrote W).
        let w_scale = scale[singular.column];
        sys.stage_jacobians_into(t, q, v, &zero, vals, jac);
        let w_finite = jac.mass.iter().all(|x| x.is_finite());
        let gamma = jac.mass.amax() / (kmax * kmax);
        if !gamma.is_finite() {
            return Ok(());
        }
        let kk = &jac.constraint_v;
        for b in 0..N {
            for a in 0..N {
                let mut s = 0.0;
                for i in 0..M {
                    s += kk[(i, a)] * kk[(i, b)];
                }
                jac.mass[(a, b)] += gamma * s;
            }
        }
        let scale = column_scales::<N>(jac.mass.as_slice());
        if factor_in_place::<N>(jac.mass.as_mut_slice(), &mut perm, &scale, &[N]).is_err() {
            return Ok(());
        }
        // The saddle matrix is regular and W is not: refused (see above). A
        // W that is not finite is left to Newton, which reports it as such.
        if w_finite {
            let detail = singular_mass_detail(sys, singular.column, singular.pivot, w_scale);
            return Err(StepError::SingularInitialState { t, detail: detail.into() });
        }
    }
    // S = K W⁻¹ Kᵀ and κ₁(S) = ‖S‖₁ ‖S⁻¹‖₁, computed exactly (M is small).
    let mut winv_kt = jac.constraint_v.transpose();
    for mut col in winv_kt.column_iter_mut() {
        let mut c: Vector<N> = col.clone_owned();
        solve_in_place::<N>(jac.mass.as_slice(), &perm, c.as_mut_slice());
        col.copy_from(&c);
    }
    let schur: Matrix<M, M> = jac.constraint_v * winv_kt;
    let norm1 = |a: &Matrix<M, M>| a.column_iter().map(|c| c.iter().map(|x| x.abs()).sum::<f64>()).fold(0.0, f64::max);
    let mut lu = Lu::<M>::new();
    let condition = match lu.factor(&schur) {
        Err(_) => f64::INFINITY,
        Ok(()) => {
            let mut inverse = Matrix::<M, M>::identity();
            for mut col in inverse.column_iter_mut() {
                let mut c: Vector<M> = col.clone_owned();
                lu.solve_in_place(&mut c);
                col.copy_from(&c);
            }
            norm1(&schur) * norm1(&inverse)
        }
    };
    // Written so that a NaN condition fails the test.
    if condition <= CONSTRAINT_CONDITION_LIMIT {
        Ok(())
    } else {
        Err(StepError::DependentConstraints { t, condition, limit: CONSTRAINT_CONDITION_LIMIT })
    }
}
