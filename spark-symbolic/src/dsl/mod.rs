//! The DSL parser: the tokens inside `nonholonomic_system! { … }` →
//! [`SystemSpec`]. Hand-written over `proc_macro2` tokens so that every error
//! points at the offending token and says what to write instead, and so that
//! `^` can be the power operator.
//!
//! # Grammar
//!
//! ```text
//! declaration := attribute* visibility? "struct" Name "{" section ("," section)* ","? "}"
//! attribute   := "#[" … "]"                  passed through to the struct (doc comments, derives)
//!              | "#[spark(crate = path)]"      where generated code finds the runtime
//!                                               (default `::spark_runtime`); not passed through
//! section     := "coordinates" ":" "[" name ("," name)* ","? "]"            required, at least one
//!              | "parameters"  ":" "{" (name "=" const_expr),* ","? "}"     runtime f64 fields
//!              | "constants"   ":" "{" (name "=" const_expr),* ","? "}"     folded at compile time
//!              | "lagrangian"  ":" expr                                     required
//!              | "constraints" ":" "[" (expr),* ","? "]"                   optional; empty = none
//!              | "forces"      ":" "{" (coordinate ":" expr),* ","? "}"    external force f(t,q,v)
//!              | "nonideal_forces" ":" "{" (coordinate ":" expr),* ","? "}"  non-ideal force N(t,q,v,ψ)
//!              | "events"      ":" "{" (name ":" event),* ","? "}"       zeros of g(t,q,v) to locate
//! event       := ("rising" | "falling" | "crossing")? "(" expr ")" "terminal"?
//!              | expr "terminal"?                                      (crossing in both directions)
//! expr        := sum
//! sum         := product (("+" | "-") product)*          left-associative
//! product     := unary (("*" | "/") unary)*              left-associative
//! unary       := ("-" | "+") unary | power
//! power       := primary ("^" unary)?                    right-associative: a^b^c = a^(b^c)
//! primary     := number | name | "t" | "pi" | "dot" "(" coordinate ")"
//!              | function "(" expr ("," expr)* ")" | "(" expr ")"
//! function    := sqrt | exp | ln | sin | cos | tan | sinh | cosh | tanh      (one argument)
//!              | atan2                                                       (atan2(y, x))
//! number      := integer or real literal: 1, 2.5, 1e-3, 1.0f64
//! ```
//!
//! So `-x^2 = -(x^2)`, `a*b^c = a*(b^c)`, `a/b*c = (a/b)*c`, `x^-1 = x^(-1)`.
//! Sections may come in any order, each at most once. A `name` is a
//! coordinate, a runtime parameter or a constant; all declared names are
//! distinct and none is `t`, `pi`, `dot`, a function name, a Rust keyword or
//! starts with `__`. A `const_expr` uses only numbers, `pi`, functions and
//! constants (a constant only those declared before it); parameter defaults
//! are evaluated to `f64` here, constants are kept as expressions for the
//! engine to fold. `lagrangian` and `constraints` may use everything,
//! including the time `t` and velocities `dot(q)`. Force blocks list
//! components by coordinate (absent = 0); only `nonideal_forces` (and
//! `nonideal` effects, see [`scenes`](crate::scenes)) may use `psi[j]`, the multiplier of
//! constraint `j` (0-based), parsed as `"psi" "[" integer "]"`.
//!
//! An event `name: falling(y) terminal` is a function `g(t,q,v)` (no
//! multipliers) whose zeros the integration driver locates on the dense
//! output: `rising` counts crossings from negative to non-negative,
//! `falling` the reverse, `crossing` (or no keyword) both; `terminal` ends
//! the run at the first counted crossing. Event names are distinct from each
//! other (they live in their own namespace, apart from coordinates and
//! parameters).
//!
//! ```text
//! nonholonomic_system! {
//!     /// Skate on an inclined plane
//!     pub struct Skate {
//!         coordinates: [x, y, theta],
//!         parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
//!         lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
//!         constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
//!     }
//! }
//! ```

