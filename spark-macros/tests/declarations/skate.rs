//! A well-formed declaration compiles and its generated type works.
use spark_runtime::{nonholonomic_system, NonholonomicSystem, Vector};

nonholonomic_system! {
    /// Skate on an inclined plane.
    pub struct Skate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
        constants: { half = 1/2 },
        lagrangian: half*m*(dot(x)^2 + dot(y)^2) + half*inertia*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x), ],
    }
}

nonholonomic_system! {
    /// Unconstrained, time-dependent, sections in another order.
    pub(crate) struct Forced {
        lagrangian: dot(q)^2/2 - q^2/2 + q*cos(t),
        coordinates: [q],
    }
}

#[test]
fn skate_and_a_forced_system() {
    let s = Skate::default();
    let q = Vector::<3>::new(0.5, 0.0, 0.3);
    let v = Vector::<3>::new(0.1, 0.2, 1.0);
    let l = s.lagrangian(0.0, &q, &v);
    let expected = 0.5 * (0.01 + 0.04) + 0.5 + 0.5;
    assert!((l - expected).abs() < 1e-14, "{l} vs {expected}");
    const { assert!(!<Forced as NonholonomicSystem<1, 0>>::STRUCTURE.lagrangian_autonomous) };
}
