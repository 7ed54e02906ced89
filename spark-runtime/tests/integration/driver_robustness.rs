//! The integration driver under inputs a demanding user tries: a warm start
//! outside Newton's basin, a stepper reused for a second run, step counts
//! up to `usize::MAX`, unbounded halving, out-of-range options and huge
//! floats in error messages.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use spark_runtime::fixtures::paper::{MobileRobot, Skate};
use spark_runtime::{
    nonholonomic_system, ConsistencyPolicy, FailurePolicy, IntegrationError, Method, NewtonOptions, NoObserver,
    NonholonomicSystem, RejectionPolicy, RunOptions, Schedule, State, StepError, Stepper, Tableau, Vector,
    DEFAULT_MAX_HALVINGS, DEFAULT_MAX_SUBSTEPS, MAX_HALVINGS, MAX_STEP_SIZE,
};

/// Records the largest single allocation of this thread.
struct Largest;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = LARGEST.try_with(|c| c.set(c.get().max(layout.size())));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = LARGEST.try_with(|c| c.set(c.get().max(new_size)));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Largest = Largest;

nonholonomic_system! {
    /// A particle kept at constant speed (k quadratic in v) in an anisotropic well.
    pub struct ConstantSpeed {
        coordinates: [x, y, z],
        parameters: { speed = 1.0, k = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - k/2*(x^2 + 2*y^2 + 3*z^2),
        constraints: [ dot(x)^2 + dot(y)^2 + dot(z)^2 - speed^2 ],
    }
}

nonholonomic_system! {
    /// A spring of stiffness sqrt(t_end − t): the equations are NaN after
    /// t_end, so every step past it fails at any step size.
    pub struct Expiring {
        coordinates: [x, y],
        parameters: { t_end = 0.5 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - sqrt(t_end - t)*(x^2 + y^2)/2,
        constraints: [ dot(y) - dot(x) ],
    }
}

fn speed_start() -> (Vector<3>, Vector<3>) {
    (Vector::<3>::new(0.5, 0.0, 0.0), Vector::<3>::new(0.6, 0.8, 0.0))
}

fn expiring_start() -> (Vector<2>, Vector<2>) {
    (Vector::<2>::new(1.0, 0.0), Vector::<2>::new(0.5, 0.5))
}

fn quiet(max_halvings: u32) -> RunOptions {
    RunOptions { max_halvings, ..RunOptions::default() }
}

/// Lobatto IIIA-B and IIIA-B-D s = 5 at h = 1/4 on |v| = 1: the guess
/// extrapolated from the last steps lies outside Newton's basin at step 3
/// (off by 0.12 in V) while the cold guess converges; the step retries
/// cold before anything else (and so would the driver), so the run
/// succeeds without halving.
#[test]
fn a_failed_warm_start_is_retried_cold() {
    let (q0, v0) = speed_start();
    for method in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
        let mut st: spark_runtime::Stepper![ConstantSpeed, 5] =
            Stepper::new(ConstantSpeed::default(), Tableau::new(method).unwrap());
        let tr = st
            .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.25, steps: 40 }, &quiet(0), &mut NoObserver)
            .unwrap_or_else(|e| panic!("{method}: {e}"));
        let r = tr.report;
        assert_eq!(r.steps, 40);
        assert!(r.cold_retries >= 1, "{method}: {r:?}");
        assert!(r.cold_starts > r.cold_retries, "the first step and every retried one start cold: {r:?}");
        assert_eq!(r.rejected_steps, 0, "{method}: {r:?}");
        assert!(r.max_constraint_residual <= 1e-14, "{method}: {r:?}");
    }
}

/// A second `integrate` on a used stepper, from the end of the first run,
/// is bit-identical to the same run on a fresh stepper: nothing of the
/// first run (warm start, round-off carry, energy anchor) leaks into it.
#[test]
fn a_reused_stepper_reproduces_a_fresh_one() {
    let (q0, v0) = (Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let tab = Tableau::new(Method::Gauss).unwrap();
    let schedule = Schedule::Fixed { h: 0.1, steps: 2500 };
    let opts = RunOptions::default();
    let mut used: spark_runtime::Stepper![MobileRobot, 3] = Stepper::new(MobileRobot::default(), tab);
    let first = used.integrate(0.0, &q0, &v0, schedule, &opts, &mut NoObserver).unwrap();
    let end = first.last().unwrap();
    let again = used.integrate(end.t, &end.q, &end.v, schedule, &opts, &mut NoObserver).unwrap();
    let mut fresh: spark_runtime::Stepper![MobileRobot, 3] = Stepper::new(MobileRobot::default(), tab);
    let reference = fresh.integrate(end.t, &end.q, &end.v, schedule, &opts, &mut NoObserver).unwrap();
    assert_eq!(again, reference);
    // And a rerun from the first initial state repeats the first run.
    let rerun = used.integrate(0.0, &q0, &v0, schedule, &opts, &mut NoObserver).unwrap();
    assert_eq!(rerun, first);

    // A run under the rejection policy to a final time too.
    let reject = RunOptions { on_failure: FailurePolicy::Reject(RejectionPolicy::default()), ..opts };
    let until = Schedule::Until { h: 0.1, t_end: end.t + 250.0 };
    let protected = |st: &mut spark_runtime::Stepper![MobileRobot, 3]| {
        st.integrate(end.t, &end.q, &end.v, until, &reject, &mut |_: &State<4>, _: usize| {}).unwrap()
    };
    let mut fresh: spark_runtime::Stepper![MobileRobot, 3] = Stepper::new(MobileRobot::default(), tab);
    used.integrate(0.0, &q0, &v0, schedule, &opts, &mut NoObserver).unwrap();
    assert_eq!(protected(&mut used), protected(&mut fresh));
}

/// Step counts far beyond what could be recorded: the driver reserves a
/// bounded amount of sample storage up front (a reservation for every step
/// would be 1.1 TB for 1e10 steps and abort; for 2.9e17 it would overflow the
/// capacity), so a run that fails at its third step returns that failure;
/// `usize::MAX` steps and a final time beyond the floats are typed errors,
/// not overflows.
#[test]
fn huge_step_counts_reserve_bounded_storage() {
    let (q0, v0) = expiring_start();
    let mut st: spark_runtime::Stepper![Expiring, 2] =
        Stepper::new(Expiring::default(), Tableau::new(Method::Gauss).unwrap());
    for steps in [10_000_000_000usize, 290_000_000_000_000_000, usize::MAX] {
        LARGEST.with(|c| c.set(0));
        let err = st
            .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.2, steps }, &quiet(2), &mut NoObserver)
            .expect_err("the equations are NaN after t = 0.5");
        let largest = LARGEST.with(|c| c.get());
        match &err {
            IntegrationError::Step { index: 2, partial, .. } => assert_eq!(partial.steps, 2, "{err}"),
            other => panic!("steps = {steps:e}: expected a failure at step 2, got {other}"),
        }
        assert!(largest <= 2 << 20, "steps = {steps:e}: an allocation of {largest} bytes");
    }
    let far = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 1e300, steps: 1 << 40 }, &quiet(0), &mut NoObserver);
    assert!(matches!(far, Err(IntegrationError::InvalidSchedule(_))), "{far:?}");
}

