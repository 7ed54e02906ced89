//! Force blocks `{ coordinate: expr, … }`: the components of an external
//! force `f(t,q,v)` or a non-ideal constraint force `N(t,q,v,ψ)` keyed by the
//! coordinate they act on (absent components are zero), shared by the
//! `forces:`/`nonideal_forces:` sections and the `force`/`nonideal` effects.

use super::expr::{describe, parse_expression, split_commas};
use super::names::{list, nearest};
use super::scope::Scope;
use crate::spec::{SpecError, SrcExpr};
use proc_macro2::{Group, TokenTree};

fn err<T>(span: proc_macro2::Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// Parses the braces of a force block into one entry per coordinate
/// (`None` = zero). `what` names the block in messages ("force `drive`"),
/// `example` is a corrected form to suggest.
pub(crate) fn parse_force_block(
    group: &Group,
    scope: &Scope<'_>,
    what: &str,
    example: &str,
) -> Result<Vec<Option<SrcExpr>>, SpecError> {
    let coords: Vec<&str> = scope.coordinates.iter().map(|c| c.name.as_str()).collect();
    let mut out: Vec<Option<SrcExpr>> = vec![None; coords.len()];
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let pieces = split_commas(&toks);
    if pieces.is_empty() {
        return err(group.span(), format!("{what} has no components; write e.g. {example}"));
    }
    for (piece, comma) in pieces {
        let (ident, value) = match piece.as_slice() {
            [] => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
            [TokenTree::Ident(id), TokenTree::Punct(p), value @ ..] if p.as_char() == ':' => {
                if value.is_empty() {
                    return err(
                        p.span(),
                        format!("the `{id}` component of {what} is empty: write an expression after `:`"),
                    );
                }
                (id, value)
            }
            [TokenTree::Ident(id), second, ..] => {
                return err(
                    second.span(),
                    format!(
                        "expected `:` after `{id}` in {what}: components are `coordinate: expression`, e.g. {example}"
                    ),
                )
            }
            [first, ..] => {
                return err(
                    first.span(),
                    format!("expected `coordinate: expression` in {what}, found {}; e.g. {example}", describe(first)),
                )
            }
        };
        let name = ident.to_string();
        let Some(i) = coords.iter().position(|c| *c == name) else {
            let mut msg = if scope.parameters.iter().any(|p| p.name == name) {
                format!("`{name}` is a parameter, not a coordinate: a component of {what} is keyed by the coordinate it acts on")
            } else {
                format!("unknown coordinate `{name}` in {what}")
            };
            if let Some(n) = nearest(&name, coords.iter().copied()) {
                msg.push_str(&format!("; did you mean `{n}`?"));
            }
            msg.push_str(&format!(" Coordinates: {}.", list(&coords)));
            return err(ident.span(), msg);
        };
        if out[i].is_some() {
            return err(
                ident.span(),
                format!("coordinate `{name}` appears twice in {what}; write its component once, as a sum"),
            );
        }
        let component = format!("the `{name}` component of {what}");
        out[i] = Some(parse_expression(value, scope, &component, ident.span())?);
    }
    Ok(out)
}
