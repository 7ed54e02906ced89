//! Named effects and scenes: the optional `effects:` and `scenes:` sections.
//!
//! A scene is desugared into a plain [`SystemSpec`] (the base declaration with
//! the scene's potentials subtracted from `L`, its constraints appended, its
//! forces added to the base `forces`/`nonideal_forces`), so each scene goes
//! through the same engine as a hand-written declaration and its generated
//! code holds nothing of the effects it leaves out.
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
//! Forces of several effects in a scene add up component by component. In a
//! `nonideal` effect the multiplier of a constraint effect is written by the
//! effect's name, that of base constraint `j` as `psi[j]`. A scene's
//! constraints are the base ones, then its constraint/holonomic effects in
//! the scene's order; until a scene fixes that order, the name of effect `e`
//! stands for the provisional index `M_base + e`, which the scene maps to the
//! constraint's place (or rejects, if the scene leaves the constraint out).
//! A `force` may not use multipliers (it would be a non-ideal force).

use super::expr::{describe, parse_expression, split_commas, Context, Multipliers, Scope};
use super::forces::parse_force_block;
use super::names::{list, nearest};
use crate::spec::{BinOp, ConstraintSpec, Func, SpecError, SrcExpr, SystemSpec};
use proc_macro2::{Delimiter, Group, Ident, Span, TokenStream, TokenTree};

/// The effect kinds, as written.
pub const EFFECT_KINDS: [&str; 6] = ["potential", "constraint", "holonomic", "force", "nonideal", "event"];

