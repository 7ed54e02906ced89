//! The generated derivatives of every system in `problems::systems`, checked
//! against formulas derived by hand (written out below, one function per
//! system), at random states and non-default parameters, through every trait
//! method. Central finite differences of the generated values against the
//! generated Jacobians are an extra check that also guards the hand formulas.

use problems::systems::{
    AppellHamel, ChaplyginSleigh, DoublePendulum, McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate,
    TurntableSkate,
};
use spark_runtime::{ConstraintForm, Matrix, NonholonomicSystem, Structure, Vector};

/// Everything a system provides, from the hand derivation.
struct Hand<const N: usize, const M: usize> {
    l: f64,
    /// `∇_v L`.
    p: Vector<N>,
    /// `∇_q L`.
    f: Vector<N>,
    mass: Matrix<N, N>,
    /// `(i, l) = ∂p_i/∂q_l`.
    p_q: Matrix<N, N>,
    f_q: Matrix<N, N>,
    f_v: Matrix<N, N>,
    k: Vector<M>,
    k_q: Matrix<M, N>,
    k_v: Matrix<M, N>,
    /// `kv_q[j][(i, l)] = ∂K_{j i}/∂q_l`.
    kv_q: [Matrix<N, N>; M],
    /// `kv_v[j][(i, l)] = ∂K_{j i}/∂v_l`.
    kv_v: [Matrix<N, N>; M],
    l_t: f64,
    p_t: Vector<N>,
    f_t: Vector<N>,
    k_t: Vector<M>,
}

impl<const N: usize, const M: usize> Hand<N, M> {
    fn zero() -> Self {
        Hand {
            l: 0.0,
            p: Vector::zeros(),
            f: Vector::zeros(),
            mass: Matrix::zeros(),
            p_q: Matrix::zeros(),
            f_q: Matrix::zeros(),
            f_v: Matrix::zeros(),
            k: Vector::zeros(),
            k_q: Matrix::zeros(),
            k_v: Matrix::zeros(),
            kv_q: [Matrix::zeros(); M],
            kv_v: [Matrix::zeros(); M],
            l_t: 0.0,
            p_t: Vector::zeros(),
            f_t: Vector::zeros(),
            k_t: Vector::zeros(),
        }
    }
}

/// Small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn vector<const K: usize>(&mut self, lo: f64, hi: f64) -> Vector<K> {
        Vector::from_fn(|_, _| self.uniform(lo, hi))
    }
}

fn assert_close<const R: usize, const C: usize>(what: &str, got: &Matrix<R, C>, want: &Matrix<R, C>, tol: f64) {
    let scale = 1.0 + want.amax();
    let err = (got - want).amax();
    assert!(err <= tol * scale, "{what}: error {err:e}\n got {got}\nwant {want}");
}

fn assert_scalar(what: &str, got: f64, want: f64, tol: f64) {
    assert!((got - want).abs() <= tol * (1.0 + want.abs()), "{what}: got {got}, want {want}");
}

const TOL: f64 = 1e-13;

/// `−Σ_j ψ_j d[j]`: the derivative of `R = −Kᵀψ` from the derivatives of `K`.
fn minus_psi_sum<const N: usize, const M: usize>(d: &[Matrix<N, N>; M], psi: &Vector<M>) -> Matrix<N, N> {
    let mut out = Matrix::<N, N>::zeros();
    for j in 0..M {
        out -= d[j] * psi[j];
    }
    out
}

