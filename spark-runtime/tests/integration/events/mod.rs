//! Events located on the dense output.
//!
//! - Accuracy: on five systems (the paper's particle, skate, mobile robot,
//!   McLachlan–Perlmutter particles, and a system with a time-dependent,
//!   velocity-nonlinear constraint) every located event time agrees to
//!   ≤ 1e-12 with an independent bracket: bisection in `t` on the event
//!   function along the reference integrator (extrapolation at 1e-14), which
//!   shares nothing with the SPARK step or its dense output. Far from
//!   `t = 0` (runs that start at `t = 1000`) the same holds: the location
//!   tolerance is a fraction of the step, not relative to `t`.
//! - In other units of time (a system whose time scale is `τ`) the event
//!   times are `τ` times those of `τ = 1`, to 1e-13 of `τ`.
//! - An event exactly at a step boundary is reported once.
//! - Several events in one step come in time order; directions filter.
//! - A terminal event ends the run exactly at its time.
//! - Events declared in the DSL are generated with exact derivatives and
//!   stop `integrate` when terminal; a scene adds the event effects it
//!   selects to the base events, which every scene keeps.
//! - Tolerance-driven and reversible runs locate events and feed dense
//!   observers as fixed-step runs do (`adaptive`).

mod adaptive;
mod affine;
mod detection;
mod limit;

use affine::Affine;
use spark_runtime::fixtures::paper::{General, MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::reference::{integrate, integrate_at, ReferenceOptions};
use spark_runtime::{
    event_time_tolerance, nonholonomic_system, Direction, EventFunctions, EventGradient, EventSpec, Method, NoEvents,
    NoObserver, NonholonomicSystem, Observer, RunOptions, RuntimeEvents, Schedule, State, Stepper, Tableau, Trajectory,
    Vector,
};

/// The first zero of `g` after `t0` along the reference solution, by a scan
/// every `scan` and bisection to the resolution of `t`.
fn reference_zero<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    start: &State<N>,
    g: &Affine<N>,
    t_end: f64,
    scan: f64,
    after: f64,
) -> Option<f64>
where
    Sys: NonholonomicSystem<N, M>,
{
    let opts = ReferenceOptions::default();
    let count = ((t_end - start.t) / scan).ceil() as usize;
    let times: Vec<f64> = (1..=count).map(|k| start.t + k as f64 * scan).collect();
    let r = integrate_at(sys, start.t, &start.q, &start.v, &times, &opts).unwrap();
    let mut a = *start;
    let mut ga = g.gradient(a.t, &a.q, &a.v).value;
    for (k, &t) in times.iter().enumerate() {
        let gb = g.gradient(t, &r.q[k], &r.v[k]).value;
        if t > after && (ga < 0.0) != (gb < 0.0) && a.t >= after - scan {
            // Bisection from the left end, integrating the reference each time.
            let (mut lo, mut hi) = (a.t, t);
            let left = a;
            // To the resolution of `t`: the bracket is as sharp as a double.
            loop {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                let s = integrate(sys, left.t, &left.q, &left.v, mid, &opts).unwrap();
                let gm = g.gradient(mid, &s.q[0], &s.v[0]).value;
                if (gm < 0.0) == (ga < 0.0) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return Some(0.5 * (lo + hi));
        }
        a = State::new(t, r.q[k], r.v[k]);
        ga = gb;
    }
    None
}

/// Runs Gauss s = 4 with `h` over `[t0, t_end]` with the events `gs` and
/// checks every located event against the reference bracket. Returns the
/// largest difference and the number of events.
fn check_system<Sys, const N: usize, const M: usize, const D: usize>(
    sys: Sys,
    start: State<N>,
    gs: &[Affine<N>],
    h: f64,
    t_end: f64,
) -> (f64, usize)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let specs: Vec<EventSpec> =
        gs.iter().map(|_| EventSpec { name: "g", direction: Direction::Both, terminal: false, source: "" }).collect();
    let gradient = |i: usize, t: f64, q: &Vector<N>, v: &Vector<N>| gs[i].gradient(t, q, v);
    let events = RuntimeEvents { specs: &specs, gradient: &gradient };
    let mut st = Stepper::<Sys, N, M, 4, D>::new(sys.clone(), Tableau::new(Method::Gauss).unwrap());
    let steps = ((t_end - start.t) / h).round() as usize;
    let traj = st
        .integrate_with_events(
            start.t,
            &start.q,
            &start.v,
            Schedule::Fixed { h, steps },
            &RunOptions::default(),
            &mut NoObserver,
            &events,
        )
        .unwrap();
    assert!(!traj.events.is_empty(), "{}: no events", Sys::SOURCE.name);
    let mut worst = 0.0f64;
    let mut last_t = f64::NEG_INFINITY;
    for e in &traj.events {
        assert!(e.t >= last_t, "events out of time order");
        last_t = e.t;
        assert!(e.residual.abs() < 1e-11, "{}: |g| = {:.1e} at the event", Sys::SOURCE.name, e.residual);
        // The reference zero of the same function nearest to the located one.
        let z = reference_zero::<Sys, N, M>(&sys, &start, &gs[e.index], e.t + 0.05, 0.01, e.t - 0.02)
            .unwrap_or_else(|| panic!("{}: no reference zero near t = {}", Sys::SOURCE.name, e.t));
        worst = worst.max((z - e.t).abs());
        assert!(
            (z - e.t).abs() <= 1e-12,
            "{} event {} at t = {:.15}: reference bracket {:.15} (|Δt| = {:.1e})",
            Sys::SOURCE.name,
            e.index,
            e.t,
            z,
            (z - e.t).abs()
        );
    }
    println!("{:12} {} events, max |Δt| vs reference bracket {worst:.1e}", Sys::SOURCE.name, traj.events.len());
    (worst, traj.events.len())
}

