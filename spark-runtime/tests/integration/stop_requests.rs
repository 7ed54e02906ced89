//! Runs that their caller stops: an observer's `stop_requested` in the
//! fixed-step, adaptive and reversible drivers, and the `stop` of
//! `integrate_ensemble_until`, each ending where it was asked with its own
//! error and, up to there, the run it would otherwise have been.

use spark_runtime::fixtures::paper::{MpParticles, Skate};
use spark_runtime::{
    integrate_adaptive, integrate_ensemble, integrate_ensemble_until, integrate_reversible, AdaptiveError,
    AdaptiveOptions, IntegrationError, Jacobian, LaneError, Method, NewtonMode, NewtonOptions, NonholonomicSystem,
    Observer, RunOptions, Schedule, State, Stepper, Tableau, Vector,
};

/// Counts the accepted steps and asks to stop after the `after`-th.
struct StopAfter {
    after: usize,
    seen: Vec<State<3>>,
}

impl Observer<3, 1> for StopAfter {
    fn observe<Sys: NonholonomicSystem<3, 1>>(&mut self, _: &Sys, state: &State<3>, _: usize) {
        self.seen.push(*state);
    }
    fn stop_requested(&mut self) -> bool {
        self.seen.len() >= self.after
    }
}

fn skate_stepper() -> Stepper<Skate, 3, 1, 2, 11> {
    Stepper::new(Skate::default(), Tableau::new(Method::Gauss).unwrap())
}

const Q0: [f64; 3] = [0.0, 0.0, 0.0];
const V0: [f64; 3] = [0.0, 0.0, 1.0];

#[test]
fn a_fixed_step_run_stops_after_the_step_its_observer_asks_to_stop_at() {
    let (q0, v0) = (Vector::<3>::from(Q0), Vector::<3>::from(V0));
    let schedule = Schedule::Fixed { h: 0.1, steps: 1000 };
    let options = RunOptions { record_every: 1, ..RunOptions::default() };
    let mut all = StopAfter { after: usize::MAX, seen: Vec::new() };
    let full = skate_stepper().integrate(0.0, &q0, &v0, schedule, &options, &mut all).unwrap();
    assert_eq!(full.samples.len(), 1001);

    let mut observer = StopAfter { after: 37, seen: Vec::new() };
    match skate_stepper().integrate(0.0, &q0, &v0, schedule, &options, &mut observer) {
        Err(IntegrationError::Stopped { steps, t, partial }) => {
            assert_eq!(steps, 37);
            assert_eq!(partial.steps, 37);
            assert_eq!(t.to_bits(), all.seen[36].t.to_bits());
            let message = IntegrationError::Stopped { steps, t, partial }.to_string();
            assert!(message.contains("stopped by its observer after 37 steps"), "{message}");
        }
        other => panic!("expected Stopped after 37 steps, got {other:?}"),
    }
    // The steps it took are the uninterrupted run's, bit for bit.
    assert_eq!(observer.seen, all.seen[..37]);
}

#[test]
fn a_stop_asked_at_the_last_step_is_a_finished_run() {
    let (q0, v0) = (Vector::<3>::from(Q0), Vector::<3>::from(V0));
    let mut observer = StopAfter { after: 10, seen: Vec::new() };
    let run = skate_stepper()
        .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 10 }, &RunOptions::default(), &mut observer)
        .unwrap();
    assert_eq!(run.report.steps, 10);
}

#[test]
fn adaptive_and_reversible_runs_stop_where_their_observer_asks() {
    let (q0, v0) = (Vector::<3>::from(Q0), Vector::<3>::from(V0));
    let options = AdaptiveOptions { rtol: 1e-8, atol: 1e-8, ..AdaptiveOptions::default() };
    let mut observer = StopAfter { after: 5, seen: Vec::new() };
    match integrate_adaptive(&mut skate_stepper(), 0.0, &q0, &v0, 100.0, &options, &mut observer) {
        Err(AdaptiveError::Stopped { t, partial }) => {
            assert_eq!(partial.accepted, 5);
            assert_eq!(t.to_bits(), observer.seen[4].t.to_bits());
            assert!(t < 100.0);
        }
        other => panic!("expected Stopped, got {other:?}"),
    }
    let mut observer = StopAfter { after: 7, seen: Vec::new() };
    let density = |_: f64, _: &Vector<3>, _: &Vector<3>| 1.0;
    match integrate_reversible(&mut skate_stepper(), 0.0, &q0, &v0, 100.0, density, &options, &mut observer) {
        Err(AdaptiveError::Stopped { partial, .. }) => assert_eq!(partial.accepted, 7),
        other => panic!("expected Stopped, got {other:?}"),
    }
}