/// Compares every trait method of `sys` with `hand` at `points`, and the
/// generated Jacobians with finite differences of the generated values.
fn check<S, const N: usize, const M: usize>(
    name: &str,
    sys: &S,
    hand: fn(&S, f64, &Vector<N>, &Vector<N>) -> Hand<N, M>,
    points: &[(f64, Vector<N>, Vector<N>, Vector<M>)],
) where
    S: NonholonomicSystem<N, M>,
{
    for (idx, (t, q, v, psi)) in points.iter().enumerate() {
        let w = |s: &str| format!("{name} point {idx}: {s}");
        let h = hand(sys, *t, q, v);
        assert_scalar(&w("lagrangian"), sys.lagrangian(*t, q, v), h.l, TOL);
        assert_scalar(&w("energy"), sys.energy(*t, q, v), h.p.dot(v) - h.l, TOL);
        assert_close(&w("momentum"), &sys.momentum(*t, q, v), &h.p, TOL);
        assert_close(&w("force"), &sys.force(*t, q, v), &h.f, TOL);
        assert_close(&w("mass_matrix"), &sys.mass_matrix(*t, q, v), &h.mass, TOL);
        assert_close(&w("constraint"), &sys.constraint(*t, q, v), &h.k, TOL);
        assert_close(&w("constraint_q"), &sys.constraint_q(*t, q, v), &h.k_q, TOL);
        assert_close(&w("constraint_v"), &sys.constraint_v(*t, q, v), &h.k_v, TOL);
        let td = sys.time_derivatives(*t, q, v);
        assert_scalar(&w("lagrangian_t"), td.lagrangian_t, h.l_t, TOL);
        assert_close(&w("momentum_t"), &td.momentum_t, &h.p_t, TOL);
        assert_close(&w("force_t"), &td.force_t, &h.f_t, TOL);
        assert_close(&w("constraint_t"), &td.constraint_t, &h.k_t, TOL);

        let r = -(h.k_v.transpose() * psi);
        let sv = sys.stage_values(*t, q, v, psi);
        let (sv2, sj) = sys.stage_jacobians(*t, q, v, psi);
        // The fused refresh of the stage-decoupled matrix, into storage
        // holding garbage (every entry must be overwritten).
        let (mut sv3, mut k_q, mut k_v) = (sv, Matrix::<M, N>::repeat(f64::NAN), Matrix::<M, N>::repeat(f64::NAN));
        sv3.momentum.fill(f64::NAN);
        sv3.force.fill(f64::NAN);
        sv3.constraint.fill(f64::NAN);
        sv3.constraint_force.fill(f64::NAN);
        sys.stage_values_and_constraint_jacobians(*t, q, v, psi, &mut sv3, &mut k_q, &mut k_v);
        assert_close(&w("fused constraint_q"), &k_q, &h.k_q, TOL);
        assert_close(&w("fused constraint_v"), &k_v, &h.k_v, TOL);
        // The residual's in-place form, into garbage as well.
        let mut sv4 = sv3;
        sv4.momentum.fill(f64::NAN);
        sv4.force.fill(f64::NAN);
        sv4.constraint.fill(f64::NAN);
        sv4.constraint_force.fill(f64::NAN);
        sys.stage_values_into(*t, q, v, psi, &mut sv4);
        for (tag, vals) in [
            ("stage_values", &sv),
            ("stage_jacobians.0", &sv2),
            ("values_and_constraint_jacobians", &sv3),
            ("stage_values_into", &sv4),
        ] {
            assert_close(&w(&format!("{tag}.momentum")), &vals.momentum, &h.p, TOL);
            assert_close(&w(&format!("{tag}.force")), &vals.force, &h.f, TOL);
            assert_close(&w(&format!("{tag}.constraint")), &vals.constraint, &h.k, TOL);
            assert_close(&w(&format!("{tag}.constraint_force")), &vals.constraint_force, &r, TOL);
        }
        assert_close(&w("momentum_q"), &sj.momentum_q, &h.p_q, TOL);
        assert_close(&w("mass"), &sj.mass, &h.mass, TOL);
        assert_close(&w("force_q"), &sj.force_q, &h.f_q, TOL);
        assert_close(&w("force_v"), &sj.force_v, &h.f_v, TOL);
        assert_close(&w("stage constraint_q"), &sj.constraint_q, &h.k_q, TOL);
        assert_close(&w("stage constraint_v"), &sj.constraint_v, &h.k_v, TOL);
        assert_close(&w("constraint_force_q"), &sj.constraint_force_q, &minus_psi_sum(&h.kv_q, psi), TOL);
        assert_close(&w("constraint_force_v"), &sj.constraint_force_v, &minus_psi_sum(&h.kv_v, psi), TOL);

        finite_differences(&w(""), sys, *t, q, v, psi);
    }
}

