//! Building a [`SystemSpec`] from the raw sections, in named steps: the
//! declared names (coordinates, parameters, constants, each distinct and
//! none reserved), the folded constants and parameter defaults, then the
//! expressions of `L`, the constraints, the forces and the events.

use super::eval;
use super::events::parse_events;
use super::expr::{describe, parse_expression, split_commas};
use super::forces::parse_force_block;
use super::names::reserved_reason;
use super::scope::{Context, Multipliers, Scope};
use super::{single_group, Header, Sections, MAX_COORDINATES};
use crate::spec::{Constant, ConstraintSpec, Named, Parameter, SpecError, SrcExpr, SystemSpec};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenTree};

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
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

/// The declared names, in section source order so that a duplicate is
/// reported where it appears second, with the unparsed values of the
/// parameters and constants (and the span of each `=`).
struct Names {
    coordinates: Vec<Named>,
    parameters: Vec<Named>,
    parameter_values: Vec<(Vec<TokenTree>, Span)>,
    constants: Vec<Named>,
    constant_values: Vec<(Vec<TokenTree>, Span)>,
}

impl Names {
    fn scope(&self, context: Context) -> Scope<'_> {
        Scope {
            coordinates: &self.coordinates,
            parameters: &self.parameters,
            constants: &self.constants,
            context,
            multipliers: Multipliers::None,
        }
    }
}

/// Reads the sections in source order and declares their names.
fn declare_names(name: &Ident, s: &Sections) -> Result<Names, SpecError> {
    let mut declared: Vec<(String, &'static str)> = Vec::new();
    let mut names = Names {
        coordinates: Vec::new(),
        parameters: Vec::new(),
        parameter_values: Vec::new(),
        constants: Vec::new(),
        constant_values: Vec::new(),
    };
    for kind in &s.order {
        match *kind {
            "coordinates" => {
                let (span, value) =
                    s.coordinates.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("coordinates", span, value, Delimiter::Bracket)?;
                names.coordinates = declare_coordinates(&group, &mut declared)?;
            }
            "parameters" => {
                let (span, value) =
                    s.parameters.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("parameters", span, value, Delimiter::Brace)?;
                for (id, value, eq) in assignments("parameter", &group)? {
                    names.parameters.push(declare(&id, "parameter", &mut declared)?);
                    names.parameter_values.push((value, eq));
                }
            }
            "constants" => {
                let (span, value) = s.constants.as_ref().map(|(a, b)| (*a, b.as_slice())).unwrap_or((name.span(), &[]));
                let group = single_group("constants", span, value, Delimiter::Brace)?;
                for (id, value, eq) in assignments("constant", &group)? {
                    names.constants.push(declare(&id, "constant", &mut declared)?);
                    names.constant_values.push((value, eq));
                }
            }
            _ => {}
        }
    }
    Ok(names)
}

/// The names of a `coordinates: [x, y]` list, at least one.
fn declare_coordinates(group: &Group, declared: &mut Vec<(String, &'static str)>) -> Result<Vec<Named>, SpecError> {
    let mut coordinates = Vec::new();
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    for (piece, comma) in split_commas(&toks) {
        match piece.as_slice() {
            [TokenTree::Ident(id)] => coordinates.push(declare(id, "coordinate", declared)?),
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
                    format!("expected a coordinate name, found {}; write e.g. `coordinates: [x, y]`", describe(other)),
                )
            }
        }
    }
    if coordinates.is_empty() {
        return err(group.span(), "no coordinates: declare at least one, e.g. `coordinates: [x, y]`");
    }
    if coordinates.len() > MAX_COORDINATES {
        return err(
            group.span(),
            format!(
                "{} coordinates: spark supports at most {MAX_COORDINATES} (the symbolic derivatives take time \
                 growing like n², and a step's dense Newton matrix and stack use like n²); split the system into \
                 smaller ones or reduce the coordinates",
                coordinates.len()
            ),
        );
    }
    Ok(coordinates)
}

/// The constants, in order (each may use earlier ones), and their values.
fn fold_constants(names: &Names) -> Result<(Vec<Constant>, Vec<f64>), SpecError> {
    let mut constants = Vec::new();
    let mut values = Vec::new();
    for (i, (value, eq)) in names.constant_values.iter().enumerate() {
        let what = format!("constant `{}`", names.constants[i].name);
        let expr = parse_expression(value, &names.scope(Context::Constant(i)), &what, *eq)?;
        let v = eval::eval(&expr, &values)?;
        if !v.is_finite() {
            return err(expr.span(), format!("{what} evaluates to {v}; give it a finite value"));
        }
        values.push(v);
        constants.push(Constant { name: names.constants[i].clone(), value: expr });
    }
    Ok((constants, values))
}

