//! Parser tests: accepted declarations, precedence, every error message with
//! the token it points at, and random token soup that must never panic.

use super::*;
use crate::spec::{BinOp, SrcExpr};
use proptest::prelude::*;

const SKATE: &str = r#"
    /// Skate on an inclined plane
    pub struct Skate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
"#;

fn parse_str(src: &str) -> Result<SystemSpec, SpecError> {
    parse(src.parse::<TokenStream>().expect("test source must lex"))
}

/// Fully parenthesized prefix form, with names, for structural comparisons.
fn sexpr(e: &SrcExpr, s: &SystemSpec) -> String {
    match e {
        SrcExpr::Num(v, _) => format!("{v}"),
        SrcExpr::Time(_) => "t".into(),
        SrcExpr::Pi(_) => "pi".into(),
        SrcExpr::Coord(i, _) => s.coordinates[*i].name.clone(),
        SrcExpr::Velocity(i, _) => format!("(dot {})", s.coordinates[*i].name),
        SrcExpr::Param(i, _) => s.parameters[*i].name.name.clone(),
        SrcExpr::Const(i, _) => s.constants[*i].name.name.clone(),
        SrcExpr::Multiplier(j, _) => format!("(psi {j})"),
        SrcExpr::Neg(a, _) => format!("(neg {})", sexpr(a, s)),
        SrcExpr::Binary(op, a, b, _) => {
            let o = match op {
                BinOp::Add => "+",
                BinOp::Sub => "-",
                BinOp::Mul => "*",
                BinOp::Div => "/",
                BinOp::Pow => "^",
            };
            format!("({o} {} {})", sexpr(a, s), sexpr(b, s))
        }
        SrcExpr::Call(f, args, _) => {
            let args: Vec<String> = args.iter().map(|a| sexpr(a, s)).collect();
            format!("({} {})", f.name(), args.join(" "))
        }
    }
}

/// Parses `lagrangian: <expr>` in a fixed context and returns its S-expression.
fn lag(expr: &str) -> String {
    let src = format!(
        "struct S {{ coordinates: [x, y, z], parameters: {{ a = 1, b = 2, c = 3 }}, constants: {{ k = 2 }}, lagrangian: {expr} }}"
    );
    let spec = parse_str(&src).unwrap_or_else(|e| panic!("`{expr}` should parse, got: {}", e.message));
    sexpr(&spec.lagrangian, &spec)
}

/// The source text a span covers (needs proc-macro2's `span-locations`).
fn text_at(src: &str, span: Span) -> String {
    let (start, end) = (span.start(), span.end());
    let lines: Vec<&str> = src.lines().collect();
    if start.line == 0 || start.line > lines.len() {
        return String::new();
    }
    if start.line == end.line {
        lines[start.line - 1].chars().skip(start.column).take(end.column - start.column).collect()
    } else {
        lines[start.line - 1].chars().skip(start.column).collect()
    }
}

/// Parses a declaration that must fail; returns (message, text under the span).
fn error(src: &str) -> (String, String) {
    match parse_str(src) {
        Ok(_) => panic!("expected an error for:\n{src}"),
        Err(e) => (e.message.clone(), text_at(src, e.span)),
    }
}

/// A declaration whose lagrangian is `expr`; the error must point at `at` and
/// mention `needle`.
fn assert_error(src: &str, at: &str, needle: &str) {
    let (msg, text) = error(src);
    assert!(msg.contains(needle), "message `{msg}` lacks `{needle}`");
    assert_eq!(text, at, "span of `{msg}`");
}

fn with_lag(expr: &str) -> String {
    format!("struct S {{ coordinates: [x, y, theta], parameters: {{ m = 1 }}, lagrangian: {expr} }}")
}

#[test]
fn skate_parses() {
    let s = parse_str(SKATE).unwrap();
    assert_eq!(s.name.to_string(), "Skate");
    assert_eq!(s.vis.to_string(), "pub");
    assert!(s.attrs.to_string().contains("doc"));
    let coords: Vec<&str> = s.coordinates.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(coords, ["x", "y", "theta"]);
    let params: Vec<(&str, f64)> = s.parameters.iter().map(|p| (p.name.name.as_str(), p.default)).collect();
    assert_eq!(params, [("m", 1.0), ("inertia", 1.0), ("g", 1.0), ("beta", std::f64::consts::FRAC_PI_2)]);
    assert_eq!(s.constraints.len(), 1);
    assert_eq!(sexpr(&s.constraints[0].expr, &s), "(- (* (cos theta) (dot y)) (* (sin theta) (dot x)))");
    assert_eq!(
        sexpr(&s.lagrangian, &s),
        "(+ (+ (* (/ m 2) (+ (^ (dot x) 2) (^ (dot y) 2))) (* (/ inertia 2) (^ (dot theta) 2))) (* (* (* m g) x) (sin beta)))"
    );
    assert_eq!(s.runtime_path.to_string(), ":: spark_runtime");
}

#[test]
fn precedence_and_associativity() {
    assert_eq!(lag("-x^2"), "(neg (^ x 2))");
    assert_eq!(lag("a*b^c"), "(* a (^ b c))");
    assert_eq!(lag("a^b^c"), "(^ a (^ b c))");
    assert_eq!(lag("x^-2"), "(^ x (neg 2))");
    assert_eq!(lag("-x^-y^2"), "(neg (^ x (neg (^ y 2))))");
    assert_eq!(lag("a/b*c"), "(* (/ a b) c)");
    assert_eq!(lag("a-b-c"), "(- (- a b) c)");
    assert_eq!(lag("a-b*c+x"), "(+ (- a (* b c)) x)");
    assert_eq!(lag("(a+b)^2"), "(^ (+ a b) 2)");
    assert_eq!(lag("2*-x"), "(* 2 (neg x))");
    assert_eq!(lag("--x"), "(neg (neg x))");
    assert_eq!(lag("+x"), "x");
    assert_eq!(lag("dot(x)^2*k"), "(* (^ (dot x) 2) k)");
    assert_eq!(lag("atan2(y, x) + sqrt(exp(t))"), "(+ (atan2 y x) (sqrt (exp t)))");
    assert_eq!(lag("sinh(x)*cosh(y)/tanh(z) - tan(ln(x))"), "(- (/ (* (sinh x) (cosh y)) (tanh z)) (tan (ln x)))");
    assert_eq!(lag("1e-3 + 2.5 + 10 + 1_000 + 3f64"), "(+ (+ (+ (+ 0.001 2.5) 10) 1000) 3)");
    assert_eq!(lag("pi*t"), "(* pi t)");
}

#[test]
fn sections_in_any_order_with_trailing_commas() {
    let s = parse_str(
        "pub(crate) struct P { constraints: [dot(z) - y*dot(x),], lagrangian: dot(x)^2, constants: { h = 1/2, q = h*h, }, coordinates: [x, y, z,], }",
    )
    .unwrap();
    assert_eq!(s.vis.to_string(), "pub (crate)");
    assert_eq!(s.constants.len(), 2);
    assert_eq!(eval_constant(&s.constants[1].value, &[0.5]).unwrap(), 0.25);
    assert!(s.parameters.is_empty());
    let s = parse_str("struct U { coordinates: [x], lagrangian: dot(x)^2, constraints: [] }").unwrap();
    assert!(s.constraints.is_empty());
}

