//! The checks of a step that starts cold (not where the stepper's previous
//! step ended): an inconsistent state, dependent constraint rows and a
//! singular mass matrix that the constraints make up for are typed errors,
//! not a silent `Ok`.

use spark_runtime::{
    consistent_velocity, nonholonomic_system, ConsistencyPolicy, IntegrationError, Jacobian, Method, NewtonMode,
    NewtonOptions, NoObserver, NonholonomicSystem, RunOptions, Schedule, State, StepError, Stepper, Tableau, Vector,
};

nonholonomic_system! {
    /// Two constraints whose rows `K = [(1, 0, y), (1, 0, x)]` coincide on
    /// the plane `x = y`: regular elsewhere, dependent there.
    pub struct Crossing {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2 + z^2)/2,
        constraints: [ dot(x) + y*dot(z), dot(x) + x*dot(z) ],
    }
}

nonholonomic_system! {
    /// The nonholonomic particle of the paper (§8.1).
    pub struct Particle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - x^2 - y^2,
        constraints: [ dot(z) - y*dot(x) ],
    }
}

fn energy<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(sys: &Sys, s: &State<N>) -> f64 {
    sys.energy(s.t, &s.q, &s.v)
}

/// On `x = y` the two rows coincide: a step solved there returns |ψ| ≈ 2e3
/// and loses half the energy. Off the plane the same system steps.
#[test]
fn dependent_constraint_rows_are_a_typed_error() {
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let mut st = Stepper::<_, 3, 2, 2, 13>::new(Crossing::default(), tab);
    // v = (0, 1, 0) satisfies both constraints wherever x = y.
    let on = State::new(0.0, Vector::<3>::new(0.5, 0.5, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let err = st.step(&on, 0.1).unwrap_err();
    let StepError::DependentConstraints { condition, limit, .. } = err else { panic!("{err}") };
    assert!(condition > limit, "{err}");
    assert!(err.to_string().contains("condition number"), "{err}");
    // Nearly dependent (x − y = 1e-9): κ ≈ 4(1 + x²)²/(x − y)² ≈ 6e18, also refused.
    let near = State::new(0.0, Vector::<3>::new(0.5 + 1e-9, 0.5, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    assert!(matches!(st.step(&near, 0.1), Err(StepError::DependentConstraints { .. })));
    // Independent rows (x − y = 0.5): steps, keeps the constraints and the energy.
    let off = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let r = st.step(&off, 0.01).unwrap();
    assert!(Crossing::default().constraint(r.state.t, &r.state.q, &r.state.v).amax() < 1e-14);
    assert!((energy(&Crossing::default(), &r.state) - energy(&Crossing::default(), &off)).abs() < 1e-6);
}

/// A step solved from an inconsistent state halves the energy (1.0 →
/// 0.498): the end constraint removes the inconsistent part of the velocity
/// with an impulse. The error says what to do, and the driver's projection
/// is the remedy it names.
#[test]
fn an_inconsistent_start_is_a_typed_error_with_the_remedy() {
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle::default(), tab);
    // k = v₃ − y v₁ = 1 at y = 0; E = 1.0.
    let bad = State::new(0.0, Vector::<3>::new(0.0, 0.0, 0.0), Vector::<3>::new(0.0, 0.0, 2f64.sqrt()));
    assert!((energy(&Particle::default(), &bad) - 1.0).abs() < 1e-15);
    let err = st.step(&bad, 0.1).unwrap_err();
    assert!(matches!(err, StepError::InconsistentStart { residual, .. } if residual == 2f64.sqrt()), "{err}");
    assert!(err.to_string().contains("ConsistencyPolicy::Project"), "{err}");
    let project = RunOptions { consistency: ConsistencyPolicy::Project { tolerance: 1e-12 }, ..RunOptions::default() };
    let tr =
        st.integrate(0.0, &bad.q, &bad.v, Schedule::Fixed { h: 0.1, steps: 3 }, &project, &mut NoObserver).unwrap();
    assert!(tr.report.projected_initial_velocity && tr.report.max_constraint_residual < 1e-15);
}

nonholonomic_system! {
    /// `x = a + b` with a kinetic term, `w = a − b` without one but in a
    /// constraint and in `x ẇ`: the mass matrix `[[1, 1, 0], [1, 1, 0],
    /// [0, 0, 1]]` is singular with no zero column (so the macro accepts
    /// it), and the saddle matrix is regular.
    pub struct HiddenMassless {
        coordinates: [a, b, y],
        lagrangian: ((dot(a) + dot(b))^2 + dot(y)^2)/2 + (a + b)*(dot(a) - dot(b)) - (a + b)^2/2 - y^2/2
            - (a - b)^2/2,
        constraints: [ dot(a) - dot(b) - y*(dot(a) + dot(b)) ],
    }
}

/// A singular mass matrix whose missing inertia the constraints make up
/// for determines the motion but not a step: the momentum rows of the step
/// along its null space are dependent, and Gauss s = 2 and 3 returned `Ok`
/// steps 7.4e-4 and 3.5e-6 off in `a + b` (against 1e-7 and 1e-10 for the
/// order). Every cold step, every mode, and `integrate` refuse the start with
/// the coordinate, before any Newton iteration.
#[test]
fn a_singular_mass_matrix_that_the_constraints_make_up_for_is_a_typed_error() {
    let sys = HiddenMassless::default();
    let q0 = Vector::<3>::new(0.3, 0.2, 0.3);
    let projected = ConsistencyPolicy::Project { tolerance: 0.0 };
    let v0 = consistent_velocity(&sys, 0.0, &q0, &Vector::<3>::new(0.1, 0.1, -0.4), projected).unwrap();
    let start = State::new(0.0, q0, v0);
    let check = |err: StepError, what: &str| {
        let text = err.to_string();
        assert!(matches!(err, StepError::SingularInitialState { .. }), "{what}: {text}");
        assert!(text.contains("coordinate `b`") && text.contains("regular Lagrangian"), "{what}: {text}");
    };
    macro_rules! every_mode {
        ($method:expr, $s:literal) => {
            for (mode, jacobian) in [
                (NewtonMode::Full, Jacobian::Auto),
                (NewtonMode::Simplified, Jacobian::Exact),
                (NewtonMode::Simplified, Jacobian::StageDecoupled),
            ] {
                let what = format!("{} s={} {mode:?}/{jacobian:?}", $method, $s);
                let options = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
                let mut st: spark_runtime::Stepper![HiddenMassless, $s] =
                    Stepper::new(sys, Tableau::new($method).unwrap()).with_options(options);
                check(st.step(&start, 0.1).unwrap_err(), &what);
                let run = st.integrate(
                    0.0,
                    &q0,
                    &v0,
                    Schedule::Fixed { h: 0.1, steps: 3 },
                    &RunOptions::default(),
                    &mut NoObserver,
                );
                match run {
                    Err(IntegrationError::Step { source, .. }) => check(source, &what),
                    other => panic!("{what}: {other:?}"),
                }
            }
        };
    }
    every_mode!(Method::Gauss, 1);
    every_mode!(Method::Gauss, 2);
    every_mode!(Method::Gauss, 3);
    every_mode!(Method::LobattoIIIAB, 2);
    every_mode!(Method::LobattoIIIABD, 3);
}
