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
//!              | "forces"      ":" "{" (coordinate ":" expr),* ","? "}"    external force f(t,q,v); empty = none
//!              | "nonideal_forces" ":" "{" (coordinate ":" expr),* ","? "}"  non-ideal force N(t,q,v,ψ); empty = none
//!              | "events"      ":" "{" (name ":" event),* ","? "}"       zeros of g(t,q,v) to locate; empty = none
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

mod build;
mod effects;
mod eval;
mod events;
mod expr;
mod forces;
mod locate;
mod names;
mod scope;
#[cfg(test)]
mod tests;
mod validate;

pub use expr::MAX_OPERATIONS;
pub use locate::{find_declaration, LocateError};
pub use validate::validate;

use crate::spec::{Declaration, SpecError, SrcExpr, SystemSpec};
use expr::{describe, split_commas};
use names::{list, nearest};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenStream, TokenTree};
use quote::quote;

/// The most coordinates a declaration may have. The engine's work grows
/// like `n²` (every derivative is a pass over the expression graph, ≈ 4 s
/// at `n = 400` and 15 s at `n = 800` for the macro, optimized; a cargo
/// build runs the macro unoptimized, several times slower), a step's
/// Newton matrix is dense `D × D` with `D = s(n + m) + n`, and a step's
/// stack use grows like `10 n²` bytes: at `n = 401` it is 1.6 MiB, within
/// the 2 MiB of a rayon worker that runs an ensemble's members
/// (`tests/tests/large_systems.rs`), and beyond about `n = 440` it is not.
/// A larger declaration is refused at its `coordinates` list, before any
/// differentiation, instead of stalling the compiler or `spark.compile`.
pub const MAX_COORDINATES: usize = 400;

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
    build::build(header, sections)
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
            if let Some(reason) = names::struct_name_reason(&id.to_string(), "struct name") {
                return err(id.span(), reason);
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

/// Evaluates a constant [`SrcExpr`] (numbers, `pi`, functions and constants
/// with the given values), e.g. to fold a [`Constant`](crate::spec::Constant)'s value. Errors name
/// the first non-constant leaf.
pub fn eval_constant(expr: &SrcExpr, constant_values: &[f64]) -> Result<f64, SpecError> {
    eval::eval(expr, constant_values)
}
