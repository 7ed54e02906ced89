//! Force, non-ideal and holonomic effects declared with the macro:
//! generated `f`, `N`, their Jacobians and the holonomic residuals against
//! the hand-written systems of `spark_runtime::fixtures::effects`, the macro friction
//! skate's trajectory against the hand-written one, the energy balance
//! `E(T) − E(0) = ∫ fᵀv dt` of the driven/damped sleigh at the method's
//! order, and a constraint nonlinear in `v` declared as an effect (Chetaev's
//! `K = ∂k/∂v`) against the reference integrator.

use problems::systems::scenes::{
    AppellHamelCord, AppellHamelSprung, BodyRailed, BodyTethered, RodPendulum, SkateOnBlade, SkateWithFriction,
    SleighDamped, SleighDriven, SleighDrivenDamped, SleighDrivenDampedByHand, SleighFree,
};
use spark_runtime::diagnostics::holonomic_drift;
use spark_runtime::fixtures::effects::{DrivenSkate, FrictionSkate, RodPendulum as HandRod};
use spark_runtime::fixtures::paper::Skate;
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{Matrix, Method, NonholonomicSystem, State, Stepper, Tableau, Vector};

/// Deterministic uniform numbers in `[lo, hi)` (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * x
    }
    fn vector<const N: usize>(&mut self, lo: f64, hi: f64) -> Vector<N> {
        Vector::<N>::from_fn(|_, _| self.uniform(lo, hi))
    }
}

/// `|a − b|` relative to `1 + |b|`, entrywise maximum.
fn rel<const R: usize, const C: usize>(a: &Matrix<R, C>, b: &Matrix<R, C>) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs() / (1.0 + y.abs())).fold(0.0, f64::max)
}