/// A step size the step's equations cannot use is refused before the
/// first step, with what to change: a subnormal `h` (whose `1/h`
/// overflows; it would fail inside Newton with a non-finite residual), an `h`
/// that does not move `t0`, and output times closer than the smallest
/// normal float. The smallest normal step runs.
#[test]
fn unusable_step_sizes_are_refused_before_the_first_step() {
    let (q0, v0) = speed_start();
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    let cases: [(f64, Schedule<'_>, &str); 12] = [
        (0.0, Schedule::Fixed { h: 1e-311, steps: 3 }, "subnormal"),
        (0.0, Schedule::Fixed { h: -5e-324, steps: 3 }, "subnormal"),
        (0.0, Schedule::Sampled { h: 1e-311, times: &[1e-310] }, "subnormal"),
        (0.0, Schedule::Until { h: 1e-311, t_end: 1e-310 }, "subnormal"),
        (1e20, Schedule::Fixed { h: 1.0, steps: 3 }, "resolution of t"),
        // t0 + h moves, but the rounded times t0 + k·h do not advance by h:
        // from 1e12 in steps of 1e-4 (0.82 units in the last place) steps 2
        // and 3 would both end at 1e12 + 2.44e-4.
        (1e12, Schedule::Fixed { h: 1e-4, steps: 3 }, "resolution of t"),
        (-1e12, Schedule::Sampled { h: -1e-3, times: &[-1e12 - 1e-2] }, "resolution of t"),
        (0.0, Schedule::Times(&[1e-320, 1.0]), "closer than 2.2e-308"),
        // h² overflows in the Newton matrix: refused up front, where the run
        // would fail after halving with "non-finite value in the Jacobian".
        (0.0, Schedule::Fixed { h: 1e300, steps: 1 }, "h² overflows"),
        (0.0, Schedule::Until { h: -1e155, t_end: -1e300 }, "h² overflows"),
        (0.0, Schedule::Sampled { h: 1e200, times: &[1e300] }, "h² overflows"),
        (0.0, Schedule::Times(&[1.0, 1e155]), "more than 1.34e154 apart"),
    ];
    for (t0, schedule, what) in cases {
        let err = st.integrate(t0, &q0, &v0, schedule, &quiet(2), &mut NoObserver).unwrap_err();
        assert!(matches!(err, IntegrationError::InvalidSchedule(_)), "{schedule:?}: {err:?}");
        assert!(err.to_string().contains(what) && err.to_string().contains("use"), "{schedule:?}: {err}");
    }
    assert_eq!(spark_runtime::check_step_size(0.0, f64::MIN_POSITIVE), Ok(()));
    assert_eq!(MAX_STEP_SIZE, f64::MAX.sqrt());
    assert!((MAX_STEP_SIZE * MAX_STEP_SIZE).is_finite());
    assert_eq!(spark_runtime::check_step_size(0.0, -MAX_STEP_SIZE), Ok(()));
    assert!(spark_runtime::check_step_size(0.0, MAX_STEP_SIZE * (1.0 + f64::EPSILON))
        .unwrap_err()
        .contains("1.34e154"));
    assert!(spark_runtime::check_step_size(1.0, 1e-17).unwrap_err().contains("resolution of t at t0"));
    // 16 units in the last place of t0 is the smallest step.
    let floor = spark_runtime::time_resolution(1e12);
    assert_eq!(spark_runtime::check_step_size(1e12, floor), Ok(()));
    assert!(spark_runtime::check_step_size(1e12, -floor * (1.0 - f64::EPSILON)).is_err());
    assert!(spark_runtime::check_step_size(f64::NAN, 0.1).is_ok(), "t0 is checked with the initial state");
    // `Stepper::step` called directly refuses a subnormal step as well,
    // before Newton (where `1/h` overflows into a non-finite residual), and
    // a step whose `h²` overflows.
    let start = spark_runtime::State::new(0.0, q0, v0);
    for (h, what) in [(1e-311, "subnormal"), (-5e-324, "subnormal"), (1e200, "h² overflows"), (-1e155, "h² overflows")]
    {
        let err = st.step(&start, h).unwrap_err();
        assert!(matches!(err, spark_runtime::StepError::InvalidStep { .. }), "{h}: {err:?}");
        assert!(err.to_string().contains(what), "{h}: {err}");
    }
    let tiny = Schedule::Fixed { h: f64::MIN_POSITIVE, steps: 3 };
    let traj = st.integrate(0.0, &q0, &v0, tiny, &quiet(2), &mut NoObserver).unwrap();
    assert_eq!(traj.samples.len(), 4);
    assert!(traj.samples.iter().all(|s| s.q.iter().chain(s.v.iter()).all(|x| x.is_finite())));
}

/// `max_halvings` is bounded by [`MAX_HALVINGS`]: `u32::MAX` (a recursive
/// halving would nest ≈ 1075 deep and overflow the stack) is refused by name, and
/// the largest allowed value runs without recursion on a 256 KiB thread
/// and returns promptly at the largest step size, `MAX_STEP_SIZE`.
#[test]
fn halving_is_bounded_and_needs_no_stack() {
    let worker = std::thread::Builder::new().stack_size(256 << 10);
    let handle = worker
        .spawn(|| {
            let (q0, v0) = speed_start();
            let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
                Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
            let huge = Schedule::Fixed { h: MAX_STEP_SIZE, steps: 1 };
            let refused = st.integrate(0.0, &q0, &v0, huge, &quiet(u32::MAX), &mut NoObserver).unwrap_err();
            let deepest = st.integrate(0.0, &q0, &v0, huge, &quiet(MAX_HALVINGS), &mut NoObserver).unwrap_err();
            (refused.to_string(), deepest)
        })
        .unwrap();
    let (refused, deepest) = handle.join().expect("the driver must not overflow a 256 KiB stack");
    assert!(refused.contains("RunOptions::max_halvings") && refused.contains("at most"), "{refused}");
    match &deepest {
        IntegrationError::Step { index: 0, source, .. } => assert!(source.history().is_some(), "{deepest}"),
        other => panic!("expected the Newton failure of step 0, got {other}"),
    }
}

/// Halving stops where half a step no longer changes `t`: at t = 1e15
/// (resolution 0.125) a failing step of size 4 (a fixed step there is at
/// least 16 units in the last place, 3.55) is halved a few times and
/// the run reports the Newton failure, not a step "below the resolution of
/// t" that the driver itself produced.
#[test]
fn halving_stops_at_the_resolution_of_t() {
    let (q0, v0) = expiring_start();
    let mut sys = Expiring::default();
    sys.set_parameter("t_end", 1e15).unwrap();
    let mut st: spark_runtime::Stepper![Expiring, 2] = Stepper::new(sys, Tableau::new(Method::Gauss).unwrap());
    let schedule = Schedule::Fixed { h: 4.0, steps: 3 };
    let err = st.integrate(1e15, &q0, &v0, schedule, &quiet(MAX_HALVINGS), &mut NoObserver).unwrap_err();
    match &err {
        IntegrationError::Step { index: 0, source: StepError::NonFinite { h, .. }, partial, .. } => {
            // Halved while t + h/2 ≠ t: down to h = 2⁻³ = the resolution at 1e15.
            assert_eq!(*h, 0.125, "{err}");
            assert_eq!(partial.steps, 0);
        }
        other => panic!("expected the Newton failure, got {other}"),
    }
}

/// The default `max_halvings` rescues steps Newton cannot solve (|v| = 1
/// with Gauss s = 2 at h = 1.5 needs three halvings; up to h = 0.7 the
/// cold retry alone suffices, at h = 1 one halving) and changes nothing in
/// runs that succeed without it: paper systems and the constant-speed
/// particle give bit-identical trajectories and reports with
/// `max_halvings = 0`.
#[test]
fn the_default_halving_changes_no_successful_run() {
    assert_eq!(RunOptions::default().max_halvings, DEFAULT_MAX_HALVINGS);
    let default = RunOptions::default();
    let (q0, v0) = speed_start();
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    let big = Schedule::Fixed { h: 1.5, steps: 40 };
    let strict = st.integrate(0.0, &q0, &v0, big, &quiet(0), &mut NoObserver);
    assert!(matches!(strict, Err(IntegrationError::Step { .. })), "{strict:?}");
    let rescued = st.integrate(0.0, &q0, &v0, big, &default, &mut NoObserver).unwrap();
    assert!(rescued.report.rejected_steps > 0 && rescued.report.max_constraint_residual <= 1e-14);

    let small = Schedule::Fixed { h: 0.1, steps: 400 };
    let a = st.integrate(0.0, &q0, &v0, small, &quiet(0), &mut NoObserver).unwrap();
    let b = st.integrate(0.0, &q0, &v0, small, &default, &mut NoObserver).unwrap();
    assert_eq!(a, b);

    let (q0, v0) = (Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let mut robot: spark_runtime::Stepper![MobileRobot, 2] =
        Stepper::new(MobileRobot::default(), Tableau::new(Method::LobattoIIIAB).unwrap());
    let s = Schedule::Fixed { h: 0.2, steps: 500 };
    let a = robot.integrate(0.0, &q0, &v0, s, &quiet(0), &mut NoObserver).unwrap();
    let b = robot.integrate(0.0, &q0, &v0, s, &default, &mut NoObserver).unwrap();
    assert_eq!(a, b);

    let (q0, v0) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let mut skate: spark_runtime::Stepper![Skate, 3] =
        Stepper::new(Skate::default(), Tableau::new(Method::LobattoIIIAB).unwrap());
    let times: Vec<f64> = (1..=300).map(|k| 0.1 * k as f64 + 0.01 * (k % 7) as f64).collect();
    let a = skate.integrate(0.0, &q0, &v0, Schedule::Times(&times), &quiet(0), &mut NoObserver).unwrap();
    let b = skate.integrate(0.0, &q0, &v0, Schedule::Times(&times), &default, &mut NoObserver).unwrap();
    assert_eq!(a, b);
}

/// Out-of-range options are refused by name before any step, instead of
/// rejecting a consistent state (`|k| = 0 > NaN`) or blaming the discrete
/// map for every step.
#[test]
fn invalid_options_are_refused_by_name() {
    let (q0, v0) = speed_start();
    let schedule = Schedule::Fixed { h: 0.1, steps: 5 };
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    for (consistency, name) in [
        (ConsistencyPolicy::Error { tolerance: f64::NAN }, "ConsistencyPolicy::Error::tolerance"),
        (ConsistencyPolicy::Error { tolerance: -1.0 }, "ConsistencyPolicy::Error::tolerance"),
        (ConsistencyPolicy::Project { tolerance: f64::NAN }, "ConsistencyPolicy::Project::tolerance"),
    ] {
        let opts = RunOptions { consistency, ..RunOptions::default() };
        match st.integrate(0.0, &q0, &v0, schedule, &opts, &mut NoObserver) {
            Err(IntegrationError::InvalidOption(e)) => assert_eq!(e.option, name, "{e}"),
            other => panic!("{consistency:?}: expected InvalidOption, got {other:?}"),
        }
    }
    // A valid tolerance still accepts the consistent state.
    let opts = RunOptions { consistency: ConsistencyPolicy::Error { tolerance: 0.0 }, ..RunOptions::default() };
    st.integrate(0.0, &q0, &v0, schedule, &opts, &mut NoObserver).unwrap();

    // The energy guard's limit, for a system whose energy it checks.
    let (rq, rv) = (Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let robot = State::new(0.0, rq, rv);
    for limit in [f64::NAN, -1.0, 0.0, f64::INFINITY] {
        let newton = NewtonOptions { energy_drift_limit: Some(limit), ..NewtonOptions::default() };
        let mut st: spark_runtime::Stepper![MobileRobot, 2] =
            Stepper::new(MobileRobot::default(), Tableau::new(Method::Gauss).unwrap()).with_options(newton);
        match st.integrate(0.0, &rq, &rv, schedule, &RunOptions::default(), &mut NoObserver) {
            Err(IntegrationError::InvalidOption(e)) => {
                assert_eq!(e.option, "NewtonOptions::energy_drift_limit", "{e}");
                assert!(e.to_string().contains("None turns the energy guard off"), "{e}");
            }
            other => panic!("limit {limit}: expected InvalidOption, got {other:?}"),
        }
        match st.step(&robot, 0.1) {
            Err(StepError::InvalidOption(e)) => assert_eq!(e.option, "NewtonOptions::energy_drift_limit"),
            other => panic!("limit {limit}: expected InvalidOption from step, got {other:?}"),
        }
        // Repaired through options_mut, the same stepper steps again.
        st.options_mut().energy_drift_limit = Some(1.0);
        st.step(&robot, 0.1).unwrap();
    }
    for (newton, name) in [
        (NewtonOptions { tolerance: f64::NAN, ..NewtonOptions::default() }, "NewtonOptions::tolerance"),
        (NewtonOptions { tolerance: -1e-15, ..NewtonOptions::default() }, "NewtonOptions::tolerance"),
        // A tolerance of 1 or more accepts an update with no correct digit.
        (NewtonOptions { tolerance: 1.0, ..NewtonOptions::default() }, "NewtonOptions::tolerance"),
        (NewtonOptions { tolerance: 1e300, ..NewtonOptions::default() }, "NewtonOptions::tolerance"),
        (NewtonOptions { tolerance: f64::INFINITY, ..NewtonOptions::default() }, "NewtonOptions::tolerance"),
        (
            NewtonOptions { stagnation_level: f64::INFINITY, ..NewtonOptions::default() },
            "NewtonOptions::stagnation_level",
        ),
        (NewtonOptions { max_iterations: 0, ..NewtonOptions::default() }, "NewtonOptions::max_iterations"),
        (NewtonOptions { max_iterations: 33, ..NewtonOptions::default() }, "NewtonOptions::max_iterations"),
        (NewtonOptions { extrapolation_degree: 0, ..NewtonOptions::default() }, "NewtonOptions::extrapolation_degree"),
    ] {
        assert_eq!(newton.validate().unwrap_err().option, name);
    }
    NewtonOptions { tolerance: 0.0, ..NewtonOptions::default() }.validate().unwrap();
    NewtonOptions { tolerance: 0.5, ..NewtonOptions::default() }.validate().unwrap();
}

fn longest_digit_run(s: &str) -> usize {
    s.split(|c: char| !c.is_ascii_digit()).map(str::len).max().unwrap_or(0)
}

/// Floats in error messages are compact: h = 1e300 prints as `1.000e300`,
/// not as a 301-digit number (a run refuses that step size up front, so
/// its messages are checked at h = 1e150).
#[test]
fn error_messages_print_floats_compactly() {
    let (q0, v0) = speed_start();
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    let sys = ConstantSpeed::default();
    assert!(sys.constraint(0.0, &q0, &v0).amax() <= 1e-15);
    let start = State::new(1e300, q0, v0);
    let stepped = [
        st.step(&start, 1e300).unwrap_err().to_string(),
        st.step(&State::new(0.0, q0, v0), 1e300).unwrap_err().to_string(),
    ];
    // `Stepper::step` refuses the step size before Newton, whose matrix
    // would overflow, and says to use a smaller one.
    assert!(stepped[1].contains("h² overflows") && stepped[1].contains("smaller |h|"), "{}", stepped[1]);
    let mut runs = vec![st
        .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 1e150, steps: 1 }, &quiet(0), &mut NoObserver)
        .unwrap_err()
        .to_string()];
    // Under the rejection policy the step is cut down to its floor
    // (1e150·2⁻¹²), and the error names the sizes tried.
    let reject = RunOptions { on_failure: FailurePolicy::Reject(RejectionPolicy::default()), ..quiet(0) };
    let protected = st.integrate(0.0, &q0, &v0, Schedule::Until { h: 1e150, t_end: 1e150 }, &reject, &mut NoObserver);
    let protected = protected.unwrap_err();
    assert!(matches!(protected, IntegrationError::Floor { .. }), "{protected}");
    runs.push(protected.to_string());
    for (messages, exponent) in [(&stepped[..], "e300"), (&runs[..], "e150")] {
        for m in messages {
            assert!(longest_digit_run(m) <= 17, "{m}");
            assert!(m.contains(exponent), "{m}");
        }
    }
}

/// The largest `|E − E₀|` and `max |k|` over every step, from the system the
/// driver hands to the observer.
struct Extremes {
    e0: f64,
    max_energy_error: f64,
    max_residual: f64,
    steps: usize,
}

impl<const N: usize, const M: usize> spark_runtime::Observer<N, M> for Extremes {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, system: &Sys, s: &State<N>, _: usize) {
        self.max_energy_error = self.max_energy_error.max((system.energy(s.t, &s.q, &s.v) - self.e0).abs());
        self.max_residual = self.max_residual.max(system.constraint(s.t, &s.q, &s.v).amax());
        self.steps += 1;
    }
}

