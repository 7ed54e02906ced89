//! Unit tests of the stepper against hand-written systems: exact Jacobian vs
//! finite differences, the paper's closed forms (§7.1–7.3, eqs. 7.2, 7.3),
//! reversibility, error paths and the driver.

// Stage loops index several parallel arrays (c, a, b, stage values) with one index.
#![allow(clippy::needless_range_loop)]

use crate::fixtures::paper::{General, MobileRobot, MpParticles, Particle, Skate};
use crate::*;
use nalgebra::{DMatrix, DVector};

type V<const N: usize> = Vector<N>;

fn tab<const S: usize>(m: Method) -> Tableau<S> {
    Tableau::new(m).unwrap()
}

// ---------------------------------------------------------------- Jacobian

/// Unknowns `z` away from the solution, so every block of the Newton
/// matrix is exercised (shared with the stage-decoupled matrix's tests).
pub(crate) fn probe<const D: usize>() -> Vector<D> {
    Vector::<D>::from_fn(|i, _| 0.3 + 0.17 * ((i * 7 + 3) % 11) as f64 / 11.0 - 0.1 * (i % 3) as f64)
}

/// Calls `$check::<_, 2, 1, S, D>(General::default(), method, $state, $h)`
/// for every coefficient family on the general test system, at the stage
/// counts the derivative tests use.
macro_rules! on_general_for_every_family {
    ($check:ident, $state:expr, $h:expr) => {{
        use $crate::fixtures::paper::General;
        use $crate::Method;
        $check::<_, 2, 1, 1, 5>(General::default(), Method::Gauss, $state, $h);
        $check::<_, 2, 1, 2, 8>(General::default(), Method::Gauss, $state, $h);
        $check::<_, 2, 1, 3, 11>(General::default(), Method::Gauss, $state, $h);
        $check::<_, 2, 1, 3, 11>(General::default(), Method::LobattoIIIAB, $state, $h);
        $check::<_, 2, 1, 4, 14>(General::default(), Method::LobattoIIIABD, $state, $h);
        $check::<_, 2, 1, 1, 5>(General::default(), Method::SymplecticEulerI, $state, $h);
        $check::<_, 2, 1, 1, 5>(General::default(), Method::SymplecticEulerII, $state, $h);
        $check::<_, 2, 1, 2, 8>(General::default(), Method::ModifiedLobattoIIIAB, $state, $h);
        $check::<_, 2, 1, 2, 8>(General::default(), Method::LobattoIIIBALda, $state, $h);
    }};
}
pub(crate) use on_general_for_every_family;

/// Exact Newton Jacobian against central differences of the residual at a
/// point away from the solution (shared with the effects tests).
pub(crate) fn check_jacobian<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    state: State<N>,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M>,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, tab(method));
    let z = probe::<D>();
    let (_, jac) = st.residual_and_jacobian(&state, h, &z);
    let mut worst: f64 = 0.0;
    for col in 0..D {
        let eps = 1e-6 * (1.0 + z[col].abs());
        let (mut zp, mut zm) = (z, z);
        zp[col] += eps;
        zm[col] -= eps;
        let fd = (st.residual_at(&state, h, &zp) - st.residual_at(&state, h, &zm)) / (2.0 * eps);
        for row in 0..D {
            worst = worst.max((fd[row] - jac[(row, col)]).abs() / (1.0 + jac[(row, col)].abs()));
        }
    }
    assert!(worst < 1e-7, "{method} s={S} on {}: Jacobian vs central differences {worst:e}", Sys::SOURCE.name);
}

#[test]
fn exact_jacobian_matches_finite_differences() {
    let g = State::new(0.4, V::<2>::new(0.3, -0.2), V::<2>::new(0.5, 0.1));
    on_general_for_every_family!(check_jacobian, g, 0.3);
    let r = State::new(0.0, V::<4>::new(0.1, 0.2, 0.7, 0.3), V::<4>::new(1.0, 0.0, 0.5, 1.0));
    check_jacobian::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::LobattoIIIABD, r, -0.2);
    let s = State::new(0.0, V::<3>::new(0.1, 0.2, 0.7), V::<3>::new(0.3, 0.1, 1.0));
    check_jacobian::<_, 3, 1, 2, 11>(Skate::default(), Method::Gauss, s, 0.1);
}

// ---------------------------------------------------------------- closed forms

/// Newton with a central-difference Jacobian, for the closed forms (shares
/// nothing with the stepper's solver).
fn fd_newton(f: impl Fn(&DVector<f64>) -> DVector<f64>, x0: DVector<f64>) -> DVector<f64> {
    let mut x = x0;
    for _ in 0..50 {
        let g = f(&x);
        let n = x.len();
        let mut j = DMatrix::zeros(n, n);
        for c in 0..n {
            let eps = 1e-7 * (1.0 + x[c].abs());
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += eps;
            xm[c] -= eps;
            j.set_column(c, &((f(&xp) - f(&xm)) / (2.0 * eps)));
        }
        let dx = j.lu().solve(&g).unwrap();
        x -= &dx;
        if dx.amax() < 1e-16 * (1.0 + x.amax()) {
            break;
        }
    }
    x
}

