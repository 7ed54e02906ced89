//! `integrate_plan`, the one entry the front ends call, and
//! `integrate_adaptive_at`, the tolerance-driven run sampled at output times:
//!
//! - each plan runs exactly what the entry point it stands for runs (bit for
//!   bit: fixed steps, fixed steps sampled at times, tolerance-driven steps);
//! - a tolerance-driven run sampled at output times has the steps of the same
//!   run recorded at its steps, and its samples are the continuous extension
//!   of those steps at exactly the requested times, as accurate as the
//!   tolerance asks;
//! - events are located only when the plan asks for them; a terminal event
//!   ends a sampled run at its time;
//! - what a front end can type wrong is an error that names it.

use spark_runtime::fixtures::paper::Skate;
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{
    integrate_adaptive_at, integrate_adaptive_with_events, integrate_plan, nonholonomic_system, AdaptiveError,
    AdaptiveOptions, DenseStep, Method, NoEvents, NoObserver, NonholonomicSystem, Observer, PlanError, RunOptions,
    RunPlan, Schedule, State, Stepper, Stepping, Tableau, Tolerance, Vector,
};

nonholonomic_system! {
    /// The knife edge on a spring, with a crossing event and a terminal one.
    pub struct EventSkate {
        coordinates: [x, y, theta],
        parameters: { k = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 + dot(theta)^2/2 - k/2*(sqrt(x^2 + y^2) - 1)^2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        events: { cross: y, far: rising(x^2 + y^2 - 3.61) terminal },
    }
}

type EventStepper = Stepper<EventSkate, 3, 1, 2, 11>;

fn event_start() -> State<3> {
    let heading = 0.3f64;
    State::new(
        0.0,
        Vector::<3>::new(1.5, 0.2, heading),
        Vector::<3>::new(0.8 * heading.cos(), 0.8 * heading.sin(), 0.7),
    )
}

fn event_stepper() -> EventStepper {
    Stepper::new(EventSkate::default(), Tableau::new(Method::Gauss).unwrap())
}

fn tolerance(rtol: f64, t_end: f64) -> Tolerance {
    Tolerance { rtol, atol: rtol, first_step: None, max_step: None, max_steps: 100_000, t_end }
}

fn adaptive_options(t: &Tolerance) -> AdaptiveOptions {
    AdaptiveOptions { rtol: t.rtol, atol: t.atol, max_steps: t.max_steps, ..AdaptiveOptions::default() }
}

fn bits(s: &State<3>) -> Vec<u64> {
    std::iter::once(s.t).chain(s.q.iter().copied()).chain(s.v.iter().copied()).map(f64::to_bits).collect()
}

/// A dense step's start and end times, and its states at the wanted times
/// it holds.
type Piece = (f64, f64, Vec<(f64, State<3>)>);

/// Every dense step of a run, sampled at the wanted times.
#[derive(Default)]
struct Pieces {
    steps: Vec<Piece>,
    wanted: Vec<f64>,
}

impl Observer<3, 1> for Pieces {
    const DENSE: bool = true;
    fn observe<Sys: NonholonomicSystem<3, 1>>(&mut self, _: &Sys, _: &State<3>, _: usize) {}
    fn observe_dense<const S: usize>(&mut self, step: &DenseStep<'_, 3, S>) {
        let (a, b) = (step.start.t, step.end.t);
        let inside: Vec<(f64, State<3>)> =
            self.wanted.iter().filter(|&&t| step.contains(t)).map(|&t| (t, step.state_at(t))).collect();
        self.steps.push((a, b, inside));
    }
}

#[test]
fn each_plan_runs_what_its_entry_point_runs() {
    let start = event_start();
    let (q0, v0) = (start.q, start.v);
    let options = RunOptions::default();
    let times: Vec<f64> = (1..=30).map(|k| 0.1 * k as f64 + 0.013).collect();
    // Fixed steps, recorded at the steps, events off.
    let plan = RunPlan { stepping: Stepping::Fixed { h: 0.05, steps: 80 }, times: None, events: false };
    let planned = integrate_plan(&mut event_stepper(), 0.0, &q0, &v0, &plan, &options, &mut NoObserver).unwrap();
    let direct = event_stepper()
        .integrate_with_events(
            0.0,
            &q0,
            &v0,
            Schedule::Fixed { h: 0.05, steps: 80 },
            &options,
            &mut NoObserver,
            &NoEvents,
        )
        .unwrap();
    assert_eq!(planned.trajectory, direct);
    assert!(planned.controller.is_none());
    assert!(planned.trajectory.events.is_empty(), "events are located only when asked for");
    // Fixed steps sampled at times, events on.
    let plan = RunPlan { stepping: Stepping::Fixed { h: 0.05, steps: 80 }, times: Some(&times), events: true };
    let planned = integrate_plan(&mut event_stepper(), 0.0, &q0, &v0, &plan, &options, &mut NoObserver).unwrap();
    let direct = event_stepper()
        .integrate(0.0, &q0, &v0, Schedule::Sampled { h: 0.05, times: &times }, &options, &mut NoObserver)
        .unwrap();
    assert_eq!(planned.trajectory, direct);
    assert_eq!(planned.trajectory.report.terminal_event, Some(1), "the skate passes r = 1.9 before t = 1");
    // Tolerance-driven steps, events off.
    let tol = tolerance(1e-9, 4.0);
    let plan = RunPlan { stepping: Stepping::Tolerance(tol), times: None, events: false };
    let planned = integrate_plan(&mut event_stepper(), 0.0, &q0, &v0, &plan, &options, &mut NoObserver).unwrap();
    let direct = integrate_adaptive_with_events(
        &mut event_stepper(),
        0.0,
        &q0,
        &v0,
        4.0,
        &adaptive_options(&tol),
        &mut NoObserver,
        &NoEvents,
    )
    .unwrap();
    assert_eq!(planned.trajectory, direct.trajectory);
    assert_eq!(planned.controller, Some(direct.report));
    assert_eq!(planned.trajectory.samples.last().unwrap().t, 4.0, "the last step lands on t_end");
}

#[test]
fn a_tolerance_driven_run_sampled_at_times_is_the_extension_of_the_same_steps() {
    let (sys, start) = (Skate::default(), State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0)));
    let times: Vec<f64> = (0..=40).map(|k| 0.25 * k as f64).collect();
    let tableau = || Tableau::new(Method::Gauss).unwrap();
    let mut interior = Vec::new();
    for rtol in [1e-6, 1e-10] {
        let options = AdaptiveOptions { rtol, atol: rtol, ..AdaptiveOptions::default() };
        let mut st = Stepper::<Skate, 3, 1, 3, 15>::new(sys, tableau());
        let sampled =
            integrate_adaptive_at(&mut st, 0.0, &start.q, &start.v, &times, &options, &mut NoObserver, &NoEvents)
                .unwrap();
        let mut pieces = Pieces { wanted: times.clone(), ..Pieces::default() };
        let stepped =
            integrate_adaptive_with_events(&mut st, 0.0, &start.q, &start.v, 10.0, &options, &mut pieces, &NoEvents)
                .unwrap();
        // The same steps: the controller's statistics agree.
        assert_eq!(sampled.report, stepped.report);
        assert_eq!(sampled.trajectory.report.steps, stepped.trajectory.report.steps);
        // The samples: the initial point, then exactly each time, each the
        // extension of the step that holds it (the first piece that does:
        // a time on a step boundary is the end of the earlier step).
        let samples = &sampled.trajectory.samples;
        assert_eq!(samples.len(), times.len() + 1);
        assert_eq!(samples[0].t, 0.0);
        for (s, &t) in samples[1..].iter().zip(&times) {
            assert_eq!(s.t, t);
            let (_, _, inside) =
                pieces.steps.iter().find(|(_, _, inside)| inside.iter().any(|(u, _)| *u == t)).unwrap();
            let (_, expected) = inside.iter().find(|(u, _)| *u == t).unwrap();
            let state = State { t: s.t, q: s.q, v: s.v };
            assert_eq!(bits(&state), bits(expected), "t = {t}");
        }
        // As accurate as the tolerance asks: against the reference solver.
        let r = integrate_at(&sys, 0.0, &start.q, &start.v, &times, &ReferenceOptions::default()).unwrap();
        let worst = samples[1..]
            .iter()
            .zip(r.q.iter().zip(&r.v))
            .map(|(s, (q, v))| (s.q - q).amax().max((s.v - v).amax()))
            .fold(0.0f64, f64::max);
        let end = (samples.last().unwrap().q - r.q.last().unwrap()).amax();
        // The end is a step's end, as accurate as the steps; the times
        // inside steps carry the extension's lower order (the same run:
        // 7.8e-5 and 4.3e-7 inside, 2.2e-6 and 1.4e-9 at the end).
        assert!(end < 50.0 * rtol, "rtol = {rtol:e}: error at the end {end:e}");
        interior.push(worst);
        // The last time is the end: the run lands on it.
        assert_eq!(sampled.trajectory.samples.last().unwrap().t, 10.0);
    }
    assert!(interior[1] < 1e-2 * interior[0], "the extension follows the tolerance: {interior:?}");
}

