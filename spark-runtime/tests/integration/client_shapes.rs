//! Shapes of user systems beyond `newcomer_systems` and
//! `newcomer_unusual_systems`, each checked against an implementation
//! written here from the paper's equations alone:
//!
//! - `SixThree`: N = 6, M = 3; a mass matrix depending on `q` through several
//!   parameters, a gyroscopic (magnetic) term pulsating in `t`, an external
//!   force depending on `t` and `v`, two linear constraints and one affine
//!   constraint with an explicit `t` drift.
//! - `KineticOne`: N = 1, M = 0; a Lagrangian quartic in `v` with a
//!   `q`-dependent factor, a force quadratic in `v` and periodic in `t`.
//! - `FullTwo`: M = N = 2; a constraint with an explicit `t`, one whose
//!   row depends on `q`, a `q`-dependent mass and a force in `t` and `v`.
//! - `VanishingRow`: an affine constraint `x ẏ − a` whose row `K = (0, x)`
//!   vanishes at `x = 0`: a start there is a clear error, never a run.
//!
//! For each system the test writes `∇_v L`, `∇_q L + f`, `k` and `K = k_v`
//! by hand, checks them against central differences of a hand-written `L`
//! (so the hand formulas are right) and against the generated functions;
//! then every step of Gauss s = 1..3, Lobatto IIIA-B s = 2, 3 and IIIA-B-D
//! s = 2, 3, in full and in simplified Newton, is compared with a dense
//! Newton solve of eq. (6.1) written here (finite-difference Jacobian,
//! iterated until the update stops shrinking), from the cold guess
//! `V_i = v0`, `Ψ_i = 0`, `v1 = v0`.

use spark_runtime::{
    consistent_velocity, nonholonomic_system, ConditionEquation, ConsistencyPolicy, Method, NewtonMode, NewtonOptions,
    NoObserver, NonholonomicSystem, RunOptions, Schedule, State, StepError, Stepper, Tableau, TableauTable, Vector,
};

nonholonomic_system! {
    /// Six coordinates, three constraints (one with an explicit t drift), a q-dependent mass
    /// with several parameters, a pulsating magnetic term and a force in t and v.
    pub struct SixThree {
        coordinates: [x, y, th, ph, z, w],
        parameters: {
            m = 1.2, a = 0.4, i1 = 0.3, i2 = 0.2, mz = 1.5, c = 0.5, mw = 0.8, b = 0.6, e = 0.3,
            kx = 0.7, g = 1.1, kw = 2.0, r = 0.35, u = 0.25, om = 1.3, c1 = 0.1, c2 = 0.2, c3 = 0.05,
            f0 = 0.4, f1 = 0.3,
        },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + (i1 + m*a^2*sin(ph)^2)/2*dot(th)^2 + i2/2*dot(ph)^2
            + (mz + c*cos(th))/2*dot(z)^2 + mw/2*dot(w)^2
            + b*(1 + e*sin(t))/2*(x*dot(y) - y*dot(x))
            - kx/2*(x^2 + y^2) - g*z - kw/2*(w - z)^2,
        constraints: [
            cos(th)*dot(y) - sin(th)*dot(x),
            cos(th)*dot(x) + sin(th)*dot(y) - r*dot(ph),
            dot(z) - sin(x)*dot(w) - u*cos(om*t),
        ],
        forces: {
            x: -c1*dot(x) + f0*cos(om*t),
            th: -c2*dot(th)*dot(y),
            w: -c3*dot(w)^3 + f1*sin(t),
        },
    }
}

nonholonomic_system! {
    /// One coordinate, no constraint: a kinetic term quartic in v with a q-dependent factor,
    /// a force quadratic in v and periodic in t.
    pub struct KineticOne {
        coordinates: [x],
        parameters: { al = 0.25, k = 1.5, c = 0.1, amp = 0.3, w = 0.9 },
        lagrangian: (1 + al*x^2)*(dot(x)^2/2 + dot(x)^4/24) - k/4*x^4,
        forces: { x: -c*dot(x)*(1 + sin(t)) + amp*cos(w*t)*dot(x)^2 },
    }
}

nonholonomic_system! {
    /// As many constraints as coordinates, one with an explicit t and one with a q-dependent
    /// row; a q-dependent mass and a force in t and v.
    pub struct FullTwo {
        coordinates: [x, y],
        parameters: { al = 0.3, a = 0.7, w = 1.1, b = 0.4, c = 0.2 },
        lagrangian: (1 + al*x^2)*dot(x)^2/2 + dot(y)^2/2 - x^2/2 - y^4/4,
        constraints: [ dot(x) - a*cos(w*t), dot(y) - b*x*dot(x) ],
        forces: { y: -c*dot(y)*(1 + t^2/10) },
    }
}