/// `L = ½vᵀMv − U(q)`, `k = K(q)v + b(q)` pieces of a system, read from the
/// trait at the point where each is needed (M is constant).
struct Mech<'a, Sys, const N: usize, const M: usize>(&'a Sys);

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize> Mech<'_, Sys, N, M> {
    fn m(&self) -> Matrix<N, N> {
        self.0.mass_matrix(0.0, &V::zeros(), &V::zeros())
    }
    fn grad_u(&self, q: &V<N>) -> V<N> {
        -self.0.force(0.0, q, &V::zeros())
    }
    fn k(&self, q: &V<N>) -> Matrix<M, N> {
        self.0.constraint_v(0.0, q, &V::zeros())
    }
    fn b(&self, q: &V<N>) -> V<M> {
        self.0.constraint(0.0, q, &V::zeros())
    }
}

fn dv<const N: usize>(x: &DVector<f64>, at: usize) -> V<N> {
    V::<N>::from_fn(|i, _| x[at + i])
}

/// The paper's closed forms for one step; returns `(q₁, v₁)`.
fn closed_form<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    method: Method,
    q0: &V<N>,
    v0: &V<N>,
    h: f64,
) -> (V<N>, V<N>)
where
    Sys: NonholonomicSystem<N, M>,
{
    let s = Mech(sys);
    let mm = s.m();
    let x0 = DVector::from_iterator(N + M, v0.iter().copied().chain(std::iter::repeat_n(0.0, M)));
    let cat = |a: V<N>, b: V<M>| DVector::from_iterator(N + M, a.iter().copied().chain(b.iter().copied()));
    match method {
        // §7.1: q₁ = q₀ + hv₁, Mv₁ = Mv₀ − h(∇U(q₀) + K(q₀)ᵀΨ), K(q₁)v₁ + b(q₁) = 0.
        Method::SymplecticEulerI => {
            let x = fd_newton(
                |x| {
                    let (v1, psi) = (dv::<N>(x, 0), dv::<M>(x, N));
                    let q1 = q0 + h * v1;
                    cat(mm * (v1 - v0) + h * (s.grad_u(q0) + s.k(q0).transpose() * psi), s.k(&q1) * v1 + s.b(&q1))
                },
                x0,
            );
            let v1 = dv::<N>(&x, 0);
            (q0 + h * v1, v1)
        }
        // §7.2: q₁ = q₀ + hv₀, Mv₁ = Mv₀ − h(∇U(q₁) + K(q₁)ᵀΨ), K(q₁)v₁ + b(q₁) = 0.
        Method::SymplecticEulerII => {
            let q1 = q0 + h * v0;
            let x = fd_newton(
                |x| {
                    let (v1, psi) = (dv::<N>(x, 0), dv::<M>(x, N));
                    cat(mm * (v1 - v0) + h * (s.grad_u(&q1) + s.k(&q1).transpose() * psi), s.k(&q1) * v1 + s.b(&q1))
                },
                x0,
            );
            (q1, dv::<N>(&x, 0))
        }
        // §7.3: q₁ = q₀ + (h/2)(v₀+v₁), Mv₁ = Mv₀ − h∇U(q̄) − hK(q̄)ᵀΨ, K(q₁)v₁ + b(q₁) = 0.
        Method::Gauss => {
            let x = fd_newton(
                |x| {
                    let (v1, psi) = (dv::<N>(x, 0), dv::<M>(x, N));
                    let q1 = q0 + 0.5 * h * (v0 + v1);
                    let qm = 0.5 * (q0 + q1);
                    cat(mm * (v1 - v0) + h * s.grad_u(&qm) + h * s.k(&qm).transpose() * psi, s.k(&q1) * v1 + s.b(&q1))
                },
                x0,
            );
            let v1 = dv::<N>(&x, 0);
            (q0 + 0.5 * h * (v0 + v1), v1)
        }
        // (7.2) and, for the §8.4 variant, its condition replaced by
        // K(q₀ + (h/2)V₁)V₁ + b(q₀ + (h/2)V₁) = 0.
        Method::LobattoIIIAB | Method::ModifiedLobattoIIIAB => {
            let x = fd_newton(
                |x| {
                    let (v, psi) = (dv::<N>(x, 0), dv::<M>(x, N));
                    let q1 = q0 + h * v;
                    let cond = if method == Method::LobattoIIIAB {
                        0.5 * (s.k(q0) * v + s.b(q0)) + 0.5 * (s.k(&q1) * v + s.b(&q1))
                    } else {
                        let qm = q0 + 0.5 * h * v;
                        s.k(&qm) * v + s.b(&qm)
                    };
                    cat(mm * (v - v0) + 0.5 * h * (s.grad_u(q0) + s.k(q0).transpose() * psi), cond)
                },
                x0.clone(),
            );
            let big_v = dv::<N>(&x, 0);
            let q1 = q0 + h * big_v;
            // Mv₁ + K(q₁)ᵀ(h/2 Ψ₂) = MV₁ − (h/2)∇U(q₁), K(q₁)v₁ = −b(q₁): linear.
            let y = fd_newton(
                |y| {
                    let (v1, mu) = (dv::<N>(y, 0), dv::<M>(y, N));
                    cat(
                        mm * v1 + s.k(&q1).transpose() * mu - mm * big_v + 0.5 * h * s.grad_u(&q1),
                        s.k(&q1) * v1 + s.b(&q1),
                    )
                },
                x0,
            );
            (q1, dv::<N>(&y, 0))
        }
        // (7.3): Q₁ = q₀ + (h/2)v₀, Mv₁ = Mv₀ − h(∇U(Q₁) + K(Q₁)ᵀΨ), q₁ = q₀ + (h/2)(v₀+v₁), K(q₁)v₁ + b(q₁) = 0.
        Method::LobattoIIIBALda => {
            let qm = q0 + 0.5 * h * v0;
            let x = fd_newton(
                |x| {
                    let (v1, psi) = (dv::<N>(x, 0), dv::<M>(x, N));
                    let q1 = q0 + 0.5 * h * (v0 + v1);
                    cat(mm * (v1 - v0) + h * (s.grad_u(&qm) + s.k(&qm).transpose() * psi), s.k(&q1) * v1 + s.b(&q1))
                },
                x0,
            );
            let v1 = dv::<N>(&x, 0);
            (q0 + 0.5 * h * (v0 + v1), v1)
        }
        Method::LobattoIIIABD => unreachable!("no closed form in the paper"),
    }
}

