//! Tests of the error estimate, the PI controller and the reversible rule.

use crate::adaptive::*;
use crate::fixtures::paper::{MobileRobot, MpParticles, OrbitParticle, Particle, Skate};
use crate::reference::{integrate as reference, ReferenceOptions};
use crate::*;

type V<const N: usize> = Vector<N>;

/// Largest and smallest ratio estimate/true local error over the step sizes
/// whose true error lies well above round-off, and how many there were.
fn estimate_ratios<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    state: State<N>,
    hs: &[f64],
) -> (f64, f64, usize)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap());
    let (mut lo, mut hi, mut used) = (f64::INFINITY, 0.0f64, 0);
    for &h in hs {
        st.reset_run();
        // A step size beyond the method's reach (Newton or the energy
        // guard fails) has no local error to compare.
        let Ok(est) = st.step_with_estimate(&state, h, 1e-6, 1e-6) else { continue };
        let exact = reference(&sys, state.t, &state.q, &state.v, state.t + h, &ReferenceOptions::default()).unwrap();
        let (dq, dv) = (est.state.q - exact.q[0], est.state.v - exact.v[0]);
        let truth = (dq.norm_squared() + dv.norm_squared()).sqrt();
        let estimate = (est.error_q.norm_squared() + est.error_v.norm_squared()).sqrt();
        // Above 1e-10 the reference (≈ 1e-14) and Newton (≈ 1e-15) errors
        // are negligible against the local error being measured.
        if truth > 1e-10 && truth < 1e-2 {
            let r = estimate / truth;
            lo = lo.min(r);
            hi = hi.max(r);
            used += 1;
        }
    }
    (lo, hi, used)
}

macro_rules! every_family {
    ($sys:expr, $n:literal, $m:literal, $state:expr, $hs:expr, $out:ident) => {{
        let s = $state;
        let mut one = |name: String, (lo, hi, used): (f64, f64, usize)| {
            let ok = used >= 2 && lo >= 0.1 && hi <= 10.0;
            $out.push((ok, format!("{name}: estimate/true local error in [{lo:.3}, {hi:.3}] over {used} step sizes")));
        };
        let sys = $sys;
        let label = |m: Method, s: usize| format!("{} {m} s={s}", stringify!($sys));
        one(
            label(Method::Gauss, 1),
            estimate_ratios::<_, $n, $m, 1, { 1 * ($n + $m) + $n }>(sys.clone(), Method::Gauss, s, $hs),
        );
        one(
            label(Method::Gauss, 2),
            estimate_ratios::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(sys.clone(), Method::Gauss, s, $hs),
        );
        one(
            label(Method::Gauss, 3),
            estimate_ratios::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(sys.clone(), Method::Gauss, s, $hs),
        );
        for method in
            [Method::LobattoIIIAB, Method::LobattoIIIABD, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda]
        {
            one(label(method, 2), estimate_ratios::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(sys.clone(), method, s, $hs));
        }
        for method in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            one(label(method, 3), estimate_ratios::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(sys.clone(), method, s, $hs));
        }
        for method in [Method::SymplecticEulerI, Method::SymplecticEulerII] {
            one(label(method, 1), estimate_ratios::<_, $n, $m, 1, { 1 * ($n + $m) + $n }>(sys.clone(), method, s, $hs));
        }
    }};
}

const HS: [f64; 6] = [0.8, 0.4, 0.2, 0.1, 0.05, 0.025];

#[test]
fn step_doubling_estimate_tracks_the_true_local_error_within_a_factor_10() {
    let mut out = Vec::new();
    every_family!(Particle, 3, 1, State::new(0.0, V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 1.0, 0.0)), &HS, out);
    every_family!(Skate::default(), 3, 1, State::new(0.0, V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0)), &HS, out);
    every_family!(
        MobileRobot::default(),
        4,
        2,
        State::new(0.0, V::<4>::zeros(), V::<4>::new(1.0, 0.0, 0.5, 1.0)),
        &HS,
        out
    );
    let mq = V::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let mv = V::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]);
    every_family!(MpParticles, 7, 1, State::new(0.0, mq, mv), &HS, out);
    // The orbit at its farthest point and near its closest one.
    every_family!(
        OrbitParticle::default(),
        3,
        1,
        State::new(0.0, V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 0.3, 0.0)),
        &HS,
        out
    );
    for (_, line) in &out {
        println!("{line}");
    }
    let bad: Vec<&str> = out.iter().filter(|(ok, _)| !ok).map(|(_, l)| l.as_str()).collect();
    assert!(bad.is_empty(), "at least 2 step sizes with the ratio in [0.1, 10] needed:\n{}", bad.join("\n"));
}

