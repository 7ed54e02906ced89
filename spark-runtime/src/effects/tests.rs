//! Effects in the stepper: exact Jacobian vs finite differences with `f` and
//! `N`, trajectories vs the ψ-eliminated reference ODE, the energy balance
//! `E(t) − E(0) = ∫ (f + N)ᵀv dt` at two step sizes, and holonomic drift.

use super::*;
use crate::reference::{integrate_at, ReferenceOptions};
use crate::tests::check_jacobian;
use crate::{Method, Stepper, Tableau};

fn skate_state(theta: f64, speed: f64, omega: f64) -> State<3> {
    let (s, c) = theta.sin_cos();
    State::new(0.0, Vector::<3>::new(0.1, -0.2, theta), Vector::<3>::new(c * speed, s * speed, omega))
}

#[test]
fn jacobian_with_forcing_and_nonideal_force_matches_finite_differences() {
    let s = skate_state(0.7, 0.4, 0.9);
    // Wider smoothing so the finite differences resolve N's curvature.
    let friction = FrictionSkate { mu: 0.4, delta: 0.3, epsilon: 0.5, ..FrictionSkate::default() };
    check_jacobian::<_, 3, 1, 1, 7>(DrivenSkate::default(), Method::SymplecticEulerI, s, 0.2);
    check_jacobian::<_, 3, 1, 2, 11>(DrivenSkate::default(), Method::Gauss, s, 0.2);
    check_jacobian::<_, 3, 1, 3, 15>(DrivenSkate::default(), Method::LobattoIIIAB, s, 0.2);
    check_jacobian::<_, 3, 1, 2, 11>(friction, Method::Gauss, s, 0.2);
    check_jacobian::<_, 3, 1, 4, 19>(friction, Method::LobattoIIIABD, s, -0.2);
    check_jacobian::<_, 3, 1, 1, 7>(friction, Method::SymplecticEulerII, s, 0.2);
    let p = State::new(0.0, Vector::<2>::new(0.6, -0.8), Vector::<2>::new(0.8, 0.6));
    check_jacobian::<_, 2, 1, 2, 8>(RodPendulum::default(), Method::Gauss, p, 0.2);
}

/// Runs `steps` steps of size `h`; returns the states and the work
/// `Σ h Σ_j b_j (f_j + N_j)ᵀV_j` of the effects at the stages.
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
    let mut states = vec![start];
    let mut work = 0.0;
    let mut x = start;
    for _ in 0..steps {
        let r = st.step(&x, h).unwrap();
        work += super::effect_work(&sys, &tab, &x, h, &r);
        x = r.state;
        states.push(x);
    }
    (states, work)
}

/// Energy-balance defect `|E(T) − E(0) − W|` for step sizes `h` and `h/2`.
fn balance<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> (f64, f64, f64)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let defect = |h: f64, n: usize| {
        let (states, work) = run::<Sys, N, M, S, D>(sys.clone(), method, start, h, n);
        let end = states.last().unwrap();
        let de = sys.energy(end.t, &end.q, &end.v) - sys.energy(start.t, &start.q, &start.v);
        ((de - work).abs(), work)
    };
    let (d1, w) = defect(h, steps);
    let (d2, _) = defect(h / 2.0, 2 * steps);
    (d1, d2, w)
}

#[test]
fn energy_balance_of_forced_and_frictional_skates_holds_to_the_method_order() {
    let s = skate_state(0.3, 1.0, 0.8);
    // Gauss s=2 (order 4): the defect shrinks ≈ 16× when h halves.
    let (d1, d2, w) = balance::<_, 3, 1, 2, 11>(DrivenSkate::default(), Method::Gauss, s, 0.1, 20);
    assert!(w.abs() > 0.1, "the forcing must do visible work, got {w}");
    assert!(d1 < 1e-4 && d1 / d2 > 11.0, "forced: defects {d1:e} (h) and {d2:e} (h/2)");
    // Symplectic Euler I (order 1): ≈ 2×.
    let (d1, d2, _) = balance::<_, 3, 1, 1, 7>(DrivenSkate::default(), Method::SymplecticEulerI, s, 0.02, 100);
    assert!(d1 / d2 > 1.7 && d1 / d2 < 2.6, "forced, Euler: defects {d1:e}, {d2:e}");
    let friction = FrictionSkate { mu: 0.3, delta: 0.05, epsilon: 0.1, ..FrictionSkate::default() };
    let (d1, d2, w) = balance::<_, 3, 1, 2, 11>(friction, Method::Gauss, s, 0.1, 20);
    assert!(w < -0.05, "friction must dissipate, got work {w}");
    assert!(d1 < 1e-4 && d1 / d2 > 11.0, "friction: defects {d1:e} (h) and {d2:e} (h/2)");
}