mod effects;
mod eval;
mod expr;
mod forces;
mod locate;
mod names;
#[cfg(test)]
mod tests;
mod validate;

pub use locate::{find_declaration, LocateError};
pub use validate::validate;

/// The path under which callers find the parsing-and-desugaring of a
/// declaration with scenes.
pub mod scenes {
    pub use super::effects::EFFECT_KINDS;
    pub use crate::scenes::parse_with_scenes;
}

use crate::spec::{
    Constant, ConstraintSpec, Declaration, EventDecl, EventDirection, Named, Parameter, SpecError, SrcExpr, SystemSpec,
};
use expr::{describe, parse_expression, split_commas, Context, Multipliers, Scope};
use names::{list, nearest, reserved_reason};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenStream, TokenTree};
use quote::quote;

/// The section names [`parse`] reads, in the order the documentation lists them.
pub const SECTIONS: [&str; 8] =
    ["coordinates", "parameters", "constants", "lagrangian", "constraints", "forces", "nonideal_forces", "events"];

/// Every section name a declaration may use: [`SECTIONS`] and the optional
/// `effects` and `scenes` that [`parse_declaration`] reads.
pub const ALL_SECTIONS: [&str; 10] = [
    "coordinates",
    "parameters",
    "constants",
    "lagrangian",
    "constraints",
    "forces",
    "nonideal_forces",
    "events",
    "effects",
    "scenes",
];

/// A missing `,` between two sections: the value of section `section` holds
/// a top-level `name:` (a colon that is not part of `::`), which no section
/// value contains, so it starts the next section.
pub(crate) fn missing_section_comma(section: &str, value: &[TokenTree]) -> Option<SpecError> {
    value.windows(2).find_map(|w| match w {
        [TokenTree::Ident(id), TokenTree::Punct(p)]
            if p.as_char() == ':' && p.spacing() == proc_macro2::Spacing::Alone =>
        {
            Some(SpecError {
                span: id.span(),
                message: format!(
                    "missing `,` before `{id}:`: sections are separated by commas, so end the `{section}` section \
                     with `,`"
                ),
            })
        }
        _ => None,
    })
}

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// Parses a whole body of a `nonholonomic_system!` invocation, `effects:`
/// and `scenes:` included (both empty in the result when absent). Never
/// panics; every malformed declaration is a [`SpecError`] at the offending
/// token.
pub fn parse_declaration(input: TokenStream) -> Result<Declaration, SpecError> {
    match effects::parse_with_effects(&input)? {
        Some(declaration) => Ok(declaration),
        None => Ok(Declaration { base: parse(input)?, effects: Vec::new(), scenes: Vec::new() }),
    }
}

/// Parses the body of a `nonholonomic_system!` invocation without `effects:`
/// and `scenes:`. Never panics; every malformed declaration is a
/// [`SpecError`] at the offending token.
pub fn parse(input: TokenStream) -> Result<SystemSpec, SpecError> {
    let tokens: Vec<TokenTree> = input.into_iter().collect();
    let header = parse_header(&tokens)?;
    let sections = parse_sections(&header.name, &header.body)?;
    build(header, sections)
}

/// Everything before and including the struct body.
struct Header {
    attrs: TokenStream,
    vis: TokenStream,
    name: Ident,
    body: Group,
    runtime_path: TokenStream,
}

const EXPECTED_STRUCT: &str = "expected a declaration `pub struct Name { coordinates: [..], lagrangian: .. }`";