#[test]
fn the_report_covers_every_step_and_the_observer_sees_the_system() {
    let sys = Skate::default();
    let q0 = Vector::<3>::new(0.0, 0.0, 0.0);
    let v0 = Vector::<3>::new(1.0, 0.0, 1.0);
    let mut st = Stepper::<Skate, 3, 1, 2, 11>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let (h, steps) = (0.3, 200);
    let mut extremes = Extremes {
        e0: sys.energy(0.0, &q0, &v0),
        max_energy_error: 0.0,
        max_residual: sys.constraint(0.0, &q0, &v0).amax(),
        steps: 0,
    };
    // Only the endpoints are recorded; the report still covers every step.
    let options = RunOptions { record_every: 0, ..RunOptions::default() };
    let traj = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h, steps }, &options, &mut extremes).unwrap();
    assert_eq!(traj.samples.len(), 2);
    assert_eq!(extremes.steps, steps);
    assert!(extremes.max_energy_error > 0.0 && extremes.max_residual > 0.0);
    assert_eq!(traj.report.max_energy_error, extremes.max_energy_error);
    assert_eq!(traj.report.max_constraint_residual, extremes.max_residual);
    // Recording every step gives the same extremes.
    let every = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h, steps }, &RunOptions::default(), &mut NoObserver);
    let every = every.unwrap();
    assert_eq!(every.report.max_energy_error, traj.report.max_energy_error);
    assert_eq!(every.report.max_constraint_residual, traj.report.max_constraint_residual);
    // Quantities not observed stay zero.
    let none = RunOptions {
        observe: spark_runtime::Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let quiet = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h, steps }, &none, &mut NoObserver).unwrap();
    assert_eq!((quiet.report.max_energy_error, quiet.report.max_constraint_residual), (0.0, 0.0));
}

