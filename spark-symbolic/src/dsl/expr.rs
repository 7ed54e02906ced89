//! The expression sub-language: a precedence-climbing parser over
//! `proc_macro2` tokens that resolves every identifier against the declared
//! names and checks function names and arities.
//!
//! Precedence, loosest first: `+ -` (left), `* /` (left), unary `-`/`+`,
//! `^` (right-associative; its exponent may carry its own unary minus).
//! Hence `-x^2 = -(x^2)`, `a*b^c = a*(b^c)`, `a^b^c = a^(b^c)`,
//! `a^-b = a^(-b)`, `a/b*c = (a/b)*c`.

use super::names::{list, nearest};
use super::scope::Scope;
use crate::spec::{BinOp, Func, SpecError, SrcExpr};
use proc_macro2::{Delimiter, Spacing, Span, TokenTree};
use std::cell::Cell;

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// A short quotation of a token for messages.
pub(crate) fn describe(tt: &TokenTree) -> String {
    match tt {
        TokenTree::Ident(i) => format!("`{i}`"),
        TokenTree::Punct(p) => format!("`{}`", p.as_char()),
        TokenTree::Literal(l) => format!("`{l}`"),
        TokenTree::Group(g) => match g.delimiter() {
            Delimiter::Parenthesis => "`( … )`".into(),
            Delimiter::Bracket => "`[ … ]`".into(),
            Delimiter::Brace => "`{ … }`".into(),
            Delimiter::None => "an expression".into(),
        },
    }
}

fn is_punct(tt: Option<&TokenTree>, c: char) -> bool {
    matches!(tt, Some(TokenTree::Punct(p)) if p.as_char() == c)
}

/// Splits tokens at top-level commas. Returns each piece with the span of the
/// comma that ends it (if any). A trailing comma gives no empty last piece.
pub(crate) fn split_commas(tokens: &[TokenTree]) -> Vec<(Vec<TokenTree>, Option<Span>)> {
    let mut pieces = Vec::new();
    let mut cur = Vec::new();
    for tt in tokens {
        match tt {
            TokenTree::Punct(p) if p.as_char() == ',' => {
                pieces.push((std::mem::take(&mut cur), Some(p.span())));
            }
            _ => cur.push(tt.clone()),
        }
    }
    if !cur.is_empty() {
        pieces.push((cur, None));
    }
    pieces
}

/// Parses a numeric literal token.
pub(crate) fn number(lit: &proc_macro2::Literal) -> Result<f64, SpecError> {
    let span = lit.span();
    let repr = lit.to_string();
    let (negative, body) = match repr.strip_prefix('-') {
        Some(rest) => (true, rest.to_string()),
        None => (false, repr.clone()),
    };
    let parsed: syn::Lit = match syn::parse_str(&body) {
        Ok(l) => l,
        Err(_) => return err(span, format!("`{repr}` is not a number; write e.g. `1.5` or `2`")),
    };
    let (digits, suffix) = match &parsed {
        syn::Lit::Int(i) => (i.base10_digits().to_string(), i.suffix().to_string()),
        syn::Lit::Float(f) => (f.base10_digits().to_string(), f.suffix().to_string()),
        syn::Lit::Str(_) | syn::Lit::ByteStr(_) | syn::Lit::CStr(_) => {
            return err(span, format!("expected a number, found the string {repr}; write e.g. `1.0` without quotes"))
        }
        syn::Lit::Bool(_) => return err(span, format!("expected a number, found `{repr}`")),
        _ => return err(span, format!("expected a number, found {repr}; write e.g. `1.0`")),
    };
    if !suffix.is_empty() && suffix != "f64" {
        let hint =
            if suffix.chars().next().is_some_and(|c| c.is_ascii_alphabetic()) && !suffix.starts_with(['i', 'u', 'f']) {
                format!("; for a product write `{digits}*{suffix}`")
            } else {
                "; remove the type suffix".to_string()
            };
        return err(span, format!("numeric literal `{repr}` has suffix `{suffix}`{hint}"));
    }
    // A literal with a nonzero digit before its exponent that reads as 0
    // (`1e-400`) lies below the smallest positive f64, about 4.9e-324: it
    // would silently become 0, e.g. a smoothing `eps` that then leaves
    // `sqrt(x^2 + eps^2)` non-differentiable at 0.
    let mantissa = digits.split(['e', 'E']).next().unwrap_or_default();
    let nonzero = mantissa.chars().any(|c| matches!(c, '1'..='9'));
    match digits.parse::<f64>() {
        Ok(v) if v == 0.0 && nonzero => err(
            span,
            format!(
                "`{repr}` is below the smallest positive f64 (about 4.9e-324) and would read as 0; write 0, or \
                 rescale the units so that it is a representable number"
            ),
        ),
        Ok(v) if v.is_finite() => Ok(if negative { -v } else { v }),
        _ => err(span, format!("`{repr}` is out of range for f64")),
    }
}