/// Twelve McLachlan–Perlmutter members (two lane groups, one of them
/// partly filled), as in the lane tests.
fn mp_starts() -> Vec<State<7>> {
    (0..12)
        .map(|j| {
            let q0 = Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
            let mut v0 = Vector::<7>::zeros();
            v0[1] = 0.04 * j as f64;
            State::new(0.0, q0, v0)
        })
        .collect()
}

fn mp_options() -> NewtonOptions {
    NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Auto, ..NewtonOptions::default() }
}

#[test]
fn an_ensemble_stops_when_asked_and_is_otherwise_unchanged_by_the_checks() {
    let tableau = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let starts = mp_starts();
    // 3000 steps sampled every 700: the checks every 1024 steps fall
    // between samples, and the samples stay where they were.
    let plain =
        integrate_ensemble::<_, 7, 1, 2, 23>(&MpParticles, tableau, mp_options(), &starts, 0.05, 3000, 700).unwrap();
    let never = integrate_ensemble_until::<_, 7, 1, 2, 23>(
        &MpParticles,
        tableau,
        mp_options(),
        &starts,
        0.05,
        3000,
        700,
        spark_runtime::DEFAULT_MAX_HALVINGS,
        &|| false,
    )
    .unwrap();
    assert_eq!(plain, never);
    for run in &plain {
        let times: Vec<f64> = run.samples.iter().map(|s| s.t).collect();
        let expected: Vec<f64> = [0, 700, 1400, 2100, 2800, 3000].iter().map(|&k| k as f64 * 0.05).collect();
        assert_eq!(times.len(), expected.len());
        for (t, e) in times.iter().zip(&expected) {
            assert!((t - e).abs() < 1e-9, "sample at {t}, expected {e}");
        }
    }
    let stopped = integrate_ensemble_until::<_, 7, 1, 2, 23>(
        &MpParticles,
        tableau,
        mp_options(),
        &starts,
        0.05,
        1_000_000,
        0,
        spark_runtime::DEFAULT_MAX_HALVINGS,
        &|| true,
    );
    assert_eq!(stopped, Err(LaneError::Stopped { steps: 1024 }));
}

/// An observer that declares it watches no step (`Observer::STEPS = false`)
/// is never called, not even asked to stop, and the run is the one
/// `NoObserver` gets, bit for bit.
#[test]
fn an_observer_that_watches_no_step_is_not_called() {
    struct Unwatching {
        called: usize,
    }
    impl Observer<3, 1> for Unwatching {
        const STEPS: bool = false;
        fn observe<Sys: NonholonomicSystem<3, 1>>(&mut self, _: &Sys, _: &State<3>, _: usize) {
            self.called += 1;
        }
        fn stop_requested(&mut self) -> bool {
            self.called += 1;
            true
        }
    }
    let (q0, v0) = (Vector::<3>::from(Q0), Vector::<3>::from(V0));
    let schedule = Schedule::Fixed { h: 0.1, steps: 50 };
    let options = RunOptions { record_every: 1, ..RunOptions::default() };
    let mut observer = Unwatching { called: 0 };
    let run = skate_stepper().integrate(0.0, &q0, &v0, schedule, &options, &mut observer).unwrap();
    assert_eq!(observer.called, 0);
    let quiet = skate_stepper().integrate(0.0, &q0, &v0, schedule, &options, &mut spark_runtime::NoObserver).unwrap();
    let bits = |t: &spark_runtime::Trajectory<3, 1>| {
        t.samples
            .iter()
            .flat_map(|s| [s.t].into_iter().chain(s.q.iter().copied()).chain(s.v.iter().copied()).map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&run), bits(&quiet));
    assert_eq!(run.samples.len(), 51);
}
