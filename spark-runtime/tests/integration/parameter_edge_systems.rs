//! Systems whose structure facts sit on an edge: parameters whose default
//! is 0 or 1 multiply a position-dependent mass, a gyroscopic term
//! `A(q)·v`, a potential, an off-diagonal constant mass, a quartic kinetic
//! term, an exponent, a forcing and a non-ideal force, so a fact proved
//! from the default values instead of the symbols would hold at the
//! defaults and break once a user sets the field. The systems also cover
//! `m = n − 1` constraints with explicit `t`, no constraints with a
//! time-dependent magnetic term, and a Caldirola–Kanai Lagrangian (explicit
//! `t` in the mass).
//!
//! Each is checked at its defaults and at other values, set both on a
//! fresh stepper and through [`Stepper::system_mut`] on a stepper that has
//! already stepped: exact derivatives, structure facts that hold for every
//! parameter value, and steps equal to the tightly converged solution of
//! their equations in every Newton mode, for Gauss s = 1..4, Lobatto IIIA-B
//! s = 2..4 and IIIA-B-D s = 2, 3; values that leave no motion (a NaN
//! parameter, a mass cancelled at the start) are errors.
//!
//! Measured against an independent implementation (the same declarations
//! written in CasADi, the tableaux built from their defining conditions in
//! 40-digit arithmetic, the residual of (6.1) solved by a plain Newton loop
//! to a residual of 3e-16, the non-ideal force weighted as the constraint
//! force): the generated derivatives, every block at 100 random points,
//! agree to 5.2e-16 relative, and 1440 steps of h = 0.1 (four per system,
//! parameter set, method and Newton mode) agree in `q₁` and `v₁` to 4.6e-15.

use super::newcomer_systems::{against_tight, derivative_error, step_distance, tally_against_tight, EVERY_MODE};
use spark_runtime::{
    consistent_velocity, nonholonomic_system, ConsistencyPolicy, ConstraintForm, Jacobian, Method, NewtonMode,
    NewtonOptions, NonholonomicSystem, State, Stepper, Tableau, Vector, HISTORY_CAPACITY,
};

nonholonomic_system! {
    /// A knife edge whose mass, inertia exponent, magnetic term, potential and rheonomic drift
    /// all vanish or reduce to a constant at the parameters' defaults.
    pub struct EdgeDefaults {
        coordinates: [x, y, th],
        parameters: { c = 0.0, e = 1.0, g = 0.0, a = 0.0, w = 0.0, p = 0.0 },
        lagrangian: (1 + c*y^2)/2*dot(x)^2 + e/2*dot(y)^2*(1 + x^2)^p + dot(th)^2/2
            + a*(x*dot(y) - y*dot(x)) - g*sin(x)*cos(y) - (x^2 + y^2)/2,
        constraints: [ cos(th)*dot(y) - sin(th)*dot(x) + w*t*x ],
    }
}

nonholonomic_system! {
    /// A constant mass matrix that is diagonal only at the defaults, a diagonal stiffness,
    /// and two affine constraints with explicit t on three coordinates (m = n − 1).
    pub struct OffDiagonalMass {
        coordinates: [x, y, z],
        parameters: { c = 0.0, d = 0.0, k1 = 1.0, k2 = 0.0, w = 0.0 },
        lagrangian: (2*dot(x)^2 + 2*c*dot(x)*dot(y) + dot(y)^2 + 2*d*dot(y)*dot(z) + 3/2*dot(z)^2)/2
            - k1*(1 - cos(x)) - k2/2*y^2 - z^4/4,
        constraints: [ dot(x) + y*dot(z) - w*t, dot(y) - sin(x)*dot(z) + t/10 ],
    }
}

