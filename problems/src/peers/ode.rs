//! The ψ-eliminated ODE (paper eq. 2.3) as a first-order system `y = (q, v)`,
//! integrated with the `ode_solvers` crate's DOP853: what a Rust user who
//! does not know about SPARK would reach for.
//!
//! The right-hand side uses the generated code's fused `stage_jacobians`
//! (one call gives `∇_q L`, `∇²_vv L`, `∂(∇_v L)/∂q`, `k_q`, `K`) and solves
//! the saddle-point system by a Schur complement with fixed-size LU
//! factorizations (`N × N` and `M × M`), so the peer pays for nothing but
//! the method.

use nalgebra::SVector;
use ode_solvers::{Dop853, System};
use spark_runtime::{Matrix, NonholonomicSystem, Vector};
use std::cell::Cell;

/// Accelerations `v̇` of the ψ-eliminated equations at `(t, q, v)`, or `None`
/// where the saddle-point matrix is singular.
pub fn acceleration<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> Option<Vector<N>>
where
    Sys: NonholonomicSystem<N, M>,
{
    let (values, jac) = sys.stage_jacobians(t, q, v, &Vector::<M>::zeros());
    let mut rhs = values.force - jac.momentum_q * v;
    let mut rk = -(jac.constraint_q * v);
    if !Sys::STRUCTURE.autonomous() {
        let td = sys.time_derivatives(t, q, v);
        rhs -= td.momentum_t;
        rk -= td.constraint_t;
    }
    let minv_rhs = solve(jac.mass, rhs)?;
    if M == 0 {
        return Some(minv_rhs);
    }
    let minv_kt = solve(jac.mass, jac.constraint_v.transpose())?;
    let schur = jac.constraint_v * minv_kt;
    let psi = solve(schur, jac.constraint_v * minv_rhs - rk)?;
    Some(minv_rhs - minv_kt * psi)
}

/// `A⁻¹B` by Gaussian elimination with partial pivoting on fixed-size
/// values (nalgebra's LU needs typenum bounds that generic `N` cannot name).
fn solve<const N: usize, const C: usize>(mut a: Matrix<N, N>, mut b: Matrix<N, C>) -> Option<Matrix<N, C>> {
    for k in 0..N {
        let (p, pivot) = (k..N).map(|i| (i, a[(i, k)].abs())).max_by(|x, y| x.1.total_cmp(&y.1))?;
        if pivot == 0.0 || !pivot.is_finite() {
            return None;
        }
        a.swap_rows(k, p);
        b.swap_rows(k, p);
        for i in k + 1..N {
            let f = a[(i, k)] / a[(k, k)];
            for j in k..N {
                a[(i, j)] -= f * a[(k, j)];
            }
            for j in 0..C {
                b[(i, j)] -= f * b[(k, j)];
            }
        }
    }
    for k in (0..N).rev() {
        for j in 0..C {
            let mut x = b[(k, j)];
            for i in k + 1..N {
                x -= a[(k, i)] * b[(i, j)];
            }
            b[(k, j)] = x / a[(k, k)];
        }
    }
    Some(b)
}

/// The first-order system `ẏ = (v, v̇(t, q, v))` with `y ∈ R^Y`, `Y = 2N`.
pub struct FirstOrder<'a, Sys, const N: usize, const M: usize> {
    sys: &'a Sys,
    evaluations: Cell<usize>,
}

impl<Sys, const N: usize, const M: usize, const Y: usize> System<f64, SVector<f64, Y>> for FirstOrder<'_, Sys, N, M>
where
    Sys: NonholonomicSystem<N, M>,
{
    fn system(&self, t: f64, y: &SVector<f64, Y>, dy: &mut SVector<f64, Y>) {
        self.evaluations.set(self.evaluations.get() + 1);
        let q = Vector::<N>::from_fn(|i, _| y[i]);
        let v = Vector::<N>::from_fn(|i, _| y[N + i]);
        match acceleration::<Sys, N, M>(self.sys, t, &q, &v) {
            Some(a) => {
                for i in 0..N {
                    dy[i] = v[i];
                    dy[N + i] = a[i];
                }
            }
            // NaN makes the solver's error estimate fail the step and report it.
            None => dy.fill(f64::NAN),
        }
    }
}

/// The end state of one DOP853 run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdeRun<const N: usize> {
    /// `q(t₁)`.
    pub q: Vector<N>,
    /// `v(t₁)`.
    pub v: Vector<N>,
    /// Accepted steps.
    pub steps: usize,
    /// Right-hand-side evaluations.
    pub evaluations: usize,
}

/// Errors of the DOP853 peer.
#[derive(Debug, thiserror::Error)]
pub enum OdeError {
    /// `Y` is not `2N`.
    #[error("state dimension {y} must be twice the number of coordinates {n}")]
    Dimension {
        /// `Y`.
        y: usize,
        /// `N`.
        n: usize,
    },
    /// The solver gave up.
    #[error("ode_solvers DOP853 failed: {0}")]
    Solver(String),
    /// The solver returned no end state.
    #[error("ode_solvers DOP853 returned no output")]
    NoOutput,
}

/// Integrates the ψ-eliminated ODE from `(t0, q0, v0)` to `t1` with DOP853 at
/// tolerances `rtol`, `atol`; `Y` must be `2N`.
pub fn dop853<Sys, const N: usize, const M: usize, const Y: usize>(
    sys: &Sys,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t1: f64,
    rtol: f64,
    atol: f64,
) -> Result<OdeRun<N>, OdeError>
where
    Sys: NonholonomicSystem<N, M>,
{
    if Y != 2 * N {
        return Err(OdeError::Dimension { y: Y, n: N });
    }
    let y0 = SVector::<f64, Y>::from_fn(|i, _| if i < N { q0[i] } else { v0[i - N] });
    let system = FirstOrder::<Sys, N, M> { sys, evaluations: Cell::new(0) };
    // Dense output at the single point t1: the solver stores two states only.
    let mut solver = Dop853::new(system, t0, t1, t1 - t0, y0, rtol, atol);
    let stats = solver.integrate().map_err(|e| OdeError::Solver(e.to_string()))?;
    let y = *solver.y_out().last().ok_or(OdeError::NoOutput)?;
    let last_t = *solver.x_out().last().ok_or(OdeError::NoOutput)?;
    if (last_t - t1).abs() > 1e-9 * t1.abs().max(1.0) {
        return Err(OdeError::NoOutput);
    }
    Ok(OdeRun {
        q: Vector::<N>::from_fn(|i, _| y[i]),
        v: Vector::<N>::from_fn(|i, _| y[N + i]),
        steps: stats.accepted_steps as usize,
        evaluations: stats.num_eval as usize,
    })
}
