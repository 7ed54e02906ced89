//! The expression sub-language: a precedence-climbing parser over
//! `proc_macro2` tokens that resolves every identifier against the declared
//! names and checks function names and arities.
//!
//! Precedence, loosest first: `+ -` (left), `* /` (left), unary `-`/`+`,
//! `^` (right-associative; its exponent may carry its own unary minus).
//! Hence `-x^2 = -(x^2)`, `a*b^c = a*(b^c)`, `a^b^c = a^(b^c)`,
//! `a^-b = a^(-b)`, `a/b*c = (a/b)*c`.

use super::names::{list, nearest};
use crate::spec::{BinOp, Func, Named, SpecError, SrcExpr};
use proc_macro2::{Delimiter, Spacing, Span, TokenTree};

/// Where an expression appears, which decides what it may refer to.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Context {
    /// `lagrangian` or a constraint: everything.
    Dynamic,
    /// The value of constant number `index`: numbers, `pi`, functions and
    /// earlier constants only.
    Constant(usize),
    /// The default of parameter number `index`: numbers, `pi`, functions and
    /// constants only.
    Default(usize),
}

/// Which constraint multipliers `ψ` an expression may use: only a
/// non-ideal force `N(t,q,v,ψ)` may.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Multipliers<'a> {
    /// Not in scope (`L`, constraints, holonomic `g`, constants, defaults):
    /// `psi[j]` is an error that says where multipliers belong.
    None,
    /// An external force `f(t,q,v)`: multipliers are recognized (by index
    /// or by a constraint effect's name) and rejected with a hint.
    Forbidden {
        /// Constraint effects and the multiplier index each one stands for.
        named: &'a [(String, usize)],
    },
    /// A non-ideal force: `psi[j]` for the base declaration's constraints
    /// `j < base`, and constraint effects by name.
    Allowed {
        /// Number of constraints of the base declaration.
        base: usize,
        /// Constraint effects and the multiplier index each one stands for.
        named: &'a [(String, usize)],
    },
}

/// The declared names an expression is resolved against.
#[derive(Clone, Copy)]
pub(crate) struct Scope<'a> {
    pub coordinates: &'a [Named],
    pub parameters: &'a [Named],
    pub constants: &'a [Named],
    pub context: Context,
    pub multipliers: Multipliers<'a>,
}

const NONIDEAL_HINT: &str = "a force that depends on a constraint's multiplier is a non-ideal constraint force: \
                             declare it as `name: nonideal { coordinate: … }` (or in `nonideal_forces: { … }`)";

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