#[test]
fn empty_blocks_declare_nothing_as_absent_ones_do() {
    let s = parse_str(
        "struct U { coordinates: [x, y], parameters: {}, constraints: [], forces: {}, nonideal_forces: {}, \
         events: {}, lagrangian: dot(x)^2 + dot(y)^2 }",
    )
    .unwrap();
    assert!(s.parameters.is_empty() && s.constraints.is_empty() && s.events.is_empty());
    assert!(s.external_force.is_empty(), "an empty `forces` block is no force, not N zero components");
    assert!(s.nonideal_force.is_empty(), "an empty `nonideal_forces` block is no force");
    // A stray comma is still an error, not an empty block.
    let (msg, at) = error("struct U { coordinates: [x], lagrangian: dot(x)^2, forces: { , } }");
    assert!(msg.contains("unexpected `,`"), "{msg}");
    assert_eq!(at, ",");
}

#[test]
fn parameter_defaults_are_evaluated() {
    let s = parse_str(
        "struct P { constants: { two = 2 }, coordinates: [x], parameters: { a = -two^2, b = atan2(1, 1)*4, c = sqrt(two)^2, d = 1e3 }, lagrangian: dot(x)^2 }",
    )
    .unwrap();
    let d: Vec<f64> = s.parameters.iter().map(|p| p.default).collect();
    assert_eq!(d[0], -4.0);
    assert_eq!(d[1], std::f64::consts::PI);
    assert!((d[2] - 2.0).abs() < 1e-15);
    assert_eq!(d[3], 1000.0);
}

#[test]
fn spark_attribute_sets_runtime_path_and_is_not_passed_through() {
    let s =
        parse_str("#[spark(crate = crate::rt)] #[derive(Default)] struct A { coordinates: [x], lagrangian: dot(x)^2 }")
            .unwrap();
    assert_eq!(s.runtime_path.to_string(), "crate :: rt");
    assert_eq!(s.attrs.to_string(), "# [derive (Default)]");
}

#[test]
fn header_errors() {
    assert_error("pub Skate { coordinates: [x], lagrangian: dot(x)^2 }", "Skate", "missing `struct`");
    assert_error("pub enum Skate { }", "enum", "declares a struct");
    assert_error("struct { coordinates: [x] }", "{ coordinates: [x] }", "struct's name");
    assert_error("struct S<T> { coordinates: [x] }", "<", "generic parameters are not supported");
    assert_error("struct S;", ";", "expected `{`");
    assert_error("struct S { coordinates: [x], lagrangian: dot(x)^2 } struct T {}", "struct", "one struct");
    assert_error("#![doc = \"x\"] struct S {}", "!", "inner attributes");
    assert_error("#[spark(krate = x)] struct S {}", "krate", "unknown `spark` option");
    let (msg, _) = error("");
    assert!(msg.contains("found nothing"), "{msg}");
}

#[test]
fn section_errors() {
    assert_error(
        "struct S { coordinates: [x], lagrangian: dot(x)^2, coordinate: [y] }",
        "coordinate",
        "did you mean `coordinates`?",
    );
    assert_error(
        "struct S { coordinates: [x], lagrangian: dot(x)^2, coordinates: [y] }",
        "coordinates",
        "appears twice",
    );
    assert_error("struct S { coordinates: [x] }", "S", "has no Lagrangian");
    assert_error("struct S { lagrangian: 1 }", "S", "has no coordinates");
    assert_error("struct S { coordinates: [], lagrangian: 1 }", "[]", "no coordinates");
    assert_error("struct S { coordinates: (x, y), lagrangian: 1 }", "(x, y)", "brackets");
    assert_error("struct S { coordinates: [x: f64], lagrangian: 1 }", ":", "just a name");
    assert_error("struct S { coordinates: [x], lagrangian: dot(x)^2, x }", "x", "remove the `,` before it");
    assert_error("struct S { coordinates [x], lagrangian: 1 }", "coordinates", "expected `:`");
    assert_error("struct S { coordinates: [x], lagrangian:, }", "lagrangian", "has no value");
    assert_error("struct S { coordinates: [x],, lagrangian: 1 }", ",", "unexpected `,`");
    assert_error("struct S { /// doc\n coordinates: [x], lagrangian: 1 }", "/// doc", "above `struct`");
    assert_error("struct S { coordinates: [x], lagrangian: 1, constraints: dot(x) }", "dot", "list in brackets");
}

#[test]
fn name_errors() {
    assert_error("struct S { coordinates: [x, y, x], lagrangian: 1 }", "x", "declared twice as a coordinate");
    assert_error(
        "struct S { coordinates: [x], parameters: { x = 1 }, lagrangian: 1 }",
        "x",
        "already declared as a coordinate",
    );
    assert_error(
        "struct S { constants: { m = 2 }, coordinates: [x], parameters: { m = 1 }, lagrangian: 1 }",
        "m",
        "already declared as a constant",
    );
    assert_error("struct S { coordinates: [t], lagrangian: 1 }", "t", "reserved for the time");
    assert_error("struct S { coordinates: [x], parameters: { pi = 3 }, lagrangian: 1 }", "pi", "reserved");
    assert_error("struct S { coordinates: [sin], lagrangian: 1 }", "sin", "is a function");
    assert_error("struct S { coordinates: [dot], lagrangian: 1 }", "dot", "reserved for velocities");
    assert_error("struct S { coordinates: [x, type], lagrangian: 1 }", "type", "Rust keyword");
    assert_error("struct S { coordinates: [__q], lagrangian: 1 }", "__q", "reserved for generated code");
}

/// A struct named like a primitive type the generated code names (`f64`
/// fields, `usize` constants, `bool` flags, `&str` sources) shadows it, and
/// the expansion fails in rustc far from the declaration.
#[test]
fn struct_names_that_break_the_generated_code_are_errors() {
    for name in ["f64", "usize", "bool", "str", "r#f64"] {
        assert_error(
            &format!("pub struct {name} {{ coordinates: [x], lagrangian: dot(x)^2 }}"),
            name,
            "names a Rust primitive type that the generated code uses; choose another struct name",
        );
    }
    assert_error("struct __S { coordinates: [x], lagrangian: dot(x)^2 }", "__S", "reserved for generated code");
    assert_error("struct type { coordinates: [x], lagrangian: dot(x)^2 }", "type", "Rust keyword");
    for name in ["f32", "i32", "u8", "char", "info", "integrate", "ensemble"] {
        assert!(parse_str(&format!("struct {name} {{ coordinates: [x], lagrangian: dot(x)^2 }}")).is_ok(), "{name}");
    }
}

