//! Parameter terms: the parameter-only subexpressions of the functions a
//! step evaluates at every iterate — the stage values, the stage values
//! with the constraint Jacobians, the stage Jacobians, the end point's
//! values with and without the constraint Jacobians, and the energy —
//! computed once per change of the parameters by `parameter_terms` and read
//! by the `*_with_terms` variants of those functions, which the stepper
//! calls. The skate's `m g sin β` is then one load per evaluation instead of
//! a `sin` at every stage point of every iterate.
//!
//! A variant reads each term where the plain function computes it and
//! performs every other operation as the plain function does, so the two
//! return the same bits. Systems without parameter terms, and systems with a
//! body long enough to be split into helpers, get no variants: the trait's
//! defaults call the plain functions.

use super::body::{Dest, Gen, Out};
use super::SPLIT_STATEMENTS;
use crate::emit::{emit, Emitted, Inputs, Target};
use crate::graph::NodeId;
use proc_macro2::{Literal, TokenStream};
use quote::{format_ident, quote};
use std::collections::HashMap;

/// `PARAMETER_TERMS`, `parameter_terms` and the six `*_with_terms`
/// methods, or nothing (see the module docs).
pub(super) fn methods(gen: &mut Gen) -> TokenStream {
    let (values, jacobians) = gen.stage_outs();
    let write = |outs: Vec<Out>| -> Vec<Out> { outs.into_iter().map(|o| o.into_dest(Dest::Write)).collect() };
    let values = write(values);
    let mut fused = values.clone();
    let m = gen.m.clone();
    let (kq, kv) = (gen.model.constraint_q.clone(), gen.model.constraint_v.clone());
    fused.extend(write(vec![gen.matrix("constraint_q", &kq, &m), gen.matrix("constraint_v", &kv, &m)]));
    let mut all = values.clone();
    all.extend(write(jacobians));
    let (end_values, end_fused) = gen.end_point_outs();
    let energy = vec![(Target::Let(format_ident!("energy")), gen.model.energy)];
    let entries = |outs: &[Out]| -> Vec<(Target, NodeId)> { outs.iter().flat_map(|o| o.entries.clone()).collect() };
    let bodies = [
        (entries(&values), &values[..]),
        (entries(&fused), &fused[..]),
        (entries(&all), &all[..]),
        (entries(&end_values), &end_values[..]),
        (entries(&end_fused), &end_fused[..]),
    ];

    let params = gen.params.clone();
    let runtime = gen.rt.clone();
    let stage = Inputs { parameters: &params, runtime: &runtime, sin_cos_memo: Some(&gen.sin_cos_slots) };
    let mut emitted: Vec<Emitted> = Vec::new();
    for (e, _) in &bodies {
        emitted.push(emit(&mut gen.model.graph, e, &stage));
    }
    let inputs = Inputs { sin_cos_memo: None, ..stage };
    emitted.push(emit(&mut gen.model.graph, &energy, &inputs));
    if emitted.iter().any(|e| e.statements.len() > SPLIT_STATEMENTS) {
        return quote!();
    }
    // Every body's terms, each once, in order of first appearance.
    let mut index: HashMap<NodeId, usize> = HashMap::new();
    let mut terms: Vec<NodeId> = Vec::new();
    for node in emitted.iter().flat_map(Emitted::parameter_terms) {
        index.entry(node).or_insert_with(|| {
            terms.push(node);
            terms.len() - 1
        });
    }
    if terms.is_empty() {
        return quote!();
    }
    let stores: Vec<(Target, NodeId)> =
        terms.iter().enumerate().map(|(i, &node)| (Target::Store(format_ident!("terms"), i, None), node)).collect();
    let fill = emit(&mut gen.model.graph, &stores, &inputs).statements;
    let mut with = Vec::new();
    for (e, (_, outs)) in emitted.iter().zip(&bodies) {
        let Some(statements) = e.statements_with_terms(&index) else { return quote!() };
        let decls = gen.decls(outs);
        with.push(quote!(#(#decls)* #(#statements)*));
    }
    let Some(energy) = emitted[bodies.len()].statements_with_terms(&index) else { return quote!() };
    let count = Literal::usize_unsuffixed(terms.len());
    let (rt, n, m) = (&gen.rt, &gen.n, &gen.m);
    let trait_path = quote!(<Self as #rt::NonholonomicSystem<#n, #m>>);
    let sig = quote!(&self, terms: &[f64], t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>);
    // Terms too short for this system: its own, computed here (the same
    // bits, at the cost the plain function pays).
    let terms_or_own = quote! {
        let mut own = [0.0f64; #count];
        let terms: &[f64] = match terms.get(..#count) {
            ::core::option::Option::Some(terms) => terms,
            ::core::option::Option::None => {
                #trait_path::parameter_terms(self, &mut own);
                &own
            }
        };
    };
    let (values_with, fused_with, all_with) = (&with[0], &with[1], &with[2]);
    let (end_values_with, end_fused_with) = (&with[3], &with[4]);
    quote! {
        const PARAMETER_TERMS: usize = #count;

        fn parameter_terms(&self, terms: &mut [f64]) {
            let ::core::option::Option::Some(terms) = terms.get_mut(..#count) else { return };
            #(#fill)*
        }

        fn energy_with_terms(#sig) -> f64 {
            #terms_or_own
            #(#energy)*
            energy
        }

        fn stage_values_with_terms(#sig, psi: &#rt::Vector<#m>, values: &mut #rt::StageValues<#n, #m>) {
            #terms_or_own
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            #values_with
        }

        fn stage_values_and_constraint_jacobians_with_terms(
            #sig,
            psi: &#rt::Vector<#m>,
            values: &mut #rt::StageValues<#n, #m>,
            constraint_q: &mut #rt::Matrix<#m, #n>,
            constraint_v: &mut #rt::Matrix<#m, #n>
        ) {
            #terms_or_own
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            #fused_with
        }

        fn end_point_values_with_terms(#sig, values: &mut #rt::StageValues<#n, #m>) {
            #terms_or_own
            let #rt::StageValues { momentum, constraint, sin_cos_memo, .. } = values;
            #end_values_with
        }

        fn end_point_values_and_constraint_jacobians_with_terms(
            #sig,
            values: &mut #rt::StageValues<#n, #m>,
            constraint_q: &mut #rt::Matrix<#m, #n>,
            constraint_v: &mut #rt::Matrix<#m, #n>
        ) {
            #terms_or_own
            let #rt::StageValues { momentum, constraint, sin_cos_memo, .. } = values;
            #end_fused_with
        }

        fn stage_jacobians_with_terms(
            #sig,
            psi: &#rt::Vector<#m>,
            values: &mut #rt::StageValues<#n, #m>,
            jacobians: &mut #rt::StageJacobians<#n, #m>
        ) {
            #terms_or_own
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            let #rt::StageJacobians {
                momentum_q, mass, force_q, force_v, constraint_q, constraint_v,
                constraint_force_q, constraint_force_v,
            } = jacobians;
            #all_with
        }
    }
}