fn orbit() -> (OrbitParticle, State<3>) {
    (OrbitParticle::default(), State::new(0.0, V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 0.3, 0.0)))
}

fn orbit_run(tol: f64, t_end: f64) -> (AdaptiveRun<3, 1>, f64) {
    let (sys, s) = orbit();
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let options = AdaptiveOptions { rtol: tol, atol: tol, record_every: 0, ..AdaptiveOptions::default() };
    let run = integrate_adaptive(&mut st, s.t, &s.q, &s.v, t_end, &options, &mut NoObserver).unwrap();
    let exact = reference(&sys, s.t, &s.q, &s.v, t_end, &ReferenceOptions::default()).unwrap();
    let last = run.trajectory.last().unwrap();
    assert_eq!(last.t, t_end);
    let err = ((last.q - exact.q[0]).norm_squared() + (last.v - exact.v[0]).norm_squared()).sqrt();
    (run, err)
}

#[test]
fn controller_error_follows_the_tolerance_and_steps_follow_the_time_scale() {
    let (loose, e_loose) = orbit_run(1e-5, 3.0);
    let (tight, e_tight) = orbit_run(1e-8, 3.0);
    println!("tol 1e-5: error {e_loose:.3e}, {:?}", loose.report);
    println!("tol 1e-8: error {e_tight:.3e}, {:?}", tight.report);
    // Three decades of tolerance buy about two decades of global error
    // (order 4: `tol^{4/5}` per unit time, amplified by the close passes).
    assert!(e_tight < e_loose / 50.0, "error {e_tight:.3e} at 1e-8 vs {e_loose:.3e} at 1e-5");
    // The orbit's time scale varies by ≈ 100: so do the accepted steps.
    for r in [&loose.report, &tight.report] {
        assert!(r.largest_step > 20.0 * r.smallest_step, "{r:?}");
        assert!(r.rejected > 0, "{r:?}");
        if r.newton_failures == 0 {
            assert_eq!(r.solves, 3 * (r.accepted + r.rejected));
        }
    }
}

#[test]
fn adaptive_steps_beat_fixed_steps_of_equal_cost_on_the_orbit() {
    let t_end = 3.0;
    let (run, e_adaptive) = orbit_run(1e-8, t_end);
    let (sys, s) = orbit();
    let solves = run.report.solves;
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let options = RunOptions { record_every: 0, ..RunOptions::default() };
    let traj = st
        .integrate(
            s.t,
            &s.q,
            &s.v,
            Schedule::Fixed { h: t_end / solves as f64, steps: solves },
            &options,
            &mut NoObserver,
        )
        .unwrap();
    let exact = reference(&sys, s.t, &s.q, &s.v, t_end, &ReferenceOptions::default()).unwrap();
    let last = traj.last().unwrap();
    let e_fixed = ((last.q - exact.q[0]).norm_squared() + (last.v - exact.v[0]).norm_squared()).sqrt();
    println!("{solves} solves: adaptive error {e_adaptive:.3e}, fixed error {e_fixed:.3e}");
    assert!(e_fixed > 10.0 * e_adaptive, "fixed {e_fixed:.3e} vs adaptive {e_adaptive:.3e} at {solves} solves");
}

