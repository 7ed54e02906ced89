//! Numeric evaluation of constant expressions (constant values and
//! parameter defaults), so that a default such as `pi/2` becomes an `f64`
//! and a constant such as `ln(0)` or a division by zero is rejected where it
//! is written.

use crate::spec::{BinOp, Func, SpecError, SrcExpr};

/// Evaluates a constant expression; `constants` holds the values of the
/// constants it may refer to. Names that are not constant are an error (the
/// parser has already rejected them, so this only guards against misuse).
pub(crate) fn eval(expr: &SrcExpr, constants: &[f64]) -> Result<f64, SpecError> {
    let bad = |span, what: &str| Err(SpecError { span, message: format!("{what} is not a constant number") });
    Ok(match expr {
        SrcExpr::Num(v, _) => *v,
        SrcExpr::Pi(_) => std::f64::consts::PI,
        SrcExpr::Const(i, span) => match constants.get(*i) {
            Some(v) => *v,
            None => return bad(*span, "a constant declared later"),
        },
        SrcExpr::Time(s) => return bad(*s, "the time `t`"),
        SrcExpr::Coord(_, s) => return bad(*s, "a coordinate"),
        SrcExpr::Velocity(_, s) => return bad(*s, "a velocity"),
        SrcExpr::Param(_, s) => return bad(*s, "a parameter"),
        SrcExpr::Multiplier(_, s) => return bad(*s, "a multiplier"),
        SrcExpr::Neg(a, _) => -eval(a, constants)?,
        SrcExpr::Binary(op, a, b, span) => {
            let (a, b) = (eval(a, constants)?, eval(b, constants)?);
            match op {
                BinOp::Add => a + b,
                BinOp::Sub => a - b,
                BinOp::Mul => a * b,
                // Caught here even where the quotient is used in a way that
                // gives a finite value again (`1/(1/0) = 0`).
                BinOp::Div if b == 0.0 => {
                    return Err(SpecError { span: *span, message: crate::lower::DIVISION_BY_ZERO.into() })
                }
                BinOp::Div => a / b,
                BinOp::Pow => a.powf(b),
            }
        }
        SrcExpr::Call(f, args, span) => {
            let mut vals = [0.0; 2];
            for (slot, a) in vals.iter_mut().zip(args) {
                *slot = eval(a, constants)?;
            }
            if args.len() != f.arity() {
                return Err(SpecError {
                    span: *span,
                    message: format!("`{}` has the wrong number of arguments", f.name()),
                });
            }
            let x = vals[0];
            match f {
                Func::Sqrt => x.sqrt(),
                Func::Exp => x.exp(),
                Func::Ln => x.ln(),
                Func::Sin => x.sin(),
                Func::Cos => x.cos(),
                Func::Tan => x.tan(),
                Func::Sinh => x.sinh(),
                Func::Cosh => x.cosh(),
                Func::Tanh => x.tanh(),
                Func::Atan2 => x.atan2(vals[1]),
            }
        }
    })
}