#[test]
fn a_terminal_event_ends_a_sampled_tolerance_run_at_its_time() {
    let start = event_start();
    let times: Vec<f64> = (1..=200).map(|k| 0.1 * k as f64).collect();
    let plan = RunPlan { stepping: Stepping::Tolerance(tolerance(1e-10, 20.0)), times: Some(&times), events: true };
    let run =
        integrate_plan(&mut event_stepper(), 0.0, &start.q, &start.v, &plan, &RunOptions::default(), &mut NoObserver)
            .unwrap();
    let traj = &run.trajectory;
    let far = traj.events.iter().find(|e| e.name == "far").expect("the skate passes r = 1.9 before t = 1");
    assert_eq!(traj.events.last().unwrap().name, "far", "nothing is located after the terminal event");
    assert_eq!(traj.report.terminal_event, Some(1));
    assert!((far.q[0].powi(2) + far.q[1].powi(2) - 3.61).abs() < 1e-9);
    let last = traj.samples.last().unwrap();
    assert_eq!(last.t, far.t, "the last sample is the event's state");
    assert!(far.t < 20.0);
    // Every time before the event is sampled, none after it.
    let before = times.iter().filter(|&&t| t <= far.t).count();
    assert_eq!(traj.samples.len(), 1 + before + usize::from(!times.contains(&far.t)));
    assert!(traj.samples[1..=before].iter().zip(&times).all(|(s, &t)| s.t == t));
    // Without events the same plan runs to the last time.
    let quiet = RunPlan { events: false, ..plan };
    let run =
        integrate_plan(&mut event_stepper(), 0.0, &start.q, &start.v, &quiet, &RunOptions::default(), &mut NoObserver)
            .unwrap();
    assert_eq!(run.trajectory.samples.len(), times.len() + 1);
    assert!(run.trajectory.events.is_empty());
}