#[test]
fn generated_forces_and_their_jacobians_equal_the_hand_written_ones() {
    let mut rng = Rng(0x5eed_1234_abcd_0001);
    let (tau, c) = (0.7, 0.45);
    let sleigh = SleighDrivenDamped { tau, c, ..SleighDrivenDamped::default() };
    let by_hand = SleighDrivenDampedByHand { tau, c, ..SleighDrivenDampedByHand::default() };
    let driven_skate = DrivenSkate { torque: tau, damping: c, ..DrivenSkate::default() };
    // Wide smoothing so that N's derivatives are far from their limits.
    let (mu, delta, epsilon) = (0.35, 0.3, 0.5);
    let ice = SkateWithFriction { mu, delta, epsilon, ..SkateWithFriction::default() };
    let hand_ice = FrictionSkate { mu, delta, epsilon, skate: Skate::default() };
    let mut worst = [0.0f64; 4];
    for _ in 0..200 {
        let t = rng.uniform(-2.0, 2.0);
        let q = rng.vector::<3>(-3.0, 3.0);
        let v = rng.vector::<3>(-2.0, 2.0);
        let psi = rng.vector::<1>(-2.0, 2.0);
        // f = (−c v₁, −c v₂, τ − c v₃) for the sleigh and the hand-written driven skate.
        let (f, fq, fv) = sleigh.external_force_jacobians(t, &q, &v);
        let (hf, hq, hv) = driven_skate.external_force_jacobians(t, &q, &v);
        assert_eq!(sleigh.external_force(t, &q, &v), f);
        worst[0] = worst[0].max(rel(&f, &hf)).max(rel(&fq, &hq)).max(rel(&fv, &hv));
        // The scene and the hand declaration with the force in the base.
        let (sv, sj) = sleigh.stage_jacobians(t, &q, &v, &psi);
        let (bv, bj) = by_hand.stage_jacobians(t, &q, &v, &psi);
        assert_eq!((sv, sj), (bv, bj));
        assert_eq!((f, fq, fv), by_hand.external_force_jacobians(t, &q, &v));
        // Non-ideal friction force of the blade.
        let n = ice.nonideal_force_jacobians(t, &q, &v, &psi);
        let h = hand_ice.nonideal_force_jacobians(t, &q, &v, &psi);
        assert_eq!(ice.nonideal_force(t, &q, &v, &psi), n.value);
        worst[1] = worst[1].max(rel(&n.value, &h.value)).max(rel(&n.q, &h.q)).max(rel(&n.v, &h.v));
        worst[2] = worst[2].max(rel(&n.psi, &h.psi));
        // The rest of the friction skate is the hand-written skate.
        let (iv, ij) = ice.stage_jacobians(t, &q, &v, &psi);
        let (kv, kj) = hand_ice.stage_jacobians(t, &q, &v, &psi);
        let pairs = [
            rel(&iv.momentum, &kv.momentum),
            rel(&iv.force, &kv.force),
            rel(&iv.constraint_force, &kv.constraint_force),
            rel(&ij.mass, &kj.mass),
            rel(&ij.force_q, &kj.force_q),
            rel(&ij.constraint_v, &kj.constraint_v),
            rel(&ij.constraint_force_q, &kj.constraint_force_q),
            rel(&iv.constraint, &kv.constraint),
        ];
        worst[3] = pairs.iter().fold(worst[3], |a, &b| a.max(b));
        // Single-effect scenes carry only their part of f.
        let (df, dq, dv) = SleighDriven { tau, ..SleighDriven::default() }.external_force_jacobians(t, &q, &v);
        assert_eq!((df, dq, dv), (Vector::<3>::new(0.0, 0.0, tau), Matrix::zeros(), Matrix::zeros()));
        let (mf, _, mv) = SleighDamped { c, ..SleighDamped::default() }.external_force_jacobians(t, &q, &v);
        assert!(rel(&mf, &(-c * v)) < 1e-15 && rel(&mv, &(-c * Matrix::<3, 3>::identity())) < 1e-15);
    }
    assert!(worst.iter().all(|w| *w < 1e-13), "worst relative differences (f, N, ∂N/∂ψ, skate) {worst:?}");
    // Effects appear exactly where the scene selects them.
    const { assert!(!SleighFree::HAS_FORCING && SleighDriven::HAS_FORCING && SleighDrivenDamped::HAS_FORCING) };
    const { assert!(!SkateOnBlade::HAS_NONIDEAL_FORCE && SkateWithFriction::HAS_NONIDEAL_FORCE) };
    const { assert!(!SkateWithFriction::HAS_FORCING && !SleighDrivenDamped::HAS_NONIDEAL_FORCE) };
    assert!(SleighFree::SOURCE.external_force.is_empty() && SkateOnBlade::SOURCE.nonideal_force.is_empty());
    assert_eq!(SleighDriven::SOURCE.external_force, ["0", "0", "(p tau)"]);
    let n_src = SkateWithFriction::SOURCE.nonideal_force;
    assert!(n_src.len() == 3 && n_src[0].contains("(psi 0)") && n_src[2] == "0", "{n_src:?}");
    // The force does not touch the stage functions: same code as without it.
    assert_eq!(SleighFree::OPERATIONS, SleighDrivenDamped::OPERATIONS);
    assert_eq!(SleighDrivenDamped::OPERATIONS, SleighDrivenDampedByHand::OPERATIONS);
    assert_eq!(SkateOnBlade::OPERATIONS, SkateWithFriction::OPERATIONS);
}

fn run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> (Vec<State<N>>, f64)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let tab = Tableau::<S>::new(method).unwrap();
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tab);
    let (mut states, mut work, mut x) = (vec![start], 0.0, start);
    for _ in 0..steps {
        let r = st.step(&x, h).unwrap();
        work += spark_runtime::diagnostics::effect_work(&sys, &tab, &x, h, &r);
        x = r.state;
        states.push(x);
    }
    (states, work)
}

fn skate_state(theta: f64, speed: f64, omega: f64) -> State<3> {
    let (s, c) = theta.sin_cos();
    State::new(0.0, Vector::<3>::new(0.1, -0.2, theta), Vector::<3>::new(c * speed, s * speed, omega))
}

#[test]
fn macro_friction_skate_follows_the_hand_written_trajectory() {
    let (mu, delta, epsilon) = (0.3, 0.05, 0.1);
    let ice = SkateWithFriction { mu, delta, epsilon, ..SkateWithFriction::default() };
    let hand = FrictionSkate { mu, delta, epsilon, skate: Skate::default() };
    let start = skate_state(0.3, 1.0, 0.8);
    let (a, wa) = run::<_, 3, 1, 2, 11>(ice, Method::Gauss, start, 0.1, 50);
    let (b, wb) = run::<_, 3, 1, 2, 11>(hand, Method::Gauss, start, 0.1, 50);
    let diff = a.iter().zip(&b).map(|(x, y)| (x.q - y.q).amax().max((x.v - y.v).amax())).fold(0.0, f64::max);
    assert!(diff < 1e-12, "macro vs hand-written friction skate: {diff:e}");
    assert!(wa < -0.05 && (wa - wb).abs() < 1e-12, "friction work {wa} vs {wb}");
}