#[test]
fn events_agree_with_an_independent_bracket_on_five_systems() {
    let h = 0.01;
    let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    check_system::<_, 3, 1, { 4 * 4 + 3 }>(
        Particle,
        particle,
        &[
            Affine { w: [1.0, 0.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.3, kappa: 0.0 },
            Affine { w: [0.0; 3], u: [0.0, 1.0, 0.0], a: 0.0, b: 0.0, kappa: 0.0 },
        ],
        h,
        4.0,
    );
    let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    check_system::<_, 3, 1, { 4 * 4 + 3 }>(
        Skate::default(),
        skate,
        &[
            Affine { w: [0.0, 0.0, 1.0], u: [0.0; 3], a: 0.0, b: -2.0, kappa: 0.0 },
            Affine { w: [0.0; 3], u: [1.0, 0.0, 0.0], a: 0.0, b: -0.2, kappa: 1.0 },
        ],
        h,
        4.0,
    );
    let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    check_system::<_, 4, 2, { 4 * 6 + 4 }>(
        MobileRobot::default(),
        robot,
        &[
            Affine { w: [0.0, 1.0, 0.0, 0.0], u: [0.0; 4], a: 0.0, b: -0.4, kappa: 0.0 },
            Affine { w: [0.0; 4], u: [0.0, 0.0, 0.0, 1.0], a: 0.0, b: -0.5, kappa: 0.0 },
        ],
        h,
        4.0,
    );
    let mp = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    check_system::<_, 7, 1, { 4 * 8 + 7 }>(
        MpParticles,
        mp,
        &[
            Affine { w: [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], u: [0.0; 7], a: 0.0, b: 0.0, kappa: 0.0 },
            Affine { w: [0.0; 7], u: [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0], a: 0.0, b: 0.0, kappa: 0.0 },
        ],
        h,
        4.0,
    );
    // Time-dependent constraint v₂ − q₁v₁ − a v₁² + e sin t = 0, and an event
    // function that depends on t explicitly.
    let g = General::default();
    let v1 = 0.8;
    let (q0, q1) = (0.3, -0.2);
    let general = State::new(0.0, Vector::<2>::new(q0, q1), Vector::<2>::new(v1, q0 * v1 + g.a * v1 * v1));
    check_system::<_, 2, 1, { 4 * 3 + 2 }>(
        g,
        general,
        &[
            Affine { w: [1.0, 0.0], u: [0.0; 2], a: 0.0, b: 0.0, kappa: 0.0 },
            Affine { w: [0.0, 1.0], u: [0.0, 0.5], a: 0.1, b: 0.05, kappa: 0.5 },
        ],
        h,
        4.0,
    );
}

#[test]
fn events_far_from_the_origin_of_time_are_located_to_1e_12() {
    // The tolerance: a fraction of the step, and never below what a double
    // resolves at `t`.
    assert_eq!(event_time_tolerance(0.5, 0.1), 1e-13 * 0.1);
    assert_eq!(event_time_tolerance(1e-7, -1e-8), 1e-13 * 1e-8);
    assert_eq!(event_time_tolerance(-50.0, 0.01), 4.0 * (50f64.next_up() - 50.0));
    assert_eq!(event_time_tolerance(1e6, 0.1), 4.0 * (1e6f64.next_up() - 1e6));
    // Starting at t = 1000, where a tolerance relative to t would allow 1e-11.
    let t0 = 1000.0;
    let h = 0.01;
    let particle = State::new(t0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let (worst, count) = check_system::<_, 3, 1, { 4 * 4 + 3 }>(
        Particle,
        particle,
        &[
            Affine { w: [1.0, 0.0, 0.0], u: [0.0; 3], a: 0.0, b: -0.3, kappa: 0.0 },
            Affine { w: [0.0; 3], u: [0.0, 1.0, 0.0], a: 0.0, b: 0.0, kappa: 0.0 },
        ],
        h,
        t0 + 4.0,
    );
    assert!(count >= 4 && worst <= 1e-12);
    // The time-dependent constraint, with an event that depends on t.
    let g = General::default();
    let v1 = 0.8;
    let (q0, q1) = (0.3, -0.2);
    let v2 = q0 * v1 + g.a * v1 * v1 - g.e * t0.sin();
    let general = State::new(t0, Vector::<2>::new(q0, q1), Vector::<2>::new(v1, v2));
    let (worst, count) = check_system::<_, 2, 1, { 4 * 3 + 2 }>(
        g,
        general,
        &[
            Affine { w: [1.0, 0.0], u: [0.0; 2], a: 0.0, b: 0.0, kappa: 0.0 },
            Affine { w: [0.0, 1.0], u: [0.0, 0.5], a: 0.1, b: 0.05 - 0.1 * t0, kappa: 0.5 },
        ],
        h,
        t0 + 4.0,
    );
    assert!(count >= 1 && worst <= 1e-12);
}

fn time_event<const N: usize>(target: f64) -> impl Fn(usize, f64, &Vector<N>, &Vector<N>) -> EventGradient<N> {
    move |_, t, _, _| EventGradient { value: t - target, t: 1.0, q: Vector::zeros(), v: Vector::zeros() }
}

fn particle_stepper() -> Stepper<Particle, 3, 1, 2, 11> {
    Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap())
}

fn particle_start() -> State<3> {
    State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0))
}

