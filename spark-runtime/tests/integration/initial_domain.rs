//! A run from a state where a function of the declaration is undefined is
//! refused before the first step with every cause a user can act on: the
//! state outside a function's domain or where it is not differentiable, an
//! overflow, a parameter. The projection of the initial velocity, which is
//! no step, names no step size.

use spark_runtime::{consistent_velocity, nonholonomic_system, ConsistencyPolicy, StepError, Vector};

nonholonomic_system! {
    /// A relativistic particle in a harmonic well: `L` is defined for
    /// `|v| ≤ 1` only.
    pub struct Relativistic {
        coordinates: [x],
        lagrangian: -sqrt(1 - dot(x)^2) - x^2/2,
    }
}

nonholonomic_system! {
    /// A logarithmic potential, defined for `x > 0`.
    pub struct Logarithmic {
        coordinates: [x],
        lagrangian: dot(x)^2/2 - ln(x),
    }
}

nonholonomic_system! {
    /// Unit speed: `k` is not differentiable where the speed vanishes.
    pub struct UnitSpeed {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ sqrt(dot(x)^2 + dot(y)^2) - 1 ],
    }
}

nonholonomic_system! {
    /// A constraint whose value is undefined for `x < 0`.
    pub struct RootRail {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ dot(y) - sqrt(x)*dot(x) ],
    }
}

nonholonomic_system! {
    /// `sinh(v_x) = x`: at `x = 1e200` the projection's first Newton update
    /// from `v_x = 0` is 1e200, where `sinh` overflows.
    pub struct SinhRail {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ sinh(dot(x)) - x ],
    }
}

nonholonomic_system! {
    /// `v_x² + 1 = 0` has no real solution: the projection's first update
    /// from `v_x = 1` lands on `v_x = 0`, where `dk/dv` vanishes.
    pub struct NoRealSpeed {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ dot(x)^2 + 1 ],
    }
}

const PROJECT: ConsistencyPolicy = ConsistencyPolicy::Project { tolerance: 1e-12 };

/// The error of the initial check at `(q0, v0)`, as text.
fn refusal<Sys: spark_runtime::NonholonomicSystem<N, M>, const N: usize, const M: usize>(
    sys: Sys,
    q0: [f64; N],
    v0: [f64; N],
) -> (StepError, String) {
    let err = consistent_velocity(&sys, 0.0, &Vector::<N>::from(q0), &Vector::<N>::from(v0), PROJECT).unwrap_err();
    let text = err.to_string();
    (err, text)
}

#[test]
fn a_state_outside_the_domain_of_l_names_the_domain_first() {
    for (err, text) in [refusal(Relativistic::new(), [0.0], [1.5]), refusal(Logarithmic::new(), [-1.0], [0.0])] {
        assert!(matches!(err, StepError::NonFiniteInitialValue { .. }), "{err:?}");
        assert!(
            text.contains("is NaN at the initial state")
                && text.contains("outside its domain (sqrt or ln of a negative number")
                && text.contains("overflows f64")
                && text.contains("a parameter makes it undefined"),
            "{text}"
        );
    }
}

#[test]
fn constraint_rows_at_a_point_where_k_is_not_differentiable_say_so() {
    let (err, text) = refusal(UnitSpeed::new(), [0.0, 0.0], [0.0, 0.0]);
    let StepError::NonFiniteInitialValue { quantity, .. } = err else { panic!("{err:?}") };
    assert_eq!(quantity, "constraint Jacobian dk/dv");
    assert!(text.contains("not differentiable (sqrt at 0"), "{text}");
}

#[test]
fn an_undefined_constraint_at_the_initial_state_names_no_step() {
    let (err, text) = refusal(RootRail::new(), [-1.0, 0.0], [1.0, 0.0]);
    assert!(matches!(err, StepError::NonFinite { h: 0.0, .. }), "{err:?}");
    assert!(
        text.starts_with("non-finite value in the constraint k(t0, q0, v0) at t0 = 0.000e0, before the first step")
            && text.contains("outside its domain")
            && !text.contains("h = ")
            && !text.contains("history"),
        "{text}"
    );
}

#[test]
fn a_projection_that_overflows_says_it_is_the_initial_projection_not_a_step() {
    let (err, text) = refusal(SinhRail::new(), [1e200, 0.1], [0.0, 0.0]);
    assert!(matches!(err, StepError::NonFinite { h: 0.0, .. }), "{err:?}");
    assert!(
        text.starts_with("non-finite value in the projection of the initial velocity onto the constraints")
            && text.contains("before the first step")
            && text.contains("overflows f64")
            && !text.contains("h = "),
        "{text}"
    );
}

#[test]
fn a_projection_that_meets_a_singular_saddle_matrix_later_names_the_constraint() {
    let (err, text) = refusal(NoRealSpeed::new(), [0.0, 0.0], [1.0, 0.0]);
    let StepError::SingularMatrix { h, history, .. } = &err else { panic!("{err:?}") };
    assert_eq!((*h, history.len()), (0.0, 2), "{err:?}");
    assert!(
        text.starts_with(
            "numerically singular saddle matrix at iteration 2 in the projection of the initial velocity onto the \
             constraints"
        ) && text.contains("before the first step")
            && text.contains(": multiplier column 0 (constraint 1 of 1) of the saddle matrix")
            && !text.contains("h = "),
        "{text}"
    );
}

nonholonomic_system! {
    /// `|v|² + c = 0` has no real velocity for `c > 0`.
    pub struct ImaginarySpeed {
        coordinates: [x, y],
        parameters: { c = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - x^2/2,
        constraints: [ dot(x)^2 + dot(y)^2 + c ],
    }
}

/// A projection that finds no consistent velocity says so, naming the
/// projection and its causes (no real solution, a `v0` too far), not a step
/// size to reduce: it is no step.
#[test]
fn a_projection_without_a_solution_names_the_projection_not_a_step_size() {
    let (q0, v0) = (Vector::<2>::new(0.3, 0.1), Vector::<2>::new(0.5, 0.5));
    let project = ConsistencyPolicy::Project { tolerance: 1e-12 };
    let err = consistent_velocity(&ImaginarySpeed::default(), 0.0, &q0, &v0, project).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, StepError::Diverged { .. } | StepError::MaxIterations { .. }), "{text}");
    assert!(text.contains("projection of the initial velocity") && text.contains("no solution at q0"), "{text}");
    assert!(!text.contains("smaller step") && !text.contains("h = "), "{text}");
}