fn parse_header(tokens: &[TokenTree]) -> Result<Header, SpecError> {
    let mut i = 0;
    let mut attrs = TokenStream::new();
    let mut runtime_path = quote!(::spark_runtime);
    while let Some(TokenTree::Punct(p)) = tokens.get(i) {
        if p.as_char() != '#' {
            return err(p.span(), format!("unexpected `{}`: {EXPECTED_STRUCT}", p.as_char()));
        }
        match tokens.get(i + 1) {
            Some(TokenTree::Group(g)) if g.delimiter() == Delimiter::Bracket => {
                if let Some(path) = spark_attribute(g)? {
                    runtime_path = path;
                } else {
                    attrs.extend([tokens[i].clone(), tokens[i + 1].clone()]);
                }
                i += 2;
            }
            Some(TokenTree::Punct(bang)) if bang.as_char() == '!' => {
                return err(bang.span(), "inner attributes `#![…]` are not allowed here; use an outer attribute `#[…]`")
            }
            _ => return err(p.span(), "expected an attribute `#[…]` after `#`"),
        }
    }
    let mut vis = TokenStream::new();
    if let Some(TokenTree::Ident(id)) = tokens.get(i) {
        if id == "pub" {
            vis.extend([tokens[i].clone()]);
            i += 1;
            if let Some(TokenTree::Group(g)) = tokens.get(i) {
                if g.delimiter() == Delimiter::Parenthesis {
                    vis.extend([tokens[i].clone()]);
                    i += 1;
                }
            }
        }
    }
    match tokens.get(i) {
        Some(TokenTree::Ident(id)) if id == "struct" => i += 1,
        Some(TokenTree::Ident(id)) => {
            let s = id.to_string();
            let msg = if matches!(tokens.get(i + 1), Some(TokenTree::Group(g)) if g.delimiter() == Delimiter::Brace) {
                format!("missing `struct`: write `struct {s} {{ … }}`")
            } else if ["enum", "fn", "union", "trait", "type", "impl", "mod"].contains(&s.as_str()) {
                format!("`nonholonomic_system!` declares a struct, not `{s}`: write `struct Name {{ … }}`")
            } else {
                format!("expected `struct`, found `{s}`: write `struct Name {{ … }}`")
            };
            return err(id.span(), msg);
        }
        Some(TokenTree::Group(g)) if g.delimiter() == Delimiter::Brace => {
            return err(g.span(), "missing `struct Name` before the body: write `pub struct Name { … }`")
        }
        Some(other) => return err(other.span(), format!("expected `struct`, found {}", describe(other))),
        None => {
            let span = tokens.last().map_or_else(Span::call_site, TokenTree::span);
            return err(span, format!("{EXPECTED_STRUCT}, found nothing"));
        }
    }
    let name = match tokens.get(i) {
        Some(TokenTree::Ident(id)) => {
            if let Some(reason) = names::is_keyword(&id.to_string()).then(|| format!("`{id}` is a Rust keyword")) {
                return err(id.span(), format!("{reason}; choose another struct name"));
            }
            id.clone()
        }
        Some(other) => {
            return err(other.span(), format!("expected the struct's name after `struct`, found {}", describe(other)))
        }
        None => {
            return err(tokens[i - 1].span(), "expected the struct's name after `struct`, e.g. `struct Skate { … }`")
        }
    };
    i += 1;
    let body = match tokens.get(i) {
        Some(TokenTree::Group(g)) if g.delimiter() == Delimiter::Brace => g.clone(),
        Some(TokenTree::Punct(p)) if p.as_char() == '<' => {
            return err(p.span(), "generic parameters are not supported: parameters are runtime fields, declare them under `parameters: { … }`")
        }
        Some(other) => {
            return err(other.span(), format!("expected `{{` after `struct {name}`, found {}: write `struct {name} {{ coordinates: [..], lagrangian: .. }}`", describe(other)))
        }
        None => return err(name.span(), format!("missing body: write `struct {name} {{ coordinates: [..], lagrangian: .. }}`")),
    };
    i += 1;
    if let Some(extra) = tokens.get(i) {
        return err(
            extra.span(),
            format!("unexpected {} after the struct body: `nonholonomic_system!` declares one struct; use one invocation per system", describe(extra)),
        );
    }
    Ok(Header { attrs, vis, name, body, runtime_path })
}