fn compare_closed_form<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    q0: V<N>,
    v0: V<N>,
    h: f64,
    steps: usize,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tab(method));
    let mut state = State::new(0.0, q0, v0);
    let (mut q, mut v) = (q0, v0);
    for k in 0..steps {
        state = st.step(&state, h).unwrap().state;
        (q, v) = closed_form(&sys, method, &q, &v, h);
        let err = (state.q - q).amax().max((state.v - v).amax());
        assert!(err <= 1e-13, "{method} on {} step {k}: SPARK vs closed form differ by {err:e}", Sys::SOURCE.name);
    }
}

#[test]
fn s1_methods_and_lobatto_s2_match_the_paper_closed_forms() {
    let (pq, pv) = (V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 1.0, 0.0));
    let (sq, sv) = (V::<3>::new(0.0, 0.0, 0.0), V::<3>::new(0.0, 0.0, 1.0));
    let (rq, rv) = (V::<4>::zeros(), V::<4>::new(1.0, 0.0, 0.5, 1.0));
    for m in [Method::SymplecticEulerI, Method::SymplecticEulerII, Method::Gauss] {
        compare_closed_form::<_, 3, 1, 1, 7>(Particle, m, pq, pv, 0.2, 20);
        compare_closed_form::<_, 3, 1, 1, 7>(Skate::default(), m, sq, sv, 0.1, 20);
        compare_closed_form::<_, 4, 2, 1, 10>(MobileRobot::default(), m, rq, rv, 0.2, 20);
    }
    for m in [Method::LobattoIIIAB, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
        compare_closed_form::<_, 3, 1, 2, 11>(Particle, m, pq, pv, 0.2, 20);
        compare_closed_form::<_, 3, 1, 2, 11>(Skate::default(), m, sq, sv, 0.1, 20);
        compare_closed_form::<_, 4, 2, 2, 16>(MobileRobot::default(), m, rq, rv, 0.2, 20);
        let mq = V::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
        let mv = V::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]);
        compare_closed_form::<_, 7, 1, 2, 23>(MpParticles, m, mq, mv, 0.05, 20);
    }
}

// ---------------------------------------------------------------- reversibility

fn round_trip<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, tab(method));
    let mut s = start;
    for _ in 0..steps {
        s = st.step(&s, h).unwrap().state;
    }
    for _ in 0..steps {
        s = st.step(&s, -h).unwrap().state;
    }
    (s.q - start.q).amax().max((s.v - start.v).amax())
}

#[test]
fn symmetric_methods_retrace_their_steps_and_euler_methods_do_not() {
    let skate = State::new(0.0, V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0));
    let robot = State::new(0.0, V::<4>::zeros(), V::<4>::new(1.0, 0.0, 0.5, 1.0));
    let general = State::new(0.0, V::<2>::new(0.3, -0.2), V::<2>::new(0.5, 0.15 + 0.05 * 0.25));
    let mut g = general;
    g.v[1] = g.q[0] * g.v[0] + 0.1 * g.v[0] * g.v[0];
    for m in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
        if m == Method::Gauss {
            assert!(round_trip::<_, 3, 1, 1, 7>(Skate::default(), m, skate, 0.1, 50) <= 1e-12);
        }
        assert!(round_trip::<_, 3, 1, 2, 11>(Skate::default(), m, skate, 0.1, 50) <= 1e-12, "{m}");
        assert!(round_trip::<_, 4, 2, 3, 22>(MobileRobot::default(), m, robot, 0.2, 50) <= 1e-12, "{m}");
        assert!(round_trip::<_, 2, 1, 3, 11>(General::default(), m, g, 0.1, 30) <= 1e-12, "{m}");
    }
    for m in [Method::SymplecticEulerI, Method::SymplecticEulerII] {
        let d = round_trip::<_, 4, 2, 1, 10>(MobileRobot::default(), m, robot, 0.2, 50);
        assert!(d > 1e-6, "{m} is not symmetric, yet it returned to the start within {d:e}");
    }
}