#[test]
fn parameter_and_constant_errors() {
    assert_error(
        "struct S { coordinates: [x], parameters: { m = \"heavy\" }, lagrangian: 1 }",
        "\"heavy\"",
        "found the string",
    );
    assert_error(
        "struct S { coordinates: [x], parameters: { m = x }, lagrangian: 1 }",
        "x",
        "must be a constant number, not the coordinate `x`",
    );
    assert_error(
        "struct S { coordinates: [x], parameters: { a = 1, b = a }, lagrangian: 1 }",
        "a",
        "not the runtime parameter `a`",
    );
    assert_error("struct S { coordinates: [x], parameters: { m = t }, lagrangian: 1 }", "t", "not the time");
    assert_error("struct S { coordinates: [x], parameters: { m = dot(x) }, lagrangian: 1 }", "dot", "velocity");
    assert_error("struct S { coordinates: [x], parameters: { m }, lagrangian: 1 }", "m", "needs a default value");
    assert_error("struct S { coordinates: [x], parameters: { m: f64 = 1.0 }, lagrangian: 1 }", ":", "write `m = 1.0`");
    assert_error("struct S { coordinates: [x], parameters: { m = 1/0 }, lagrangian: 1 }", "/", "division by zero");
    assert_error(
        "struct S { coordinates: [x], constants: { c = x }, lagrangian: 1 }",
        "x",
        "constant `c` cannot depend on the coordinate `x`",
    );
    assert_error(
        "struct S { coordinates: [x], parameters: { m = 1 }, constants: { c = 2*m }, lagrangian: 1 }",
        "m",
        "runtime parameter `m`",
    );
    assert_error("struct S { coordinates: [x], constants: { a = b, b = 1 }, lagrangian: 1 }", "b", "declared later");
    assert_error("struct S { coordinates: [x], constants: { a = a }, lagrangian: 1 }", "a", "itself");
    assert_error("struct S { coordinates: [x], constants: { a = ln(0) }, lagrangian: 1 }", "ln", "evaluates to -inf");
    assert_error(
        "struct S { coordinates: [x], parameters: { m = 1, }, constants: { two = true }, lagrangian: 1 }",
        "true",
        "unknown identifier",
    );
}

#[test]
fn expression_errors() {
    assert_error(&with_lag("thta"), "thta", "did you mean `theta`?");
    assert_error(&with_lag("foo"), "foo", "Known names");
    assert_error(&with_lag("xdot"), "xdot", "write `dot(x)`");
    assert_error(&with_lag("PI"), "PI", "write `pi`");
    assert_error(&with_lag("FRAC_PI_2"), "FRAC_PI_2", "write `pi/2`");
    assert_error(&with_lag("dot(z)"), "z", "velocity of unknown coordinate `z`");
    assert_error(&with_lag("dot(thetta)"), "thetta", "did you mean `dot(theta)`?");
    assert_error(&with_lag("dot(m)"), "m", "is a parameter, not a coordinate");
    assert_error(&with_lag("dot(x + y)"), "x", "not an expression");
    assert_error(&with_lag("dot(2)"), "2", "one coordinate name");
    assert_error(&with_lag("dot()"), "()", "needs a coordinate");
    assert_error(&with_lag("dot(dot(x))"), "dot", "accelerations");
    assert_error(&with_lag("dot"), "dot", "write `dot(x)`");
    assert_error(&with_lag("sine(x)"), "sine", "did you mean `sin`?");
    assert_error(&with_lag("log(x)"), "log", "write `ln(x)`");
    assert_error(&with_lag("pow(x, 2)"), "pow", "`a^b`");
    assert_error(&with_lag("x(y)"), "x", "not a function");
    assert_error(&with_lag("sin(x, y)"), "sin", "takes 1 argument: `sin(x)`, found 2");
    assert_error(&with_lag("atan2(y)"), "atan2", "takes 2 arguments");
    assert_error(&with_lag("sin"), "sin", "is a function");
    assert_error(&with_lag("x +"), "+", "ends with `+`");
    assert_error(&with_lag("* x"), "*", "starts with `*`");
    assert_error(&with_lag("x + * y"), "*", "two operators in a row");
    assert_error(&with_lag("x^"), "^", "ends with `^`");
    assert_error(&with_lag("x ** 2"), "*", "write `x^2`");
    assert_error(&with_lag("2 x"), "x", "missing operator");
    assert_error(&with_lag("2x"), "2x", "write `2*x`");
    assert_error(&with_lag("2u8"), "2u8", "remove the type suffix");
    assert_error(&with_lag("1e400*x"), "1e400", "out of range for f64");
    assert_error(&with_lag("1e-400*x"), "1e-400", "would read as 0");
    assert_error(&with_lag("x + 0.5E-330*y"), "0.5E-330", "would read as 0");
    // Zero written with an exponent, and a subnormal, are numbers.
    assert!(parse_str(&with_lag("0e-400*x + 0.0e5 + 1e-320*x")).is_ok());
    assert_error(&with_lag("x.sin()"), ".", "method calls");
    assert_error(&with_lag("()"), "()", "empty parentheses");
    assert_error(&with_lag("[x]"), "[x]", "use parentheses");
    assert_error(&with_lag("sin(x,,)"), ",", "empty argument");
    assert_error(&with_lag("std::f64::consts::PI"), "std", "paths are not supported");
    assert_error(&with_lag("vec![1]"), "vec", "declare it under `constants: { … }`");
    assert_error(&with_lag("x = y"), "=", "must vanish");
    assert_error("struct S { coordinates: [x], lagrangian: 1, constraints: [dot(x),, x] }", ",", "unexpected `,`");
    assert_error(
        "struct S { coordinates: [x], lagrangian: 1, constraints: [dot(x) +] }",
        "+",
        "constraint 1 ends with `+`",
    );
}

#[test]
fn deep_nesting_is_an_error_not_a_stack_overflow() {
    let deep = format!("{}x{}", "(".repeat(5000), ")".repeat(5000));
    let (msg, _) = error(&with_lag(&deep));
    assert!(msg.contains("nested too deeply"), "{msg}");
    let (msg, _) = error(&with_lag(&format!("{}x", "-".repeat(5000))));
    assert!(msg.contains("nested too deeply"), "{msg}");
    let (msg, _) = error(&with_lag(&vec!["x"; 5000].join("^")));
    assert!(msg.contains("nested too deeply"), "{msg}");
    // Moderate nesting is fine.
    lag(&format!("{}x{}", "(".repeat(100), ")".repeat(100)));
}

/// Runs `f` on a thread with the 8 MiB stack of a main thread (the
/// compiler's, the Python package's check thread), where a stack overflow
/// aborts the process.
fn on_main_sized_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new().stack_size(8 << 20).spawn(f).expect("thread").join().expect("no panic")
}

/// A chain `x + x + …` is parsed in a loop but is a tree as deep as it is
/// long: one of 200 000 terms would overflow the stack of the passes over
/// the tree (and abort the Python interpreter in `spark.compile`'s check). More
/// than `MAX_OPERATIONS` operations in one expression, in one chain or
/// spread over parentheses and call arguments, are an error at the first
/// operation beyond the limit; the limit itself runs through the whole
/// check (parse, generate, analyze).
#[test]
fn expressions_with_more_operations_than_supported_are_an_error_not_a_stack_overflow() {
    for (what, expr) in [
        ("a sum", format!("dot(x)^2{}", "+x".repeat(200_000))),
        ("a product", format!("dot(x)^2{}", "*x".repeat(200_000))),
        ("sums in parentheses", format!("dot(x)^2{}", "+(x+x+x+x)".repeat(50_000))),
        ("sums in arguments", format!("dot(x)^2{}", "+sin(x+x+x+x)".repeat(50_000))),
    ] {
        let src = with_lag(&expr);
        let (msg, text) = on_main_sized_stack(move || error(&src));
        assert!(msg.contains(&format!("more than {MAX_OPERATIONS} operations")), "{what}: {msg}");
        assert!(msg.starts_with("the lagrangian"), "{what}: {msg}");
        assert!(text == "+" || text == "*", "{what}: span of `{msg}`: {text}");
    }
    // Exactly the limit: `dot(x)^2` is one operation, each `+x` another.
    let at_limit = format!("struct S {{ coordinates: [x], lagrangian: dot(x)^2{} }}", "+x".repeat(MAX_OPERATIONS - 1));
    on_main_sized_stack(move || {
        let spec = parse_str(&at_limit).expect("parses");
        crate::generate(&spec).expect("generates");
        crate::analyze(&spec).expect("analyzes");
    });
}