/// `#[spark(crate = path)]` → `Some(path)`; other attributes → `None`.
fn spark_attribute(attr: &Group) -> Result<Option<TokenStream>, SpecError> {
    let toks: Vec<TokenTree> = attr.stream().into_iter().collect();
    let (Some(TokenTree::Ident(id)), rest) = (toks.first(), toks.get(1..).unwrap_or(&[])) else { return Ok(None) };
    if id != "spark" {
        return Ok(None);
    }
    let usage = "write `#[spark(crate = path::to::spark_runtime)]`";
    let [TokenTree::Group(args)] = rest else { return err(id.span(), format!("malformed `spark` attribute: {usage}")) };
    let args: Vec<TokenTree> = args.stream().into_iter().collect();
    match args.as_slice() {
        [TokenTree::Ident(k), TokenTree::Punct(eq), path @ ..]
            if k == "crate" && eq.as_char() == '=' && !path.is_empty() =>
        {
            Ok(Some(path.iter().cloned().collect()))
        }
        [first, ..] => err(first.span(), format!("unknown `spark` option: {usage}")),
        [] => err(id.span(), format!("empty `spark` attribute: {usage}")),
    }
}

/// The raw sections: value tokens with the span of the section name.
#[derive(Default)]
struct Sections {
    coordinates: Option<(Span, Vec<TokenTree>)>,
    parameters: Option<(Span, Vec<TokenTree>)>,
    constants: Option<(Span, Vec<TokenTree>)>,
    lagrangian: Option<(Span, Vec<TokenTree>)>,
    constraints: Option<(Span, Vec<TokenTree>)>,
    forces: Option<(Span, Vec<TokenTree>)>,
    nonideal_forces: Option<(Span, Vec<TokenTree>)>,
    events: Option<(Span, Vec<TokenTree>)>,
    /// Section names in source order (decides which duplicate name is "second").
    order: Vec<&'static str>,
}

fn parse_sections(name: &Ident, body: &Group) -> Result<Sections, SpecError> {
    let toks: Vec<TokenTree> = body.stream().into_iter().collect();
    let mut s = Sections::default();
    let mut previous: Option<&'static str> = None;
    for (piece, comma) in split_commas(&toks) {
        let Some(first) = piece.first() else {
            return err(comma.unwrap_or(body.span()), "unexpected `,`: remove it");
        };
        let section_list = list(&ALL_SECTIONS);
        let ident = match first {
            TokenTree::Ident(id) => id,
            TokenTree::Punct(p) if p.as_char() == '#' => {
                return err(
                    p.span(),
                    format!(
                        "attributes and doc comments are not allowed inside `struct {name}`; put them above `struct`"
                    ),
                )
            }
            other => {
                return err(other.span(), format!("expected a section ({section_list}), found {}", describe(other)))
            }
        };
        let sname = ident.to_string();
        let known = ALL_SECTIONS.iter().find(|s| **s == sname).copied();
        match piece.get(1) {
            Some(TokenTree::Punct(p)) if p.as_char() == ':' => {
                if p.spacing() == proc_macro2::Spacing::Joint
                    && matches!(piece.get(2), Some(TokenTree::Punct(q)) if q.as_char() == ':')
                {
                    return err(p.span(), format!("write `{sname}: …` with a single `:`"));
                }
            }
            _ => {
                let msg = match (known, previous) {
                    (Some(k), _) => format!("expected `:` after `{k}`: write `{k}: …`"),
                    (None, Some(prev)) => format!(
                        "expected a section ({section_list}), found `{sname}`; if it belongs to `{prev}`, remove the `,` before it"
                    ),
                    _ => format!("expected a section ({section_list}), found `{sname}`"),
                };
                return err(ident.span(), msg);
            }
        }
        let Some(kind) = known else {
            let mut msg = format!("unknown section `{sname}`");
            if let Some(n) = nearest(&sname, ALL_SECTIONS) {
                msg.push_str(&format!("; did you mean `{n}`?"));
            }
            msg.push_str(&format!(" Sections: {section_list}."));
            return err(ident.span(), msg);
        };
        let value: Vec<TokenTree> = piece[2..].to_vec();
        if value.is_empty() {
            return err(ident.span(), format!("`{kind}:` has no value; {}", section_example(kind)));
        }
        if let Some(e) = missing_section_comma(kind, &value) {
            return Err(e);
        }
        if kind == "effects" || kind == "scenes" {
            // `parse_declaration` takes these two out before calling
            // `parse`; reaching here means `parse` was called directly.
            return err(
                ident.span(),
                format!("`{kind}:` is read by `spark_symbolic::dsl::parse_declaration`, not by `dsl::parse`"),
            );
        }
        let slot = match kind {
            "coordinates" => &mut s.coordinates,
            "parameters" => &mut s.parameters,
            "constants" => &mut s.constants,
            "lagrangian" => &mut s.lagrangian,
            "forces" => &mut s.forces,
            "nonideal_forces" => &mut s.nonideal_forces,
            "events" => &mut s.events,
            _ => &mut s.constraints,
        };
        if slot.is_some() {
            return err(ident.span(), format!("section `{kind}` appears twice; merge the two into one"));
        }
        *slot = Some((ident.span(), value));
        s.order.push(kind);
        previous = Some(kind);
    }
    Ok(s)
}