/// The parameters with their default values.
fn evaluate_defaults(names: &Names, constant_values: &[f64]) -> Result<Vec<Parameter>, SpecError> {
    let mut parameters = Vec::new();
    for (i, (value, eq)) in names.parameter_values.iter().enumerate() {
        let what = format!("the default of parameter `{}`", names.parameters[i].name);
        let expr = parse_expression(value, &names.scope(Context::Default(i)), &what, *eq)?;
        let v = eval::eval(&expr, constant_values)?;
        if !v.is_finite() {
            return err(expr.span(), format!("{what} evaluates to {v}; give it a finite value"));
        }
        parameters.push(Parameter { name: names.parameters[i].clone(), default: v });
    }
    Ok(parameters)
}

/// The `constraints: [ … ]` list, each with the span of its whole text.
fn parse_constraints(s: &Sections, scope: &Scope<'_>) -> Result<Vec<ConstraintSpec>, SpecError> {
    let mut constraints = Vec::new();
    let Some((span, value)) = s.constraints.as_ref() else {
        return Ok(constraints);
    };
    let group = single_group("constraints", *span, value, Delimiter::Bracket)?;
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    for (j, (piece, comma)) in split_commas(&toks).into_iter().enumerate() {
        let Some(first) = piece.first() else {
            return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it");
        };
        let what = format!("constraint {}", j + 1);
        let expr = parse_expression(&piece, scope, &what, first.span())?;
        let last = piece.last().map_or(first.span(), TokenTree::span);
        constraints.push(ConstraintSpec {
            expr,
            span: first.span().join(last).unwrap_or(first.span()),
            holonomic: false,
        });
    }
    Ok(constraints)
}

/// The `forces` and `nonideal_forces` blocks (empty when absent or written
/// `{}`); only the latter may use the multipliers of the `m` constraints.
type ForceBlocks = (Vec<Option<SrcExpr>>, Vec<Option<SrcExpr>>);

fn parse_forces(s: &Sections, scope: &Scope<'_>, coordinate: &str, m: usize) -> Result<ForceBlocks, SpecError> {
    // An empty block declares no force, as an empty `parameters`, `constraints`
    // or `events` block declares none: it stays an empty list rather than N
    // zero components, so the system has no force method and reports no
    // forcing, exactly as without the block.
    let mut external_force = Vec::new();
    if let Some((span, value)) = s.forces.as_ref() {
        let group = single_group("forces", *span, value, Delimiter::Brace)?;
        let scope = Scope { multipliers: Multipliers::Forbidden { named: &[] }, ..*scope };
        let example = format!("`forces: {{ {coordinate}: tau }}`");
        if !group.stream().is_empty() {
            external_force = parse_force_block(&group, &scope, "the external force", &example)?;
        }
    }
    let mut nonideal_force = Vec::new();
    if let Some((span, value)) = s.nonideal_forces.as_ref() {
        let group = single_group("nonideal_forces", *span, value, Delimiter::Brace)?;
        let scope = Scope { multipliers: Multipliers::Allowed { base: m, named: &[] }, ..*scope };
        let example = format!("`nonideal_forces: {{ {coordinate}: -mu*psi[0] }}`");
        if !group.stream().is_empty() {
            nonideal_force = parse_force_block(&group, &scope, "the non-ideal force", &example)?;
        }
    }
    Ok((external_force, nonideal_force))
}

/// The spec of a declaration from its header and raw sections.
pub(super) fn build(header: Header, s: Sections) -> Result<SystemSpec, SpecError> {
    let Header { attrs, vis, name, runtime_path, .. } = header;
    let names = declare_names(&name, &s)?;
    if s.coordinates.is_none() {
        return err(name.span(), format!("`struct {name}` has no coordinates: add a section `coordinates: [x, y]`"));
    }
    let Some((lag_span, lag_tokens)) = s.lagrangian.as_ref() else {
        let example = names.coordinates.first().map_or("x".to_string(), |c| c.name.clone());
        return err(
            name.span(),
            format!("`struct {name}` has no Lagrangian: add a section `lagrangian: …`, e.g. `lagrangian: dot({example})^2/2`"),
        );
    };
    let (constants, constant_values) = fold_constants(&names)?;
    let parameters = evaluate_defaults(&names, &constant_values)?;
    let scope = names.scope(Context::Dynamic);
    let lagrangian = parse_expression(lag_tokens, &scope, "the lagrangian", *lag_span)?;
    let constraints = parse_constraints(&s, &scope)?;
    let (external_force, nonideal_force) = parse_forces(&s, &scope, &names.coordinates[0].name, constraints.len())?;
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
    let coordinates = names.coordinates;
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
