//! Initial values: the consistency check of `(t₀, q₀, v₀)`, the projection of
//! `v₀` onto `{v : k(t₀,q₀,v) = 0}` in the kinetic-energy metric, and the
//! consistent acceleration and multiplier of the ψ-eliminated equations
//! (used for the stepper's cold-start guess and the multiplier observer).

use crate::error::{IterationRecord, NewtonHistory, StepError};
use crate::linalg::{column_scales, factor_in_place, solve_in_place, Lu};
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};

/// What to do when `|k(t₀, q₀, v₀)|` exceeds the tolerance.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ConsistencyPolicy {
    /// Return [`StepError::InconsistentInitialState`].
    Error {
        /// Largest accepted `max_i |k_i(t₀,q₀,v₀)|`.
        tolerance: f64,
    },
    /// Replace `v₀` by the closest consistent velocity in the kinetic-energy
    /// metric `∇²_vv L(t₀,q₀,v₀)`.
    Project {
        /// Largest accepted `max_i |k_i|` before projecting.
        tolerance: f64,
    },
}

impl Default for ConsistencyPolicy {
    fn default() -> Self {
        ConsistencyPolicy::Error { tolerance: 1e-12 }
    }
}

/// Why a saddle-point solve failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum SaddleFailure {
    /// A pivot of `W` (block `"W"`) or of the Schur complement `K W⁻¹ Kᵀ`
    /// (block `"K W⁻¹ Kᵀ"`) fell below `64 ε` times its column's largest entry.
    Singular {
        /// Which factorization failed.
        block: &'static str,
        /// Column of that block.
        column: usize,
        /// The pivot.
        pivot: f64,
        /// The column's largest magnitude.
        scale: f64,
    },
    /// The solution is not finite.
    NonFinite,
}

/// Solves `[[W, Kᵀ],[K, 0]] [x; y] = [r1; r2]` by the Schur complement
/// `K W⁻¹ Kᵀ` (all fixed-size: `N + M` cannot be named as a const on stable).
/// Copies `W` (`8·N²` bytes on the stack); see [`saddle_solve_in_place`].
pub(crate) fn saddle_solve<const N: usize, const M: usize>(
    w: &Matrix<N, N>,
    k: &Matrix<M, N>,
    r1: &Vector<N>,
    r2: &Vector<M>,
) -> Result<(Vector<N>, Vector<M>), SaddleFailure> {
    let mut w = *w;
    saddle_solve_in_place(&mut w, k, r1, r2)
}

/// [`saddle_solve`] factoring `w` in place (it holds the LU factors
/// afterwards), so that no `N × N` matrix goes on the stack: the caller's
/// `w` may live on the heap (the stepper's cold start passes its stage
/// Jacobian work storage).
pub(crate) fn saddle_solve_in_place<const N: usize, const M: usize>(
    w: &mut Matrix<N, N>,
    k: &Matrix<M, N>,
    r1: &Vector<N>,
    r2: &Vector<M>,
) -> Result<(Vector<N>, Vector<M>), SaddleFailure> {
    let scale = column_scales::<N>(w.as_slice());
    let mut perm = [0usize; N];
    factor_in_place::<N>(w.as_mut_slice(), &mut perm, &scale, &[N]).map_err(|e| SaddleFailure::Singular {
        block: "W",
        column: e.column,
        pivot: e.pivot,
        scale: scale[e.column],
    })?;
    let wlu = |b: &mut Vector<N>| solve_in_place::<N>(w.as_slice(), &perm, b.as_mut_slice());
    let mut winv_r1 = *r1;
    wlu(&mut winv_r1);
    if M == 0 {
        return Ok((winv_r1, Vector::<M>::zeros()));
    }
    let mut winv_kt = k.transpose();
    for mut col in winv_kt.column_iter_mut() {
        let mut c: Vector<N> = col.clone_owned();
        wlu(&mut c);
        col.copy_from(&c);
    }
    let schur = k * winv_kt;
    let mut slu = Lu::<M>::new();
    slu.factor(&schur).map_err(|e| SaddleFailure::Singular {
        block: "K W⁻¹ Kᵀ",
        column: e.column,
        pivot: e.pivot,
        scale: schur.column(e.column).amax(),
    })?;
    let mut y = k * winv_r1 - r2;
    slu.solve_in_place(&mut y);
    let x = winv_r1 - winv_kt * y;
    if x.iter().chain(y.iter()).all(|v| v.is_finite()) {
        Ok((x, y))
    } else {
        Err(SaddleFailure::NonFinite)
    }
}

