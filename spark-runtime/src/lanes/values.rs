//! Stage values of `W` lanes in structure-of-arrays form: what
//! [`NonholonomicSystem::stage_values_in_lanes`] writes for the lane
//! kernel, and the lane-by-lane evaluation every system has by default.
//!
//! Row `n` of a lane array holds entry `n` of every lane, so that the
//! kernel's loops over lanes vectorize; `nonholonomic_system!` generates
//! the system's own functions in the same form, each lane computing
//! exactly the operations of the scalar functions.

// Lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

use crate::system::{Matrix, NonholonomicSystem, StageValues, Vector};

/// [`StageValues`] of `W` lanes: entry `n` of lane `w` at `[n][w]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaneStageValues<const N: usize, const M: usize, const W: usize> {
    /// `P = ∇_v L(t,q,v)`.
    pub momentum: [[f64; W]; N],
    /// `F = ∇_q L(t,q,v)`.
    pub force: [[f64; W]; N],
    /// `k(t,q,v)`.
    pub constraint: [[f64; W]; M],
    /// `R = −K(t,q,v)ᵀ ψ`.
    pub constraint_force: [[f64; W]; N],
}

impl<const N: usize, const M: usize, const W: usize> LaneStageValues<N, M, W> {
    /// All entries zero.
    pub fn zeros() -> Self {
        LaneStageValues {
            momentum: [[0.0; W]; N],
            force: [[0.0; W]; N],
            constraint: [[0.0; W]; M],
            constraint_force: [[0.0; W]; N],
        }
    }
}

/// The constraint Jacobians `k_q` and `K = k_v` of `W` lanes: entry
/// `(i, j)` of lane `w` at `[j][i][w]` (column-major, as nalgebra stores
/// a matrix).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaneConstraintJacobians<const N: usize, const M: usize, const W: usize> {
    /// `k_q`.
    pub constraint_q: [[[f64; W]; M]; N],
    /// `K = k_v`.
    pub constraint_v: [[[f64; W]; M]; N],
}

impl<const N: usize, const M: usize, const W: usize> LaneConstraintJacobians<N, M, W> {
    /// All entries zero.
    pub fn zeros() -> Self {
        LaneConstraintJacobians { constraint_q: [[[0.0; W]; M]; N], constraint_v: [[[0.0; W]; M]; N] }
    }
}

/// Lane `w` of the lane rows `x`, as a vector.
#[inline(always)]
fn lane<const K: usize, const W: usize>(x: &[[f64; W]; K], w: usize) -> Vector<K> {
    Vector::<K>::from_fn(|k, _| x[k][w])
}

/// The default of [`NonholonomicSystem::energy_in_lanes`]: the energy of
/// every lane `w` with `lanes[w]` by [`NonholonomicSystem::energy`]; `NaN`
/// for the others.
pub(crate) fn energy_lane_by_lane<Sys, const N: usize, const M: usize, const W: usize>(
    sys: &Sys,
    t: f64,
    q: &[[f64; W]; N],
    v: &[[f64; W]; N],
    lanes: &[bool; W],
) -> [f64; W]
where
    Sys: NonholonomicSystem<N, M> + ?Sized,
{
    std::array::from_fn(|w| if lanes[w] { sys.energy(t, &lane(q, w), &lane(v, w)) } else { f64::NAN })
}

/// The default of [`NonholonomicSystem::stage_values_in_lanes`]: every lane
/// `w` with `lanes[w]` gathered into vectors and evaluated by
/// [`NonholonomicSystem::stage_values`] (or, with `jacobians`,
/// [`NonholonomicSystem::stage_values_and_constraint_jacobians`]); the
/// other lanes' entries are left as they are.
#[allow(clippy::too_many_arguments)]
pub(crate) fn lane_by_lane<Sys, const N: usize, const M: usize, const W: usize>(
    sys: &Sys,
    t: f64,
    q: &[[f64; W]; N],
    v: &[[f64; W]; N],
    psi: &[[f64; W]; M],
    lanes: &[bool; W],
    values: &mut LaneStageValues<N, M, W>,
    mut jacobians: Option<&mut LaneConstraintJacobians<N, M, W>>,
) where
    Sys: NonholonomicSystem<N, M> + ?Sized,
{
    let (mut kq, mut kv) = (Matrix::<M, N>::zeros(), Matrix::<M, N>::zeros());
    for w in 0..W {
        if !lanes[w] {
            continue;
        }
        let (qw, vw, psiw) = (lane(q, w), lane(v, w), lane(psi, w));
        let vals = match jacobians.as_deref_mut() {
            Some(jac) => {
                let mut vals = StageValues::zeros();
                sys.stage_values_and_constraint_jacobians(t, &qw, &vw, &psiw, &mut vals, &mut kq, &mut kv);
                for j in 0..N {
                    for i in 0..M {
                        jac.constraint_q[j][i][w] = kq[(i, j)];
                        jac.constraint_v[j][i][w] = kv[(i, j)];
                    }
                }
                vals
            }
            None => sys.stage_values(t, &qw, &vw, &psiw),
        };
        for n in 0..N {
            values.momentum[n][w] = vals.momentum[n];
            values.force[n][w] = vals.force[n];
            values.constraint_force[n][w] = vals.constraint_force[n];
        }
        for m in 0..M {
            values.constraint[m][w] = vals.constraint[m];
        }
    }
}
