//! Simplification and emission as a reader sees them: the rendered Rust of
//! small expressions, common-subexpression sharing and operation counts.

use proc_macro2::{Ident, Span};
use spark_symbolic::emit::{emit, Inputs, Target};
use spark_symbolic::graph::{Fun, Graph, Node, NodeId, Var};

fn x(g: &mut Graph) -> NodeId {
    g.var(Var::Q(0))
}
fn y(g: &mut Graph) -> NodeId {
    g.var(Var::Q(1))
}

/// Renders outputs `r0, r1, …` and returns (code without spaces, ops).
fn render(g: &mut Graph, outs: &[NodeId]) -> (String, usize) {
    let params = [Ident::new("m", Span::call_site()), Ident::new("g", Span::call_site())];
    let targets: Vec<(Target, NodeId)> = outs
        .iter()
        .enumerate()
        .map(|(i, &n)| (Target::Let(Ident::new(&format!("r{i}"), Span::call_site())), n))
        .collect();
    let runtime = quote::quote!(::spark_runtime);
    let e = emit(g, &targets, &Inputs { parameters: &params, runtime: &runtime, sin_cos_memo: None });
    let code: String = e.statements.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(" ");
    (code.chars().filter(|c| !c.is_whitespace()).collect(), e.ops)
}

fn one(g: &mut Graph, n: NodeId) -> String {
    render(g, &[n]).0
}

#[test]
fn like_terms_neutral_and_absorbing_elements() {
    let mut g = Graph::new();
    let (a, b) = (x(&mut g), y(&mut g));
    let two_a = g.scale(2.0, a);
    let three_a = g.scale(3.0, a);
    let s = g.add2(two_a, three_a);
    assert_eq!(one(&mut g, s), "letr0:f64=5.0*q[0];");
    let d = g.sub(a, a);
    assert!(g.is_const(d, 0.0));
    let zero = g.constant(0.0);
    let one_ = g.constant(1.0);
    assert_eq!(g.add2(a, zero), a);
    assert_eq!(g.mul2(a, one_), a);
    assert!(g.is_const(g.clone().mul2(a, zero), 0.0));
    assert_eq!(g.pow(a, one_), a);
    assert!(g.is_const(g.clone().pow(a, zero), 1.0));
    let na = g.neg(a);
    assert_eq!(g.neg(na), a, "-(-x) = x");
    // x + y − x = y; 2(x + y) − 2y = 2x.
    let s = g.add(&[a, b, na]);
    assert_eq!(s, b);
    let xy = g.add2(a, b);
    let t = g.scale(2.0, xy);
    let two_b = g.scale(2.0, b);
    let u = g.sub(t, two_b);
    assert_eq!(u, two_a);
}

#[test]
fn powers_merge_and_render_as_multiplications() {
    let mut g = Graph::new();
    let a = x(&mut g);
    let sq = g.mul2(a, a);
    let two = g.constant(2.0);
    assert_eq!(*g.node(sq), Node::Pow(a, two), "x·x = x²");
    assert_eq!(one(&mut g, sq), "letr0:f64=q[0]*q[0];");
    let x3 = g.powc(a, 3.0);
    let x5 = g.mul2(sq, x3);
    assert_eq!(x5, g.clone().powc(a, 5.0), "x²·x³ = x⁵");
    let x6 = g.powc(sq, 3.0);
    assert_eq!(x6, g.clone().powc(a, 6.0), "(x²)³ = x⁶");
    let r = g.sqrt(a);
    let r2 = g.powc(r, 2.0);
    assert_eq!(r2, a, "(√x)² = x");
    assert_eq!(one(&mut g, r), "letr0:f64=q[0].sqrt();");
    let inv = g.powc(a, -1.0);
    assert_eq!(one(&mut g, inv), "letr0:f64=1.0/q[0];");
    let rinv = g.powc(a, -0.5);
    assert_eq!(one(&mut g, rinv), "letr0:f64=1.0/q[0].sqrt();");
    assert_eq!(one(&mut g, x3), "letr0:f64=q[0]*q[0]*q[0];");
    let x4 = g.powc(a, 4.0);
    assert_eq!(render(&mut g, &[x4]), ("lets0=q[0]*q[0];letr0:f64=s0*s0;".to_string(), 2));
    let xr = g.powc(a, 1.7);
    assert_eq!(one(&mut g, xr), "letr0:f64=q[0].powf(1.7);");
}