fn err<T>(span: Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// One declared effect.
#[derive(Clone, Debug)]
enum Effect {
    Potential(SrcExpr),
    Constraint(SrcExpr, Span),
    /// `g` and its velocity-level form `k = g_t + g_q v`.
    Holonomic {
        k: SrcExpr,
        g: SrcExpr,
        span: Span,
    },
    /// External force components by coordinate.
    Force(Vec<Option<SrcExpr>>),
    /// Non-ideal constraint force components; multipliers of constraint
    /// effects carry provisional indices until a scene orders them.
    Nonideal(Vec<Option<SrcExpr>>),
    /// An event, named like the effect.
    Event(crate::spec::EventDecl),
}

/// The base declaration and one [`SystemSpec`] per scene, or `None` when
/// the input has neither `effects:` nor `scenes:`.
pub fn parse_with_scenes(input: &TokenStream) -> Result<Option<(SystemSpec, Vec<SystemSpec>)>, SpecError> {
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
    let specs = parse_scenes(&base, &declared, &scenes_group, scenes_span)?;
    Ok(Some((base, specs)))
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

fn parse_effects(base: &SystemSpec, group: &Group) -> Result<Vec<(Ident, Effect)>, SpecError> {
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
    // `M_base + e` (see `resolve_multipliers`).
    let m_base = base.constraints.len();
    let mut named: Vec<(String, usize)> = Vec::new();
    for (e, r) in raw.iter().enumerate() {
        if matches!(r.kind.to_string().as_str(), "constraint" | "holonomic") {
            let n = r.name.to_string();
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
    let mut out: Vec<(Ident, Effect)> = Vec::new();
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
                let k = time_derivative(&g)?;
                Effect::Holonomic { k, g, span: args.span() }
            }
            "force" => {
                let scope = Scope { multipliers: Multipliers::Forbidden { named: &named }, ..scope };
                let example = format!("`{name}: force {{ {}: … }}`", base.coordinates[0].name);
                Effect::Force(parse_force_block(args, &scope, &format!("force `{name}`"), &example)?)
            }
            "event" => Effect::Event(super::parse_event(name, &arg_tokens, &scope)?),
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
        out.push((name.clone(), effect));
    }
    check_lowerable(base, m_base + raw.len(), &out)?;
    Ok(out)
}

/// Lowers every effect's expressions once into a scratch graph, so that a
/// division by zero or a constant outside a function's domain is an error at
/// its token even in an effect that no scene selects. Provisional multiplier
/// indices (up to `multipliers`) stand for placeholder constraints.
fn check_lowerable(base: &SystemSpec, multipliers: usize, effects: &[(Ident, Effect)]) -> Result<(), SpecError> {
    let mut scratch = base.clone();
    let placeholder = ConstraintSpec { expr: num(0.0, base.name.span()), span: base.name.span(), position: None };
    scratch.constraints.resize(multipliers.max(base.constraints.len()), placeholder);
    let mut lower = crate::lower::Lowerer::new(&scratch);
    let mut graph = crate::graph::Graph::new();
    for (_, effect) in effects {
        match effect {
            Effect::Potential(e) | Effect::Constraint(e, _) | Effect::Holonomic { g: e, .. } => {
                lower.lower(&mut graph, e)?;
            }
            Effect::Event(decl) => {
                lower.lower(&mut graph, &decl.expr)?;
            }
            Effect::Force(components) | Effect::Nonideal(components) => {
                for e in components.iter().flatten() {
                    lower.lower(&mut graph, e)?;
                }
            }
        }
    }
    Ok(())
}

/// Component-wise sum of two force blocks (empty = absent).
fn add_forces(acc: Vec<Option<SrcExpr>>, more: &[Option<SrcExpr>]) -> Vec<Option<SrcExpr>> {
    if acc.is_empty() {
        return more.to_vec();
    }
    acc.into_iter()
        .zip(more)
        .map(|(a, b)| match (a, b) {
            (None, b) => b.clone(),
            (a, None) => a,
            (Some(a), Some(b)) => Some(SrcExpr::Binary(BinOp::Add, Box::new(a), Box::new(b.clone()), b.span())),
        })
        .collect()
}

/// Replaces the provisional multiplier indices of constraint effects
/// (`M_base + effect index`) by the scene's constraint indices; a multiplier
/// of a constraint the scene leaves out is an error at its use.
fn resolve_multipliers(
    e: &SrcExpr,
    m_base: usize,
    index_of: &[Option<usize>],
    effects: &[(Ident, Effect)],
    context: &(String, String),
) -> Result<SrcExpr, SpecError> {
    let go = |x: &SrcExpr| resolve_multipliers(x, m_base, index_of, effects, context);
    Ok(match e {
        SrcExpr::Multiplier(j, s) if *j >= m_base => {
            let k = *j - m_base;
            match index_of.get(k).copied().flatten() {
                Some(i) => SrcExpr::Multiplier(i, *s),
                None => {
                    let (effect, scene) = context;
                    let c = effects.get(k).map_or("?".to_string(), |(n, _)| n.to_string());
                    return err(
                        *s,
                        format!(
                            "non-ideal force `{effect}` uses the multiplier of constraint `{c}`, which scene `{scene}` \
                             does not select; add `{c}` to the scene"
                        ),
                    );
                }
            }
        }
        SrcExpr::Neg(a, s) => SrcExpr::Neg(Box::new(go(a)?), *s),
        SrcExpr::Binary(op, a, b, s) => SrcExpr::Binary(*op, Box::new(go(a)?), Box::new(go(b)?), *s),
        SrcExpr::Call(f, args, s) => SrcExpr::Call(*f, args.iter().map(go).collect::<Result<_, _>>()?, *s),
        other => other.clone(),
    })
}

fn parse_scenes(
    base: &SystemSpec,
    effects: &[(Ident, Effect)],
    group: &Group,
    section: Span,
) -> Result<Vec<SystemSpec>, SpecError> {
    let toks: Vec<TokenTree> = group.stream().into_iter().collect();
    let mut specs: Vec<SystemSpec> = Vec::new();
    let m_base = base.constraints.len();
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
        if *name == base.name || specs.iter().any(|s| s.name == *name) {
            return err(name.span(), format!("scene `{name}` is declared twice (or named like the base struct)"));
        }
        let items: Vec<TokenTree> = list_group.stream().into_iter().collect();
        let mut spec = base.clone();
        spec.name = name.clone();
        let mut chosen: Vec<String> = Vec::new();
        // Scene constraint index of each selected constraint effect.
        let mut index_of: Vec<Option<usize>> = vec![None; effects.len()];
        let mut nonideal: Vec<(String, &[Option<SrcExpr>])> = Vec::new();
        for (item, comma) in split_commas(&items) {
            let id = match item.as_slice() {
                [TokenTree::Ident(id)] => id,
                [] => return err(comma.unwrap_or(list_group.span()), "unexpected `,`: remove it"),
                [first, ..] => return err(first.span(), "a scene lists effect names, e.g. `[drive, damping]`"),
            };
            let key = id.to_string();
            if chosen.contains(&key) {
                return err(id.span(), format!("effect `{key}` is listed twice in scene `{name}`"));
            }
            let Some(e) = effects.iter().position(|(n, _)| *n == key) else {
                let known: Vec<String> = effects.iter().map(|(n, _)| n.to_string()).collect();
                let mut msg = format!("unknown effect `{key}` in scene `{name}`");
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
            match &effects[e].1 {
                Effect::Potential(u) => {
                    let span = u.span();
                    spec.lagrangian = SrcExpr::Binary(BinOp::Sub, Box::new(spec.lagrangian), Box::new(u.clone()), span);
                }
                Effect::Constraint(k, span) => {
                    index_of[e] = Some(spec.constraints.len());
                    spec.constraints.push(ConstraintSpec { expr: k.clone(), span: *span, position: None });
                }
                Effect::Holonomic { k, g, span } => {
                    index_of[e] = Some(spec.constraints.len());
                    spec.constraints.push(ConstraintSpec { expr: k.clone(), span: *span, position: Some(g.clone()) });
                }
                Effect::Force(f) => spec.external_force = add_forces(std::mem::take(&mut spec.external_force), f),
                Effect::Nonideal(f) => nonideal.push((key.clone(), f)),
                Effect::Event(decl) => {
                    if spec.events.iter().any(|e| e.name.name == decl.name.name) {
                        return err(
                            id.span(),
                            format!(
                                "scene `{name}` already has an event `{key}` from the base declaration; rename one"
                            ),
                        );
                    }
                    spec.events.push(decl.clone());
                }
            }
            chosen.push(key);
        }
        // Multipliers are resolved once the scene's constraint order is known.
        for (effect, force) in nonideal {
            let context = (effect, name.to_string());
            let resolved: Vec<Option<SrcExpr>> = force
                .iter()
                .map(|c| c.as_ref().map(|x| resolve_multipliers(x, m_base, &index_of, effects, &context)).transpose())
                .collect::<Result<_, _>>()?;
            spec.nonideal_force = add_forces(std::mem::take(&mut spec.nonideal_force), &resolved);
        }
        let doc = if chosen.is_empty() {
            format!("Scene `{name}` of `{}`: no effects.", base.name)
        } else {
            format!("Scene `{name}` of `{}` with the effects {}.", base.name, chosen.join(", "))
        };
        let attrs = std::mem::take(&mut spec.attrs);
        spec.attrs = quote::quote!(#[doc = #doc] #attrs);
        specs.push(spec);
    }
    if specs.is_empty() {
        return err(section, "`scenes:` is empty; declare at least one, e.g. `scenes: { Free = [] }`");
    }
    Ok(specs)
}

/// Whether some leaf of `e` satisfies `leaf`.
fn mentions(e: &SrcExpr, leaf: &dyn Fn(&SrcExpr) -> bool) -> bool {
    match e {
        SrcExpr::Neg(a, _) => mentions(a, leaf),
        SrcExpr::Binary(_, a, b, _) => mentions(a, leaf) || mentions(b, leaf),
        SrcExpr::Call(_, args, _) => args.iter().any(|a| mentions(a, leaf)),
        other => leaf(other),
    }
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

fn is_zero(e: &SrcExpr) -> bool {
    matches!(e, SrcExpr::Num(x, _) if *x == 0.0)
}

fn num(x: f64, span: Span) -> SrcExpr {
    SrcExpr::Num(x, span)
}

fn bin(op: BinOp, a: SrcExpr, b: SrcExpr, span: Span) -> SrcExpr {
    match op {
        BinOp::Add if is_zero(&a) => b,
        BinOp::Add | BinOp::Sub if is_zero(&b) => a,
        BinOp::Sub if is_zero(&a) => SrcExpr::Neg(Box::new(b), span),
        BinOp::Mul if is_zero(&a) || is_zero(&b) => num(0.0, span),
        BinOp::Mul if matches!(a, SrcExpr::Num(x, _) if x == 1.0) => b,
        BinOp::Mul if matches!(b, SrcExpr::Num(x, _) if x == 1.0) => a,
        BinOp::Div if is_zero(&a) => num(0.0, span),
        _ => SrcExpr::Binary(op, Box::new(a), Box::new(b), span),
    }
}

fn call(f: Func, a: SrcExpr, span: Span) -> SrcExpr {
    SrcExpr::Call(f, vec![a], span)
}

/// `dg/dt = ∂g/∂t + Σ ∂g/∂q_i v_i` for a position-level `g(t,q)`; a velocity
/// in `g` is an error at its span.
fn time_derivative(e: &SrcExpr) -> Result<SrcExpr, SpecError> {
    use BinOp::*;
    Ok(match e {
        SrcExpr::Num(_, s) | SrcExpr::Pi(s) | SrcExpr::Param(_, s) | SrcExpr::Const(_, s) => num(0.0, *s),
        SrcExpr::Time(s) => num(1.0, *s),
        SrcExpr::Coord(i, s) => SrcExpr::Velocity(*i, *s),
        SrcExpr::Velocity(_, s) => {
            return err(*s, "a holonomic constraint g(t, q) = 0 may not involve velocities; use `constraint(…)`")
        }
        SrcExpr::Multiplier(_, s) => return err(*s, "a holonomic constraint g(t, q) = 0 may not involve multipliers"),
        SrcExpr::Neg(a, s) => {
            let da = time_derivative(a)?;
            if is_zero(&da) {
                da
            } else {
                SrcExpr::Neg(Box::new(da), *s)
            }
        }
        SrcExpr::Binary(op, a, b, s) => {
            let s = *s;
            let (da, db) = (time_derivative(a)?, time_derivative(b)?);
            let (a, b) = ((**a).clone(), (**b).clone());
            match op {
                Add | Sub => bin(*op, da, db, s),
                Mul => bin(Add, bin(Mul, da, b.clone(), s), bin(Mul, a, db, s), s),
                Div => {
                    let num_part = bin(Sub, bin(Mul, da, b.clone(), s), bin(Mul, a, db.clone(), s), s);
                    bin(Div, num_part, bin(Pow, b, num(2.0, s), s), s)
                }
                Pow if is_zero(&db) => {
                    // d(a^b) = b a^(b−1) a' for a constant exponent.
                    let lowered = bin(Pow, a, bin(Sub, b.clone(), num(1.0, s), s), s);
                    bin(Mul, bin(Mul, b, lowered, s), da, s)
                }
                Pow => {
                    // d(a^b) = a^b (b' ln a + b a'/a).
                    let whole = bin(Pow, a.clone(), b.clone(), s);
                    let inner =
                        bin(Add, bin(Mul, db, call(Func::Ln, a.clone(), s), s), bin(Div, bin(Mul, b, da, s), a, s), s);
                    bin(Mul, whole, inner, s)
                }
            }
        }
        SrcExpr::Call(f, args, s) => {
            let s = *s;
            let a = args[0].clone();
            let da = time_derivative(&a)?;
            if *f == Func::Atan2 {
                let (y, x) = (args[0].clone(), args[1].clone());
                let (dy, dx) = (da, time_derivative(&x)?);
                let top = bin(Sub, bin(Mul, x.clone(), dy, s), bin(Mul, y.clone(), dx, s), s);
                let bottom = bin(Add, bin(Pow, x, num(2.0, s), s), bin(Pow, y, num(2.0, s), s), s);
                return Ok(bin(Div, top, bottom, s));
            }
            if is_zero(&da) {
                return Ok(da);
            }
            let outer = match f {
                Func::Sqrt => bin(Div, num(0.5, s), call(Func::Sqrt, a, s), s),
                Func::Exp => call(Func::Exp, a, s),
                Func::Ln => bin(Div, num(1.0, s), a, s),
                Func::Sin => call(Func::Cos, a, s),
                Func::Cos => SrcExpr::Neg(Box::new(call(Func::Sin, a, s)), s),
                Func::Tan => bin(Div, num(1.0, s), bin(Pow, call(Func::Cos, a, s), num(2.0, s), s), s),
                Func::Sinh => call(Func::Cosh, a, s),
                Func::Cosh => call(Func::Sinh, a, s),
                Func::Tanh => bin(Sub, num(1.0, s), bin(Pow, call(Func::Tanh, a, s), num(2.0, s), s), s),
                // Returned early above; kept for exhaustiveness.
                Func::Atan2 => num(0.0, s),
            };
            bin(Mul, outer, da, s)
        }
    })
}

/// Expands a declaration with scenes into the base type and one type per
/// scene; `None` when the declaration has no `effects:`/`scenes:`.
pub fn expand_scenes(input: &TokenStream) -> Option<Result<TokenStream, SpecError>> {
    let parsed = match parse_with_scenes(input) {
        Ok(None) => return None,
        Ok(Some(p)) => p,
        Err(e) => return Some(Err(e)),
    };
    let (base, scenes) = parsed;
    let mut out = match crate::generate_checked(&base, false) {
        Ok(t) => t,
        Err(e) => return Some(Err(e)),
    };
    for spec in &scenes {
        match crate::generate(spec) {
            Ok(t) => out.extend(t),
            Err(e) => return Some(Err(e)),
        }
    }
    Some(Ok(out))
}
