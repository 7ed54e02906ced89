//! The bad-input case: every invalid input comes back as a typed error.

use super::{integration_error_kind, step_error_kind};
use crate::experiments::stress::{CaseReport, Scale, StressError};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::systems::stress::NearParallel;
use crate::systems::Skate;
use spark_runtime::{
    FailurePolicy, Method, NonholonomicSystem, RejectionPolicy, RunOptions, Schedule, State, Stepper, Vector,
};

/// One bad-input scenario: what it is, the error kind expected, what came back.
struct Bad {
    what: &'static str,
    expected: &'static str,
    got: Result<String, String>,
    observed_steps: usize,
}

/// NaN/inf state and parameters, `h = 0`, an inconsistent initial state, a
/// final time behind the start: each must come back as the expected typed
/// error before any step is observed.
pub fn bad_input(_scale: Scale) -> Result<CaseReport, StressError> {
    let mut c = CaseReport::new(
        "bad_input",
        "Bad input",
        "Each scenario calls the library as a user would (driver `integrate`, `Stepper::step`, `set_parameter`, \
         `integrate` under the rejection policy) on the skate or the near-parallel particle, and must return the expected typed \
         error with no step taken (an observer counts the steps; nothing is returned but the error).",
    );
    let mut cases = driver_scenarios();
    cases.extend(parameter_scenarios());
    cases.push(nan_constraint_scenario()?);
    cases.extend(stepper_scenarios()?);
    cases.extend(protected_scenarios()?);
    for b in &cases {
        let (passed, detail) = match &b.got {
            Ok(s) => (false, format!("no error: {s}")),
            Err(msg) => {
                let kind = msg.split(" — ").next().unwrap_or("");
                c.errors.push(format!("{}: {msg}", b.what));
                (kind == b.expected && b.observed_steps == 0, format!("{msg} (steps observed: {})", b.observed_steps))
            }
        };
        c.check(format!("{} → {}", b.what, b.expected), passed, detail);
    }
    c.energy = "—".into();
    c.figure = Some(bad_input_figure(&c, cases.len()));
    Ok(c)
}

/// The initial state of the skate scenarios.
fn skate_start() -> (Vector<3>, Vector<3>) {
    (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0))
}

/// The schedule of the driver scenarios.
const FIXED: Schedule<'static> = Schedule::Fixed { h: 0.1, steps: 10 };

/// The outcome of a driver run and the number of steps its observer saw.
fn driven<const N: usize, const M: usize>(
    r: Result<spark_runtime::Trajectory<N, M>, spark_runtime::IntegrationError>,
    count: usize,
) -> (Result<String, String>, usize) {
    (
        r.map(|t| format!("Ok({} steps)", t.report.steps)).map_err(|e| format!("{} — {e}", integration_error_kind(&e))),
        count,
    )
}

/// Bad states, step sizes, output times and parameter fields through the
/// driver, on the skate.
fn driver_scenarios() -> Vec<Bad> {
    let (q0, v0) = skate_start();
    let opts = RunOptions::default();
    let drive = |sys: Skate, q: Vector<3>, v: Vector<3>, schedule: Schedule<'_>| -> (Result<String, String>, usize) {
        let mut st = <Stepper![Skate, 2]>::new(sys, spark_runtime::Tableau::new(Method::Gauss).expect("s=2"));
        let mut count = 0usize;
        let mut obs = |_: &State<3>, _: usize| count += 1;
        let r = st.integrate(0.0, &q, &v, schedule, &opts, &mut obs);
        driven(r, count)
    };
    let bad = |what, expected, (got, observed_steps): (Result<String, String>, usize)| Bad {
        what,
        expected,
        got,
        observed_steps,
    };
    let nan_field = Skate { beta: f64::NAN, ..Skate::default() };
    let inf_field = Skate { g: f64::INFINITY, ..Skate::default() };
    vec![
        bad(
            "NaN in q0",
            "Initial/InvalidStep",
            drive(Skate::default(), Vector::<3>::new(f64::NAN, 0.0, 0.0), v0, FIXED),
        ),
        bad(
            "+inf in v0",
            "Initial/InvalidStep",
            drive(Skate::default(), q0, Vector::<3>::new(0.0, 0.0, f64::INFINITY), FIXED),
        ),
        bad("h = 0", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: 0.0, steps: 10 })),
        bad("h = NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: f64::NAN, steps: 10 })),
        bad("output time NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Times(&[0.5, f64::NAN]))),
        bad(
            "inconsistent initial state (v0 = (1, 1, 0), |k| = 1)",
            "Initial/InconsistentInitialState",
            drive(Skate::default(), q0, Vector::<3>::new(1.0, 1.0, 0.0), FIXED),
        ),
        bad(
            "parameter field beta = NaN (set directly)",
            "Initial/NonFiniteInitialValue",
            drive(nan_field, q0, v0, FIXED),
        ),
        bad(
            "parameter field g = +inf (set directly)",
            "Initial/NonFiniteInitialValue",
            drive(inf_field, q0, v0, FIXED),
        ),
        bad(
            "v0 = (0, 0, 1e155): |v0|² and the energy overflow",
            "Initial/NonFiniteInitialValue",
            drive(Skate::default(), q0, Vector::<3>::new(0.0, 0.0, 1e155), FIXED),
        ),
        bad(
            "mass m = 0: singular mass matrix",
            "Initial/SingularInitialState",
            drive(Skate { m: 0.0, ..Skate::default() }, q0, v0, FIXED),
        ),
        bad(
            "h = 1e300 (h² overflows)",
            "InvalidSchedule",
            drive(Skate::default(), q0, v0, Schedule::Fixed { h: 1e300, steps: 1 }),
        ),
    ]
}

