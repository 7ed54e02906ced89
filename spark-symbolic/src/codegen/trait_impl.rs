//! The `NonholonomicSystem` implementation: the bodies of the value and
//! derivative methods (`lagrangian`, `energy`, `momentum`, …, the fused
//! `stage_values`, `stage_values_into`, `stage_jacobians_into`,
//! `stage_values_and_constraint_jacobians`, with their parameter-term
//! variants from [`super::terms`]) and the `impl` item that holds
//! them together with the constants, the parameter methods and the effects.

use super::body::{Body, Gen};
use crate::emit::Target;
use proc_macro2::{Ident, TokenStream};
use quote::{format_ident, quote};

/// The methods every declaration has, their bodies emitted in this order;
/// also returns the fused stage functions' and the bundle's bodies with
/// their operation counts.
pub(super) fn methods(gen: &mut Gen) -> (TokenStream, (Body, Body, Body)) {
    let (n, m) = (gen.n.clone(), gen.m.clone());
    let lagrangian = gen.scalar("lagrangian", "lagrangian", gen.model.lagrangian);
    let energy = gen.scalar("energy", "energy", gen.model.energy);
    let o = gen.vector("momentum", &gen.model.momentum.clone(), &n);
    let momentum = gen.returning("momentum", o);
    let o = gen.vector("force", &gen.model.force.clone(), &n);
    let force = gen.returning("force", o);
    let o = gen.matrix("mass", &gen.model.mass.clone(), &n);
    let mass = gen.returning("mass_matrix", o);
    let o = gen.vector("constraint", &gen.model.constraint.clone(), &m);
    let constraint = gen.returning("constraint", o);
    let o = gen.matrix("constraint_q", &gen.model.constraint_q.clone(), &m);
    let constraint_q = gen.returning("constraint_q", o);
    let o = gen.matrix("constraint_v", &gen.model.constraint_v.clone(), &m);
    let constraint_v = gen.returning("constraint_v", o);
    // The diagonal of `F_q` alone, for the stage-decoupled refresh of a
    // system whose stiffness it keeps at each stage point.
    let stiffness = gen.model.diagonal_stiffness().then(|| {
        let diagonal: Vec<_> = gen.model.force_q.iter().enumerate().map(|(i, row)| row[i]).collect();
        let o = gen.vector("stiffness", &diagonal, &n);
        gen.returning("stiffness_diagonal", o)
    });

    let md = &*gen.model;
    let td_outs = vec![
        gen.vector("momentum_t", &md.momentum_t, &n),
        gen.vector("force_t", &md.force_t, &n),
        gen.vector("constraint_t", &md.constraint_t, &m),
    ];
    let lt = md.lagrangian_t;
    let (time_derivatives, _) =
        gen.body("time_derivatives", vec![(Target::Let(format_ident!("lagrangian_t")), lt)], &td_outs, false);

    let fused = gen.fused();
    let (values_and_constraint_jacobians, _) = gen.values_and_constraint_jacobians();
    let ((end_point_values, _), (end_point_fused, _)) = gen.end_point();
    let in_lanes = lanes_method(gen);
    let with_terms = super::terms::methods(gen);
    let (stage_values, stage_jacobians) = (&fused.0 .0, &fused.1 .0);
    let (rt, n, m) = (&gen.rt, &gen.n, &gen.m);
    let sig = quote!(&self, t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>);
    let sj_sig = quote!(
        #sig,
        psi: &#rt::Vector<#m>,
        values: &mut #rt::StageValues<#n, #m>,
        jacobians: &mut #rt::StageJacobians<#n, #m>
    );
    let stiffness_diagonal = stiffness.map(|body| {
        quote! {
            fn stiffness_diagonal(#sig) -> Option<#rt::Vector<#n>> {
                Some({ #body })
            }
        }
    });
    let methods = quote! {
        fn lagrangian(#sig) -> f64 {
            #lagrangian
            lagrangian
        }

        fn energy(#sig) -> f64 {
            #energy
            energy
        }

        fn momentum(#sig) -> #rt::Vector<#n> {
            #momentum
        }

        fn force(#sig) -> #rt::Vector<#n> {
            #force
        }

        fn mass_matrix(#sig) -> #rt::Matrix<#n, #n> {
            #mass
        }

        fn constraint(#sig) -> #rt::Vector<#m> {
            #constraint
        }

        fn constraint_q(#sig) -> #rt::Matrix<#m, #n> {
            #constraint_q
        }

        fn constraint_v(#sig) -> #rt::Matrix<#m, #n> {
            #constraint_v
        }

        #stiffness_diagonal

        fn time_derivatives(#sig) -> #rt::TimeDerivatives<#n, #m> {
            #time_derivatives
            #rt::TimeDerivatives { lagrangian_t, momentum_t, force_t, constraint_t }
        }

        fn stage_values(#sig, psi: &#rt::Vector<#m>) -> #rt::StageValues<#n, #m> {
            let mut values = #rt::StageValues::zeros();
            <Self as #rt::NonholonomicSystem<#n, #m>>::stage_values_into(self, t, q, v, psi, &mut values);
            values
        }

        fn stage_values_into(#sig, psi: &#rt::Vector<#m>, values: &mut #rt::StageValues<#n, #m>) {
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            #stage_values
        }

        fn stage_jacobians(#sig, psi: &#rt::Vector<#m>)
            -> (#rt::StageValues<#n, #m>, #rt::StageJacobians<#n, #m>) {
            let mut values = #rt::StageValues::zeros();
            let mut jacobians = #rt::StageJacobians::zeros();
            <Self as #rt::NonholonomicSystem<#n, #m>>::stage_jacobians_into(
                self, t, q, v, psi, &mut values, &mut jacobians,
            );
            (values, jacobians)
        }

        fn stage_values_and_constraint_jacobians(
            #sig,
            psi: &#rt::Vector<#m>,
            values: &mut #rt::StageValues<#n, #m>,
            constraint_q: &mut #rt::Matrix<#m, #n>,
            constraint_v: &mut #rt::Matrix<#m, #n>
        ) {
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            #values_and_constraint_jacobians
        }

        fn end_point_values_into(#sig, values: &mut #rt::StageValues<#n, #m>) {
            let #rt::StageValues { momentum, constraint, sin_cos_memo, .. } = values;
            #end_point_values
        }

        fn end_point_values_and_constraint_jacobians(
            #sig,
            values: &mut #rt::StageValues<#n, #m>,
            constraint_q: &mut #rt::Matrix<#m, #n>,
            constraint_v: &mut #rt::Matrix<#m, #n>
        ) {
            let #rt::StageValues { momentum, constraint, sin_cos_memo, .. } = values;
            #end_point_fused
        }

        #in_lanes

        #with_terms

        fn stage_jacobians_into(#sj_sig) {
            let #rt::StageValues { momentum, force, constraint, constraint_force, sin_cos_memo } = values;
            let #rt::StageJacobians {
                momentum_q, mass, force_q, force_v, constraint_q, constraint_v,
                constraint_force_q, constraint_force_v,
            } = jacobians;
            #stage_jacobians
        }
    };
    (methods, fused)
}

/// A lane method's body: `values` without the constraint Jacobians, `fused`
/// with them (`k_q`, `K = k_v` into `jacobians`).
fn with_or_without_jacobians(rt: &TokenStream, values: &TokenStream, fused: &TokenStream) -> TokenStream {
    quote! {
        match jacobians {
            ::core::option::Option::None => { #values }
            ::core::option::Option::Some(jacobians) => {
                let #rt::LaneConstraintJacobians { constraint_q, constraint_v } = jacobians;
                #fused
            }
        }
    }
}

/// `stage_values_in_lanes`, `end_point_values_in_lanes` and
/// `energy_in_lanes` in lane form (each left out, so the trait's default,
/// when its body would be too long).
fn lanes_method(gen: &mut Gen) -> TokenStream {
    let energy = gen.lane_energy().map(|body| {
        let n = &gen.n;
        quote! {
            #[inline(always)]
            #[allow(clippy::needless_range_loop, unused_variables, unused_mut)]
            fn energy_in_lanes<const W: usize>(
                &self,
                t: f64,
                q: &[[f64; W]; #n],
                v: &[[f64; W]; #n],
                lanes: &[bool; W],
            ) -> [f64; W] {
                #body
                energy
            }
        }
    });
    let (rt, n, m) = (gen.rt.clone(), gen.n.clone(), gen.m.clone());
    let end_point = gen.lane_end_point_bodies().map(|(values, fused)| {
        let with_or_without = with_or_without_jacobians(&rt, &values, &fused);
        quote! {
            #[inline(always)]
            #[allow(clippy::needless_range_loop, clippy::too_many_arguments, unused_variables, unused_mut)]
            fn end_point_values_in_lanes<const W: usize>(
                &self,
                t: f64,
                q: &[[f64; W]; #n],
                v: &[[f64; W]; #n],
                lanes: &[bool; W],
                values: &mut #rt::LaneStageValues<#n, #m, W>,
                jacobians: ::core::option::Option<&mut #rt::LaneConstraintJacobians<#n, #m, W>>,
            ) {
                let #rt::LaneStageValues { momentum, constraint, .. } = values;
                #with_or_without
            }
        }
    });
    let Some((values, fused)) = gen.lane_bodies() else { return quote!(#energy #end_point) };
    let with_or_without = with_or_without_jacobians(&rt, &values, &fused);
    quote! {
        #energy

        #end_point

        #[inline(always)]
        #[allow(clippy::needless_range_loop, clippy::too_many_arguments, unused_variables, unused_mut)]
        fn stage_values_in_lanes<const W: usize>(
            &self,
            t: f64,
            q: &[[f64; W]; #n],
            v: &[[f64; W]; #n],
            psi: &[[f64; W]; #m],
            lanes: &[bool; W],
            values: &mut #rt::LaneStageValues<#n, #m, W>,
            jacobians: ::core::option::Option<&mut #rt::LaneConstraintJacobians<#n, #m, W>>,
        ) {
            let #rt::LaneStageValues { momentum, force, constraint, constraint_force } = values;
            #with_or_without
        }
    }
}

/// The `impl NonholonomicSystem<N, M> for Name` item: `consts` (STRUCTURE,
/// SOURCE, OPERATIONS), `parameters` (the parameter methods), the
/// `methods` and the `effects` items.
pub(super) fn trait_impl(
    gen: &Gen,
    name: &Ident,
    consts: TokenStream,
    parameters: TokenStream,
    methods: TokenStream,
    effects: TokenStream,
) -> TokenStream {
    let (rt, n, m) = (&gen.rt, &gen.n, &gen.m);
    quote! {
        #[allow(unused_variables, unused_mut, clippy::all)]
        impl #rt::NonholonomicSystem<#n, #m> for #name {
            #consts
            #parameters

            #methods

            #effects
        }
    }
}