/// A sum of `k` distinct terms, in the Lagrangian and in a constraint,
/// lowers to a graph that grows linearly with `k`: the fold of the chain
/// `a + b + c + …` does not keep its partial sums of more than
/// `KEPT_PARTIAL_SUM` operands, each of which would copy the terms before
/// it (`k²/2` operands in all: 0.6 GB and 20 s of CPU for 10 000 terms).
#[test]
fn long_sums_lower_to_a_graph_linear_in_their_terms() {
    let size = |k: usize| {
        on_main_sized_stack(move || {
            let terms: String = (1..=k).map(|i| format!(" + atan2(x, {i})")).collect();
            let spec = parse_str(&format!(
                "struct S {{ coordinates: [x, y], lagrangian: dot(x)^2 + dot(y)^2{terms}, constraints: [ dot(y){terms} ] }}"
            ))
            .expect("parses");
            let mut g = crate::graph::Graph::new();
            let mut lower = crate::lower::Lowerer::new(&spec);
            lower.lower(&mut g, &spec.lagrangian).expect("lowers");
            lower.lower(&mut g, &spec.constraints[0].expr).expect("lowers");
            g.size()
        })
    };
    let (small, large) = (size(2_000), size(4_000));
    // Each term is a constant, a call and its operands, and the sums'
    // operands: a few per term, where the partial sums would be thousands.
    assert!(large <= 10 * 4_000, "a sum of 4000 terms lowers to {large} nodes and operands");
    assert!(large <= 2 * small + 100, "a sum of 2000 terms lowers to {small}, one of 4000 to {large}");
}

/// A product of `k` distinct factors, in the Lagrangian and in a
/// constraint, lowers to a graph that grows linearly with `k`, and so does
/// the graph once the code is generated: the fold of the chain `a·b·c·…`
/// does not keep its partial products of more than `KEPT_PARTIAL_PRODUCT`
/// operands, nor does emission make every left-folded prefix of a product
/// of more than `KEPT_PREFIX` factors a node (`k²/2` operands each way:
/// most of a minute to check a product of 4000 factors).
#[test]
fn long_products_lower_and_emit_to_a_graph_linear_in_their_factors() {
    // The graph of the lowered expressions, and of the model once its code
    // is generated (when `generate`).
    let size = |k: usize, generate: bool| {
        on_main_sized_stack(move || {
            let factors: String = (1..=k).map(|i| format!("*atan2(m, {i})")).collect();
            let spec = parse_str(&format!(
                "struct P {{ coordinates: [x, y], parameters: {{ m = 1.0 }}, \
                 lagrangian: dot(x)^2/2{factors} + dot(y)^2/2 - x^2, constraints: [ dot(y) - x*dot(x){factors} ] }}"
            ))
            .expect("parses");
            if !generate {
                let mut g = crate::graph::Graph::new();
                let mut lower = crate::lower::Lowerer::new(&spec);
                lower.lower(&mut g, &spec.lagrangian).expect("lowers");
                lower.lower(&mut g, &spec.constraints[0].expr).expect("lowers");
                return g.size();
            }
            let mut model = crate::model::Model::build(&spec).expect("builds");
            crate::codegen::generate_items(&spec, &mut model);
            model.graph.size()
        })
    };
    let (small, large) = (size(2_000, false), size(4_000, false));
    // Each factor is a constant, a call and its operands, and the
    // products' operands: a few per factor, where the partial products
    // would be thousands.
    assert!(large <= 10 * 4_000, "a product of 4000 factors lowers to {large} nodes and operands");
    assert!(large <= 2 * small + 100, "a product of 2000 factors lowers to {small}, one of 4000 to {large}");
    let (small, large) = (size(300, true), size(600, true));
    assert!(large <= 40 * 600, "generating code for 600 factors makes a graph of {large}");
    assert!(large <= 2 * small + 1_000, "generating code for 300 factors makes a graph of {small}, for 600 of {large}");
}

/// `asin(x)` and `acos(x)` are `atan2` forms with `x` written twice, so
/// nested calls double the tree at each level: 40 levels would exhaust
/// memory. The copies count against `MAX_OPERATIONS`, so deep nesting is an
/// error at once, and a few levels still parse.
#[test]
fn nested_asin_and_acos_count_their_copies_against_the_operation_limit() {
    for f in ["asin", "acos"] {
        let src = with_lag(&format!("dot(x)^2 + {}x{}", format!("{f}(").repeat(40), ")".repeat(40)));
        let (msg, text) = on_main_sized_stack(move || error(&src));
        assert!(msg.contains(&format!("more than {MAX_OPERATIONS} operations")), "{f}: {msg}");
        assert_eq!(text, f, "{f}: span of `{msg}`");
    }
    lag(&format!("dot(x)^2 + {}x{}", "asin(acos(".repeat(3), "))".repeat(3)));
}

/// Named constants refer to earlier ones. A chain `c1 = c0*c0, c2 = c1*c1,
/// …` is small as written, but each constant's expression written out in
/// place doubles at each link: the neutral text (`SOURCE`, `lagrangian_source`)
/// writes a constant as its value instead. A long chain `c_i = c_(i-1) + 1`
/// is lowered link by link rather than as one recursion as deep as the
/// chain (which overflows the compiler's stack with a debug build of the
/// macro).
#[test]
fn constant_chains_stay_small_in_the_neutral_text_and_shallow_in_lowering() {
    let doubling: Vec<String> =
        std::iter::once("c0 = 1".to_string()).chain((1..24).map(|i| format!("c{i} = c{}*c{}", i - 1, i - 1))).collect();
    let src =
        format!("struct S {{ coordinates: [x], constants: {{ {} }}, lagrangian: c23*dot(x)^2 }}", doubling.join(", "));
    let spec = parse_str(&src).expect("parses");
    let a = crate::analyze(&spec).expect("analyzes");
    assert_eq!(a.lagrangian_source, "(* 1.0 (^ (v x) 2.0))");
    let long: Vec<String> =
        std::iter::once("c0 = 1".to_string()).chain((1..3000).map(|i| format!("c{i} = c{} + 1", i - 1))).collect();
    let src =
        format!("struct S {{ coordinates: [x], constants: {{ {} }}, lagrangian: c2999*dot(x)^2 }}", long.join(", "));
    on_main_sized_stack(move || {
        let spec = parse_str(&src).expect("parses");
        crate::generate(&spec).map_err(|e| e.message).expect("generates");
        crate::analyze(&spec).map_err(|e| e.message).expect("analyzes");
    });
}

