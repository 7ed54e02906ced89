//! The `events` section and the `event(…)` effect: an event's name,
//! direction keyword, function and `terminal` flag.

use super::expr::{describe, parse_expression, split_commas};
use super::names::reserved_reason;
use super::scope::Scope;
use crate::spec::{EventDecl, EventDirection, Named, SpecError};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenTree};

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// The entries `name: [rising|falling|crossing](expr) [terminal]` of an
/// `events` section. An empty section declares no event, as an empty
/// `parameters`, `constraints` or `forces` section declares none: the
/// system is then the one without the section.
pub(super) fn parse_events(group: &Group, scope: &Scope<'_>) -> Result<Vec<EventDecl>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let example = "`events: { impact: falling(y) terminal }`";
    let pieces = split_commas(&toks);
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