/// Nesting (parentheses, powers, signs, calls) beyond which an expression is
/// rejected, so that absurd input cannot overflow the compiler's stack.
const MAX_DEPTH: usize = 200;

/// Binary operations (`+ - * / ^`) beyond which one expression is rejected.
/// A chain `a + b + c + …` is parsed in a loop but becomes a tree as deep as
/// it is long, and the passes over the tree (cloning, dropping, lowering)
/// recurse: a sum of 200 000 terms overflows an 8 MiB stack (the Python
/// package's check thread, the compiler's). Bounding the operations bounds
/// the depth of the tree (at most this plus [`MAX_DEPTH`]). A declaration
/// with the most coordinates ([`MAX_COORDINATES`](super::MAX_COORDINATES))
/// and a coupling term per neighbouring pair, written term by term, has
/// about 2 400 in its Lagrangian. `asin(x)` and `acos(x)` are written
/// through `atan2` with `x` twice, so they count the operations of `x` once
/// more, and 2 for `1 - x^2`: nested `asin(asin(…))` doubles the tree at
/// each level, and 40 levels would otherwise exhaust memory.
pub const MAX_OPERATIONS: usize = 20_000;

/// The token-level parser for one expression.
struct Parser<'s, 'a> {
    toks: Vec<TokenTree>,
    pos: usize,
    scope: &'s Scope<'a>,
    what: &'s str,
    /// Current nesting of `unary` calls, including enclosing expressions.
    depth: usize,
    /// The operations of the whole expression.
    operations: &'s Operations<'s>,
}

/// Binary operations parsed so far in one expression, its parenthesized
/// parts and call arguments included, and the expression's name.
struct Operations<'s> {
    count: Cell<usize>,
    what: &'s str,
}

/// Parses `tokens` as one complete expression. `what` names it in messages
/// ("the lagrangian", "constraint 2"); `anchor` is where an empty expression
/// is reported.
pub(crate) fn parse_expression(
    tokens: &[TokenTree],
    scope: &Scope<'_>,
    what: &str,
    anchor: Span,
) -> Result<SrcExpr, SpecError> {
    parse_nested(tokens, scope, what, anchor, 0, &Operations { count: Cell::new(0), what })
}

fn parse_nested(
    tokens: &[TokenTree],
    scope: &Scope<'_>,
    what: &str,
    anchor: Span,
    depth: usize,
    operations: &Operations<'_>,
) -> Result<SrcExpr, SpecError> {
    if tokens.is_empty() {
        return err(anchor, format!("{what} is empty: write an expression, e.g. `dot(x)^2/2`"));
    }
    let mut p = Parser { toks: tokens.to_vec(), pos: 0, scope, what, depth, operations };
    let e = p.sum()?;
    if let Some(tt) = p.toks.get(p.pos) {
        if let (TokenTree::Ident(id), Some(TokenTree::Punct(next))) = (tt, p.toks.get(p.pos + 1)) {
            if matches!(next.as_char(), '=' | ':') && next.spacing() == Spacing::Alone {
                // `m = 1 g = 2`, `{ x: a y: b }`: the next entry of a list.
                return err(
                    id.span(),
                    format!("missing `,` before `{id} {}`: separate the entries with `,`", next.as_char()),
                );
            }
        }
        return p.trailing(tt);
    }
    Ok(e)
}