nonholonomic_system! {
    /// An affine constraint whose row K = (0, x) vanishes on x = 0.
    pub struct VanishingRow {
        coordinates: [x, y],
        parameters: { a = 0.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - y^2/2,
        constraints: [ x*dot(y) - a ],
    }
}

/// A system written by hand: `L`, `∇_v L`, `∇_q L + f`, `k` and `K = k_v`
/// as closed formulas of `(t, q, v)`, independent of the macro.
trait Hand {
    const N: usize;
    const M: usize;
    fn lagrangian(&self, t: f64, q: &[f64], v: &[f64]) -> f64;
    fn momentum(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64>;
    /// `∇_q L` (without the external force).
    fn grad_q(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64>;
    fn external(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64>;
    fn k(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64>;
    /// `K = k_v`, `M` rows of `N`.
    fn kv(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<Vec<f64>>;
}

impl Hand for SixThree {
    const N: usize = 6;
    const M: usize = 3;
    fn lagrangian(&self, t: f64, q: &[f64], v: &[f64]) -> f64 {
        let SixThree { m, a, i1, i2, mz, c, mw, b, e, kx, g, kw, .. } = *self;
        let (x, y, th, ph, z, w) = (q[0], q[1], q[2], q[3], q[4], q[5]);
        m / 2.0 * (v[0] * v[0] + v[1] * v[1])
            + (i1 + m * a * a * ph.sin().powi(2)) / 2.0 * v[2] * v[2]
            + i2 / 2.0 * v[3] * v[3]
            + (mz + c * th.cos()) / 2.0 * v[4] * v[4]
            + mw / 2.0 * v[5] * v[5]
            + b * (1.0 + e * t.sin()) / 2.0 * (x * v[1] - y * v[0])
            - kx / 2.0 * (x * x + y * y)
            - g * z
            - kw / 2.0 * (w - z).powi(2)
    }
    fn momentum(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        let SixThree { m, a, i1, i2, mz, c, mw, b, e, .. } = *self;
        let bb = b * (1.0 + e * t.sin());
        vec![
            m * v[0] - bb * q[1] / 2.0,
            m * v[1] + bb * q[0] / 2.0,
            (i1 + m * a * a * q[3].sin().powi(2)) * v[2],
            i2 * v[3],
            (mz + c * q[2].cos()) * v[4],
            mw * v[5],
        ]
    }
    fn grad_q(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        let SixThree { m, a, c, b, e, kx, g, kw, .. } = *self;
        let bb = b * (1.0 + e * t.sin());
        vec![
            bb * v[1] / 2.0 - kx * q[0],
            -bb * v[0] / 2.0 - kx * q[1],
            -c * q[2].sin() * v[4] * v[4] / 2.0,
            m * a * a * q[3].sin() * q[3].cos() * v[2] * v[2],
            -g + kw * (q[5] - q[4]),
            -kw * (q[5] - q[4]),
        ]
    }
    fn external(&self, t: f64, _q: &[f64], v: &[f64]) -> Vec<f64> {
        let SixThree { om, c1, c2, c3, f0, f1, .. } = *self;
        vec![-c1 * v[0] + f0 * (om * t).cos(), 0.0, -c2 * v[2] * v[1], 0.0, 0.0, -c3 * v[5].powi(3) + f1 * t.sin()]
    }
    fn k(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        let SixThree { r, u, om, .. } = *self;
        let (s, c) = q[2].sin_cos();
        vec![c * v[1] - s * v[0], c * v[0] + s * v[1] - r * v[3], v[4] - q[0].sin() * v[5] - u * (om * t).cos()]
    }
    fn kv(&self, _t: f64, q: &[f64], _v: &[f64]) -> Vec<Vec<f64>> {
        let (s, c) = q[2].sin_cos();
        vec![
            vec![-s, c, 0.0, 0.0, 0.0, 0.0],
            vec![c, s, 0.0, -self.r, 0.0, 0.0],
            vec![0.0, 0.0, 0.0, 0.0, 1.0, -q[0].sin()],
        ]
    }
}

impl Hand for KineticOne {
    const N: usize = 1;
    const M: usize = 0;
    fn lagrangian(&self, _t: f64, q: &[f64], v: &[f64]) -> f64 {
        let (x, xd) = (q[0], v[0]);
        (1.0 + self.al * x * x) * (xd * xd / 2.0 + xd.powi(4) / 24.0) - self.k / 4.0 * x.powi(4)
    }
    fn momentum(&self, _t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        let (x, xd) = (q[0], v[0]);
        vec![(1.0 + self.al * x * x) * (xd + xd.powi(3) / 6.0)]
    }
    fn grad_q(&self, _t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        let (x, xd) = (q[0], v[0]);
        vec![2.0 * self.al * x * (xd * xd / 2.0 + xd.powi(4) / 24.0) - self.k * x.powi(3)]
    }
    fn external(&self, t: f64, _q: &[f64], v: &[f64]) -> Vec<f64> {
        vec![-self.c * v[0] * (1.0 + t.sin()) + self.amp * (self.w * t).cos() * v[0] * v[0]]
    }
    fn k(&self, _t: f64, _q: &[f64], _v: &[f64]) -> Vec<f64> {
        Vec::new()
    }
    fn kv(&self, _t: f64, _q: &[f64], _v: &[f64]) -> Vec<Vec<f64>> {
        Vec::new()
    }
}

impl Hand for FullTwo {
    const N: usize = 2;
    const M: usize = 2;
    fn lagrangian(&self, _t: f64, q: &[f64], v: &[f64]) -> f64 {
        (1.0 + self.al * q[0] * q[0]) * v[0] * v[0] / 2.0 + v[1] * v[1] / 2.0 - q[0] * q[0] / 2.0 - q[1].powi(4) / 4.0
    }
    fn momentum(&self, _t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        vec![(1.0 + self.al * q[0] * q[0]) * v[0], v[1]]
    }
    fn grad_q(&self, _t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        vec![self.al * q[0] * v[0] * v[0] - q[0], -q[1].powi(3)]
    }
    fn external(&self, t: f64, _q: &[f64], v: &[f64]) -> Vec<f64> {
        vec![0.0, -self.c * v[1] * (1.0 + t * t / 10.0)]
    }
    fn k(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        vec![v[0] - self.a * (self.w * t).cos(), v[1] - self.b * q[0] * v[0]]
    }
    fn kv(&self, _t: f64, q: &[f64], _v: &[f64]) -> Vec<Vec<f64>> {
        vec![vec![1.0, 0.0], vec![-self.b * q[0], 1.0]]
    }
}

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// Sixth-order central difference of `f` at 0.
fn diff6(f: impl Fn(f64) -> f64, e: f64) -> f64 {
    (f(3.0 * e) - 9.0 * f(2.0 * e) + 45.0 * f(e) - 45.0 * f(-e) + 9.0 * f(-2.0 * e) - f(-3.0 * e)) / (60.0 * e)
}

/// Largest relative error `|x − y| / (1 + |x|)`.
fn rel(x: f64, y: f64) -> f64 {
    let d = (x - y).abs() / (1.0 + x.abs());
    if d.is_nan() {
        f64::INFINITY
    } else {
        d
    }
}

/// `(hand vs differences of the hand L, generated vs hand)`: the largest
/// relative errors of `∇_v L`, `∇_q L`, `k_v` (against differences of `k`)
/// and, against the hand formulas, of the generated `momentum`, `force`,
/// `external_force`, `constraint`, `constraint_v`, `energy`, and of the
/// generated Jacobians against differences of the generated values
/// (external force included).
fn derivative_errors<Sys, const N: usize, const M: usize>(sys: &Sys) -> (f64, f64)
where
    Sys: NonholonomicSystem<N, M> + Hand,
{
    let mut rng = Lcg(11);
    let (mut hand, mut generated) = (0.0f64, 0.0f64);
    let e = 1e-3;
    for _ in 0..25 {
        let t = 2.0 * rng.next();
        let q: Vec<f64> = (0..N).map(|_| rng.next()).collect();
        let v: Vec<f64> = (0..N).map(|_| rng.next() + 0.2).collect();
        let (qv, vv) = (Vector::<N>::from_column_slice(&q), Vector::<N>::from_column_slice(&v));
        let psi = Vector::<M>::from_fn(|_, _| rng.next());
        let shifted = |x: &[f64], j: usize, d: f64| {
            let mut y = x.to_vec();
            y[j] += d;
            y
        };
        // The hand formulas against differences of the hand L and k.
        let (p, fq, k, kv) = (
            sys.momentum_hand(t, &q, &v),
            Hand::grad_q(sys, t, &q, &v),
            Hand::k(sys, t, &q, &v),
            Hand::kv(sys, t, &q, &v),
        );
        for j in 0..N {
            hand = hand.max(rel(p[j], diff6(|d| Hand::lagrangian(sys, t, &q, &shifted(&v, j, d)), e)));
            hand = hand.max(rel(fq[j], diff6(|d| Hand::lagrangian(sys, t, &shifted(&q, j, d), &v), e)));
            for (i, row) in kv.iter().enumerate() {
                hand = hand.max(rel(row[j], diff6(|d| Hand::k(sys, t, &q, &shifted(&v, j, d))[i], e)));
            }
        }
        // The generated functions against the hand ones.
        let f = Hand::external(sys, t, &q, &v);
        let gp = NonholonomicSystem::momentum(sys, t, &qv, &vv);
        let gf = NonholonomicSystem::force(sys, t, &qv, &vv);
        let gext = sys.external_force(t, &qv, &vv);
        let gk = NonholonomicSystem::constraint(sys, t, &qv, &vv);
        let gkv = sys.constraint_v(t, &qv, &vv);
        for j in 0..N {
            generated = generated.max(rel(p[j], gp[j])).max(rel(fq[j], gf[j])).max(rel(f[j], gext[j]));
            for i in 0..M {
                generated = generated.max(rel(kv[i][j], gkv[(i, j)]));
            }
        }
        for i in 0..M {
            generated = generated.max(rel(k[i], gk[i]));
        }
        let energy: f64 = p.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>() - Hand::lagrangian(sys, t, &q, &v);
        generated = generated.max(rel(energy, sys.energy(t, &qv, &vv)));
        generated =
            generated.max(rel(Hand::lagrangian(sys, t, &q, &v), NonholonomicSystem::lagrangian(sys, t, &qv, &vv)));
        // The generated Jacobians (external force folded in, as the stepper
        // folds it) against differences of the generated values.
        let stage = |tt: f64, qq: &Vector<N>, vv: &Vector<N>| {
            let mut s = sys.stage_values(tt, qq, vv, &psi);
            s.force += sys.external_force(tt, qq, vv);
            s
        };
        let (mut vals, mut jac) = sys.stage_jacobians(t, &qv, &vv, &psi);
        let (ef, efq, efv) = sys.external_force_jacobians(t, &qv, &vv);
        vals.force += ef;
        jac.force_q += efq;
        jac.force_v += efv;
        let reference = stage(t, &qv, &vv);
        for i in 0..N {
            generated = generated.max(rel(vals.force[i], reference.force[i]));
        }
        for j in 0..N {
            for wrt_q in [true, false] {
                let at = |d: f64| {
                    let (mut qq, mut vv2) = (qv, vv);
                    if wrt_q {
                        qq[j] += d;
                    } else {
                        vv2[j] += d;
                    }
                    stage(t, &qq, &vv2)
                };
                for i in 0..N {
                    let (dp, df, dr) = (
                        diff6(|d| at(d).momentum[i], e),
                        diff6(|d| at(d).force[i], e),
                        diff6(|d| at(d).constraint_force[i], e),
                    );
                    let (jp, jf, jr) = if wrt_q {
                        (jac.momentum_q[(i, j)], jac.force_q[(i, j)], jac.constraint_force_q[(i, j)])
                    } else {
                        (jac.mass[(i, j)], jac.force_v[(i, j)], jac.constraint_force_v[(i, j)])
                    };
                    generated = generated.max(rel(jp, dp)).max(rel(jf, df)).max(rel(jr, dr));
                }
                for i in 0..M {
                    let dk = diff6(|d| at(d).constraint[i], e);
                    let jk = if wrt_q { jac.constraint_q[(i, j)] } else { jac.constraint_v[(i, j)] };
                    generated = generated.max(rel(jk, dk));
                }
            }
        }
        let td = sys.time_derivatives(t, &qv, &vv);
        for i in 0..N {
            generated = generated.max(rel(td.momentum_t[i], diff6(|d| stage(t + d, &qv, &vv).momentum[i], e)));
            // `force_t` is ∂(∇_q L)/∂t, without the external force.
            generated =
                generated.max(rel(td.force_t[i], diff6(|d| sys.stage_values(t + d, &qv, &vv, &psi).force[i], e)));
        }
        for i in 0..M {
            generated = generated.max(rel(td.constraint_t[i], diff6(|d| stage(t + d, &qv, &vv).constraint[i], e)));
        }
    }
    (hand, generated)
}

trait MomentumHand {
    fn momentum_hand(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64>;
}

impl<T: Hand> MomentumHand for T {
    fn momentum_hand(&self, t: f64, q: &[f64], v: &[f64]) -> Vec<f64> {
        Hand::momentum(self, t, q, v)
    }
}

/// Solves `A x = b` by Gaussian elimination with partial pivoting.
fn solve_dense(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col] == 0.0 || !a[pivot][col].is_finite() {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (top, rest) = a.split_at_mut(col + 1);
        let pivot_row = &top[col];
        for (offset, row) in rest.iter_mut().enumerate() {
            let f = row[col] / pivot_row[col];
            for (x, p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
            b[col + 1 + offset] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row][k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    Some(x)
}

/// The residual of eq. (6.1) in the unknowns `x = [V_1..V_s, Ψ_1..Ψ_s, v1]`,
/// written from the method's coefficient table: rows
/// `P_i − p0 − h Σ_j â_ij F_j − h Σ_j ã_ij R_j` (`F = ∇_q L + f`,
/// `R = −Kᵀ Ψ`), the same for `p1` with `b̂`, `b̃`, the `s − 1` internal
/// conditions and `k(t1, q1, v1)`.
fn residual<H: Hand>(sys: &H, tab: &TableauTable, t0: f64, q0: &[f64], v0: &[f64], h: f64, x: &[f64]) -> Vec<f64> {
    let (n, m, s) = (H::N, H::M, tab.stages);
    let vel = |j: usize| &x[j * n..(j + 1) * n];
    let psi = |j: usize| &x[s * n + j * m..s * n + (j + 1) * m];
    let v1 = &x[s * (n + m)..];
    let point = |weights: &[f64]| -> Vec<f64> {
        (0..n).map(|c| q0[c] + h * (0..s).map(|j| weights[j] * vel(j)[c]).sum::<f64>()).collect()
    };
    let times: Vec<f64> = tab.c.iter().map(|c| t0 + c * h).collect();
    let qs: Vec<Vec<f64>> = tab.a.iter().map(|row| point(row)).collect();
    let forces: Vec<Vec<f64>> = (0..s)
        .map(|j| {
            let g = sys.grad_q(times[j], &qs[j], vel(j));
            let f = sys.external(times[j], &qs[j], vel(j));
            g.iter().zip(&f).map(|(a, b)| a + b).collect()
        })
        .collect();
    let reactions: Vec<Vec<f64>> = (0..s)
        .map(|j| {
            let k = sys.kv(times[j], &qs[j], vel(j));
            (0..n).map(|c| -(0..m).map(|i| k[i][c] * psi(j)[i]).sum::<f64>()).collect()
        })
        .collect();
    let p0 = sys.momentum(t0, q0, v0);
    let mut rows = Vec::with_capacity(x.len());
    let momentum_row = |rows: &mut Vec<f64>, p: Vec<f64>, hat: &[f64], tilde: &[f64]| {
        for c in 0..n {
            let f: f64 = (0..s).map(|j| hat[j] * forces[j][c]).sum();
            let r: f64 = (0..s).map(|j| tilde[j] * reactions[j][c]).sum();
            rows.push(p[c] - p0[c] - h * f - h * r);
        }
    };
    for i in 0..s {
        momentum_row(&mut rows, sys.momentum(times[i], &qs[i], vel(i)), &tab.a_hat[i], &tab.a_tilde[i]);
    }
    let q1 = point(&tab.b);
    momentum_row(&mut rows, sys.momentum(t0 + h, &q1, v1), &tab.b_hat, &tab.b_tilde);
    for cond in &tab.conditions {
        match cond {
            ConditionEquation::Weights { omega } => {
                let ks: Vec<Vec<f64>> = (0..s).map(|j| sys.k(times[j], &qs[j], vel(j))).collect();
                rows.extend((0..m).map(|i| (0..s).map(|j| omega[j] * ks[j][i]).sum::<f64>()));
            }
            ConditionEquation::Point { c, alpha, beta } => {
                let vc: Vec<f64> = (0..n).map(|col| (0..s).map(|j| beta[j] * vel(j)[col]).sum()).collect();
                rows.extend(sys.k(t0 + c * h, &point(alpha), &vc));
            }
            ConditionEquation::MultiplierDifference { i, j } => {
                rows.extend((0..m).map(|r| psi(*i)[r] - psi(*j)[r]));
            }
        }
    }
    rows.extend(sys.k(t0 + h, &q1, v1));
    assert_eq!(rows.len(), x.len(), "{} equations for {} unknowns", rows.len(), x.len());
    rows
}

/// The solution `x` of eq. (6.1) by Newton with a central-difference
/// Jacobian, from `V_i = v0`, `Ψ_i = 0`, `v1 = v0`, iterated until the update
/// stops shrinking (below 1e-16 relative, or not smaller for three updates).
fn independent_step<H: Hand>(sys: &H, tab: &TableauTable, t0: f64, q0: &[f64], v0: &[f64], h: f64) -> Vec<f64> {
    let (m, s) = (H::M, tab.stages);
    let mut x: Vec<f64> = (0..s).flat_map(|_| v0.iter().copied()).chain(std::iter::repeat_n(0.0, s * m)).collect();
    x.extend_from_slice(v0);
    let d = x.len();
    let (mut best, mut stalls) = (f64::INFINITY, 0);
    for _ in 0..60 {
        let g = residual(sys, tab, t0, q0, v0, h, &x);
        let mut jac = vec![vec![0.0; d]; d];
        for col in 0..d {
            let e = 1e-6 * x[col].abs().max(1.0);
            let (mut up, mut down) = (x.clone(), x.clone());
            up[col] += e;
            down[col] -= e;
            let (gu, gd) = (residual(sys, tab, t0, q0, v0, h, &up), residual(sys, tab, t0, q0, v0, h, &down));
            for row in 0..d {
                jac[row][col] = (gu[row] - gd[row]) / (2.0 * e);
            }
        }
        let dx = solve_dense(jac, g.iter().map(|r| -r).collect()).expect("independent Newton: singular Jacobian");
        let size = dx.iter().zip(&x).map(|(a, b)| a.abs() / b.abs().max(1.0)).fold(0.0, f64::max);
        x.iter_mut().zip(&dx).for_each(|(a, b)| *a += b);
        if size < 1e-16 {
            break;
        }
        if size < best {
            best = size;
            stalls = 0;
        } else {
            stalls += 1;
            if stalls >= 3 {
                break;
            }
        }
    }
    x
}

/// The largest scaled distance between a step of the stepper and the
/// independent solution `x`, over `q1`, `v1`, `V` and `μ = hΨ`.
fn distance<H: Hand, const N: usize, const M: usize, const S: usize>(
    step: &spark_runtime::StepResult<N, M, S>,
    tab: &TableauTable,
    q0: &[f64],
    h: f64,
    x: &[f64],
) -> f64 {
    let (n, m, s) = (N, M, S);
    let far = super::newcomer_systems::scaled_distance;
    let mut worst = 0.0f64;
    for j in 0..s {
        for c in 0..n {
            worst = worst.max(far(step.stage_velocities[j][c], x[j * n + c]));
        }
        for i in 0..m {
            worst = worst.max(far(h * step.stage_multipliers[j][i], h * x[s * n + j * m + i]));
        }
    }
    for c in 0..n {
        let q1 = q0[c] + h * (0..s).map(|j| tab.b[j] * x[j * n + c]).sum::<f64>();
        worst = worst.max(far(step.state.q[c], q1));
        worst = worst.max(far(step.state.v[c], x[s * (n + m) + c]));
    }
    worst
}

/// Per run its label and the largest distance with the largest Newton
/// iteration count, or the failure.
type RunResults = Vec<(String, Result<(f64, usize), String>)>;

/// Steps of every method and Newton mode from `start`, each compared with
/// the independent solve from the same state; returns per run its label and
/// the largest distance, or the failure.
fn steps_against_independent<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    steps: usize,
) -> RunResults
where
    Sys: NonholonomicSystem<N, M> + Hand + Clone,
{
    [NewtonMode::Full, NewtonMode::Simplified]
        .into_iter()
        .map(|mode| {
            let label = format!("{} {method} s={S} {mode:?}", Sys::SOURCE.name);
            let tableau = Tableau::<S>::new(method).unwrap();
            let table = TableauTable::of(&tableau);
            let options = NewtonOptions { mode, ..NewtonOptions::default() };
            let mut stepper = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tableau).with_options(options);
            let (mut state, mut worst, mut iterations) = (*start, 0.0f64, 0usize);
            for k in 0..steps {
                let step = match stepper.step(&state, h) {
                    Ok(step) => step,
                    Err(e) => return (label, Err(format!("step {k}: {e}"))),
                };
                let (q0, v0): (Vec<f64>, Vec<f64>) =
                    (state.q.iter().copied().collect(), state.v.iter().copied().collect());
                let x = independent_step(sys, &table, state.t, &q0, &v0, h);
                worst = worst.max(distance::<Sys, N, M, S>(&step, &table, &q0, h, &x));
                iterations = iterations.max(step.iterations);
                state = step.state;
            }
            (label, Ok((worst, iterations)))
        })
        .collect()
}

/// Runs [`steps_against_independent`] for Gauss s = 1..3, Lobatto IIIA-B and
/// IIIA-B-D s = 2, 3 and collects the labels with their results.
macro_rules! every_method {
    ($sys:expr, $ty:ty, $n:literal, $m:literal, $start:expr, $h:expr, $steps:expr) => {{
        let mut all = Vec::new();
        all.extend(steps_against_independent::<$ty, $n, $m, 1, { $n + $m + $n }>(
            &$sys,
            Method::Gauss,
            &$start,
            $h,
            $steps,
        ));
        all.extend(steps_against_independent::<$ty, $n, $m, 2, { 2 * ($n + $m) + $n }>(
            &$sys,
            Method::Gauss,
            &$start,
            $h,
            $steps,
        ));
        all.extend(steps_against_independent::<$ty, $n, $m, 3, { 3 * ($n + $m) + $n }>(
            &$sys,
            Method::Gauss,
            &$start,
            $h,
            $steps,
        ));
        for method in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            all.extend(steps_against_independent::<$ty, $n, $m, 2, { 2 * ($n + $m) + $n }>(
                &$sys, method, &$start, $h, $steps,
            ));
            all.extend(steps_against_independent::<$ty, $n, $m, 3, { 3 * ($n + $m) + $n }>(
                &$sys, method, &$start, $h, $steps,
            ));
        }
        all
    }};
}

/// The consistent start of [`SixThree`] nearest `v = (0.4, −0.2, 0.5, 1, 0.3, 0.3)`.
fn six_three_start(sys: &SixThree) -> State<6> {
    let q0 = Vector::<6>::from([0.3, -0.2, 0.4, 0.1, 0.5, 0.2]);
    let v0 = Vector::<6>::from([0.4, -0.2, 0.5, 1.0, 0.3, 0.3]);
    let v0 = consistent_velocity(sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 1e-12 }).unwrap();
    State::new(0.0, q0, v0)
}

/// The hand formulas of the systems agree with differences of their hand
/// `L` and `k`, and the generated functions and Jacobians (external force
/// included) with the hand formulas and with differences of the generated
/// values.
#[test]
fn client_shapes_have_the_derivatives_of_their_declarations() {
    let (hand, generated) = derivative_errors::<SixThree, 6, 3>(&SixThree::default());
    eprintln!("SixThree: hand formulas vs differences {hand:.2e}, generated vs hand and differences {generated:.2e}");
    assert!(hand < 1e-9 && generated < 1e-9, "SixThree: {hand:.2e} {generated:.2e}");
    let (hand, generated) = derivative_errors::<KineticOne, 1, 0>(&KineticOne::default());
    eprintln!("KineticOne: hand formulas vs differences {hand:.2e}, generated vs hand and differences {generated:.2e}");
    assert!(hand < 1e-9 && generated < 1e-9, "KineticOne: {hand:.2e} {generated:.2e}");
    let (hand, generated) = derivative_errors::<FullTwo, 2, 2>(&FullTwo::default());
    eprintln!("FullTwo: hand formulas vs differences {hand:.2e}, generated vs hand and differences {generated:.2e}");
    assert!(hand < 1e-9 && generated < 1e-9, "FullTwo: {hand:.2e} {generated:.2e}");
}

/// The generated functions equal the hand formulas to round-off (no
/// difference quotient involved).
#[test]
fn client_shapes_evaluate_as_written_by_hand() {
    fn worst<Sys: NonholonomicSystem<N, M> + Hand, const N: usize, const M: usize>(sys: &Sys) -> f64 {
        let mut rng = Lcg(3);
        let mut worst = 0.0f64;
        for _ in 0..200 {
            let t = 3.0 * rng.next();
            let q: Vec<f64> = (0..N).map(|_| 2.0 * rng.next()).collect();
            let v: Vec<f64> = (0..N).map(|_| 2.0 * rng.next()).collect();
            let (qv, vv) = (Vector::<N>::from_column_slice(&q), Vector::<N>::from_column_slice(&v));
            let pairs = [
                (Hand::momentum(sys, t, &q, &v), NonholonomicSystem::momentum(sys, t, &qv, &vv).as_slice().to_vec()),
                (Hand::grad_q(sys, t, &q, &v), NonholonomicSystem::force(sys, t, &qv, &vv).as_slice().to_vec()),
                (Hand::external(sys, t, &q, &v), sys.external_force(t, &qv, &vv).as_slice().to_vec()),
                (Hand::k(sys, t, &q, &v), NonholonomicSystem::constraint(sys, t, &qv, &vv).as_slice().to_vec()),
            ];
            for (a, b) in pairs {
                for (x, y) in a.iter().zip(&b) {
                    worst = worst.max(rel(*x, *y));
                }
            }
        }
        worst
    }
    let (a, b) = (worst::<SixThree, 6, 3>(&SixThree::default()), worst::<KineticOne, 1, 0>(&KineticOne::default()));
    let c = worst::<FullTwo, 2, 2>(&FullTwo::default());
    eprintln!("generated vs hand, pointwise: SixThree {a:.2e}, KineticOne {b:.2e}, FullTwo {c:.2e}");
    assert!(a < 1e-14 && b < 1e-14 && c < 1e-14, "{a:.2e} {b:.2e} {c:.2e}");
}

/// Every step of Gauss s = 1..3, Lobatto IIIA-B and IIIA-B-D s = 2, 3, in
/// full and simplified Newton, equals the independent solve of eq. (6.1)
/// from the same state to 1e-13 (scaled, in `q1`, `v1`, `V`, `hΨ`).
#[test]
fn client_shapes_step_as_an_independent_solve_of_the_spark_equations() {
    let six = SixThree::default();
    let start = six_three_start(&six);
    let mut results = every_method!(six, SixThree, 6, 3, start, 0.1, 12);
    let one = KineticOne::default();
    let start = State::new(0.0, Vector::<1>::new(0.8), Vector::<1>::new(-0.6));
    results.extend(every_method!(one, KineticOne, 1, 0, start, 0.1, 12));
    let full = FullTwo::default();
    let (q0, v0) = (Vector::<2>::new(0.3, -0.2), Vector::<2>::new(0.0, 0.0));
    let v0 = consistent_velocity(&full, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 1e-12 }).unwrap();
    let start = State::new(0.0, q0, v0);
    results.extend(every_method!(full, FullTwo, 2, 2, start, 0.1, 12));
    let mut failures = Vec::new();
    let mut largest = 0.0f64;
    for (label, r) in &results {
        match r {
            Ok((d, iterations)) => {
                largest = largest.max(*d);
                if *d > 1e-13 {
                    failures.push(format!("{label}: distance {d:.2e}"));
                }
                if *iterations > 12 {
                    failures.push(format!("{label}: {iterations} Newton iterations"));
                }
            }
            Err(e) => failures.push(format!("{label}: {e}")),
        }
    }
    eprintln!("{} runs of 12 steps, largest distance to the independent solve {largest:.2e}", results.len());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A whole run of the six-coordinate system in both Newton modes keeps
/// every constraint, the rheonomic one included, to round-off, and the two
/// modes agree to the Newton tolerance.
#[test]
fn six_three_runs_keep_the_constraints_in_both_newton_modes() {
    let six = SixThree::default();
    let start = six_three_start(&six);
    let mut ends = Vec::new();
    for mode in [NewtonMode::Full, NewtonMode::Simplified] {
        let options = NewtonOptions { mode, ..NewtonOptions::default() };
        let mut stepper: spark_runtime::Stepper![SixThree, 3] =
            Stepper::new(six, Tableau::new(Method::Gauss).unwrap()).with_options(options);
        let run = stepper
            .integrate(
                start.t,
                &start.q,
                &start.v,
                Schedule::Fixed { h: 0.05, steps: 400 },
                &RunOptions::default(),
                &mut NoObserver,
            )
            .unwrap();
        assert!(run.report.max_constraint_residual < 1e-13, "{mode:?}: {:.2e}", run.report.max_constraint_residual);
        let end = run.samples.last().unwrap();
        assert!(end.q.iter().chain(end.v.iter()).all(|x| x.is_finite()));
        ends.push((end.q, end.v));
    }
    let d = (ends[0].0 - ends[1].0).amax().max((ends[0].1 - ends[1].1).amax());
    assert!(d < 1e-10, "full and simplified Newton end {d:.2e} apart");
}

/// A start on `x = 0`, where the row `K = (0, x)` of `x ẏ − a` vanishes, is
/// refused with a clear error (never a run): with `a = 0` the constraint
/// holds for every velocity and determines nothing (the saddle matrix is
/// singular); with `a ≠ 0` it cannot hold at all, and no projection exists.
#[test]
fn a_constraint_row_vanishing_at_the_start_is_a_clear_error() {
    let q0 = Vector::<2>::new(0.0, 0.3);
    let v0 = Vector::<2>::new(1.0, 0.0);
    for (a, policy) in [
        (0.0, ConsistencyPolicy::default()),
        (0.0, ConsistencyPolicy::Project { tolerance: 1e-12 }),
        (0.5, ConsistencyPolicy::default()),
        (0.5, ConsistencyPolicy::Project { tolerance: 1e-12 }),
    ] {
        let sys = VanishingRow { a };
        let checked = consistent_velocity(&sys, 0.0, &q0, &v0, policy);
        let message = match &checked {
            Ok(v) => panic!("a = {a}, {policy:?}: consistent_velocity accepted the start with v0 = {v:?}"),
            Err(e) => e.to_string(),
        };
        // A vanishing row is named as a singular saddle matrix; with `a ≠ 0`
        // the check says that v0 violates the constraint, and the
        // projection that no consistent velocity can be solved for there.
        assert!(
            matches!(
                checked,
                Err(StepError::SingularInitialState { .. }
                    | StepError::InconsistentInitialState { .. }
                    | StepError::SingularMatrix { .. })
            ),
            "a = {a}, {policy:?}: {message}"
        );
        assert!(message.contains("singular") || message.contains("inconsistent"), "a = {a}, {policy:?}: {message}");
        let mut stepper: spark_runtime::Stepper![VanishingRow, 2] =
            Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
        let options = RunOptions { consistency: policy, ..RunOptions::default() };
        match stepper.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 10 }, &options, &mut NoObserver) {
            Ok(run) => panic!("a = {a}, {policy:?}: the run succeeded: {:?}", run.samples.last()),
            Err(e) => {
                let text = e.to_string();
                eprintln!("a = {a}, {policy:?}: {text}");
                assert!(text.contains("singular") || text.contains("inconsistent"), "{text}");
            }
        }
        // A step called directly from there is refused too.
        let state = State::new(0.0, q0, v0);
        let step = stepper.step(&state, 0.1);
        assert!(step.is_err(), "a = {a}: step from x = 0 returned {:?}", step.map(|s| s.state));
    }
}

/// A run that crosses `x = 0`, where the row of `x ẏ = 0` vanishes, either
/// succeeds with finite states that keep the constraint, or fails with an
/// error: never a NaN state returned as a success.
#[test]
fn a_run_through_a_vanishing_constraint_row_is_finite_or_an_error() {
    let sys = VanishingRow { a: 0.0 };
    for (h, steps) in [(0.1, 10), (0.125, 8), (0.07, 20)] {
        let mut stepper: spark_runtime::Stepper![VanishingRow, 2] =
            Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
        let (q0, v0) = (Vector::<2>::new(0.5, 0.3), Vector::<2>::new(-1.0, 0.0));
        match stepper.integrate(0.0, &q0, &v0, Schedule::Fixed { h, steps }, &RunOptions::default(), &mut NoObserver) {
            Ok(run) => {
                for s in &run.samples {
                    assert!(s.q.iter().chain(s.v.iter()).all(|x| x.is_finite()), "h = {h}: {s:?}");
                }
                assert!(
                    run.report.max_constraint_residual < 1e-12,
                    "h = {h}: {:.2e}",
                    run.report.max_constraint_residual
                );
            }
            Err(e) => eprintln!("h = {h}: {e}"),
        }
    }
}