fn reference_error<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> f64
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let (states, _) = run::<Sys, N, M, S, D>(sys.clone(), method, start, h, steps);
    let end = states.last().unwrap();
    let reference = integrate_at(&sys, start.t, &start.q, &start.v, &[end.t], &ReferenceOptions::default()).unwrap();
    (end.q - reference.q[0]).amax().max((end.v - reference.v[0]).amax())
}

#[test]
fn trajectories_with_effects_match_the_reference_ode_at_the_method_order() {
    let s = skate_state(0.3, 1.0, 0.8);
    let e1 = reference_error::<_, 3, 1, 2, 11>(DrivenSkate::default(), Method::Gauss, s, 0.1, 20);
    let e2 = reference_error::<_, 3, 1, 2, 11>(DrivenSkate::default(), Method::Gauss, s, 0.05, 40);
    assert!(e1 < 1e-4 && e1 / e2 > 12.0, "driven skate vs reference: {e1:e}, {e2:e}");
    let friction = FrictionSkate { mu: 0.3, delta: 0.05, epsilon: 0.1, ..FrictionSkate::default() };
    let e1 = reference_error::<_, 3, 1, 2, 11>(friction, Method::Gauss, s, 0.1, 20);
    let e2 = reference_error::<_, 3, 1, 2, 11>(friction, Method::Gauss, s, 0.05, 40);
    assert!(e1 < 1e-3 && e1 / e2 > 12.0, "friction skate vs reference: {e1:e}, {e2:e}");
    let p = State::new(0.0, Vector::<2>::new(0.6, -0.8), Vector::<2>::new(0.8, 0.6));
    let e1 = reference_error::<_, 2, 1, 2, 8>(RodPendulum::default(), Method::Gauss, p, 0.1, 20);
    let e2 = reference_error::<_, 2, 1, 2, 8>(RodPendulum::default(), Method::Gauss, p, 0.05, 40);
    assert!(e1 < 1e-4 && e1 / e2 > 12.0, "rod pendulum vs reference: {e1:e}, {e2:e}");
}

#[test]
fn holonomic_drift_is_measured_and_converges() {
    let p = State::new(0.0, Vector::<2>::new(0.6, -0.8), Vector::<2>::new(0.8, 0.6));
    let sys = RodPendulum::default();
    // Symplectic Euler I does not conserve |q|²: the drift is O(h).
    let (coarse, _) = run::<_, 2, 1, 1, 5>(sys, Method::SymplecticEulerI, p, 0.02, 250);
    let (fine, _) = run::<_, 2, 1, 1, 5>(sys, Method::SymplecticEulerI, p, 0.01, 500);
    let (d1, d2) = (holonomic_drift(&sys, &coarse), holonomic_drift(&sys, &fine));
    assert!(d1 > 1e-6 && d1 < 1e-1, "drift {d1:e}");
    assert!(d1 / d2 > 1.6 && d1 / d2 < 2.5, "drift must shrink like h: {d1:e}, {d2:e}");
    // Gauss collocation conserves the quadratic invariant ½|q|² exactly
    // (measured: drift at round-off level, 7e-16 after 100 steps).
    let (gauss, _) = run::<_, 2, 1, 2, 8>(sys, Method::Gauss, p, 0.1, 100);
    assert!(holonomic_drift(&sys, &gauss) < 1e-13);
    assert_eq!(holonomic_drift(&crate::handwritten::Skate::default(), &[skate_state(0.0, 1.0, 0.0)]), 0.0);
}