/// Central differences of `stage_values` in `q`, `v` and of the values in `t`.
fn finite_differences<S, const N: usize, const M: usize>(
    what: &str,
    sys: &S,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    psi: &Vector<M>,
) where
    S: NonholonomicSystem<N, M>,
{
    let eps = 1e-6;
    let tol = 1e-7;
    let (_, sj) = sys.stage_jacobians(t, q, v, psi);
    let mut fd = [Matrix::<N, N>::zeros(); 6];
    let mut fd_k = [Matrix::<M, N>::zeros(); 2];
    for l in 0..N {
        for (wrt, dir) in [(0usize, 0usize), (1, 1)] {
            let mut e = Vector::<N>::zeros();
            e[l] = eps;
            let (qp, qm, vp, vm) = if dir == 0 { (q + e, q - e, *v, *v) } else { (*q, *q, v + e, v - e) };
            let plus = sys.stage_values(t, &qp, &vp, psi);
            let minus = sys.stage_values(t, &qm, &vm, psi);
            let d = |a: Vector<N>, b: Vector<N>| (a - b) / (2.0 * eps);
            fd[wrt].set_column(l, &d(plus.momentum, minus.momentum));
            fd[2 + wrt].set_column(l, &d(plus.force, minus.force));
            fd[4 + wrt].set_column(l, &d(plus.constraint_force, minus.constraint_force));
            fd_k[wrt].set_column(l, &((plus.constraint - minus.constraint) / (2.0 * eps)));
        }
    }
    assert_close(&format!("{what} fd momentum_q"), &sj.momentum_q, &fd[0], tol);
    assert_close(&format!("{what} fd mass"), &sj.mass, &fd[1], tol);
    assert_close(&format!("{what} fd force_q"), &sj.force_q, &fd[2], tol);
    assert_close(&format!("{what} fd force_v"), &sj.force_v, &fd[3], tol);
    assert_close(&format!("{what} fd constraint_force_q"), &sj.constraint_force_q, &fd[4], tol);
    assert_close(&format!("{what} fd constraint_force_v"), &sj.constraint_force_v, &fd[5], tol);
    assert_close(&format!("{what} fd constraint_q"), &sj.constraint_q, &fd_k[0], tol);
    assert_close(&format!("{what} fd constraint_v"), &sj.constraint_v, &fd_k[1], tol);
    let td = sys.time_derivatives(t, q, v);
    let fdt = |f: &dyn Fn(f64) -> f64| (f(t + eps) - f(t - eps)) / (2.0 * eps);
    assert_scalar(&format!("{what} fd lagrangian_t"), td.lagrangian_t, fdt(&|s| sys.lagrangian(s, q, v)), tol);
    for i in 0..N {
        assert_scalar(&format!("{what} fd momentum_t"), td.momentum_t[i], fdt(&|s| sys.momentum(s, q, v)[i]), tol);
        assert_scalar(&format!("{what} fd force_t"), td.force_t[i], fdt(&|s| sys.force(s, q, v)[i]), tol);
    }
    for j in 0..M {
        assert_scalar(
            &format!("{what} fd constraint_t"),
            td.constraint_t[j],
            fdt(&|s| sys.constraint(s, q, v)[j]),
            tol,
        );
    }
}

