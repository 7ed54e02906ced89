//! A knife edge on a spring, declared in units of the length `r0`: the
//! system of `examples/unit_scales.rs` and of the integration tests
//! `small_scales`, which step the same motion with every length scaled by
//! `λ` (`r0 = λ`, start `λ·(1.5, 0.2)`, speed `0.8·λ`).

use spark_runtime::{nonholonomic_system, State, Vector};

nonholonomic_system! {
    /// A knife edge (skate) on a spring of rest length `r0` anchored at the
    /// origin: the mass `m` has the moment of inertia `m r0²`, so every
    /// length scales with `r0` and the heading and the time do not.
    pub struct ElasticSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, k = 1.0, r0 = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + m*r0^2/2*dot(theta)^2 - k/2*(sqrt(x^2 + y^2) - r0)^2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
}

/// The system and its start with every length scaled by `lambda`: the same
/// motion at every `lambda`, in other units.
pub fn elastic_skate(lambda: f64) -> (ElasticSkate, State<3>) {
    let (heading, turn_rate, speed) = (0.3f64, 0.7, 0.8 * lambda);
    let q0 = Vector::<3>::new(1.5 * lambda, 0.2 * lambda, heading);
    let v0 = Vector::<3>::new(speed * heading.cos(), speed * heading.sin(), turn_rate);
    (ElasticSkate { r0: lambda, ..ElasticSkate::default() }, State::new(0.0, q0, v0))
}

/// Steps the skate scaled by `lambda` `steps` times by `h` with `method`
/// (two stages) and `options`, and solves each step again, from the same
/// stepper state, to round-off (tolerance 0, full Newton). Returns the
/// largest difference of `q₁` and `v₁` between the two, lengths and their
/// rates relative to `lambda` (the heading's as they are), and the mean
/// Newton updates per step of `options`.
pub fn distance_to_tight(
    lambda: f64,
    method: spark_runtime::Method,
    options: spark_runtime::NewtonOptions,
    h: f64,
    steps: usize,
) -> Result<(f64, f64), String> {
    use spark_runtime::{Jacobian, NewtonMode, NewtonOptions, Stepper, Tableau};
    let (system, mut state) = elastic_skate(lambda);
    let tableau = Tableau::<2>::new(method).map_err(|e| e.to_string())?;
    let mut stepper = Stepper::<_, 3, 1, 2, 11>::new(system, tableau).with_options(options);
    let tight = NewtonOptions { tolerance: 0.0, mode: NewtonMode::Full, jacobian: Jacobian::Auto, ..options };
    let scale = [lambda, lambda, 1.0];
    let (mut worst, mut updates) = (0.0f64, 0);
    for _ in 0..steps {
        let mut reference = stepper.clone();
        *reference.options_mut() = tight;
        let solved = reference.step(&state, h).map_err(|e| e.to_string())?;
        let step = stepper.step(&state, h).map_err(|e| e.to_string())?;
        for (c, scale) in scale.iter().enumerate() {
            let q = (step.state.q[c] - solved.state.q[c]).abs();
            let v = (step.state.v[c] - solved.state.v[c]).abs();
            worst = worst.max(q.max(v) / scale);
        }
        updates += step.iterations;
        state = step.state;
    }
    Ok((worst, updates as f64 / steps as f64))
}