#[test]
fn adaptive_run_integrates_backward_and_reports_its_failures() {
    let (sys, s) = orbit();
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let o = AdaptiveOptions { rtol: 1e-8, atol: 1e-8, ..AdaptiveOptions::default() };
    let fwd = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 1.0, &o, &mut NoObserver).unwrap();
    let end = fwd.trajectory.last().unwrap();
    let back = integrate_adaptive(&mut st, end.t, &end.q, &end.v, 0.0, &o, &mut NoObserver).unwrap();
    let start = back.trajectory.last().unwrap();
    assert_eq!(start.t, 0.0);
    assert!((start.q - s.q).amax() < 1e-5 && (start.v - s.v).amax() < 1e-5, "{start:?}");
    assert_eq!(fwd.trajectory.samples.len(), fwd.report.accepted + 1);
    let few = AdaptiveOptions { max_steps: 3, ..o };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &few, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::TooManySteps { attempts: 3, .. }), "{err}");
    assert!(!err.to_string().contains("max_step ="), "{err}");
    // A largest step that cannot reach t_end within the limit is refused
    // before the first step, with the steps it needs, in both rules; one
    // that can just do so runs.
    let tiny = AdaptiveOptions { max_step: Some(1e-6), max_steps: 5, ..o };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &tiny, &mut NoObserver).unwrap_err();
    let AdaptiveError::MaxStepTooSmall { needed, max_steps: 5, .. } = err else { panic!("{err}") };
    assert_eq!(needed, 3e6);
    assert!(err.to_string().contains("max_step = 1.000e-6 (AdaptiveOptions::max_step"), "{err}");
    assert!(err.to_string().contains("raise max_step or the limit"), "{err}");
    let err = integrate_reversible(&mut st, s.t, &s.q, &s.v, 3.0, |_, _, _| 1.0, &tiny, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::MaxStepTooSmall { .. }), "{err}");
    let enough = AdaptiveOptions { max_step: Some(0.5), max_steps: 6, ..o };
    let run = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &enough, &mut NoObserver);
    assert!(!matches!(run, Err(AdaptiveError::MaxStepTooSmall { .. })), "{run:?}");
    // A given first step below the smallest step a run takes at t0 is
    // refused before the first step in both rules, naming the option and
    // the floor: the resolution of t far from 0, or min_step. The same
    // step capped by max_step counts as what it is; one at the floor runs.
    let far = 1e6;
    let resolution = 16.0 * f64::EPSILON * far;
    let below = AdaptiveOptions { initial_step: Some(1e-12), ..o };
    let err = integrate_adaptive(&mut st, far, &s.q, &s.v, far + 3.0, &below, &mut NoObserver).unwrap_err();
    let AdaptiveError::FirstStepTooSmall { first_step, floor, t0 } = err else { panic!("{err}") };
    assert_eq!((first_step, floor, t0), (1e-12, resolution, far));
    assert!(err.to_string().contains("first_step = 1.000e-12 (AdaptiveOptions::initial_step"), "{err}");
    assert!(err.to_string().contains("16 units in the last place of t0"), "{err}");
    let err =
        integrate_reversible(&mut st, far, &s.q, &s.v, far + 3.0, |_, _, _| 1.0, &below, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::FirstStepTooSmall { .. }), "{err}");
    let capped = AdaptiveOptions { initial_step: Some(1.0), max_step: Some(0.3), min_step: 0.25, ..o };
    let run = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &capped, &mut NoObserver);
    assert!(!matches!(run, Err(AdaptiveError::FirstStepTooSmall { .. })), "{run:?}");
    let under_min = AdaptiveOptions { initial_step: Some(0.1), min_step: 0.2, ..o };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &under_min, &mut NoObserver).unwrap_err();
    let AdaptiveError::FirstStepTooSmall { floor, .. } = err else { panic!("{err}") };
    assert_eq!(floor, 0.2);
    assert!(err.to_string().contains("below min_step = 2.000e-1 (AdaptiveOptions::min_step)"), "{err}");
    let at_floor = AdaptiveOptions { initial_step: Some(resolution), ..o };
    let run = integrate_adaptive(&mut st, far, &s.q, &s.v, far + 3.0, &at_floor, &mut NoObserver);
    assert!(!matches!(run, Err(AdaptiveError::FirstStepTooSmall { .. })), "{run:?}");
    let floor = AdaptiveOptions { min_step: 0.5, initial_step: Some(1.0), ..o };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &floor, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::StepSizeTooSmall { .. }), "{err}");
    assert!(err.to_string().contains("loosen rtol/atol"), "{err}");
}