/// `|E(T) − E(0) − W|` for `h` and `h/2`, and the work `W`.
fn balance<Sys, const S: usize, const D: usize>(sys: Sys, method: Method, h: f64, steps: usize) -> (f64, f64, f64)
where
    Sys: NonholonomicSystem<3, 1> + Clone,
{
    // Heading θ = 0.3 with the contact point moving along the blade.
    let start = skate_state(0.3, 0.8, 0.6);
    let defect = |h: f64, n: usize| {
        let (states, work) = run::<Sys, 3, 1, S, D>(sys.clone(), method, start, h, n);
        let end = states.last().unwrap();
        let de = sys.energy(end.t, &end.q, &end.v) - sys.energy(start.t, &start.q, &start.v);
        ((de - work).abs(), work)
    };
    let (d1, w) = defect(h, steps);
    let (d2, _) = defect(h / 2.0, 2 * steps);
    // Shown with `--nocapture`, for the documentation.
    println!("energy balance {method:?}: W = {w:.4}, defects {d1:.2e} (h = {h}), {d2:.2e} (h/2), ratio {:.1}", d1 / d2);
    (d1, d2, w)
}

#[test]
fn sleigh_energy_balance_holds_at_the_method_order() {
    // Gauss s = 2 has order 4: the defect shrinks ≈ 16× when h halves.
    let (d1, d2, w) = balance::<_, 2, 11>(SleighDriven::default(), Method::Gauss, 0.2, 20);
    assert!(w > 0.1 && d1 < 1e-4 && d1 / d2 > 12.0, "driven: W = {w}, defects {d1:e}, {d2:e}");
    let (d1, d2, w) = balance::<_, 2, 11>(SleighDamped::default(), Method::Gauss, 0.2, 20);
    assert!(w < -0.05 && d1 < 1e-4 && d1 / d2 > 12.0, "damped: W = {w}, defects {d1:e}, {d2:e}");
    let (d1, d2, w) = balance::<_, 2, 11>(SleighDrivenDamped::default(), Method::Gauss, 0.2, 20);
    assert!(w.abs() > 0.05 && d1 < 1e-4 && d1 / d2 > 12.0, "driven+damped: W = {w}, defects {d1:e}, {d2:e}");
    // Lobatto IIIA-B s = 3 (order 4) as well; symplectic Euler I (order 1) ≈ 2×.
    let (d1, d2, _) = balance::<_, 3, 15>(SleighDrivenDamped::default(), Method::LobattoIIIAB, 0.2, 20);
    assert!(d1 < 1e-4 && d1 / d2 > 12.0, "driven+damped, Lobatto IIIA-B: defects {d1:e}, {d2:e}");
    let (d1, d2, _) = balance::<_, 1, 7>(SleighDrivenDamped::default(), Method::SymplecticEulerI, 0.02, 200);
    assert!(d1 / d2 > 1.7 && d1 / d2 < 2.6, "driven+damped, Euler I: defects {d1:e}, {d2:e}");
    // Without forcing there is no work; the energy error is the method's, O(h⁴).
    let (d1, d2, w) = balance::<_, 2, 11>(SleighFree::default(), Method::Gauss, 0.2, 20);
    assert!(w == 0.0 && d1 < 1e-5 && d1 / d2 > 12.0, "free sleigh: W = {w}, |ΔE| = {d1:e}, {d2:e}");
}