fn section_example(kind: &str) -> &'static str {
    match kind {
        "coordinates" => "write e.g. `coordinates: [x, y, theta]`",
        "parameters" => "write e.g. `parameters: { m = 1.0, g = 9.81 }`",
        "constants" => "write e.g. `constants: { two = 2 }`",
        "lagrangian" => "write e.g. `lagrangian: dot(x)^2/2 - x^2/2`",
        "forces" => "write e.g. `forces: { theta: tau, x: -c*dot(x) }` (components by coordinate, absent = 0)",
        "nonideal_forces" => {
            "write e.g. `nonideal_forces: { x: -mu*psi[0]*cos(theta) }` (`psi[j]`: multiplier of constraint j)"
        }
        "events" => "write e.g. `events: { impact: falling(y) terminal, lap: rising(theta - pi) }`",
        _ => "write e.g. `constraints: [ dot(y) - x*dot(z) ]`, or `constraints: []` for none",
    }
}

/// The single group a list-like section must consist of.
fn single_group(kind: &str, span: Span, value: &[TokenTree], delim: Delimiter) -> Result<Group, SpecError> {
    match value {
        [TokenTree::Group(g)] if g.delimiter() == delim => Ok(g.clone()),
        [first, ..] => {
            let shape = if delim == Delimiter::Bracket { "a list in brackets `[ … ]`" } else { "braces `{ … }`" };
            err(first.span(), format!("`{kind}` must be {shape}; {}", section_example(kind)))
        }
        [] => err(span, format!("`{kind}:` has no value; {}", section_example(kind))),
    }
}

/// Checks a new name against the reserved ones and the ones declared so far.
fn declare(ident: &Ident, kind: &'static str, declared: &mut Vec<(String, &'static str)>) -> Result<Named, SpecError> {
    let name = ident.to_string();
    if let Some(reason) = reserved_reason(&name) {
        return err(ident.span(), format!("{reason}; choose another name for this {kind}"));
    }
    if let Some((_, prev)) = declared.iter().find(|(n, _)| *n == name) {
        let what = if *prev == kind {
            format!("`{name}` is declared twice as a {kind}")
        } else {
            format!("`{name}` is already declared as a {prev}")
        };
        return err(ident.span(), format!("{what}; every coordinate, parameter and constant needs its own name"));
    }
    declared.push((name.clone(), kind));
    Ok(Named { name, span: ident.span() })
}

