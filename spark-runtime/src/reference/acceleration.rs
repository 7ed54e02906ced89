//! The ψ-eliminated accelerations of paper eq. (2.3): the saddle-point
//! solve for `(v̇, ψ)`, with Newton's method in `(v̇, ψ)` when a non-ideal
//! constraint force makes it nonlinear in `ψ`.

use super::ReferenceError;
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use nalgebra::{DMatrix, DVector};

/// Accelerations and multipliers of the system at `(t, q, v)`: the solution
/// `(v̇, ψ)` of the saddle-point system of paper eq. (2.3).
///
/// Uses [`NonholonomicSystem::stage_jacobians_into`] (evaluated with
/// `ψ = 0`: `∇_q L`, `∇²_vv L`, `∂(∇_v L)/∂q`, `k_q`, `K`),
/// `time_derivatives`, and the forcing and non-ideal force when the system
/// has them. The Jacobians and the dense saddle matrix live on the heap
/// (allocated once per call), so the stack use is `O(N)` for systems whose
/// in-place methods write in place (generated ones do).
pub fn acceleration<S, const N: usize, const M: usize>(
    sys: &S,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> Result<(Vector<N>, Vector<M>), ReferenceError>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    acceleration_with(sys, t, q, v, &mut Scratch::new())
}

/// Heap storage of one acceleration evaluation, allocated once per
/// integration and reused by every right-hand side.
pub(super) struct Scratch<const N: usize, const M: usize> {
    values: StageValues<N, M>,
    jacobians: Box<StageJacobians<N, M>>,
    /// `∂N/∂ψ` of a non-ideal constraint force.
    psi_jacobian: Box<Matrix<N, M>>,
    /// `[[∇²_vv L, Kᵀ],[K, 0]]`.
    saddle: DMatrix<f64>,
    /// `[r_v; r_k]`.
    rhs: DVector<f64>,
}

impl<const N: usize, const M: usize> Scratch<N, M> {
    pub(super) fn new() -> Self {
        Scratch {
            values: StageValues::zeros(),
            jacobians: StageJacobians::boxed_zeros(),
            psi_jacobian: Box::new(Matrix::zeros()),
            saddle: DMatrix::zeros(N + M, N + M),
            rhs: DVector::zeros(N + M),
        }
    }
}

/// [`acceleration`] in caller-provided heap storage.
pub(super) fn acceleration_with<S, const N: usize, const M: usize>(
    sys: &S,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    scratch: &mut Scratch<N, M>,
) -> Result<(Vector<N>, Vector<M>), ReferenceError>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    let Scratch { values, jacobians: jac, saddle: a, rhs: b, .. } = scratch;
    sys.stage_jacobians_into(t, q, v, &Vector::<M>::zeros(), values, jac);
    let td = sys.time_derivatives(t, q, v);
    let mut rhs_v = values.force - jac.momentum_q * v - td.momentum_t;
    if S::HAS_FORCING {
        rhs_v += sys.external_force(t, q, v);
    }
    let rhs_k = -td.constraint_t - jac.constraint_q * v;
    a.fill(0.0);
    for j in 0..N {
        for i in 0..N {
            a[(i, j)] = jac.mass[(i, j)];
        }
        b[j] = rhs_v[j];
    }
    for r in 0..M {
        for j in 0..N {
            a[(N + r, j)] = jac.constraint_v[(r, j)];
            a[(j, N + r)] = jac.constraint_v[(r, j)];
        }
        b[N + r] = rhs_k[r];
    }
    if !a.iter().chain(b.iter()).all(|x| x.is_finite()) {
        return Err(ReferenceError::NonFinite { t });
    }
    if S::HAS_NONIDEAL_FORCE {
        return nonideal_acceleration(sys, t, q, v, scratch);
    }
    let lu = a.clone().full_piv_lu();
    let mut x = lu.solve(&*b).ok_or(ReferenceError::SingularSaddle { t })?;
    // One step of iterative refinement recovers the digits lost to the
    // conditioning of the saddle matrix, which matters at 1e-14 tolerances.
    let residual = &*b - &*a * &x;
    if let Some(dx) = lu.solve(&residual) {
        x += dx;
    }
    if !x.iter().all(|v| v.is_finite()) {
        return Err(ReferenceError::NonFinite { t });
    }
    let vdot = Vector::<N>::from_fn(|i, _| x[i]);
    let psi = Vector::<M>::from_fn(|i, _| x[N + i]);
    Ok((vdot, psi))
}

/// `(v̇, ψ)` with a non-ideal constraint force: `W v̇ + Kᵀψ − N(t,q,v,ψ) = r_v`,
/// `K v̇ = r_k`, solved by Newton's method in `(v̇, ψ)` (`N` is nonlinear in
/// `ψ`, e.g. dry friction `∝ |ψ|`), starting from the ideal solution `N = 0`.
/// `scratch.saddle` holds `[[W, Kᵀ],[K, 0]]` and `scratch.rhs` holds
/// `[r_v; r_k]` on entry.
fn nonideal_acceleration<S, const N: usize, const M: usize>(
    sys: &S,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    scratch: &mut Scratch<N, M>,
) -> Result<(Vector<N>, Vector<M>), ReferenceError>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    let Scratch { values, jacobians, psi_jacobian, saddle, rhs } = scratch;
    let dim = N + M;
    let mut x = DVector::<f64>::zeros(dim);
    let mut converged = false;
    for _ in 0..60 {
        let psi = Vector::<M>::from_fn(|i, _| x[N + i]);
        // N(ψ) accumulates into the zeroed constraint force; ∂N/∂q and
        // ∂N/∂v go into Jacobian blocks this solve does not read.
        values.constraint_force.fill(0.0);
        sys.add_nonideal_force_jacobians(t, q, v, &psi, values, jacobians, psi_jacobian);
        // g = [[W, Kᵀ],[K, 0]] x − [N; 0] − [r_v; r_k].
        let mut g = &*saddle * &x - &*rhs;
        for i in 0..N {
            g[i] -= values.constraint_force[i];
        }
        let mut a = saddle.clone();
        for i in 0..N {
            for r in 0..M {
                a[(i, N + r)] -= psi_jacobian[(i, r)];
            }
        }
        if !a.iter().chain(g.iter()).all(|x| x.is_finite()) {
            return Err(ReferenceError::NonFinite { t });
        }
        let dx = a.full_piv_lu().solve(&g).ok_or(ReferenceError::SingularSaddle { t })?;
        x -= &dx;
        let scale = 1.0 + x.amax();
        if dx.amax() <= 4.0 * f64::EPSILON * scale {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(ReferenceError::NonidealNotConverged { t });
    }
    if !x.iter().all(|v| v.is_finite()) {
        return Err(ReferenceError::NonFinite { t });
    }
    Ok((Vector::<N>::from_fn(|i, _| x[i]), Vector::<M>::from_fn(|i, _| x[N + i])))
}