nonholonomic_system! {
    /// A constant stiffness whose coupling is zero at the defaults, with a constant
    /// non-diagonal mass.
    pub struct ZeroCoupling {
        coordinates: [x, y, z],
        parameters: { kappa = 0.0, k = 1.0, c = 0.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2 + c*dot(x)*dot(z))/2 - k/2*(x^2 + y^2 + z^2) - kappa*x*y,
        constraints: [ dot(z) - y*dot(x) ],
    }
}

nonholonomic_system! {
    /// No constraints: a time-dependent magnetic term cubic in q and a quartic kinetic term,
    /// both zero at the defaults.
    pub struct MagneticFree {
        coordinates: [x, y],
        parameters: { b = 0.0, lam = 0.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 + b*(1 + 0.3*sin(t))*(x^2*dot(y) - y^3*dot(x))/2
            - (x^2 + y^2)^2/4 + lam*dot(x)^4/12,
    }
}

nonholonomic_system! {
    /// A Caldirola–Kanai oscillator (explicit t in the mass and the potential) on a rheonomic
    /// guide, with a forcing and a non-ideal force that vanish at the defaults.
    pub struct Kanai {
        coordinates: [x, y, z],
        parameters: { gam = 0.0, f0 = 0.0, w = 1.0, mu = 0.0 },
        lagrangian: exp(gam*t)*((dot(x)^2 + dot(y)^2 + dot(z)^2) - (x^2 + y^2 + z^2))/2,
        constraints: [ dot(z) - x*dot(y) - sin(t)*cos(y)/5 ],
        forces: { x: f0*sin(w*t) },
        nonideal_forces: { y: -mu*psi[0]*dot(y) },
    }
}

/// The systems at their defaults and at other values.
fn edge_defaults() -> [EdgeDefaults; 2] {
    [EdgeDefaults::default(), EdgeDefaults { c: 2.0, e: 1.3, g: 2.0, a: 0.7, w: 0.4, p: 0.5 }]
}
fn off_diagonal_mass() -> [OffDiagonalMass; 2] {
    [OffDiagonalMass::default(), OffDiagonalMass { c: 0.6, d: -0.4, k1: 3.0, k2: 2.0, w: 0.3 }]
}
fn zero_coupling() -> [ZeroCoupling; 2] {
    [ZeroCoupling::default(), ZeroCoupling { kappa: 0.8, k: 2.0, c: 0.9 }]
}
fn magnetic_free() -> [MagneticFree; 2] {
    [MagneticFree::default(), MagneticFree { b: 1.2, lam: 0.5 }]
}
fn kanai() -> [Kanai; 2] {
    [Kanai::default(), Kanai { gam: 0.3, f0: 0.8, w: 1.7, mu: 0.4 }]
}

/// The structure facts do not depend on the defaults: every parameter that
/// multiplies a term is a symbol, so the facts are those of the terms.
#[test]
fn structure_facts_hold_for_every_parameter_value() {
    let forms = [
        EdgeDefaults::STRUCTURE.constraint_form,
        OffDiagonalMass::STRUCTURE.constraint_form,
        ZeroCoupling::STRUCTURE.constraint_form,
        MagneticFree::STRUCTURE.constraint_form,
        Kanai::STRUCTURE.constraint_form,
    ];
    use ConstraintForm::{Affine, Linear, None as Unconstrained};
    assert_eq!(forms, [Affine, Affine, Linear, Unconstrained, Affine]);
    // A wrong fact fails to compile.
    const {
        let s = EdgeDefaults::STRUCTURE;
        assert!(!s.constant_mass_matrix && !s.separable && s.lagrangian_autonomous && !s.constraints_autonomous);
        assert!(!<EdgeDefaults as NonholonomicSystem<3, 1>>::CONSTANT_STIFFNESS);
        assert!(!<EdgeDefaults as NonholonomicSystem<3, 1>>::DIAGONAL_STIFFNESS);

        let s = OffDiagonalMass::STRUCTURE;
        assert!(s.constant_mass_matrix && s.separable && !s.constraints_autonomous);
        assert!(!<OffDiagonalMass as NonholonomicSystem<3, 2>>::CONSTANT_STIFFNESS);
        assert!(<OffDiagonalMass as NonholonomicSystem<3, 2>>::DIAGONAL_STIFFNESS);

        let s = ZeroCoupling::STRUCTURE;
        assert!(s.constant_mass_matrix && s.separable && s.autonomous());
        assert!(<ZeroCoupling as NonholonomicSystem<3, 1>>::CONSTANT_STIFFNESS);
        assert!(!<ZeroCoupling as NonholonomicSystem<3, 1>>::DIAGONAL_STIFFNESS);

        let s = MagneticFree::STRUCTURE;
        assert!(!s.constant_mass_matrix && !s.separable && !s.lagrangian_autonomous);

        let s = Kanai::STRUCTURE;
        assert!(!s.constant_mass_matrix && s.separable && !s.lagrangian_autonomous);
        assert!(Kanai::HAS_FORCING && Kanai::HAS_NONIDEAL_FORCE);
    }
}

#[test]
fn derivatives_are_exact_at_the_defaults_and_away_from_them() {
    let mut worst = Vec::new();
    for sys in edge_defaults() {
        worst.push(("EdgeDefaults", derivative_error(&sys)));
    }
    for sys in off_diagonal_mass() {
        worst.push(("OffDiagonalMass", derivative_error(&sys)));
    }
    for sys in zero_coupling() {
        worst.push(("ZeroCoupling", derivative_error(&sys)));
    }
    for sys in magnetic_free() {
        worst.push(("MagneticFree", derivative_error(&sys)));
    }
    for sys in kanai() {
        worst.push(("Kanai", derivative_error(&sys)));
    }
    println!("{worst:?}");
    for (name, e) in worst {
        assert!(e <= 1e-8, "{name}: derivative error {e:.3e}");
    }
}

/// A start consistent with the constraints of `sys` (projected).
fn start<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(
    sys: &Sys,
    q0: [f64; N],
    v0: [f64; N],
) -> State<N> {
    let (q0, v0) = (Vector::<N>::from(q0), Vector::<N>::from(v0));
    let v0 = consistent_velocity(sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 1e-14 }).unwrap();
    State::new(0.0, q0, v0)
}

