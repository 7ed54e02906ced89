//! The optional-effect items of the trait implementation: the external
//! force, the non-ideal constraint force, the holonomic residual and the
//! events, each emitted only when the declaration has it (`HAS_*` constants
//! tell the runtime which are present).

use super::body::{matrix_outputs, Body, Dest, Gen, Out};
use crate::emit::Target;
use crate::source::sexpr;
use crate::spec::{EventDirection, SystemSpec};
use proc_macro2::{Literal, TokenStream};
use quote::{format_ident, quote};

/// One effect's bodies: the value method, the by-value Jacobian method
/// (with its operation count each) and the in-place `add_*` method.
pub(super) type EffectBody = (Body, Body, TokenStream);

/// Bodies (statements, operation count) of the optional-effect methods;
/// `None` when the declaration lacks the effect.
pub(super) struct EffectBodies {
    /// `external_force`, `external_force_jacobians` and
    /// `add_external_force_jacobians` (same statements, accumulated in place).
    pub(super) forcing: Option<EffectBody>,
    /// `nonideal_force`, `nonideal_force_jacobians` and
    /// `add_nonideal_force_jacobians`.
    pub(super) nonideal: Option<EffectBody>,
    /// `holonomic_residual`.
    pub(super) holonomic: Option<TokenStream>,
}

impl Gen<'_> {
    /// Bodies of the optional-effect methods (after [`Gen::fused`], so that
    /// the stage functions are emitted from the same graph either way).
    pub(super) fn effects(&mut self) -> EffectBodies {
        let mut out = EffectBodies { forcing: None, nonideal: None, holonomic: None };
        if !self.model.external_force.is_empty() {
            out.forcing = Some(self.forcing());
        }
        if !self.model.nonideal_force.is_empty() {
            out.nonideal = Some(self.nonideal());
        }
        if !self.model.holonomic.is_empty() {
            let m = self.m.clone();
            let g = self.vector("holonomic", &self.model.holonomic.clone(), &m);
            out.holonomic = Some(self.body("holonomic_residual", Vec::new(), &[g], false).0);
        }
        out
    }

    fn forcing(&mut self) -> EffectBody {
        let n = self.n.clone();
        let md = &*self.model;
        let f = self.vector("external_force", &md.external_force, &n);
        let fq = self.matrix("external_force_q", &md.external_force_q, &n);
        let fv = self.matrix("external_force_v", &md.external_force_v, &n);
        let value = self.body("external_force", Vec::new(), std::slice::from_ref(&f), false);
        let adds = [f.clone().into_dest(Dest::Add), fq.clone().into_dest(Dest::Add), fv.clone().into_dest(Dest::Add)];
        let jac = self.body("external_force_jacobians", Vec::new(), &[f, fq, fv], false);
        let add = self.body("add_external_force_jacobians", Vec::new(), &adds, false).0;
        (value, jac, add)
    }

    fn nonideal(&mut self) -> EffectBody {
        let (n, m, rt) = (self.n.clone(), self.m.clone(), self.rt.clone());
        let md = &*self.model;
        let f = self.vector("nonideal_force", &md.nonideal_force, &n);
        let fq = self.matrix("nonideal_force_q", &md.nonideal_force_q, &n);
        let fv = self.matrix("nonideal_force_v", &md.nonideal_force_v, &n);
        let name = format_ident!("nonideal_force_psi");
        let fpsi = Out {
            entries: matrix_outputs(&name, &md.nonideal_force_psi),
            ty: quote!(#rt::Matrix<#n, #m>),
            name,
            dest: Dest::Local,
        };
        let value = self.body("nonideal_force", Vec::new(), std::slice::from_ref(&f), true);
        let adds = [
            f.clone().into_dest(Dest::Add),
            fq.clone().into_dest(Dest::Add),
            fv.clone().into_dest(Dest::Add),
            fpsi.clone().into_dest(Dest::Write),
        ];
        let jac = self.body("nonideal_force_jacobians", Vec::new(), &[f, fq, fv, fpsi], true);
        let add = self.body("add_nonideal_force_jacobians", Vec::new(), &adds, true).0;
        (value, jac, add)
    }
}