/// The acceleration `a = v̇` and multiplier `ψ` of the constrained equations
/// at `(t, q, v)`, from
/// `W a + Kᵀψ = ∇_q L − (∂p/∂q) v − ∂p/∂t` and `K a = −(k_q v + k_t)`.
/// Returns `None` when the saddle-point matrix is singular.
pub fn consistent_acceleration<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> Option<(Vector<N>, Vector<M>)>
where
    Sys: NonholonomicSystem<N, M>,
{
    if std::mem::size_of::<StageJacobians<N, M>>() > LARGE_JACOBIANS {
        // Large N: the Jacobians go on the heap (one allocation per call).
        let mut jac = StageJacobians::boxed_zeros();
        return consistent_acceleration_in(sys, t, q, v, &mut StageValues::zeros(), &mut jac);
    }
    let (mut vals, mut jac) = (StageValues::zeros(), StageJacobians::zeros());
    consistent_acceleration_in(sys, t, q, v, &mut vals, &mut jac)
}

/// Size of `StageJacobians` above which [`consistent_acceleration`] puts
/// them on the heap instead of the stack (`N ≳ 37`).
const LARGE_JACOBIANS: usize = 64 << 10;

/// [`consistent_acceleration`] with caller-provided scratch storage for the
/// stage values and Jacobians (overwritten; `jac.mass` ends up holding LU
/// factors). With heap storage no `N × N` matrix goes on the stack: the
/// stepper's cold start uses its own work storage, allocation-free.
pub(crate) fn consistent_acceleration_in<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    vals: &mut StageValues<N, M>,
    jac: &mut StageJacobians<N, M>,
) -> Option<(Vector<N>, Vector<M>)>
where
    Sys: NonholonomicSystem<N, M>,
{
    sys.stage_jacobians_into(t, q, v, &Vector::<M>::zeros(), vals, jac);
    let (mut r1, mut r2) = (vals.force - jac.momentum_q * v, -(jac.constraint_q * v));
    if !Sys::STRUCTURE.autonomous() {
        let td = sys.time_derivatives(t, q, v);
        r1 -= td.momentum_t;
        r2 -= td.constraint_t;
    }
    if Sys::HAS_FORCING {
        r1 += sys.external_force(t, q, v);
    }
    // A non-ideal force N(ψ) is left out: this is a starting guess, and
    // Newton on the step equations accounts for it.
    saddle_solve_in_place(&mut jac.mass, &jac.constraint_v, &r1, &r2).ok()
}