/// Runs `$body!(method, s)` for Gauss s = 1..4, Lobatto IIIA-B s = 2..4
/// and Lobatto IIIA-B-D s = 2, 3.
macro_rules! every_method {
    ($body:ident) => {
        $body!(Method::Gauss, 1);
        $body!(Method::Gauss, 2);
        $body!(Method::Gauss, 3);
        $body!(Method::Gauss, 4);
        $body!(Method::LobattoIIIAB, 2);
        $body!(Method::LobattoIIIAB, 3);
        $body!(Method::LobattoIIIAB, 4);
        $body!(Method::LobattoIIIABD, 2);
        $body!(Method::LobattoIIIABD, 3);
    };
}

/// Every Newton mode stops on the tightly converged step, at the defaults
/// and away from them: 12 steps of h = 0.1 per system, parameter set,
/// method and mode, in `q₁`, `v₁`, `V` and `hΨ`.
#[test]
fn steps_equal_the_tight_solve_at_the_defaults_and_away_from_them() {
    let (mut results, mut failures) = (Vec::new(), Vec::new());
    macro_rules! check {
        ($systems:expr, $n:literal, $m:literal, $q0:expr, $v0:expr) => {{
            for sys in $systems {
                let start = start::<_, $n, $m>(&sys, $q0, $v0);
                macro_rules! tight {
                    ($method:expr, $s:literal) => {
                        results.extend(against_tight::<_, $n, $m, $s, { $s * ($n + $m) + $n }>(
                            &EVERY_MODE,
                            &sys,
                            $method,
                            &start,
                            0.1,
                            12,
                        ))
                    };
                }
                every_method!(tight);
            }
        }};
    }
    check!(edge_defaults(), 3, 1, [0.3, -0.2, 0.4], [0.7, 0.2, 0.5]);
    check!(off_diagonal_mass(), 3, 2, [0.3, -0.2, 0.4], [0.7, 0.2, 0.5]);
    check!(zero_coupling(), 3, 1, [0.5, -0.3, 0.2], [0.4, 0.6, -0.1]);
    check!(magnetic_free(), 2, 0, [0.6, -0.4], [0.3, 0.8]);
    check!(kanai(), 3, 1, [0.5, 0.2, -0.3], [0.4, -0.6, 0.2]);
    let worst = tally_against_tight(&results, &mut failures);
    println!("{} runs of 12 steps, largest distance {:.2e} ({})", results.len(), worst.0, worst.1);
    assert!(failures.is_empty(), "{} of {} runs:\n{}", failures.len(), results.len(), failures.join("\n"));
}

