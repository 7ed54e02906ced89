//! A first Newton update that the affine rule accepts (`step::affine_along`)
//! is accurate only where it starts near the solution: the residual it
//! solves is rounded where the iteration starts, and a step many times the
//! system's time scale starts far from its solution. Such a step is
//! confirmed by a further update and equals the root of its equations.

use spark_runtime::{
    nonholonomic_system, Jacobian, Method, NewtonMode, NewtonOptions, State, Stepper, Tableau, Vector,
};

nonholonomic_system! {
    /// A skate on a belt that moves with velocity `u (sin wt · x, cos wt)`:
    /// the blade's constraint is affine in `v` with a time-dependent term.
    /// The heading rate is constant, so the step's equations are affine in
    /// every other unknown once the heading's are right.
    pub struct BeltSkate {
        coordinates: [x, y, th],
        parameters: { m = 1.2, inertia = 0.3, u = 0.5, w = 1.7, g = 0.8 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(th)^2 - m*g*y - x^2/4,
        constraints: [ cos(th)*(dot(y) - u*cos(w*t)) - sin(th)*(dot(x) - u*sin(w*t)*x) ],
    }
}

/// The largest difference scaled by `max(1, |reference|)`.
fn scaled_difference(got: &[f64], reference: &[f64]) -> f64 {
    got.iter().zip(reference).map(|(g, r)| (g - r).abs() / r.abs().max(1.0)).fold(0.0, f64::max)
}

/// One cold Gauss s = 2 step at h = 30 (about eight periods of the belt):
/// its first update, from the cold guess, moves the unknowns by 11 times
/// their size. Accepted as it stood, the step was 3.3e-12 off in `q₁` and
/// 3.5e-12 in `v₁` and `Ψ` in every Newton mode. The reference is the
/// root of the step's equations (6.1) solved in 50-digit arithmetic
/// (mpmath, with `∇L` and `k` written out from the declaration), rounded
/// to f64.
#[test]
fn a_far_first_update_is_confirmed_before_the_step_ends() {
    let (t0, h) = (0.7, 30.0);
    let q0 = Vector::<3>::new(0.1, -0.2, 0.6);
    // Consistent with the constraint at (t0, q0) to round-off.
    let v0 = Vector::<3>::new(0.2938742594077298, 0.3551235649043834, 0.9);
    let q1 = [-1.0115841427999164, 972.7439610167598, 27.6];
    let v1 = [0.30133344733854805, -0.7933274025490274, 0.9];
    let psi = [-5.4396446802583736, -3.627155820978241];
    let base = NewtonOptions::default();
    let modes = [
        ("full", NewtonOptions { mode: NewtonMode::Full, jacobian: Jacobian::Exact, ..base }),
        ("simplified, exact", NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Exact, ..base }),
        (
            "simplified, stage-decoupled",
            NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::StageDecoupled, ..base },
        ),
    ];
    for (name, options) in modes {
        let tableau = Tableau::<2>::new(Method::Gauss).unwrap();
        let mut stepper = Stepper::<_, 3, 1, 2, 11>::new(BeltSkate::default(), tableau).with_options(options);
        let r = stepper.step(&State::new(t0, q0, v0), h).unwrap();
        let multipliers: Vec<f64> = r.stage_multipliers.iter().map(|p| p[0]).collect();
        let errors = [
            scaled_difference(r.state.q.as_slice(), &q1),
            scaled_difference(r.state.v.as_slice(), &v1),
            scaled_difference(&multipliers, &psi),
        ];
        let shown: Vec<String> = errors.iter().map(|e| format!("{e:.1e}")).collect();
        println!("{name}: q1, v1, Ψ off by {shown:?} after {} updates", r.iterations);
        assert!(errors.iter().all(|&e| e <= 1e-13), "{name}: q1, v1, Ψ off by {shown:?}");
    }
}