impl Parser<'_, '_> {
    fn peek(&self) -> Option<&TokenTree> {
        self.toks.get(self.pos)
    }

    fn peek_op(&self) -> Option<(char, Span)> {
        match self.peek() {
            Some(TokenTree::Punct(p)) => Some((p.as_char(), p.span())),
            _ => None,
        }
    }

    /// Counts one binary operation at `span`; an error once the expression
    /// has more than [`MAX_OPERATIONS`].
    fn operation(&self, span: Span) -> Result<(), SpecError> {
        self.operations_at(1, span)
    }

    /// Counts `n` binary operations at `span`; an error once the expression
    /// has more than [`MAX_OPERATIONS`].
    fn operations_at(&self, n: usize, span: Span) -> Result<(), SpecError> {
        let count = self.operations.count.get().saturating_add(n);
        self.operations.count.set(count);
        if count > MAX_OPERATIONS {
            return err(
                span,
                format!(
                    "{} has more than {MAX_OPERATIONS} operations (`+ - * / ^`): split it using constants or \
                     simplify it",
                    self.operations.what
                ),
            );
        }
        Ok(())
    }

    fn sum(&mut self) -> Result<SrcExpr, SpecError> {
        let mut lhs = self.product()?;
        while let Some((c @ ('+' | '-'), span)) = self.peek_op() {
            self.operation(span)?;
            self.pos += 1;
            let rhs = self.operand_after(c, span, Self::product)?;
            let op = if c == '+' { BinOp::Add } else { BinOp::Sub };
            lhs = SrcExpr::Binary(op, Box::new(lhs), Box::new(rhs), span);
        }
        Ok(lhs)
    }

    fn product(&mut self) -> Result<SrcExpr, SpecError> {
        let mut lhs = self.unary()?;
        while let Some((c @ ('*' | '/'), span)) = self.peek_op() {
            self.check_double_star()?;
            self.operation(span)?;
            self.pos += 1;
            let rhs = self.operand_after(c, span, Self::unary)?;
            let op = if c == '*' { BinOp::Mul } else { BinOp::Div };
            lhs = SrcExpr::Binary(op, Box::new(lhs), Box::new(rhs), span);
        }
        Ok(lhs)
    }

    fn unary(&mut self) -> Result<SrcExpr, SpecError> {
        if self.depth >= MAX_DEPTH {
            let span = self.peek().map_or_else(Span::call_site, TokenTree::span);
            return err(
                span,
                format!(
                    "{} is nested too deeply (over {MAX_DEPTH} levels): split it using constants or simplify it",
                    self.what
                ),
            );
        }
        self.depth += 1;
        let result = self.unary_inner();
        self.depth -= 1;
        result
    }

