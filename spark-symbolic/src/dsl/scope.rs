//! What an expression may refer to where it appears ([`Scope`]): the
//! declared names, the time and velocities only in dynamic expressions,
//! multipliers only in non-ideal forces, and the messages that say why a
//! name is refused or unknown.

use super::names::{list, nearest};
use crate::spec::{Func, Named, SpecError, SrcExpr};
use proc_macro2::{Delimiter, Span, TokenTree};

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

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
    pub(super) fn resolve(&self, ident: &proc_macro2::Ident) -> Result<SrcExpr, SpecError> {
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
    pub(super) fn multiplier(
        &self,
        psi: &proc_macro2::Ident,
        group: &proc_macro2::Group,
    ) -> Result<SrcExpr, SpecError> {
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
    pub(super) fn velocity(&self, dot_span: Span, group: &proc_macro2::Group) -> Result<SrcExpr, SpecError> {
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