// ---------------------------------------------------------------- Newton and errors

#[test]
fn simplified_newton_reaches_the_same_solution() {
    let start = State::new(0.0, V::<4>::zeros(), V::<4>::new(1.0, 0.0, 0.5, 1.0));
    let mut full = Stepper::<_, 4, 2, 3, 22>::new(MobileRobot::default(), tab(Method::Gauss));
    let opts = NewtonOptions { mode: NewtonMode::Simplified, ..NewtonOptions::default() };
    let mut simp = Stepper::<_, 4, 2, 3, 22>::new(MobileRobot::default(), tab(Method::Gauss)).with_options(opts);
    let (mut a, mut b) = (start, start);
    let (mut ia, mut ib) = (0, 0);
    for _ in 0..40 {
        let ra = full.step(&a, 0.2).unwrap();
        let rb = simp.step(&b, 0.2).unwrap();
        (a, b) = (ra.state, rb.state);
        ia += ra.iterations;
        ib += rb.iterations;
    }
    assert!((a.q - b.q).amax() < 1e-12 && (a.v - b.v).amax() < 1e-12);
    assert!(ib >= ia, "simplified Newton ({ib}) should not need fewer iterations than full Newton ({ia})");
}

#[test]
fn failures_are_typed_errors() {
    let mut st = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tab(Method::Gauss));
    let s = State::new(0.0, V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0));
    assert!(matches!(st.step(&s, 0.0), Err(StepError::InvalidStep { .. })));
    assert!(matches!(st.step(&s, f64::NAN), Err(StepError::InvalidStep { .. })));
    let bad = State::new(0.0, V::<3>::new(f64::NAN, 0.0, 0.0), s.v);
    assert!(matches!(st.step(&bad, 0.1), Err(StepError::InvalidStep { .. })));
    for x in [f64::INFINITY, f64::NEG_INFINITY] {
        let bad_q = State::new(0.0, V::<3>::new(0.0, x, 0.0), s.v);
        let bad_v = State::new(0.0, s.q, V::<3>::new(0.0, 0.0, x));
        for bad in [bad_q, bad_v] {
            assert!(matches!(st.step(&bad, 0.1), Err(StepError::InvalidStep { .. })), "{bad:?}");
        }
    }
    // A continued step passes the checks, a non-finite copy of its end does not.
    let end = st.step(&s, 0.1).unwrap().state;
    assert!(st.step(&end, 0.1).is_ok());
    let bad = State::new(end.t, end.q, V::<3>::new(end.v[0], f64::NAN, end.v[2]));
    assert!(matches!(st.step(&bad, 0.1), Err(StepError::InvalidStep { .. })));
    // A huge step on the stiff quartic MP potential: Newton cannot converge.
    let mut mp = Stepper::<_, 7, 1, 2, 23>::new(MpParticles, tab(Method::Gauss));
    let q = V::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let v = V::<7>::from_row_slice(&[0.0, 5.0, 3.0, 0.0, 0.0, 0.0, 0.0]);
    let err = mp.step(&State::new(0.0, q, v), 40.0).unwrap_err();
    let hist = err.history().expect("Newton failures carry their history");
    assert!(!hist.is_empty(), "{err}");
    assert!(matches!(
        err,
        StepError::Diverged { .. }
            | StepError::MaxIterations { .. }
            | StepError::SingularMatrix { .. }
            | StepError::NonFinite { .. }
    ));
    // A singular Newton matrix: zero mass for the skate's heading, whose
    // velocity the message names by its coordinate.
    let mut sk = Stepper::<_, 3, 1, 2, 11>::new(Skate { inertia: 0.0, ..Skate::default() }, tab(Method::Gauss));
    let err = sk.step(&s, 0.1).unwrap_err();
    let StepError::SingularMatrix { detail, .. } = &err else { panic!("{err:?}") };
    assert!(detail.contains("the velocity of `theta`"), "{err}");
}