/// Derivatives can swell far beyond the expression written: the second
/// derivative of a product of `k` factors in one coordinate has about `k³`
/// operands, so a Lagrangian of 150 factors `(x + i)` (1 KB of text) would
/// generate 12 MB of Rust that rustc cannot compile. Past `MAX_GRAPH_SIZE`
/// it is an error on the struct's name that names the limit, within
/// seconds.
#[test]
fn derivatives_that_swell_beyond_the_graph_limit_are_an_error() {
    let factors: Vec<String> = (1..=150).map(|i| format!("(x + {i})")).collect();
    let src = format!("struct S {{ coordinates: [x], lagrangian: dot(x)^2 + {} }}", factors.join("*"));
    let msg = on_main_sized_stack(move || {
        let spec = parse_str(&src).expect("parses");
        crate::generate(&spec).map(|_| ()).map_err(|e| e.message)
    })
    .expect_err("a swollen declaration is refused");
    assert!(msg.starts_with("the derivatives of `S` grow beyond the engine's limit"), "{msg}");
    assert!(msg.contains(&crate::graph::MAX_GRAPH_SIZE.to_string()) && msg.contains("MAX_GRAPH_SIZE"), "{msg}");
}

/// A random well-formed expression over a fixed scope, printed with the
/// minimal parentheses the grammar needs, and its expected S-expression.
fn arb_expr() -> impl Strategy<Value = (String, String)> {
    let leaf = prop_oneof![
        Just(("x".to_string(), "x".to_string())),
        Just(("dot(y)".to_string(), "(dot y)".to_string())),
        Just(("a".to_string(), "a".to_string())),
        Just(("k".to_string(), "k".to_string())),
        Just(("t".to_string(), "t".to_string())),
        Just(("pi".to_string(), "pi".to_string())),
        (0u32..20).prop_map(|n| (n.to_string(), n.to_string())),
    ];
    // Every subexpression is printed parenthesized unless it is a leaf, so the
    // expected structure is unambiguous; operators and functions cover all.
    leaf.prop_recursive(4, 40, 3, |inner| {
        prop_oneof![
            (inner.clone(), inner.clone(), 0usize..5).prop_map(|((a, sa), (b, sb), op)| {
                let o = ["+", "-", "*", "/", "^"][op];
                (format!("({a}) {o} ({b})"), format!("({o} {sa} {sb})"))
            }),
            inner.clone().prop_map(|(a, sa)| (format!("-({a})"), format!("(neg {sa})"))),
            (inner.clone(), 0usize..9).prop_map(|((a, sa), f)| {
                let f = ["sqrt", "exp", "ln", "sin", "cos", "tan", "sinh", "cosh", "tanh"][f];
                (format!("{f}({a})"), format!("({f} {sa})"))
            }),
            (inner.clone(), inner)
                .prop_map(|((a, sa), (b, sb))| (format!("atan2({a}, {b})"), format!("(atan2 {sa} {sb})"))),
        ]
    })
}

/// Tokens a user might plausibly (mis)type.
fn arb_soup() -> impl Strategy<Value = String> {
    let atom = prop_oneof![
        Just("x"),
        Just("y"),
        Just("dot"),
        Just("sin"),
        Just("atan2"),
        Just("t"),
        Just("pi"),
        Just("m"),
        Just("struct"),
        Just("pub"),
        Just("S"),
        Just("coordinates"),
        Just("parameters"),
        Just("constants"),
        Just("lagrangian"),
        Just("constraints"),
        Just(":"),
        Just(","),
        Just("="),
        Just("+"),
        Just("-"),
        Just("*"),
        Just("/"),
        Just("^"),
        Just("#"),
        Just("!"),
        Just("."),
        Just(";"),
        Just("::"),
        Just("1"),
        Just("2.5"),
        Just("1e-3"),
        Just("\"s\""),
        Just("2x"),
        Just("true"),
        Just("'c'"),
        Just("<"),
        Just(">"),
        Just("__a"),
        Just("type"),
        Just("_"),
        Just("1e999"),
        Just("0x1F"),
        Just("3u8"),
    ]
    .prop_map(str::to_string);
    atom.prop_recursive(4, 64, 8, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..8).prop_map(|v| format!("({})", v.join(" "))),
            prop::collection::vec(inner.clone(), 0..8).prop_map(|v| format!("[{}]", v.join(" "))),
            prop::collection::vec(inner.clone(), 0..8).prop_map(|v| format!("{{{}}}", v.join(" "))),
            prop::collection::vec(inner, 1..8).prop_map(|v| v.join(" ")),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_expressions_parse_to_their_structure((src, expected) in arb_expr()) {
        prop_assert_eq!(lag(&src), expected);
    }

    #[test]
    fn token_soup_never_panics(soup in arb_soup(), prefix in 0usize..4) {
        let src = match prefix {
            0 => soup,
            1 => format!("struct S {{ {soup} }}"),
            2 => format!("struct S {{ coordinates: [x, y], parameters: {{ m = 1 }}, lagrangian: {soup} }}"),
            _ => format!("struct S {{ coordinates: [x], lagrangian: 1, constraints: [{soup}], constants: {{ c = {soup} }} }}"),
        };
        if let Ok(tokens) = src.parse::<TokenStream>() {
            if let Err(e) = parse(tokens) {
                prop_assert!(!e.message.is_empty());
            }
        }
    }
}

#[test]
fn find_declaration_searches_items_and_inline_modules() {
    let file = r#"
        use spark_runtime::nonholonomic_system;
        nonholonomic_system! { pub struct A { coordinates: [x], lagrangian: dot(x)^2 } }
        mod inner {
            spark_runtime::nonholonomic_system! {
                /// Doc.
                pub(crate) struct B { coordinates: [y], lagrangian: dot(y)^2 }
            }
        }
        fn unrelated() {}
    "#;
    let b = find_declaration(file, "B").unwrap();
    assert_eq!(parse(b).unwrap().name.to_string(), "B");
    assert!(find_declaration(file, "A").is_ok());
    match find_declaration(file, "C") {
        Err(LocateError::NotFound { name, available }) => {
            assert_eq!(name, "C");
            assert_eq!(available, ["A", "B"]);
        }
        other => panic!("expected NotFound, got {other:?}"),
    }
    assert!(matches!(find_declaration("fn (", "A"), Err(LocateError::Syntax(_))));
    let e = find_declaration("", "A").unwrap_err().to_string();
    assert!(e.contains("the file has none"), "{e}");
}