/// A fixed-step run of the particle from [`particle_start`], `steps` steps
/// of size `h` with default options, locating `events`.
fn particle_run<O, E>(h: f64, steps: usize, observer: &mut O, events: &E) -> Trajectory<3, 1>
where
    O: Observer<3, 1>,
    E: EventFunctions<Particle, 3>,
{
    let s0 = particle_start();
    particle_stepper()
        .integrate_with_events(
            0.0,
            &s0.q,
            &s0.v,
            Schedule::Fixed { h, steps },
            &RunOptions::default(),
            observer,
            events,
        )
        .unwrap()
}

#[test]
fn an_event_at_a_step_boundary_is_reported_once() {
    for (name, direction) in [("rising", Direction::Rising), ("both", Direction::Both)] {
        let specs = [EventSpec { name, direction, terminal: false, source: "" }];
        let g = time_event::<3>(0.5);
        let events = RuntimeEvents { specs: &specs, gradient: &g };
        let traj = particle_run(0.125, 8, &mut NoObserver, &events);
        assert_eq!(traj.events.len(), 1, "{name}: {:?}", traj.events);
        assert_eq!(traj.events[0].t, 0.5);
        assert_eq!(traj.events[0].step, 3);
        assert!(traj.events[0].rising);
    }
    // A zero within round-off of a grid point (the sign flips just after it).
    let specs = [EventSpec { name: "near", direction: Direction::Both, terminal: false, source: "" }];
    let g = time_event::<3>(0.5 + 1e-16);
    let events = RuntimeEvents { specs: &specs, gradient: &g };
    let traj = particle_run(0.125, 8, &mut NoObserver, &events);
    assert_eq!(traj.events.len(), 1, "{:?}", traj.events);
    assert!((traj.events[0].t - 0.5).abs() <= 1e-15);
}

