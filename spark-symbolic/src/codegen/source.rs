//! The constants of the trait implementation that describe the declaration
//! rather than compute with it: `STRUCTURE` (what the model proved),
//! `SOURCE` (the neutral S-expression text of every expression, for peers
//! such as the CasADi cross-check), `OPERATIONS` (the operation counts) and
//! `NONLINEARITY` (where the step's equations are not affine).

use super::Operations;
use crate::model::{ConstraintForm, Model};
use crate::nonlinearity::Nonlinearity;
use crate::source::{constraint_sexprs, holonomic_sexprs, sexpr};
use crate::spec::{SrcExpr, SystemSpec};
use proc_macro2::{Literal, TokenStream};
use quote::quote;

fn form_tokens(rt: &TokenStream, f: ConstraintForm) -> TokenStream {
    match f {
        ConstraintForm::None => quote!(#rt::ConstraintForm::None),
        ConstraintForm::Linear => quote!(#rt::ConstraintForm::Linear),
        ConstraintForm::Affine => quote!(#rt::ConstraintForm::Affine),
        ConstraintForm::Nonlinear => quote!(#rt::ConstraintForm::Nonlinear),
    }
}

/// `const STRUCTURE`, `const SOURCE`, `const OPERATIONS`,
/// `const NONLINEARITY` and, when the model proves it,
/// `const CONSTANT_STIFFNESS` or `const DIAGONAL_STIFFNESS`.
pub(super) fn descriptive_consts(rt: &TokenStream, spec: &SystemSpec, model: &Model, ops: &Operations) -> TokenStream {
    let structure = model.structure;
    let b = |x: bool| if x { quote!(true) } else { quote!(false) };
    let (la, ca, cm, sep) = (
        b(structure.lagrangian_autonomous),
        b(structure.constraints_autonomous),
        b(structure.constant_mass_matrix),
        b(structure.separable),
    );
    let form = form_tokens(rt, structure.constraint_form);
    let (o_sv, o_sj, o_b) = (
        Literal::usize_unsuffixed(ops.stage_values),
        Literal::usize_unsuffixed(ops.stage_jacobians),
        Literal::usize_unsuffixed(ops.bundle),
    );
    let source = source_const(rt, spec, model);
    let nonlinearity = nonlinearity_const(rt, model);
    let stiffness = if model.constant_stiffness() {
        quote!(
            const CONSTANT_STIFFNESS: bool = true;
        )
    } else if model.diagonal_stiffness() {
        quote!(
            const DIAGONAL_STIFFNESS: bool = true;
        )
    } else {
        quote!()
    };
    quote! {
        const STRUCTURE: #rt::Structure = #rt::Structure {
            lagrangian_autonomous: #la,
            constraints_autonomous: #ca,
            constant_mass_matrix: #cm,
            separable: #sep,
            constraint_form: #form,
        };
        #source
        const OPERATIONS: #rt::OperationCounts = #rt::OperationCounts {
            stage_values: #o_sv,
            stage_jacobians: #o_sj,
            bundle: #o_b,
        };
        #stiffness
        #nonlinearity
    }
}

/// `const NONLINEARITY`: the curved pairs of variable groups and the
/// coordinates whose position enters the force or the constraint force
/// ([`Nonlinearity`]).
fn nonlinearity_const(rt: &TokenStream, model: &Model) -> TokenStream {
    let Nonlinearity { pairs, closed_affine_cover, stiffness_columns, constraint_force_columns } =
        Nonlinearity::of(model);
    let (a, b): (Vec<_>, Vec<_>) =
        pairs.into_iter().map(|(a, b)| (Literal::u32_unsuffixed(a), Literal::u32_unsuffixed(b))).unzip();
    let stiffness = stiffness_columns.into_iter().map(Literal::u32_unsuffixed);
    let constraint_force = constraint_force_columns.into_iter().map(Literal::u32_unsuffixed);
    quote! {
        const NONLINEARITY: ::core::option::Option<#rt::Nonlinearity> = ::core::option::Option::Some(#rt::Nonlinearity {
            pairs: &[#((#a, #b)),*],
            closed_affine_cover: #closed_affine_cover,
            stiffness_columns: &[#(#stiffness),*],
            constraint_force_columns: &[#(#constraint_force),*],
        });
    }
}

/// `const SOURCE`: names and S-expression text of `L`, `k`, the forces and
/// the holonomic `g` (empty when no constraint is holonomic).
fn source_const(rt: &TokenStream, spec: &SystemSpec, model: &Model) -> TokenStream {
    let name_str = spec.name.to_string();
    let coord_names = spec.coordinates.iter().map(|c| c.name.clone());
    let param_names = spec.parameters.iter().map(|p| p.name.name.clone());
    let lag_src = sexpr(spec, &spec.lagrangian);
    let k_src = constraint_sexprs(spec, model);
    let components = |xs: &[Option<SrcExpr>]| -> Vec<String> {
        xs.iter().map(|x| x.as_ref().map_or_else(|| "0".to_string(), |e| sexpr(spec, e))).collect()
    };
    let f_src = components(&spec.external_force);
    let n_src = components(&spec.nonideal_force);
    let g_src = holonomic_sexprs(spec);
    quote! {
        const SOURCE: #rt::SystemSource = #rt::SystemSource {
            name: #name_str,
            external_force: &[#(#f_src),*],
            nonideal_force: &[#(#n_src),*],
            holonomic: &[#(#g_src),*],
            coordinates: &[#(#coord_names),*],
            parameters: &[#(#param_names),*],
            lagrangian: #lag_src,
            constraints: &[#(#k_src),*],
        };
    }
}