#[test]
fn wrong_plans_are_errors_that_name_what_is_wrong() {
    let start = event_start();
    let (q0, v0) = (start.q, start.v);
    let options = RunOptions::default();
    let run = |plan: &RunPlan<'_>| integrate_plan(&mut event_stepper(), 0.0, &q0, &v0, plan, &options, &mut NoObserver);
    let fixed = Stepping::Fixed { h: 0.1, steps: 10 };
    let tol = Stepping::Tolerance(tolerance(1e-8, 1.0));
    // Events of a system that declares none.
    let mut skate = Stepper::<Skate, 3, 1, 2, 11>::new(Skate::default(), Tableau::new(Method::Gauss).unwrap());
    let plan = RunPlan { stepping: fixed, times: None, events: true };
    let err = integrate_plan(
        &mut skate,
        0.0,
        &Vector::<3>::zeros(),
        &Vector::<3>::new(0.0, 0.0, 1.0),
        &plan,
        &options,
        &mut NoObserver,
    )
    .unwrap_err();
    assert_eq!(err, PlanError::NoDeclaredEvents);
    assert!(err.to_string().contains("declares no events"), "{err}");
    // Output times outside the interval, either way.
    for (stepping, t) in [(fixed, 1.5), (fixed, -0.1), (tol, 1.25)] {
        let times = [0.5, t];
        let times = if t < 0.0 { &times[1..] } else { &times[..] };
        match run(&RunPlan { stepping, times: Some(times), events: false }) {
            Err(PlanError::TimeOutsideInterval { t: bad, .. }) => assert_eq!(bad, t),
            other => panic!("expected an output time outside the interval, got {other:?}"),
        }
    }
    // Output times that are not strictly monotone, or none.
    for times in [&[0.5, 0.5][..], &[0.6, 0.4][..], &[][..], &[0.3, f64::NAN][..]] {
        match run(&RunPlan { stepping: tol, times: Some(times), events: false }) {
            Err(PlanError::Tolerance(AdaptiveError::InvalidOutputTimes { reason })) => assert!(!reason.is_empty()),
            other => panic!("times {times:?}: expected invalid output times, got {other:?}"),
        }
    }
    // The last time at t0: nothing to integrate.
    let at_start = integrate_adaptive_at(
        &mut event_stepper(),
        0.0,
        &q0,
        &v0,
        &[0.0],
        &AdaptiveOptions::default(),
        &mut NoObserver,
        &NoEvents,
    );
    assert!(matches!(at_start, Err(AdaptiveError::InvalidOutputTimes { .. })), "{at_start:?}");
    // A tolerance the controller cannot use.
    let bad = Stepping::Tolerance(Tolerance { rtol: -1.0, ..tolerance(1e-8, 1.0) });
    let err = run(&RunPlan { stepping: bad, times: None, events: false }).unwrap_err();
    assert!(err.to_string().contains("rtol"), "{err}");
    // A step limit that is reached.
    let few = Stepping::Tolerance(Tolerance { max_steps: 3, ..tolerance(1e-12, 5.0) });
    let err = run(&RunPlan { stepping: few, times: None, events: false }).unwrap_err();
    assert!(matches!(err, PlanError::Tolerance(AdaptiveError::TooManySteps { attempts: 3, .. })), "{err:?}");
    assert!(err.to_string().contains("--max-steps"), "{err}");
}