/// Steps from the defaults, then sets the other values through
/// [`Stepper::system_mut`] and steps on: each step after the change equals
/// the step that a fresh stepper built with the new values solves with full
/// Newton to the round-off floor (a clone of the changed stepper would share
/// whatever it kept from the defaults). Returns the largest distance of
/// those steps, or the failure of a step.
fn after_system_mut<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    (mode, jacobian): (NewtonMode, Jacobian),
    [defaults, other]: [Sys; 2],
    method: Method,
    start: &State<N>,
) -> Result<f64, String>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let h = 0.1;
    let tableau = Tableau::new(method).unwrap();
    let opts = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(defaults, tableau).with_options(opts);
    let tight_opts = NewtonOptions {
        mode: NewtonMode::Full,
        jacobian: Jacobian::Auto,
        tolerance: 0.0,
        max_iterations: HISTORY_CAPACITY,
        ..NewtonOptions::default()
    };
    let mut tight = Stepper::<Sys, N, M, S, D>::new(other.clone(), tableau).with_options(tight_opts);
    let mut state = *start;
    for k in 0..3 {
        state = stepper.step(&state, h).map_err(|e| format!("step {k} at the defaults: {e}"))?.state;
    }
    *stepper.system_mut() = other;
    // The new values' motion through the state reached: project onto their constraints.
    let project = ConsistencyPolicy::Project { tolerance: 1e-14 };
    let v = consistent_velocity(stepper.system(), state.t, &state.q, &state.v, project).map_err(|e| e.to_string())?;
    state = State::new(state.t, state.q, v);
    let mut worst = 0.0f64;
    for k in 0..10 {
        let b = tight.step(&state, h).map_err(|e| format!("step {k} after the change, tight: {e}"))?;
        let a = stepper.step(&state, h).map_err(|e| format!("step {k} after the change: {e}"))?;
        worst = worst.max(step_distance(&a, &b, h));
        state = a.state;
    }
    Ok(worst)
}