#[test]
fn several_events_in_one_step_come_in_time_order_and_directions_filter() {
    let specs = [
        EventSpec { name: "late", direction: Direction::Both, terminal: false, source: "" },
        EventSpec { name: "early", direction: Direction::Both, terminal: false, source: "" },
        EventSpec { name: "falling-only", direction: Direction::Falling, terminal: false, source: "" },
        EventSpec { name: "rising-only", direction: Direction::Rising, terminal: false, source: "" },
    ];
    let targets = [0.31, 0.27, 0.29, 0.3];
    let g = |i: usize, t: f64, _: &Vector<3>, _: &Vector<3>| EventGradient {
        value: t - targets[i],
        t: 1.0,
        q: Vector::zeros(),
        v: Vector::zeros(),
    };
    let events = RuntimeEvents { specs: &specs, gradient: &g };
    let traj = particle_run(0.5, 2, &mut NoObserver, &events);
    let names: Vec<&str> = traj.events.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(names, ["early", "rising-only", "late"]);
    for e in &traj.events {
        assert!((e.t - targets[e.index]).abs() <= 1e-15, "{} at {}", e.name, e.t);
    }
    assert_eq!(traj.report.events, 3);
}

#[test]
fn a_terminal_event_ends_the_run_exactly_there() {
    // y = q₁ first falls through 0.5 after its maximum; terminal.
    let specs = [
        EventSpec { name: "count", direction: Direction::Both, terminal: false, source: "" },
        EventSpec { name: "stop", direction: Direction::Falling, terminal: true, source: "" },
    ];
    let g = |i: usize, t: f64, q: &Vector<3>, _: &Vector<3>| {
        if i == 0 {
            EventGradient { value: t - 0.1, t: 1.0, q: Vector::zeros(), v: Vector::zeros() }
        } else {
            EventGradient { value: q[1] - 0.5, t: 0.0, q: Vector::<3>::new(0.0, 1.0, 0.0), v: Vector::zeros() }
        }
    };
    let events = RuntimeEvents { specs: &specs, gradient: &g };
    let mut seen = Vec::new();
    let mut observer = |s: &State<3>, _: usize| seen.push(s.t);
    let traj = particle_run(0.1, 100, &mut observer, &events);
    let stop = traj.events.last().unwrap();
    assert_eq!(stop.name, "stop");
    assert!(!stop.rising);
    assert_eq!(traj.report.terminal_event, Some(1));
    let last = traj.samples.last().unwrap();
    assert_eq!(last.t, stop.t, "the run ends at the event time");
    assert_eq!(last.q, stop.q);
    assert!((last.q[1] - 0.5).abs() < 1e-12);
    assert!(traj.report.steps < 100);
    assert_eq!(*seen.last().unwrap(), stop.t);
    assert_eq!(traj.events.iter().filter(|e| e.name == "count").count(), 1);
    // A system without events runs as it does without an event set: no
    // events, no terminal.
    let plain = particle_run(0.1, 10, &mut NoObserver, &NoEvents);
    assert!(plain.events.is_empty() && plain.report.terminal_event.is_none());
}

/// Records the interval each dense step covers and its samples at both ends.
struct DenseSteps {
    steps: Vec<(f64, f64, State<3>)>,
}

impl spark_runtime::Observer<3, 1> for DenseSteps {
    const DENSE: bool = true;
    fn observe<Sys: spark_runtime::NonholonomicSystem<3, 1>>(&mut self, _: &Sys, _: &State<3>, _: usize) {}
    fn observe_dense<const S: usize>(&mut self, step: &spark_runtime::DenseStep<'_, 3, S>) {
        self.steps.push((step.start.t, step.end.t, step.state_at(step.end.t)));
    }
}

#[test]
fn a_dense_observer_sees_the_last_step_only_up_to_the_terminal_event() {
    // Terminal at t = 0.35, inside the fourth step of size 0.1.
    let specs = [EventSpec { name: "stop", direction: Direction::Rising, terminal: true, source: "" }];
    let g = time_event::<3>(0.35);
    let events = RuntimeEvents { specs: &specs, gradient: &g };
    let mut dense = DenseSteps { steps: Vec::new() };
    let traj = particle_run(0.1, 10, &mut dense, &events);
    let stop = traj.events.last().unwrap();
    assert!((stop.t - 0.35).abs() <= 1e-15, "event at {}", stop.t);
    assert_eq!(dense.steps.len(), 4, "{:?}", dense.steps);
    let (start, end, at_end) = dense.steps[3];
    assert!((start - 0.3).abs() <= 1e-15);
    assert_eq!(end, stop.t, "the last dense step ends at the terminal event");
    assert_eq!(at_end.q, stop.q);
    assert_eq!(at_end.v, stop.v);
    // The earlier steps are whole.
    for (k, &(a, b, _)) in dense.steps[..3].iter().enumerate() {
        assert!((a - 0.1 * k as f64).abs() <= 1e-15 && (b - 0.1 * (k + 1) as f64).abs() <= 1e-15);
    }
}