impl Scope<'_> {
    fn what_context(&self) -> String {
        match self.context {
            Context::Dynamic => String::new(),
            Context::Constant(i) => format!("constant `{}`", self.constants[i].name),
            Context::Default(i) => format!("the default of parameter `{}`", self.parameters[i].name),
        }
    }

    fn known_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = Vec::new();
        if matches!(self.context, Context::Dynamic) {
            names.push("t");
            names.extend(self.coordinates.iter().map(|n| n.name.as_str()));
            names.extend(self.parameters.iter().map(|n| n.name.as_str()));
        }
        names.push("pi");
        match self.context {
            Context::Constant(i) => names.extend(self.constants[..i].iter().map(|n| n.name.as_str())),
            _ => names.extend(self.constants.iter().map(|n| n.name.as_str())),
        }
        if let Multipliers::Allowed { named, .. } = self.multipliers {
            names.extend(named.iter().map(|(n, _)| n.as_str()));
        }
        names
    }

    /// A message for a name that is declared but not allowed in a constant
    /// context (`kind` is e.g. "the coordinate `x`").
    fn forbidden(&self, span: Span, kind: &str, is_param: bool) -> Result<SrcExpr, SpecError> {
        match self.context {
            Context::Dynamic => unreachable_dynamic(span),
            Context::Constant(i) => {
                let c = &self.constants[i].name;
                let hint = if is_param {
                    format!("make `{c}` a parameter, or write the expression where you use `{c}`")
                } else {
                    format!("write the expression where you use `{c}` (in `lagrangian` or `constraints`)")
                };
                err(
                    span,
                    format!(
                        "constant `{c}` cannot depend on {kind}: constants are numbers folded at compile time; {hint}"
                    ),
                )
            }
            Context::Default(i) => {
                let p = &self.parameters[i].name;
                let hint = if is_param {
                    "write the value, or declare a constant under `constants: { … }` and use it in both defaults"
                        .to_string()
                } else {
                    format!("write a number, e.g. `{p} = 1.0`")
                };
                err(span, format!("the default of parameter `{p}` must be a constant number, not {kind}; {hint}"))
            }
        }
    }

    /// Resolves a plain identifier (not followed by parentheses).
    fn resolve(&self, ident: &proc_macro2::Ident) -> Result<SrcExpr, SpecError> {
        let name = ident.to_string();
        let span = ident.span();
        let dynamic = matches!(self.context, Context::Dynamic);
        if name == "pi" {
            return Ok(SrcExpr::Pi(span));
        }
        if name == "t" {
            return if dynamic { Ok(SrcExpr::Time(span)) } else { self.forbidden(span, "the time `t`", false) };
        }
        if let Some(i) = self.coordinates.iter().position(|n| n.name == name) {
            return if dynamic {
                Ok(SrcExpr::Coord(i, span))
            } else {
                self.forbidden(span, &format!("the coordinate `{name}`"), false)
            };
        }
        if let Some(i) = self.parameters.iter().position(|n| n.name == name) {
            return if dynamic {
                Ok(SrcExpr::Param(i, span))
            } else {
                self.forbidden(span, &format!("the runtime parameter `{name}`"), true)
            };
        }
        if let Some(i) = self.constants.iter().position(|n| n.name == name) {
            if let Context::Constant(c) = self.context {
                if i == c {
                    return err(span, format!("constant `{name}` cannot refer to itself; write its value"));
                }
                if i > c {
                    let cur = &self.constants[c].name;
                    return err(
                        span,
                        format!(
                            "constant `{cur}` uses `{name}`, which is declared later; declare `{name}` before `{cur}`"
                        ),
                    );
                }
            }
            return Ok(SrcExpr::Const(i, span));
        }
        match self.multipliers {
            Multipliers::Allowed { named, .. } => {
                if let Some((_, j)) = named.iter().find(|(n, _)| *n == name) {
                    return Ok(SrcExpr::Multiplier(*j, span));
                }
            }
            Multipliers::Forbidden { named } => {
                if named.iter().any(|(n, _)| *n == name) {
                    return err(
                        span,
                        format!(
                            "a force f(t, q, v) may not depend on `{name}`, the multiplier of constraint `{name}`; \
                             {NONIDEAL_HINT}"
                        ),
                    );
                }
            }
            Multipliers::None => {}
        }
        if let Some(f) = Func::from_name(&name) {
            let args = if f.arity() == 2 { "y, x" } else { "x" };
            return err(span, format!("`{name}` is a function: write `{name}({args})`"));
        }
        if name == "dot" {
            let example = self.coordinates.first().map_or("x", |c| c.name.as_str());
            return err(span, format!("`dot` needs a coordinate: write `dot({example})` for its velocity"));
        }
        err(span, self.unknown_message(&name))
    }

    fn unknown_message(&self, name: &str) -> String {
        let dynamic = matches!(self.context, Context::Dynamic);
        let place = if dynamic { String::new() } else { format!(" in {}", self.what_context()) };
        // Common spellings of a velocity: xdot, x_dot, dot_x, dx, vx, v_x.
        if dynamic {
            for c in self.coordinates {
                let c = c.name.as_str();
                let forms = [
                    format!("{c}dot"),
                    format!("{c}_dot"),
                    format!("dot_{c}"),
                    format!("dot{c}"),
                    format!("d{c}"),
                    format!("v{c}"),
                    format!("v_{c}"),
                    format!("{c}_t"),
                ];
                if forms.iter().any(|f| f == name) {
                    return format!("unknown identifier `{name}`; write `dot({c})` for the velocity of `{c}`");
                }
            }
        }
        match name {
            "PI" => return format!("unknown identifier `PI`{place}; write `pi`"),
            "TAU" => return format!("unknown identifier `TAU`{place}; write `2*pi`"),
            "E" | "e" => return format!("unknown identifier `{name}`{place}; write `exp(1)` for Euler's number"),
            _ => {}
        }
        if let Some(d) = name.strip_prefix("FRAC_PI_") {
            return format!("unknown identifier `{name}`{place}; write `pi/{d}`");
        }
        let known = self.known_names();
        let mut msg = format!("unknown identifier `{name}`{place}");
        match nearest(name, known.iter().copied()) {
            Some(s) => msg.push_str(&format!("; did you mean `{s}`?")),
            None => msg.push('.'),
        }
        if dynamic {
            msg.push_str(&format!(
                " Known names: {}. Declare new names under `coordinates`, `parameters` or `constants`.",
                list(&known)
            ));
        } else {
            msg.push_str(&format!(" Allowed here: numbers and {}.", list(&known)));
        }
        if let Multipliers::Allowed { base, named } = self.multipliers {
            let names: Vec<&str> = named.iter().map(|(n, _)| n.as_str()).collect();
            let by_name = if names.is_empty() {
                String::new()
            } else {
                format!(", constraint effects by name: {}", list(&names))
            };
            let by_index = match base {
                0 => "none by index".to_string(),
                1 => "`psi[0]` for the base constraint".to_string(),
                b => format!("`psi[0]` … `psi[{}]` for the base constraints", b - 1),
            };
            msg.push_str(&format!(" Multipliers here: {by_index}{by_name}."));
        }
        msg
    }

    /// `psi[j]`: the multiplier of the base declaration's constraint `j`.
    fn multiplier(&self, psi: &proc_macro2::Ident, group: &proc_macro2::Group) -> Result<SrcExpr, SpecError> {
        let toks: Vec<TokenTree> = group.stream().into_iter().collect();
        let span = psi.span().join(group.span()).unwrap_or(psi.span());
        let index = match toks.as_slice() {
            [TokenTree::Literal(l)] => l.to_string().parse::<usize>().ok(),
            _ => None,
        };
        let Some(j) = index else {
            return err(
                group.span(),
                "write the multiplier of constraint j as `psi[j]` with an integer j, e.g. `psi[0]`",
            );
        };
        match self.multipliers {
            Multipliers::None => err(
                span,
                format!(
                    "the multiplier `psi[{j}]` may only appear in a non-ideal constraint force \
                     (a `name: nonideal {{ … }}` effect or the `nonideal_forces: {{ … }}` section)"
                ),
            ),
            Multipliers::Forbidden { .. } => {
                err(span, format!("a force f(t, q, v) may not depend on the multiplier `psi[{j}]`; {NONIDEAL_HINT}"))
            }
            Multipliers::Allowed { base, named } => {
                if j < base {
                    return Ok(SrcExpr::Multiplier(j, span));
                }
                let have = match base {
                    0 => "the base declaration has no constraints".to_string(),
                    1 => "the base declaration has 1 constraint, `psi[0]`".to_string(),
                    b => format!("the base declaration has {b} constraints, `psi[0]` … `psi[{}]`", b - 1),
                };
                let mut msg = format!("`psi[{j}]` is out of range: {have} (indices are 0-based)");
                if !named.is_empty() {
                    let names: Vec<String> = named.iter().map(|(n, _)| format!("`{n}`")).collect();
                    msg.push_str(&format!(
                        "; the multiplier of a constraint effect is written by its name: {}",
                        names.join(", ")
                    ));
                }
                err(span, msg)
            }
        }
    }

    /// `dot(…)`: the velocity of a coordinate.
    fn velocity(&self, dot_span: Span, group: &proc_macro2::Group) -> Result<SrcExpr, SpecError> {
        let toks: Vec<TokenTree> = group.stream().into_iter().collect();
        let example = self.coordinates.first().map_or("x", |c| c.name.as_str());
        let ident = match toks.as_slice() {
            [] => return err(group.span(), format!("`dot()` needs a coordinate: write `dot({example})`")),
            [TokenTree::Ident(i)] => i.clone(),
            [TokenTree::Group(g)] if matches!(g.delimiter(), Delimiter::None | Delimiter::Parenthesis) => {
                let inner = proc_macro2::Group::new(Delimiter::Parenthesis, g.stream());
                return self.velocity(dot_span, &inner);
            }
            [TokenTree::Ident(i), TokenTree::Group(_), ..] if i == "dot" => return err(
                i.span(),
                "accelerations are not allowed: the Lagrangian and the constraints depend on t, q and dot(q) only; \
                     write `dot(x)` for a velocity",
            ),
            [first, ..] => {
                return err(
                    first.span(),
                    format!(
                        "`dot` takes one coordinate name, not an expression: write e.g. `dot({example})`, \
                         and `dot(x) + dot(y)` instead of `dot(x + y)`"
                    ),
                )
            }
        };
        let name = ident.to_string();
        let span = ident.span();
        let coords: Vec<&str> = self.coordinates.iter().map(|n| n.name.as_str()).collect();
        let Some(i) = coords.iter().position(|c| *c == name) else {
            let what = if name == "t" {
                "`t` is the time, not a coordinate".to_string()
            } else if self.parameters.iter().any(|p| p.name == name) {
                format!("`{name}` is a parameter, not a coordinate")
            } else if self.constants.iter().any(|p| p.name == name) {
                format!("`{name}` is a constant, not a coordinate")
            } else {
                format!("velocity of unknown coordinate `{name}`")
            };
            let mut msg = format!("{what}; only coordinates have velocities");
            match nearest(&name, coords.iter().copied()) {
                Some(s) => msg.push_str(&format!("; did you mean `dot({s})`?")),
                None => msg.push('.'),
            }
            msg.push_str(&format!(" Coordinates: {}.", list(&coords)));
            return err(span, msg);
        };
        match self.context {
            Context::Dynamic => Ok(SrcExpr::Velocity(i, dot_span.join(group.span()).unwrap_or(dot_span))),
            _ => self.forbidden(dot_span, &format!("the velocity `dot({name})`"), false),
        }
    }
}