/// Parameters changed through `system_mut` on a stepper that has stepped
/// (its factors, warm start and stage-decoupled matrix built from the
/// defaults) give the steps of the new values in every Newton mode.
#[test]
fn parameters_changed_on_a_running_stepper_take_effect_in_every_mode() {
    let mut failures = Vec::new();
    let mut worst = 0.0f64;
    macro_rules! check {
        ($systems:expr, $n:literal, $m:literal, $q0:expr, $v0:expr) => {{
            let systems = $systems;
            let start = start::<_, $n, $m>(&systems[0], $q0, $v0);
            macro_rules! changed {
                ($method:expr, $s:literal) => {
                    for mode in EVERY_MODE {
                        let r = after_system_mut::<_, $n, $m, $s, { $s * ($n + $m) + $n }>(
                            mode,
                            systems.clone(),
                            $method,
                            &start,
                        );
                        let label = format!("{} {} s={} {:?}", stringify!($systems), $method, $s, mode);
                        match r {
                            Ok(d) if d <= 1e-13 => worst = worst.max(d),
                            Ok(d) => failures.push(format!("{label}: {d:.3e} from the tight solve")),
                            Err(e) => failures.push(format!("{label}: {e}")),
                        }
                    }
                };
            }
            every_method!(changed);
        }};
    }
    check!(edge_defaults(), 3, 1, [0.3, -0.2, 0.4], [0.7, 0.2, 0.5]);
    check!(off_diagonal_mass(), 3, 2, [0.3, -0.2, 0.4], [0.7, 0.2, 0.5]);
    check!(zero_coupling(), 3, 1, [0.5, -0.3, 0.2], [0.4, 0.6, -0.1]);
    check!(magnetic_free(), 2, 0, [0.6, -0.4], [0.3, 0.8]);
    check!(kanai(), 3, 1, [0.5, 0.2, -0.3], [0.4, -0.6, 0.2]);
    println!("largest distance after the change {worst:.2e}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Values set at run time that leave no motion are errors, never a step
/// returned as a success: a NaN parameter (in a term that is 0 at the
/// defaults) and a quartic kinetic term whose coefficient cancels the mass
/// of `x` at the start are refused before a run, naming the cause, and a
/// step from that state fails.
#[test]
fn parameters_that_leave_no_motion_are_errors() {
    use spark_runtime::{IntegrationError, NoObserver, RunOptions, Schedule, StepError};
    let run = RunOptions { consistency: ConsistencyPolicy::Error { tolerance: 1e-12 }, ..RunOptions::default() };
    let (q0, v0) = (Vector::<3>::new(0.3, -0.2, 0.4), Vector::<3>::new(0.4f64.cos(), 0.4f64.sin(), 0.5));
    let nan = EdgeDefaults { c: f64::NAN, ..edge_defaults()[1] };
    let err = consistent_velocity(&nan, 0.0, &q0, &v0, ConsistencyPolicy::Error { tolerance: 1e-12 }).unwrap_err();
    assert!(matches!(err, StepError::NonFiniteInitialValue { .. }), "{err}");
    for method in [Method::Gauss, Method::LobattoIIIABD] {
        let mut stepper: spark_runtime::Stepper![EdgeDefaults, 2] = Stepper::new(nan, Tableau::new(method).unwrap());
        let err = stepper.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 3 }, &run, &mut NoObserver);
        assert!(matches!(err, Err(IntegrationError::Initial(StepError::NonFiniteInitialValue { .. }))), "{err:?}");
        assert!(stepper.step(&State::new(0.0, q0, v0), 0.1).is_err());
    }
    // 1 + lam·ẋ² = 0 at ẋ = 0.5: the mass of `x` vanishes (no constraint supplies it).
    let singular = MagneticFree { b: 1.0, lam: -4.0 };
    let (q0, v0) = (Vector::<2>::new(0.1, 0.2), Vector::<2>::new(0.5, 0.8));
    let err = consistent_velocity(&singular, 0.0, &q0, &v0, ConsistencyPolicy::Error { tolerance: 1e-12 }).unwrap_err();
    assert!(matches!(&err, StepError::SingularInitialState { detail, .. } if detail.contains("`x`")), "{err}");
    for method in [Method::Gauss, Method::LobattoIIIABD] {
        for jacobian in [Jacobian::Exact, Jacobian::StageDecoupled] {
            let opts = NewtonOptions { mode: NewtonMode::Simplified, jacobian, ..NewtonOptions::default() };
            let mut stepper: spark_runtime::Stepper![MagneticFree, 2] =
                Stepper::new(singular, Tableau::new(method).unwrap()).with_options(opts);
            let err = stepper.integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.1, steps: 3 }, &run, &mut NoObserver);
            assert!(matches!(err, Err(IntegrationError::Initial(StepError::SingularInitialState { .. }))), "{err:?}");
            assert!(stepper.step(&State::new(0.0, q0, v0), 0.1).is_err());
        }
    }
}