#[test]
fn the_report_of_a_tolerance_driven_run_covers_the_steps_it_does_not_record() {
    let start = event_start();
    let tol = tolerance(1e-5, 6.0);
    let times = [6.0];
    let every_step = RunPlan { stepping: Stepping::Tolerance(tol), times: None, events: false };
    let only_end = RunPlan { times: Some(&times), ..every_step };
    let options = RunOptions::default();
    let all = integrate_plan(&mut event_stepper(), 0.0, &start.q, &start.v, &every_step, &options, &mut NoObserver)
        .unwrap()
        .trajectory;
    let end = integrate_plan(&mut event_stepper(), 0.0, &start.q, &start.v, &only_end, &options, &mut NoObserver)
        .unwrap()
        .trajectory;
    assert_eq!(end.samples.len(), 2);
    // The largest energy error over the steps is inside the run, not at its
    // end, and both runs report it.
    let at_end = (end.samples[1].energy.unwrap() - end.samples[0].energy.unwrap()).abs();
    assert!(all.report.max_energy_error > 2.0 * at_end, "{} vs {at_end}", all.report.max_energy_error);
    assert_eq!(end.report.max_energy_error, all.report.max_energy_error);
    assert_eq!(end.report.max_constraint_residual, all.report.max_constraint_residual);
}