#[test]
fn inconsistent_initial_velocity_is_rejected_or_projected() {
    let sys = MobileRobot::default();
    let q0 = V::<4>::new(0.0, 0.0, 0.3, 0.0);
    let v0 = V::<4>::new(1.0, 0.5, 0.5, 1.0);
    let err = consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::Error { tolerance: 1e-12 }).unwrap_err();
    assert!(matches!(err, StepError::InconsistentInitialState { .. }));
    let v = consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 1e-12 }).unwrap();
    assert!(sys.constraint(0.0, &q0, &v).amax() < 1e-15);
    // Optimality: W(v − v₀) lies in the range of Kᵀ, i.e. is orthogonal to ker K.
    let w = sys.mass_matrix(0.0, &q0, &v0);
    let k = sys.constraint_v(0.0, &q0, &v0);
    let r = w * (v - v0);
    let lambda = (k * k.transpose()).try_inverse().unwrap() * (k * r);
    assert!((r - k.transpose() * lambda).amax() < 1e-14);
    // Nonlinear constraint: Newton projection.
    let g = General::default();
    let (q, gv0) = (V::<2>::new(0.3, 0.1), V::<2>::new(0.7, 0.0));
    let v = consistent_velocity(&g, 0.2, &q, &gv0, ConsistencyPolicy::Project { tolerance: 0.0 }).unwrap();
    assert!(g.constraint(0.2, &q, &v).amax() < 1e-15);
    // The driver projects by option and reports it.
    let mut st = Stepper::<_, 4, 2, 2, 16>::new(sys, tab(Method::LobattoIIIABD));
    let opts = RunOptions { consistency: ConsistencyPolicy::Project { tolerance: 1e-12 }, ..RunOptions::default() };
    let tr = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 10 }, &opts, &mut NoObserver).unwrap();
    assert!(tr.report.projected_initial_velocity && tr.report.max_constraint_residual <= 1e-14);
    let e = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 10 }, &RunOptions::default(), &mut NoObserver);
    assert!(matches!(e, Err(IntegrationError::Initial(StepError::InconsistentInitialState { .. }))));
}

/// The run's consistency check measures each residual against the size of
/// the terms it is computed from, as a step's cold start does: a skate
/// sliding at 8e5 whose velocity satisfies the constraint to round-off
/// starts (its residual is above an absolute 1e-12), and one off
/// the constraint by 1e-9 of its speed is refused.
#[test]
fn the_initial_consistency_check_is_relative_to_the_constraint_terms() {
    let sys = Skate::default();
    let speed = 0.8e6;
    let start = |heading: f64| {
        let v = V::<3>::new(speed * heading.cos(), speed * heading.sin(), 0.7);
        (V::<3>::new(1.5, 0.2, heading), v, sys.constraint(0.0, &V::<3>::new(1.5, 0.2, heading), &v).amax())
    };
    // The first heading in steps of 0.01 whose velocity, rounded, leaves a
    // residual above 1e-12 (it stays at round-off, ≤ 4ε·speed).
    let (q0, v0, residual) = (1..100).map(|i| start(0.01 * i as f64)).find(|s| s.2 > 1e-12).unwrap();
    assert!(residual <= 4.0 * f64::EPSILON * speed, "{residual:e}");
    assert_eq!(consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::default()).unwrap(), v0);
    let mut st = Stepper::<_, 3, 1, 2, 11>::new(sys, tab(Method::Gauss));
    let schedule = Schedule::Fixed { h: 1e-7, steps: 10 };
    let run = st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    assert!(!run.report.projected_initial_velocity);
    let off = V::<3>::new(v0[0], v0[1] + 1e-3, 0.7);
    let err = consistent_velocity(&sys, 0.0, &q0, &off, ConsistencyPolicy::default()).unwrap_err();
    let StepError::InconsistentInitialState { residual, tolerance } = err else { panic!("{err}") };
    // The bound: 1e-12 times |cos θ·v_y| + |sin θ·v_x|.
    let terms = (q0[2].cos() * off[1]).abs() + (q0[2].sin() * off[0]).abs();
    assert!(residual > 9e-4 && (tolerance / (1e-12 * terms) - 1.0).abs() <= 1e-12, "{residual:e} {tolerance:e}");
}

#[test]
fn projection_and_consistent_acceleration_need_only_a_regular_saddle_matrix() {
    // m = 0: W = diag(0, 0, I, 3I_w) is singular, but W is positive definite
    // on ker K (v_x and v_y follow v_φ), so [[W, Kᵀ],[K, 0]] is regular.
    let sys = MobileRobot { m: 0.0, ..MobileRobot::default() };
    let q0 = V::<4>::new(0.0, 0.0, 0.3, 0.0);
    let v0 = V::<4>::new(1.0, 0.5, 0.5, 1.0);
    let v = consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 1e-12 }).unwrap();
    // Only v_θ and v_φ carry weight in ½(v − v₀)ᵀW(v − v₀), and k = 0 leaves
    // both free: they keep their values, and v_x, v_y follow the wheel (ℓ = 1).
    let expect = V::<4>::new(0.3f64.cos(), 0.3f64.sin(), 0.5, 1.0);
    assert!((v - expect).amax() < 1e-15, "{v}");
    let (a, psi) = consistent_acceleration(&sys, 0.0, &q0, &v).expect("the saddle matrix is regular");
    let (w, k) = (sys.mass_matrix(0.0, &q0, &v), sys.constraint_v(0.0, &q0, &v));
    assert!((w * a + k.transpose() * psi - sys.force(0.0, &q0, &v)).amax() < 1e-14);
    assert!((k * a + sys.constraint_q(0.0, &q0, &v) * v).amax() < 1e-14);
    // A singular saddle matrix (the skate's heading has no inertia and no
    // constraint fixes it) is reported as such, naming the coordinate and
    // the parameter that is 0.
    let skate = Skate { inertia: 0.0, ..Skate::default() };
    let (q, v0) = (V::<3>::new(0.0, 0.0, 0.3), V::<3>::new(1.0, 0.5, 0.3));
    let err = consistent_velocity(&skate, 0.0, &q, &v0, ConsistencyPolicy::Project { tolerance: 0.0 }).unwrap_err();
    match &err {
        StepError::SingularInitialState { detail, .. } => {
            assert!(detail.contains("coordinate `theta`") && detail.contains("0 here: inertia."), "{err}")
        }
        _ => panic!("{err:?}"),
    }
    assert!(consistent_acceleration(&skate, 0.0, &q, &v0).is_none());
}