/// Step rejection is a failure policy of the one driver loop: under
/// `FailurePolicy::Reject` a run of the constant-speed particle at h = 1.5
/// (where Newton fails without help) is rescued by adaptive sub-steps and
/// the report counts them; the run with a terminal event, the dense output
/// and the samples work as under the default policy; a run that needs no
/// rejection is bit-identical under every policy; giving up at the floor is
/// an `IntegrationError::Floor`.
#[test]
fn rejection_is_a_failure_policy_of_the_driver() {
    let (q0, v0) = speed_start();
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    let policy = RejectionPolicy::default();
    let reject = RunOptions { on_failure: FailurePolicy::Reject(policy), ..RunOptions::default() };
    let big = Schedule::Fixed { h: 1.5, steps: 40 };
    let run = st.integrate(0.0, &q0, &v0, big, &reject, &mut NoObserver).unwrap();
    let r = run.report;
    assert_eq!(r.steps, 40);
    assert!(r.rejected_steps > 0 && r.steps_with_rejections > 0, "{r:?}");
    assert!(r.substeps > r.steps && r.smallest_step < 1.5, "{r:?}");
    assert!(r.max_constraint_residual <= 1e-14, "{r:?}");
    assert_eq!(run.samples.last().unwrap().t, 60.0);

    // The same run to a final time: the observer sees every scheduled
    // step's end, the report the same sub-steps.
    let mut count = 0;
    let until = Schedule::Until { h: 1.5, t_end: 60.0 };
    let protected = st.integrate(0.0, &q0, &v0, until, &reject, &mut |_: &State<3>, _: usize| count += 1).unwrap();
    assert_eq!(count, 40);
    let end = protected.last().unwrap();
    assert_eq!((end.q, end.v), (run.samples.last().unwrap().q, run.samples.last().unwrap().v));
    let p = protected.report;
    assert_eq!((p.rejected_steps, p.substeps, p.smallest_step), (r.rejected_steps, r.substeps, r.smallest_step));

    // No failure: one sub-step per step, the same run up to the rounding
    // of the step sizes (rejection steps to the end of the interval).
    let small = Schedule::Fixed { h: 0.1, steps: 400 };
    let a = st.integrate(0.0, &q0, &v0, small, &RunOptions::default(), &mut NoObserver).unwrap();
    let b = st.integrate(0.0, &q0, &v0, small, &reject, &mut NoObserver).unwrap();
    assert_eq!((b.report.rejected_steps, b.report.substeps), (0, 400));
    let (ea, eb) = (a.last().unwrap(), b.last().unwrap());
    assert!((ea.q - eb.q).amax() < 1e-10 && (ea.v - eb.v).amax() < 1e-10, "{ea:?} {eb:?}");

    // Sampled output through the dense extension of the rejected sub-steps.
    let times: Vec<f64> = (1..=30).map(|k| 2.0 * k as f64).collect();
    let sampled = st.integrate(0.0, &q0, &v0, Schedule::Sampled { h: 1.5, times: &times }, &reject, &mut NoObserver);
    let sampled = sampled.unwrap();
    assert_eq!(sampled.samples.len(), 31);
    // t = 6 ends the fourth step: the sample there is the step's end.
    assert_eq!(sampled.samples[3].t, 6.0);
    assert_eq!((sampled.samples[3].q, sampled.samples[3].v), (run.samples[4].q, run.samples[4].v));
    assert_eq!(sampled.report.rejected_steps, r.rejected_steps);

    // No room to halve: the floor is reached at once.
    let tight =
        RunOptions { on_failure: FailurePolicy::Reject(RejectionPolicy { max_halvings: 0, ..policy }), ..reject };
    match st.integrate(0.0, &q0, &v0, big, &tight, &mut NoObserver) {
        Err(IntegrationError::Floor { detail, partial, .. }) => assert!(detail.rejections == 1 && partial.steps < 40),
        other => panic!("expected the floor, got {other:?}"),
    }
    match st.integrate(0.0, &q0, &v0, until, &tight, &mut NoObserver) {
        Err(IntegrationError::Floor { detail, partial, .. }) => assert!(detail.rejections == 1 && partial.steps < 40),
        other => panic!("expected the floor, got {other:?}"),
    }
    // An invalid policy is an option error before any step.
    let bad = RunOptions { on_failure: FailurePolicy::Reject(RejectionPolicy { regrow_after: 0, ..policy }), ..reject };
    match st.integrate(0.0, &q0, &v0, big, &bad, &mut NoObserver) {
        Err(IntegrationError::InvalidOption(e)) => assert_eq!(e.option, "RejectionPolicy::regrow_after"),
        other => panic!("expected an option error, got {other:?}"),
    }
}

