//! Dense output and events on tolerance-driven and reversible runs: every
//! accepted step is handed to the same code as a fixed step's
//! (`DenseRun::accepted` in the driver), so
//!
//! - a dense observer sees every accepted step (both half steps of a step
//!   with estimate, each step of a reversible run) as a continuous chain from
//!   `t₀` to `t_end`, whose interpolants follow the solution;
//! - events are located where a fixed-step run locates them (to 1e-12 in t,
//!   with steps bounded so that the dense output is that accurate);
//! - a terminal event stops the run exactly at its time.

use super::affine::Affine;
use spark_runtime::fixtures::paper::{Particle, Skate};
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{
    integrate_adaptive, integrate_adaptive_with_events, integrate_reversible, integrate_reversible_with_events,
    nonholonomic_system, AdaptiveOptions, DenseStep, Direction, EventRecord, EventSpec, Method, NoObserver,
    NonholonomicSystem, Observer, RunOptions, RuntimeEvents, Schedule, State, Stepper, Tableau, Vector,
};

fn specs(n: usize, terminal: Option<usize>) -> Vec<EventSpec> {
    (0..n)
        .map(|i| EventSpec { name: "g", direction: Direction::Both, terminal: terminal == Some(i), source: "" })
        .collect()
}

/// Tight tolerances, and steps of at most `max_step`: an event is located on
/// the dense output, whose error at Gauss s = 4 grows like `h⁴`
/// (docs/adaptive.md §Events), so the tolerance alone, which lets the steps
/// of the particle grow to 0.18, would place it only to ~5e-10 although the
/// grid states are right to 1e-13. Bounded so that no dense piece is longer
/// than the fixed run's steps of 0.01: 0.02 for a step with estimate (two
/// half steps), 0.01 for a reversible step.
fn tight(max_step: f64) -> AdaptiveOptions {
    AdaptiveOptions { rtol: 1e-13, atol: 1e-13, max_step: Some(max_step), ..AdaptiveOptions::default() }
}

/// The events of a fixed-step run (Gauss s = 4, h = 0.01), of an adaptive
/// run and of a reversible run (both at rtol = atol = 1e-13), of the same
/// event functions.
#[allow(clippy::type_complexity)]
fn three_runs<Sys, const N: usize, const M: usize, const D: usize>(
    sys: Sys,
    start: &State<N>,
    gs: &[Affine<N>],
    terminal: Option<usize>,
    t_end: f64,
) -> [(Vec<EventRecord<N>>, State<N>); 3]
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let specs = specs(gs.len(), terminal);
    let gradient = |i: usize, t: f64, q: &Vector<N>, v: &Vector<N>| gs[i].gradient(t, q, v);
    let events = RuntimeEvents { specs: &specs, gradient: &gradient };
    let mut st = Stepper::<Sys, N, M, 4, D>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let h = 0.01;
    let steps = ((t_end - start.t) / h).round() as usize;
    let (q, v) = (&start.q, &start.v);
    let fixed = st
        .integrate_with_events(
            start.t,
            q,
            v,
            Schedule::Fixed { h, steps },
            &RunOptions::default(),
            &mut NoObserver,
            &events,
        )
        .unwrap();
    let adaptive =
        integrate_adaptive_with_events(&mut st, start.t, q, v, t_end, &tight(0.02), &mut NoObserver, &events).unwrap();
    let density = |_: f64, _: &Vector<N>, v: &Vector<N>| 1.0 + v.norm_squared();
    let reversible = integrate_reversible_with_events(
        &mut st,
        start.t,
        q,
        v,
        t_end,
        density,
        &tight(0.01),
        &mut NoObserver,
        &events,
    )
    .unwrap();
    for (name, run) in [("adaptive", &adaptive), ("reversible", &reversible)] {
        assert_eq!(run.trajectory.report.events, run.trajectory.events.len(), "{name}");
        assert!(run.report.accepted > 0, "{name}");
    }
    [
        (fixed.events.clone(), fixed.last().unwrap()),
        (adaptive.trajectory.events.clone(), adaptive.trajectory.last().unwrap()),
        (reversible.trajectory.events.clone(), reversible.trajectory.last().unwrap()),
    ]
}

