//! The neutral S-expression text of the user's source expressions (see
//! `spark_runtime::SystemSource`): named constants substituted, numbers
//! printed so that they parse back to the same `f64`.

use crate::spec::{BinOp, SrcExpr, SystemSpec};

/// Prints one source expression as a prefix S-expression.
pub fn sexpr(spec: &SystemSpec, e: &SrcExpr) -> String {
    let mut out = String::new();
    write(spec, e, &mut out, 0);
    out
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

fn write(spec: &SystemSpec, e: &SrcExpr, out: &mut String, depth: usize) {
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
        SrcExpr::Const(i, _) => match spec.constants.get(*i) {
            Some(c) => write(spec, &c.value, out, depth + 1),
            None => out.push_str("nan"),
        },
        SrcExpr::Neg(a, _) => {
            out.push_str("(neg ");
            write(spec, a, out, depth + 1);
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
            write(spec, left, out, depth + 1);
            for (_, b) in chain.iter().rev() {
                out.push(' ');
                write(spec, b, out, depth + 1);
                out.push(')');
            }
        }
        SrcExpr::Call(f, args, _) => {
            out.push('(');
            out.push_str(f.name());
            for a in args {
                out.push(' ');
                write(spec, a, out, depth + 1);
            }
            out.push(')');
        }
    }
}
