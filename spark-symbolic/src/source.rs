//! The neutral S-expression text of the user's source expressions (see
//! `spark_runtime::SystemSource`): named constants replaced by their
//! values, numbers printed so that they parse back to the same `f64`. A constraint row the
//! model forms itself (the `k = g_t + g_q·v` of a holonomic constraint) is
//! printed from the graph in the same grammar.

use crate::graph::{Graph, Node, NodeId, Var};
use crate::model::Model;
use crate::spec::{BinOp, SrcExpr, SystemSpec};

/// The text of each constraint row `k_j`: as written, or for a holonomic
/// row the `k` the model formed.
pub fn constraint_sexprs(spec: &SystemSpec, model: &Model) -> Vec<String> {
    spec.constraints
        .iter()
        .zip(&model.constraint)
        .map(|(c, &k)| if c.holonomic { node_sexpr(&model.graph, spec, k) } else { sexpr(spec, &c.expr) })
        .collect()
}

/// The text of each holonomic `g_j` ("0" for a row written at velocity
/// level); empty when no row is holonomic.
pub fn holonomic_sexprs(spec: &SystemSpec) -> Vec<String> {
    if !spec.constraints.iter().any(|c| c.holonomic) {
        return Vec::new();
    }
    spec.constraints.iter().map(|c| if c.holonomic { sexpr(spec, &c.expr) } else { "0".to_string() }).collect()
}

/// Prints one graph node as a prefix S-expression (`+` and `*` n-ary).
pub fn node_sexpr(g: &Graph, spec: &SystemSpec, id: NodeId) -> String {
    let mut out = String::new();
    write_node(g, spec, id, &mut out, 0);
    out
}

fn write_node(g: &Graph, spec: &SystemSpec, id: NodeId, out: &mut String, depth: usize) {
    if depth > 2_000 {
        out.push_str("nan");
        return;
    }
    let coordinate = |i: u32| spec.coordinates.get(i as usize).map_or("?", |c| c.name.as_str());
    let form = |head: &str, args: &[NodeId], out: &mut String| {
        out.push('(');
        out.push_str(head);
        for &a in args {
            out.push(' ');
            write_node(g, spec, a, out, depth + 1);
        }
        out.push(')');
    };
    match g.node(id) {
        Node::Const(_) => number(g.as_const(id).unwrap_or(f64::NAN), out),
        Node::Var(Var::Time) => out.push('t'),
        Node::Var(Var::Q(i)) => out.push_str(&format!("(q {})", coordinate(*i))),
        Node::Var(Var::V(i)) => out.push_str(&format!("(v {})", coordinate(*i))),
        Node::Var(Var::P(i)) => {
            out.push_str(&format!("(p {})", spec.parameters.get(*i as usize).map_or("?", |p| p.name.name.as_str())))
        }
        Node::Var(Var::Psi(j)) => out.push_str(&format!("(psi {j})")),
        Node::Add(xs) => form("+", xs, out),
        Node::Mul(xs) => form("*", xs, out),
        Node::Pow(b, e) => form("^", &[*b, *e], out),
        Node::Call(f, xs) => form(f.method(), xs, out),
    }
}

/// Prints one source expression as a prefix S-expression.
pub fn sexpr(spec: &SystemSpec, e: &SrcExpr) -> String {
    let mut out = String::new();
    write(spec, e, &mut Vec::new(), &mut out, 0);
    out
}

/// The value of constant `i`, evaluating the constants up to `i` into
/// `values` (in order: each refers only to earlier ones) on first use. The
/// parser has checked that every constant evaluates to a finite number.
fn constant_value(spec: &SystemSpec, i: usize, values: &mut Vec<f64>) -> f64 {
    while values.len() <= i {
        let Some(c) = spec.constants.get(values.len()) else { return f64::NAN };
        let v = crate::dsl::eval_constant(&c.value, values).unwrap_or(f64::NAN);
        values.push(v);
    }
    values[i]
}

fn op_name(op: BinOp) -> &'static str {
    match op {
        BinOp::Add => "+",
        BinOp::Sub => "-",
        BinOp::Mul => "*",
        BinOp::Div => "/",
        BinOp::Pow => "^",
    }
}

fn number(x: f64, out: &mut String) {
    // `{:?}` of an f64 is the shortest text that round-trips.
    out.push_str(&format!("{x:?}"));
}

fn write(spec: &SystemSpec, e: &SrcExpr, constants: &mut Vec<f64>, out: &mut String, depth: usize) {
    if depth > 2_000 {
        out.push_str("nan");
        return;
    }
    let named = |kind: &str, list: &[&str], i: usize, out: &mut String| {
        out.push_str(&format!("({kind} {})", list.get(i).copied().unwrap_or("?")));
    };
    match e {
        SrcExpr::Num(x, _) => number(*x, out),
        SrcExpr::Time(_) => out.push('t'),
        SrcExpr::Pi(_) => out.push_str("pi"),
        SrcExpr::Coord(i, _) | SrcExpr::Velocity(i, _) => {
            let names: Vec<&str> = spec.coordinates.iter().map(|c| c.name.as_str()).collect();
            named(if matches!(e, SrcExpr::Coord(..)) { "q" } else { "v" }, &names, *i, out)
        }
        SrcExpr::Param(i, _) => {
            let names: Vec<&str> = spec.parameters.iter().map(|p| p.name.name.as_str()).collect();
            named("p", &names, *i, out)
        }
        SrcExpr::Multiplier(j, _) => out.push_str(&format!("(psi {j})")),
        // A named constant is its value: its expression written out in
        // place would make the text grow exponentially along a chain such
        // as `c1 = c0*c0, c2 = c1*c1, …` (2^40 copies of `c0` for 40 links).
        SrcExpr::Const(i, _) => number(constant_value(spec, *i, constants), out),
        SrcExpr::Neg(a, _) => {
            out.push_str("(neg ");
            write(spec, a, constants, out, depth + 1);
            out.push(')');
        }
        SrcExpr::Binary(op, a, b, _) => {
            let name = op_name(*op);
            // A left-nested chain `a + b − c …` prints as nested binary
            // forms `(- (+ a b) c)`, written iteratively so that long sums
            // are not deep recursion.
            let mut chain = vec![(name, &**b)];
            let mut left = &**a;
            while let SrcExpr::Binary(o, a2, b2, _) = left {
                if *o == BinOp::Pow {
                    break;
                }
                chain.push((op_name(*o), &**b2));
                left = a2;
            }
            for (name, _) in chain.iter() {
                out.push('(');
                out.push_str(name);
                out.push(' ');
            }
            write(spec, left, constants, out, depth + 1);
            for (_, b) in chain.iter().rev() {
                out.push(' ');
                write(spec, b, constants, out, depth + 1);
                out.push(')');
            }
        }
        SrcExpr::Call(f, args, _) => {
            out.push('(');
            out.push_str(f.name());
            for a in args {
                out.push(' ');
                write(spec, a, constants, out, depth + 1);
            }
            out.push(')');
        }
    }
}
