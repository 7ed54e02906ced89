//! Lowering of the parser's [`SrcExpr`] trees into the expression graph:
//! named constants and `pi` are folded at compile time, identifiers become
//! [`Var`]s, `sqrt` becomes a power.

use crate::graph::{Fun, Graph, NodeId, Var};
use crate::simplify::{Partial, PartialProduct, ProductChain, SumChain, KEPT_PARTIAL_PRODUCT, KEPT_PARTIAL_SUM};
use crate::spec::{BinOp, Func, SpecError, SrcExpr, SystemSpec};

/// Lowers source expressions of one declaration, caching its named constants.
pub struct Lowerer<'a> {
    spec: &'a SystemSpec,
    constants: Vec<Option<NodeId>>,
}

fn fun_of(f: Func) -> Option<Fun> {
    Some(match f {
        Func::Sqrt => return None,
        Func::Exp => Fun::Exp,
        Func::Ln => Fun::Ln,
        Func::Sin => Fun::Sin,
        Func::Cos => Fun::Cos,
        Func::Tan => Fun::Tan,
        Func::Sinh => Fun::Sinh,
        Func::Cosh => Fun::Cosh,
        Func::Tanh => Fun::Tanh,
        Func::Atan2 => Fun::Atan2,
    })
}

impl<'a> Lowerer<'a> {
    /// A lowerer for the expressions of `spec`.
    pub fn new(spec: &'a SystemSpec) -> Lowerer<'a> {
        Lowerer { spec, constants: vec![None; spec.constants.len()] }
    }

    /// Lowers one expression. Errors point at the offending token: an index
    /// the parser did not resolve, a named constant that refers to itself, a
    /// division whose denominator simplifies to the constant 0 (`m/(2 - 2)`,
    /// `dot(x)^2/(x - x)`), or a constant subexpression that is not a finite
    /// number (`ln(0)`).
    pub fn lower(&mut self, g: &mut Graph, e: &SrcExpr) -> Result<NodeId, SpecError> {
        g.uncounted(|g| self.lower_depth(g, e, 0))
    }

    fn lower_depth(&mut self, g: &mut Graph, e: &SrcExpr, depth: usize) -> Result<NodeId, SpecError> {
        let err = |span, message: String| SpecError { span, message };
        if depth > 2_000 {
            return Err(err(e.span(), "expression nested too deeply (more than 2000 levels)".into()));
        }
        let n = self.spec.coordinates.len();
        let id = match e {
            SrcExpr::Num(x, s) => {
                if !x.is_finite() {
                    return Err(err(*s, format!("number `{x}` is not finite; write a finite f64 literal")));
                }
                g.constant(*x)
            }
            SrcExpr::Time(_) => g.var(Var::Time),
            SrcExpr::Pi(_) => g.constant(std::f64::consts::PI),
            SrcExpr::Coord(i, s) | SrcExpr::Velocity(i, s) => {
                if *i >= n {
                    return Err(err(*s, format!("coordinate index {i} out of range (the system has {n} coordinates)")));
                }
                let i = *i as u32;
                g.var(if matches!(e, SrcExpr::Coord(..)) { Var::Q(i) } else { Var::V(i) })
            }
            SrcExpr::Multiplier(j, s) => {
                let m = self.spec.constraints.len();
                if *j >= m {
                    return Err(err(*s, format!("multiplier index {j} out of range (the system has {m} constraints)")));
                }
                g.var(Var::Psi(*j as u32))
            }
            SrcExpr::Param(i, s) => {
                if *i >= self.spec.parameters.len() {
                    return Err(err(*s, format!("parameter index {i} out of range")));
                }
                g.var(Var::P(*i as u32))
            }
            SrcExpr::Const(i, s) => {
                if *i >= self.spec.constants.len() {
                    return Err(err(*s, format!("constant index {i} out of range")));
                }
                // A constant refers only to constants declared before it:
                // lowering those first, in order, finds each reference
                // already lowered, so a chain `c1 = c0 + 1, c2 = c1 + 1, …`
                // is not a recursion as deep as the chain is long (which
                // would overflow the compiler's stack with a debug build of
                // the macro).
                let spec = self.spec;
                for j in 0..=*i {
                    if self.constants[j].is_some() {
                        continue;
                    }
                    let c = &spec.constants[j];
                    let at = if j == *i { *s } else { c.name.span };
                    let id = self.lower_depth(g, &c.value, depth + 1)?;
                    if g.as_const(id).is_none() {
                        return Err(err(
                            at,
                            format!(
                                "constant `{}` must be a number known at compile time; use a parameter for values \
                                 that change at run time",
                                c.name.name
                            ),
                        ));
                    }
                    self.constants[j] = Some(id);
                }
                match self.constants[*i] {
                    Some(id) => id,
                    None => return Err(err(*s, format!("constant index {i} was not lowered"))),
                }
            }
            SrcExpr::Neg(a, _) => {
                let a = self.lower_depth(g, a, depth + 1)?;
                g.neg(a)
            }
            SrcExpr::Binary(BinOp::Pow, a, b, s) => {
                let a = self.lower_depth(g, a, depth + 1)?;
                let b = self.lower_depth(g, b, depth + 1)?;
                let r = g.pow(a, b);
                check_finite(g, &[a, b], r, *s)?;
                r
            }
            SrcExpr::Binary(op, ..) => {
                // Walk the left spine of a chain `a ± b ± c …` (or `a */ b */ c …`)
                // iteratively, so that long sums do not count as deep nesting.
                let additive = matches!(op, BinOp::Add | BinOp::Sub);
                let mut chain = Vec::new();
                let mut left = e;
                while let SrcExpr::Binary(o, a, b, s) = left {
                    if *o == BinOp::Pow || matches!(o, BinOp::Add | BinOp::Sub) != additive {
                        break;
                    }
                    chain.push((*o, &**b, *s));
                    left = a;
                }
                let first = self.lower_depth(g, left, depth + 1)?;
                if additive {
                    self.lower_sum(g, first, chain, depth)?
                } else {
                    self.lower_product(g, first, chain, depth)?
                }
            }
            SrcExpr::Call(f, args, s) => {
                if args.len() != f.arity() {
                    return Err(err(*s, format!("`{}` takes {} argument(s), got {}", f.name(), f.arity(), args.len())));
                }
                let mut xs = Vec::with_capacity(args.len());
                for a in args {
                    xs.push(self.lower_depth(g, a, depth + 1)?);
                }
                let r = match fun_of(*f) {
                    None => g.sqrt(xs[0]),
                    Some(fun) => g.call(fun, &xs),
                };
                check_finite(g, &xs, r, *s)?;
                r
            }
        };
        Ok(id)
    }

    /// The chain `first ± b ± c …` (`chain` holds the operands after
    /// `first`, last first), folded from the left as `add(&[partial, b])`
    /// would fold it, with the same nodes, checks and errors, but without
    /// interning its partial sums of more than `KEPT_PARTIAL_SUM` operands
    /// ([`SumChain`]): in time and memory linear in the terms rather than
    /// quadratic.
    fn lower_sum(
        &mut self,
        g: &mut Graph,
        first: NodeId,
        chain: Vec<(BinOp, &SrcExpr, proc_macro2::Span)>,
        depth: usize,
    ) -> Result<NodeId, SpecError> {
        // What `check_finite` looks at in the partial sum: whether it is a
        // constant node, and the node when it is a single operand.
        let mut partial = Partial::Node(first);
        let mut sum: Option<SumChain> = None;
        for (o, b, s) in chain.into_iter().rev() {
            let b = self.lower_depth(g, b, depth + 1)?;
            let term = if o == BinOp::Sub { g.neg(b) } else { b };
            let acc_is_const = matches!(partial, Partial::Node(a) if g.as_const(a).is_some());
            let chain = sum.get_or_insert_with(|| g.sum_chain(first, KEPT_PARTIAL_SUM));
            partial = g.sum_chain_push(chain, term);
            let (nonfinite, is_const) = match partial {
                Partial::Node(r) => (g.has_nonfinite_operand(r), g.as_const(r).is_some()),
                Partial::Sum { constant } => (constant.is_some_and(|c| !c.is_finite()), false),
            };
            check_finite_parts(nonfinite, acc_is_const && g.as_const(b).is_some() && !is_const, s)?;
        }
        Ok(match sum {
            Some(chain) => g.sum_chain_finish(chain),
            None => first,
        })
    }

    /// The chain `first */ b */ c …` (`chain` holds the operands after
    /// `first`, last first), folded from the left as `mul2` and `div` would
    /// fold it, with the same nodes, checks and errors, but without
    /// interning its partial products of more than `KEPT_PARTIAL_PRODUCT`
    /// operands ([`ProductChain`]): in time and memory linear in the factors
    /// rather than quadratic.
    fn lower_product(
        &mut self,
        g: &mut Graph,
        first: NodeId,
        chain: Vec<(BinOp, &SrcExpr, proc_macro2::Span)>,
        depth: usize,
    ) -> Result<NodeId, SpecError> {
        let mut partial = PartialProduct::Node(first);
        let mut product: Option<ProductChain> = None;
        for (o, b, s) in chain.into_iter().rev() {
            let b = self.lower_depth(g, b, depth + 1)?;
            if o == BinOp::Div && g.is_const(b, 0.0) {
                return Err(SpecError { span: s, message: DIVISION_BY_ZERO.into() });
            }
            // `div(a, b)` is `mul(&[a, b^-1])`.
            let term = if o == BinOp::Div {
                let m1 = g.constant(-1.0);
                g.pow(b, m1)
            } else {
                b
            };
            let acc_is_const = matches!(partial, PartialProduct::Node(a) if g.as_const(a).is_some());
            let chain = product.get_or_insert_with(|| g.product_chain(first, KEPT_PARTIAL_PRODUCT));
            partial = g.product_chain_push(chain, term);
            let (nonfinite, is_const) = match partial {
                PartialProduct::Node(r) => (g.has_nonfinite_operand(r), g.as_const(r).is_some()),
                PartialProduct::Long { nonfinite } => (nonfinite, false),
            };
            check_finite_parts(nonfinite, acc_is_const && g.as_const(b).is_some() && !is_const, s)?;
        }
        Ok(match product {
            Some(chain) => g.product_chain_finish(chain),
            None => first,
        })
    }
}

/// The message for a `/` whose denominator simplifies to the constant 0: the
/// quotient is infinite (or NaN) wherever it is evaluated, so the generated
/// code would carry `inf` into the mass matrix, the forces or the constraints.
pub(crate) const DIVISION_BY_ZERO: &str =
    "division by zero: the denominator of this `/` simplifies to the constant 0, \
     so the quotient is infinite wherever it is evaluated; correct the denominator (e.g. `m/2` rather than \
     `m/(2 - 2)`) or remove the division";

/// Constant operands whose result could not be folded, or a folded number
/// that overflowed (`1e308*1e308*x`), mean the value is not a finite number:
/// say so at the operator instead of emitting `inf`/`NaN`.
fn check_finite(g: &Graph, args: &[NodeId], r: NodeId, span: proc_macro2::Span) -> Result<(), SpecError> {
    let constant_args = args.iter().all(|&a| g.as_const(a).is_some());
    check_finite_parts(g.has_nonfinite_operand(r), constant_args && g.as_const(r).is_none(), span)
}

/// [`check_finite`] given its two findings: `r` has an operand that is not a
/// finite number, or its operands are constants and it is not.
fn check_finite_parts(
    nonfinite_operand: bool,
    unfolded_constant: bool,
    span: proc_macro2::Span,
) -> Result<(), SpecError> {
    if nonfinite_operand {
        return Err(SpecError {
            span,
            message: "this expression folds to a number beyond the range of f64 (±1.8e308), so the generated code \
                      would compute `inf` or `NaN` here; use smaller constants (rescale the units)"
                .into(),
        });
    }
    if unfolded_constant {
        return Err(SpecError {
            span,
            message: "this constant subexpression is not a finite number: its value overflows f64 (beyond \
                      ±1.8e308, e.g. exp(1000)), it divides by zero, or a function is outside its domain (e.g. \
                      ln(-1)); correct the constants"
                .into(),
        });
    }
    Ok(())
}