/// `count` random states (`t ∈ [0, 3]`, `q, v ∈ [−1.5, 1.5]`, `ψ ∈ [−1, 1]`)
/// after the given fixed ones.
fn points<const N: usize, const M: usize>(
    seed: u64,
    fixed: &[(Vector<N>, Vector<N>)],
    count: usize,
) -> Vec<(f64, Vector<N>, Vector<N>, Vector<M>)> {
    let mut rng = Rng(seed);
    let mut out: Vec<_> = fixed.iter().map(|(q, v)| (0.0, *q, *v, rng.vector(-1.0, 1.0))).collect();
    for _ in 0..count {
        out.push((rng.uniform(0.0, 3.0), rng.vector(-1.5, 1.5), rng.vector(-1.5, 1.5), rng.vector(-1.0, 1.0)));
    }
    out
}

/// Sets every parameter to a random value in `[0.5, 2]` through
/// `set_parameter`, and checks the round trip through `parameter_values`.
fn randomize<S: NonholonomicSystem<N, M>, const N: usize, const M: usize>(sys: &mut S, seed: u64) {
    let mut rng = Rng(seed);
    let names = S::SOURCE.parameters;
    let values: Vec<f64> = names.iter().map(|_| rng.uniform(0.5, 2.0)).collect();
    for (n, x) in names.iter().zip(&values) {
        sys.set_parameter(n, *x).unwrap();
    }
    assert_eq!(sys.parameter_values(), values);
    assert!(sys.set_parameter("no_such_parameter", 1.0).is_err());
    if let Some(first) = names.first() {
        assert!(sys.set_parameter(first, f64::NAN).is_err());
        assert_eq!(sys.parameter_values(), values, "a rejected value must not be stored");
    }
}

fn run<S, const N: usize, const M: usize>(
    name: &str,
    mut sys: S,
    hand: fn(&S, f64, &Vector<N>, &Vector<N>) -> Hand<N, M>,
    structure: Structure,
    fixed: &[(Vector<N>, Vector<N>)],
) where
    S: NonholonomicSystem<N, M>,
{
    assert_eq!(S::STRUCTURE, structure, "{name}: structure facts");
    assert_eq!(S::SOURCE.name, name);
    check(name, &sys, hand, &points(7, fixed, 4));
    randomize(&mut sys, 11);
    check(name, &sys, hand, &points(13, &[], 4));
}

const fn structure(mass: bool, separable: bool, form: ConstraintForm, constraints_autonomous: bool) -> Structure {
    Structure {
        lagrangian_autonomous: true,
        constraints_autonomous,
        constant_mass_matrix: mass,
        separable,
        constraint_form: form,
    }
}

fn diag<const N: usize>(d: [f64; N]) -> Matrix<N, N> {
    Matrix::from_diagonal(&Vector::from(d))
}

// ---------------------------------------------------------------------------
// Hand derivations.

/// `L = ½|v|² − (x² + y²)`, `k = v₃ − y v₁`.
fn particle(_: &NonholonomicParticle, _t: f64, q: &Vector<3>, v: &Vector<3>) -> Hand<3, 1> {
    let (x, y) = (q[0], q[1]);
    let mut h = Hand::zero();
    h.l = 0.5 * v.norm_squared() - (x * x + y * y);
    h.p = *v;
    h.f = Vector::from([-2.0 * x, -2.0 * y, 0.0]);
    h.mass = diag([1.0; 3]);
    h.f_q = diag([-2.0, -2.0, 0.0]);
    h.k = Vector::from([v[2] - y * v[0]]);
    h.k_q = Matrix::from([[0.0], [-v[0]], [0.0]]);
    h.k_v = Matrix::from([[-y], [0.0], [1.0]]);
    h.kv_q[0][(0, 1)] = -1.0;
    h
}

