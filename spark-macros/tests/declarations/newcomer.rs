//! Declarations a new user writes: physics-style parameter names (`I`, `M`,
//! `R`) compile without warnings, `atan`/`asin`/`acos` are available, a
//! massless coordinate is fine when a constraint fixes its velocity, and the
//! base of a system with scenes is not rejected for a coordinate only a
//! scene's constraint determines.
#![deny(warnings)]
use spark_runtime::{nonholonomic_system, NonholonomicSystem, Vector};

nonholonomic_system! {
    pub struct Wheel {
        coordinates: [x, phi],
        parameters: { M = 2.0, I = 0.5, R = 0.3 },
        lagrangian: M/2*dot(x)^2 + I/2*dot(phi)^2 - atan(x) + asin(x/4) - acos(x/5),
        constraints: [ dot(x) - R*dot(phi) ],
    }
}

nonholonomic_system! {
    /// `s` has no inertia; the constraint ties dot(s) to dot(x).
    pub struct Follower {
        coordinates: [x, s],
        lagrangian: dot(x)^2/2 - x^2/2,
        constraints: [ dot(s) - x*dot(x) ],
    }
}

nonholonomic_system! {
    pub struct Tracer {
        coordinates: [x, y, s],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        effects: { pen: constraint(dot(s) - sqrt(1 + dot(x)^2 + dot(y)^2)) },
        scenes: { Drawing = [pen] },
    }
}

#[test]
fn physics_style_names_and_scenes() {
    let w = Wheel { M: 1.0, I: 1.0, R: 2.0 };
    let (q, v) = (Vector::<2>::new(0.5, 0.0), Vector::<2>::new(2.0, 1.0));
    let expected = 2.0 + 0.5 - 0.5f64.atan() + 0.125f64.asin() - 0.1f64.acos();
    assert!((w.lagrangian(0.0, &q, &v) - expected).abs() < 1e-15);
    assert_eq!(w.constraint(0.0, &q, &v)[0], 0.0);
    assert_eq!((Follower::M, Tracer::M, Drawing::M), (1, 0, 1));
}
