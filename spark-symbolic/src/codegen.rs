//! Assembly of the generated items: the parameter struct, its `Default`, the
//! inherent `N`/`M`/`new`, and the `NonholonomicSystem` implementation whose
//! method bodies come from [`crate::emit`].

use crate::emit::{emit, Emitted, Inputs, Target};
use crate::graph::NodeId;
use crate::model::{ConstraintForm, Model, NodeMatrix};
use crate::source::sexpr;
use crate::spec::{SpecError, SystemSpec};
use proc_macro2::{Ident, Literal, TokenStream};
use quote::{format_ident, quote};

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

/// Statement threshold above which a body is split into helper functions
/// so that rustc's super-linear passes stay fast.
pub const SPLIT_STATEMENTS: usize = 150;

fn vector_outputs(name: &Ident, xs: &[NodeId]) -> Vec<(Target, NodeId)> {
    xs.iter().enumerate().map(|(i, &x)| (Target::Store(name.clone(), i, None), x)).collect()
}

fn matrix_outputs(name: &Ident, xs: &NodeMatrix) -> Vec<(Target, NodeId)> {
    let mut out = Vec::new();
    for (i, row) in xs.iter().enumerate() {
        for (j, &x) in row.iter().enumerate() {
            out.push((Target::Store(name.clone(), i, Some(j)), x));
        }
    }
    out
}

/// Where a generated method's output lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Dest {
    /// A local `let mut name = zeros();` the method returns by value.
    Local,
    /// A `name: &mut` binding into the caller's storage, overwritten: zeroed
    /// first (one `fill`) only when some entry is structurally zero, since
    /// the stores skip zero entries.
    Write,
    /// A `name: &mut` binding into the caller's storage, accumulated into
    /// (`+=`): never zeroed.
    Add,
}

/// One output variable of a generated method: its name, type and entries.
#[derive(Clone)]
struct Out {
    name: Ident,
    ty: TokenStream,
    entries: Vec<(Target, NodeId)>,
    dest: Dest,
}

impl Out {
    /// The same output written into caller storage (`Write`) or accumulated
    /// into it (`Add`) instead of a local.
    fn into_dest(mut self, dest: Dest) -> Self {
        if dest == Dest::Add {
            for (t, _) in &mut self.entries {
                if let Target::Store(name, i, j) = t {
                    *t = Target::Add(name.clone(), *i, *j);
                }
            }
        }
        self.dest = dest;
        self
    }
}

struct Gen<'a> {
    model: &'a mut Model,
    params: Vec<Ident>,
    rt: TokenStream,
    n: Literal,
    m: Literal,
    helpers: Vec<TokenStream>,
}