/// Checks `(t₀, q₀, v₀)` against the constraints and, by `policy`, returns
/// `v₀` unchanged, returns the projected velocity, or fails.
///
/// The projection minimizes `½(v − v₀)ᵀ W (v − v₀)` subject to
/// `k(t₀, q₀, v) = 0` with `W = ∇²_vv L(t₀, q₀, v₀)`, by Newton on
/// `W(v − v₀) + K(v)ᵀλ = 0`, `k(v) = 0`.
pub fn consistent_velocity<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    policy: ConsistencyPolicy,
) -> Result<Vector<N>, StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    if !t0.is_finite() || q0.iter().chain(v0.iter()).any(|x| !x.is_finite()) {
        return Err(StepError::InvalidStep { t: t0, h: 0.0, reason: "initial state is not finite" });
    }
    let k0 = sys.constraint(t0, q0, v0);
    // A NaN residual would otherwise compare as "inconsistent" and blame the
    // velocity; the cause is a non-finite parameter or constraint value.
    if k0.iter().any(|x| !x.is_finite()) {
        return Err(StepError::NonFinite {
            t: t0,
            h: 0.0,
            stage: "constraint at the initial state (check the parameters)",
            history: Box::default(),
        });
    }
    let residual = k0.amax();
    let tolerance = match policy {
        ConsistencyPolicy::Error { tolerance } | ConsistencyPolicy::Project { tolerance } => tolerance,
    };
    if residual <= tolerance {
        return Ok(*v0);
    }
    if let ConsistencyPolicy::Error { .. } = policy {
        return Err(StepError::InconsistentInitialState { residual, tolerance });
    }
    let w = sys.mass_matrix(t0, q0, v0);
    let mut v = *v0;
    let mut lambda = Vector::<M>::zeros();
    let mut history = NewtonHistory::default();
    let mut prev = f64::NAN;
    for _ in 0..crate::error::HISTORY_CAPACITY {
        let (vals, jac) = sys.stage_jacobians(t0, q0, &v, &lambda);
        // Residual: W(v − v0) − R(λ) with R = −Kᵀλ, and k(v).
        let g1 = w * (v - v0) - vals.constraint_force;
        let g2 = vals.constraint;
        let res = g1.amax().max(g2.amax());
        // Jacobian [[W − ∂R/∂v, Kᵀ],[K, 0]].
        let a = w - jac.constraint_force_v;
        let (dv, dl) = match saddle_solve(&a, &jac.constraint_v, &g1, &g2) {
            Ok(x) => x,
            Err(SaddleFailure::Singular { block, column, pivot, scale }) => {
                history.push(IterationRecord { residual: res, update: f64::NAN, rate: f64::NAN });
                return Err(StepError::SingularMatrix {
                    t: t0,
                    h: 0.0,
                    detail: format!(
                        "(the initial velocity projection, not a step) column {column} of block {block} of \
                         [[W, Kᵀ],[K, 0]]: pivot {pivot:.3e} is below 64 eps x its largest entry {scale:.3e}; {}",
                        if block == "W" {
                            "the mass matrix W = ∇²_vv L is singular at (t0, q0): is a mass or inertia parameter zero?"
                        } else {
                            "the constraint rows K = ∂k/∂v are dependent or vanish at (t0, q0, v); for constraints \
                             nonlinear in v, start from a v0 where ∂k/∂v has full rank (near the constraint surface)"
                        }
                    )
                    .into(),
                    history: Box::new(history),
                });
            }
            Err(SaddleFailure::NonFinite) => {
                history.push(IterationRecord { residual: res, update: f64::NAN, rate: f64::NAN });
                return Err(StepError::NonFinite {
                    t: t0,
                    h: 0.0,
                    stage: "velocity projection",
                    history: Box::new(history),
                });
            }
        };
        v -= dv;
        lambda -= dl;
        let upd = crate::convergence::scaled_update_norm(&dv, &v);
        let rate = upd / prev;
        history.push(IterationRecord { residual: res, update: upd, rate });
        if !upd.is_finite() {
            return Err(StepError::NonFinite {
                t: t0,
                h: 0.0,
                stage: "velocity projection",
                history: Box::new(history),
            });
        }
        if upd <= 4.0 * f64::EPSILON || (rate < 1.0 && rate * upd <= 4.0 * f64::EPSILON) {
            return Ok(v);
        }
        if rate >= 1.0 && history.len() > 2 {
            return Err(StepError::Diverged { t: t0, h: 0.0, history: Box::new(history) });
        }
        prev = upd;
    }
    Err(StepError::MaxIterations { t: t0, h: 0.0, history: Box::new(history) })
}
