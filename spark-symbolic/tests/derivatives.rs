//! Property tests: random expression trees over every operator and function,
//! lowered into the graph (so simplified on construction), differentiated
//! symbolically, and compared with forward-mode hyper-dual numbers.

use num_dual::{DualNum, HyperDual64};
use proptest::prelude::*;
use spark_symbolic::diff::Differentiator;
use spark_symbolic::emit::{emit, Inputs, Target};
use spark_symbolic::graph::{Fun, Graph, NodeId, Var};

/// A random expression over three variables. Domains are kept valid by
/// construction: `ln`, `sqrt`, real powers, divisors and negative integer
/// powers take `a² + c` with `c > 0`; `exp`, `sinh`, `cosh` and `tan` take
/// `sin(a)` (bounded, and away from tan's poles).
#[derive(Clone, Debug)]
enum E {
    X(usize),
    C(f64),
    Add(Box<E>, Box<E>),
    Sub(Box<E>, Box<E>),
    Mul(Box<E>, Box<E>),
    Div(Box<E>, Box<E>),
    Neg(Box<E>),
    PowI(Box<E>, i32),
    PowR(Box<E>, f64),
    Sqrt(Box<E>),
    Exp(Box<E>),
    Ln(Box<E>),
    Sin(Box<E>),
    Cos(Box<E>),
    Tan(Box<E>),
    Sinh(Box<E>),
    Cosh(Box<E>),
    Tanh(Box<E>),
    Atan2(Box<E>, Box<E>, bool),
}

fn positive<D: DualNum<f64> + Copy>(a: D) -> D {
    a * a + D::from(0.5)
}

fn eval<D: DualNum<f64> + Copy>(e: &E, x: &[D; 3]) -> D {
    match e {
        E::X(i) => x[*i],
        E::C(c) => D::from(*c),
        E::Add(a, b) => eval(a, x) + eval(b, x),
        E::Sub(a, b) => eval(a, x) - eval(b, x),
        E::Mul(a, b) => eval(a, x) * eval(b, x),
        E::Div(a, b) => eval(a, x) / positive(eval(b, x)),
        E::Neg(a) => -eval(a, x),
        E::PowI(a, k) => {
            let a = eval(a, x);
            if *k < 0 {
                positive(a).powi(*k)
            } else {
                a.powi(*k)
            }
        }
        E::PowR(a, r) => positive(eval(a, x)).powf(*r),
        E::Sqrt(a) => positive(eval(a, x)).sqrt(),
        E::Exp(a) => eval(a, x).sin().exp(),
        E::Ln(a) => positive(eval(a, x)).ln(),
        E::Sin(a) => eval(a, x).sin(),
        E::Cos(a) => eval(a, x).cos(),
        E::Tan(a) => eval(a, x).sin().tan(),
        E::Sinh(a) => eval(a, x).sin().sinh(),
        E::Cosh(a) => eval(a, x).sin().cosh(),
        E::Tanh(a) => tanh_reference(eval(a, x)),
        E::Atan2(a, b, s) => {
            let d = positive(eval(b, x));
            // The engine does not distinguish −0 from +0 (it folds `−0` to
            // `0`), which only matters on atan2's branch cut: compare there
            // with the +0 convention.
            (eval(a, x) + D::from(0.0)).atan2(if *s { d } else { -d })
        }
    }
}

