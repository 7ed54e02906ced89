//! Method bodies: the outputs a generated method computes ([`Out`]), their
//! emission through [`crate::emit`] and the splitting of long bodies into
//! helper functions, plus the fused stage functions and the bundle that the
//! operation counts cover.

use crate::emit::{emit, Emitted, Inputs, Target};
use crate::graph::NodeId;
use crate::model::{Model, NodeMatrix};
use proc_macro2::{Ident, Literal, TokenStream};
use quote::{format_ident, quote};
use std::cell::RefCell;

use super::SPLIT_STATEMENTS;

/// A method body and its operation count.
pub(super) type Body = (TokenStream, usize);

fn vector_outputs(name: &Ident, xs: &[NodeId]) -> Vec<(Target, NodeId)> {
    xs.iter().enumerate().map(|(i, &x)| (Target::Store(name.clone(), i, None), x)).collect()
}

pub(super) fn matrix_outputs(name: &Ident, xs: &NodeMatrix) -> Vec<(Target, NodeId)> {
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
pub(super) enum Dest {
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
pub(super) struct Out {
    pub(super) name: Ident,
    pub(super) ty: TokenStream,
    pub(super) entries: Vec<(Target, NodeId)>,
    pub(super) dest: Dest,
}

impl Out {
    /// The same output written into caller storage (`Write`) or accumulated
    /// into it (`Add`) instead of a local.
    pub(super) fn into_dest(mut self, dest: Dest) -> Self {
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

/// The generator of one declaration's method bodies: the model whose graph
/// the bodies are emitted from, the parameter names, the runtime path, the
/// literals `N` and `M`, and the helper functions split-off bodies call.
pub(super) struct Gen<'a> {
    pub(super) model: &'a mut Model,
    pub(super) params: Vec<Ident>,
    pub(super) rt: TokenStream,
    pub(super) n: Literal,
    pub(super) m: Literal,
    pub(super) helpers: Vec<TokenStream>,
    /// The memo slots of the stage bodies' sine–cosine pairs, by argument
    /// (see [`Inputs::sin_cos_memo`]).
    pub(super) sin_cos_slots: RefCell<Vec<NodeId>>,
}

impl<'a> Gen<'a> {
    /// A generator over `model` with runtime path `rt` and sizes `n`, `m`.
    pub(super) fn new(model: &'a mut Model, params: &[Ident], rt: TokenStream, n: usize, m: usize) -> Gen<'a> {
        Gen {
            model,
            params: params.to_vec(),
            rt,
            n: Literal::usize_unsuffixed(n),
            m: Literal::usize_unsuffixed(m),
            helpers: Vec::new(),
            sin_cos_slots: RefCell::new(Vec::new()),
        }
    }

    pub(super) fn vector(&self, name: &str, xs: &[NodeId], len: &Literal) -> Out {
        let name = format_ident!("{}", name);
        let rt = &self.rt;
        Out { entries: vector_outputs(&name, xs), ty: quote!(#rt::Vector<#len>), name, dest: Dest::Local }
    }

    pub(super) fn matrix(&self, name: &str, xs: &NodeMatrix, rows: &Literal) -> Out {
        let name = format_ident!("{}", name);
        let (rt, n) = (&self.rt, &self.n);
        Out { entries: matrix_outputs(&name, xs), ty: quote!(#rt::Matrix<#rows, #n>), name, dest: Dest::Local }
    }

    /// Emits a body computing `outs` (locals declared with `zeros()`, or
    /// `&mut` bindings into caller storage, see [`Dest`]) and the scalar
    /// `lets`, splitting it into helpers when it is large. Returns the
    /// statements and the operation count.
    pub(super) fn body(&mut self, fname: &str, lets: Vec<(Target, NodeId)>, outs: &[Out], psi: bool) -> Body {
        self.body_with_memo(fname, lets, outs, psi, false)
    }

    /// [`body`](Self::body), its sine–cosine pairs kept in the stage point's
    /// `sin_cos_memo` when `memo` (the stage bodies, which have one in scope).
    pub(super) fn body_with_memo(
        &mut self,
        fname: &str,
        lets: Vec<(Target, NodeId)>,
        outs: &[Out],
        psi: bool,
        memo: bool,
    ) -> Body {
        let mut entries = lets;
        for o in outs {
            entries.extend(o.entries.iter().cloned());
        }
        let slots = memo.then_some(&self.sin_cos_slots);
        let inputs = Inputs { parameters: &self.params, runtime: &self.rt, sin_cos_memo: slots };
        let emitted = emit(&mut self.model.graph, &entries, &inputs);
        let Emitted { ops, shared, .. } = emitted;
        let statements = &emitted.statements;
        let decls = self.decls(outs);
        let has_lets = entries.iter().any(|(t, _)| matches!(t, Target::Let(_)));
        // Helpers take `(t, q, v)`; `holonomic_residual` has no `v` to pass.
        if statements.len() <= SPLIT_STATEMENTS || has_lets || fname == "holonomic_residual" {
            return (quote!(#(#decls)* #(#statements)*), ops);
        }
        (self.split(fname, decls, emitted.statements_in_array(), shared, outs, psi), ops)
    }

    /// The declarations `outs` need before their stores: a local's
    /// `zeros()`, or the zeroing of caller storage whose structural zeros
    /// the stores skip.
    pub(super) fn decls(&self, outs: &[Out]) -> Vec<TokenStream> {
        let graph = &self.model.graph;
        let decls = outs.iter().filter_map(|o| {
            let (name, ty) = (&o.name, &o.ty);
            match o.dest {
                Dest::Local => Some(quote!(let mut #name = <#ty>::zeros();)),
                // Through the contiguous slice: a `memset` of constant length, where
                // nalgebra's `fill` walks its element iterator one entry at a
                // time (a third of an mp7 full-Newton step).
                Dest::Write if o.entries.iter().any(|(_, x)| graph.is_const(*x, 0.0)) => {
                    Some(quote!(#name.as_mut_slice().fill(0.0);))
                }
                Dest::Write | Dest::Add => None,
            }
        });
        decls.collect()
    }

    /// A body that computes the single output `out` and returns it by value.
    pub(super) fn returning(&mut self, fname: &str, out: Out) -> TokenStream {
        let name = out.name.clone();
        let (body, _) = self.body(fname, Vec::new(), &[out], false);
        quote!(#body #name)
    }

    /// A body that computes the scalar `name` (a `let`) and returns it.
    pub(super) fn scalar(&mut self, fname: &str, name: &str, node: NodeId) -> TokenStream {
        self.body(fname, vec![(Target::Let(format_ident!("{}", name)), node)], &[], false).0
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

    pub(super) fn stage_outs(&self) -> (Vec<Out>, Vec<Out>) {
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

    /// Bodies of `stage_values_into` and `stage_jacobians_into` (writing
    /// through `&mut` bindings to the caller's `StageValues`/`StageJacobians`
    /// fields; `stage_values` and `stage_jacobians` delegate to them) and
    /// the bundle.
    pub(super) fn fused(&mut self) -> (Body, Body, Body) {
        let (values, jacobians) = self.stage_outs();
        let values: Vec<Out> = values.into_iter().map(|o| o.into_dest(Dest::Write)).collect();
        let sv = self.body_with_memo("stage_values", Vec::new(), &values, true, true);
        let mut all = values;
        all.extend(jacobians);
        let all: Vec<Out> = all.into_iter().map(|o| o.into_dest(Dest::Write)).collect();
        let sj = self.body_with_memo("stage_jacobians", Vec::new(), &all, true, true);
        (sv, sj, self.bundle())
    }

    /// Body of `stage_values_and_constraint_jacobians`: the stage values
    /// and `k_q`, `K = k_v`, written through `&mut` bindings into the
    /// caller's storage, with their shared subexpressions computed once.
    pub(super) fn values_and_constraint_jacobians(&mut self) -> Body {
        let (values, _) = self.stage_outs();
        let m = self.m.clone();
        let md = &*self.model;
        let mut outs = values;
        outs.push(self.matrix("constraint_q", &md.constraint_q, &m));
        outs.push(self.matrix("constraint_v", &md.constraint_v, &m));
        let outs: Vec<Out> = outs.into_iter().map(|o| o.into_dest(Dest::Write)).collect();
        self.body_with_memo("stage_values_and_constraint_jacobians", Vec::new(), &outs, true, true)
    }

    /// The outputs a step reads at its end point (and the midpoint of the
    /// methods with a midpoint constraint): the momentum and the constraint
    /// (`values`), and with them `k_q`, `K = k_v` (`fused`), written into
    /// the caller's storage. The forces there enter no equation.
    pub(super) fn end_point_outs(&self) -> (Vec<Out>, Vec<Out>) {
        let (n, m) = (self.n.clone(), self.m.clone());
        let md = &*self.model;
        let values = vec![self.vector("momentum", &md.momentum, &n), self.vector("constraint", &md.constraint, &m)];
        let mut fused = values.clone();
        fused.push(self.matrix("constraint_q", &md.constraint_q, &m));
        fused.push(self.matrix("constraint_v", &md.constraint_v, &m));
        let write = |outs: Vec<Out>| -> Vec<Out> { outs.into_iter().map(|o| o.into_dest(Dest::Write)).collect() };
        (write(values), write(fused))
    }

    /// Bodies of `end_point_values_into` and
    /// `end_point_values_and_constraint_jacobians` ([`Self::end_point_outs`]).
    pub(super) fn end_point(&mut self) -> (Body, Body) {
        let (values, fused) = self.end_point_outs();
        let values = self.body_with_memo("end_point_values", Vec::new(), &values, false, true);
        let fused = self.body_with_memo("end_point_values_and_constraint_jacobians", Vec::new(), &fused, false, true);
        (values, fused)
    }

    /// The two bodies of `stage_values_in_lanes` in lane form (see
    /// [`crate::emit::Emitted::statements_in_lanes`]): the stage values,
    /// and the stage values with `k_q` and `K = k_v`. `None` when either is
    /// longer than [`SPLIT_STATEMENTS`]: such a system keeps the trait's
    /// lane-by-lane default rather than one very long generic function.
    pub(super) fn lane_bodies(&mut self) -> Option<(TokenStream, TokenStream)> {
        let (values, _) = self.stage_outs();
        let m = self.m.clone();
        let md = &*self.model;
        let mut fused = values.clone();
        fused.push(self.matrix("constraint_q", &md.constraint_q, &m));
        fused.push(self.matrix("constraint_v", &md.constraint_v, &m));
        let values = self.lane_body(&values)?;
        let fused = self.lane_body(&fused)?;
        Some((values, fused))
    }

    /// The two bodies of `end_point_values_in_lanes` in lane form: the
    /// momentum and the constraint, and with them `k_q` and `K = k_v`
    /// ([`Self::end_point_outs`]). `None` when either is longer than
    /// [`SPLIT_STATEMENTS`] (the trait's default then evaluates the stage
    /// values in lanes at `ψ = 0`).
    pub(super) fn lane_end_point_bodies(&mut self) -> Option<(TokenStream, TokenStream)> {
        let (values, fused) = self.end_point_outs();
        let values = self.lane_body(&values)?;
        let fused = self.lane_body(&fused)?;
        Some((values, fused))
    }

    /// The body of `energy_in_lanes` in lane form (a lane array `energy`),
    /// or `None` when it is longer than [`SPLIT_STATEMENTS`].
    pub(super) fn lane_energy(&mut self) -> Option<TokenStream> {
        let energy = (Target::Let(format_ident!("energy")), self.model.energy);
        self.lane_statements(vec![energy])
    }

    fn lane_body(&mut self, outs: &[Out]) -> Option<TokenStream> {
        self.lane_statements(outs.iter().flat_map(|o| o.entries.iter().cloned()).collect())
    }

    fn lane_statements(&mut self, entries: Vec<(Target, NodeId)>) -> Option<TokenStream> {
        let inputs = Inputs { parameters: &self.params, runtime: &self.rt, sin_cos_memo: None };
        let emitted = emit(&mut self.model.graph, &entries, &inputs);
        if emitted.statements.len() > SPLIT_STATEMENTS {
            return None;
        }
        let statements = emitted.statements_in_lanes();
        Some(quote!(#(#statements)*))
    }

    /// The statements of the bundle (see [`super::Operations::bundle`]).
    fn bundle(&mut self) -> Body {
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
        let inputs = Inputs { parameters: &self.params, runtime: &self.rt, sin_cos_memo: None };
        let mut entries = l;
        for o in &bundle_outs {
            entries.extend(o.entries.iter().cloned());
        }
        let bundle = emit(&mut self.model.graph, &entries, &inputs);
        let statements = bundle.statements;
        (quote!(#(#statements)*), bundle.ops)
    }
}
