//! The bad-input case: every invalid input comes back as a typed error.

use super::{integration_error_kind, rejection_error_kind, step_error_kind};
use crate::experiments::stress::{CaseReport, Scale, StressError};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::systems::stress::NearParallel;
use crate::systems::Skate;
use spark_runtime::{
    integrate_with_rejection, Method, NonholonomicSystem, RejectionPolicy, RunOptions, Schedule, State, Stepper, Vector,
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
         `integrate_with_rejection`) on the skate or the near-parallel particle, and must return the expected typed \
         error with no step taken (an observer counts the steps; nothing is returned but the error).",
    );
    let q0 = Vector::<3>::zeros();
    let v0 = Vector::<3>::new(0.0, 0.0, 1.0);
    let opts = RunOptions::default();
    let mut cases: Vec<Bad> = Vec::new();
    let drive = |sys: Skate, q: Vector<3>, v: Vector<3>, schedule: Schedule<'_>| -> (Result<String, String>, usize) {
        let mut st = Stepper::<Skate, 3, 1, 2, 11>::new(sys, spark_runtime::Tableau::new(Method::Gauss).expect("s=2"));
        let mut count = 0usize;
        let mut obs = |_: &State<3>, _: usize| count += 1;
        let r = st.integrate(0.0, &q, &v, schedule, &opts, &mut obs);
        (
            r.map(|t| format!("Ok({} steps)", t.report.steps))
                .map_err(|e| format!("{} — {e}", integration_error_kind(&e))),
            count,
        )
    };
    let fixed = Schedule::Fixed { h: 0.1, steps: 10 };
    let mut push = |what, expected, (got, observed_steps): (Result<String, String>, usize)| {
        cases.push(Bad { what, expected, got, observed_steps })
    };
    push("NaN in q0", "Initial/InvalidStep", drive(Skate::default(), Vector::<3>::new(f64::NAN, 0.0, 0.0), v0, fixed));
    push(
        "+inf in v0",
        "Initial/InvalidStep",
        drive(Skate::default(), q0, Vector::<3>::new(0.0, 0.0, f64::INFINITY), fixed),
    );
    push("h = 0", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: 0.0, steps: 10 }));
    push("h = NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: f64::NAN, steps: 10 }));
    push("output time NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Times(&[0.5, f64::NAN])));
    push(
        "inconsistent initial state (v0 = (1, 1, 0), |k| = 1)",
        "Initial/InconsistentInitialState",
        drive(Skate::default(), q0, Vector::<3>::new(1.0, 1.0, 0.0), fixed),
    );
    let nan_field = Skate { beta: f64::NAN, ..Skate::default() };
    push("parameter field beta = NaN (set directly)", "Step/NonFinite", drive(nan_field, q0, v0, fixed));
    let inf_field = Skate { g: f64::INFINITY, ..Skate::default() };
    push("parameter field g = +inf (set directly)", "Step/NonFinite", drive(inf_field, q0, v0, fixed));
    // Parameters through the API.
    let mut sk = Skate::default();
    let api = |r: Result<(), spark_runtime::SystemError>| match r {
        Ok(()) => (Ok("accepted".to_string()), 0),
        Err(e) => (
            Err(format!(
                "{} — {e}",
                match e {
                    spark_runtime::SystemError::NonFiniteParameter { .. } => "NonFiniteParameter",
                    spark_runtime::SystemError::UnknownParameter { .. } => "UnknownParameter",
                }
            )),
            0,
        ),
    };
    push("set_parameter(\"beta\", NaN)", "NonFiniteParameter", api(sk.set_parameter("beta", f64::NAN)));
    push("set_parameter(\"g\", -inf)", "NonFiniteParameter", api(sk.set_parameter("g", f64::NEG_INFINITY)));
    push("set_parameter(\"gravity\", 1)", "UnknownParameter", api(sk.set_parameter("gravity", 1.0)));
    // A constraint that depends on a non-finite parameter: the initial check must say so.
    {
        let sys = NearParallel { eps: f64::NAN };
        let mut st = crate::stress_stepper!(NearParallel, 2, Method::Gauss, sys);
        let mut count = 0usize;
        let mut obs = |_: &State<3>, _: usize| count += 1;
        let r = st.integrate(
            0.0,
            &Vector::<3>::new(1.0, 0.5, 0.0),
            &Vector::<3>::new(0.3, 0.0, 0.15),
            fixed,
            &opts,
            &mut obs,
        );
        let got = r
            .map(|t| format!("Ok({} steps)", t.report.steps))
            .map_err(|e| format!("{} — {e}", integration_error_kind(&e)));
        push("parameter field eps = NaN in the constraint", "Initial/NonFinite", (got, count));
    }
    // Stepper::step directly.
    {
        let mut st = Stepper::<Skate, 3, 1, 2, 11>::new(Skate::default(), spark_runtime::Tableau::new(Method::Gauss)?);
        let step = |st: &mut Stepper<Skate, 3, 1, 2, 11>, s: State<3>, h: f64| -> (Result<String, String>, usize) {
            (st.step(&s, h).map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", step_error_kind(&e))), 0)
        };
        push("Stepper::step with h = 0", "InvalidStep", step(&mut st, State::new(0.0, q0, v0), 0.0));
        push("Stepper::step with t0 = NaN", "InvalidStep", step(&mut st, State::new(f64::NAN, q0, v0), 0.1));
        push("Stepper::step with h = -inf", "InvalidStep", step(&mut st, State::new(0.0, q0, v0), f64::NEG_INFINITY));
        push(
            "Stepper::step with h below the resolution of t (t0 = 1e20, h = 1)",
            "InvalidStep",
            step(&mut st, State::new(1e20, q0, v0), 1.0),
        );
    }
    // Final time behind the start.
    {
        let mut st = crate::stress_stepper!(Skate, 2, Method::Gauss, Skate::default());
        let mut count = 0usize;
        let r = integrate_with_rejection(&mut st, 5.0, &q0, &v0, 1.0, 0.1, &RejectionPolicy::default(), &mut |_| {
            count += 1
        });
        push(
            "final time 1 behind the start 5 (h = 0.1)",
            "InvalidInterval",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), count),
        );
        let mut count = 0usize;
        let r = integrate_with_rejection(&mut st, 0.0, &q0, &v0, 1.0, 0.0, &RejectionPolicy::default(), &mut |_| {
            count += 1
        });
        push(
            "protected run with h = 0",
            "InvalidInterval",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), count),
        );
        let bad_policy = RejectionPolicy { min_step: f64::NAN, ..RejectionPolicy::default() };
        let r = integrate_with_rejection(&mut st, 0.0, &q0, &v0, 1.0, 0.1, &bad_policy, &mut |_| {});
        push(
            "rejection policy with min_step = NaN",
            "InvalidPolicy",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), 0),
        );
    }
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
    let n = cases.len() as f64;
    let passed = c.checks.iter().filter(|k| k.passed).count() as f64;
    c.figure = Some(Figure {
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
    });
    Ok(c)
}