/// Entries `name = value` of `parameters` or `constants`.
fn assignments(kind: &'static str, group: &Group) -> Result<Vec<(Ident, Vec<TokenTree>, Span)>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let example = if kind == "parameter" { "m = 1.0" } else { "two = 2" };
    let mut out = Vec::new();
    for (piece, comma) in split_commas(&toks) {
        let ident = match piece.first() {
            Some(TokenTree::Ident(id)) => id.clone(),
            Some(TokenTree::Punct(p)) if p.as_char() == '#' => {
                return err(
                    p.span(),
                    format!("attributes are not allowed on a {kind}; document it in the struct's doc comment"),
                )
            }
            Some(other) => {
                return err(
                    other.span(),
                    format!("expected a {kind} name, found {}; write e.g. `{example}`", describe(other)),
                )
            }
            None => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
        };
        match piece.get(1) {
            Some(TokenTree::Punct(p)) if p.as_char() == '=' && p.spacing() == proc_macro2::Spacing::Alone => {
                if piece.len() == 2 {
                    return err(p.span(), format!("missing value after `{ident} =`; write e.g. `{ident} = 1.0`"));
                }
                out.push((ident, piece[2..].to_vec(), p.span()));
            }
            Some(TokenTree::Punct(p)) if p.as_char() == ':' => {
                return err(
                    p.span(),
                    format!("write `{ident} = 1.0`: a {kind} is always an f64, give its value after `=`"),
                )
            }
            Some(other) => {
                return err(other.span(), format!("expected `=` after {kind} `{ident}`; write e.g. `{ident} = 1.0`"))
            }
            None => {
                let msg = if kind == "parameter" {
                    format!("parameter `{ident}` needs a default value: write `{ident} = 1.0`")
                } else {
                    format!("constant `{ident}` needs a value: write `{ident} = 2`")
                };
                return err(ident.span(), msg);
            }
        }
    }
    Ok(out)
}

