//! Code generation: the items generated for one declaration, one module per
//! item. `body` emits method bodies from the model's graph (and splits
//! long ones into helpers); `item` is the parameter struct, its `Default`
//! and the inherent `N`/`M`/`new`; the `NonholonomicSystem` implementation
//! is assembled from `source` (`STRUCTURE`, `SOURCE`, `OPERATIONS`),
//! `params` (`parameter_values`, `set_parameter`), `trait_impl` (the
//! value and derivative methods), `terms` (the parameter terms computed
//! once per change of the parameters) and `effects` (forces, holonomic
//! residual, events).
//!
//! The declaration is validated before it gets here
//! ([`crate::dsl::validate()`]); generation itself does not fail.

mod body;
mod effects;
mod item;
mod params;
mod source;
mod terms;
mod trait_impl;

use crate::model::Model;
use crate::spec::SystemSpec;
use body::Gen;
use proc_macro2::{Ident, TokenStream};
use quote::quote;

/// Operation counts of the generated functions (see [`crate::emit`] for
/// what is counted).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Operations {
    /// `stage_values`.
    pub stage_values: usize,
    /// `stage_jacobians` (values and Jacobians together).
    pub stage_jacobians: usize,
    /// `L`, `∇_q L`, `∇_v L`, `∇²_vv L`, `∂(∇_v L)/∂q`, `k`, `k_q`, `k_v`,
    /// `R = −Kᵀψ`, `∂R/∂q`, `∂R/∂v`, evaluated together (the set CasADi is
    /// compared with).
    pub bundle: usize,
    /// `external_force_jacobians` (`f`, `∂f/∂q`, `∂f/∂v`); 0 without forcing.
    pub external_force_jacobians: usize,
    /// `nonideal_force_jacobians` (`N`, `∂N/∂q`, `∂N/∂v`, `∂N/∂ψ`); 0 without
    /// a non-ideal force.
    pub nonideal_force_jacobians: usize,
}

impl Operations {
    fn of(fused: &(body::Body, body::Body, body::Body), effects: &effects::EffectBodies) -> Operations {
        let (sv, sj, bundle) = fused;
        Operations {
            stage_values: sv.1,
            stage_jacobians: sj.1,
            bundle: bundle.1,
            external_force_jacobians: effects.forcing.as_ref().map_or(0, |f| f.1 .1),
            nonideal_force_jacobians: effects.nonideal.as_ref().map_or(0, |f| f.1 .1),
        }
    }
}

/// Statement threshold above which a body is split into helper functions
/// so that rustc's super-linear passes stay fast.
pub const SPLIT_STATEMENTS: usize = 150;

/// Operation counts of a built model, without generating code.
pub fn count_operations(model: &mut Model, params: &[Ident]) -> Operations {
    let mut gen = Gen::new(model, params, quote!(::spark_runtime), 0, 0);
    let fused = gen.fused();
    let effects = gen.effects();
    Operations::of(&fused, &effects)
}

/// The statements of the bundle CasADi is compared with (see
/// [`Operations::bundle`]), for review of what the count covers.
pub fn bundle_code(model: &mut Model, params: &[Ident]) -> (TokenStream, usize) {
    let mut gen = Gen::new(model, params, quote!(::spark_runtime), 0, 0);
    gen.fused().2
}

/// Generates all items for a validated `spec` from its built `model`: the
/// struct item, then the trait implementation.
pub fn generate_items(spec: &SystemSpec, model: &mut Model) -> (TokenStream, Operations) {
    let rt = if spec.runtime_path.is_empty() { quote!(::spark_runtime) } else { spec.runtime_path.clone() };
    let params: Vec<Ident> = spec.parameters.iter().map(|p| Ident::new(&p.name.name, p.name.span)).collect();
    let (n, m) = (model.n, model.m);
    let mut gen = Gen::new(model, &params, rt.clone(), n, m);
    let (methods, fused) = trait_impl::methods(&mut gen);
    let effect_bodies = gen.effects();
    let ops = Operations::of(&fused, &effect_bodies);
    let effects = effects::effect_items(&mut gen, spec, effect_bodies);
    let helpers = std::mem::take(&mut gen.helpers);
    let consts = source::descriptive_consts(&rt, spec, gen.model, &ops);
    let parameters = params::parameter_methods(&rt, &params);
    let trait_impl = trait_impl::trait_impl(&gen, &spec.name, consts, parameters, methods, effects);
    let item = item::struct_items(spec, &params, &gen.n, &gen.m, &helpers);
    (with_struct_cfg(spec, quote!(#item #trait_impl)), ops)
}

/// `items` with the `#[cfg(…)]` attributes of the declaration's struct on
/// every item besides the struct, which carries them already: a
/// configuration that removes the struct removes its implementations with
/// it, as for a hand-written struct and its impls. Without such an
/// attribute `items` come back untouched.
fn with_struct_cfg(spec: &SystemSpec, items: TokenStream) -> TokenStream {
    let Ok(attrs) = syn::parse::Parser::parse2(syn::Attribute::parse_outer, spec.attrs.clone()) else {
        return items;
    };
    let cfgs: Vec<syn::Attribute> = attrs.into_iter().filter(|a| a.path().is_ident("cfg")).collect();
    if cfgs.is_empty() {
        return items;
    }
    let Ok(mut file) = syn::parse2::<syn::File>(items.clone()) else {
        return items;
    };
    for item in &mut file.items {
        let attrs = match item {
            syn::Item::Struct(s) if s.ident == spec.name => continue,
            syn::Item::Impl(i) => &mut i.attrs,
            syn::Item::Struct(s) => &mut s.attrs,
            syn::Item::Const(c) => &mut c.attrs,
            syn::Item::Fn(f) => &mut f.attrs,
            syn::Item::Mod(m) => &mut m.attrs,
            syn::Item::Static(s) => &mut s.attrs,
            syn::Item::Enum(e) => &mut e.attrs,
            syn::Item::Type(t) => &mut t.attrs,
            syn::Item::Macro(m) => &mut m.attrs,
            _ => continue,
        };
        attrs.extend(cfgs.iter().cloned());
    }
    quote!(#file)
}