/// `L = ½m(v₁² + v₂²) + ½I v₃² + m g x sin β`, `k = cos θ v₂ − sin θ v₁`.
fn skate(s: &Skate, _t: f64, q: &Vector<3>, v: &Vector<3>) -> Hand<3, 1> {
    let (x, th) = (q[0], q[2]);
    let (sn, cs) = th.sin_cos();
    let mut h = Hand::zero();
    h.l = 0.5 * s.m * (v[0] * v[0] + v[1] * v[1]) + 0.5 * s.inertia * v[2] * v[2] + s.m * s.g * x * s.beta.sin();
    h.p = Vector::from([s.m * v[0], s.m * v[1], s.inertia * v[2]]);
    h.f = Vector::from([s.m * s.g * s.beta.sin(), 0.0, 0.0]);
    h.mass = diag([s.m, s.m, s.inertia]);
    h.k = Vector::from([cs * v[1] - sn * v[0]]);
    h.k_q = Matrix::from([[0.0], [0.0], [-sn * v[1] - cs * v[0]]]);
    h.k_v = Matrix::from([[-sn], [cs], [0.0]]);
    h.kv_q[0][(0, 2)] = -cs;
    h.kv_q[0][(1, 2)] = -sn;
    h
}

/// `L = ½m(v₁² + v₂²) + ½I v₃² + (3/2)I_ω v₄² − 10 sin φ`,
/// `k = (v₁ − ℓ cos θ v₄, v₂ − ℓ sin θ v₄)`.
fn robot(s: &MobileRobot, _t: f64, q: &Vector<4>, v: &Vector<4>) -> Hand<4, 2> {
    let (th, phi) = (q[2], q[3]);
    let (sn, cs) = th.sin_cos();
    let l = s.ell;
    let mut h = Hand::zero();
    h.l = 0.5 * s.m * (v[0] * v[0] + v[1] * v[1]) + 0.5 * s.inertia * v[2] * v[2] + 1.5 * s.inertia_wheel * v[3] * v[3]
        - 10.0 * phi.sin();
    h.p = Vector::from([s.m * v[0], s.m * v[1], s.inertia * v[2], 3.0 * s.inertia_wheel * v[3]]);
    h.f = Vector::from([0.0, 0.0, 0.0, -10.0 * phi.cos()]);
    h.mass = diag([s.m, s.m, s.inertia, 3.0 * s.inertia_wheel]);
    h.f_q[(3, 3)] = 10.0 * phi.sin();
    h.k = Vector::from([v[0] - l * cs * v[3], v[1] - l * sn * v[3]]);
    h.k_q[(0, 2)] = l * sn * v[3];
    h.k_q[(1, 2)] = -l * cs * v[3];
    h.k_v = Matrix::from([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [-l * cs, -l * sn]]);
    h.kv_q[0][(3, 2)] = l * sn;
    h.kv_q[1][(3, 2)] = -l * cs;
    h
}

/// `L = ½|v|² − U`, `U = ½(|q|² + q₅²q₆² + q₂²q₅² + q₃²q₆² + q₄²q₇²)`,
/// `k = v₁ + q₅v₅ + q₆v₆ + q₇v₇` (indices 1-based in the formulas).
fn mclachlan(_: &McLachlanPerlmutter7, _t: f64, q: &Vector<7>, v: &Vector<7>) -> Hand<7, 1> {
    let [q1, q2, q3, q4, q5, q6, q7] = [q[0], q[1], q[2], q[3], q[4], q[5], q[6]];
    let u = 0.5 * (q.norm_squared() + q5 * q5 * q6 * q6 + q2 * q2 * q5 * q5 + q3 * q3 * q6 * q6 + q4 * q4 * q7 * q7);
    let grad_u = Vector::from([
        q1,
        q2 + q2 * q5 * q5,
        q3 + q3 * q6 * q6,
        q4 + q4 * q7 * q7,
        q5 + q5 * q6 * q6 + q2 * q2 * q5,
        q6 + q5 * q5 * q6 + q3 * q3 * q6,
        q7 + q4 * q4 * q7,
    ]);
    let mut hess = diag([
        1.0,
        1.0 + q5 * q5,
        1.0 + q6 * q6,
        1.0 + q7 * q7,
        1.0 + q6 * q6 + q2 * q2,
        1.0 + q5 * q5 + q3 * q3,
        1.0 + q4 * q4,
    ]);
    for (i, j, x) in [(1, 4, 2.0 * q2 * q5), (2, 5, 2.0 * q3 * q6), (3, 6, 2.0 * q4 * q7), (4, 5, 2.0 * q5 * q6)] {
        hess[(i, j)] = x;
        hess[(j, i)] = x;
    }
    let mut h = Hand::zero();
    h.l = 0.5 * v.norm_squared() - u;
    h.p = *v;
    h.f = -grad_u;
    h.mass = diag([1.0; 7]);
    h.f_q = -hess;
    h.k = Vector::from([v[0] + q5 * v[4] + q6 * v[5] + q7 * v[6]]);
    h.k_q = Matrix::from([[0.0], [0.0], [0.0], [0.0], [v[4]], [v[5]], [v[6]]]);
    h.k_v = Matrix::from([[1.0], [0.0], [0.0], [0.0], [q5], [q6], [q7]]);
    for i in 4..7 {
        h.kv_q[0][(i, i)] = 1.0;
    }
    h
}

