//! Parsing of the optional `effects:` and `scenes:` sections into a
//! [`Declaration`]: each effect's expressions, and each scene's list of
//! effects resolved to their declarations. Turning a scene into a plain
//! [`SystemSpec`] is the next stage, [`crate::scenes`].
//!
//! ```text
//! effects := "effects" ":" "{" (name ":" effect),* ","? "}"
//! effect  := "potential"  "(" expr ")"     U(t,q,v), subtracted from L
//!          | "constraint" "(" expr ")"     an extra constraint k(t,q,v) = 0
//!          | "holonomic"  "(" expr ")"     g(t,q) = 0, imposed as k = g_t + g_q v (g kept for drift)
//!          | "force"    "{" (coordinate ":" expr),* "}"   external force f(t,q,v); absent = 0
//!          | "nonideal" "{" (coordinate ":" expr),* "}"   non-ideal constraint force N(t,q,v,ψ)
//!          | "event"    "(" event ")"                  an event located by the driver (see `dsl` docs)
//! scenes  := "scenes" ":" "{" (Name "=" "[" name,* "]"),* ","? "}"
//! ```
//!
//! In a `nonideal` effect the multiplier of a constraint effect is written
//! by the effect's name, that of base constraint `j` as `psi[j]`. Until a
//! scene fixes the constraint order, the name of effect `e` stands for the
//! provisional index `M_base + e`. A `force` may not use multipliers (it
//! would be a non-ideal force).

use super::expr::{describe, parse_expression, split_commas};
use super::forces::parse_force_block;
use super::names::{list, nearest, reserved_reason, struct_name_reason};
use super::scope::{Context, Multipliers, Scope};
use crate::spec::{Declaration, Effect, EffectDecl, SceneDecl, SpecError, SrcExpr, SystemSpec};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenStream, TokenTree};

/// The effect kinds, as written.
pub const EFFECT_KINDS: [&str; 6] = ["potential", "constraint", "holonomic", "force", "nonideal", "event"];

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// The declaration with its effects and scenes, or `None` when the input
/// has neither `effects:` nor `scenes:` (a plain declaration, for
/// [`super::parse`]).
pub(super) fn parse_with_effects(input: &TokenStream) -> Result<Option<Declaration>, SpecError> {
    let tokens: Vec<TokenTree> = input.clone().into_iter().collect();
    let Some(body_at) =
        tokens.iter().position(|t| matches!(t, TokenTree::Group(g) if g.delimiter() == Delimiter::Brace))
    else {
        return Ok(None);
    };
    let TokenTree::Group(body) = &tokens[body_at] else { return Ok(None) };
    let inner: Vec<TokenTree> = body.stream().into_iter().collect();
    let (mut effects, mut scenes, mut kept) = (None, None, Vec::<TokenTree>::new());
    for (piece, comma) in split_commas(&inner) {
        let section = match (piece.first(), piece.get(1)) {
            (Some(TokenTree::Ident(id)), Some(TokenTree::Punct(p))) if p.as_char() == ':' => {
                let name = id.to_string();
                (name == "effects" || name == "scenes").then_some((name, id.span()))
            }
            _ => None,
        };
        match section {
            Some((name, span)) => {
                let slot = if name == "effects" { &mut effects } else { &mut scenes };
                if slot.is_some() {
                    return err(span, format!("section `{name}` appears twice; merge the two into one"));
                }
                if let Some(e) = super::missing_section_comma(&name, piece.get(2..).unwrap_or(&[])) {
                    return Err(e);
                }
                let group = match piece.get(2..) {
                    Some([TokenTree::Group(g)]) if g.delimiter() == Delimiter::Brace => g.clone(),
                    _ => return err(span, format!("`{name}:` takes a `{{ … }}` block, e.g. {}", example(&name))),
                };
                *slot = Some((span, group));
            }
            None => {
                kept.extend(piece);
                if comma.is_some() {
                    kept.push(TokenTree::Punct(proc_macro2::Punct::new(',', proc_macro2::Spacing::Alone)));
                }
            }
        }
    }
    if effects.is_none() && scenes.is_none() {
        return Ok(None);
    }
    let mut stripped = tokens.clone();
    let mut g = Group::new(Delimiter::Brace, kept.into_iter().collect());
    g.set_span(body.span());
    stripped[body_at] = TokenTree::Group(g);
    let base = super::parse(stripped.into_iter().collect())?;
    let declared = match &effects {
        Some((_, group)) => parse_effects(&base, group)?,
        None => Vec::new(),
    };
    let Some((scenes_span, scenes_group)) = scenes else {
        let span = effects.as_ref().map_or(body.span(), |(s, _)| *s);
        return err(span, "`effects:` without `scenes:` selects nothing; add e.g. `scenes: { Driven = [drive] }`");
    };
    let scenes = parse_scenes(&base, &declared, &scenes_group, scenes_span)?;
    Ok(Some(Declaration { base, effects: declared, scenes }))
}