#[test]
fn every_adaptive_option_is_checked_before_any_step() {
    let (sys, s) = orbit();
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let d = AdaptiveOptions::default();
    let cases: Vec<(AdaptiveOptions, &str)> = vec![
        (AdaptiveOptions { rtol: f64::NAN, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { rtol: 1e-17, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { atol: -1.0, ..d }, "AdaptiveOptions::atol"),
        (AdaptiveOptions { atol: 0.0, rtol: 0.0, ..d }, "AdaptiveOptions::atol"),
        // A relative error as large as the state controls no digit; an
        // absolute one above any state with a finite energy bounds nothing.
        (AdaptiveOptions { rtol: 1e300, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { rtol: 1.0, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { rtol: f64::INFINITY, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { rtol: -1e-6, ..d }, "AdaptiveOptions::rtol"),
        (AdaptiveOptions { atol: 1e300, ..d }, "AdaptiveOptions::atol"),
        (AdaptiveOptions { atol: f64::NAN, ..d }, "AdaptiveOptions::atol"),
        (AdaptiveOptions { initial_step: Some(0.0), ..d }, "AdaptiveOptions::initial_step"),
        (AdaptiveOptions { initial_step: Some(f64::INFINITY), ..d }, "AdaptiveOptions::initial_step"),
        (AdaptiveOptions { max_step: Some(f64::NAN), ..d }, "AdaptiveOptions::max_step"),
        (AdaptiveOptions { max_step: Some(1e-3), min_step: 1e-2, ..d }, "AdaptiveOptions::max_step"),
        (AdaptiveOptions { min_step: -1.0, ..d }, "AdaptiveOptions::min_step"),
        (AdaptiveOptions { safety: 0.0, ..d }, "AdaptiveOptions::safety"),
        (AdaptiveOptions { safety: 1.5, ..d }, "AdaptiveOptions::safety"),
        (AdaptiveOptions { min_factor: 1.0, ..d }, "AdaptiveOptions::min_factor"),
        (AdaptiveOptions { max_factor: 1.0, ..d }, "AdaptiveOptions::max_factor"),
        (AdaptiveOptions { max_factor: f64::INFINITY, ..d }, "AdaptiveOptions::max_factor"),
        (AdaptiveOptions { max_steps: 0, ..d }, "AdaptiveOptions::max_steps"),
        (AdaptiveOptions { consistency: ConsistencyPolicy::Error { tolerance: f64::NAN }, ..d }, "ConsistencyPolicy"),
    ];
    for (o, name) in cases {
        let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 1.0, &o, &mut NoObserver).unwrap_err();
        assert!(matches!(err, AdaptiveError::InvalidOption(_)) && err.to_string().contains(name), "{name}: {err}");
        let err = integrate_reversible(&mut st, s.t, &s.q, &s.v, 1.0, |_, _, _| 1.0, &o, &mut NoObserver).unwrap_err();
        assert!(matches!(err, AdaptiveError::InvalidOption(_)), "{name}: {err}");
    }
    // The edges of the ranges run.
    for (rtol, atol) in [(0.999, 1e-6), (1e-15, 0.0), (0.0, MAX_ABSOLUTE_TOLERANCE)] {
        AdaptiveOptions { rtol, atol, ..d }.validate().unwrap();
    }
    let loose = AdaptiveOptions { rtol: 0.999, max_step: Some(0.1), ..d };
    integrate_adaptive(&mut st, s.t, &s.q, &s.v, 0.2, &loose, &mut NoObserver).unwrap();
    // One step with its estimate checks the same ranges.
    for (rtol, atol) in [(1e300, 1e-6), (1e-6, 1e300), (f64::NAN, 1e-6), (0.0, 0.0)] {
        let err = st.step_with_estimate(&s, 0.01, rtol, atol).unwrap_err();
        assert!(matches!(err.error, StepError::InvalidOption(_)), "{rtol:e} {atol:e}: {}", err.error);
        assert_eq!(err.solves, 0);
    }
    for t_end in [0.0, f64::NAN, f64::INFINITY] {
        let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, t_end, &d, &mut NoObserver).unwrap_err();
        assert!(matches!(err, AdaptiveError::InvalidInterval { .. }), "{err}");
    }
    let bad_v = V::<3>::new(0.0, 0.3, 1.0);
    let err = integrate_adaptive(&mut st, s.t, &s.q, &bad_v, 1.0, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::Initial(_)), "{err}");
    let err = integrate_reversible(&mut st, s.t, &s.q, &s.v, 1.0, |_, _, _| -1.0, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::InvalidDensity { .. }), "{err}");
    let mut euler: Stepper![OrbitParticle, 1] = Stepper::new(sys, Tableau::new(Method::SymplecticEulerI).unwrap());
    let err = integrate_reversible(&mut euler, s.t, &s.q, &s.v, 1.0, |_, _, _| 1.0, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::NotSymmetric { .. }), "{err}");
}

