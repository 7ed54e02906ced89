//! Every catalogue system's stage values, end-point values and energy in
//! lane form (`stage_values_in_lanes`, `end_point_values_in_lanes` and
//! `energy_in_lanes`, the bodies
//! `nonholonomic_system!` generates, or the trait's lane-by-lane defaults
//! where a body would be too long) are bit for bit its scalar ones at each
//! lane's point, the stage values with and without the constraint
//! Jacobians: what lets a member stepped in the lane kernel match its run
//! alone.

use problems::catalog::{visit_system, Dispatch, SystemEntry, SystemKind, SystemVisitor};
use spark_runtime::{LaneConstraintJacobians, LaneStageValues, Matrix, StageValues, Vector};

const W: usize = 8;

fn same(a: f64, b: f64, what: &str) {
    assert_eq!(a.to_bits(), b.to_bits(), "{what}: {a:e} (lanes) vs {b:e} (scalar)");
}

struct LaneValuesMatchScalar;

impl SystemVisitor for LaneValuesMatchScalar {
    type Output = ();
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(self, entry: &'static SystemEntry) {
        let sys = Sys::default();
        // Eight different points near the entry's default start, every
        // entry different in every lane.
        let wobble = |i: usize, w: usize, k: f64| 0.05 * k * ((1 + i + 3 * w) as f64).sin();
        let q: [[f64; W]; N] = std::array::from_fn(|n| std::array::from_fn(|w| entry.q0[n] + wobble(n, w, 1.0)));
        let v: [[f64; W]; N] = std::array::from_fn(|n| std::array::from_fn(|w| entry.v0[n] + wobble(n, w, 2.0)));
        let psi: [[f64; W]; M] = std::array::from_fn(|m| std::array::from_fn(|w| 0.3 + wobble(m, w, 3.0)));
        let t = entry.t0 + 0.37;
        let energy = sys.energy_in_lanes(t, &q, &v, &[true; W]);
        for w in 0..W {
            let (qw, vw) = (Vector::<N>::from_fn(|n, _| q[n][w]), Vector::<N>::from_fn(|n, _| v[n][w]));
            same(energy[w], sys.energy(t, &qw, &vw), &format!("{} lane {w} energy", entry.name));
        }
        let mut values = LaneStageValues::<N, M, W>::zeros();
        let mut jacobians = LaneConstraintJacobians::<N, M, W>::zeros();
        for with_jacobians in [false, true] {
            let jac = if with_jacobians { Some(&mut jacobians) } else { None };
            sys.stage_values_in_lanes(t, &q, &v, &psi, &[true; W], &mut values, jac);
            for w in 0..W {
                let qw = Vector::<N>::from_fn(|n, _| q[n][w]);
                let vw = Vector::<N>::from_fn(|n, _| v[n][w]);
                let psiw = Vector::<M>::from_fn(|m, _| psi[m][w]);
                let what = |field: &str, i: usize| {
                    format!("{} lane {w} {field}[{i}] (Jacobians: {with_jacobians})", entry.name)
                };
                let scalar = if with_jacobians {
                    let (mut vals, mut kq, mut kv) =
                        (StageValues::zeros(), Matrix::<M, N>::zeros(), Matrix::<M, N>::zeros());
                    sys.stage_values_and_constraint_jacobians(t, &qw, &vw, &psiw, &mut vals, &mut kq, &mut kv);
                    for j in 0..N {
                        for i in 0..M {
                            same(jacobians.constraint_q[j][i][w], kq[(i, j)], &what("k_q", j * M + i));
                            same(jacobians.constraint_v[j][i][w], kv[(i, j)], &what("K", j * M + i));
                        }
                    }
                    vals
                } else {
                    sys.stage_values(t, &qw, &vw, &psiw)
                };
                for n in 0..N {
                    same(values.momentum[n][w], scalar.momentum[n], &what("momentum", n));
                    same(values.force[n][w], scalar.force[n], &what("force", n));
                    same(values.constraint_force[n][w], scalar.constraint_force[n], &what("constraint force", n));
                }
                for m in 0..M {
                    same(values.constraint[m][w], scalar.constraint[m], &what("constraint", m));
                }
            }
        }
        // The end point's momentum and constraint (and constraint
        // Jacobians), against the scalar end-point functions.
        for with_jacobians in [false, true] {
            let mut values = LaneStageValues::<N, M, W>::zeros();
            let jac = if with_jacobians { Some(&mut jacobians) } else { None };
            sys.end_point_values_in_lanes(t, &q, &v, &[true; W], &mut values, jac);
            for w in 0..W {
                let qw = Vector::<N>::from_fn(|n, _| q[n][w]);
                let vw = Vector::<N>::from_fn(|n, _| v[n][w]);
                let what = |field: &str, i: usize| {
                    format!("{} lane {w} end point {field}[{i}] (Jacobians: {with_jacobians})", entry.name)
                };
                let mut scalar = StageValues::zeros();
                if with_jacobians {
                    let (mut kq, mut kv) = (Matrix::<M, N>::zeros(), Matrix::<M, N>::zeros());
                    sys.end_point_values_and_constraint_jacobians(t, &qw, &vw, &mut scalar, &mut kq, &mut kv);
                    for j in 0..N {
                        for i in 0..M {
                            same(jacobians.constraint_q[j][i][w], kq[(i, j)], &what("k_q", j * M + i));
                            same(jacobians.constraint_v[j][i][w], kv[(i, j)], &what("K", j * M + i));
                        }
                    }
                } else {
                    sys.end_point_values_into(t, &qw, &vw, &mut scalar);
                }
                for n in 0..N {
                    same(values.momentum[n][w], scalar.momentum[n], &what("momentum", n));
                }
                for m in 0..M {
                    same(values.constraint[m][w], scalar.constraint[m], &what("constraint", m));
                }
            }
        }
    }
}

#[test]
fn every_system_s_values_in_lanes_are_its_scalar_values() {
    for &kind in SystemKind::ALL {
        visit_system(kind, LaneValuesMatchScalar);
    }
}