/// The structural-singularity checks of `generate` reject exactly the
/// declarations whose accelerations no state determines, and nothing else.
#[test]
fn structurally_singular_declarations_are_rejected_and_regular_ones_are_not() {
    let generate_str = |src: &str| crate::generate(&parse_str(src).expect("parses")).map(|_| ());
    let message = |src: &str| generate_str(src).expect_err("must be rejected").message;
    // Regular: two independent constraints (the robot), M = N.
    for ok in [
        "struct R { coordinates: [x, y, th, ph], lagrangian: (dot(x)^2 + dot(y)^2 + dot(th)^2 + dot(ph)^2)/2,
           constraints: [ dot(x) - cos(th)*dot(ph), dot(y) - sin(th)*dot(ph) ] }",
        "struct Q { coordinates: [x, y], lagrangian: (dot(x)^2 + dot(y)^2)/2,
           constraints: [ dot(x) - y, dot(y) + x ] }",
    ] {
        assert!(generate_str(ok).is_ok(), "{ok}: {:?}", generate_str(ok).err().map(|e| e.message));
    }
    assert!(message("struct A { coordinates: [x, th], lagrangian: dot(x)^2/2 - th^2 }")
        .contains("`th` of `A` has no inertia"));
    assert!(message("struct B { coordinates: [x, y], lagrangian: dot(x)^2/2 + x*dot(y) }")
        .contains("at most linear in `dot(y)`"));
    assert!(message("struct C { coordinates: [x], lagrangian: dot(x)^2/2, constraints: [ dot(x), dot(x) - x ] }")
        .contains("2 constraints on 1 coordinates"));
    // ∇²_vv L ≡ 0: every velocity is in a constraint, but the momenta do not
    // depend on the velocities (the runtime's Newton matrix is singular).
    let (msg, at) = generate_error(
        "struct E { coordinates: [x, y], lagrangian: -(x^2 + y^2)/2, constraints: [dot(x) - y*dot(y)] }",
    );
    assert!(msg.contains("the Lagrangian of `E` has no velocity term") && msg.contains("is identically 0"), "{msg}");
    assert_eq!(at, "-");
    let (msg, _) = generate_error(
        "struct E { coordinates: [x, y], lagrangian: y*dot(x) - x^2/2, constraints: [dot(x) - 1, dot(y) - x] }",
    );
    assert!(msg.contains("at most linear in the velocities") && msg.contains("regular Lagrangian"), "{msg}");
    let (msg, _) = generate_error("struct E { coordinates: [x], lagrangian: -x^2/2, constraints: [dot(x) - cos(t)] }");
    assert!(msg.contains("has no velocity term"), "{msg}");
    // Fewer velocities with inertia than N − M: the columns [∇²_vv L; K] of
    // v₁ have rank at most 1 + 1 < 3.
    let (msg, at) = generate_error(
        "struct G { coordinates: [x, y, z], lagrangian: dot(x)^2/2 - z^2, constraints: [dot(y) - x*dot(z)] }",
    );
    assert!(msg.contains("involves only `dot(x)`") && msg.contains("the 2 coordinates `y`, `z`"), "{msg}");
    assert_eq!(at, "dot(x)");
    // A coordinate without inertia whose velocity a constraint fixes: the
    // saddle-point matrix is regular, but Gauss's momentum rows of `s` are
    // dependent (exactly for `p_s` constant or linear in `q`), so its steps
    // fail with a singular Newton matrix or return a wrong step as solved.
    let (msg, at) =
        generate_error("struct F { coordinates: [x, s], lagrangian: dot(x)^2/2, constraints: [ dot(s) - x*dot(x) ] }");
    assert!(msg.contains("`s` of `F` has no inertia: `dot(s)` appears only in constraints"), "{msg}");
    assert!(msg.contains("A constraint fixes the velocity of `s` but not the step"), "{msg}");
    assert_eq!(at, "s");
    let (msg, at) = generate_error(
        "struct C { coordinates: [x, y, w], lagrangian: (dot(x)^2 + dot(y)^2)/2 + x*dot(w) - w^2/2,
           constraints: [ dot(w) - y*dot(x) ] }",
    );
    assert!(msg.contains("`w` of `C` has no inertia: the Lagrangian is at most linear in `dot(w)`"), "{msg}");
    assert_eq!(at, "w");
    assert!(message(
        "struct D { coordinates: [x, y, z], lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2,
           constraints: [ dot(y) - x*dot(z), sin(x)*dot(y) - x*sin(x)*dot(z) + t ] }"
    )
    .contains("proportional"));
}

/// Parses and generates a declaration that must fail; returns (message,
/// text under the span).
fn generate_error(src: &str) -> (String, String) {
    let tokens = src.parse::<TokenStream>().expect("test source must lex");
    let result = match crate::scenes::parse_with_scenes(&tokens) {
        Ok(Some((base, specs))) => specs.iter().try_for_each(|s| crate::generate(s).map(|_| ())).map(|()| base),
        Ok(None) => parse(tokens).and_then(|s| crate::generate(&s).map(|_| s)),
        Err(e) => Err(e),
    };
    match result {
        Ok(_) => panic!("expected an error for:\n{src}"),
        Err(e) => (e.message.clone(), text_at(src, e.span)),
    }
}

/// A `/` whose denominator simplifies to the constant 0 is an error at that
/// `/` wherever it is written, even where the quotient is used in a way that
/// is finite again (`1/(1/0)`) or never used (a constant, an effect no scene
/// selects).
#[test]
fn divisions_by_a_denominator_that_simplifies_to_zero_are_errors_at_the_slash() {
    let base = "coordinates: [x, y], parameters: { m = 1 }, lagrangian: m/2*(dot(x)^2 + dot(y)^2)";
    for src in [
        "struct A { coordinates: [x], parameters: { m = 1 }, lagrangian: m/(2 - 2)*dot(x)^2 }".to_string(),
        "struct A { coordinates: [x], lagrangian: dot(x)^2/(x - x) }".to_string(),
        "struct A { coordinates: [x], constants: { zero = 0 }, lagrangian: dot(x)^2/zero }".to_string(),
        "struct A { coordinates: [x], constants: { c = 2/(1 - 1) }, lagrangian: dot(x)^2 }".to_string(),
        "struct A { coordinates: [x], parameters: { m = 1/(1/0) }, lagrangian: dot(x)^2 }".to_string(),
        format!("struct A {{ {base}, constraints: [dot(x) - dot(y)/(m - m)] }}"),
        format!("struct A {{ {base}, forces: {{ x: 1/(y - y) }} }}"),
        format!("struct A {{ {base}, effects: {{ u: potential(x^2/(1 - 1)) }}, scenes: {{ Free = [] }} }}"),
        format!("struct A {{ {base}, effects: {{ r: holonomic(x/(y - y)) }}, scenes: {{ R = [r] }} }}"),
    ] {
        let (msg, at) = generate_error(&src);
        assert!(msg.starts_with("division by zero: the denominator of this `/`"), "{src}: {msg}");
        assert_eq!(at, "/", "{src}: {msg}");
    }
    // Denominators that are not the constant 0 stay accepted.
    assert!(crate::generate(&parse_str("struct A { coordinates: [x], lagrangian: dot(x)^2/(2 - x) }").unwrap()).is_ok());
}