#[test]
fn a_step_with_estimate_continues_like_the_half_steps_it_keeps() {
    let (sys, s) = orbit();
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let est = st.step_with_estimate(&s, 0.1, 1e-8, 1e-8).unwrap();
    assert!(st.is_warm_for(&est.state));
    // The kept state is the two half steps, bit for bit.
    let mut plain: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let mid = plain.step(&s, 0.05).unwrap().state;
    let end = plain.step(&mid, 0.05).unwrap().state;
    assert_eq!(end, est.state);
    // A failed attempt leaves the stepper continuing from where it was.
    let next = st.step_with_estimate(&est.state, 1e6, 1e-8, 1e-8);
    assert!(next.is_err());
    assert!(st.is_warm_for(&est.state));
}

/// `σ = r^{−3/2}`: the orbit's local time scale.
fn orbit_density(q: &V<3>) -> f64 {
    OrbitParticle::default().radius(q).powf(-1.5)
}

#[test]
fn reversible_steps_keep_the_energy_error_bounded() {
    let (sys, s) = orbit();
    let tol = 1e-6;
    let o = AdaptiveOptions { rtol: tol, atol: tol, record_every: 1, ..AdaptiveOptions::default() };
    let energy_error = |traj: &Trajectory<3, 1>, upto: f64| -> f64 {
        let e0 = traj.samples[0].energy.unwrap();
        traj.samples.iter().filter(|p| p.t <= upto).map(|p| (p.energy.unwrap() - e0).abs()).fold(0.0, f64::max)
    };
    let (t1, t2) = (25.0, 200.0);
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let rev =
        integrate_reversible(&mut st, s.t, &s.q, &s.v, t2, |_, q, _| orbit_density(q), &o, &mut NoObserver).unwrap();
    let ada = integrate_adaptive(&mut st, s.t, &s.q, &s.v, t2, &o, &mut NoObserver).unwrap();
    let (r1, r2) = (energy_error(&rev.trajectory, t1), energy_error(&rev.trajectory, t2));
    let (a1, a2) = (energy_error(&ada.trajectory, t1), energy_error(&ada.trajectory, t2));
    println!("reversible: |ΔE| {r1:.3e} to t = {t1}, {r2:.3e} to t = {t2}; {:?}", rev.report);
    println!("controlled: |ΔE| {a1:.3e} to t = {t1}, {a2:.3e} to t = {t2}; {:?}", ada.report);
    assert!(r2 < 2.0 * r1, "reversible energy error grows: {r1:.3e} → {r2:.3e}");
    // The error-controlled step sequence is not symmetric: its energy error
    // drifts (about linearly in t).
    assert!(a2 > 4.0 * a1, "controlled energy error {a1:.3e} → {a2:.3e}");
    assert!(rev.report.largest_step > 20.0 * rev.report.smallest_step, "{:?}", rev.report);
}

/// A pure relative tolerance (`atol = 0`) on a motion with coordinates that
/// stay at zero: the particle released at rest from `x = 1` keeps
/// `y = z = ẏ = ż = 0`, whose weights are 0. Their zero errors count zero:
/// `0/0` would make the error norm NaN and reject every step down to
/// `StepSizeTooSmall` at `t = 0`.
#[test]
fn a_pure_relative_tolerance_accepts_coordinates_at_rest() {
    let mut st: Stepper![Particle, 2] = Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let (q, v) = (V::<3>::new(1.0, 0.0, 0.0), V::<3>::zeros());
    for reversible in [false, true] {
        let o = AdaptiveOptions { rtol: 1e-8, atol: 0.0, ..AdaptiveOptions::default() };
        let run = if reversible {
            integrate_reversible(&mut st, 0.0, &q, &v, 1.0, |_, _, _| 1.0, &o, &mut NoObserver)
        } else {
            integrate_adaptive(&mut st, 0.0, &q, &v, 1.0, &o, &mut NoObserver)
        }
        .unwrap_or_else(|e| panic!("reversible {reversible}: {e}"));
        let end = run.trajectory.last().unwrap();
        assert_eq!(end.t, 1.0);
        // ẍ = −2x: x = cos(√2 t).
        let x = 2f64.sqrt().cos();
        assert!((end.q[0] - x).abs() < 1e-6, "reversible {reversible}: x = {} vs {x}", end.q[0]);
        assert_eq!((end.q[1], end.q[2], end.v[1], end.v[2]), (0.0, 0.0, 0.0, 0.0));
    }
}

