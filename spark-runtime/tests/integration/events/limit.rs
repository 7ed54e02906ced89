//! A run keeps at most `max_events` located events: one more ends it with
//! `TooManyEvents`, fixed steps and tolerance-driven alike, instead of
//! keeping events until memory runs out. The default limit is what fits in
//! the record memory limit.

use spark_runtime::events::max_located_events;
use spark_runtime::fixtures::paper::Particle;
use spark_runtime::{
    integrate_adaptive_with_events, AdaptiveError, AdaptiveOptions, Direction, EventGradient, EventSpec,
    IntegrationError, Method, NoObserver, RunOptions, RuntimeEvents, Schedule, State, Stepper, Tableau, Vector,
};

/// `sin(10 t)`: a zero every π/10, about 32 over [0, 10].
fn often(_: usize, t: f64, _: &Vector<3>, _: &Vector<3>) -> EventGradient<3> {
    EventGradient { value: (10.0 * t).sin(), t: 10.0 * (10.0 * t).cos(), q: Vector::zeros(), v: Vector::zeros() }
}

const SPECS: [EventSpec; 1] = [EventSpec { name: "often", direction: Direction::Both, terminal: false, source: "" }];

fn stepper() -> Stepper<Particle, 3, 1, 2, 11> {
    Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap())
}

fn start() -> State<3> {
    State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0))
}

#[test]
fn a_fixed_step_run_that_locates_more_events_than_it_keeps_ends_with_an_error() {
    let events = RuntimeEvents { specs: &SPECS, gradient: &often };
    let s = start();
    let run = |max_events| {
        let options = RunOptions { max_events, ..RunOptions::default() };
        let schedule = Schedule::Fixed { h: 0.01, steps: 1000 };
        stepper().integrate_with_events(0.0, &s.q, &s.v, schedule, &options, &mut NoObserver, &events)
    };
    let all = run(None).unwrap();
    assert_eq!(all.events.len(), 31, "{:?}", all.report);
    assert_eq!(run(Some(31)).unwrap().events, all.events);
    let err = run(Some(10)).unwrap_err();
    let IntegrationError::TooManyEvents { max_events: 10, t, ref partial } = err else { panic!("{err}") };
    // The eleventh zero, 11π/10, lies in the step from 3.45.
    assert_eq!(t, 0.01 * 345.0);
    assert_eq!(partial.events, 10);
    assert!(err.to_string().contains("more than 10 events"), "{err}");
    assert!(err.to_string().contains("RunOptions::max_events"), "{err}");
}

#[test]
fn a_tolerance_driven_run_that_locates_more_events_than_it_keeps_ends_with_an_error() {
    let events = RuntimeEvents { specs: &SPECS, gradient: &often };
    let s = start();
    let run = |max_events| {
        let options = AdaptiveOptions { rtol: 1e-8, atol: 1e-8, max_events, ..AdaptiveOptions::default() };
        integrate_adaptive_with_events(&mut stepper(), 0.0, &s.q, &s.v, 10.0, &options, &mut NoObserver, &events)
    };
    assert_eq!(run(None).unwrap().trajectory.events.len(), 31);
    let err = run(Some(5)).unwrap_err();
    let AdaptiveError::TooManyEvents { max_events: 5, t, .. } = err else { panic!("{err}") };
    // The sixth zero, 6π/10, lies in the step from `t`.
    assert!(t < 6.0 * std::f64::consts::PI / 10.0, "{t}");
    assert!(err.to_string().contains("more than 5 events"), "{err}");
}

#[test]
fn the_default_limit_is_what_fits_in_the_record_memory() {
    let bytes = spark_runtime::record_memory_limit();
    let max = max_located_events::<3>(&SPECS) as u64;
    assert!(max > 0);
    let per_event = bytes / max;
    // A record and a row of it: more than the 16 coordinates and velocities
    // of each, at most a few hundred bytes.
    assert!((2 * 6 * 8..1024).contains(&per_event), "{per_event} bytes an event");
}