/// A number beyond the range of f64, folded from finite literals
/// (`1e308*1e308`) or made by differentiation (the coefficient
/// `1e300·(1e300 − 1)` of the second derivative of `x^1e300`), is an error
/// at the operator or the expression whose derivatives overflow, from
/// `generate` and `analyze` alike; code generation never sees it (writing
/// `inf` as a literal panics).
#[test]
fn numbers_that_overflow_when_folded_or_differentiated_are_errors() {
    let base = "coordinates: [x, y], parameters: { m = 1 }, lagrangian: m/2*(dot(x)^2 + dot(y)^2)";
    let folded = [
        "struct A { coordinates: [x], lagrangian: dot(x)^2/2 + 1e308*1e308*x }".to_string(),
        "struct A { coordinates: [x], lagrangian: dot(x)^2/2 + 1e308*x*1e308 }".to_string(),
        "struct A { coordinates: [x], lagrangian: dot(x)^2/2 + (1e308 + 1e308)*x }".to_string(),
        format!("struct A {{ {base}, constraints: [1e308*dot(x)*1e308 - dot(y)] }}"),
        format!("struct A {{ {base}, forces: {{ x: 1e200*y*1e200 }} }}"),
    ];
    for src in &folded {
        let (msg, at) = generate_error(src);
        assert!(msg.starts_with("this expression folds to a number beyond the range of f64"), "{src}: {msg}");
        assert!(at == "*" || at == "+", "{src}: {msg} at {at}");
    }
    let differentiated = [
        ("struct A { coordinates: [x], lagrangian: dot(x)^2/2 + x^1e300 }".to_string(), "the Lagrangian", "dot"),
        ("struct A { coordinates: [x], lagrangian: dot(x)^2/2 + x^1e160*dot(x) }".to_string(), "the Lagrangian", "dot"),
        ("struct A { coordinates: [x], lagrangian: (dot(x)^2)^1e200 }".to_string(), "the Lagrangian", "dot"),
        (format!("struct A {{ {base}, constraints: [dot(x)^1e300 - dot(y)] }}"), "constraint 1", "dot"),
        (format!("struct A {{ {base}, forces: {{ x: y^1e300*1e300 }} }}"), "this force", "y"),
    ];
    for (src, what, at_expected) in &differentiated {
        let (msg, at) = generate_error(src);
        assert!(
            msg.starts_with(&format!("differentiating {what} gives a number beyond the range of f64")),
            "{src}: {msg}"
        );
        assert!(at.starts_with(at_expected), "{src}: {msg} at {at}");
        let spec = parse_str(src).unwrap();
        assert!(crate::analyze(&spec).is_err(), "{src}");
    }
    for src in folded.iter().chain(differentiated.iter().map(|d| &d.0)) {
        let out = crate::expand(src.parse().unwrap()).to_string();
        assert!(out.contains("compile_error"), "{src}: {out}");
    }
    // Large but finite coefficients stay accepted.
    for src in [
        "struct A { coordinates: [x], lagrangian: dot(x)^2/2 + x^1e150 }",
        "struct A { coordinates: [x], lagrangian: 1e300*dot(x)^2 + 1e300*x^3 }",
    ] {
        assert!(crate::generate(&parse_str(src).unwrap()).is_ok(), "{src}");
    }
}

/// A constant subexpression that cannot be folded to a finite number is an
/// error at its operator that names the three ways it happens: a function
/// whose value overflows f64 (`exp(1000)`, `10^400`), a division by zero, or
/// a function outside its domain (`ln(-1)`, `(-1)^0.5`).
#[test]
fn constant_subexpressions_that_are_not_finite_name_overflow_and_domain() {
    for (term, at) in [("exp(1000)*x", "exp"), ("cosh(800)*x", "cosh"), ("10^400*x", "^"), ("ln(-1)*x", "ln")] {
        let src = format!("struct A {{ coordinates: [x], lagrangian: dot(x)^2/2 - {term} }}");
        let (msg, text) = generate_error(&src);
        assert!(msg.starts_with("this constant subexpression is not a finite number"), "{src}: {msg}");
        assert!(
            msg.contains("overflows f64") && msg.contains("divides by zero") && msg.contains("outside its domain"),
            "{src}: {msg}"
        );
        assert!(text.starts_with(at), "{src}: {msg} at {text}");
    }
}

