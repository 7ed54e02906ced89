//! What sign-based detection sees, on event functions of `t` alone (so the
//! located times do not depend on the dense output):
//!
//! - each accepted (sub-)step is split into `EVENT_SUBINTERVALS` = 4 equal
//!   parts; two crossings of one function inside the same part cancel,
//!   whatever their distance (more than a fifth of a step included), and two
//!   in different parts are both seen, however close. A step with estimate of
//!   a tolerance-driven run is checked as its two half steps, so there the
//!   parts are an eighth of the step;
//! - `rising`/`falling` are taken in the direction the run goes: a backward
//!   run reports a function that increases with `t` as falling.

use spark_runtime::fixtures::paper::Particle;
use spark_runtime::{
    integrate_adaptive_with_events, AdaptiveOptions, Direction, EventGradient, EventSpec, Method, NoObserver,
    RunOptions, RuntimeEvents, Schedule, State, Stepper, Tableau, Vector, EVENT_SUBINTERVALS,
};

/// `g(t) = (t − a)(t − b)`: a falling zero at `a`, a rising one at `b > a`.
fn pair(a: f64, b: f64) -> impl Fn(usize, f64, &Vector<3>, &Vector<3>) -> EventGradient<3> {
    move |_, t, _, _| EventGradient {
        value: (t - a) * (t - b),
        t: 2.0 * t - a - b,
        q: Vector::zeros(),
        v: Vector::zeros(),
    }
}

fn start(t0: f64) -> State<3> {
    State::new(t0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0))
}

fn stepper() -> Stepper<Particle, 3, 1, 2, 11> {
    Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap())
}

/// The located `(t, rising)` of `g` over fixed steps `h` from `t0`.
fn fixed(
    g: &dyn Fn(usize, f64, &Vector<3>, &Vector<3>) -> EventGradient<3>,
    direction: Direction,
    t0: f64,
    h: f64,
    steps: usize,
) -> Vec<(f64, bool)> {
    let specs = [EventSpec { name: "g", direction, terminal: false, source: "" }];
    let events = RuntimeEvents { specs: &specs, gradient: g };
    let s = start(t0);
    let run = stepper()
        .integrate_with_events(
            t0,
            &s.q,
            &s.v,
            Schedule::Fixed { h, steps },
            &RunOptions::default(),
            &mut NoObserver,
            &events,
        )
        .unwrap();
    assert_eq!((run.report.rejected_steps, run.report.smallest_step), (0, h.abs()), "{:?}", run.report);
    run.events.iter().map(|e| (e.t, e.rising)).collect()
}

/// The located `(t, rising)` of `g` over a tolerance-driven run from `t0`
/// to `t_end` whose steps are all `|t_end − t0| / 2` (a loose tolerance, and
/// that step as first and largest step).
fn adaptive(
    g: &dyn Fn(usize, f64, &Vector<3>, &Vector<3>) -> EventGradient<3>,
    direction: Direction,
    t0: f64,
    t_end: f64,
) -> Vec<(f64, bool)> {
    let specs = [EventSpec { name: "g", direction, terminal: false, source: "" }];
    let events = RuntimeEvents { specs: &specs, gradient: g };
    let h = 0.5 * (t_end - t0).abs();
    let options = AdaptiveOptions {
        rtol: 0.1,
        atol: 0.1,
        initial_step: Some(h),
        max_step: Some(h),
        ..AdaptiveOptions::default()
    };
    let s = start(t0);
    let run = integrate_adaptive_with_events(&mut stepper(), t0, &s.q, &s.v, t_end, &options, &mut NoObserver, &events)
        .unwrap();
    assert_eq!((run.report.accepted, run.report.rejected), (2, 0), "{:?}", run.report);
    assert_eq!((run.report.smallest_step, run.report.largest_step), (h, h));
    run.trajectory.events.iter().map(|e| (e.t, e.rising)).collect()
}

fn assert_located(got: &[(f64, bool)], want: &[(f64, bool)], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: {got:?}, expected {want:?}");
    for (g, w) in got.iter().zip(want) {
        assert!((g.0 - w.0).abs() <= 1e-14 && g.1 == w.1, "{what}: {got:?}, expected {want:?}");
    }
}

#[test]
fn two_crossings_cancel_only_within_one_part_of_a_step() {
    assert_eq!(EVENT_SUBINTERVALS, 4);
    // Fixed steps of 1 from 0: parts [0, 0.25], [0.25, 0.5], …
    // 0.23 apart (more than a fifth of the step) in one part: not seen.
    assert_located(&fixed(&pair(0.26, 0.49), Direction::Both, 0.0, 1.0, 2), &[], "h = 1, zeros 0.26 and 0.49");
    // 0.02 apart in two parts: both seen, falling then rising.
    let both = [(0.24, false), (0.26, true)];
    assert_located(&fixed(&pair(0.24, 0.26), Direction::Both, 0.0, 1.0, 2), &both, "h = 1, zeros 0.24 and 0.26");
    // A tolerance-driven run with steps of 1 is checked as half steps: parts
    // of 0.125, so the pair fixed steps of 1 miss is seen, and a pair inside
    // [0.25, 0.375] is not.
    let seen = [(0.26, false), (0.49, true)];
    assert_located(&adaptive(&pair(0.26, 0.49), Direction::Both, 0.0, 2.0), &seen, "adaptive, zeros 0.26 and 0.49");
    assert_located(&adaptive(&pair(0.26, 0.37), Direction::Both, 0.0, 2.0), &[], "adaptive, zeros 0.26 and 0.37");
}

#[test]
fn directions_are_taken_in_the_direction_of_the_run() {
    // g = t − 0.5 increases with t: a forward run sees it rise, a backward
    // run (from 1 to 0) fall.
    let g = |_: usize, t: f64, _: &Vector<3>, _: &Vector<3>| EventGradient {
        value: t - 0.5,
        t: 1.0,
        q: Vector::zeros(),
        v: Vector::zeros(),
    };
    let rising = [(0.5, true)];
    let falling = [(0.5, false)];
    assert_located(&fixed(&g, Direction::Rising, 0.0, 0.1, 10), &rising, "forward, rising");
    assert_located(&fixed(&g, Direction::Falling, 0.0, 0.1, 10), &[], "forward, falling");
    assert_located(&fixed(&g, Direction::Rising, 1.0, -0.1, 10), &[], "backward, rising");
    assert_located(&fixed(&g, Direction::Falling, 1.0, -0.1, 10), &falling, "backward, falling");
    assert_located(&fixed(&g, Direction::Both, 1.0, -0.1, 10), &falling, "backward, both");
    assert_located(&adaptive(&g, Direction::Rising, 0.0, 1.0), &rising, "adaptive forward, rising");
    assert_located(&adaptive(&g, Direction::Rising, 1.0, 0.0), &[], "adaptive backward, rising");
    assert_located(&adaptive(&g, Direction::Falling, 1.0, 0.0), &falling, "adaptive backward, falling");
}