/// Far from `t = 0` the first step the controller estimates can lie below
/// the resolution of `t` (16 units in the last place: 3.6e-3 at 1e12,
/// where the event skate's estimate is 3e-3); the run then starts from that
/// floor and proceeds as it does from `t = 0` (the system is autonomous),
/// its times strictly increasing. A first step given below the floor is
/// refused before the first step, naming the option and the resolution,
/// not with advice to loosen the tolerance.
#[test]
fn a_tolerance_driven_run_far_from_t_zero_starts_at_the_resolution_of_t() {
    let start = event_start();
    let (q0, v0) = (start.q, start.v);
    let t0 = 1e12;
    let floor = spark_runtime::time_resolution(t0);
    let options = RunOptions::default();
    let plan = RunPlan { stepping: Stepping::Tolerance(tolerance(1e-6, t0 + 2.0)), times: None, events: false };
    let run = integrate_plan(&mut event_stepper(), t0, &q0, &v0, &plan, &options, &mut NoObserver)
        .unwrap_or_else(|e| panic!("{e}"));
    let t: Vec<f64> = run.trajectory.samples.iter().map(|s| s.t).collect();
    assert_eq!((t[0], *t.last().unwrap()), (t0, t0 + 2.0));
    assert!(t.windows(2).all(|w| w[1] - w[0] >= floor), "{t:?}");
    // The same steps' states from t = 0 agree to the tolerance.
    let shifted = RunPlan { stepping: Stepping::Tolerance(tolerance(1e-6, 2.0)), times: None, events: false };
    let near = integrate_plan(&mut event_stepper(), 0.0, &q0, &v0, &shifted, &options, &mut NoObserver).unwrap();
    let (a, b) = (run.trajectory.samples.last().unwrap(), near.trajectory.samples.last().unwrap());
    assert!((a.q - b.q).amax() < 1e-4 && (a.v - b.v).amax() < 1e-4, "{:?} vs {:?}", a.q, b.q);
    // A first step below the resolution names it.
    let given = Tolerance { first_step: Some(floor / 4.0), ..tolerance(1e-6, t0 + 2.0) };
    let plan = RunPlan { stepping: Stepping::Tolerance(given), times: None, events: false };
    let err = integrate_plan(&mut event_stepper(), t0, &q0, &v0, &plan, &options, &mut NoObserver).unwrap_err();
    assert!(matches!(err, PlanError::Tolerance(AdaptiveError::FirstStepTooSmall { .. })), "{err:?}");
    let text = err.to_string();
    assert!(text.contains("first_step") && text.contains("resolution of t there"), "{text}");
}

/// `RunPlan::recorded_times` names the times a run of the plan records at,
/// bit for bit: fixed steps with every recording interval (one that divides
/// the step count, one that does not, 0 for the endpoints alone, one beyond
/// the count), from a `t0` far from zero where `t0 + k·h` rounds, forward
/// and backward; output times; and none for tolerance-driven steps.
#[test]
fn recorded_times_are_the_times_a_run_records_at() {
    let start = event_start();
    for (t0, h) in [(0.0, 0.1), (1e5 + 0.3, 0.07), (2.5, -0.05)] {
        for (steps, every) in [(12, 1), (12, 3), (12, 5), (12, 0), (12, 40), (1, 1), (1, 0)] {
            let plan = RunPlan { stepping: Stepping::Fixed { h, steps }, times: None, events: false };
            let options = RunOptions { record_every: every, ..RunOptions::default() };
            let run =
                integrate_plan(&mut event_stepper(), t0, &start.q, &start.v, &plan, &options, &mut NoObserver).unwrap();
            let recorded: Vec<u64> = run.trajectory.samples.iter().map(|s| s.t.to_bits()).collect();
            let named: Vec<u64> = plan.recorded_times(t0, every).unwrap().iter().map(|t| t.to_bits()).collect();
            assert_eq!(named, recorded, "t0 = {t0}, h = {h}, {steps} steps, every {every}");
        }
    }
    let times = [0.05, 0.3, 0.71];
    let sampled = RunPlan { stepping: Stepping::Fixed { h: 0.1, steps: 8 }, times: Some(&times), events: false };
    let run = integrate_plan(
        &mut event_stepper(),
        0.0,
        &start.q,
        &start.v,
        &sampled,
        &RunOptions::default(),
        &mut NoObserver,
    )
    .unwrap();
    let recorded: Vec<f64> = run.trajectory.samples.iter().map(|s| s.t).collect();
    assert_eq!(sampled.recorded_times(0.0, 1), Some(recorded));
    let adaptive = RunPlan { stepping: Stepping::Tolerance(tolerance(1e-8, 1.0)), times: None, events: false };
    assert_eq!(adaptive.recorded_times(0.0, 1), None);
}