fn example(section: &str) -> &'static str {
    if section == "effects" {
        "`effects: { spring: potential(k/2*x^2), rod: holonomic(x^2 + y^2 - 1) }`"
    } else {
        "`scenes: { Free = [], Sprung = [spring] }`"
    }
}

/// The kind keyword and argument group of one `name: kind(…)` / `name: kind { … }` entry.
struct RawEffect {
    name: Ident,
    kind: Ident,
    args: Group,
}

fn raw_effects(group: &Group) -> Result<Vec<RawEffect>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let mut out: Vec<RawEffect> = Vec::new();
    for (piece, comma) in split_commas(&toks) {
        let (name, kind, args) = match piece.as_slice() {
            [] => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
            [TokenTree::Ident(name), TokenTree::Punct(p), TokenTree::Ident(kind), TokenTree::Group(args)]
                if p.as_char() == ':' && matches!(args.delimiter(), Delimiter::Parenthesis | Delimiter::Brace) =>
            {
                (name, kind, args)
            }
            [TokenTree::Ident(name), TokenTree::Punct(p), TokenTree::Ident(kind), rest @ ..] if p.as_char() == ':' => {
                let at = rest.first().map_or(kind.span(), TokenTree::span);
                let shape = if is_force_kind(&kind.to_string()) {
                    format!("`{name}: {kind} {{ coordinate: expression, … }}`")
                } else {
                    format!("`{name}: {kind}(…)` with one parenthesized argument")
                };
                return err(at, format!("effect `{name}`: write {shape}"));
            }
            [first, ..] => {
                return err(
                    first.span(),
                    format!(
                        "expected `name: kind(…)` or `name: kind {{ … }}` in `effects`, found {}; e.g. {}",
                        describe(first),
                        example("effects")
                    ),
                )
            }
        };
        if out.iter().any(|e| e.name == *name) {
            return err(name.span(), format!("effect `{name}` is declared twice; give each effect its own name"));
        }
        out.push(RawEffect { name: name.clone(), kind: kind.clone(), args: args.clone() });
    }
    Ok(out)
}

fn is_force_kind(kind: &str) -> bool {
    kind == "force" || kind == "nonideal"
}

