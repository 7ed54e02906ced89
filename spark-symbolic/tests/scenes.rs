//! Effects and scenes: a scene generates exactly the code of the same system
//! declared by hand without the left-out effects (identical token stream
//! modulo the type name and doc line, identical operation counts), holonomic
//! effects become velocity-level constraints, and malformed sections are
//! errors with a span.

use proc_macro2::TokenStream;
use spark_symbolic::scenes::parse_with_scenes;
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

/// A holonomic row `k = g_t + g_q·v` is taken by the graph differentiator,
/// the one that takes every other derivative: `tan' = 1 + tan²` reuses the
/// `tan` node, so the row costs what the same row written by hand costs,
/// and `SOURCE` prints the `k` the generated code computes.
#[test]
fn holonomic_rows_are_differentiated_on_the_graph() {
    let src = SCENED.replace("(x^2 + y^2 - ell^2)/2", "tan(x) - y");
    let (_, s) = parse_with_scenes(&tokens(&src)).unwrap().unwrap();
    let rod = analyze(&s[3]).unwrap();
    let hand = by_hand("m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2", "(1 + tan(x)^2)*dot(x) - dot(y)");
    let hand = analyze(&hand).unwrap();
    assert_eq!(rod.operations, hand.operations);
    assert_eq!(rod.constraint_sources.len(), 1);
    let k = &rod.constraint_sources[0];
    assert!(k.contains("(tan (q x))") && !k.contains("cos"), "{k}");
    let code = generate(&s[3]).unwrap().to_string();
    assert!(code.contains(&format!("constraints : & [{k:?}]")), "{code}");
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

const FORCED: &str = r#"
pub struct Sled {
    coordinates: [x, y, theta],
    parameters: { m = 1.0, inertia = 0.5, tau = 0.4, c = 0.3, mu = 0.2 },
    lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2,
    constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    effects: {
        drive: force { theta: tau },
        damping: force { x: -c*dot(x), y: -c*dot(y) },
        rail: constraint(dot(x) - 0.5),
        rod: holonomic((x^2 + y^2 - 1)/2),
        rub: nonideal { x: -mu*psi[0]*cos(theta), y: -mu*rail*sin(theta) },
    },
    scenes: { Free = [], Driven = [drive], Both = [drive, damping], Rubbing = [rail, rub], Mixed = [rod, rail, rub] },
}
"#;

fn forced_hand(extra: &str) -> SystemSpec {
    dsl::parse(tokens(&format!(
        "pub struct Hand {{ coordinates: [x, y, theta], parameters: {{ m = 1.0, inertia = 0.5, tau = 0.4, c = 0.3, \
         mu = 0.2 }}, lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2, \
         constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) {extra} }}"
    )))
    .unwrap()
}

#[test]
fn force_and_nonideal_scenes_generate_the_code_of_the_hand_declared_system() {
    let (base, s) = parse_with_scenes(&tokens(FORCED)).unwrap().unwrap();
    let (free, driven, both, rubbing) = (&s[0], &s[1], &s[2], &s[3]);
    // No effect: the code of the base declaration, no trace of forcing.
    assert_eq!(normalized(free.clone()), normalized(base.clone()));
    let free_code = generate(free).unwrap().to_string();
    for absent in ["HAS_FORCING", "external_force (", "HAS_NONIDEAL_FORCE", "HAS_HOLONOMIC"] {
        assert!(!free_code.contains(absent), "`{absent}` in a scene without effects");
    }
    // One force effect = the same force in the base declaration, token for token.
    let hand = forced_hand("], forces: { theta: tau }");
    assert_eq!(normalized(driven.clone()), normalized(hand.clone()));
    let code = generate(driven).unwrap().to_string();
    assert!(code.contains("const HAS_FORCING : bool = true"), "{code}");
    assert!(code.contains("external_force : & [\"0\" , \"0\" , \"(p tau)\"]"), "{code}");
    // Two force effects add up component by component: `a + b` in the source.
    let hand = forced_hand("], forces: { theta: tau, x: -c*dot(x), y: -c*dot(y) }");
    assert_eq!(normalized(both.clone()), normalized(hand.clone()));
    let (a, h) = (analyze(both).unwrap().operations, analyze(&hand).unwrap().operations);
    assert_eq!(a, h);
    assert!(a.external_force_jacobians > 0 && a.nonideal_force_jacobians == 0, "{a:?}");
    assert_eq!((a.stage_values, a.stage_jacobians), {
        let f = analyze(free).unwrap().operations;
        (f.stage_values, f.stage_jacobians)
    });
    // Non-ideal force: `psi[0]` is the base constraint, `rail` the scene's second one.
    let hand = forced_hand(", dot(x) - 0.5 ], nonideal_forces: { x: -mu*psi[0]*cos(theta), y: -mu*psi[1]*sin(theta) }");
    assert_eq!(normalized(rubbing.clone()), normalized(hand.clone()));
    let code = generate(rubbing).unwrap().to_string();
    assert!(code.contains("(psi 1)") && code.contains("fn nonideal_force_jacobians"), "{code}");
    assert!(analyze(rubbing).unwrap().operations.nonideal_force_jacobians > 0);
}

#[test]
fn multipliers_follow_the_scene_constraint_order_and_holonomic_rows_report_g() {
    let (_, s) = parse_with_scenes(&tokens(FORCED)).unwrap().unwrap();
    let mixed = &s[4];
    // Constraints: base blade, rod (holonomic), rail: `rail` is ψ₂ here.
    assert_eq!(mixed.constraints.len(), 3);
    let code = generate(mixed).unwrap().to_string();
    assert!(code.contains("\"(* (* (neg (p mu)) (psi 2)) (sin (q theta)))\""), "{code}");
    assert!(code.contains("const HAS_HOLONOMIC : bool = true"), "{code}");
    // g: 0 for the blade and the rail, the rod's g(q) in its row.
    assert!(
        code.contains("holonomic : & [\"0\" , \"(/ (- (+ (^ (q x) 2.0) (^ (q y) 2.0)) 1.0) 2.0)\" , \"0\"]"),
        "{code}"
    );
    assert!(code.contains("fn holonomic_residual"), "{code}");
}

#[test]
fn malformed_forces_are_errors() {
    let bad = |from: &str, to: &str| error_of(&FORCED.replace(from, to));
    let e = bad("drive: force { theta: tau }", "drive: force { thetta: tau }");
    assert!(e.contains("unknown coordinate `thetta`") && e.contains("did you mean `theta`"), "{e}");
    let e = bad("damping: force { x: -c*dot(x), y: -c*dot(y) }", "damping: force { x: -c*dot(x), x: -c }");
    assert!(e.contains("coordinate `x` appears twice"), "{e}");
    let e = bad("drive: force { theta: tau }", "drive: force { theta: tau*psi[0] }");
    assert!(e.contains("may not depend on the multiplier `psi[0]`") && e.contains("nonideal"), "{e}");
    let e = bad("drive: force { theta: tau }", "drive: force { theta: tau*rail }");
    assert!(e.contains("may not depend on `rail`"), "{e}");
    let e = bad("rub: nonideal { x: -mu*psi[0]*cos(theta)", "rub: nonideal { x: -mu*psi[1]*cos(theta)");
    assert!(e.contains("`psi[1]` is out of range") && e.contains("`rail`"), "{e}");
    let e = bad("y: -mu*rail*sin(theta)", "y: -mu*rial*sin(theta)");
    assert!(e.contains("unknown identifier `rial`") && e.contains("`rail`, `rod`"), "{e}");
    let e = bad("rod: holonomic((x^2 + y^2 - 1)/2)", "rod: holonomic(x*psi[0])");
    assert!(e.contains("may only appear in a non-ideal"), "{e}");
    let e = bad("rod: holonomic((x^2 + y^2 - 1)/2)", "rod: holonomic(x*dot(y))");
    assert!(e.contains("may not involve velocities"), "{e}");
    let e = bad("Rubbing = [rail, rub]", "Rubbing = [rub]");
    assert!(e.contains("uses the multiplier of constraint `rail`, which scene `Rubbing` does not select"), "{e}");
    let e = bad("drive: force { theta: tau }", "drive: force(tau)");
    assert!(e.contains("drive: force { coordinate: expression"), "{e}");
    let e = bad("drive: force { theta: tau }", "drive: force { tau: 1 }");
    assert!(e.contains("`tau` is a parameter, not a coordinate"), "{e}");
    // The base sections: psi outside `nonideal_forces`, out of range inside.
    let err_of = |extra: &str| match dsl::parse(tokens(&format!(
        "pub struct A {{ coordinates: [x], lagrangian: dot(x)^2/2, constraints: [dot(x) - 1], {extra} }}"
    ))) {
        Err(e) => e.message,
        Ok(_) => panic!("expected an error for {extra}"),
    };
    assert!(err_of("forces: { x: psi[0] }").contains("may not depend on the multiplier `psi[0]`"));
    assert!(err_of("nonideal_forces: { x: psi[1] }").contains("base declaration has 1 constraint, `psi[0]`"));
    assert!(err_of("forces: { x: 1, x: 2 }").contains("appears twice"));
    let e = match dsl::parse(tokens("pub struct A { coordinates: [x], lagrangian: dot(x)^2/2 + psi[0] }")) {
        Err(e) => e.message,
        Ok(_) => panic!("psi in L must be an error"),
    };
    assert!(e.contains("may only appear in a non-ideal constraint force"), "{e}");
}

/// A constraint effect's name stands for its multiplier in `nonideal`
/// forces, where `t`, `pi` and the functions keep their own meaning: a
/// constraint named `pi` would make `nonideal { y: -mu*pi }` the constant −μπ,
/// a constraint named `t` the time, each generated as a success. Such names are
/// refused like the names of coordinates; a scene name, a struct of its
/// own, may not be a Rust keyword or a primitive type the generated code
/// uses (as the base struct's may not).
#[test]
fn constraint_effects_named_like_the_time_pi_or_a_function_and_keyword_scenes_are_errors() {
    for name in ["t", "pi", "sin", "atan2", "dot", "type"] {
        let e = error_of(&FORCED.replace("rail", name));
        assert!(e.contains(&format!("`{name}`")) && e.contains("choose another name for this effect"), "{name}: {e}");
        let e = error_of(&FORCED.replace("rod", name));
        assert!(e.contains(&format!("`{name}`")) && e.contains("choose another name for this effect"), "{name}: {e}");
    }
    // The multiplier's own spelling is no reserved word: `psi` names the multiplier.
    let (_, scenes) = parse_with_scenes(&tokens(&FORCED.replace("rail", "psi"))).unwrap().unwrap();
    let rubbing = generate(&scenes[3]).unwrap().to_string();
    assert!(rubbing.contains("(psi 1)") && !rubbing.contains("(neg pi)"), "{rubbing}");
    for name in ["Self", "struct", "type", "fn"] {
        let e = error_of(&FORCED.replace("Rubbing", name));
        assert!(e.contains(&format!("`{name}` is a Rust keyword; choose another scene name")), "{name}: {e}");
    }
    for name in ["f64", "usize", "bool", "str"] {
        let e = error_of(&FORCED.replace("Rubbing", name));
        assert!(
            e.contains(&format!("`{name}` names a Rust primitive type")) && e.contains("scene name"),
            "{name}: {e}"
        );
    }
}
