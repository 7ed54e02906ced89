//! The paper's four systems declared with `nonholonomic_system!`, and the
//! initial values the examples start them from, shared by the profiling
//! examples (`step_profile`, `driver_cost`, `lanes_profile`,
//! `extrapolation_degree`) so that they time the same generated code, and by
//! the integration test `end_point_values`. Each uses some of them.
#![allow(dead_code)]

use spark_runtime::{nonholonomic_system, State, Vector};

/// The particle's initial values (§8.1).
pub fn particle_start() -> State<3> {
    State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0))
}

/// The skate's initial values (§8.2).
pub fn skate_start() -> State<3> {
    State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0))
}

/// The mobile robot's initial values (§8.3).
pub fn robot_start() -> State<4> {
    State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0))
}

/// The McLachlan–Perlmutter particles' state `j = 5` of Fig. 8.4.
pub fn mp7_start() -> State<7> {
    let angle = 5.0 * std::f64::consts::PI / 18.0;
    let mut start =
        State::new(0.0, Vector::<7>::from_column_slice(&[angle.cos(), 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]), Vector::zeros());
    start.v[1] = angle.sin();
    start
}

nonholonomic_system! {
    /// The nonholonomic particle (§8.1).
    pub struct Particle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

nonholonomic_system! {
    /// The skate on an inclined plane (§8.2).
    pub struct Skate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
}

nonholonomic_system! {
    /// The mobile robot (§8.3).
    pub struct MobileRobot {
        coordinates: [x, y, theta, phi],
        parameters: { m = 1.0, inertia = 1.0, inertia_wheel = 1.0, ell = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + 3/2*inertia_wheel*dot(phi)^2
            - 10*sin(phi),
        constraints: [
            dot(x) - ell*cos(theta)*dot(phi),
            dot(y) - ell*sin(theta)*dot(phi),
        ],
    }
}

nonholonomic_system! {
    /// McLachlan and Perlmutter's particles, n = 7, the constraint as the
    /// paper prints it (§8.4).
    pub struct Mp7 {
        coordinates: [q1, q2, q3, q4, q5, q6, q7],
        lagrangian: (dot(q1)^2 + dot(q2)^2 + dot(q3)^2 + dot(q4)^2 + dot(q5)^2 + dot(q6)^2 + dot(q7)^2)/2
            - (q1^2 + q2^2 + q3^2 + q4^2 + q5^2 + q6^2 + q7^2
               + q5^2*q6^2 + q2^2*q5^2 + q3^2*q6^2 + q4^2*q7^2)/2,
        constraints: [ dot(q1) + q5*dot(q5) + q6*dot(q6) + q7*dot(q7) ],
    }
}