impl Gen<'_> {
    fn vector(&self, name: &str, xs: &[NodeId], len: &Literal) -> Out {
        let name = format_ident!("{}", name);
        let rt = &self.rt;
        Out { entries: vector_outputs(&name, xs), ty: quote!(#rt::Vector<#len>), name, dest: Dest::Local }
    }

    fn matrix(&self, name: &str, xs: &NodeMatrix, rows: &Literal) -> Out {
        let name = format_ident!("{}", name);
        let (rt, n) = (&self.rt, &self.n);
        Out { entries: matrix_outputs(&name, xs), ty: quote!(#rt::Matrix<#rows, #n>), name, dest: Dest::Local }
    }

    /// Emits a body computing `outs` (locals declared with `zeros()`, or
    /// `&mut` bindings into caller storage, see [`Dest`]) and the scalar
    /// `lets`, splitting it into helpers when it is large. Returns the
    /// statements and the operation count.
    fn body(&mut self, fname: &str, lets: Vec<(Target, NodeId)>, outs: &[Out], psi: bool) -> (TokenStream, usize) {
        let mut entries = lets;
        for o in outs {
            entries.extend(o.entries.iter().cloned());
        }
        let inputs = Inputs { parameters: &self.params };
        let emitted = emit(&mut self.model.graph, &entries, &inputs);
        let Emitted { ops, shared, .. } = emitted;
        let statements = &emitted.statements;
        let graph = &self.model.graph;
        let decls = outs.iter().filter_map(|o| {
            let (name, ty) = (&o.name, &o.ty);
            match o.dest {
                Dest::Local => Some(quote!(let mut #name = <#ty>::zeros();)),
                Dest::Write if o.entries.iter().any(|(_, x)| graph.is_const(*x, 0.0)) => Some(quote!(#name.fill(0.0);)),
                Dest::Write | Dest::Add => None,
            }
        });
        let decls: Vec<TokenStream> = decls.collect();
        let has_lets = entries.iter().any(|(t, _)| matches!(t, Target::Let(_)));
        // Helpers take `(t, q, v)`; `holonomic_residual` has no `v` to pass.
        if statements.len() <= SPLIT_STATEMENTS || has_lets || fname == "holonomic_residual" {
            return (quote!(#(#decls)* #(#statements)*), ops);
        }
        (self.split(fname, decls, emitted.statements_in_array(), shared, outs, psi), ops)
    }

    /// Splits a long body: shared values move into a stack array `w`, and
    /// consecutive chunks of statements become helper functions.
    fn split(
        &mut self,
        fname: &str,
        decls: Vec<TokenStream>,
        statements: Vec<TokenStream>,
        shared: usize,
        outs: &[Out],
        psi: bool,
    ) -> TokenStream {
        let (rt, n, m) = (&self.rt, &self.n, &self.m);
        let psi_param = if psi { quote!(psi: &#rt::Vector<#m>,) } else { quote!() };
        let psi_arg = if psi { quote!(psi,) } else { quote!() };
        let out_params: Vec<TokenStream> = outs
            .iter()
            .map(|o| {
                let (name, ty) = (&o.name, &o.ty);
                quote!(#name: &mut #ty)
            })
            .collect();
        let out_args: Vec<TokenStream> = outs
            .iter()
            .map(|o| {
                let name = &o.name;
                match o.dest {
                    Dest::Local => quote!(&mut #name),
                    Dest::Write | Dest::Add => quote!(&mut *#name),
                }
            })
            .collect();
        let shared_len = Literal::usize_unsuffixed(shared.max(1));
        let mut calls = Vec::new();
        for (k, chunk) in statements.chunks(SPLIT_STATEMENTS).enumerate() {
            let helper = format_ident!("__{}_part{}", fname, k);
            self.helpers.push(quote! {
                #[inline(never)]
                #[allow(clippy::too_many_arguments)]
                fn #helper(&self, t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>, #psi_param
                    w: &mut [f64; #shared_len], #(#out_params),*) {
                    #(#chunk)*
                }
            });
            calls.push(quote!(self.#helper(t, q, v, #psi_arg &mut w, #(#out_args),*);));
        }
        quote! {
            #(#decls)*
            let mut w = [0.0f64; #shared_len];
            #(#calls)*
        }
    }
}

fn form_tokens(rt: &TokenStream, f: ConstraintForm) -> TokenStream {
    match f {
        ConstraintForm::None => quote!(#rt::ConstraintForm::None),
        ConstraintForm::Linear => quote!(#rt::ConstraintForm::Linear),
        ConstraintForm::Affine => quote!(#rt::ConstraintForm::Affine),
        ConstraintForm::Nonlinear => quote!(#rt::ConstraintForm::Nonlinear),
    }
}

/// Operation counts of a built model, without generating code.
pub fn count_operations(model: &mut Model, params: &[Ident]) -> Operations {
    let mut gen = Gen {
        model,
        params: params.to_vec(),
        rt: quote!(::spark_runtime),
        n: Literal::usize_unsuffixed(0),
        m: Literal::usize_unsuffixed(0),
        helpers: Vec::new(),
    };
    let (sv, sj, bundle) = gen.fused();
    let effects = gen.effects();
    Operations {
        stage_values: sv.1,
        stage_jacobians: sj.1,
        bundle: bundle.1,
        external_force_jacobians: effects.forcing.as_ref().map_or(0, |f| f.1 .1),
        nonideal_force_jacobians: effects.nonideal.as_ref().map_or(0, |f| f.1 .1),
    }
}

/// One effect's bodies: the value method, the by-value Jacobian method
/// (with its operation count each) and the in-place `add_*` method.
type EffectBody = ((TokenStream, usize), (TokenStream, usize), TokenStream);

/// Bodies (statements, operation count) of the optional-effect methods;
/// `None` when the declaration lacks the effect.
struct EffectBodies {
    /// `external_force`, `external_force_jacobians` and
    /// `add_external_force_jacobians` (same statements, accumulated in place).
    forcing: Option<EffectBody>,
    /// `nonideal_force`, `nonideal_force_jacobians` and
    /// `add_nonideal_force_jacobians`.
    nonideal: Option<EffectBody>,
    /// `holonomic_residual`.
    holonomic: Option<TokenStream>,
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
        let (value, _) = gen.body("event_value", vec![(Target::Let(format_ident!("event")), node)], &[], false);
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
            crate::spec::EventDirection::Rising => quote!(#rt::Direction::Rising),
            crate::spec::EventDirection::Falling => quote!(#rt::Direction::Falling),
            crate::spec::EventDirection::Both => quote!(#rt::Direction::Both),
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

/// The statements of the bundle CasADi is compared with (see
/// [`Operations::bundle`]), for review of what the count covers.
pub fn bundle_code(model: &mut Model, params: &[Ident]) -> (TokenStream, usize) {
    let mut gen = Gen {
        model,
        params: params.to_vec(),
        rt: quote!(::spark_runtime),
        n: Literal::usize_unsuffixed(0),
        m: Literal::usize_unsuffixed(0),
        helpers: Vec::new(),
    };
    gen.fused().2
}

impl Gen<'_> {
    fn stage_outs(&self) -> (Vec<Out>, Vec<Out>) {
        let (n, m) = (self.n.clone(), self.m.clone());
        let md = &*self.model;
        let values = vec![
            self.vector("momentum", &md.momentum, &n),
            self.vector("force", &md.force, &n),
            self.vector("constraint", &md.constraint, &m),
            self.vector("constraint_force", &md.constraint_force, &n),
        ];
        let jacobians = vec![
            self.matrix("momentum_q", &md.momentum_q, &n),
            self.matrix("mass", &md.mass, &n),
            self.matrix("force_q", &md.force_q, &n),
            self.matrix("force_v", &md.force_v, &n),
            self.matrix("constraint_q", &md.constraint_q, &m),
            self.matrix("constraint_v", &md.constraint_v, &m),
            self.matrix("constraint_force_q", &md.constraint_force_q, &n),
            self.matrix("constraint_force_v", &md.constraint_force_v, &n),
        ];
        (values, jacobians)
    }

    /// Bodies of the optional-effect methods (after [`Self::fused`], so that
    /// the stage functions are emitted from the same graph either way).
    fn effects(&mut self) -> EffectBodies {
        let (n, m, rt) = (self.n.clone(), self.m.clone(), self.rt.clone());
        let mut out = EffectBodies { forcing: None, nonideal: None, holonomic: None };
        if !self.model.external_force.is_empty() {
            let md = &*self.model;
            let f = self.vector("external_force", &md.external_force, &n);
            let fq = self.matrix("external_force_q", &md.external_force_q, &n);
            let fv = self.matrix("external_force_v", &md.external_force_v, &n);
            let value = self.body("external_force", Vec::new(), std::slice::from_ref(&f), false);
            let adds =
                [f.clone().into_dest(Dest::Add), fq.clone().into_dest(Dest::Add), fv.clone().into_dest(Dest::Add)];
            let jac = self.body("external_force_jacobians", Vec::new(), &[f, fq, fv], false);
            let add = self.body("add_external_force_jacobians", Vec::new(), &adds, false).0;
            out.forcing = Some((value, jac, add));
        }
        if !self.model.nonideal_force.is_empty() {
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
            out.nonideal = Some((value, jac, add));
        }
        if !self.model.holonomic.is_empty() {
            let g = self.vector("holonomic", &self.model.holonomic.clone(), &m);
            out.holonomic = Some(self.body("holonomic_residual", Vec::new(), &[g], false).0);
        }
        out
    }

    /// Bodies of `stage_values`, `stage_jacobians_into` (writing through
    /// `&mut` bindings to the caller's `StageValues`/`StageJacobians` fields;
    /// `stage_jacobians` delegates to it) and the bundle.
    fn fused(&mut self) -> ((TokenStream, usize), (TokenStream, usize), (TokenStream, usize)) {
        let (values, jacobians) = self.stage_outs();
        let sv = self.body("stage_values", Vec::new(), &values, true);
        let mut all = values;
        all.extend(jacobians);
        let all: Vec<Out> = all.into_iter().map(|o| o.into_dest(Dest::Write)).collect();
        let sj = self.body("stage_jacobians", Vec::new(), &all, true);
        let n = self.n.clone();
        let m = self.m.clone();
        // The bundle has Kᵀψ (as CasADi computes it), the negative of R.
        let md = &mut *self.model;
        let g = &mut md.graph;
        let neg_v =
            |g: &mut crate::graph::Graph, xs: &[NodeId]| -> Vec<NodeId> { xs.iter().map(|&x| g.neg(x)).collect() };
        let kt_psi = neg_v(g, &md.constraint_force);
        let kt_psi_q: NodeMatrix = md.constraint_force_q.iter().map(|row| neg_v(g, row)).collect();
        let kt_psi_v: NodeMatrix = md.constraint_force_v.iter().map(|row| neg_v(g, row)).collect();
        let md = &*self.model;
        let bundle_outs = vec![
            self.vector("force", &md.force, &n),
            self.vector("momentum", &md.momentum, &n),
            self.matrix("mass", &md.mass, &n),
            self.matrix("momentum_q", &md.momentum_q, &n),
            self.vector("constraint", &md.constraint, &m),
            self.matrix("constraint_q", &md.constraint_q, &m),
            self.matrix("constraint_v", &md.constraint_v, &m),
            self.vector("kt_psi", &kt_psi, &n),
            self.matrix("kt_psi_q", &kt_psi_q, &n),
            self.matrix("kt_psi_v", &kt_psi_v, &n),
        ];
        let l = vec![(Target::Let(format_ident!("lagrangian")), md.lagrangian)];
        let inputs = Inputs { parameters: &self.params };
        let mut entries = l;
        for o in &bundle_outs {
            entries.extend(o.entries.iter().cloned());
        }
        let bundle = emit(&mut self.model.graph, &entries, &inputs);
        let statements = bundle.statements;
        (sv, sj, (quote!(#(#statements)*), bundle.ops))
    }
}

/// Traits the user already derives on the struct (`#[derive(...)]` in the
/// attributes passed through), so that the generated derives do not clash.
fn user_derives(attrs: &TokenStream) -> Vec<Ident> {
    let mut out = Vec::new();
    let Ok(attrs) = syn::parse::Parser::parse2(syn::Attribute::parse_outer, attrs.clone()) else {
        return out;
    };
    for a in attrs.iter().filter(|a| a.path().is_ident("derive")) {
        let _ = a.parse_nested_meta(|m| {
            if let Some(seg) = m.path.segments.last() {
                out.push(seg.ident.clone());
            }
            Ok(())
        });
    }
    out
}

/// Generates all items for `spec` from its built `model`.
pub fn generate_items(spec: &SystemSpec, model: &mut Model) -> Result<(TokenStream, Operations), SpecError> {
    let rt = if spec.runtime_path.is_empty() { quote!(::spark_runtime) } else { spec.runtime_path.clone() };
    let params: Vec<Ident> = spec.parameters.iter().map(|p| Ident::new(&p.name.name, p.name.span)).collect();
    let (nn, mm) = (model.n, model.m);
    let structure = model.structure;
    let mut gen = Gen {
        model,
        params: params.clone(),
        rt: rt.clone(),
        n: Literal::usize_unsuffixed(nn),
        m: Literal::usize_unsuffixed(mm),
        helpers: Vec::new(),
    };
    let (n, m) = (gen.n.clone(), gen.m.clone());
    let sig = quote!(&self, t: f64, q: &#rt::Vector<#n>, v: &#rt::Vector<#n>);

    // Simple methods.
    let (lag_body, _) =
        gen.body("lagrangian", vec![(Target::Let(format_ident!("lagrangian")), gen.model.lagrangian)], &[], false);
    let (energy_body, _) =
        gen.body("energy", vec![(Target::Let(format_ident!("energy")), gen.model.energy)], &[], false);
    let single = |gen: &mut Gen, fname: &str, out: Out| -> TokenStream {
        let name = out.name.clone();
        let (body, _) = gen.body(fname, Vec::new(), &[out], false);
        quote!(#body #name)
    };
    let o = gen.vector("momentum", &gen.model.momentum.clone(), &n);
    let momentum_body = single(&mut gen, "momentum", o);
    let o = gen.vector("force", &gen.model.force.clone(), &n);
    let force_body = single(&mut gen, "force", o);
    let o = gen.matrix("mass", &gen.model.mass.clone(), &n);
    let mass_body = single(&mut gen, "mass_matrix", o);
    let o = gen.vector("constraint", &gen.model.constraint.clone(), &m);
    let constraint_body = single(&mut gen, "constraint", o);
    let o = gen.matrix("constraint_q", &gen.model.constraint_q.clone(), &m);
    let kq_body = single(&mut gen, "constraint_q", o);
    let o = gen.matrix("constraint_v", &gen.model.constraint_v.clone(), &m);
    let kv_body = single(&mut gen, "constraint_v", o);

    // Time derivatives.
    let md = &*gen.model;
    let td_outs = vec![
        gen.vector("momentum_t", &md.momentum_t, &n),
        gen.vector("force_t", &md.force_t, &n),
        gen.vector("constraint_t", &md.constraint_t, &m),
    ];
    let lt = md.lagrangian_t;
    let (td_body, _) =
        gen.body("time_derivatives", vec![(Target::Let(format_ident!("lagrangian_t")), lt)], &td_outs, false);

    // Fused stage functions.
    let (sv, sj, bundle) = gen.fused();
    let effects = gen.effects();
    let ops = Operations {
        stage_values: sv.1,
        stage_jacobians: sj.1,
        bundle: bundle.1,
        external_force_jacobians: effects.forcing.as_ref().map_or(0, |f| f.1 .1),
        nonideal_force_jacobians: effects.nonideal.as_ref().map_or(0, |f| f.1 .1),
    };
    let (sv_body, sj_body) = (sv.0, sj.0);
    let psi_sig = quote!(psi: &#rt::Vector<#m>);
    let mut effect_items = TokenStream::new();
    let sj_sig = quote!(
        #sig,
        psi: &#rt::Vector<#m>,
        values: &mut #rt::StageValues<#n, #m>,
        jacobians: &mut #rt::StageJacobians<#n, #m>
    );
    if let Some(((value, _), (jac, _), add)) = effects.forcing {
        effect_items.extend(quote! {
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
        effect_items.extend(quote! {
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
        effect_items.extend(quote! {
            const HAS_HOLONOMIC: bool = true;

            fn holonomic_residual(&self, t: f64, q: &#rt::Vector<#n>) -> #rt::Vector<#m> {
                #body
                holonomic
            }
        });
    }
    if !spec.events.is_empty() {
        effect_items.extend(event_items(&mut gen, spec));
    }
    let helpers = std::mem::take(&mut gen.helpers);

    // Struct, Default, inherent items.
    let (attrs, vis, name) = (&spec.attrs, &spec.vis, &spec.name);
    let derived = user_derives(attrs);
    if let Some(d) = derived.iter().find(|d| *d == "Default") {
        return Err(SpecError {
            span: d.span(),
            message: "`Default` is generated from the parameter defaults; remove it from `#[derive(...)]`".into(),
        });
    }
    let derives: Vec<Ident> = ["Clone", "Copy", "Debug", "PartialEq"]
        .iter()
        .filter(|t| !derived.iter().any(|d| d == *t))
        .map(|t| Ident::new(t, proc_macro2::Span::call_site()))
        .collect();
    let fields = spec.parameters.iter().zip(&params).map(|(p, id)| {
        let doc = format!("Runtime parameter `{}` (default `{:?}`).", p.name.name, p.default);
        quote!(#[doc = #doc] pub #id: f64,)
    });
    let defaults = spec.parameters.iter().zip(&params).map(|(p, id)| {
        let d = Literal::f64_unsuffixed(p.default.abs());
        if p.default < 0.0 {
            quote!(#id: -#d,)
        } else {
            quote!(#id: #d,)
        }
    });
    for p in &spec.parameters {
        if !p.default.is_finite() {
            return Err(SpecError {
                span: p.name.span,
                message: format!("parameter `{}` needs a finite default value", p.name.name),
            });
        }
    }

    // SOURCE.
    let name_str = name.to_string();
    let coord_names = spec.coordinates.iter().map(|c| c.name.clone());
    let param_names: Vec<String> = spec.parameters.iter().map(|p| p.name.name.clone()).collect();
    let lag_src = sexpr(spec, &spec.lagrangian);
    let k_src = spec.constraints.iter().map(|c| sexpr(spec, &c.expr));
    let components = |xs: &[Option<crate::spec::SrcExpr>]| -> Vec<String> {
        xs.iter().map(|x| x.as_ref().map_or_else(|| "0".to_string(), |e| sexpr(spec, e))).collect()
    };
    let f_src = components(&spec.external_force);
    let n_src = components(&spec.nonideal_force);
    let g_src: Vec<String> = if spec.constraints.iter().any(|c| c.position.is_some()) {
        spec.constraints
            .iter()
            .map(|c| c.position.as_ref().map_or_else(|| "0".to_string(), |g| sexpr(spec, g)))
            .collect()
    } else {
        Vec::new()
    };

    // set_parameter.
    let known = param_names.join(", ");
    let unknown = quote! {
        ::core::result::Result::Err(#rt::SystemError::UnknownParameter {
            name: ::std::string::ToString::to_string(name),
            known: ::std::string::ToString::to_string(#known),
        })
    };
    let set_body = if params.is_empty() {
        quote!(let _ = value; #unknown)
    } else {
        let arms = param_names.iter().zip(&params).map(|(s, id)| quote!(#s => &mut self.#id,));
        quote! {
            let slot: &mut f64 = match name {
                #(#arms)*
                _ => return #unknown,
            };
            if !value.is_finite() {
                return ::core::result::Result::Err(#rt::SystemError::NonFiniteParameter {
                    name: ::std::string::ToString::to_string(name),
                    value,
                });
            }
            *slot = value;
            ::core::result::Result::Ok(())
        }
    };

    let b = |x: bool| if x { quote!(true) } else { quote!(false) };
    let (la, ca, cm, sep) = (
        b(structure.lagrangian_autonomous),
        b(structure.constraints_autonomous),
        b(structure.constant_mass_matrix),
        b(structure.separable),
    );
    let form = form_tokens(&rt, structure.constraint_form);
    let (o_sv, o_sj, o_b) = (
        Literal::usize_unsuffixed(ops.stage_values),
        Literal::usize_unsuffixed(ops.stage_jacobians),
        Literal::usize_unsuffixed(ops.bundle),
    );
    let doc_n = "Number of generalized coordinates.";
    let doc_m = "Number of constraints.";
    let tokens = quote! {
        #attrs
        #[derive(#(#derives),*)]
        #vis struct #name {
            #(#fields)*
        }

        #[allow(clippy::all)]
        impl ::core::default::Default for #name {
            fn default() -> Self {
                Self { #(#defaults)* }
            }
        }

        #[allow(dead_code, unused_variables, unused_mut, clippy::all)]
        impl #name {
            #[doc = #doc_n]
            pub const N: usize = #n;
            #[doc = #doc_m]
            pub const M: usize = #m;
            /// The system with its default parameters.
            pub fn new() -> Self {
                <Self as ::core::default::Default>::default()
            }
            #(#helpers)*
        }

        #[allow(unused_variables, unused_mut, clippy::all)]
        impl #rt::NonholonomicSystem<#n, #m> for #name {
            const STRUCTURE: #rt::Structure = #rt::Structure {
                lagrangian_autonomous: #la,
                constraints_autonomous: #ca,
                constant_mass_matrix: #cm,
                separable: #sep,
                constraint_form: #form,
            };
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
            const OPERATIONS: #rt::OperationCounts = #rt::OperationCounts {
                stage_values: #o_sv,
                stage_jacobians: #o_sj,
                bundle: #o_b,
            };

            fn parameter_values(&self) -> ::std::vec::Vec<f64> {
                ::std::vec![#(self.#params),*]
            }

            fn set_parameter(&mut self, name: &str, value: f64) -> ::core::result::Result<(), #rt::SystemError> {
                #set_body
            }

            fn lagrangian(#sig) -> f64 {
                #lag_body
                lagrangian
            }

            fn energy(#sig) -> f64 {
                #energy_body
                energy
            }

            fn momentum(#sig) -> #rt::Vector<#n> {
                #momentum_body
            }

            fn force(#sig) -> #rt::Vector<#n> {
                #force_body
            }

            fn mass_matrix(#sig) -> #rt::Matrix<#n, #n> {
                #mass_body
            }

            fn constraint(#sig) -> #rt::Vector<#m> {
                #constraint_body
            }

            fn constraint_q(#sig) -> #rt::Matrix<#m, #n> {
                #kq_body
            }

            fn constraint_v(#sig) -> #rt::Matrix<#m, #n> {
                #kv_body
            }

            fn time_derivatives(#sig) -> #rt::TimeDerivatives<#n, #m> {
                #td_body
                #rt::TimeDerivatives { lagrangian_t, momentum_t, force_t, constraint_t }
            }

            fn stage_values(#sig, psi: &#rt::Vector<#m>) -> #rt::StageValues<#n, #m> {
                #sv_body
                #rt::StageValues { momentum, force, constraint, constraint_force }
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

            fn stage_jacobians_into(#sj_sig) {
                let #rt::StageValues { momentum, force, constraint, constraint_force } = values;
                let #rt::StageJacobians {
                    momentum_q, mass, force_q, force_v, constraint_q, constraint_v,
                    constraint_force_q, constraint_force_v,
                } = jacobians;
                #sj_body
            }

            #effect_items
        }
    };
    Ok((tokens, ops))
}