/// A start where no step can succeed is refused by `consistent_velocity`
/// (which every run calls first) with the cause, instead of failing in the
/// first step with an energy drift against `E0 = inf` or a singular Newton
/// matrix.
#[test]
fn initial_states_where_no_step_can_succeed_are_refused_with_the_cause() {
    let q0 = V::<3>::zeros();
    let fixed = Schedule::Fixed { h: 0.1, steps: 3 };
    let run = |sys: Skate, v0: V<3>| {
        Stepper::<_, 3, 1, 2, 11>::new(sys, tab(Method::Gauss))
            .integrate(0.0, &q0, &v0, fixed, &RunOptions::default(), &mut NoObserver)
            .unwrap_err()
    };
    // |v0|² overflows: the energy is not finite (k = v_y = 0 holds).
    let huge = V::<3>::new(0.0, 0.0, 1e155);
    for policy in [ConsistencyPolicy::default(), ConsistencyPolicy::Project { tolerance: 0.0 }] {
        let err = consistent_velocity(&Skate::default(), 0.0, &q0, &huge, policy).unwrap_err();
        let StepError::NonFiniteInitialValue { quantity, value, .. } = &err else { panic!("{err:?}") };
        assert!(quantity.starts_with("energy") && !value.is_finite(), "{err}");
    }
    let err = run(Skate::default(), huge);
    assert!(matches!(err, IntegrationError::Initial(StepError::NonFiniteInitialValue { .. })), "{err:?}");
    let text = err.to_string();
    assert!(text.starts_with("initial state: the energy") && text.contains("overflows f64"), "{text}");
    // A parameter that makes the force undefined (0·inf) is named as such.
    let err = run(Skate { g: f64::INFINITY, ..Skate::default() }, V::<3>::new(0.0, 0.0, 1.0));
    assert!(matches!(err, IntegrationError::Initial(StepError::NonFiniteInitialValue { .. })), "{err:?}");
    // m = 0: x has no inertia and no constraint ties it at θ = 0 (k = v_y).
    let massless = Skate { m: 0.0, ..Skate::default() };
    let v0 = V::<3>::new(0.0, 0.0, 1.0);
    let err = consistent_velocity(&massless, 0.0, &q0, &v0, ConsistencyPolicy::default()).unwrap_err();
    let StepError::SingularInitialState { detail, .. } = &err else { panic!("{err:?}") };
    assert!(detail.contains("coordinate `x`") && detail.contains("Parameters that are 0 here: m."), "{err}");
    let text = run(massless, v0).to_string();
    assert!(text.contains("initial state") && text.contains("mass matrix W = d²L/dv²"), "{text}");
    assert!(text.contains("zero mass or inertia"), "{text}");
    // The same with a v0 to project (k = v_y = 1): the projection's first
    // matrix is that saddle matrix, and its failure names the cause alike.
    let off = V::<3>::new(0.0, 1.0, 1.0);
    let err =
        consistent_velocity(&massless, 0.0, &q0, &off, ConsistencyPolicy::Project { tolerance: 0.0 }).unwrap_err();
    let StepError::SingularInitialState { detail, .. } = &err else { panic!("{err:?}") };
    assert!(detail.contains("coordinate `x`") && detail.contains("Parameters that are 0 here: m."), "{err}");
    let project = RunOptions { consistency: ConsistencyPolicy::Project { tolerance: 1e-12 }, ..RunOptions::default() };
    let err = Stepper::<_, 3, 1, 2, 11>::new(massless, tab(Method::Gauss))
        .integrate(0.0, &q0, &off, fixed, &project, &mut NoObserver)
        .unwrap_err();
    assert!(matches!(err, IntegrationError::Initial(StepError::SingularInitialState { .. })), "{err:?}");
    // A negative mass is no error in itself (the saddle matrix is regular).
    let negative = Skate { m: -1.0, ..Skate::default() };
    assert_eq!(consistent_velocity(&negative, 0.0, &q0, &v0, ConsistencyPolicy::default()), Ok(v0));
    // A singular W with a regular saddle matrix passes the check (the robot
    // with m = 0: the constraints tie v_x and v_y to the wheel), but no step
    // is determined there: the first step refuses it before Newton, naming
    // the coordinate and the parameter, instead of failing with a singular
    // Newton matrix after four halvings.
    let robot = MobileRobot { m: 0.0, ..MobileRobot::default() };
    let (rq, rv) = (V::<4>::new(0.0, 0.0, 0.3, 0.0), V::<4>::new(0.3f64.cos(), 0.3f64.sin(), 0.5, 1.0));
    assert_eq!(consistent_velocity(&robot, 0.0, &rq, &rv, ConsistencyPolicy::default()), Ok(rv));
    let err = Stepper::<_, 4, 2, 2, 16>::new(robot, tab(Method::Gauss))
        .integrate(0.0, &rq, &rv, fixed, &RunOptions::default(), &mut NoObserver)
        .unwrap_err();
    let IntegrationError::Step { index: 0, source: StepError::SingularInitialState { detail, .. }, .. } = &err else {
        panic!("{err:?}")
    };
    assert!(detail.contains("coordinate `x`") && detail.contains("Parameters that are 0 here: m."), "{err}");
}

