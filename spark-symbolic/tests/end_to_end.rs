//! DSL text → parser → engine → tokens that parse as a Rust file.

use spark_symbolic::{analyze, dsl, generate, ConstraintForm};

fn parse(src: &str) -> spark_symbolic::SystemSpec {
    let tokens: proc_macro2::TokenStream = src.parse().expect("tokens");
    dsl::parse(tokens).unwrap_or_else(|e| panic!("parse: {}", e.message))
}

#[test]
fn skate_from_dsl_generates_valid_rust() {
    let spec = parse(
        "/// Skate on an inclined plane
        pub struct Skate {
            coordinates: [x, y, theta],
            parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
            lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
            constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        }",
    );
    let file: syn::File = syn::parse2(generate(&spec).expect("generate")).expect("valid Rust");
    assert_eq!(file.items.len(), 4);
    let a = analyze(&spec).expect("analyze");
    assert_eq!(a.structure.constraint_form, ConstraintForm::Linear);
    assert!(a.structure.constant_mass_matrix);
}

/// An empty `forces: {}`, `nonideal_forces: {}` or `events: {}` block
/// declares nothing: the generated code, the structure facts and the
/// operation counts are those of the declaration without the block.
#[test]
fn empty_force_and_event_blocks_generate_what_absent_ones_do() {
    let base = "coordinates: [x, y, theta], parameters: { m = 1.0 }, \
                lagrangian: m/2*(dot(x)^2 + dot(y)^2) + dot(theta)^2/2, \
                constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ]";
    let absent = parse(&format!("pub struct Skate {{ {base} }}"));
    let code = generate(&absent).expect("generate").to_string();
    let facts = analyze(&absent).expect("analyze");
    for blocks in ["forces: {}", "nonideal_forces: {}", "events: {}", "forces: {}, nonideal_forces: {}, events: {},"] {
        let empty = parse(&format!("pub struct Skate {{ {base}, {blocks} }}"));
        assert_eq!(generate(&empty).expect("generate").to_string(), code, "{blocks}");
        assert_eq!(analyze(&empty).expect("analyze"), facts, "{blocks}");
    }
}

const EVERYTHING: &str = "struct Everything {
            coordinates: [a, b],
            parameters: { k = 2.0 },
            constants: { c = 3.0, d = c^2 },
            lagrangian: exp(a)*dot(a)^2/2 + sqrt(1 + b^2)*dot(b)^2 + k*t*a + atan2(a, 2 + b^2)
                + tanh(b)*sinh(a)*cosh(dot(b)) - d*a^(-2.5)*ln(2 + b^2) + tan(a/10)*dot(a)*dot(b) + cos(a)
                + sqrt(dot(a)^2 + dot(b)^2)^3 + dot(a)*b,
            constraints: [ dot(a)^2 + b*dot(b) + t, sin(a)*dot(b) - 1 ],
        }";

/// The energy (built term by term with Euler's relation where a term is
/// homogeneous in `v`) equals `∇_v L · v − L` at random points.
#[test]
fn energy_matches_its_definition() {
    use spark_symbolic::graph::Var;
    let spec = parse(EVERYTHING);
    let m = spark_symbolic::model::Model::build(&spec).expect("model");
    for k in 0..20 {
        let x = |i: u32| ((k * 7 + i * 3) as f64 * 0.37).sin() + 1.2;
        let env = |v: Var| match v {
            Var::Time => x(0),
            Var::Q(i) => x(1 + i),
            Var::V(i) => x(4 + i) - 1.5,
            Var::P(_) => 2.0,
            Var::Psi(_) => f64::NAN,
        };
        let g = &m.graph;
        let pv: f64 = (0..2).map(|i| g.eval(m.momentum[i], &env) * env(Var::V(i as u32))).sum();
        let want = pv - g.eval(m.lagrangian, &env);
        let got = g.eval(m.energy, &env);
        assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "{got} vs {want}");
    }
}

#[test]
fn every_function_and_time_from_dsl() {
    let spec = parse(EVERYTHING);
    syn::parse2::<syn::File>(generate(&spec).expect("generate")).expect("valid Rust");
    let a = analyze(&spec).expect("analyze");
    assert!(!a.structure.lagrangian_autonomous && !a.structure.constraints_autonomous);
    assert!(!a.structure.constant_mass_matrix && !a.structure.separable);
    assert_eq!(a.structure.constraint_form, ConstraintForm::Nonlinear);
    // A named constant is its value in the neutral text (`d = c^2`, `c = 3`).
    assert!(a.lagrangian_source.contains("(* 9.0 (^ (q a) (neg 2.5)))"), "{}", a.lagrangian_source);
}

#[test]
fn holonomic_constraint_from_dsl_is_an_error() {
    let spec = parse("struct H { coordinates: [x, y], lagrangian: dot(x)^2, constraints: [x^2 + y^2 - 1] }");
    let e = generate(&spec).expect_err("holonomic");
    assert!(e.message.contains("holonomic"), "{}", e.message);
}

/// The velocity-level form the message suggests is quoted while it is
/// short; a long one is described by its length, so the message stays
/// readable whatever the size of the declaration.
#[test]
fn a_long_holonomic_constraint_is_not_quoted_in_full() {
    let short = parse("struct H { coordinates: [x, y], lagrangian: dot(x)^2, constraints: [x^2 + y^2 - 1] }");
    let e = generate(&short).expect_err("holonomic");
    assert!(e.message.contains("g_t + g_q·v: `"), "{}", e.message);
    let terms: Vec<String> = (1..=300).map(|k| format!("sin({k}*x)*y")).collect();
    let long = parse(&format!(
        "struct H {{ coordinates: [x, y], lagrangian: dot(x)^2, constraints: [{}] }}",
        terms.join(" + ")
    ));
    let e = generate(&long).expect_err("holonomic");
    assert!(e.message.contains("characters long, too long to quote here"), "{}", e.message);
    assert!(e.message.len() < 1000, "{} bytes: {}", e.message.len(), e.message);
}

/// Derives the user writes are not derived twice; `Default` is generated
/// from the parameter defaults, so deriving it is an error that says so.
#[test]
fn user_derives_do_not_clash() {
    let spec = parse("#[derive(Debug, Clone)] struct A { coordinates: [x], lagrangian: dot(x)^2 }");
    let code = generate(&spec).expect("generate").to_string();
    assert_eq!(code.matches("Debug").count(), 1, "{code}");
    assert_eq!(code.matches("Clone").count(), 1, "{code}");
    assert!(code.contains("Copy"));
    let spec = parse("#[derive(Default)] struct A { coordinates: [x], lagrangian: dot(x)^2 }");
    let e = generate(&spec).expect_err("derive(Default)");
    assert!(e.message.contains("remove it"), "{}", e.message);
}