/// An observer that wants the dense output: records every accepted state
/// and counts the continuous extensions it is given.
struct DenseRecorder<const N: usize> {
    states: Vec<(State<N>, usize)>,
    pieces: usize,
}

impl<const N: usize, const M: usize> spark_runtime::Observer<N, M> for DenseRecorder<N> {
    const DENSE: bool = true;
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, s: &State<N>, iterations: usize) {
        self.states.push((*s, iterations));
    }
    fn observe_dense<const S: usize>(&mut self, step: &spark_runtime::DenseStep<'_, N, S>) {
        assert_eq!(step.state_at(step.end.t), step.end);
        self.pieces += 1;
    }
}

/// `system` from `(0, q0, v0)` by `method` with `s` stages: `integrate`
/// takes exactly the steps of a bare loop of `Stepper::step` whatever the
/// observer (a closure, a dense one, none), and the run continues each
/// step from the previous one where the schedule pins the step times.
fn matches_the_bare_loop<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: Sys,
    method: Method,
    q0: Vector<N>,
    v0: Vector<N>,
    steps: usize,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let tab = Tableau::<S>::new(method).unwrap();
    // h = 1/8 from t = 0: the step times accumulate exactly, so the bare
    // loop's states are the ones the driver pins.
    let h = 0.125;
    let mut bare = Stepper::<Sys, N, M, S, D>::new(system.clone(), tab);
    let mut state = State::new(0.0, q0, v0);
    let mut expected = Vec::with_capacity(steps);
    for _ in 0..steps {
        let r = bare.step(&state, h).unwrap();
        state = r.state;
        expected.push((r.state, r.iterations));
    }
    let mut st = Stepper::<Sys, N, M, S, D>::new(system, tab);
    let schedule = Schedule::Fixed { h, steps };
    let name = std::any::type_name::<Sys>();

    let mut seen = Vec::with_capacity(steps);
    let tr = st
        .integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut |s: &State<N>, i: usize| seen.push((*s, i)))
        .unwrap();
    assert!(seen == expected, "{name} {method}: the closure observer's states differ from the bare loop's");
    assert_eq!(tr.samples.len(), steps + 1);
    for (s, (e, i)) in tr.samples[1..].iter().zip(&expected) {
        assert_eq!((s.t, s.q, s.v, s.newton_iterations), (e.t, e.q, e.v, *i), "{name} {method}");
    }
    assert_eq!(tr.report.cold_starts, 1, "{name} {method}: {:?}", tr.report);

    let mut dense = DenseRecorder { states: Vec::new(), pieces: 0 };
    st.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut dense).unwrap();
    assert!(dense.states == expected, "{name} {method}: the dense observer's states differ from the bare loop's");
    assert_eq!(dense.pieces, steps);

    let quiet = RunOptions {
        observe: spark_runtime::Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let end = st.integrate(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver).unwrap().last().unwrap();
    assert_eq!(end, expected[steps - 1].0, "{name} {method}");

    // h = 0.1: t₀ + Σh drifts from the pinned (k+1)·h, and every step still
    // continues the previous one (warm started, no second cold start).
    let tenth = st.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps }, &quiet, &mut NoObserver).unwrap();
    assert_eq!(tenth.report.cold_starts, 1, "{name} {method}: {:?}", tenth.report);
    assert_eq!(tenth.last().unwrap().t, 0.1 * steps as f64);
}

