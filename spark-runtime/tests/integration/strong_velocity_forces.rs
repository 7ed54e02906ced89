//! Cold steps under velocity-dependent forces that change the velocity by
//! much more than itself within one step: linear damping with `h·c = 7.5`,
//! a magnetic term `A(q)·v` with `h·b = 12`, a cubic drag with
//! `h·3c·v₀² = 108` beside a time-dependent drive. From the cold guess
//! `V_i = v₀ + c_i h a₀` Newton diverges there (in every mode for the
//! damping and the drag; the magnetic term's Gauss step stalls in
//! simplified Newton), and the step is solved by following its branch of
//! solutions from `h = 0` (`step/homotopy.rs`). Each step must succeed in
//! every Newton mode and equal the tightly converged solution of its
//! equations, and a step far beyond the branch's reach must still fail
//! with a typed error, not a success.

use super::newcomer_systems::{against_tight, tally_against_tight, EVERY_MODE};
use super::newcomer_unusual_systems::start;
use spark_runtime::{
    nonholonomic_system, Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, StepError, Stepper, Tableau,
};

nonholonomic_system! {
    /// A knife edge in a harmonic well with linear damping of rate `c`
    /// on every coordinate.
    pub struct DampedKnife {
        coordinates: [x, y, th],
        parameters: { c = 30.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(th)^2)/2 - (x^2 + y^2)/2,
        constraints: [ cos(th)*dot(y) - sin(th)*dot(x) ],
        forces: { x: -c*dot(x), y: -c*dot(y), th: -c*dot(th) },
    }
}

nonholonomic_system! {
    /// A knife edge in a magnetic field of strength `b` that grows away
    /// from the origin: the Lagrangian's term `b(1 + x²/4)(x·ẏ − y·ẋ)/2`.
    pub struct MagneticKnife {
        coordinates: [x, y, th],
        parameters: { b = 12.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(th)^2)/2 + b*(1 + x^2/4)*(x*dot(y) - y*dot(x))/2
            - (x^2 + y^2)/2,
        constraints: [ cos(th)*dot(y) - sin(th)*dot(x) ],
    }
}

nonholonomic_system! {
    /// A particle on a rheonomic guide with a cubic drag of strength `c`
    /// and a periodic drive: forcing nonlinear in `v` and explicit in `t`.
    pub struct CubicDrag {
        coordinates: [x, y, z],
        parameters: { c = 40.0, f0 = 2.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2 + z^2)/2,
        constraints: [ dot(z) - x*dot(y) - sin(t)/5 ],
        forces: { x: -c*dot(x)^3 + f0*cos(2*t), y: -c*dot(y)^3 },
    }
}

/// The cold step of size `h` from `start` in every Newton mode against the
/// tight solve: the largest distance, failures added to `failures`.
fn steps<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    failures: &mut Vec<String>,
) -> (f64, String)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    tally_against_tight(&against_tight::<Sys, N, M, S, D>(&EVERY_MODE, sys, method, start, h, 1), failures)
}

/// Damping, a magnetic term and cubic drag at step sizes where the cold
/// guess overshoots: every mode solves the steps and equals the tight solve.
#[test]
fn strong_velocity_forces_step_in_every_mode() {
    let mut failures = Vec::new();
    let mut worst = Vec::new();
    let damped = start(&DampedKnife::default(), 0.0, [1.0, 0.5, 0.3], [0.8, -0.4, 1.5]);
    worst.push(steps::<_, 3, 1, 3, 15>(&DampedKnife::default(), Method::LobattoIIIABD, &damped, 0.25, &mut failures));
    worst.push(steps::<_, 3, 1, 2, 11>(&DampedKnife::default(), Method::Gauss, &damped, 0.25, &mut failures));
    let magnetic = start(&MagneticKnife::default(), 0.0, [0.8, 0.6, 0.2], [0.3, -0.2, -0.5]);
    worst.push(steps::<_, 3, 1, 2, 11>(&MagneticKnife::default(), Method::Gauss, &magnetic, 1.0, &mut failures));
    worst.push(steps::<_, 3, 1, 3, 15>(&MagneticKnife::default(), Method::LobattoIIIAB, &magnetic, 1.0, &mut failures));
    let drag = start(&CubicDrag::default(), 0.0, [0.2, 0.1, 0.0], [3.0, -2.0, 0.0]);
    worst.push(steps::<_, 3, 1, 2, 11>(&CubicDrag::default(), Method::Gauss, &drag, 0.1, &mut failures));
    worst.push(steps::<_, 3, 1, 2, 11>(&CubicDrag::default(), Method::LobattoIIIABD, &drag, 0.1, &mut failures));
    println!("largest distances from the tight solve: {worst:?}");
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A step far beyond what the method can take on a strongly damped system
/// is still a typed failure, reported with the history of the solve at the
/// full step, which the stepper's last history repeats.
#[test]
fn a_step_beyond_the_branch_still_fails() {
    let damped = start(&DampedKnife::default(), 0.0, [1.0, 0.5, 0.3], [0.8, -0.4, 1.5]);
    for mode in [NewtonMode::Full, NewtonMode::Simplified] {
        let opts = NewtonOptions { mode, ..NewtonOptions::default() };
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(DampedKnife::default(), Tableau::new(Method::Gauss).unwrap())
            .with_options(opts);
        let err = st.step(&damped, 1e3).expect_err("h = 1000 is beyond the branch");
        let history = err.history().unwrap_or_else(|| panic!("{mode:?}: {err}"));
        assert!(matches!(err, StepError::Diverged { .. } | StepError::MaxIterations { .. }), "{mode:?}: {err}");
        assert_eq!(format!("{:?}", st.last_history()), format!("{history:?}"), "{mode:?}");
    }
}