/// An interval whose length overflows f64 is refused up front; a long one
/// is stepped from its start with the resolution of `t` there (not at
/// `t_end`: `t_end = 1e12` refused every step below 3.6e-3 from `t = 0`,
/// `t_end = 1e300` every step below 3.6e285), so it runs until
/// `max_steps` rather than stopping at once with `StepSizeTooSmall`.
#[test]
fn long_intervals_step_at_the_resolution_of_the_current_time() {
    let mut st: Stepper![Particle, 2] = Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let (q, v) = (V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 1.0, 0.0));
    let d = AdaptiveOptions::default();
    let err = integrate_adaptive(&mut st, -1e308, &q, &v, 1e308, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::InvalidInterval { .. }) && err.to_string().contains("overflows"), "{err}");
    let err = integrate_reversible(&mut st, 1e308, &q, &v, -1e308, |_, _, _| 1.0, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::InvalidInterval { .. }), "{err}");
    let few = AdaptiveOptions { max_steps: 20, ..d };
    for t_end in [1e12, 1e300, -1e300] {
        let err = integrate_adaptive(&mut st, 0.0, &q, &v, t_end, &few, &mut NoObserver).unwrap_err();
        assert!(matches!(err, AdaptiveError::TooManySteps { attempts: 20, .. }), "t_end = {t_end:e}: {err}");
        let err = integrate_reversible(&mut st, 0.0, &q, &v, t_end, |_, _, _| 1.0, &few, &mut NoObserver).unwrap_err();
        assert!(matches!(err, AdaptiveError::TooManySteps { attempts: 20, .. }), "reversible {t_end:e}: {err}");
    }
}

/// Reversible steps of 0.1 (a constant density, bounded by `max_step`)
/// accumulate to 0.9999999999999999 after ten steps, not 1: the rule's
/// next step would leave a sliver of 1.1e-16 behind, below the resolution
/// of `t`, where the run would stop with `StepSizeTooSmall`. The step is
/// stretched onto `t_end` instead.
#[test]
fn a_reversible_run_lands_on_t_end_across_round_off_in_t() {
    let mut st: Stepper![Particle, 2] = Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let (q, v) = (V::<3>::new(1.0, 0.0, 0.0), V::<3>::new(0.0, 1.0, 0.0));
    let o = AdaptiveOptions { rtol: 1e-2, atol: 1e-2, max_step: Some(0.1), ..AdaptiveOptions::default() };
    for t_end in [1.0, 10.0, -1.0] {
        let run = integrate_reversible(&mut st, 0.0, &q, &v, t_end, |_, _, _| 10.0, &o, &mut NoObserver)
            .unwrap_or_else(|e| panic!("t_end = {t_end}: {e}"));
        assert_eq!(run.trajectory.last().unwrap().t, t_end);
        assert_eq!(run.report.accepted, (10.0 * t_end.abs()).round() as usize, "t_end = {t_end}");
    }
}