/// Non-finite and unknown parameters through `set_parameter`.
fn parameter_scenarios() -> Vec<Bad> {
    let mut sk = Skate::default();
    let api = |what, expected, r: Result<(), spark_runtime::SystemError>| {
        let got = match r {
            Ok(()) => Ok("accepted".to_string()),
            Err(e) => Err(format!(
                "{} — {e}",
                match e {
                    spark_runtime::SystemError::NonFiniteParameter { .. } => "NonFiniteParameter",
                    spark_runtime::SystemError::UnknownParameter { .. } => "UnknownParameter",
                }
            )),
        };
        Bad { what, expected, got, observed_steps: 0 }
    };
    vec![
        api("set_parameter(\"beta\", NaN)", "NonFiniteParameter", sk.set_parameter("beta", f64::NAN)),
        api("set_parameter(\"g\", -inf)", "NonFiniteParameter", sk.set_parameter("g", f64::NEG_INFINITY)),
        api("set_parameter(\"gravity\", 1)", "UnknownParameter", sk.set_parameter("gravity", 1.0)),
    ]
}

/// A constraint that depends on a non-finite parameter: the initial check
/// must say so.
fn nan_constraint_scenario() -> Result<Bad, StressError> {
    let sys = NearParallel { eps: f64::NAN };
    let mut st = <Stepper![NearParallel, 2]>::new(sys, spark_runtime::Tableau::new(Method::Gauss)?);
    let mut count = 0usize;
    let mut obs = |_: &State<3>, _: usize| count += 1;
    let (q, v) = (Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(0.3, 0.0, 0.15));
    let r = st.integrate(0.0, &q, &v, FIXED, &RunOptions::default(), &mut obs);
    let (got, observed_steps) = driven(r, count);
    Ok(Bad { what: "parameter field eps = NaN in the constraint", expected: "Initial/NonFinite", got, observed_steps })
}

/// Bad times and step sizes through `Stepper::step` directly.
fn stepper_scenarios() -> Result<Vec<Bad>, StressError> {
    let (q0, v0) = skate_start();
    let mut st = <Stepper![Skate, 2]>::new(Skate::default(), spark_runtime::Tableau::new(Method::Gauss)?);
    let mut step = |what, s: State<3>, h: f64| Bad {
        what,
        expected: "InvalidStep",
        got: st.step(&s, h).map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", step_error_kind(&e))),
        observed_steps: 0,
    };
    Ok(vec![
        step("Stepper::step with h = 0", State::new(0.0, q0, v0), 0.0),
        step("Stepper::step with t0 = NaN", State::new(f64::NAN, q0, v0), 0.1),
        step("Stepper::step with h = -inf", State::new(0.0, q0, v0), f64::NEG_INFINITY),
        step("Stepper::step with h below the resolution of t (t0 = 1e20, h = 1)", State::new(1e20, q0, v0), 1.0),
    ])
}

/// A final time behind the start, `h = 0` and a bad policy through the
/// driver under the rejection policy (`FailurePolicy::Reject`, a run to a
/// final time; the first two count the steps they observe).
fn protected_scenarios() -> Result<Vec<Bad>, StressError> {
    let (q0, v0) = skate_start();
    let mut st = <Stepper![Skate, 2]>::new(Skate::default(), spark_runtime::Tableau::new(Method::Gauss)?);
    let mut run = |what, expected, t0: f64, h: f64, policy: &RejectionPolicy, observed: bool| {
        let mut count = 0usize;
        let options = RunOptions { on_failure: FailurePolicy::Reject(*policy), ..RunOptions::default() };
        let schedule = Schedule::Until { h, t_end: 1.0 };
        let r = st.integrate(t0, &q0, &v0, schedule, &options, &mut |_: &State<3>, _: usize| count += 1);
        let (got, count) = driven(r, count);
        Bad { what, expected, got, observed_steps: if observed { count } else { 0 } }
    };
    let bad_policy = RejectionPolicy { min_step: f64::NAN, ..RejectionPolicy::default() };
    Ok(vec![
        run(
            "final time 1 behind the start 5 (h = 0.1), rejection policy",
            "InvalidSchedule",
            5.0,
            0.1,
            &RejectionPolicy::default(),
            true,
        ),
        run("h = 0 under the rejection policy", "InvalidSchedule", 0.0, 0.0, &RejectionPolicy::default(), true),
        run("rejection policy with min_step = NaN", "InvalidOption", 0.0, 0.1, &bad_policy, false),
    ])
}

/// One point per scenario: 1 when it returned the expected typed error.
fn bad_input_figure(c: &CaseReport, scenarios: usize) -> Figure {
    let n = scenarios as f64;
    let passed = c.checks.iter().filter(|k| k.passed).count() as f64;
    Figure {
        title: c.title.clone(),
        panels: vec![Panel {
            title: format!("scenarios returning the expected typed error: {passed} of {n}"),
            x_label: "scenario".into(),
            y_label: "1 = expected typed error, 0 = not".into(),
            x_scale: Axis::Linear,
            y_scale: Axis::Linear,
            series: vec![Series::new(
                "outcome",
                c.checks.iter().enumerate().map(|(i, k)| (i as f64 + 1.0, if k.passed { 1.0 } else { 0.0 })).collect(),
            )],
        }],
        columns: 1,
        panel_size: (820, 360),
    }
}