fn parse_effects(base: &SystemSpec, group: &Group) -> Result<Vec<EffectDecl>, SpecError> {
    let names = |v: &[crate::spec::Parameter]| v.iter().map(|p| p.name.clone()).collect::<Vec<_>>();
    let params = names(&base.parameters);
    let consts: Vec<_> = base.constants.iter().map(|c| c.name.clone()).collect();
    let scope = Scope {
        coordinates: &base.coordinates,
        parameters: &params,
        constants: &consts,
        context: Context::Dynamic,
        multipliers: Multipliers::None,
    };
    let raw = raw_effects(group)?;
    // Constraint effects name their multiplier inside `nonideal` forces. Until
    // a scene fixes the constraint order, effect `e` stands for the index
    // `M_base + e` (see `crate::scenes`).
    let m_base = base.constraints.len();
    let mut named: Vec<(String, usize)> = Vec::new();
    for (e, r) in raw.iter().enumerate() {
        if matches!(r.kind.to_string().as_str(), "constraint" | "holonomic") {
            let n = r.name.to_string();
            // The name is read inside expressions, where `t`, `pi` and the
            // functions keep their own meaning: `nonideal { y: -mu*pi }`
            // would be −μπ, not −μ times the multiplier of a constraint `pi`.
            if let Some(reason) = reserved_reason(&n) {
                return err(
                    r.name.span(),
                    format!(
                        "{reason}; a constraint effect's name stands for its multiplier in `nonideal` forces, so \
                         choose another name for this effect"
                    ),
                );
            }
            let clash = base.coordinates.iter().map(|c| &c.name).chain(params.iter().map(|p| &p.name));
            if clash.chain(consts.iter().map(|c| &c.name)).any(|d| *d == n) {
                return err(
                    r.name.span(),
                    format!(
                        "constraint effect `{n}` has the name of a coordinate, parameter or constant; a constraint \
                         effect's name stands for its multiplier in `nonideal` forces, so give it its own name"
                    ),
                );
            }
            named.push((n, m_base + e));
        }
    }
    let mut out: Vec<EffectDecl> = Vec::new();
    for r in &raw {
        let RawEffect { name, kind, args } = r;
        let kind_s = kind.to_string();
        let braces = args.delimiter() == Delimiter::Brace;
        if EFFECT_KINDS.contains(&kind_s.as_str()) && braces != is_force_kind(&kind_s) {
            let shape = if braces {
                format!("`{name}: {kind_s}(…)` with parentheses")
            } else {
                format!("`{name}: {kind_s} {{ coordinate: expression, … }}` with braces, components by coordinate name")
            };
            return err(args.span(), format!("effect `{name}`: write {shape}"));
        }
        let arg_tokens: Vec<TokenTree> = args.stream().into_iter().collect();
        let what = format!("effect `{name}`");
        let effect = match kind_s.as_str() {
            "potential" => Effect::Potential(parse_expression(&arg_tokens, &scope, &what, args.span())?),
            "constraint" => {
                let expr = parse_expression(&arg_tokens, &scope, &what, args.span())?;
                if !mentions(&expr, &|e| matches!(e, SrcExpr::Velocity(..))) {
                    if !mentions(&expr, &|e| matches!(e, SrcExpr::Coord(..))) {
                        return err(args.span(), no_coordinate_message("constraint", name));
                    }
                    return err(
                        args.span(),
                        format!(
                            "constraint `{name}` does not involve velocities; declare it as `{name}: holonomic(…)`"
                        ),
                    );
                }
                Effect::Constraint(expr, args.span())
            }
            "holonomic" => {
                let g = parse_expression(&arg_tokens, &scope, &what, args.span())?;
                if !mentions(&g, &|e| matches!(e, SrcExpr::Coord(..) | SrcExpr::Velocity(..))) {
                    return err(args.span(), no_coordinate_message("holonomic constraint", name));
                }
                if let Some(at) = first_leaf(&g, &|e| matches!(e, SrcExpr::Velocity(..))) {
                    return err(
                        at,
                        "a holonomic constraint g(t, q) = 0 may not involve velocities; use `constraint(…)`",
                    );
                }
                Effect::Holonomic(g, args.span())
            }
            "force" => {
                let scope = Scope { multipliers: Multipliers::Forbidden { named: &named }, ..scope };
                let example = format!("`{name}: force {{ {}: … }}`", base.coordinates[0].name);
                Effect::Force(parse_force_block(args, &scope, &format!("force `{name}`"), &example)?)
            }
            "event" => Effect::Event(super::events::parse_event(name, &arg_tokens, &scope)?),
            "nonideal" => {
                let scope = Scope { multipliers: Multipliers::Allowed { base: m_base, named: &named }, ..scope };
                let example = format!("`{name}: nonideal {{ {}: … }}`", base.coordinates[0].name);
                Effect::Nonideal(parse_force_block(args, &scope, &format!("non-ideal force `{name}`"), &example)?)
            }
            other => {
                let mut msg = format!("unknown effect kind `{other}`");
                if let Some(n) = nearest(other, EFFECT_KINDS) {
                    msg.push_str(&format!("; did you mean `{n}`?"));
                }
                msg.push_str(&format!(" Kinds: {}.", list(&EFFECT_KINDS)));
                return err(kind.span(), msg);
            }
        };
        out.push(EffectDecl { name: name.clone(), effect });
    }
    Ok(out)
}