fn lower(g: &mut Graph, e: &E) -> NodeId {
    let pos = |g: &mut Graph, a: NodeId| {
        let a2 = g.powc(a, 2.0);
        let h = g.constant(0.5);
        g.add(&[a2, h])
    };
    match e {
        E::X(i) => g.var(Var::Q(*i as u32)),
        E::C(c) => g.constant(*c),
        E::Add(a, b) => {
            let (a, b) = (lower(g, a), lower(g, b));
            g.add2(a, b)
        }
        E::Sub(a, b) => {
            let (a, b) = (lower(g, a), lower(g, b));
            g.sub(a, b)
        }
        E::Mul(a, b) => {
            let (a, b) = (lower(g, a), lower(g, b));
            g.mul2(a, b)
        }
        E::Div(a, b) => {
            let (a, b) = (lower(g, a), lower(g, b));
            let b = pos(g, b);
            g.div(a, b)
        }
        E::Neg(a) => {
            let a = lower(g, a);
            g.neg(a)
        }
        E::PowI(a, k) => {
            let mut a = lower(g, a);
            if *k < 0 {
                a = pos(g, a);
            }
            g.powc(a, *k as f64)
        }
        E::PowR(a, r) => {
            let a = lower(g, a);
            let a = pos(g, a);
            g.powc(a, *r)
        }
        E::Sqrt(a) => {
            let a = lower(g, a);
            let a = pos(g, a);
            g.sqrt(a)
        }
        E::Ln(a) => {
            let a = lower(g, a);
            let a = pos(g, a);
            g.call(Fun::Ln, &[a])
        }
        E::Exp(a) | E::Tan(a) | E::Sinh(a) | E::Cosh(a) => {
            let a = lower(g, a);
            let s = g.call(Fun::Sin, &[a]);
            let f = match e {
                E::Exp(_) => Fun::Exp,
                E::Tan(_) => Fun::Tan,
                E::Sinh(_) => Fun::Sinh,
                _ => Fun::Cosh,
            };
            g.call(f, &[s])
        }
        E::Sin(a) | E::Cos(a) | E::Tanh(a) => {
            let a = lower(g, a);
            let f = match e {
                E::Sin(_) => Fun::Sin,
                E::Cos(_) => Fun::Cos,
                _ => Fun::Tanh,
            };
            g.call(f, &[a])
        }
        E::Atan2(a, b, s) => {
            let a = lower(g, a);
            let b = lower(g, b);
            let mut d = pos(g, b);
            if !*s {
                d = g.neg(d);
            }
            g.call(Fun::Atan2, &[a, d])
        }
    }
}

/// `tanh` for the reference, as `±(1 − 2/(e^{2|u|} + 1))`: its derivative
/// parts come from `2/(e^{2|u|} + 1)` alone and keep their digits where
/// `tanh(u)` rounds to ±1, unlike a derivative `1 − tanh²` (which loses
/// every digit of `sech² u` there).
fn tanh_reference<D: DualNum<f64> + Copy>(u: D) -> D {
    let one = D::from(1.0);
    let two = D::from(2.0);
    if u.re() >= 0.0 {
        one - two / ((u * two).exp() + one)
    } else {
        -(one - two / ((-u * two).exp() + one))
    }
}

/// The largest `|u|` over the `tanh(u)` the expression evaluates at `x`.
/// Beyond 300, `e^{2|u|}` overflows in [`tanh_reference`] (the derivative
/// parts become NaN), so such points have no reference.
fn largest_tanh_argument(e: &E, x: &[f64; 3]) -> f64 {
    let here = match e {
        E::Tanh(a) => eval(a, x).abs(),
        _ => 0.0,
    };
    let children: Vec<&E> = match e {
        E::X(_) | E::C(_) => Vec::new(),
        E::Add(a, b) | E::Sub(a, b) | E::Mul(a, b) | E::Div(a, b) | E::Atan2(a, b, _) => vec![a, b],
        E::Neg(a)
        | E::PowI(a, _)
        | E::PowR(a, _)
        | E::Sqrt(a)
        | E::Exp(a)
        | E::Ln(a)
        | E::Sin(a)
        | E::Cos(a)
        | E::Tan(a)
        | E::Sinh(a)
        | E::Cosh(a)
        | E::Tanh(a) => vec![a],
    };
    children.into_iter().map(|c| largest_tanh_argument(c, x)).fold(here, f64::max)
}

fn arb_expr() -> impl Strategy<Value = E> {
    let leaf = prop_oneof![
        3 => (0usize..3).prop_map(E::X),
        1 => prop_oneof![Just(0.0), Just(1.0), Just(-1.0), Just(2.0), -3.0..3.0f64].prop_map(E::C),
    ];
    leaf.prop_recursive(5, 40, 2, |inner| {
        let b = |e: E| Box::new(e);
        prop_oneof![
            (inner.clone(), inner.clone()).prop_map(move |(x, y)| E::Add(b(x), b(y))),
            (inner.clone(), inner.clone()).prop_map(move |(x, y)| E::Sub(b(x), b(y))),
            (inner.clone(), inner.clone()).prop_map(move |(x, y)| E::Mul(b(x), b(y))),
            (inner.clone(), inner.clone()).prop_map(move |(x, y)| E::Div(b(x), b(y))),
            inner.clone().prop_map(move |x| E::Neg(b(x))),
            (inner.clone(), -3i32..5).prop_map(move |(x, k)| E::PowI(b(x), k)),
            (inner.clone(), prop_oneof![Just(0.5), Just(-0.5), Just(1.5), Just(-1.5), -2.0..2.5f64])
                .prop_map(move |(x, r)| E::PowR(b(x), r)),
            inner.clone().prop_map(move |x| E::Sqrt(b(x))),
            inner.clone().prop_map(move |x| E::Exp(b(x))),
            inner.clone().prop_map(move |x| E::Ln(b(x))),
            inner.clone().prop_map(move |x| E::Sin(b(x))),
            inner.clone().prop_map(move |x| E::Cos(b(x))),
            inner.clone().prop_map(move |x| E::Tan(b(x))),
            inner.clone().prop_map(move |x| E::Sinh(b(x))),
            inner.clone().prop_map(move |x| E::Cosh(b(x))),
            inner.clone().prop_map(move |x| E::Tanh(b(x))),
            (inner.clone(), inner, any::<bool>()).prop_map(move |(x, y, s)| E::Atan2(b(x), b(y), s)),
        ]
    })
}

