//! Tableaux a user builds by hand: `Tableau`'s fields are public, so any
//! stage count and any coefficients reach the stepper, not only those of
//! `Tableau::new` (`s ≤ MAX_STAGES` from the checked-in tables).
//!
//! A 12-stage Gauss tableau computed here runs, with dense output, like the
//! tables' 10 stages; a tableau no step can use (no stage, a NaN
//! coefficient, a repeated node where the dense output interpolates) is
//! refused naming the field, by `step`, `integrate` and the adaptive driver.

use spark_runtime::{
    integrate_adaptive, nonholonomic_system, AdaptiveError, AdaptiveOptions, ConditionRows, DenseBasis,
    IntegrationError, Method, NoObserver, RunOptions, Schedule, State, StepError, Stepper, Tableau, Vector, MAX_STAGES,
};

nonholonomic_system! {
    /// A particle in a well on the constraint ẏ = x ẋ (linear in v).
    pub struct WellOnParabola {
        coordinates: [x, y],
        parameters: { k = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - k*(x^2 + y^2)/2 - x^4/4,
        constraints: [ dot(y) - x*dot(x) ],
    }
}

/// The `S`-stage Gauss SPARK tableau (`Â = Ã = A`), computed from the
/// Legendre polynomial: nodes by Newton's method, weights from `P_S'`, and
/// `a_ij = ∫₀^{c_i} ℓ_j` by the Gauss rule itself (exact for `ℓ_j`).
fn gauss<const S: usize>() -> Tableau<S> {
    let legendre = |x: f64| {
        // (P_S(x), P_S'(x)) by the three-term recurrence.
        let (mut p0, mut p1) = (1.0, x);
        for n in 1..S {
            let n = n as f64;
            (p0, p1) = (p1, ((2.0 * n + 1.0) * x * p1 - n * p0) / (n + 1.0));
        }
        (p1, S as f64 * (x * p1 - p0) / (x * x - 1.0))
    };
    let mut c = [0.0; S];
    let mut b = [0.0; S];
    for i in 0..S {
        let mut x = -(std::f64::consts::PI * (i as f64 + 0.75) / (S as f64 + 0.5)).cos();
        for _ in 0..100 {
            let (p, dp) = legendre(x);
            x -= p / dp;
        }
        let (_, dp) = legendre(x);
        c[i] = (x + 1.0) / 2.0;
        b[i] = 1.0 / ((1.0 - x * x) * dp * dp);
    }
    let ell = |j: usize, tau: f64| (0..S).filter(|&m| m != j).fold(1.0, |l, m| l * (tau - c[m]) / (c[j] - c[m]));
    let a: [[f64; S]; S] = std::array::from_fn(|i| {
        std::array::from_fn(|j| c[i] * (0..S).map(|k| b[k] * ell(j, c[i] * c[k])).sum::<f64>())
    });
    let mut omega = [[0.0; S]; S];
    for (i, row) in omega.iter_mut().take(S - 1).enumerate() {
        for j in 0..S {
            row[j] = b[j] * c[j].powi(i as i32);
        }
    }
    Tableau {
        method: Method::Gauss,
        c,
        a,
        a_hat: a,
        a_tilde: a,
        b,
        b_hat: b,
        b_tilde: b,
        omega,
        conditions: ConditionRows::Omega,
    }
}

fn start() -> (Vector<2>, Vector<2>) {
    // ẏ = x ẋ holds: x = 0.3, ẋ = 1, ẏ = 0.3.
    (Vector::<2>::new(0.3, 0.0), Vector::<2>::new(1.0, 0.3))
}

/// Twelve stages, two more than the tables hold: the dense output's
/// interpolants hold as many nodes as the tableau has stages (room for only
/// `MAX_STAGES` nodes inside a step would end a run that samples, or locates
/// events, in an index-out-of-bounds panic).
#[test]
fn a_hand_built_tableau_beyond_the_tables_runs_with_dense_output() {
    const S: usize = 12;
    const { assert!(S > MAX_STAGES) };
    // The tableau computed here is Gauss: at s = 10 it is the tables' to round-off.
    let (ours, tables) = (gauss::<10>(), Tableau::<10>::new(Method::Gauss).unwrap());
    let largest = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(largest(&ours.c, &tables.c) < 1e-14 && largest(&ours.b, &tables.b) < 1e-14);
    assert!(largest(ours.a.as_flattened(), tables.a.as_flattened()) < 1e-13);

    let basis = DenseBasis::new(&gauss::<S>());
    assert_eq!(basis.velocity_degree(), S + 1);

    let (q0, v0) = start();
    let times = [0.05, 0.1, 0.17, 0.3];
    let schedule = Schedule::Sampled { h: 0.1, times: &times };
    let mut twelve: spark_runtime::Stepper![WellOnParabola, S] = Stepper::new(WellOnParabola::default(), gauss::<S>());
    let run = twelve.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    let mut ten: spark_runtime::Stepper![WellOnParabola, 10] = Stepper::new(WellOnParabola::default(), tables);
    let reference = ten.integrate(0.0, &q0, &v0, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
    assert_eq!(run.samples.len(), times.len() + 1);
    for (a, b) in run.samples.iter().zip(&reference.samples) {
        assert_eq!(a.t, b.t);
        // Both steps are of order ≥ 20 (equal to round-off at the grid
        // points); between them both interpolate at degree ≥ 10 in
        // h = 0.1, within about h^11 = 1e-11 of the solution.
        let on_grid = a.t == 0.0 || a.t == 0.1;
        let d = (a.q - b.q).amax().max((a.v - b.v).amax());
        let bound = if on_grid { 1e-13 } else { 1e-10 };
        assert!(d < bound, "t = {}: 12 stages against the tables' 10 differ by {d:e}", a.t);
    }
}

/// No stage, a non-finite coefficient, and (where the dense output
/// interpolates between the nodes) a repeated node. Unchecked, `S = 0`
/// would return the start's positions at `t + h` as a successful step, and
/// a repeated node would make every sample between grid points NaN in a
/// successful run.
#[test]
fn hand_built_tableaux_no_step_can_use_are_refused_naming_the_field() {
    let (q0, v0) = start();
    let state = State::new(0.0, q0, v0);
    let sys = WellOnParabola::default();

    let empty: Tableau<0> = Tableau {
        method: Method::Gauss,
        c: [],
        a: [],
        a_hat: [],
        a_tilde: [],
        b: [],
        b_hat: [],
        b_tilde: [],
        omega: [],
        conditions: ConditionRows::Omega,
    };
    let mut none: spark_runtime::Stepper![WellOnParabola, 0] = Stepper::new(sys, empty);
    let e = none.step(&state, 0.1).unwrap_err();
    assert!(matches!(e, StepError::InvalidOption(_)) && e.to_string().contains("stage count"), "{e}");
    let fixed = Schedule::Fixed { h: 0.1, steps: 3 };
    let e = none.integrate(0.0, &q0, &v0, fixed, &RunOptions::default(), &mut NoObserver).unwrap_err();
    assert!(matches!(e, IntegrationError::InvalidOption(_)) && e.to_string().contains("stage count"), "{e}");
    let e =
        integrate_adaptive(&mut none, 0.0, &q0, &v0, 1.0, &AdaptiveOptions::default(), &mut NoObserver).unwrap_err();
    assert!(matches!(e, AdaptiveError::InvalidOption(_)) && e.to_string().contains("stage count"), "{e}");

    for field in ["c", "a", "a_hat", "a_tilde", "b", "b_hat", "b_tilde", "omega"] {
        let mut tableau = Tableau::<2>::new(Method::Gauss).unwrap();
        let (c, a, a_hat, a_tilde, b, b_hat, b_tilde, omega) = (
            &mut tableau.c[1],
            &mut tableau.a[1][0],
            &mut tableau.a_hat[0][1],
            &mut tableau.a_tilde[1][1],
            &mut tableau.b[0],
            &mut tableau.b_hat[1],
            &mut tableau.b_tilde[0],
            &mut tableau.omega[0][1],
        );
        let entry = match field {
            "c" => c,
            "a" => a,
            "a_hat" => a_hat,
            "a_tilde" => a_tilde,
            "b" => b,
            "b_hat" => b_hat,
            "b_tilde" => b_tilde,
            _ => omega,
        };
        *entry = f64::NAN;
        let name = format!("Tableau::{field} = NaN");
        let mut stepper: spark_runtime::Stepper![WellOnParabola, 2] = Stepper::new(sys, tableau);
        let e = stepper.step(&state, 0.1).unwrap_err();
        assert!(matches!(e, StepError::InvalidOption(_)) && e.to_string().contains(&name), "{field}: {e}");
        let e = stepper.integrate(0.0, &q0, &v0, fixed, &RunOptions::default(), &mut NoObserver).unwrap_err();
        assert!(matches!(e, IntegrationError::InvalidOption(_)) && e.to_string().contains(&name), "{field}: {e}");
    }

    // A repeated node: refused where the run interpolates, not otherwise.
    let mut tableau = Tableau::<3>::new(Method::Gauss).unwrap();
    tableau.c[1] = tableau.c[0];
    assert!(tableau.validate().is_ok());
    let mut stepper: spark_runtime::Stepper![WellOnParabola, 3] = Stepper::new(sys, tableau);
    let times = [0.05, 0.1];
    let sampled = Schedule::Sampled { h: 0.1, times: &times };
    let e = stepper.integrate(0.0, &q0, &v0, sampled, &RunOptions::default(), &mut NoObserver).unwrap_err();
    assert!(matches!(e, IntegrationError::InvalidOption(_)) && e.to_string().contains("Tableau::c"), "{e}");
}

/// The order of a stage count outside a method's range is the formula's
/// value clamped at 0, not a wrapped `2·0 − 2`.
#[test]
fn the_order_formula_does_not_wrap_outside_the_stage_range() {
    assert_eq!(Method::LobattoIIIAB.order(0), 0);
    assert_eq!(Method::LobattoIIIABD.order(1), 0);
    assert_eq!(Method::Gauss.order(usize::MAX), usize::MAX);
    assert_eq!(Method::LobattoIIIAB.order(3), 4);
}