fn unreachable_dynamic(span: Span) -> Result<SrcExpr, SpecError> {
    // Dynamic expressions may use every name; reaching this is a parser bug,
    // reported as an error rather than a panic.
    err(span, "internal error in the spark DSL parser (name allowed in dynamic context); please report")
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
    match digits.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(if negative { -v } else { v }),
        _ => err(span, format!("`{repr}` is out of range for f64")),
    }
}

/// Nesting (parentheses, powers, signs, calls) beyond which an expression is
/// rejected, so that absurd input cannot overflow the compiler's stack.
const MAX_DEPTH: usize = 200;

/// The token-level parser for one expression.
struct Parser<'s, 'a> {
    toks: Vec<TokenTree>,
    pos: usize,
    scope: &'s Scope<'a>,
    what: &'s str,
    /// Current nesting of `unary` calls, including enclosing expressions.
    depth: usize,
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
    parse_nested(tokens, scope, what, anchor, 0)
}

fn parse_nested(
    tokens: &[TokenTree],
    scope: &Scope<'_>,
    what: &str,
    anchor: Span,
    depth: usize,
) -> Result<SrcExpr, SpecError> {
    if tokens.is_empty() {
        return err(anchor, format!("{what} is empty: write an expression, e.g. `dot(x)^2/2`"));
    }
    let mut p = Parser { toks: tokens.to_vec(), pos: 0, scope, what, depth };
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

    fn sum(&mut self) -> Result<SrcExpr, SpecError> {
        let mut lhs = self.product()?;
        while let Some((c @ ('+' | '-'), span)) = self.peek_op() {
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
                    parse_nested(&inner, self.scope, self.what, g.span(), self.depth)
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
            args.push(parse_nested(piece, self.scope, &what, group.span(), self.depth)?);
        }
        if let Some(sugar) = sugar {
            if args.len() != 1 {
                return err(span, format!("`{name}` takes 1 argument: `{name}(x)`, found {}", args.len()));
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