/// The `scenes:` entries `Name = [effect, …]`, each effect resolved to its
/// index in `effects`.
fn parse_scenes(
    base: &SystemSpec,
    effects: &[EffectDecl],
    group: &Group,
    section: Span,
) -> Result<Vec<SceneDecl>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let mut scenes: Vec<SceneDecl> = Vec::new();
    for (piece, comma) in split_commas(&toks) {
        let (name, list_group) = match piece.as_slice() {
            [] => return err(comma.unwrap_or(group.span()), "unexpected `,`: remove it"),
            [TokenTree::Ident(name), TokenTree::Punct(p), TokenTree::Group(g)]
                if p.as_char() == '=' && g.delimiter() == Delimiter::Bracket =>
            {
                (name, g)
            }
            [first, ..] => {
                return err(
                    first.span(),
                    format!(
                        "expected `Name = [effect, …]` in `scenes`, found {}; e.g. {}",
                        describe(first),
                        example("scenes")
                    ),
                )
            }
        };
        // Each scene is a struct of its own, named by the scene.
        if let Some(reason) = struct_name_reason(&name.to_string(), "scene name") {
            return err(name.span(), reason);
        }
        if *name == base.name || scenes.iter().any(|s| s.name == *name) {
            return err(name.span(), format!("scene `{name}` is declared twice (or named like the base struct)"));
        }
        let items: Vec<TokenTree> = list_group.stream().into_iter().collect();
        let mut chosen: Vec<(usize, Ident)> = Vec::new();
        for (item, comma) in split_commas(&items) {
            let id = match item.as_slice() {
                [TokenTree::Ident(id)] => id,
                [] => return err(comma.unwrap_or(list_group.span()), "unexpected `,`: remove it"),
                [first, ..] => return err(first.span(), "a scene lists effect names, e.g. `[drive, damping]`"),
            };
            let e = scene_effect(base, effects, name, id, &chosen)?;
            chosen.push((e, id.clone()));
        }
        scenes.push(SceneDecl { name: name.clone(), effects: chosen });
    }
    if scenes.is_empty() {
        return err(section, "`scenes:` is empty; declare at least one, e.g. `scenes: { Free = [] }`");
    }
    Ok(scenes)
}

/// The index in `effects` of the effect `id` listed in scene `scene` after
/// the effects `chosen`: known, not listed twice, and (for an event) not
/// named like an event of the base declaration.
fn scene_effect(
    base: &SystemSpec,
    effects: &[EffectDecl],
    scene: &Ident,
    id: &Ident,
    chosen: &[(usize, Ident)],
) -> Result<usize, SpecError> {
    let key = id.to_string();
    if chosen.iter().any(|(_, c)| *c == key) {
        return err(id.span(), format!("effect `{key}` is listed twice in scene `{scene}`"));
    }
    let Some(e) = effects.iter().position(|d| d.name == key) else {
        let known: Vec<String> = effects.iter().map(|d| d.name.to_string()).collect();
        let mut msg = format!("unknown effect `{key}` in scene `{scene}`");
        if let Some(n) = nearest(&key, known.iter().map(String::as_str)) {
            msg.push_str(&format!("; did you mean `{n}`?"));
        }
        if known.is_empty() {
            msg.push_str("; declare it in an `effects:` section");
        } else {
            msg.push_str(&format!(
                " Effects: {}.",
                known.iter().map(|k| format!("`{k}`")).collect::<Vec<_>>().join(", ")
            ));
        }
        return err(id.span(), msg);
    };
    if let Effect::Event(decl) = &effects[e].effect {
        if base.events.iter().any(|b| b.name.name == decl.name.name) {
            return err(
                id.span(),
                format!("scene `{scene}` already has an event `{key}` from the base declaration; rename one"),
            );
        }
    }
    Ok(e)
}

/// The span of the first leaf of `e`, left to right as written, that
/// satisfies `leaf`.
fn first_leaf(e: &SrcExpr, leaf: &dyn Fn(&SrcExpr) -> bool) -> Option<Span> {
    match e {
        SrcExpr::Neg(a, _) => first_leaf(a, leaf),
        SrcExpr::Binary(_, a, b, _) => first_leaf(a, leaf).or_else(|| first_leaf(b, leaf)),
        SrcExpr::Call(_, args, _) => args.iter().find_map(|a| first_leaf(a, leaf)),
        other => leaf(other).then(|| other.span()),
    }
}

/// Whether some leaf of `e` satisfies `leaf`.
fn mentions(e: &SrcExpr, leaf: &dyn Fn(&SrcExpr) -> bool) -> bool {
    first_leaf(e, leaf).is_some()
}

/// The message for a constraint effect that uses neither coordinates nor
/// velocities: neither it nor its time derivative can restrict the motion,
/// so suggesting the other kind of effect would suggest another error.
fn no_coordinate_message(kind: &str, name: &Ident) -> String {
    format!(
        "{kind} `{name}` involves neither the coordinates nor the velocities (only the time `t`, parameters and \
         numbers): no motion can satisfy or violate it, so it cannot be a constraint (its time derivative has no \
         velocity either); remove it"
    )
}