nonholonomic_system! {
    /// A ball on a vertical line with gravity; events on its height.
    pub struct Ball {
        coordinates: [y, x],
        parameters: { g = 9.81 },
        lagrangian: dot(y)^2/2 + dot(x)^2/2 - g*y,
        constraints: [ dot(x) - y ],
        events: {
            ground: falling(y) terminal,
            apex: falling(dot(y)),
            crossing_half: y - 0.5 + 0*t,
            timed: rising(t*x - 0.2*y^2),
        },
        effects: { late: event(rising(t - 0.25)) },
        scenes: { Plain = [], Late = [late] },
    }
}

#[test]
fn dsl_events_have_exact_derivatives_and_stop_terminal_runs() {
    const { assert!(<Ball as NonholonomicSystem<2, 1>>::HAS_EVENTS) };
    let specs = <Ball as NonholonomicSystem<2, 1>>::EVENTS;
    let names: Vec<&str> = specs.iter().map(|s| s.name).collect();
    assert_eq!(names, ["ground", "apex", "crossing_half", "timed"]);
    assert_eq!(specs[0].direction, Direction::Falling);
    assert!(specs[0].terminal);
    assert_eq!(specs[2].direction, Direction::Both);
    assert!(!specs[2].source.is_empty());
    // Derivatives against central differences.
    let ball = Ball::default();
    let (t, q, v) = (0.7, Vector::<2>::new(0.9, -0.3), Vector::<2>::new(-1.1, 0.4));
    for i in 0..specs.len() {
        let g = ball.event_gradient(i, t, &q, &v);
        assert_eq!(g.value, ball.event_value(i, t, &q, &v));
        let d = 1e-6;
        let fd_t = (ball.event_value(i, t + d, &q, &v) - ball.event_value(i, t - d, &q, &v)) / (2.0 * d);
        assert!((fd_t - g.t).abs() < 1e-8, "event {i} g_t {} vs {fd_t}", g.t);
        for k in 0..2 {
            let e = Vector::<2>::from_fn(|r, _| if r == k { d } else { 0.0 });
            let fq = (ball.event_value(i, t, &(q + e), &v) - ball.event_value(i, t, &(q - e), &v)) / (2.0 * d);
            let fv = (ball.event_value(i, t, &q, &(v + e)) - ball.event_value(i, t, &q, &(v - e))) / (2.0 * d);
            assert!((fq - g.q[k]).abs() < 1e-8 && (fv - g.v[k]).abs() < 1e-8, "event {i} component {k}");
        }
    }
    // Thrown up from y = 1: apex, then y = 0.5 falling, then the ground (terminal).
    let mut st: spark_runtime::Stepper![Ball, 3] = Stepper::new(ball, Tableau::new(Method::Gauss).unwrap());
    let (q0, v0) = (Vector::<2>::new(1.0, 0.0), Vector::<2>::new(2.0, 1.0));
    let traj = st
        .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.05, steps: 200 }, &RunOptions::default(), &mut NoObserver)
        .unwrap();
    let seq: Vec<&str> = traj.events.iter().map(|e| e.name.as_str()).collect();
    assert!(seq.contains(&"apex") && seq.contains(&"crossing_half"), "{seq:?}");
    assert_eq!(*seq.last().unwrap(), "ground");
    // With the constraint, the motion in y is free fall: y(t) = 1 + 2t − g t²/2.
    let g = 9.81;
    let ground = (2.0 + (4.0f64 + 2.0 * g).sqrt()) / g;
    let stop = traj.events.last().unwrap();
    assert!((stop.t - ground).abs() < 1e-12, "ground at {} vs {ground}", stop.t);
    assert_eq!(traj.samples.last().unwrap().t, stop.t);
    let apex = traj.events.iter().find(|e| e.name == "apex").unwrap();
    assert!((apex.t - 2.0 / g).abs() < 1e-12);
    // Scenes: `Plain` has the base events only, `Late` adds its own.
    assert_eq!(<Plain as NonholonomicSystem<2, 1>>::EVENTS.len(), 4);
    let late = <Late as NonholonomicSystem<2, 1>>::EVENTS;
    assert_eq!(late.len(), 5);
    assert_eq!(late[4].name, "late");
    assert_eq!(late[4].direction, Direction::Rising);
}