/// `StepSizeTooSmall` names what asked for the step: the last error
/// estimate when there was one (not "error estimate inf" for a step refused
/// before its attempt), nothing when no estimate was made (a
/// `min_step` above the first step); an interval shorter than the
/// resolution of `t` at `t₀` is refused as an interval.
#[test]
fn step_size_too_small_names_the_estimate_that_asked_for_it() {
    let (sys, s) = orbit();
    let mut st: Stepper![OrbitParticle, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let o = AdaptiveOptions { rtol: 1e-8, atol: 1e-8, min_step: 0.5, initial_step: Some(1.0), ..Default::default() };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &o, &mut NoObserver).unwrap_err();
    let AdaptiveError::StepSizeTooSmall { scaled_error, .. } = err else { panic!("{err}") };
    assert!(scaled_error.is_finite() && scaled_error > 1.0, "{err}");
    assert!(err.to_string().contains(&format!("error estimate {}", crate::error::Sci(scaled_error))), "{err}");
    let o = AdaptiveOptions { min_step: 1e300, ..AdaptiveOptions::default() };
    let err = integrate_adaptive(&mut st, s.t, &s.q, &s.v, 3.0, &o, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::StepSizeTooSmall { .. }) && !err.to_string().contains("estimate"), "{err}");
    let d = AdaptiveOptions::default();
    let err = integrate_adaptive(&mut st, 1.0, &s.q, &s.v, 1.0 + 2.2e-16, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::InvalidInterval { .. }) && err.to_string().contains("resolution"), "{err}");
    let err =
        integrate_reversible(&mut st, 1.0, &s.q, &s.v, 1.0 - 2.2e-16, |_, _, _| 1.0, &d, &mut NoObserver).unwrap_err();
    assert!(matches!(err, AdaptiveError::InvalidInterval { .. }), "{err}");
}

crate::nonholonomic_system! {
    /// A sleigh with a cross term `e cos(θ) ẋ θ̇`, a time-dependent spring and
    /// an affine, time-dependent constraint.
    pub struct CrossSleigh {
        coordinates: [x, y, th],
        parameters: { m = 1.2, i0 = 0.3, e = 0.25, k = 0.8, u = 0.3, nu = 1.1 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + i0/2*dot(th)^2 + e*cos(th)*dot(x)*dot(th)
            - k*(1 + 0.3*sin(nu*t))/2*(x^2 + y^2),
        constraints: [ cos(th)*dot(y) - sin(th)*dot(x) - u*sin(nu*t) ],
    }
}

/// Near `t = 0` the resolution of `t` is subnormal, and a tolerance no
/// step meets (`atol = 1e-300` alone: the error estimate overflows) drives
/// the controller below the smallest normal step, which `Stepper::step`
/// refuses (`1/h` overflows). The run stops at that floor with
/// `StepSizeTooSmall` and the advice to loosen the tolerance, not with the
/// step's refusal of a step size the caller never chose, nor with the
/// advice to start nearer `t = 0`.
#[test]
fn a_tolerance_that_asks_for_subnormal_steps_is_step_size_too_small() {
    let sys = CrossSleigh::default();
    let q = V::<3>::new(0.5, -0.2, 0.4);
    let v =
        consistent_velocity(&sys, 0.0, &q, &V::<3>::new(0.8, 0.3, 0.9), ConsistencyPolicy::Project { tolerance: 0.0 })
            .unwrap();
    let mut st: Stepper![CrossSleigh, 3] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    // A step limit far above the ~1300 solves the refusal takes, far below
    // the default's 10⁷ attempts of a run that does not refuse.
    let o = AdaptiveOptions { rtol: 0.0, atol: 1e-300, max_steps: 10_000, ..AdaptiveOptions::default() };
    for t_end in [5.0, -5.0] {
        let adaptive = integrate_adaptive(&mut st, 0.0, &q, &v, t_end, &o, &mut NoObserver).unwrap_err();
        // The reversible rule takes its scale from a step that meets the
        // tolerance at t0, so it ends where the error-controlled run ends.
        let reversible =
            integrate_reversible(&mut st, 0.0, &q, &v, t_end, |_, _, _| 1.0, &o, &mut NoObserver).unwrap_err();
        for err in [adaptive, reversible] {
            let AdaptiveError::StepSizeTooSmall { t, min_step, scaled_error, .. } = err else {
                panic!("t_end = {t_end}: {err}")
            };
            assert!(t == 0.0 && min_step == f64::MIN_POSITIVE, "t_end = {t_end}: {err}");
            // The estimate is reported as the number it is (about 1e282),
            // although its squares overflow.
            assert!(scaled_error.is_finite() && scaled_error > 1e200, "t_end = {t_end}: {err}");
            let text = err.to_string();
            assert!(text.contains("loosen rtol/atol") && !text.contains("nearer t = 0"), "t_end = {t_end}: {text}");
            assert!(!text.contains("inf"), "t_end = {t_end}: {text}");
        }
    }
}
