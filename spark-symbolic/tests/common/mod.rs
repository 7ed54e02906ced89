//! Builders for hand-written `SystemSpec`s and helpers shared by the tests.
#![allow(dead_code)]

use proc_macro2::{Ident, Span, TokenStream};
use spark_symbolic::spec::{BinOp, ConstraintSpec, Func, Named, Parameter, SrcExpr, SystemSpec};

pub fn sp() -> Span {
    Span::call_site()
}
pub fn num(x: f64) -> SrcExpr {
    SrcExpr::Num(x, sp())
}
pub fn q(i: usize) -> SrcExpr {
    SrcExpr::Coord(i, sp())
}
pub fn v(i: usize) -> SrcExpr {
    SrcExpr::Velocity(i, sp())
}
pub fn p(i: usize) -> SrcExpr {
    SrcExpr::Param(i, sp())
}
pub fn t() -> SrcExpr {
    SrcExpr::Time(sp())
}
fn bin(op: BinOp, a: SrcExpr, b: SrcExpr) -> SrcExpr {
    SrcExpr::Binary(op, Box::new(a), Box::new(b), sp())
}
pub fn add(a: SrcExpr, b: SrcExpr) -> SrcExpr {
    bin(BinOp::Add, a, b)
}
pub fn sub(a: SrcExpr, b: SrcExpr) -> SrcExpr {
    bin(BinOp::Sub, a, b)
}
pub fn mul(a: SrcExpr, b: SrcExpr) -> SrcExpr {
    bin(BinOp::Mul, a, b)
}
pub fn div(a: SrcExpr, b: SrcExpr) -> SrcExpr {
    bin(BinOp::Div, a, b)
}
pub fn pow(a: SrcExpr, b: SrcExpr) -> SrcExpr {
    bin(BinOp::Pow, a, b)
}
pub fn sq(a: SrcExpr) -> SrcExpr {
    pow(a, num(2.0))
}
pub fn neg(a: SrcExpr) -> SrcExpr {
    SrcExpr::Neg(Box::new(a), sp())
}
pub fn call(f: Func, args: Vec<SrcExpr>) -> SrcExpr {
    SrcExpr::Call(f, args, sp())
}
pub fn sum(xs: Vec<SrcExpr>) -> SrcExpr {
    xs.into_iter().reduce(add).unwrap_or(num(0.0))
}

/// A declaration with the given names and expressions.
pub fn spec(name: &str, coords: &[&str], params: &[(&str, f64)], l: SrcExpr, ks: Vec<SrcExpr>) -> SystemSpec {
    let named = |s: &str| Named { name: s.to_string(), span: sp() };
    SystemSpec {
        attrs: TokenStream::new(),
        vis: quote::quote!(pub),
        name: Ident::new(name, sp()),
        coordinates: coords.iter().map(|c| named(c)).collect(),
        parameters: params.iter().map(|(n, d)| Parameter { name: named(n), default: *d }).collect(),
        constants: Vec::new(),
        lagrangian: l,
        constraints: ks.into_iter().map(|expr| ConstraintSpec { expr, span: sp(), holonomic: false }).collect(),
        external_force: Vec::new(),
        nonideal_force: Vec::new(),
        events: Vec::new(),
        runtime_path: quote::quote!(::spark_runtime),
    }
}

/// Nonholonomic particle: L = ½|v|² − (q1² + q2²), k = v3 − q2 v1.
pub fn particle() -> SystemSpec {
    let l = sub(mul(num(0.5), sum((0..3).map(|i| sq(v(i))).collect())), add(sq(q(0)), sq(q(1))));
    let k = sub(v(2), mul(q(1), v(0)));
    spec("Particle", &["x", "y", "z"], &[], l, vec![k])
}

/// Skate: L = m/2 (vx² + vy²) + I/2 vθ² + m g x sin β, k = cos θ vy − sin θ vx.
pub fn skate() -> SystemSpec {
    let (m, inertia, g, beta) = (p(0), p(1), p(2), p(3));
    let l = sum(vec![
        mul(div(m.clone(), num(2.0)), add(sq(v(0)), sq(v(1)))),
        mul(div(inertia, num(2.0)), sq(v(2))),
        mul(mul(mul(m, g), q(0)), call(Func::Sin, vec![beta])),
    ]);
    let k = sub(mul(call(Func::Cos, vec![q(2)]), v(1)), mul(call(Func::Sin, vec![q(2)]), v(0)));
    spec(
        "Skate",
        &["x", "y", "theta"],
        &[("m", 1.0), ("inertia", 1.0), ("g", 1.0), ("beta", std::f64::consts::FRAC_PI_2)],
        l,
        vec![k],
    )
}

/// Mobile robot: L = m/2 (v1² + v2²) + I/2 v3² + 3/2 Iw v4² − 10 sin q4,
/// k = (v1 − ℓ cos q3 v4, v2 − ℓ sin q3 v4).
pub fn robot() -> SystemSpec {
    let (m, inertia, iw, ell) = (p(0), p(1), p(2), p(3));
    let l = sum(vec![
        mul(div(m, num(2.0)), add(sq(v(0)), sq(v(1)))),
        mul(div(inertia, num(2.0)), sq(v(2))),
        mul(mul(div(num(3.0), num(2.0)), iw), sq(v(3))),
        neg(mul(num(10.0), call(Func::Sin, vec![q(3)]))),
    ]);
    let k1 = sub(v(0), mul(mul(ell.clone(), call(Func::Cos, vec![q(2)])), v(3)));
    let k2 = sub(v(1), mul(mul(ell, call(Func::Sin, vec![q(2)])), v(3)));
    spec(
        "Robot",
        &["x", "y", "theta", "phi"],
        &[("m", 1.0), ("inertia", 1.0), ("iw", 1.0), ("ell", 1.0)],
        l,
        vec![k1, k2],
    )
}

/// McLachlan–Perlmutter particles (paper §8.4) for odd `n = 2k + 1`, k ≥ 2:
/// L = ½|v|² − ½(|q|² + q_{k+2}² q_{k+3}² + Σ_{i=1..k} q_{1+i}² q_{k+1+i}²),
/// constraint v1 + Σ_{i=k+2..n} q_i v_i.
pub fn mclachlan_perlmutter(n: usize) -> SystemSpec {
    assert!(n >= 5 && n % 2 == 1);
    let k = (n - 1) / 2;
    // 1-based indices as in the paper; q(i-1) is q_i.
    let qq = |i: usize| q(i - 1);
    let vv = |i: usize| v(i - 1);
    let kinetic = mul(num(0.5), sum((1..=n).map(|i| sq(vv(i))).collect()));
    let mut pot = (1..=n).map(|i| sq(qq(i))).collect::<Vec<_>>();
    pot.push(mul(sq(qq(k + 2)), sq(qq(k + 3))));
    for i in 1..=k {
        pot.push(mul(sq(qq(1 + i)), sq(qq(k + 1 + i))));
    }
    let l = sub(kinetic, mul(num(0.5), sum(pot)));
    let mut kk = vec![vv(1)];
    for i in (k + 2)..=n {
        kk.push(mul(qq(i), vv(i)));
    }
    let coords: Vec<String> = (1..=n).map(|i| format!("q{i}")).collect();
    let coords: Vec<&str> = coords.iter().map(|s| s.as_str()).collect();
    spec("McLachlanPerlmutter", &coords, &[], l, vec![sum(kk)])
}

/// Token text with all whitespace removed, for comparing generated code.
pub fn compact(t: &TokenStream) -> String {
    t.to_string().chars().filter(|c| !c.is_whitespace()).collect()
}