#[test]
fn every_scene_keeps_the_base_events() {
    // A scene is the base declaration plus its effects: the base `events:`
    // come first in every scene, in their order and with their indices, and
    // the scene's `event(…)` effects follow; no scene can leave one out.
    let base: Vec<&str> = <Ball as NonholonomicSystem<2, 1>>::EVENTS.iter().map(|s| s.name).collect();
    let plain: Vec<&str> = <Plain as NonholonomicSystem<2, 1>>::EVENTS.iter().map(|s| s.name).collect();
    let late: Vec<&str> = <Late as NonholonomicSystem<2, 1>>::EVENTS.iter().map(|s| s.name).collect();
    assert_eq!(plain, base);
    assert_eq!(late[..base.len()], base[..]);
    assert_eq!(late[base.len()..], ["late"]);
    // So a run of either scene stops at the base declaration's terminal
    // `ground` event, and the scene that selects none of the events still
    // locates them all.
    let (q0, v0) = (Vector::<2>::new(1.0, 0.0), Vector::<2>::new(2.0, 1.0));
    let schedule = Schedule::Fixed { h: 0.05, steps: 200 };
    let mut plain_st: spark_runtime::Stepper![Plain, 3] =
        Stepper::new(Plain::default(), Tableau::new(Method::Gauss).unwrap());
    let plain_run = plain_st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    let mut late_st: spark_runtime::Stepper![Late, 3] =
        Stepper::new(Late::default(), Tableau::new(Method::Gauss).unwrap());
    let late_run = late_st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    for (name, run) in [("Plain", &plain_run), ("Late", &late_run)] {
        assert_eq!(run.events.last().map(|e| e.name.as_str()), Some("ground"), "{name}");
        assert_eq!(run.report.terminal_event, Some(0), "{name}");
        assert!(run.events.iter().any(|e| e.name == "apex"), "{name}");
    }
    assert!(late_run.events.iter().any(|e| e.name == "late"));
    assert!(plain_run.events.iter().all(|e| e.name != "late"));
    // Leaving the base events out is a run-time choice: `NoEvents` (or a
    // `RuntimeEvents` subset) replaces them for one run.
    let quiet = plain_st
        .integrate_with_events(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver, &NoEvents)
        .unwrap();
    assert!(quiet.events.is_empty() && quiet.report.terminal_event.is_none());
    assert_eq!(quiet.report.steps, 200);
}

/// A NaN value of an event function has no sign: a check point where the
/// function is NaN starts or ends no crossing. Reading `NaN < 0` as "not
/// negative" would report a crossing at the first point after the NaN stretch
/// whenever the function is negative there (here `g` is NaN before
/// t = 0.05 and −1 after: a falling crossing "at" 0.05 with residual NaN);
/// the rising crossing at 0.55 after it is still found, by fixed and by
/// adaptive runs.
#[test]
fn a_nan_event_value_starts_or_ends_no_crossing() {
    let s0 = particle_start();
    let specs = [EventSpec { name: "nan", direction: Direction::Both, terminal: false, source: "" }];
    let g = |_: usize, t: f64, _: &Vector<3>, _: &Vector<3>| EventGradient {
        value: if t < 0.05 {
            f64::NAN
        } else if t < 0.3 {
            -1.0
        } else {
            t - 0.55
        },
        t: if t < 0.3 { 0.0 } else { 1.0 },
        q: Vector::zeros(),
        v: Vector::zeros(),
    };
    let events = RuntimeEvents { specs: &specs, gradient: &g };
    let fixed = particle_run(0.1, 10, &mut NoObserver, &events);
    let adaptive = spark_runtime::integrate_adaptive_with_events(
        &mut particle_stepper(),
        0.0,
        &s0.q,
        &s0.v,
        1.0,
        &spark_runtime::AdaptiveOptions::default(),
        &mut NoObserver,
        &events,
    )
    .unwrap();
    for (run, found) in [("fixed", &fixed.events), ("adaptive", &adaptive.trajectory.events)] {
        assert_eq!(found.len(), 1, "{run}: {found:?}");
        assert!(found[0].rising && (found[0].t - 0.55).abs() <= 1e-14, "{run}: {found:?}");
    }
}