/// `L = ½m(v₁² + v₂²) + ½I v₃²`, `ω(t) = ω₀(1 + ε sin νt)`,
/// `k = cos θ (v₂ − ω x) − sin θ (v₁ + ω y)`.
fn turntable(s: &TurntableSkate, t: f64, q: &Vector<3>, v: &Vector<3>) -> Hand<3, 1> {
    let (x, y, th) = (q[0], q[1], q[2]);
    let (sn, cs) = th.sin_cos();
    let w = s.omega0 * (1.0 + s.eps * (s.nu * t).sin());
    let w_t = s.omega0 * s.eps * s.nu * (s.nu * t).cos();
    let mut h = Hand::zero();
    h.l = 0.5 * s.m * (v[0] * v[0] + v[1] * v[1]) + 0.5 * s.inertia * v[2] * v[2];
    h.p = Vector::from([s.m * v[0], s.m * v[1], s.inertia * v[2]]);
    h.mass = diag([s.m, s.m, s.inertia]);
    h.k = Vector::from([cs * (v[1] - w * x) - sn * (v[0] + w * y)]);
    h.k_q = Matrix::from([[-w * cs], [-w * sn], [-sn * (v[1] - w * x) - cs * (v[0] + w * y)]]);
    h.k_v = Matrix::from([[-sn], [cs], [0.0]]);
    h.kv_q[0][(0, 2)] = -cs;
    h.kv_q[0][(1, 2)] = -sn;
    h.k_t = Vector::from([-w_t * (x * cs + y * sn)]);
    h
}

/// `L = ½m|v|² − m g z`, `k = v₃² − a²(v₁² + v₂²)`.
fn appell(s: &AppellHamel, _t: f64, q: &Vector<3>, v: &Vector<3>) -> Hand<3, 1> {
    let a2 = s.a * s.a;
    let mut h = Hand::zero();
    h.l = 0.5 * s.m * v.norm_squared() - s.m * s.g * q[2];
    h.p = *v * s.m;
    h.f = Vector::from([0.0, 0.0, -s.m * s.g]);
    h.mass = diag([s.m; 3]);
    h.k = Vector::from([v[2] * v[2] - a2 * (v[0] * v[0] + v[1] * v[1])]);
    h.k_v = Matrix::from([[-2.0 * a2 * v[0]], [-2.0 * a2 * v[1]], [2.0 * v[2]]]);
    h.kv_v[0] = diag([-2.0 * a2, -2.0 * a2, 2.0]);
    h
}