/// The largest |Δt| between the fixed-step events and those of the other
/// runs, which must be the same events in the same order.
fn compare<const N: usize>(name: &str, runs: &[(Vec<EventRecord<N>>, State<N>); 3]) -> f64 {
    let fixed = &runs[0].0;
    assert!(!fixed.is_empty(), "{name}: no events");
    let mut worst = 0.0f64;
    for (run, (events, _)) in ["adaptive", "reversible"].iter().zip(&runs[1..]) {
        assert_eq!(events.len(), fixed.len(), "{name} {run}: {} events, fixed steps {}", events.len(), fixed.len());
        for (a, f) in events.iter().zip(fixed) {
            assert_eq!((a.index, a.rising), (f.index, f.rising), "{name} {run}");
            let dt = (a.t - f.t).abs();
            assert!(dt <= 1e-12, "{name} {run}: event {} at {:.15}, fixed steps {:.15}", a.index, a.t, f.t);
            assert!(a.residual.abs() < 1e-11, "{name} {run}: |g| = {:.1e}", a.residual);
            worst = worst.max(dt);
        }
    }
    worst
}

#[test]
fn events_on_adaptive_runs_agree_with_the_fixed_step_locations() {
    let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let gs = [
        Affine { w: [1.0, 0.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.3, kappa: 0.0 },
        Affine { w: [0.0; 3], u: [0.0, 1.0, 0.0], a: 0.0, b: 0.0, kappa: 0.0 },
        Affine { w: [0.0, 1.0, 0.0], u: [0.0; 3], a: -0.1, b: 0.0, kappa: 0.0 },
    ];
    let runs = three_runs::<_, 3, 1, { 4 * 4 + 3 }>(Particle, &particle, &gs, None, 4.0);
    let worst_particle = compare("particle", &runs);
    let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let gs = [
        Affine { w: [0.0, 0.0, 1.0], u: [0.0; 3], a: 0.0, b: -2.0, kappa: 0.0 },
        Affine { w: [0.0; 3], u: [1.0, 0.0, 0.0], a: 0.0, b: -0.2, kappa: 0.0 },
    ];
    let runs = three_runs::<_, 3, 1, { 4 * 4 + 3 }>(Skate::default(), &skate, &gs, None, 4.0);
    let worst_skate = compare("skate", &runs);
    println!("max |Δt| adaptive/reversible vs fixed steps: particle {worst_particle:.1e}, skate {worst_skate:.1e}");
}

#[test]
fn a_terminal_event_stops_an_adaptive_run_exactly() {
    let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    // A counting event at x = 0.3, and y = 0.5 (terminal).
    let gs = [
        Affine { w: [1.0, 0.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.3, kappa: 0.0 },
        Affine { w: [0.0, 1.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.5, kappa: 0.0 },
    ];
    let runs = three_runs::<_, 3, 1, { 4 * 4 + 3 }>(Particle, &particle, &gs, Some(1), 4.0);
    compare("particle, terminal", &runs);
    for (events, last) in &runs {
        let stop = events.last().unwrap();
        assert_eq!(stop.index, 1);
        assert_eq!(last.t, stop.t, "the run ends at the event time");
        assert_eq!((last.q, last.v), (stop.q, stop.v));
        assert!((last.q[1] - 0.5).abs() < 1e-12);
        assert!(last.t < 4.0);
    }
    // The report, the observer and the last sample agree on where the run stopped.
    let specs = specs(2, Some(1));
    let gradient = |i: usize, t: f64, q: &Vector<3>, v: &Vector<3>| gs[i].gradient(t, q, v);
    let events = RuntimeEvents { specs: &specs, gradient: &gradient };
    let mut st = Stepper::<Particle, 3, 1, 4, 19>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let mut seen = Vec::new();
    let mut observer = |s: &State<3>, _: usize| seen.push(s.t);
    let (q, v) = (&particle.q, &particle.v);
    let run = integrate_adaptive_with_events(&mut st, 0.0, q, v, 4.0, &tight(0.02), &mut observer, &events).unwrap();
    let stop = run.trajectory.events.last().unwrap();
    assert_eq!(run.trajectory.report.terminal_event, Some(1));
    assert_eq!(*seen.last().unwrap(), stop.t);
    assert_eq!(seen.len(), run.report.accepted);
    assert_eq!(run.trajectory.samples.last().unwrap().t, stop.t);
}

nonholonomic_system! {
    /// A ball thrown up on a vertical line; events on its height.
    pub struct Ball {
        coordinates: [y, x],
        parameters: { g = 9.81 },
        lagrangian: dot(y)^2/2 + dot(x)^2/2 - g*y,
        constraints: [ dot(x) - y ],
        events: {
            ground: falling(y) terminal,
            apex: falling(dot(y)),
        },
    }
}

#[test]
fn adaptive_runs_locate_the_declared_events_of_a_system() {
    const { assert!(<Ball as NonholonomicSystem<2, 1>>::HAS_EVENTS) };
    // y(t) = 1 + 2t − g t²/2 (free fall): apex at 2/g, ground at (2 + √(4 + 2g))/g.
    let g = 9.81;
    let (apex, ground) = (2.0 / g, (2.0 + (4.0f64 + 2.0 * g).sqrt()) / g);
    let (q0, v0) = (Vector::<2>::new(1.0, 0.0), Vector::<2>::new(2.0, 1.0));
    let options = AdaptiveOptions { rtol: 1e-10, atol: 1e-10, ..AdaptiveOptions::default() };
    let mut st: spark_runtime::Stepper![Ball, 2] = Stepper::new(Ball::default(), Tableau::new(Method::Gauss).unwrap());
    let adaptive = integrate_adaptive(&mut st, 0.0, &q0, &v0, 10.0, &options, &mut NoObserver).unwrap();
    let reversible =
        integrate_reversible(&mut st, 0.0, &q0, &v0, 10.0, |_, _, _| 1.0, &options, &mut NoObserver).unwrap();
    for (name, run) in [("adaptive", adaptive), ("reversible", reversible)] {
        let t = &run.trajectory;
        let names: Vec<&str> = t.events.iter().map(|e| e.name.as_str()).collect();
        assert_eq!(names, ["apex", "ground"], "{name}");
        assert!((t.events[0].t - apex).abs() < 1e-12, "{name}: apex at {} vs {apex}", t.events[0].t);
        assert!((t.events[1].t - ground).abs() < 1e-12, "{name}: ground at {} vs {ground}", t.events[1].t);
        assert_eq!(t.report.terminal_event, Some(0));
        assert_eq!(t.samples.last().unwrap().t, t.events[1].t, "{name}: the run stops at the ground");
    }
}

/// Every dense step's interval, its states at both ends, and its samples at
/// three interior points; every observed state.
#[derive(Default)]
struct Chain {
    steps: Vec<(State<3>, State<3>, [State<3>; 3])>,
    observed: Vec<State<3>>,
}

impl Observer<3, 1> for Chain {
    const DENSE: bool = true;
    fn observe<Sys: NonholonomicSystem<3, 1>>(&mut self, _: &Sys, state: &State<3>, _: usize) {
        self.observed.push(*state);
    }
    fn observe_dense<const S: usize>(&mut self, step: &DenseStep<'_, 3, S>) {
        let (a, b) = (step.start.t, step.end.t);
        let inside = [0.25, 0.5, 0.75].map(|f| step.state_at(a + f * (b - a)));
        self.steps.push((step.state_at(a), step.state_at(b), inside));
    }
}

/// The largest deviation of `samples` from the reference solution.
fn deviation(start: &State<3>, samples: &[State<3>]) -> f64 {
    let times: Vec<f64> = samples.iter().map(|s| s.t).collect();
    let r = integrate_at(&Particle, start.t, &start.q, &start.v, &times, &ReferenceOptions::default()).unwrap();
    let mut worst = 0.0f64;
    for ((s, q), v) in samples.iter().zip(&r.q).zip(&r.v) {
        worst = worst.max((s.q - q).amax()).max((s.v - v).amax());
    }
    worst
}

/// Checks that the dense steps chain from the start to `t_end` without a gap
/// or an overlap, `per_step` of them per accepted step, ending at the
/// observed states; and that between grid points they follow the solution
/// as closely as the dense output of fixed steps as large as the run's
/// largest (within a factor 2: the run's grid errors differ from the fixed
/// run's). Returns both deviations.
fn check_chain<const D: usize>(
    name: &str,
    chain: &Chain,
    stepper: &mut Stepper<Particle, 3, 1, 2, D>,
    start: &State<3>,
    t_end: f64,
    per_step: usize,
    largest: f64,
) -> (f64, f64) {
    assert_eq!(chain.steps.len(), per_step * chain.observed.len(), "{name}: dense steps per accepted step");
    assert_eq!(chain.steps[0].0, *start, "{name}: the first dense step starts at the initial state");
    for (k, w) in chain.steps.windows(2).enumerate() {
        assert_eq!(w[0].1, w[1].0, "{name}: dense steps {k} and {} do not join", k + 1);
    }
    for (k, observed) in chain.observed.iter().enumerate() {
        let end = &chain.steps[per_step * (k + 1) - 1].1;
        assert_eq!((end.t, end.q, end.v), (observed.t, observed.q, observed.v), "{name}: accepted step {k}");
    }
    assert_eq!(chain.steps.last().unwrap().1.t, t_end);
    let inside: Vec<State<3>> = chain.steps.iter().flat_map(|s| s.2).collect();
    let worst = deviation(start, &inside);
    let times: Vec<f64> = inside.iter().map(|s| s.t).collect();
    let h = largest * t_end.signum();
    let fixed = stepper
        .integrate(
            start.t,
            &start.q,
            &start.v,
            Schedule::Sampled { h, times: &times },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    let fixed_states: Vec<State<3>> = fixed.samples[1..].iter().map(|s| State::new(s.t, s.q, s.v)).collect();
    let bound = deviation(start, &fixed_states);
    assert!(
        worst <= 2.0 * bound,
        "{name}: dense output off the solution by {worst:.1e}, fixed steps of {h}: {bound:.1e}"
    );
    (worst, bound)
}

#[test]
fn dense_observers_see_every_accepted_adaptive_step_continuously() {
    let start = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let options = AdaptiveOptions { rtol: 1e-8, atol: 1e-8, ..AdaptiveOptions::default() };
    let mut st = Stepper::<Particle, 3, 1, 2, 11>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    for t_end in [3.0, -3.0] {
        let mut chain = Chain::default();
        let run = integrate_adaptive(&mut st, 0.0, &start.q, &start.v, t_end, &options, &mut chain).unwrap();
        assert_eq!(chain.observed.len(), run.report.accepted);
        let largest = run.report.largest_step;
        let (a, fa) = check_chain("adaptive", &chain, &mut st, &start, t_end, 2, largest);
        let mut chain = Chain::default();
        let density = |_: f64, _: &Vector<3>, v: &Vector<3>| 1.0 + v.norm_squared();
        let run = integrate_reversible(&mut st, 0.0, &start.q, &start.v, t_end, density, &options, &mut chain).unwrap();
        assert_eq!(chain.observed.len(), run.report.accepted);
        let largest = run.report.largest_step;
        let (r, fr) = check_chain("reversible", &chain, &mut st, &start, t_end, 1, largest);
        println!(
            "t_end {t_end}: dense output vs reference: adaptive {a:.1e} (fixed steps of its largest {fa:.1e}), \
             reversible {r:.1e} (fixed {fr:.1e})"
        );
    }
}

/// The table of docs/adaptive.md §Events: how accurately an adaptive run
/// places an event against the largest step it may take. Particle, Gauss
/// s = 4, rtol = atol = 1e-13, `x = 0.3` crossing over `t ≤ 4`, against the
/// fixed run with h = 0.01. The dense output's error grows like a power of
/// the step, so each smaller bound places the event more accurately, down
/// to the round-off of the comparison, 1e-12, at 0.02 (pieces of 0.01, the
/// fixed run's step) or before.
#[test]
fn adaptive_event_times_follow_the_largest_step() {
    let start = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let gs = [Affine { w: [1.0, 0.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.3, kappa: 0.0 }];
    let specs = specs(1, None);
    let gradient = |i: usize, t: f64, q: &Vector<3>, v: &Vector<3>| gs[i].gradient(t, q, v);
    let events = RuntimeEvents { specs: &specs, gradient: &gradient };
    let mut st = Stepper::<Particle, 3, 1, 4, { 4 * 4 + 3 }>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let (q, v) = (&start.q, &start.v);
    let fixed = st
        .integrate_with_events(
            0.0,
            q,
            v,
            Schedule::Fixed { h: 0.01, steps: 400 },
            &RunOptions::default(),
            &mut NoObserver,
            &events,
        )
        .unwrap();
    let fixed_end = fixed.last().unwrap();
    assert!(!fixed.events.is_empty());
    println!("| `max_step` | largest step | event time difference | end state difference |");
    let mut previous = f64::INFINITY;
    for max_step in [None, Some(0.1), Some(0.05), Some(0.02)] {
        let options = AdaptiveOptions { rtol: 1e-13, atol: 1e-13, max_step, ..AdaptiveOptions::default() };
        let run = integrate_adaptive_with_events(&mut st, 0.0, q, v, 4.0, &options, &mut NoObserver, &events).unwrap();
        let found = &run.trajectory.events;
        assert_eq!(found.len(), fixed.events.len(), "max_step {max_step:?}");
        let dt = found.iter().zip(&fixed.events).map(|(a, f)| (a.t - f.t).abs()).fold(0.0, f64::max);
        let end = run.trajectory.last().unwrap();
        let dy = (end.q - fixed_end.q).amax().max((end.v - fixed_end.v).amax());
        let bound = max_step.map_or("none".to_string(), |h| h.to_string());
        println!("| {bound} | {:.2} | {dt:.1e} | {dy:.1e} |", run.report.largest_step);
        // About 1e-12 the comparison reaches the round-off of the two runs.
        assert!(
            dt < previous || dt <= 2e-12,
            "max_step {max_step:?}: event time difference {dt:.1e}, not below {previous:.1e}"
        );
        assert!(dy < 1e-12, "max_step {max_step:?}: end states {dy:.1e} apart");
        previous = dt;
    }
    assert!(previous <= 1e-12, "max_step 0.02: event time difference {previous:.1e}");
}