/// Expressions over `x`, `y`, `th`, their velocities, `t`, the parameter `m`
/// and numbers at the edges of f64 (huge, tiny, subnormal), with every
/// operator and function.
fn arb_extreme_expr() -> impl Strategy<Value = String> {
    let numbers = ["0", "1", "0.5", "3", "1e9", "1e16", "1e155", "1e200", "1e300", "1e308", "1e-308", "4.9e-324"];
    let leaf = prop_oneof![
        prop::sample::select(vec!["x", "y", "th", "dot(x)", "dot(y)", "dot(th)", "t", "m", "pi"]),
        prop::sample::select(numbers.to_vec()),
    ]
    .prop_map(str::to_string);
    leaf.prop_recursive(5, 48, 2, |inner| {
        prop_oneof![
            (inner.clone(), inner.clone(), prop::sample::select(vec!["+", "-", "*", "/", "^"]))
                .prop_map(|(a, b, o)| format!("({a}) {o} ({b})")),
            inner.clone().prop_map(|a| format!("-({a})")),
            (
                inner.clone(),
                prop::sample::select(vec!["sqrt", "exp", "ln", "sin", "cos", "tan", "atan", "sinh", "tanh"])
            )
                .prop_map(|(a, f)| format!("{f}({a})")),
            (inner.clone(), inner).prop_map(|(a, b)| format!("atan2({a}, {b})")),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    /// Whatever numbers a declaration folds or its derivatives multiply
    /// together, the macro and the analysis Python's `spark.compile` runs
    /// return code or an error, never panic (a number beyond f64 written as
    /// a literal would).
    #[test]
    fn declarations_with_extreme_numbers_never_panic(
        lagrangian in arb_extreme_expr(),
        constraint in arb_extreme_expr(),
        force in arb_extreme_expr(),
        event in arb_extreme_expr(),
    ) {
        let src = format!(
            "struct S {{ coordinates: [x, y, th], parameters: {{ m = 1 }}, \
             lagrangian: m/2*(dot(x)^2 + dot(y)^2 + dot(th)^2) + {lagrangian}, constraints: [{constraint}], \
             forces: {{ y: {force} }}, events: {{ e: rising({event}) }} }}"
        );
        let tokens: TokenStream = src.parse().expect("generated source lexes");
        let _ = crate::expand(tokens.clone());
        if let Ok(spec) = parse(tokens) {
            let _ = crate::analyze(&spec);
        }
    }
}

/// A number times a sum is not distributed where a coefficient would
/// overflow: code generation regroups products (`c·(1e300 − θ)` as a
/// prefix of a longer product), and distributing there would make `inf`.
#[test]
fn regrouped_products_do_not_distribute_into_an_overflow() {
    let src = "struct S { coordinates: [x, y, th], lagrangian: (dot(x)^2 + dot(y)^2 + dot(th)^2)/2, \
               constraints: [atan2(dot(th), 1e9) / atan2(dot(x), (1e300 - th) / dot(y))] }";
    let spec = parse_str(src).unwrap();
    assert!(crate::generate(&spec).is_ok());
    assert!(crate::analyze(&spec).is_ok());
}

/// Messages that name the actual mistake: a missing `,` (between sections,
/// inside a list, between entries), a number written `.5`, and section names
/// including `effects` and `scenes`.
#[test]
fn missing_commas_leading_points_and_section_names_get_their_own_messages() {
    assert_error(
        "struct S { coordinates: [x, y]\n lagrangian: dot(x)^2 }",
        "lagrangian",
        "missing `,` before `lagrangian:`",
    );
    assert_error(
        "struct S { coordinates: [x], lagrangian: dot(x)^2 constraints: [dot(x)] }",
        "constraints",
        "missing `,` before `constraints:`",
    );
    assert_error("struct S { coordinates: [x y], lagrangian: 1 }", "y", "missing `,` between coordinates `x` and `y`");
    assert_error(
        "struct S { coordinates: [x], parameters: { m = 1 g = 2 }, lagrangian: 1 }",
        "g",
        "missing `,` before `g =`",
    );
    assert_error(&with_lag(".5*dot(x)^2"), ".", "write `0.5` instead of `.5`");
    assert_error("struct S { coordinates: [x], parameters: { m = .25 }, lagrangian: 1 }", ".", "write `0.25`");
    let (msg, at) = error("struct S { coordinates: [x], lagrangian: 1, effect: { } }");
    assert!(msg.contains("did you mean `effects`?") && msg.contains("`scenes`"), "{msg}");
    assert_eq!(at, "effect");
    let e = crate::scenes::parse_with_scenes(
        &"struct S { coordinates: [x], lagrangian: dot(x)^2, effects: { u: potential(x^2) } scenes: { U = [u] } }"
            .parse()
            .unwrap(),
    )
    .unwrap_err();
    assert!(e.message.starts_with("missing `,` before `scenes:`"), "{}", e.message);
}

/// A constraint that involves neither coordinates nor velocities is refused
/// without a suggestion that would itself be refused (its time derivative,
/// or a holonomic effect).
#[test]
fn constraints_of_the_time_alone_are_refused_without_a_self_refuting_suggestion() {
    let lag = "coordinates: [x, y], lagrangian: (dot(x)^2 + dot(y)^2)/2";
    let (msg, at) = generate_error(&format!("struct A {{ {lag}, constraints: [sin(t)] }}"));
    assert!(msg.contains("depends only on the time `t`") && msg.contains("remove it"), "{msg}");
    assert!(!msg.contains("cos(t)") && !msg.contains("holonomic(g)"), "{msg}");
    assert_eq!(at, "sin(t)");
    let (msg, _) = generate_error(&format!("struct A {{ {lag}, constraints: [x - x + 1] }}"));
    assert!(msg.contains("involves neither the coordinates nor the velocities"), "{msg}");
    for effect in ["constraint(sin(t))", "holonomic(t - 1)"] {
        let (msg, _) =
            generate_error(&format!("struct A {{ {lag}, effects: {{ e: {effect} }}, scenes: {{ E = [e] }} }}"));
        assert!(msg.contains("involves neither the coordinates nor the velocities"), "{effect}: {msg}");
        assert!(!msg.contains("declare it as"), "{effect}: {msg}");
    }
    // A holonomic effect whose coordinates cancel reaches the model check.
    let (msg, _) =
        generate_error(&format!("struct A {{ {lag}, effects: {{ e: holonomic(x - x + t) }}, scenes: {{ E = [e] }} }}"));
    assert!(msg.contains("holonomic constraint g(t) = 0 that involves no coordinate"), "{msg}");
    // A position constraint still gets its velocity-level form.
    let (msg, _) = generate_error(&format!("struct A {{ {lag}, constraints: [x - sin(t)] }}"));
    assert!(msg.contains("write its time derivative instead") && msg.contains("dot(x)"), "{msg}");
}

/// `atan`, `asin`, `acos` are rewritten through `atan2` and keep their arity check.
#[test]
fn inverse_trigonometric_functions_are_atan2_sugar() {
    let s = parse_str("struct A { coordinates: [x], lagrangian: dot(x)^2/2 - atan(x) - asin(x) - acos(x) }").unwrap();
    let text = crate::source::sexpr(&s, &s.lagrangian);
    assert_eq!(text.matches("(atan2 ").count(), 3, "{text}");
    assert!(!text.contains("asin") && !text.contains("acos"), "{text}");
    let e = parse_str("struct A { coordinates: [x], lagrangian: dot(x)^2/2 - asin(x, 1) }").unwrap_err();
    assert_eq!(e.message, "`asin` takes 1 argument: `asin(x)`, found 2");
    let e = parse_str("struct A { coordinates: [x], lagrangian: dot(x)^2/2 - abs(x) }").unwrap_err();
    assert!(e.message.contains("sqrt(x^2 + eps^2)"), "{}", e.message);
}

/// A declaration with `n` coordinates `x1..xn`, `L = ½Σ dot(x_i)²`.
fn with_coordinates(n: usize) -> String {
    let names: Vec<String> = (1..=n).map(|i| format!("x{i}")).collect();
    let kinetic: Vec<String> = names.iter().map(|x| format!("dot({x})^2")).collect();
    format!("struct Big {{ coordinates: [{}], lagrangian: ({})/2 }}", names.join(", "), kinetic.join(" + "))
}

#[test]
fn more_coordinates_than_supported_are_refused_at_the_list() {
    let n = MAX_COORDINATES + 1;
    let src = with_coordinates(n);
    let (msg, text) = error(&src);
    assert!(msg.contains(&format!("{n} coordinates")) && msg.contains(&format!("at most {MAX_COORDINATES}")), "{msg}");
    assert!(text.starts_with("[x1, x2"), "span of `{msg}`: {text}");
    // 3000 coordinates (which would take minutes to differentiate) are refused just as fast, and through
    // the path the macro takes (effects and scenes included).
    let start = std::time::Instant::now();
    let e = parse_declaration(with_coordinates(3000).parse().expect("lexes")).map(|_| ()).unwrap_err();
    assert!(e.message.contains("3000 coordinates"), "{}", e.message);
    assert!(start.elapsed().as_secs_f64() < 5.0, "{:?}", start.elapsed());
    // The limit itself is accepted.
    assert_eq!(parse_str(&with_coordinates(MAX_COORDINATES)).expect("parses").coordinates.len(), MAX_COORDINATES);
}

#[test]
fn a_name_of_millions_of_characters_is_quoted_as_an_excerpt() {
    // An unknown name of 10⁷ characters filled the message (and the macro's
    // compile error) with it; the message shows its first characters and
    // its length.
    let long = format!("b{}", "a".repeat(9_999_999));
    let e = parse_str(&with_lag(&format!("dot(x)^2 + {long}"))).expect_err("an unknown name");
    let shown = e.shown_message();
    assert!(shown.len() < 400, "{} bytes: {}", shown.len(), &shown[..400]);
    assert!(shown.contains(&format!("`b{}… (10000000 characters)`", "a".repeat(39))), "{shown}");
    assert!(e.to_compile_error().to_string().len() < 600);
    // Ordinary names, and a word of exactly the limit, are quoted whole.
    let e = parse_str(&with_lag("dot(x)^2 + zeta")).expect_err("an unknown name");
    assert_eq!(e.shown_message(), e.message);
    let limit = "c".repeat(crate::spec::MAX_QUOTED_WORD);
    assert_eq!(crate::spec::bound_long_words(&format!("`{limit}` ü")), format!("`{limit}` ü"));
    // Letters beyond ASCII are counted and cut as characters.
    let wide = "é".repeat(100);
    assert_eq!(
        crate::spec::bound_long_words(&format!("name `{wide}`, again {wide}")),
        format!("name `{e}… (100 characters)`, again {e}… (100 characters)", e = "é".repeat(40))
    );
}