#[test]
fn subtraction_division_and_constant_folding() {
    let mut g = Graph::new();
    let (a, b) = (x(&mut g), y(&mut g));
    let d = g.sub(a, b);
    assert_eq!(one(&mut g, d), "letr0:f64=q[0]-q[1];");
    let q = g.div(a, b);
    assert_eq!(one(&mut g, q), "letr0:f64=q[0]/q[1];");
    let nb = g.neg(b);
    let e = g.mul2(nb, a);
    assert_eq!(render(&mut g, &[e]), ("letr0:f64=-(q[0]*q[1]);".to_string(), 2));
    let pi = g.constant(std::f64::consts::PI);
    let c = g.call(Fun::Cos, &[pi]);
    assert!(g.is_const(c, -1.0), "cos(π) folds");
    let zero = g.constant(0.0);
    let s = g.call(Fun::Sin, &[zero]);
    assert!(g.is_const(s, 0.0));
    let ex = g.call(Fun::Exp, &[a]);
    assert_eq!(g.call(Fun::Ln, &[ex]), a, "ln(exp x) = x");
    let half = g.constant(0.5);
    let one_ = g.constant(1.0);
    let s = g.add(&[half, a, half]);
    assert_eq!(one(&mut g, s), "letr0:f64=q[0]+1.0;");
    let m = g.sub(a, one_);
    assert_eq!(one(&mut g, m), "letr0:f64=q[0]-1.0;");
}

#[test]
fn shared_subexpressions_are_bound_once_and_parameters_hoisted() {
    let mut g = Graph::new();
    let (a, b) = (x(&mut g), y(&mut g));
    let s = g.call(Fun::Sin, &[a]);
    let o1 = g.mul2(s, b);
    let o2 = g.add2(s, b);
    let (code, ops) = render(&mut g, &[o1, o2]);
    assert_eq!(code, "lets0=::spark_runtime::trig::sin(q[0]);letr0:f64=q[1]*s0;letr1:f64=q[1]+s0;");
    assert_eq!(ops, 3, "sin once, one product, one sum");
    // m·g·x + m·g·y: the parameter product is computed once, first.
    let (m, gg) = (g.var(Var::P(0)), g.var(Var::P(1)));
    let t1 = g.mul(&[m, gg, a]);
    let t2 = g.mul(&[m, gg, b]);
    let (code, ops) = render(&mut g, &[t1, t2]);
    assert_eq!(code, "lets0=self.m*self.g;letr0:f64=s0*q[0];letr1:f64=s0*q[1];");
    assert_eq!(ops, 3);
}

#[test]
fn a_sine_and_cosine_of_one_angle_are_one_call() {
    let mut g = Graph::new();
    let (a, b) = (x(&mut g), y(&mut g));
    // cos x is used first and once, sin x once: both are bound together,
    // where the first of them was, by one call of the runtime's pair.
    let c = g.call(Fun::Cos, &[a]);
    let s = g.call(Fun::Sin, &[a]);
    let o1 = g.mul2(c, b);
    let o2 = g.sub(s, b);
    let (code, ops) = render(&mut g, &[o1, o2]);
    assert_eq!(code, "let(s0,s1)=::spark_runtime::trig::sin_cos(q[0]);letr0:f64=q[1]*s1;letr1:f64=s0-q[1];");
    assert_eq!(ops, 4, "the pair counts as the two calls it replaces");
    // The pair's argument is bound first; a lone sine is the runtime's
    // `trig::sin`.
    let ab = g.add2(a, b);
    let (s, c, lone) = (g.call(Fun::Sin, &[ab]), g.call(Fun::Cos, &[ab]), g.call(Fun::Sin, &[b]));
    let sum = g.add(&[s, c, lone]);
    assert_eq!(
        one(&mut g, sum),
        "lets0=q[0]+q[1];let(s1,s2)=::spark_runtime::trig::sin_cos(s0);letr0:f64=s1+s2+::spark_runtime::trig::sin(q[1]);"
    );
}