/// `L = ½m(v₁² + v₂² + a²v₃² + 2a v₃(−v₁ sin θ + v₂ cos θ)) + ½I v₃²
/// + m g sin α (x + a cos θ)`, `k = −sin θ v₁ + cos θ v₂`.
fn sleigh(s: &ChaplyginSleigh, _t: f64, q: &Vector<3>, v: &Vector<3>) -> Hand<3, 1> {
    let (x, th) = (q[0], q[2]);
    let (sn, cs) = th.sin_cos();
    let (m, a, i) = (s.m, s.a, s.inertia);
    let mg = m * s.g * s.alpha.sin();
    let side = -v[0] * sn + v[1] * cs;
    let fwd = -v[0] * cs - v[1] * sn; // ∂side/∂θ
    let mut h = Hand::zero();
    h.l = 0.5 * m * (v[0] * v[0] + v[1] * v[1] + a * a * v[2] * v[2] + 2.0 * a * v[2] * side)
        + 0.5 * i * v[2] * v[2]
        + mg * (x + a * cs);
    h.p = Vector::from([m * (v[0] - a * v[2] * sn), m * (v[1] + a * v[2] * cs), (m * a * a + i) * v[2] + m * a * side]);
    h.f = Vector::from([mg, 0.0, m * a * v[2] * fwd - mg * a * sn]);
    h.mass = Matrix::from([[m, 0.0, -m * a * sn], [0.0, m, m * a * cs], [-m * a * sn, m * a * cs, m * a * a + i]]);
    h.p_q[(0, 2)] = -m * a * v[2] * cs;
    h.p_q[(1, 2)] = -m * a * v[2] * sn;
    h.p_q[(2, 2)] = m * a * fwd;
    h.f_q[(2, 2)] = m * a * v[2] * (v[0] * sn - v[1] * cs) - mg * a * cs;
    h.f_v[(2, 0)] = -m * a * v[2] * cs;
    h.f_v[(2, 1)] = -m * a * v[2] * sn;
    h.f_v[(2, 2)] = m * a * fwd;
    h.k = Vector::from([side]);
    h.k_q = Matrix::from([[0.0], [0.0], [fwd]]);
    h.k_v = Matrix::from([[-sn], [cs], [0.0]]);
    h.kv_q[0][(0, 2)] = -cs;
    h.kv_q[0][(1, 2)] = -sn;
    h
}

/// `L = ½A v₁² + ½B v₂² + C cos(θ₁ − θ₂) v₁v₂ + (m₁ + m₂) g ℓ₁ cos θ₁ + m₂ g ℓ₂ cos θ₂`
/// with `A = (m₁ + m₂)ℓ₁²`, `B = m₂ℓ₂²`, `C = m₂ℓ₁ℓ₂`.
fn pendulum(s: &DoublePendulum, _t: f64, q: &Vector<2>, v: &Vector<2>) -> Hand<2, 0> {
    let big_a = (s.m1 + s.m2) * s.l1 * s.l1;
    let big_b = s.m2 * s.l2 * s.l2;
    let c = s.m2 * s.l1 * s.l2;
    let (sd, cd) = (q[0] - q[1]).sin_cos();
    let g1 = (s.m1 + s.m2) * s.g * s.l1;
    let g2 = s.m2 * s.g * s.l2;
    let mut h = Hand::zero();
    h.l = 0.5 * big_a * v[0] * v[0]
        + 0.5 * big_b * v[1] * v[1]
        + c * cd * v[0] * v[1]
        + g1 * q[0].cos()
        + g2 * q[1].cos();
    h.p = Vector::from([big_a * v[0] + c * cd * v[1], big_b * v[1] + c * cd * v[0]]);
    h.f = Vector::from([-c * sd * v[0] * v[1] - g1 * q[0].sin(), c * sd * v[0] * v[1] - g2 * q[1].sin()]);
    h.mass = Matrix::from([[big_a, c * cd], [c * cd, big_b]]);
    h.p_q = Matrix::from([[-c * sd * v[1], -c * sd * v[0]], [c * sd * v[1], c * sd * v[0]]]);
    h.f_q = Matrix::from([
        [-c * cd * v[0] * v[1] - g1 * q[0].cos(), c * cd * v[0] * v[1]],
        [c * cd * v[0] * v[1], -c * cd * v[0] * v[1] - g2 * q[1].cos()],
    ]);
    h.f_v = Matrix::from([[-c * sd * v[1], c * sd * v[1]], [-c * sd * v[0], c * sd * v[0]]]);
    h
}