// ---------------------------------------------------------------- driver

#[test]
fn driver_handles_time_lists_backward_steps_and_serializes() {
    let mut st = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab(Method::LobattoIIIAB));
    let (q0, v0) = (V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0));
    let times = [0.05, 0.2, 0.25, 0.6, 0.3, -0.1];
    let opts = RunOptions { observe: Observe { multipliers: true, ..Observe::default() }, ..RunOptions::default() };
    let mut seen = 0;
    let tr =
        st.integrate(0.0, &q0, &v0, Schedule::Times(&times), &opts, &mut |_: &State<3>, _: usize| seen += 1).unwrap();
    assert_eq!(seen, times.len());
    assert_eq!(tr.samples.len(), times.len() + 1);
    for (s, t) in tr.samples[1..].iter().zip(times) {
        assert_eq!(s.t, t);
    }
    // Exact skate solution: θ = t, x = (g sinβ/2)(t − sin(t)cos(t))… checked via the energy and constraint.
    assert!(tr.report.max_constraint_residual <= 1e-14);
    assert!(tr.report.max_energy_error < 1e-4);
    let psi = tr.samples[0].multipliers.unwrap();
    assert!(psi.iter().all(|x| x.is_finite()));
    let csv = tr.to_csv_string().unwrap();
    assert!(csv.starts_with("t,q_x,q_y,q_theta,v_x,v_y,v_theta,energy,constraint_residual,psi_1,newton_iterations"));
    assert_eq!(csv.lines().count(), times.len() + 2);
    let json = tr.to_json_string().unwrap();
    let back: Trajectory<3, 1> = serde_json::from_str(&json).unwrap();
    assert_eq!(back, tr);
    assert!(matches!(
        st.integrate(0.0, &q0, &v0, Schedule::Times(&[0.1, 0.1]), &opts, &mut NoObserver),
        Err(IntegrationError::InvalidSchedule(_))
    ));
    // record_every thins the output but keeps the endpoints.
    let opts = RunOptions { record_every: 7, ..RunOptions::default() };
    let tr = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h: -0.1, steps: 20 }, &opts, &mut NoObserver).unwrap();
    assert_eq!(tr.samples.len(), 1 + 2 + 1);
    assert_eq!(tr.samples.last().unwrap().t, -2.0);
    assert_eq!(tr.report.steps, 20);
    assert!(tr.report.newton_iterations_mean >= 1.0);
}

#[test]
fn stepper_macro_computes_d() {
    let mut st: crate::Stepper![Skate, 4] = Stepper::new(Skate::default(), tab(Method::Gauss));
    let r = st.step(&State::new(0.0, V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0)), 0.1).unwrap();
    assert_eq!(r.stage_velocities.len(), 4);
    let _: crate::Stepper![MobileRobot, 2] = Stepper::new(MobileRobot::default(), tab(Method::LobattoIIIABD));
}

#[test]
fn general_system_converges_at_the_expected_order() {
    // Time-dependent, non-separable, nonlinear constraint: the general path.
    let sys = General::default();
    let q0 = V::<2>::new(0.3, -0.2);
    let mut v0 = V::<2>::new(0.5, 0.0);
    v0 = consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 0.0 }).unwrap();
    let t_end = 1.0;
    let refsol = reference::integrate(&sys, 0.0, &q0, &v0, t_end, &reference::ReferenceOptions::default()).unwrap();
    let (qr, vr) = (refsol.q[0], refsol.v[0]);
    let err = |h_steps: usize| -> f64 {
        let mut st = Stepper::<_, 2, 1, 2, 8>::new(sys, tab(Method::Gauss));
        let h = t_end / h_steps as f64;
        let mut s = State::new(0.0, q0, v0);
        for _ in 0..h_steps {
            s = st.step(&s, h).unwrap().state;
        }
        (s.q - qr).amax().max((s.v - vr).amax())
    };
    let (e1, e2) = (err(10), err(20));
    let order = (e1 / e2).log2();
    assert!((order - 4.0).abs() < 0.2, "Gauss s=2 order on the general system: {order} ({e1:e}, {e2:e})");
}

