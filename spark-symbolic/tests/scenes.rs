//! Effects and scenes: a scene generates exactly the code of the same system
//! declared by hand without the left-out effects (identical token stream
//! modulo the type name and doc line, identical operation counts), holonomic
//! effects become velocity-level constraints, and malformed sections are
//! errors with a span.

use proc_macro2::TokenStream;
use spark_symbolic::dsl::scenes::parse_with_scenes;
use spark_symbolic::{analyze, dsl, generate, SystemSpec};

const SCENED: &str = r#"
pub struct Cart {
    coordinates: [x, y, theta],
    parameters: { m = 1.0, inertia = 0.5, kappa = 2.0, ell = 1.0 },
    lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2,
    effects: {
        spring: potential(kappa/2*(x^2 + y^2)),
        no_slip: constraint(cos(theta)*dot(y) - sin(theta)*dot(x)),
        rod: holonomic((x^2 + y^2 - ell^2)/2),
    },
    scenes: { Free = [], Sprung = [spring], Skating = [spring, no_slip], Rod = [rod] },
}
"#;

fn tokens(s: &str) -> TokenStream {
    s.parse().unwrap()
}

fn scenes() -> (SystemSpec, Vec<SystemSpec>) {
    parse_with_scenes(&tokens(SCENED)).unwrap().expect("has scenes")
}

/// Generated code with the name and the doc attributes normalized away.
fn normalized(mut spec: SystemSpec) -> String {
    spec.attrs = TokenStream::new();
    spec.name = proc_macro2::Ident::new("Same", proc_macro2::Span::call_site());
    generate(&spec).unwrap().to_string()
}

fn by_hand(lagrangian: &str, constraints: &str) -> SystemSpec {
    dsl::parse(tokens(&format!(
        "pub struct Hand {{ coordinates: [x, y, theta], parameters: {{ m = 1.0, inertia = 0.5, kappa = 2.0, ell = 1.0 }}, \
         lagrangian: {lagrangian}, constraints: [{constraints}] }}"
    )))
    .unwrap()
}

#[test]
fn scenes_generate_the_code_of_the_hand_declared_system() {
    let (base, scenes) = scenes();
    let names: Vec<String> = scenes.iter().map(|s| s.name.to_string()).collect();
    assert_eq!(names, ["Free", "Sprung", "Skating", "Rod"]);
    let t = "m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2";
    let cases = [
        (&scenes[0], by_hand(t, "")),
        (&scenes[1], by_hand(&format!("{t} - kappa/2*(x^2 + y^2)"), "")),
        (&scenes[2], by_hand(&format!("{t} - kappa/2*(x^2 + y^2)"), "cos(theta)*dot(y) - sin(theta)*dot(x)")),
    ];
    for (scene, hand) in cases {
        assert_eq!(normalized(scene.clone()), normalized(hand.clone()), "scene {}", scene.name);
        assert_eq!(analyze(scene).unwrap().operations, analyze(&hand).unwrap().operations);
    }
    assert_eq!(normalized(base), normalized(scenes[0].clone()));
}

#[test]
fn cost_follows_the_effects() {
    let (_, scenes) = scenes();
    let ops: Vec<_> = scenes.iter().map(|s| analyze(s).unwrap()).collect();
    // No constraint, no multiplier: M follows the scene.
    assert_eq!(ops.iter().map(|a| a.m).collect::<Vec<_>>(), [0, 0, 1, 1]);
    let jac = |i: usize| ops[i].operations.stage_jacobians;
    assert!(jac(0) <= jac(1) && jac(1) < jac(2), "stage-Jacobian ops {} {} {}", jac(0), jac(1), jac(2));
    assert!(ops.iter().all(|a| a.structure.lagrangian_autonomous && a.structure.constant_mass_matrix));
}

#[test]
fn holonomic_effects_become_velocity_level_constraints() {
    let (_, scenes) = scenes();
    let rod = analyze(&scenes[3]).unwrap();
    // d/dt ((x²+y²−ℓ²)/2) = x ẋ + y ẏ: linear in v, autonomous.
    assert_eq!(rod.structure.constraint_form, spark_symbolic::ConstraintForm::Linear);
    assert!(rod.structure.constraints_autonomous);
    let hand = by_hand("m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2", "x*dot(x) + y*dot(y)");
    assert_eq!(rod.operations, analyze(&hand).unwrap().operations);
    // A rheonomic holonomic constraint gives k_t ≠ 0.
    let moving = SCENED.replace("(x^2 + y^2 - ell^2)/2", "x - sin(t)");
    let (_, s) = parse_with_scenes(&tokens(&moving)).unwrap().unwrap();
    assert!(!analyze(&s[3]).unwrap().structure.constraints_autonomous);
}

fn error_of(src: &str) -> String {
    match parse_with_scenes(&tokens(src)) {
        Err(e) => e.message,
        Ok(_) => panic!("expected an error for {src}"),
    }
}

#[test]
fn malformed_effects_and_scenes_are_errors() {
    let e = error_of(&SCENED.replace("Skating = [spring, no_slip]", "Skating = [sprig]"));
    assert!(e.contains("unknown effect `sprig`") && e.contains("did you mean `spring`"), "{e}");
    let e = error_of(&SCENED.replace("rod: holonomic", "spring: holonomic"));
    assert!(e.contains("declared twice"), "{e}");
    let e = error_of(&SCENED.replace("Rod = [rod]", "Rod = [rod, rod]"));
    assert!(e.contains("listed twice"), "{e}");
    let e = error_of(&SCENED.replace("rod: holonomic((x^2 + y^2 - ell^2)/2)", "rod: holonomic(dot(x))"));
    assert!(e.contains("may not involve velocities"), "{e}");
    let e = error_of(
        &SCENED.replace("no_slip: constraint(cos(theta)*dot(y) - sin(theta)*dot(x))", "no_slip: constraint(x)"),
    );
    assert!(e.contains("holonomic"), "{e}");
    let e = error_of(&SCENED.replace("potential(", "potental("));
    assert!(e.contains("did you mean `potential`"), "{e}");
    let e = error_of(&SCENED.replace("Free = []", "Cart = []"));
    assert!(e.contains("twice (or named like the base struct)"), "{e}");
    let e = error_of(
        &SCENED.replace("scenes: { Free = [], Sprung = [spring], Skating = [spring, no_slip], Rod = [rod] },", ""),
    );
    assert!(e.contains("without `scenes:`"), "{e}");
    let e = error_of(&SCENED.replace("spring: potential(kappa/2*(x^2 + y^2))", "spring: potential(kapa)"));
    assert!(e.contains("kapa"), "{e}");
    // Without the sections the ordinary path is taken.
    assert!(parse_with_scenes(&tokens("pub struct A { coordinates: [x], lagrangian: dot(x)^2 }")).unwrap().is_none());
}