// ---------------------------------------------------------------------------

#[test]
fn nonholonomic_particle() {
    let paper = (Vector::from([1.0, 0.0, 0.0]), Vector::from([0.0, 1.0, 0.0]));
    let st = structure(true, true, ConstraintForm::Linear, true);
    run("NonholonomicParticle", NonholonomicParticle::default(), particle, st, &[paper]);
}

#[test]
fn skate_on_inclined_plane() {
    let paper = (Vector::zeros(), Vector::from([0.0, 0.0, 1.0]));
    let sys = Skate::default();
    assert_eq!(sys.parameter_values(), vec![1.0, 1.0, 1.0, std::f64::consts::FRAC_PI_2]);
    run("Skate", sys, skate, structure(true, true, ConstraintForm::Linear, true), &[paper]);
}

#[test]
fn mobile_robot() {
    let paper = (Vector::zeros(), Vector::from([1.0, 0.0, 0.0, 1.0]));
    run("MobileRobot", MobileRobot::default(), robot, structure(true, true, ConstraintForm::Linear, true), &[paper]);
}

#[test]
fn mclachlan_perlmutter_7() {
    // The paper's j = 0 and j = 5 states (J = 9).
    let state = |j: f64| {
        let a = (j * std::f64::consts::PI / 18.0).cos();
        let b = (j * std::f64::consts::PI / 18.0).sin();
        (Vector::from([a, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]), Vector::from([0.0, b, 0.0, 0.0, 0.0, 0.0, 0.0]))
    };
    let sys = McLachlanPerlmutter7::default();
    for j in [0.0, 5.0] {
        let (q, v) = state(j);
        assert_scalar("paper energy E0", sys.energy(0.0, &q, &v), 3.06, 1e-14);
    }
    let st = structure(true, true, ConstraintForm::Linear, true);
    run("McLachlanPerlmutter7", sys, mclachlan, st, &[state(0.0), state(5.0)]);
}

#[test]
fn turntable_skate() {
    let st = structure(true, true, ConstraintForm::Affine, false);
    run("TurntableSkate", TurntableSkate::default(), turntable, st, &[]);
}

#[test]
fn appell_hamel() {
    let sys = AppellHamel::default();
    let state = (Vector::from([0.0, 0.0, 1.0]), Vector::from([1.0, 0.0, sys.a]));
    // The saddle-point matrix [[M, Kᵀ], [K, 0]] is regular at the documented state.
    let (q, v) = state;
    let mut kkt = Matrix::<4, 4>::zeros();
    kkt.fixed_view_mut::<3, 3>(0, 0).copy_from(&sys.mass_matrix(0.0, &q, &v));
    let k = sys.constraint_v(0.0, &q, &v);
    kkt.fixed_view_mut::<1, 3>(3, 0).copy_from(&k);
    kkt.fixed_view_mut::<3, 1>(0, 3).copy_from(&k.transpose());
    assert!(kkt.determinant().abs() > 0.1, "saddle-point matrix singular: {kkt}");
    assert_scalar("constraint satisfied", sys.constraint(0.0, &q, &v)[0], 0.0, 1e-15);
    run("AppellHamel", sys, appell, structure(true, true, ConstraintForm::Nonlinear, true), &[state]);
}

#[test]
fn chaplygin_sleigh() {
    let st = structure(false, false, ConstraintForm::Linear, true);
    run("ChaplyginSleigh", ChaplyginSleigh::default(), sleigh, st, &[]);
}

#[test]
fn double_pendulum() {
    let st = structure(false, false, ConstraintForm::None, true);
    run("DoublePendulum", DoublePendulum::default(), pendulum, st, &[]);
}