/// The driver adds no arithmetic of its own to the steps: its states, with
/// the Newton iteration counts, are the bare `Stepper::step` loop's bit for
/// bit, for every kind of observer.
#[test]
fn integrate_takes_the_steps_of_a_bare_step_loop() {
    let robot = (Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    matches_the_bare_loop::<MobileRobot, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, robot.0, robot.1, 400);
    let skate = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    matches_the_bare_loop::<Skate, 3, 1, 3, 15>(Skate::default(), Method::LobattoIIIAB, skate.0, skate.1, 400);
    let (q0, v0) = speed_start();
    matches_the_bare_loop::<ConstantSpeed, 3, 1, 2, 11>(ConstantSpeed::default(), Method::Gauss, q0, v0, 200);
}

/// The sub-steps of one recovery are bounded by `RunOptions::max_substeps`
/// under either failure policy: a spring of stiffness 1e8 stepped at h = 1
/// converges only on sub-steps thousands of times smaller, so deep halving
/// (`MAX_HALVINGS`) or a rejection floor of 2⁻⁶⁰·h would cover the step by
/// that many Newton solves; the run instead reports the budget, with the
/// accepted sub-steps and the last failure. A budget that the recovery
/// fits in changes nothing, and a budget of 0 is refused by name.
#[test]
fn a_recovery_stays_within_its_substep_budget() {
    let (q0, v0) = speed_start();
    let mut stiff = ConstantSpeed::default();
    stiff.set_parameter("k", 1e14).unwrap();
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] = Stepper::new(stiff, Tableau::new(Method::Gauss).unwrap());
    let one = Schedule::Fixed { h: 1.0, steps: 3 };
    let deep = RunOptions { max_halvings: MAX_HALVINGS, ..RunOptions::default() };
    let deepest = RejectionPolicy { max_halvings: MAX_HALVINGS, min_step: 0.0, regrow_after: 2 };
    let rejecting = RunOptions { on_failure: FailurePolicy::Reject(deepest), ..RunOptions::default() };
    for options in [deep, rejecting] {
        let err = st.integrate(0.0, &q0, &v0, one, &options, &mut NoObserver).unwrap_err();
        match &err {
            IntegrationError::SubstepBudget { index: 0, t, detail, partial } => {
                assert_eq!((*t, detail.h, detail.budget), (0.0, 1.0, DEFAULT_MAX_SUBSTEPS), "{err}");
                assert!(detail.substeps <= DEFAULT_MAX_SUBSTEPS, "{err}");
                assert!(detail.substep_t > 0.0 && detail.substep_t < 1.0, "{err}");
                assert!(detail.smallest > 0.0 && detail.smallest < 1e-3, "{err}");
                assert_eq!(partial.steps, 0);
                assert!(err.to_string().contains("RunOptions::max_substeps"), "{err}");
            }
            other => panic!("expected the sub-step budget, got {other}"),
        }
    }

    // Four halvings take at most 2⁴ sub-steps: a budget of 16 is never
    // reached and the run is the default's bit for bit; a budget of 1
    // leaves no room to halve the first failing step.
    let mut st: spark_runtime::Stepper![ConstantSpeed, 2] =
        Stepper::new(ConstantSpeed::default(), Tableau::new(Method::Gauss).unwrap());
    let big = Schedule::Fixed { h: 1.5, steps: 40 };
    let default = st.integrate(0.0, &q0, &v0, big, &RunOptions::default(), &mut NoObserver).unwrap();
    assert!(default.report.rejected_steps > 0, "{:?}", default.report);
    let sixteen = RunOptions { max_substeps: 1 << DEFAULT_MAX_HALVINGS, ..RunOptions::default() };
    let fits = st.integrate(0.0, &q0, &v0, big, &sixteen, &mut NoObserver).unwrap();
    assert_eq!(fits, default);
    let one_substep = RunOptions { max_substeps: 1, ..RunOptions::default() };
    match st.integrate(0.0, &q0, &v0, big, &one_substep, &mut NoObserver) {
        Err(IntegrationError::SubstepBudget { index, detail, partial, .. }) => {
            assert_eq!((detail.budget, detail.substeps, partial.steps), (1, 0, index))
        }
        other => panic!("expected the sub-step budget, got {other:?}"),
    }
    let rejecting_one = RunOptions { max_substeps: 1, ..rejecting };
    match st.integrate(0.0, &q0, &v0, big, &rejecting_one, &mut NoObserver) {
        Err(IntegrationError::SubstepBudget { index, detail, partial, .. }) => {
            assert_eq!((detail.budget, detail.substeps, partial.steps), (1, 1, index))
        }
        other => panic!("expected the sub-step budget, got {other:?}"),
    }
    let none = RunOptions { max_substeps: 0, ..RunOptions::default() };
    match st.integrate(0.0, &q0, &v0, big, &none, &mut NoObserver) {
        Err(IntegrationError::InvalidOption(e)) => assert_eq!(e.option, "RunOptions::max_substeps"),
        other => panic!("expected an option error, got {other:?}"),
    }
}

