//! Declarations a new user writes: physics-style parameter names (`I`, `M`,
//! `R`) compile without warnings, `atan`/`asin`/`acos` are available, and
//! the base of a system with scenes is not rejected for a coordinate only a
//! scene's effects determine (a constraint on its velocity and, since a
//! step needs a regular Lagrangian, a kinetic term).
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
    /// `s` has no inertia in the base; the scene's effects tie dot(s) to the
    /// speed and give it one.
    pub struct Tracer {
        coordinates: [x, y, s],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        effects: {
            pen: constraint(dot(s) - sqrt(1 + dot(x)^2 + dot(y)^2)),
            ink: potential(-dot(s)^2/2),
        },
        scenes: { Drawing = [pen, ink] },
    }
}

#[test]
fn physics_style_names_and_scenes() {
    let w = Wheel { M: 1.0, I: 1.0, R: 2.0 };
    let (q, v) = (Vector::<2>::new(0.5, 0.0), Vector::<2>::new(2.0, 1.0));
    let expected = 2.0 + 0.5 - 0.5f64.atan() + 0.125f64.asin() - 0.1f64.acos();
    assert!((w.lagrangian(0.0, &q, &v) - expected).abs() < 1e-15);
    assert_eq!(w.constraint(0.0, &q, &v)[0], 0.0);
    assert_eq!((Tracer::M, Drawing::M), (0, 1));
}

// A `#[cfg]` on the declaration applies to everything the macro generates,
// as to a hand-written struct and its impls: a false condition removes the
// system and its implementations, and builds.
nonholonomic_system! {
    /// Never compiled.
    #[cfg(any())]
    pub struct NeverBuilt {
        coordinates: [x],
        lagrangian: dot(x)^2/2 - x^2/2,
    }
}

nonholonomic_system! {
    /// Always compiled: a true condition changes nothing.
    #[cfg(all())]
    pub struct AlwaysBuilt {
        coordinates: [x, y],
        parameters: { k = 2.0 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - k*x^2/2,
        constraints: [ dot(y) - x*dot(x) ],
    }
}

#[test]
fn a_cfg_on_the_declaration_applies_to_every_generated_item() {
    let sys = AlwaysBuilt::new();
    assert_eq!((AlwaysBuilt::N, AlwaysBuilt::M, sys.k), (2, 1, 2.0));
    let (q, v) = (Vector::<2>::new(0.5, 0.0), Vector::<2>::new(2.0, 1.0));
    // E = |v|²/2 + k x²/2.
    assert_eq!(<AlwaysBuilt as NonholonomicSystem<2, 1>>::energy(&sys, 0.0, &q, &v), 2.5 + 0.25);
}

// Empty blocks declare nothing: `forces: {}`, `nonideal_forces: {}` and
// `events: {}` are none, as empty `parameters` and `constraints` are.
nonholonomic_system! {
    pub struct EmptyBlocks {
        coordinates: [x],
        parameters: {},
        lagrangian: dot(x)^2/2 - x^2/2,
        constraints: [],
        forces: {},
        nonideal_forces: {},
        events: {},
    }
}

#[test]
fn empty_blocks_compile_to_a_system_without_them() {
    const {
        assert!(!<EmptyBlocks as NonholonomicSystem<1, 0>>::HAS_FORCING);
        assert!(!<EmptyBlocks as NonholonomicSystem<1, 0>>::HAS_NONIDEAL_FORCE);
        assert!(!<EmptyBlocks as NonholonomicSystem<1, 0>>::HAS_EVENTS);
    };
    let (q, v) = (Vector::<1>::new(1.0), Vector::<1>::new(2.0));
    assert_eq!(EmptyBlocks::new().lagrangian(0.0, &q, &v), 2.0 - 0.5);
}