/// The effect items of the trait implementation: `HAS_FORCING` and the
/// external-force methods, `HAS_NONIDEAL_FORCE` and the non-ideal methods,
/// `HAS_HOLONOMIC` and `holonomic_residual`, then the events.
pub(super) fn effect_items(gen: &mut Gen, spec: &SystemSpec, effects: EffectBodies) -> TokenStream {
    let (rt, n, m) = (gen.rt.clone(), gen.n.clone(), gen.m.clone());
    let sig = quote!(&self, t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>);
    let psi_sig = quote!(psi: &#rt::Vector<#m>);
    let mut items = TokenStream::new();
    if let Some(((value, _), (jac, _), add)) = effects.forcing {
        items.extend(quote! {
            const HAS_FORCING: bool = true;

            fn external_force(#sig) -> #rt::Vector<#n> {
                #value
                external_force
            }

            fn external_force_jacobians(#sig) -> (#rt::Vector<#n>, #rt::Matrix<#n, #n>, #rt::Matrix<#n, #n>) {
                #jac
                (external_force, external_force_q, external_force_v)
            }

            fn add_external_force_jacobians(
                #sig,
                values: &mut #rt::StageValues<#n, #m>,
                jacobians: &mut #rt::StageJacobians<#n, #m>
            ) {
                let external_force = &mut values.force;
                let external_force_q = &mut jacobians.force_q;
                let external_force_v = &mut jacobians.force_v;
                #add
            }
        });
    }
    if let Some(((value, _), (jac, _), add)) = effects.nonideal {
        items.extend(quote! {
            const HAS_NONIDEAL_FORCE: bool = true;

            fn nonideal_force(#sig, #psi_sig) -> #rt::Vector<#n> {
                #value
                nonideal_force
            }

            fn nonideal_force_jacobians(#sig, #psi_sig) -> #rt::NonidealJacobians<#n, #m> {
                #jac
                #rt::NonidealJacobians {
                    value: nonideal_force,
                    q: nonideal_force_q,
                    v: nonideal_force_v,
                    psi: nonideal_force_psi,
                }
            }

            fn add_nonideal_force_jacobians(
                #sig,
                #psi_sig,
                values: &mut #rt::StageValues<#n, #m>,
                jacobians: &mut #rt::StageJacobians<#n, #m>,
                psi_jacobian: &mut #rt::Matrix<#n, #m>
            ) {
                let nonideal_force = &mut values.constraint_force;
                let nonideal_force_q = &mut jacobians.constraint_force_q;
                let nonideal_force_v = &mut jacobians.constraint_force_v;
                let nonideal_force_psi = psi_jacobian;
                #add
            }
        });
    }
    if let Some(body) = effects.holonomic {
        items.extend(quote! {
            const HAS_HOLONOMIC: bool = true;

            fn holonomic_residual(&self, t: f64, q: &#rt::Vector<#n>) -> #rt::Vector<#m> {
                #body
                holonomic
            }
        });
    }
    if !spec.events.is_empty() {
        items.extend(event_items(gen, spec));
    }
    items
}

/// `HAS_EVENTS`, `EVENTS`, `event_value` and `event_gradient` of a
/// declaration with events: one match arm per event, each with its own
/// statements (an event's value never pays for another's).
fn event_items(gen: &mut Gen, spec: &SystemSpec) -> TokenStream {
    let (rt, n) = (gen.rt.clone(), gen.n.clone());
    let sig = quote!(&self, index: usize, t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>);
    let (mut value_arms, mut gradient_arms, mut specs) = (Vec::new(), Vec::new(), Vec::new());
    for (e, decl) in spec.events.iter().enumerate() {
        let index = Literal::usize_unsuffixed(e);
        let md = &*gen.model;
        let (node, node_t) = (md.events[e], md.events_t[e]);
        let (gq, gv) = (md.events_q[e].clone(), md.events_v[e].clone());
        let value = gen.scalar("event_value", "event", node);
        value_arms.push(quote!(#index => { #value event }));
        let outs = [gen.vector("event_q", &gq, &n), gen.vector("event_v", &gv, &n)];
        let lets = vec![(Target::Let(format_ident!("event")), node), (Target::Let(format_ident!("event_t")), node_t)];
        let (gradient, _) = gen.body("event_gradient", lets, &outs, false);
        gradient_arms.push(quote!(#index => {
            #gradient
            #rt::EventGradient { value: event, t: event_t, q: event_q, v: event_v }
        }));
        let name = &decl.name.name;
        let direction = match decl.direction {
            EventDirection::Rising => quote!(#rt::Direction::Rising),
            EventDirection::Falling => quote!(#rt::Direction::Falling),
            EventDirection::Both => quote!(#rt::Direction::Both),
        };
        let terminal = decl.terminal;
        let source = sexpr(spec, &decl.expr);
        specs.push(quote!(#rt::EventSpec { name: #name, direction: #direction, terminal: #terminal, source: #source }));
    }
    quote! {
        const HAS_EVENTS: bool = true;
        const EVENTS: &'static [#rt::EventSpec] = &[#(#specs),*];

        fn event_value(#sig) -> f64 {
            match index {
                #(#value_arms)*
                _ => 0.0,
            }
        }

        fn event_gradient(#sig) -> #rt::EventGradient<#n> {
            match index {
                #(#gradient_arms)*
                _ => #rt::EventGradient::zeros(),
            }
        }
    }
}