/// A front end refuses a request whose record would not fit in memory
/// (`check_record_size`): 2⁶² recorded steps are refused, and the record
/// interval the error names makes the same request fit; a short run fits.
#[test]
fn a_record_that_would_not_fit_names_the_interval_that_does() {
    let per_sample = 200;
    assert!(spark_runtime::check_record_size(1000, 1, 1, per_sample).is_ok());
    for (steps, members) in [(1usize << 62, 1usize), (usize::MAX, 1), (1 << 30, 1000)] {
        let e = spark_runtime::check_record_size(steps, 1, members, per_sample).unwrap_err();
        assert!(e.bytes > e.limit as f64 && e.limit <= 4 << 30, "{e}");
        assert!(e.to_string().contains(&format!("record every {}-th step", e.every)), "{e}");
        assert!(spark_runtime::check_record_size(steps, e.every as usize, members, per_sample).is_ok(), "{e}");
    }
}

nonholonomic_system! {
    /// A speed fixed along a curve, `|v|²(1 + x²) = c`: a constraint
    /// nonlinear in `v` and `q`, on which Newton diverges at `h = 10`.
    pub struct SpeedOnCurve {
        coordinates: [x, y, z],
        parameters: { c = 1.2, kap = 0.8, e = 0.3 },
        lagrangian: (dot(x)^2 + dot(y)^2 + (1 + y^2/2)*dot(z)^2)/2 - kap/2*(x^2 + y^2 + z^2) - e*x*z,
        constraints: [ (dot(x)^2 + dot(y)^2 + dot(z)^2)*(1 + x^2) - c ],
    }
}