/// Counts the events located and asks to stop once there are `limit`.
struct EventCounter {
    names: Vec<String>,
    limit: usize,
}

impl Observer<2, 1> for EventCounter {
    fn observe<Sys: NonholonomicSystem<2, 1>>(&mut self, _: &Sys, _: &State<2>, _: usize) {}
    fn observe_event(&mut self, event: &spark_runtime::EventRecord<2>) {
        self.names.push(event.name.clone());
    }
    fn stop_requested(&mut self) -> bool {
        self.names.len() >= self.limit
    }
}

/// An observer sees every located event, in the order of the run's
/// `events`, so that it can bound how many a run collects: stopping on the
/// count ends the run with `Stopped` after the step that reached it.
#[test]
fn an_observer_sees_every_located_event_and_can_stop_on_their_count() {
    let ball = Plain::default();
    let (q0, v0) = (Vector::<2>::new(1.0, 0.0), Vector::<2>::new(2.0, 1.0));
    let schedule = Schedule::Fixed { h: 0.05, steps: 200 };
    let mut st: spark_runtime::Stepper![Plain, 3] = Stepper::new(ball, Tableau::new(Method::Gauss).unwrap());
    let mut all = EventCounter { names: Vec::new(), limit: usize::MAX };
    let traj = st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut all).unwrap();
    let names: Vec<String> = traj.events.iter().map(|e| e.name.clone()).collect();
    assert!(names.len() >= 3, "{names:?}");
    assert_eq!(all.names, names);
    let mut first = EventCounter { names: Vec::new(), limit: 1 };
    match st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut first) {
        Err(spark_runtime::IntegrationError::Stopped { t, .. }) => {
            assert_eq!(first.names, names[..1]);
            assert!(t >= traj.events[0].t && t < traj.events[0].t + 0.05 + 1e-12, "stopped at {t}");
        }
        other => panic!("expected a stop after the first event, got {other:?}"),
    }
}

nonholonomic_system! {
    /// A knife edge on a spring of stiffness `k`, with the event `y = 0`:
    /// `k = 1/τ²` and velocities `∝ 1/τ` give the motion of `τ = 1` in
    /// units of time `τ`.
    pub struct TimedSkate {
        coordinates: [x, y, theta],
        parameters: { k = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 + dot(theta)^2/2 - k/2*(sqrt(x^2 + y^2) - 1)^2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        events: { cross: y },
    }
}

/// The event times of the timed skate in units of `τ`: 400 steps of
/// `h = 0.05·τ`, Gauss s = 2.
fn timed_skate_events(tau: f64) -> Vec<f64> {
    let heading = 0.3f64;
    let q0 = Vector::<3>::new(1.5, 0.2, heading);
    let v0 = Vector::<3>::new(0.8 * heading.cos() / tau, 0.8 * heading.sin() / tau, 0.7 / tau);
    let mut st =
        Stepper::<_, 3, 1, 2, 11>::new(TimedSkate { k: 1.0 / (tau * tau) }, Tableau::new(Method::Gauss).unwrap());
    let schedule = Schedule::Fixed { h: 0.05 * tau, steps: 400 };
    let run = st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    run.events.iter().map(|e| e.t / tau).collect()
}

/// An event's location tolerance is a fraction of the step, so a system
/// stated in other units of time has its events where `τ = 1` has them,
/// to 1e-13 of `τ` (with a tolerance of `1e-14·max(1, |t|)` the events at
/// `τ = 1e-3` are 4.8e-12 of `τ` off).
#[test]
fn events_in_other_units_of_time_are_located_alike() {
    let unit = timed_skate_events(1.0);
    assert_eq!(unit.len(), 2, "{unit:?}");
    for tau in [1e-3, 1e-6, 1e-9, 1e3] {
        let scaled = timed_skate_events(tau);
        assert_eq!(scaled.len(), unit.len(), "τ = {tau:e}: {scaled:?}");
        let worst = unit.iter().zip(&scaled).map(|(a, b)| (a - b).abs()).fold(0.0f64, f64::max);
        assert!(worst <= 1e-13, "τ = {tau:e}: event times off by {worst:e} of τ");
    }
}