fn build(header: Header, s: Sections) -> Result<SystemSpec, SpecError> {
    let Header { attrs, vis, name, runtime_path, .. } = header;
    // Names, in section source order so that a duplicate is reported where it
    // appears second.
    let mut declared: Vec<(String, &'static str)> = Vec::new();
    let mut coordinates = Vec::new();
    let mut param_raw = Vec::new();
    let mut param_names = Vec::new();
    let mut const_raw = Vec::new();
    let mut const_names = Vec::new();
    for kind in &s.order {
        match *kind {
            "coordinates" => {
                let (span, value) =
                    s.coordinates.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("coordinates", span, value, Delimiter::Bracket)?;
                let toks: Vec<TokenTree> = group.stream().into_iter().collect();
                for (piece, comma) in split_commas(&toks) {
                    match piece.as_slice() {
                        [TokenTree::Ident(id)] => coordinates.push(declare(id, "coordinate", &mut declared)?),
                        [] => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
                        [TokenTree::Ident(id), TokenTree::Ident(next), ..] => {
                            return err(
                                next.span(),
                                format!("missing `,` between coordinates `{id}` and `{next}`: write `{id}, {next}`"),
                            )
                        }
                        [TokenTree::Ident(id), second, ..] => {
                            return err(
                                second.span(),
                                format!("a coordinate is just a name: write `{id}` (coordinates are always f64)"),
                            )
                        }
                        [other, ..] => {
                            return err(
                                other.span(),
                                format!(
                                    "expected a coordinate name, found {}; write e.g. `coordinates: [x, y]`",
                                    describe(other)
                                ),
                            )
                        }
                    }
                }
                if coordinates.is_empty() {
                    return err(group.span(), "no coordinates: declare at least one, e.g. `coordinates: [x, y]`");
                }
            }
            "parameters" => {
                let (span, value) =
                    s.parameters.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("parameters", span, value, Delimiter::Brace)?;
                for (id, value, eq) in assignments("parameter", &group)? {
                    param_names.push(declare(&id, "parameter", &mut declared)?);
                    param_raw.push((value, eq));
                }
            }
            "constants" => {
                let (span, value) = s.constants.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("constants", span, value, Delimiter::Brace)?;
                for (id, value, eq) in assignments("constant", &group)? {
                    const_names.push(declare(&id, "constant", &mut declared)?);
                    const_raw.push((value, eq));
                }
            }
            _ => {}
        }
    }
    if s.coordinates.is_none() {
        return err(name.span(), format!("`struct {name}` has no coordinates: add a section `coordinates: [x, y]`"));
    }
    let Some((lag_span, lag_tokens)) = s.lagrangian.as_ref() else {
        let example = coordinates.first().map_or("x".to_string(), |c| c.name.clone());
        return err(
            name.span(),
            format!("`struct {name}` has no Lagrangian: add a section `lagrangian: …`, e.g. `lagrangian: dot({example})^2/2`"),
        );
    };

    // Constants, in order; each may use earlier ones.
    let mut constants = Vec::new();
    let mut const_values = Vec::new();
    for (i, (value, eq)) in const_raw.iter().enumerate() {
        let scope = Scope {
            coordinates: &coordinates,
            parameters: &param_names,
            constants: &const_names,
            context: Context::Constant(i),
            multipliers: Multipliers::None,
        };
        let what = format!("constant `{}`", const_names[i].name);
        let expr = parse_expression(value, &scope, &what, *eq)?;
        let v = eval::eval(&expr, &const_values)?;
        if !v.is_finite() {
            return err(expr.span(), format!("{what} evaluates to {v}; give it a finite value"));
        }
        const_values.push(v);
        constants.push(Constant { name: const_names[i].clone(), value: expr });
    }

    let mut parameters = Vec::new();
    for (i, (value, eq)) in param_raw.iter().enumerate() {
        let scope = Scope {
            coordinates: &coordinates,
            parameters: &param_names,
            constants: &const_names,
            context: Context::Default(i),
            multipliers: Multipliers::None,
        };
        let what = format!("the default of parameter `{}`", param_names[i].name);
        let expr = parse_expression(value, &scope, &what, *eq)?;
        let v = eval::eval(&expr, &const_values)?;
        if !v.is_finite() {
            return err(expr.span(), format!("{what} evaluates to {v}; give it a finite value"));
        }
        parameters.push(Parameter { name: param_names[i].clone(), default: v });
    }

    let scope = Scope {
        coordinates: &coordinates,
        parameters: &param_names,
        constants: &const_names,
        context: Context::Dynamic,
        multipliers: Multipliers::None,
    };
    let lagrangian = parse_expression(lag_tokens, &scope, "the lagrangian", *lag_span)?;

    let mut constraints = Vec::new();
    if let Some((span, value)) = s.constraints.as_ref() {
        let group = single_group("constraints", *span, value, Delimiter::Bracket)?;
        let toks: Vec<TokenTree> = group.stream().into_iter().collect();
        for (j, (piece, comma)) in split_commas(&toks).into_iter().enumerate() {
            let Some(first) = piece.first() else {
                return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it");
            };
            let what = format!("constraint {}", j + 1);
            let expr = parse_expression(&piece, &scope, &what, first.span())?;
            let last = piece.last().map_or(first.span(), TokenTree::span);
            constraints.push(ConstraintSpec {
                expr,
                span: first.span().join(last).unwrap_or(first.span()),
                holonomic: false,
            });
        }
    }

    let mut external_force = Vec::new();
    if let Some((span, value)) = s.forces.as_ref() {
        let group = single_group("forces", *span, value, Delimiter::Brace)?;
        let scope = Scope { multipliers: Multipliers::Forbidden { named: &[] }, ..scope };
        let example = format!("`forces: {{ {}: tau }}`", coordinates[0].name);
        external_force = forces::parse_force_block(&group, &scope, "the external force", &example)?;
    }
    let mut nonideal_force = Vec::new();
    if let Some((span, value)) = s.nonideal_forces.as_ref() {
        let group = single_group("nonideal_forces", *span, value, Delimiter::Brace)?;
        let scope = Scope { multipliers: Multipliers::Allowed { base: constraints.len(), named: &[] }, ..scope };
        let example = format!("`nonideal_forces: {{ {}: -mu*psi[0] }}`", coordinates[0].name);
        nonideal_force = forces::parse_force_block(&group, &scope, "the non-ideal force", &example)?;
    }

    let mut events = Vec::new();
    if let Some((span, value)) = s.events.as_ref() {
        let group = single_group("events", *span, value, Delimiter::Brace)?;
        events = parse_events(&group, &scope)?;
    }

    let mut attrs = attrs;
    if parameters.iter().any(|p| p.name.name.chars().any(char::is_uppercase)) {
        // Physics names parameters `I`, `M`, `R`; they become fields, which
        // rustc would otherwise flag at the user's token.
        attrs.extend(quote::quote!(#[allow(non_snake_case)]));
    }
    Ok(SystemSpec {
        attrs,
        vis,
        name,
        coordinates,
        parameters,
        constants,
        lagrangian,
        constraints,
        external_force,
        nonideal_force,
        events,
        runtime_path,
    })
}

/// The entries `name: [rising|falling|crossing](expr) [terminal]` of an
/// `events` section.
fn parse_events(group: &Group, scope: &Scope<'_>) -> Result<Vec<EventDecl>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let example = "`events: { impact: falling(y) terminal }`";
    let pieces = split_commas(&toks);
    if pieces.is_empty() {
        return err(group.span(), format!("`events` is empty; write e.g. {example}, or remove the section"));
    }
    let mut out: Vec<EventDecl> = Vec::new();
    for (piece, comma) in pieces {
        let (ident, value) = match piece.as_slice() {
            [] => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
            [TokenTree::Ident(id), TokenTree::Punct(p), value @ ..] if p.as_char() == ':' => {
                if value.is_empty() {
                    return err(p.span(), format!("event `{id}` has no function: write an expression after `:`"));
                }
                (id, value)
            }
            [TokenTree::Ident(id), second, ..] => {
                return err(second.span(), format!("expected `:` after event `{id}`: write e.g. {example}"))
            }
            [first, ..] => {
                return err(
                    first.span(),
                    format!("expected an event name, found {}; write e.g. {example}", describe(first)),
                )
            }
        };
        if out.iter().any(|e| *ident == e.name.name) {
            return err(ident.span(), format!("event `{ident}` is declared twice; give each event its own name"));
        }
        out.push(parse_event(ident, value, scope)?);
    }
    Ok(out)
}

/// One event's value `[rising|falling|crossing](expr) [terminal]` (or a bare
/// `expr [terminal]`), named `ident`.
pub(crate) fn parse_event(ident: &Ident, value: &[TokenTree], scope: &Scope<'_>) -> Result<EventDecl, SpecError> {
    let mut value = value;
    let name = ident.to_string();
    if let Some(reason) = reserved_reason(&name) {
        return err(ident.span(), format!("{reason}; choose another name for this event"));
    }
    let mut terminal = false;
    if let [rest @ .., TokenTree::Ident(last)] = value {
        if last == "terminal" {
            if rest.is_empty() {
                return err(last.span(), format!("event `{name}` has no function before `terminal`"));
            }
            terminal = true;
            value = rest;
        }
    }
    let mut direction = EventDirection::Both;
    let mut inner: Vec<TokenTree> = value.to_vec();
    if let [TokenTree::Ident(kw), TokenTree::Group(g)] = value {
        let kind = kw.to_string();
        let known = match kind.as_str() {
            "rising" => Some(EventDirection::Rising),
            "falling" => Some(EventDirection::Falling),
            "crossing" => Some(EventDirection::Both),
            _ => None,
        };
        if let Some(d) = known {
            if g.delimiter() != Delimiter::Parenthesis {
                return err(g.span(), format!("write `{kind}(expression)` with parentheses"));
            }
            direction = d;
            inner = g.stream().into_iter().collect();
            if inner.is_empty() {
                return err(g.span(), format!("`{kind}()` is empty: write the event function inside"));
            }
        }
    }
    if let Some(TokenTree::Ident(id)) = inner.last() {
        if id == "terminal" {
            return err(id.span(), "`terminal` comes last, after the event function: `name: falling(y) terminal`");
        }
    }
    let what = format!("event `{name}`");
    let expr = parse_expression(&inner, scope, &what, ident.span())?;
    Ok(EventDecl { name: Named { name, span: ident.span() }, expr, direction, terminal })
}

/// Evaluates a constant [`SrcExpr`] (numbers, `pi`, functions and constants
/// with the given values), e.g. to fold a [`Constant`]'s value. Errors name
/// the first non-constant leaf.
pub fn eval_constant(expr: &SrcExpr, constant_values: &[f64]) -> Result<f64, SpecError> {
    eval::eval(expr, constant_values)
}