/// A stagnation level of 1 or more accepts, as round-off, the update of an
/// iteration that has stopped contracting however large it is — an update
/// with no correct digit, the reason `tolerance` stays below 1. With
/// `stagnation_level = 1e300` a Lobatto IIIA-B-D step of `SpeedOnCurve`
/// that Newton cannot solve (h = 10) came back `Ok` with `|v₁| ≈ 5e5` and
/// the constraint violated by 6e20 (simplified Newton; 2e9 with full
/// Newton). Such a level is an invalid option, as an out-of-range tolerance is.
#[test]
fn a_stagnation_level_of_one_or_more_is_refused_rather_than_a_diverged_step_returned_as_ok() {
    use spark_runtime::{consistent_velocity, NewtonMode};
    let sys = SpeedOnCurve::default();
    let q0 = Vector::<3>::new(0.4, -0.3, 0.2);
    let v0 = consistent_velocity(
        &sys,
        0.1,
        &q0,
        &Vector::<3>::new(0.6, 0.5, -0.4),
        ConsistencyPolicy::Project { tolerance: 0.0 },
    )
    .unwrap();
    let start = State::new(0.1, q0, v0);
    for mode in [NewtonMode::Full, NewtonMode::Simplified] {
        let newton = NewtonOptions { mode, ..NewtonOptions::default() };
        let mut st: spark_runtime::Stepper![SpeedOnCurve, 2] =
            Stepper::new(sys, Tableau::new(Method::LobattoIIIABD).unwrap()).with_options(newton);
        assert!(st.step(&start, 10.0).is_err(), "{mode:?}: the step at h = 10 is expected to fail");
        for level in [1e300, 1e3, 1.0] {
            let newton = NewtonOptions { mode, stagnation_level: level, ..NewtonOptions::default() };
            let mut st: spark_runtime::Stepper![SpeedOnCurve, 2] =
                Stepper::new(sys, Tableau::new(Method::LobattoIIIABD).unwrap()).with_options(newton);
            match st.step(&start, 10.0) {
                Err(StepError::InvalidOption(e)) => {
                    assert_eq!(e.option, "NewtonOptions::stagnation_level", "{e}");
                    assert!(e.to_string().contains("[0, 1)"), "{e}");
                }
                Ok(r) => panic!(
                    "{mode:?}, stagnation_level {level:e}: Ok with v1 = {:?}, |k(t1, q1, v1)| = {:.1e}",
                    r.state.v.as_slice(),
                    sys.constraint(r.state.t, &r.state.q, &r.state.v)[0].abs()
                ),
                Err(other) => panic!("{mode:?}, stagnation_level {level:e}: expected InvalidOption, got {other}"),
            }
            assert_eq!(newton.validate().unwrap_err().option, "NewtonOptions::stagnation_level");
        }
    }
    for level in [0.0, 1e-12, 0.5] {
        NewtonOptions { stagnation_level: level, ..NewtonOptions::default() }.validate().unwrap();
    }
}

/// A final time on the step grid computed in floats, `t_end = t₀ + k·h`,
/// can round past the grid point the driver computes: from `t₀ = 0` with
/// `h = 0.1`, `t_end = 0.1·3` makes `(t_end − t₀)/h` 3.0000000000000004,
/// whose ceiling asked for a fourth step of size 0, and the run failed
/// after its three steps. A `t_end` a few units in the last place past a
/// grid point gave a last step below the time's resolution. Such a run
/// takes `k` steps, the last one landing on `t_end`.
#[test]
fn a_final_time_on_the_grid_computed_in_floats_takes_its_steps() {
    let tab = Tableau::new(Method::Gauss).unwrap();
    let (q0, v0) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let mut st: spark_runtime::Stepper![Skate, 2] = Stepper::new(Skate::default(), tab);
    let mut grids = 0;
    for t0 in [0.0, 0.3, 0.7, 1.0] {
        for h in [0.1, 0.01, 0.05, -0.1, 0.3] {
            for k in 1..60usize {
                let t_end = t0 + k as f64 * h;
                let run = st
                    .integrate(t0, &q0, &v0, Schedule::Until { h, t_end }, &RunOptions::default(), &mut NoObserver)
                    .unwrap_or_else(|e| panic!("t0 = {t0}, h = {h}, k = {k}, t_end = {t_end:e}: {e}"));
                let end = run.last().unwrap();
                assert_eq!(end.t, t_end, "t0 = {t0}, h = {h}, k = {k}");
                assert_eq!(run.report.steps, k, "t0 = {t0}, h = {h}, k = {k}, t_end = {t_end:e}");
                grids += usize::from(((t_end - t0) / h).abs() > k as f64);
            }
        }
    }
    // The quotient rounds past `k` in some of these (the case of the test).
    assert!(grids > 0);
    // A final time a few units in the last place past a grid point.
    let t_end = 0.3 + 1e-16;
    let run = st
        .integrate(0.0, &q0, &v0, Schedule::Until { h: 0.1, t_end }, &RunOptions::default(), &mut NoObserver)
        .unwrap();
    assert_eq!((run.report.steps, run.last().unwrap().t), (3, t_end));
    // A final time half a step past the grid keeps its short last step.
    let run = st
        .integrate(0.0, &q0, &v0, Schedule::Until { h: 0.1, t_end: 0.35 }, &RunOptions::default(), &mut NoObserver)
        .unwrap();
    assert_eq!((run.report.steps, run.last().unwrap().t), (4, 0.35));
}