    fn unary_inner(&mut self) -> Result<SrcExpr, SpecError> {
        match self.peek_op() {
            Some(('-', span)) => {
                self.pos += 1;
                let inner = self.operand_after('-', span, Self::unary)?;
                Ok(SrcExpr::Neg(Box::new(inner), span))
            }
            Some(('+', span)) => {
                self.pos += 1;
                self.operand_after('+', span, Self::unary)
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<SrcExpr, SpecError> {
        let base = self.primary()?;
        if let Some(('^', span)) = self.peek_op() {
            self.operation(span)?;
            self.pos += 1;
            let exponent = self.operand_after('^', span, Self::unary)?;
            return Ok(SrcExpr::Binary(BinOp::Pow, Box::new(base), Box::new(exponent), span));
        }
        Ok(base)
    }

    fn check_double_star(&self) -> Result<(), SpecError> {
        if let (Some(TokenTree::Punct(a)), next) = (self.peek(), self.toks.get(self.pos + 1)) {
            if a.as_char() == '*' && a.spacing() == Spacing::Joint && is_punct(next, '*') {
                return err(a.span(), "`**` is not an operator here: write `x^2` for powers");
            }
        }
        Ok(())
    }

    /// Parses the operand of operator `op` with `f`, turning "nothing there"
    /// into a message about the dangling operator.
    fn operand_after(
        &mut self,
        op: char,
        span: Span,
        f: fn(&mut Self) -> Result<SrcExpr, SpecError>,
    ) -> Result<SrcExpr, SpecError> {
        if self.peek().is_none() {
            return err(span, format!("{} ends with `{op}`: write an operand after it, or remove it", self.what));
        }
        f(self)
    }

    fn primary(&mut self) -> Result<SrcExpr, SpecError> {
        let Some(tt) = self.peek().cloned() else {
            let span = self.toks.last().map_or_else(Span::call_site, TokenTree::span);
            return err(span, format!("{} ends too early: expected an operand", self.what));
        };
        self.pos += 1;
        match tt {
            TokenTree::Literal(lit) => Ok(SrcExpr::Num(number(&lit)?, lit.span())),
            TokenTree::Ident(ident) => {
                if let Some(TokenTree::Group(g)) = self.peek() {
                    if g.delimiter() == Delimiter::Parenthesis {
                        let g = g.clone();
                        self.pos += 1;
                        return self.call(&ident, &g);
                    }
                }
                if let Some(TokenTree::Group(g)) = self.peek() {
                    if g.delimiter() == Delimiter::Bracket && ident == "psi" {
                        let g = g.clone();
                        self.pos += 1;
                        return self.scope.multiplier(&ident, &g);
                    }
                }
                if is_punct(self.peek(), ':') {
                    return err(
                        ident.span(),
                        "paths are not supported in expressions: write `pi` for π, or a number, or a declared name",
                    );
                }
                if is_punct(self.peek(), '!') {
                    return err(
                        ident.span(),
                        "macro calls are not supported in expressions: write the value, or declare it under \
                         `constants: { … }` or `parameters: { … }` and use its name",
                    );
                }
                self.scope.resolve(&ident)
            }
            TokenTree::Group(g) => match g.delimiter() {
                Delimiter::Parenthesis | Delimiter::None => {
                    let inner: Vec<TokenTree> = g.stream().into_iter().collect();
                    if inner.is_empty() {
                        return err(g.span(), "empty parentheses: write an expression inside `( … )`");
                    }
                    parse_nested(&inner, self.scope, self.what, g.span(), self.depth, self.operations)
                }
                Delimiter::Bracket | Delimiter::Brace => err(
                    g.span(),
                    format!(
                        "{} is not allowed in expressions: use parentheses `( … )`",
                        describe(&TokenTree::Group(g.clone()))
                    ),
                ),
            },
            TokenTree::Punct(p) => {
                let c = p.as_char();
                if let (Some(TokenTree::Literal(lit)), '.') = (self.peek(), c) {
                    let digits = lit.to_string();
                    if digits.starts_with(|d: char| d.is_ascii_digit()) {
                        return err(
                            p.span(),
                            format!(
                                "write `0.{digits}` instead of `.{digits}`: a number needs a digit before its decimal point"
                            ),
                        );
                    }
                }
                let msg = match c {
                    '*' | '/' | '^' => {
                        if self.pos == 1 {
                            format!("{} starts with `{c}`: write an operand before it", self.what)
                        } else {
                            format!("expected an operand, found `{c}`: two operators in a row; remove one")
                        }
                    }
                    ',' => "expected an operand, found `,`: remove it".to_string(),
                    _ => format!("expected an operand, found `{c}`; operators are `+ - * / ^`"),
                };
                err(p.span(), msg)
            }
        }
    }

    fn call(&mut self, ident: &proc_macro2::Ident, group: &proc_macro2::Group) -> Result<SrcExpr, SpecError> {
        let name = ident.to_string();
        let span = ident.span();
        if name == "dot" {
            return self.scope.velocity(span, group);
        }
        let sugar = Sugar::from_name(&name);
        let Some(func) = Func::from_name(&name).or(sugar.map(|_| Func::Atan2)) else {
            return err(span, self.unknown_function(&name));
        };
        let toks: Vec<TokenTree> = group.stream().into_iter().collect();
        let pieces = split_commas(&toks);
        let mut args = Vec::with_capacity(pieces.len());
        for (i, (piece, comma)) in pieces.iter().enumerate() {
            if piece.is_empty() {
                return err(
                    comma.unwrap_or(group.span()),
                    format!("empty argument {} of `{name}`: remove the extra `,`", i + 1),
                );
            }
            let what = format!("argument {} of `{name}`", i + 1);
            args.push(parse_nested(piece, self.scope, &what, group.span(), self.depth, self.operations)?);
        }
        if let Some(sugar) = sugar {
            if args.len() != 1 {
                return err(span, format!("`{name}` takes 1 argument: `{name}(x)`, found {}", args.len()));
            }
            if sugar != Sugar::Atan {
                // `asin(x)` is `atan2(x, sqrt(1 - x^2))`: `x` a second time,
                // and `^` and `-`. Counted, so that nested `asin(asin(…))`,
                // whose tree doubles at each level, stays within the bound
                // rather than exhausting memory.
                self.operations_at(binary_operations(&args[0]) + 2, span)?;
            }
            return Ok(sugar.expand(args.remove(0), span));
        }
        if args.len() != func.arity() {
            let expected = if func.arity() == 2 {
                "2 arguments: `atan2(y, x)`".to_string()
            } else {
                format!("1 argument: `{name}(x)`")
            };
            return err(span, format!("`{name}` takes {expected}, found {}", args.len()));
        }
        Ok(SrcExpr::Call(func, args, span))
    }

    fn unknown_function(&self, name: &str) -> String {
        let s = self.scope;
        if s.coordinates.iter().any(|n| n.name == name)
            || s.parameters.iter().any(|n| n.name == name)
            || s.constants.iter().any(|n| n.name == name)
            || name == "t"
            || name == "pi"
        {
            return format!("`{name}` is not a function: write `{name}*( … )` for a product");
        }
        let hint = match name {
            "log" => Some("write `ln(x)` for the natural logarithm".to_string()),
            "pow" | "powi" | "powf" => Some("write `a^b` for powers".to_string()),
            "abs" | "fabs" => Some(
                "it is not differentiable at 0, and Newton and the stage Jacobians need derivatives there; use a \
                 smooth stand-in such as `sqrt(x^2 + eps^2)` with a small parameter `eps`"
                    .to_string(),
            ),
            "sign" | "signum" | "sgn" => Some("it jumps at 0; use a smooth stand-in such as `tanh(x/eps)`".to_string()),
            "min" | "max" | "fmin" | "fmax" => Some(
                "it is not differentiable where its arguments are equal; use a smooth stand-in such as \
                 `(a + b + sqrt((a - b)^2 + eps^2))/2` for max(a, b)"
                    .to_string(),
            ),
            "floor" | "ceil" | "round" | "heaviside" | "step" => Some(
                "it is piecewise constant, so its derivative carries no information; smooth it, e.g. with `tanh`"
                    .to_string(),
            ),
            "asinh" | "arsinh" => Some("write `ln(x + sqrt(x^2 + 1))`".to_string()),
            "acosh" | "arcosh" => Some("write `ln(x + sqrt(x^2 - 1))`".to_string()),
            "atanh" | "artanh" => Some("write `ln((1 + x)/(1 - x))/2`".to_string()),
            "arctan" => Some("write `atan(x)` or `atan2(y, x)`".to_string()),
            "arcsin" => Some("write `asin(x)`".to_string()),
            "arccos" => Some("write `acos(x)`".to_string()),
            "holonomic" | "constraint" | "potential" | "force" | "nonideal" => Some(format!(
                "`{name}` is an effect kind, not a function: declare it under `effects: {{ rod: {name}(…) }}` and \
                 select it in `scenes: {{ Rod = [rod] }}`"
            )),
            "cot" => Some("write `1/tan(x)`".to_string()),
            "sec" => Some("write `1/cos(x)`".to_string()),
            "csc" | "cosec" => Some("write `1/sin(x)`".to_string()),
            "sq" | "square" => Some("write `x^2`".to_string()),
            "log10" => Some("write `ln(x)/ln(10)`".to_string()),
            "exp2" => Some("write `2^x`".to_string()),
            "cbrt" => Some("write `x^(1/3)`".to_string()),
            _ => None,
        };
        let funcs: Vec<&str> = Func::ALL.iter().map(|f| f.name()).chain(Sugar::ALL.iter().map(|s| s.name())).collect();
        let mut msg = format!("unknown function `{name}`");
        if let Some(h) = hint {
            msg.push_str(&format!(": {h}."));
        } else if let Some(n) = nearest(name, funcs.iter().copied().chain(["dot"])) {
            msg.push_str(&format!("; did you mean `{n}`?"));
        } else {
            msg.push('.');
        }
        msg.push_str(&format!(" Functions: {}, and `dot(x)` for velocities.", list(&funcs)));
        msg
    }

    fn trailing(&self, tt: &TokenTree) -> Result<SrcExpr, SpecError> {
        let msg = match tt {
            TokenTree::Punct(p) => match p.as_char() {
                '.' => "method calls are not supported: write `sin(x)` instead of `x.sin()` and `x^2` instead of `x.powi(2)`".to_string(),
                '=' => format!(
                    "`=` is not allowed in {}: a constraint is an expression that must vanish, so write `a - (b)` instead of `a = b`",
                    self.what
                ),
                ';' => "unexpected `;`: separate sections with `,`".to_string(),
                c => format!("unexpected `{c}` in {}; operators are `+ - * / ^`", self.what),
            },
            other => format!(
                "missing operator before {}: write `*` for a product, e.g. `a*b`, or `,` to end {}",
                describe(other),
                self.what
            ),
        };
        err(tt.span(), msg)
    }
}

/// The binary operations (`+ - * / ^`) in `e`, counted without recursion.
fn binary_operations(e: &SrcExpr) -> usize {
    let mut count = 0;
    let mut stack = vec![e];
    while let Some(e) = stack.pop() {
        match e {
            SrcExpr::Neg(a, _) => stack.push(a),
            SrcExpr::Binary(_, a, b, _) => {
                count += 1;
                stack.extend([&**a, &**b]);
            }
            SrcExpr::Call(_, args, _) => stack.extend(args),
            _ => {}
        }
    }
    count
}

/// Inverse trigonometric functions, accepted in the DSL and rewritten at
/// parse time through `atan2` (exact, with its derivative
/// `(b·a′ − a·b′)/(a² + b²)`), so the engine, the neutral source text and
/// the CasADi checker need no new operator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Sugar {
    /// `atan(x) = atan2(x, 1)`.
    Atan,
    /// `asin(x) = atan2(x, sqrt(1 − x²))`, defined for `|x| ≤ 1`.
    Asin,
    /// `acos(x) = atan2(sqrt(1 − x²), x)`, defined for `|x| ≤ 1`.
    Acos,
}

impl Sugar {
    const ALL: [Sugar; 3] = [Sugar::Atan, Sugar::Asin, Sugar::Acos];

    fn from_name(name: &str) -> Option<Sugar> {
        Sugar::ALL.into_iter().find(|s| s.name() == name)
    }

    fn name(self) -> &'static str {
        match self {
            Sugar::Atan => "atan",
            Sugar::Asin => "asin",
            Sugar::Acos => "acos",
        }
    }

    fn expand(self, x: SrcExpr, span: Span) -> SrcExpr {
        let num = |v: f64| SrcExpr::Num(v, span);
        let bin = |op: BinOp, a: SrcExpr, b: SrcExpr| SrcExpr::Binary(op, Box::new(a), Box::new(b), span);
        let cos_side = |x: &SrcExpr| {
            let square = bin(BinOp::Pow, x.clone(), num(2.0));
            SrcExpr::Call(Func::Sqrt, vec![bin(BinOp::Sub, num(1.0), square)], span)
        };
        let args = match self {
            Sugar::Atan => vec![x, num(1.0)],
            Sugar::Asin => {
                let c = cos_side(&x);
                vec![x, c]
            }
            Sugar::Acos => {
                let c = cos_side(&x);
                vec![c, x]
            }
        };
        SrcExpr::Call(Func::Atan2, args, span)
    }
}