#[test]
fn failed_steps_are_retried_as_half_steps_when_allowed() {
    let q = V::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let v = V::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let mut st = Stepper::<_, 7, 1, 2, 23>::new(MpParticles, tab(Method::Gauss));
    let big = Schedule::Fixed { h: 4.0, steps: 2 };
    let no_halving = RunOptions { max_halvings: 0, ..RunOptions::default() };
    let strict = st.integrate(0.0, &q, &v, big, &no_halving, &mut NoObserver);
    assert!(matches!(strict, Err(IntegrationError::Step { index: 0, .. })), "{strict:?}");
    let opts = RunOptions { max_halvings: 8, ..RunOptions::default() };
    let tr = st.integrate(0.0, &q, &v, big, &opts, &mut NoObserver).unwrap();
    assert_eq!(tr.report.steps, 2);
    assert!(tr.report.rejected_steps > 0);
    assert_eq!(tr.samples.last().unwrap().t, 8.0);
    assert!(tr.report.max_constraint_residual <= 1e-14);
}

#[test]
fn states_compare_like_their_components() {
    let a = State::new(0.5, V::<3>::new(1.0, -0.0, 2.0), V::<3>::new(0.0, 3.0, -4.0));
    assert_eq!(a, a);
    // Signed zeros compare equal, as `f64` does.
    assert_eq!(a, State::new(0.5, V::<3>::new(1.0, 0.0, 2.0), V::<3>::new(-0.0, 3.0, -4.0)));
    assert_ne!(a, State { t: 0.25, ..a });
    for i in 0..3 {
        for x in [7.0, f64::NAN] {
            let (mut q, mut v) = (a.q, a.v);
            q[i] = x;
            v[i] = x;
            assert_ne!(a, State { q, ..a });
            assert_ne!(a, State { v, ..a });
        }
    }
    // A NaN never compares equal, not even to itself.
    let nan = State { t: f64::NAN, ..a };
    assert_ne!(nan, nan);
}

nonholonomic_system! {
    /// The Appell–Hamel particle: a constraint quadratic in the velocities.
    struct QuadraticInV {
        coordinates: [x, y, z],
        parameters: { a = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - z,
        constraints: [ dot(z)^2 - a^2*(dot(x)^2 + dot(y)^2) ],
    }
}

/// A velocity of 1e150 against a constraint quadratic in it gives the
/// saddle matrix `[[W, Kᵀ],[K, 0]]` rows of 1 and 1e150: singular to
/// working precision as given, regular once scaled. The error names the
/// magnitudes, not a zero mass or dependent constraints; at a moderate
/// velocity the same state starts.
#[test]
fn a_start_singular_only_by_its_magnitudes_is_refused_naming_them() {
    let q0 = V::<3>::zeros();
    for (v0, policy) in [
        (V::<3>::new(1e150, 0.0, 1e150), ConsistencyPolicy::default()),
        (V::<3>::new(1e150, 1e150, 1e150), ConsistencyPolicy::Project { tolerance: 1e-12 }),
    ] {
        let err = consistent_velocity(&QuadraticInV::default(), 0.0, &q0, &v0, policy).unwrap_err();
        let StepError::SingularInitialState { detail, .. } = &err else { panic!("{err:?}") };
        assert!(detail.starts_with("the magnitudes at the initial state are out of the range"), "{err}");
        assert!(detail.contains("max |v0| = 1.000e150") && !detail.contains("zero mass"), "{err}");
    }
    consistent_velocity(&QuadraticInV::default(), 0.0, &q0, &V::<3>::new(1.0, 0.0, 1.0), ConsistencyPolicy::default())
        .unwrap();
    // A zero mass is still named as such.
    let err = consistent_velocity(
        &Skate { m: 0.0, ..Skate::default() },
        0.0,
        &q0,
        &V::<3>::new(0.0, 0.0, 1.0),
        ConsistencyPolicy::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("Parameters that are 0 here: m"), "{err}");
}

/// The skate sliding at 1e20: the step's Newton matrix holds entries from
/// 1e-4 to 1e17, regular once scaled but singular to working precision as
/// given. The error says the magnitudes are out of range, not a mass or a
/// constraint.
#[test]
fn a_step_singular_only_by_its_magnitudes_says_so() {
    let mut st = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tab(Method::Gauss));
    let state = State { t: 0.0, q: V::<3>::zeros(), v: V::<3>::new(1e20, 0.0, 1.0) };
    let err = st.step(&state, 0.1).unwrap_err();
    let StepError::SingularMatrix { detail, .. } = &err else { panic!("{err:?}") };
    assert!(detail.contains("magnitudes are out of range") && detail.contains("max |v| = 1.000e20"), "{err}");
    assert!(!detail.contains("zero mass"), "{err}");
}
