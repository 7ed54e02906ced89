//! The scenes stage, between parsing and the model: a [`Declaration`] with
//! effects and scenes becomes plain [`SystemSpec`]s, the base and one per
//! scene.
//!
//! A scene is the base declaration with the scene's potentials subtracted
//! from `L`, its constraint and holonomic effects appended to the
//! constraints (in the scene's order), and its forces added to the base
//! `forces`/`nonideal_forces` component by component. So each scene goes
//! through the same engine as a hand-written declaration, and its generated
//! code holds nothing of the effects it leaves out. A holonomic effect stays
//! `g(t,q)` here ([`ConstraintSpec::holonomic`]); the model forms its
//! velocity-level row `k = g_t + g_q·v` with the graph differentiator.
//!
//! In a `nonideal` effect, the multiplier of constraint effect `e` carries
//! the provisional index `M_base + e` (see [`crate::dsl`]); each scene maps it
//! to the constraint's place, or rejects it if the scene leaves the
//! constraint out.

use crate::spec::{BinOp, ConstraintSpec, Declaration, Effect, EffectDecl, SceneDecl, SpecError, SrcExpr, SystemSpec};
use proc_macro2::TokenStream;

fn err<T>(span: proc_macro2::Span, message: impl Into<String>) -> Result<T, SpecError> {
    Err(SpecError { span, message: message.into() })
}

/// The base declaration followed by one spec per scene (just the base for
/// a declaration without scenes). Every effect is checked once, selected or
/// not (see `check_lowerable`).
pub fn desugar(declaration: Declaration) -> Result<Vec<SystemSpec>, SpecError> {
    let Declaration { base, effects, scenes } = declaration;
    if scenes.is_empty() {
        return Ok(vec![base]);
    }
    check_lowerable(&base, &effects)?;
    let mut specs = Vec::with_capacity(scenes.len() + 1);
    for scene in &scenes {
        let spec = scene_spec(&base, &effects, scene)?;
        specs.push(spec);
    }
    specs.insert(0, base);
    Ok(specs)
}

/// The base declaration and one [`SystemSpec`] per scene, or `None` when
/// the input has neither `effects:` nor `scenes:`: [`crate::dsl::parse_declaration`]
/// and [`desugar`] in one call.
pub fn parse_with_scenes(input: &TokenStream) -> Result<Option<(SystemSpec, Vec<SystemSpec>)>, SpecError> {
    let declaration = crate::dsl::parse_declaration(input.clone())?;
    if declaration.scenes.is_empty() {
        return Ok(None);
    }
    let mut specs = desugar(declaration)?;
    let base = specs.remove(0);
    Ok(Some((base, specs)))
}

/// Lowers every effect's expressions once into a scratch graph, so that a
/// division by zero or a constant outside a function's domain is an error at
/// its token even in an effect that no scene selects. Provisional multiplier
/// indices stand for placeholder constraints.
fn check_lowerable(base: &SystemSpec, effects: &[EffectDecl]) -> Result<(), SpecError> {
    let mut scratch = base.clone();
    let multipliers = base.constraints.len() + effects.len();
    let span = base.name.span();
    let placeholder = ConstraintSpec { expr: SrcExpr::Num(0.0, span), span, holonomic: false };
    scratch.constraints.resize(multipliers, placeholder);
    let mut lower = crate::lower::Lowerer::new(&scratch);
    let mut graph = crate::graph::Graph::new();
    for d in effects {
        match &d.effect {
            Effect::Potential(e) | Effect::Constraint(e, _) | Effect::Holonomic(e, _) => {
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

/// The spec of one scene: the base with the scene's effects applied in the
/// scene's order, then the non-ideal forces with their multipliers mapped to
/// the scene's constraints, and a doc line naming the effects.
fn scene_spec(base: &SystemSpec, effects: &[EffectDecl], scene: &SceneDecl) -> Result<SystemSpec, SpecError> {
    let name = &scene.name;
    let mut spec = base.clone();
    spec.name = name.clone();
    // Scene constraint index of each selected constraint effect.
    let mut index_of: Vec<Option<usize>> = vec![None; effects.len()];
    let mut nonideal: Vec<(String, &[Option<SrcExpr>])> = Vec::new();
    for (e, id) in &scene.effects {
        match &effects[*e].effect {
            Effect::Potential(u) => {
                let span = u.span();
                spec.lagrangian = SrcExpr::Binary(BinOp::Sub, Box::new(spec.lagrangian), Box::new(u.clone()), span);
            }
            Effect::Constraint(expr, span) | Effect::Holonomic(expr, span) => {
                let holonomic = matches!(effects[*e].effect, Effect::Holonomic(..));
                index_of[*e] = Some(spec.constraints.len());
                spec.constraints.push(ConstraintSpec { expr: expr.clone(), span: *span, holonomic });
            }
            Effect::Force(f) => spec.external_force = add_forces(std::mem::take(&mut spec.external_force), f),
            Effect::Nonideal(f) => nonideal.push((id.to_string(), f)),
            Effect::Event(decl) => spec.events.push(decl.clone()),
        }
    }
    // Multipliers are resolved once the scene's constraint order is known.
    let m_base = base.constraints.len();
    for (effect, force) in nonideal {
        let context = (effect, name.to_string());
        let resolved: Vec<Option<SrcExpr>> = force
            .iter()
            .map(|c| c.as_ref().map(|x| resolve_multipliers(x, m_base, &index_of, effects, &context)).transpose())
            .collect::<Result<_, _>>()?;
        spec.nonideal_force = add_forces(std::mem::take(&mut spec.nonideal_force), &resolved);
    }
    let chosen: Vec<String> = scene.effects.iter().map(|(_, id)| id.to_string()).collect();
    let doc = if chosen.is_empty() {
        format!("Scene `{name}` of `{}`: no effects.", base.name)
    } else {
        format!("Scene `{name}` of `{}` with the effects {}.", base.name, chosen.join(", "))
    };
    let attrs = std::mem::take(&mut spec.attrs);
    spec.attrs = quote::quote!(#[doc = #doc] #attrs);
    Ok(spec)
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
    effects: &[EffectDecl],
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
                    let c = effects.get(k).map_or("?".to_string(), |d| d.name.to_string());
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