/// `|a − b| ≤ tol · max(1, |b|)`: relative, with an absolute floor at 1 so
/// that values near zero (cancellation) are compared on their natural scale.
fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * b.abs().max(1.0) || (a.is_nan() && b.is_nan())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn first_and_second_derivatives_match_hyperdual(e in arb_expr(), x in prop::array::uniform3(-1.5..1.5f64)) {
        let mut g = Graph::new();
        let f = lower(&mut g, &e);
        let env = |v: Var| match v { Var::Q(i) => x[i as usize], _ => f64::NAN };
        let mut d = Differentiator::new();
        // Value: simplification preserves it.
        let reference = eval(&e, &x);
        prop_assume!(reference.is_finite() && reference.abs() < 1e8);
        prop_assume!(largest_tanh_argument(&e, &x) < 300.0);
        let value = g.eval(f, &env);
        prop_assert!(close(value, reference, 1e-12), "value {value} vs {reference} for {e:?}");
        let mut outputs = vec![f];
        for i in 0..3 {
            for j in 0..3 {
                let mut xs = [HyperDual64::from(x[0]), HyperDual64::from(x[1]), HyperDual64::from(x[2])];
                xs[i].eps1 = 1.0;
                xs[j].eps2 = 1.0;
                let r = eval(&e, &xs);
                // The reference's own rounding noise: the same derivatives a few
                // ulps away. Where cancellation makes it larger than the
                // tolerance (compositions like exp(sin(√(exp(sin x)⁴)))), no
                // evaluation order can agree more closely than it.
                let mut nudged = xs;
                for v in &mut nudged {
                    v.re += 4.0 * f64::EPSILON * v.re.abs().max(1.0);
                }
                let rn = eval(&e, &nudged);
                let noise = |a: f64, b: f64| 10.0 * (a - b).abs() / b.abs().max(1.0);
                let (tol_i, tol_ij) = (1e-12 + noise(rn.eps1, r.eps1), 1e-12 + noise(rn.eps1eps2, r.eps1eps2));
                let di = d.diff(&mut g, f, Var::Q(i as u32));
                let dij = d.diff(&mut g, di, Var::Q(j as u32));
                let (gi, gij) = (g.eval(di, &env), g.eval(dij, &env));
                prop_assert!(close(gi, r.eps1, tol_i), "d/dx{i}: {gi} vs {} (tolerance {tol_i:e}) for {e:?}", r.eps1);
                prop_assert!(
                    close(gij, r.eps1eps2, tol_ij),
                    "d2/dx{i}dx{j}: {gij} vs {} (tolerance {tol_ij:e}) for {e:?}",
                    r.eps1eps2
                );
                outputs.extend([di, dij]);
            }
        }
        // The emitted code (one fused body with CSE over the value and all
        // derivatives) computes what the graph computes.
        let targets: Vec<(Target, NodeId)> = outputs
            .iter()
            .enumerate()
            .map(|(k, &n)| (Target::Store(proc_macro2::Ident::new("out", proc_macro2::Span::call_site()), k, None), n))
            .collect();
        let runtime = quote::quote!(::spark_runtime);
        let emitted = emit(&mut g, &targets, &Inputs { parameters: &[], runtime: &runtime, sin_cos_memo: None });
        let values = emitted.evaluate(&env);
        for (k, &n) in outputs.iter().enumerate() {
            let want = g.eval(n, &env);
            prop_assert!(close(values[k], want, 1e-12), "emitted output {k}: {} vs {want} for {e:?}", values[k]);
        }
    }
}