#[test]
fn nonlinear_constraint_effect_uses_chetaev_and_matches_the_reference() {
    use spark_runtime::ConstraintForm;
    let sys = AppellHamelCord::default();
    assert_eq!(AppellHamelCord::STRUCTURE.constraint_form, ConstraintForm::Nonlinear);
    let a = sys.a;
    let mut rng = Rng(0x5eed_0000_0000_0002);
    for _ in 0..50 {
        let (q, v) = (rng.vector::<3>(-2.0, 2.0), rng.vector::<3>(-2.0, 2.0));
        let k = sys.constraint_v(0.0, &q, &v);
        let chetaev = Matrix::<1, 3>::new(-2.0 * a * a * v[0], -2.0 * a * a * v[1], 2.0 * v[2]);
        assert!(rel(&k, &chetaev) < 1e-15, "K = {k} vs ∂k/∂v = {chetaev}");
    }
    // v₀ = (1, 0.3, −a·√1.09) satisfies k = 0 (falling, so the speed, and with
    // it K, never vanishes); Gauss s = 2 against the
    // reference ODE, with the spring (without it the motion is polynomial in t
    // and every method is exact).
    let sys = AppellHamelSprung::default();
    let v0 = Vector::<3>::new(1.0, 0.3, -a * 1.09f64.sqrt());
    let start = State::new(0.0, Vector::<3>::new(0.5, 0.0, 1.0), v0);
    assert!(sys.constraint(0.0, &start.q, &v0)[0].abs() < 1e-15);
    let error = |h: f64, n: usize| {
        let (states, _) = run::<_, 3, 1, 2, 11>(sys, Method::Gauss, start, h, n);
        let end = states.last().unwrap();
        let r = integrate_at(&sys, 0.0, &start.q, &v0, &[end.t], &ReferenceOptions::default()).unwrap();
        (end.q - r.q[0]).amax().max((end.v - r.v[0]).amax())
    };
    let (e1, e2) = (error(0.1, 20), error(0.05, 40));
    println!("Appell–Hamel sprung vs reference: {e1:.2e} (h = 0.1), {e2:.2e} (h = 0.05), ratio {:.1}", e1 / e2);
    assert!(e1 < 1e-4 && e1 / e2 > 12.0, "Appell–Hamel scene vs reference: {e1:e}, {e2:e}");
}

#[test]
fn holonomic_scenes_report_drift_through_the_generated_residual() {
    const { assert!(RodPendulum::HAS_HOLONOMIC && BodyTethered::HAS_HOLONOMIC && !BodyRailed::HAS_HOLONOMIC) };
    assert_eq!(RodPendulum::SOURCE.holonomic.len(), 1);
    assert!(BodyRailed::SOURCE.holonomic.is_empty());
    let (rod, hand) = (RodPendulum::default(), HandRod::default());
    let tether = BodyTethered::default();
    let mut rng = Rng(0x5eed_0000_0000_0003);
    for _ in 0..50 {
        let (t, q2, q3) = (rng.uniform(-1.0, 1.0), rng.vector::<2>(-2.0, 2.0), rng.vector::<3>(-2.0, 2.0));
        let (g, h) = (rod.holonomic_residual(t, &q2), hand.holonomic_residual(t, &q2));
        assert!(rel(&g, &h) < 1e-15, "{g} vs {h}");
        let expected = (q3[0] * q3[0] + q3[1] * q3[1] - tether.ell * tether.ell) / 2.0;
        assert!((tether.holonomic_residual(t, &q3)[0] - expected).abs() < 1e-15);
    }
    // Symplectic Euler I does not keep |q|² = ℓ²: the drift is O(h) and is
    // reported by the generated residual exactly as by the hand-written one.
    let p = State::new(0.0, Vector::<2>::new(0.6, -0.8), Vector::<2>::new(0.8, 0.6));
    let drift = |h: f64, n: usize| {
        let (states, _) = run::<_, 2, 1, 1, 5>(rod, Method::SymplecticEulerI, p, h, n);
        (holonomic_drift(&rod, &states), holonomic_drift(&hand, &states))
    };
    let ((d1, h1), (d2, _)) = (drift(0.02, 250), drift(0.01, 500));
    assert!(d1 == h1 && d1 > 1e-6 && d1 / d2 > 1.6 && d1 / d2 < 2.5, "drift {d1:e} (h), {d2:e} (h/2)");
    // Gauss keeps the quadratic invariant |q|² (k = q·v is its derivative).
    let (states, _) = run::<_, 2, 1, 2, 8>(rod, Method::Gauss, p, 0.1, 100);
    let gauss = holonomic_drift(&rod, &states);
    assert!(gauss < 1e-12, "Gauss drift {gauss:e}");
}
