//! Printing graph nodes back in the DSL's own syntax (`dot(x)`, `^`, named
//! coordinates and parameters), for error messages that suggest what to
//! write, e.g. the velocity-level form of a holonomic constraint.

use crate::graph::{Graph, Node, NodeId, Var};
use crate::spec::SystemSpec;

/// Precedence levels: sum < product < unary minus < power < atom.
const SUM: u8 = 1;
const PRODUCT: u8 = 2;
const UNARY: u8 = 3;
const POWER: u8 = 4;
const ATOM: u8 = 5;

fn number(x: f64) -> String {
    // `{}` prints the shortest decimal that round-trips (`2`, `0.5`).
    format!("{x}")
}

/// Prints `id` as DSL source text.
pub fn dsl_text(g: &Graph, spec: &SystemSpec, id: NodeId) -> String {
    print(g, spec, id, 0).0
}

fn wrap(s: (String, u8), min: u8) -> String {
    if s.1 < min {
        format!("({})", s.0)
    } else {
        s.0
    }
}

fn print(g: &Graph, spec: &SystemSpec, id: NodeId, depth: usize) -> (String, u8) {
    if depth > 200 {
        return ("…".into(), ATOM);
    }
    let coord = |i: u32| spec.coordinates.get(i as usize).map_or("?".to_string(), |c| c.name.clone());
    match g.node(id) {
        Node::Const(_) => {
            let x = g.as_const(id).unwrap_or(f64::NAN);
            if x < 0.0 {
                (format!("-{}", number(-x)), UNARY)
            } else {
                (number(x), ATOM)
            }
        }
        Node::Var(Var::Time) => ("t".into(), ATOM),
        Node::Var(Var::Q(i)) => (coord(*i), ATOM),
        Node::Var(Var::V(i)) => (format!("dot({})", coord(*i)), ATOM),
        Node::Var(Var::P(i)) => {
            (spec.parameters.get(*i as usize).map_or("?".to_string(), |p| p.name.name.clone()), ATOM)
        }
        Node::Var(Var::Psi(j)) => (format!("psi{j}"), ATOM),
        Node::Add(xs) => {
            let mut out = String::new();
            for (k, &x) in xs.iter().enumerate() {
                let (c, rest) = split(g, x);
                let (text, negative) = match c {
                    Some(c) if c < 0.0 => (term(g, spec, -c, rest, depth), true),
                    Some(c) => (term(g, spec, c, rest, depth), false),
                    None => (wrap(print(g, spec, x, depth + 1), SUM + 1), false),
                };
                match (k, negative) {
                    (0, true) => out.push_str(&format!("-{text}")),
                    (0, false) => out.push_str(&text),
                    (_, true) => out.push_str(&format!(" - {text}")),
                    (_, false) => out.push_str(&format!(" + {text}")),
                }
            }
            (out, SUM)
        }
        Node::Mul(xs) => {
            let c = g.as_const(xs[0]);
            let mut factors: Vec<NodeId> = if c.is_some() { xs[1..].to_vec() } else { xs.to_vec() };
            factors.sort_by_key(|&f| (crate::emit::rank(g, f), f));
            let body = factors.iter().map(|&f| wrap(print(g, spec, f, depth + 1), PRODUCT)).collect::<Vec<_>>();
            match c {
                Some(-1.0) => (format!("-{}", body.join("*")), UNARY),
                Some(c) if c < 0.0 => (format!("-{}*{}", number(-c), body.join("*")), UNARY),
                Some(c) => (format!("{}*{}", number(c), body.join("*")), PRODUCT),
                None => (body.join("*"), PRODUCT),
            }
        }
        Node::Pow(b, e) => {
            if g.is_const(*e, 0.5) {
                return (format!("sqrt({})", print(g, spec, *b, depth + 1).0), ATOM);
            }
            let base = wrap(print(g, spec, *b, depth + 1), ATOM);
            let exp = wrap(print(g, spec, *e, depth + 1), POWER);
            (format!("{base}^{exp}"), POWER)
        }
        Node::Call(f, xs) => {
            let args: Vec<String> = xs.iter().map(|&x| print(g, spec, x, depth + 1).0).collect();
            (format!("{}({})", f.method(), args.join(", ")), ATOM)
        }
    }
}

/// The numeric coefficient of a product term, if any.
fn split(g: &Graph, x: NodeId) -> (Option<f64>, NodeId) {
    match g.node(x) {
        Node::Mul(xs) => (g.as_const(xs[0]), x),
        _ => (None, x),
    }
}

/// `c·rest` without its sign, where `rest` is a product whose first factor
/// is the coefficient.
fn term(g: &Graph, spec: &SystemSpec, c: f64, x: NodeId, depth: usize) -> String {
    let Node::Mul(xs) = g.node(x) else {
        return print(g, spec, x, depth + 1).0;
    };
    let mut factors = xs[1..].to_vec();
    factors.sort_by_key(|&f| (crate::emit::rank(g, f), f));
    let body: Vec<String> = factors.iter().map(|&f| wrap(print(g, spec, f, depth + 1), PRODUCT)).collect();
    if c == 1.0 {
        body.join("*")
    } else {
        format!("{}*{}", number(c), body.join("*"))
    }
}
