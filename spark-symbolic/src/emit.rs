//! Code emission for one generated function: common-subexpression
//! elimination across all its outputs, a readable rendering of each node
//! (subtractions, divisions, `sqrt`, powers as multiplications) and the
//! operation count of exactly the code emitted.
//!
//! Because the graph is hash-consed, CSE amounts to binding every node the
//! rendered code references more than once to a `let`, in topological order.
//! Nodes that depend on runtime parameters only are bound first, so they are
//! computed once per call however often they are used.
//!
//! **Operation count** (what [`Emitted::ops`] and `OperationCounts` report):
//! every binary `+ − × ÷` written in the generated code counts 1, every
//! function or method call (`sqrt`, `sin`, `atan2`, `powi`, `powf`, …) counts
//! 1, a unary minus counts 1. Negative literals, reading inputs or
//! parameters, and stores count 0. A negation folded into a subtraction
//! (`a − b` instead of `a + (−b)`) is just the subtraction. Each shared
//! subexpression is counted once. Zero outputs are not written (the output
//! was created by `zeros()`), so they cost nothing.
//!
//! **Sine–cosine pairs.** When a body uses both `sin x` and `cos x` of one
//! node `x`, both are bound, next to each other, by one call of the
//! runtime's `trig::sin_cos` (one argument reduction for the two; counted
//! as the two calls it replaces). A lone `sin` or `cos` stays the method.

use crate::graph::{Deps, Graph, Node, NodeId, Var};
use crate::simplify::is_int;
use prefixes::Prefixes;
pub(crate) use prefixes::KEPT_PREFIX;
use proc_macro2::{Delimiter, Group, Ident, Literal, Span, TokenStream, TokenTree};
use quote::{format_ident, quote};
use std::cell::RefCell;
use std::collections::{HashMap, HashSet};

mod prefixes;

/// How the rendered code uses a node: the children listed here are the ones
/// the code refers to, which is what CSE counts.
#[derive(Clone, Debug)]
enum View {
    Leaf,
    /// `±t1 ± t2 … + constant`, each `t` a node (positive counterpart for `−`),
    /// plus `± c·inner` for groups of terms sharing the coefficient `c`.
    Sum {
        terms: Vec<(bool, NodeId)>,
        scaled: Vec<(bool, f64, NodeId)>,
        constant: f64,
    },
    /// `(n1 · n2 · …) / d`, the numerator folded from the left: two nodes
    /// (more for a product of over [`KEPT_PREFIX`] factors) and at most one
    /// denominator node.
    Prod {
        num: Vec<NodeId>,
        den: Vec<NodeId>,
    },
    Neg(NodeId),
    Times(NodeId, NodeId),
    Recip(NodeId),
    Method(&'static str, Vec<NodeId>),
    Powi(NodeId, i32),
    Powf(NodeId, NodeId),
}

impl View {
    fn children(&self) -> Vec<NodeId> {
        match self {
            View::Leaf => Vec::new(),
            View::Sum { terms, scaled, .. } => terms.iter().map(|t| t.1).chain(scaled.iter().map(|s| s.2)).collect(),
            View::Prod { num, den, .. } => num.iter().chain(den).copied().collect(),
            View::Times(a, b) | View::Powf(a, b) => vec![*a, *b],
            View::Recip(a) | View::Powi(a, _) | View::Neg(a) => vec![*a],
            View::Method(_, xs) => xs.clone(),
        }
    }
}

/// How variable a factor is: parameters only < `t` < `q` < `v` < `ψ`.
pub(crate) fn rank(g: &Graph, x: NodeId) -> u8 {
    let d = g.deps(x);
    [(Deps::PSI, 4), (Deps::V, 3), (Deps::Q, 2), (Deps::T, 1)].iter().find(|(k, _)| d.any(*k)).map_or(0, |x| x.1)
}

fn view(g: &mut Graph, n: NodeId, prefixes: &Prefixes) -> View {
    match g.node(n).clone() {
        Node::Const(_) | Node::Var(_) => View::Leaf,
        Node::Add(xs) => {
            let mut constant = 0.0;
            let mut terms = Vec::new();
            let mut groups: Vec<(f64, Vec<(bool, NodeId)>)> = Vec::new();
            // Each coefficient's group, found by its bits rather than by a
            // scan of the groups: a sum of k terms with distinct
            // coefficients (the derivative of `Σ atan2(x, i)`) would take
            // k²/2 comparisons. NaN equals nothing, so it is never looked up.
            let mut group_of: HashMap<u64, usize> = HashMap::new();
            for &x in xs.iter() {
                if let Some(c) = g.as_const(x) {
                    constant += c;
                    continue;
                }
                let (c, rest) = g.split_coefficient(x);
                if c.abs() == 1.0 {
                    terms.push((c > 0.0, rest));
                    continue;
                }
                match group_of.get(&c.abs().to_bits()).filter(|_| !c.is_nan()) {
                    Some(&i) => groups[i].1.push((c > 0.0, rest)),
                    None => {
                        group_of.insert(c.abs().to_bits(), groups.len());
                        groups.push((c.abs(), vec![(c > 0.0, rest)]));
                    }
                }
            }
            // Terms sharing a coefficient are summed first and scaled once:
            // `0.5·(a + b − c)` rather than `0.5·a + 0.5·b − 0.5·c`.
            let mut scaled = Vec::new();
            for (c, members) in groups {
                if members.len() == 1 {
                    let (positive, rest) = members[0];
                    let term = g.scale(c, rest);
                    terms.push((positive, term));
                    continue;
                }
                // Sum the group with the sign that needs fewest negations;
                // a sum without any positive term starts with this group.
                let positives = members.iter().filter(|m| m.0).count();
                let leading = !terms.iter().any(|t| t.0) && !scaled.iter().any(|s: &(bool, f64, NodeId)| s.0);
                let sign = leading || 2 * positives >= members.len();
                let inner: Vec<NodeId> = members.iter().map(|&(p, r)| if p == sign { r } else { g.neg(r) }).collect();
                let inner = g.add(&inner);
                scaled.push((sign, c, inner));
            }
            View::Sum { terms, scaled, constant }
        }
        Node::Mul(xs) => {
            let coef = g.as_const(xs[0]).unwrap_or(1.0);
            if coef == -1.0 {
                // Negate the positive product as a node of its own, so that
                // `−a·b` and `a·b` share `a·b`.
                return View::Neg(g.neg(n));
            }
            let mut items = Vec::new();
            let mut den = Vec::new();
            for &x in xs.iter() {
                if g.as_const(x).is_some() {
                    continue;
                }
                match g.node(x).clone() {
                    Node::Pow(b, e) if g.as_const(e).is_some_and(|e| e < 0.0) => {
                        let e = g.as_const(e).unwrap_or(-1.0);
                        den.push(g.powc(b, -e));
                    }
                    _ => items.push(x),
                }
            }
            // Least variable factors first (parameters, then t, q, v, ψ):
            // left-folded prefixes are nodes too, so `ℓ·cos θ` is shared by
            // `ℓ·cos θ·v` and `ℓ·cos θ·ψ`, and parameter-only prefixes are
            // hoisted.
            items.sort_by_key(|&x| (rank(g, x), x));
            if coef != 1.0 {
                items.insert(0, xs[0]);
            }
            if items.len() > KEPT_PREFIX {
                items = prefixes.factors(g, items);
            } else if items.len() >= 3 {
                let last = items.pop().unwrap_or(xs[0]);
                let prefix = g.sub_product(&items);
                items = vec![prefix, last];
            }
            if den.len() >= 2 {
                den = vec![g.mul(&den)];
            }
            View::Prod { num: items, den }
        }
        Node::Pow(b, e) => match g.as_const(e) {
            Some(k) if is_int(k) && (2.0..=32.0).contains(&k) => {
                let k = k as i64;
                if k % 2 == 0 {
                    let h = g.powc(b, (k / 2) as f64);
                    View::Times(h, h)
                } else {
                    let h = g.powc(b, (k - 1) as f64);
                    View::Times(h, b)
                }
            }
            Some(k) if is_int(k) && k > 32.0 => View::Powi(b, k as i32),
            Some(k) if k < 0.0 && (is_int(k) || is_int(k - 0.5)) => View::Recip(g.powc(b, -k)),
            Some(0.5) => View::Method("sqrt", vec![b]),
            Some(k) if k > 0.0 && is_int(k - 0.5) => {
                let whole = g.powc(b, k - 0.5);
                let half = g.powc(b, 0.5);
                View::Times(whole, half)
            }
            _ => View::Powf(b, e),
        },
        Node::Call(f, xs) => View::Method(f.method(), xs.to_vec()),
    }
}

/// How shared values and inputs are written.
#[derive(Clone, Copy, Debug)]
enum Mode {
    /// Shared values as `let sK`.
    Plain,
    /// Shared values in an array `w` (`w[k]`).
    Array,
    /// One lane `w` of the lane form: inputs `q[i][w]`, `v[i][w]`,
    /// `psi[j][w]`, shared values `sK[w]`, except the first `scalar`
    /// (parameter-only) ones, which are one `sK` for every lane.
    Lane { scalar: usize },
}

/// A rendered Rust expression, kept as a tree so that its operations can be
/// counted and parentheses placed by precedence.
#[derive(Clone, Debug)]
enum R {
    Lit(f64),
    /// An input, with its rendering.
    Var(Var, TokenStream),
    /// The `k`-th shared value (`let sK`), with its rendering.
    Shared(usize, TokenStream),
    Bin(char, Box<R>, Box<R>),
    Neg(Box<R>),
    Method(Box<R>, &'static str, Vec<R>),
    /// `sin` or `cos` of one argument, written as a call of the runtime's
    /// `trig` module (its path here), whose lone functions return the bits
    /// of its pair's members: a body that computes some of another body's
    /// outputs then computes them alike, whether or not its angles pair.
    Trig(TokenStream, &'static str, Box<R>),
    Powi(Box<R>, i32),
}

impl R {
    fn prec(&self) -> u8 {
        match self {
            R::Lit(x) if *x < 0.0 => 3,
            R::Lit(_) | R::Var(..) | R::Shared(..) => 5,
            R::Bin('+' | '-', ..) => 1,
            R::Bin(..) => 2,
            R::Neg(_) => 3,
            R::Method(..) | R::Trig(..) | R::Powi(..) => 4,
        }
    }

    fn ops(&self) -> usize {
        match self {
            R::Lit(_) | R::Var(..) | R::Shared(..) => 0,
            R::Bin(_, a, b) => 1 + a.ops() + b.ops(),
            R::Neg(a) | R::Powi(a, _) | R::Trig(_, _, a) => 1 + a.ops(),
            R::Method(a, _, xs) => 1 + a.ops() + xs.iter().map(R::ops).sum::<usize>(),
        }
    }

    /// Evaluates exactly the rendered expression (same operations, same
    /// order), for tests of the emitter.
    fn eval(&self, env: &dyn Fn(Var) -> f64, shared: &[f64]) -> f64 {
        match self {
            R::Lit(x) => *x,
            R::Var(v, _) => env(*v),
            R::Shared(k, _) => shared.get(*k).copied().unwrap_or(f64::NAN),
            R::Bin(op, a, b) => {
                let (a, b) = (a.eval(env, shared), b.eval(env, shared));
                match op {
                    '+' => a + b,
                    '-' => a - b,
                    '*' => a * b,
                    _ => a / b,
                }
            }
            R::Neg(a) => -a.eval(env, shared),
            R::Powi(a, k) => a.eval(env, shared).powi(*k),
            R::Trig(_, name, a) => {
                let x = a.eval(env, shared);
                if *name == "sin" {
                    x.sin()
                } else {
                    x.cos()
                }
            }
            R::Method(a, name, args) => {
                let x = a.eval(env, shared);
                let y = args.first().map_or(f64::NAN, |b| b.eval(env, shared));
                match *name {
                    "sqrt" => x.sqrt(),
                    "exp" => x.exp(),
                    "ln" => x.ln(),
                    "tan" => x.tan(),
                    "sinh" => x.sinh(),
                    "cosh" => x.cosh(),
                    "tanh" => x.tanh(),
                    "atan2" => x.atan2(y),
                    "powf" => x.powf(y),
                    _ => f64::NAN,
                }
            }
        }
    }

    /// Marks in `used` the shared values `sK`, `K < used.len()`, that this
    /// expression reads.
    fn mark_shared(&self, used: &mut [bool]) {
        match self {
            R::Shared(k, _) => {
                if let Some(u) = used.get_mut(*k) {
                    *u = true;
                }
            }
            R::Lit(_) | R::Var(..) => {}
            R::Bin(_, a, b) => {
                a.mark_shared(used);
                b.mark_shared(used);
            }
            R::Neg(a) | R::Powi(a, _) | R::Trig(_, _, a) => a.mark_shared(used),
            R::Method(a, _, xs) => {
                a.mark_shared(used);
                xs.iter().for_each(|x| x.mark_shared(used));
            }
        }
    }

    /// The Rust tokens, with shared values and inputs written as `mode` says.
    fn tokens(&self, mode: Mode) -> TokenStream {
        let mut out = TokenStream::new();
        self.write(mode, &mut out);
        out
    }

    /// [`write`](Self::write), in parentheses when the expression binds
    /// less tightly than `min`.
    fn write_wrapped(&self, min: u8, mode: Mode, out: &mut TokenStream) {
        if self.prec() < min {
            let mut inner = TokenStream::new();
            self.write(mode, &mut inner);
            out.extend([TokenTree::Group(Group::new(Delimiter::Parenthesis, inner))]);
        } else {
            self.write(mode, out);
        }
    }

    /// Appends the Rust tokens to `out`. Appending, rather than building
    /// each operand's stream and quoting it into its parent's, writes every
    /// token once: a left-folded sum or product of `n` operands is a chain
    /// `n` deep, whose streams quoted level by level would copy `O(n²)`
    /// tokens.
    fn write(&self, mode: Mode, out: &mut TokenStream) {
        match self {
            R::Lit(x) => {
                let l = Literal::f64_unsuffixed(x.abs());
                if *x < 0.0 {
                    out.extend(quote!(-#l));
                } else {
                    out.extend(quote!(#l));
                }
            }
            R::Shared(k, _) if matches!(mode, Mode::Array) => {
                let k = Literal::usize_unsuffixed(*k);
                out.extend(quote!(w[#k]));
            }
            R::Shared(k, t) => match mode {
                Mode::Lane { scalar } if *k >= scalar => out.extend(quote!(#t[w])),
                _ => out.extend(t.clone()),
            },
            R::Var(v, t) => match (mode, v) {
                (Mode::Lane { .. }, Var::Q(_) | Var::V(_) | Var::Psi(_)) => out.extend(quote!(#t[w])),
                _ => out.extend(t.clone()),
            },
            R::Bin(op, a, b) => {
                let p = self.prec();
                a.write_wrapped(p, mode, out);
                out.extend(match op {
                    '+' => quote!(+),
                    '-' => quote!(-),
                    '*' => quote!(*),
                    _ => quote!(/),
                });
                b.write_wrapped(p + 1, mode, out);
            }
            R::Neg(a) => {
                out.extend(quote!(-));
                a.write_wrapped(3, mode, out);
            }
            R::Method(recv, name, args) => {
                match **recv {
                    R::Lit(x) => {
                        let l = Literal::f64_suffixed(x);
                        out.extend(quote!((#l)));
                    }
                    _ => recv.write_wrapped(4, mode, out),
                }
                let name = Ident::new(name, Span::call_site());
                let mut inner = TokenStream::new();
                for (i, a) in args.iter().enumerate() {
                    if i > 0 {
                        inner.extend(quote!(,));
                    }
                    a.write(mode, &mut inner);
                }
                out.extend(quote!(.#name));
                out.extend([TokenTree::Group(Group::new(Delimiter::Parenthesis, inner))]);
            }
            R::Powi(recv, k) => {
                recv.write_wrapped(4, mode, out);
                let k = Literal::i32_unsuffixed(*k);
                out.extend(quote!(.powi(#k)));
            }
            R::Trig(trig, name, x) => {
                let name = Ident::new(name, Span::call_site());
                out.extend(quote!(#trig::#name));
                let mut inner = TokenStream::new();
                x.write(mode, &mut inner);
                out.extend([TokenTree::Group(Group::new(Delimiter::Parenthesis, inner))]);
            }
        }
    }
}

fn bin(op: char, a: R, b: R) -> R {
    R::Bin(op, Box::new(a), Box::new(b))
}

/// Where an output goes.
#[derive(Clone, Debug)]
pub enum Target {
    /// `let name: f64 = …;` (always written, even when zero).
    Let(Ident),
    /// `name[i] = …;` (vector) or `name[(i, j)] = …;` (matrix) into storage
    /// created by `zeros()`; skipped when zero.
    Store(Ident, usize, Option<usize>),
    /// `name[i] += …;` or `name[(i, j)] += …;`: accumulates into existing
    /// storage (the in-place effect methods); skipped when zero. The `+=`
    /// itself is not counted (it is the caller's fold, not the function's).
    Add(Ident, usize, Option<usize>),
}

/// The statements of one function body and what they cost.
#[derive(Clone, Debug)]
pub struct Emitted {
    /// `let` bindings of shared subexpressions, then the output stores.
    pub statements: Vec<TokenStream>,
    /// Operation count (see the module documentation).
    pub ops: usize,
    /// Number of shared subexpressions bound to `let`s.
    pub shared: usize,
    /// How many of the first `lets` depend on parameters only.
    scalar_lets: usize,
    lets: Vec<R>,
    /// The node each of `lets` binds.
    let_nodes: Vec<NodeId>,
    /// Every output's place, with its expression (`None`: structurally zero).
    outputs: Vec<(Place, Option<R>)>,
    /// The indices `k` of the `lets` that are a sine whose cosine is `k + 1`
    /// (see the module documentation).
    pairs: HashSet<usize>,
    /// The runtime crate's path, for `trig::sin_cos`.
    runtime: TokenStream,
}

impl Emitted {
    /// Evaluates the emitted code at a point, interpreting exactly the
    /// operations written (for tests of the emitter against the graph),
    /// except that sines and cosines are the platform's `sin` and `cos`
    /// (the runtime's `trig` functions are within 1 ulp of them).
    /// Returns one value per output, `0` for outputs not written.
    pub fn evaluate(&self, env: &dyn Fn(Var) -> f64) -> Vec<f64> {
        let mut shared = Vec::with_capacity(self.lets.len());
        for e in &self.lets {
            let x = e.eval(env, &shared);
            shared.push(x);
        }
        self.outputs.iter().map(|(_, e)| e.as_ref().map_or(0.0, |e| e.eval(env, &shared))).collect()
    }

    /// The parameter terms of this body: the parameter-only shared values
    /// that the rest of the body reads (those read only by other
    /// parameter-only values are not), in the order they are bound. A
    /// caller that computes them once per change of the parameters can
    /// run [`statements_with_terms`](Self::statements_with_terms) instead.
    pub fn parameter_terms(&self) -> Vec<NodeId> {
        let mut used = vec![false; self.scalar_lets];
        for e in &self.lets[self.scalar_lets..] {
            e.mark_shared(&mut used);
        }
        for e in self.outputs.iter().filter_map(|(_, e)| e.as_ref()) {
            e.mark_shared(&mut used);
        }
        (0..self.scalar_lets).filter(|&k| used[k]).map(|k| self.let_nodes[k]).collect()
    }

    /// The statements with every [parameter term](Self::parameter_terms)
    /// read from `terms[index[node]]` (a slice in scope) instead of
    /// computed, and the other parameter-only values left out: the same
    /// operations on the same values for every other statement. `None`
    /// when `index` lacks a term.
    pub fn statements_with_terms(&self, index: &HashMap<NodeId, usize>) -> Option<Vec<TokenStream>> {
        let mut loads = Vec::new();
        for node in self.parameter_terms() {
            let k = self.let_nodes.iter().position(|&n| n == node)?;
            let (name, i) = (format_ident!("s{}", k), Literal::usize_unsuffixed(*index.get(&node)?));
            loads.push(quote!(let #name = terms[#i];));
        }
        loads.extend(self.statements[self.scalar_lets..].iter().cloned());
        Some(loads)
    }

    /// The statements with shared values kept in an array `w` (`w[k] = …;`
    /// and uses `w[k]`) instead of `let sK`, so that a long body can be cut
    /// into helper functions that share `w`.
    pub fn statements_in_array(&self) -> Vec<TokenStream> {
        let lets = self.lets.iter().enumerate().map(|(k, e)| {
            if let Some(call) = self.pair_call(k, Mode::Array) {
                let (k, k1) = (Literal::usize_unsuffixed(k), Literal::usize_unsuffixed(k + 1));
                return quote!((w[#k], w[#k1]) = #call;);
            }
            if is_pair_cosine(&self.pairs, k) {
                return quote!();
            }
            let k = Literal::usize_unsuffixed(k);
            let t = e.tokens(Mode::Array);
            quote!(w[#k] = #t;)
        });
        let outs = self.outputs.iter().filter_map(|(place, e)| {
            let t = e.as_ref()?.tokens(Mode::Array);
            Some(match place {
                Place::Let(name) => quote!(let #name: f64 = #t;),
                Place::Store(..) => {
                    let place = place.tokens();
                    quote!(#place = #t;)
                }
                Place::Add(..) => {
                    let place = place.tokens();
                    quote!(#place += #t;)
                }
            })
        });
        lets.chain(outs).collect()
    }

    /// The statements in lane form, for a body with `q`, `v`, `psi` given
    /// as `[[f64; W]; _]` (row `i` holds entry `i` of every lane), `t` and
    /// the parameters shared by the lanes, and outputs `name[i][w]`
    /// (vectors) or `name[j][i][w]` (matrices, column-major): every shared
    /// value and output is a loop over all `W` lanes whose body is the
    /// scalar statement's expression, so each lane computes exactly the
    /// scalar operations. Structural zeros are written as `0.0`, since
    /// nothing zeroes the lane storage first.
    pub fn statements_in_lanes(&self) -> Vec<TokenStream> {
        let mode = Mode::Lane { scalar: self.scalar_lets };
        let lets = self.lets.iter().enumerate().map(|(k, e)| {
            let name = format_ident!("s{}", k);
            if let Some(call) = self.pair_call(k, mode) {
                let cosine = format_ident!("s{}", k + 1);
                return if k < self.scalar_lets {
                    quote!(let (#name, #cosine) = #call;)
                } else {
                    quote! {
                        let mut #name = [0.0f64; W];
                        let mut #cosine = [0.0f64; W];
                        for w in 0..W {
                            (#name[w], #cosine[w]) = #call;
                        }
                    }
                };
            }
            if is_pair_cosine(&self.pairs, k) {
                return quote!();
            }
            let t = e.tokens(mode);
            if k < self.scalar_lets {
                quote!(let #name = #t;)
            } else {
                quote! {
                    let mut #name = [0.0f64; W];
                    for w in 0..W {
                        #name[w] = #t;
                    }
                }
            }
        });
        let outs = self.outputs.iter().filter_map(|(place, e)| {
            let t = match e {
                Some(e) => e.tokens(mode),
                None if matches!(place, Place::Store(..)) => quote!(0.0),
                None => return None,
            };
            Some(match place {
                Place::Let(name) => quote! {
                    let mut #name = [0.0f64; W];
                    for w in 0..W {
                        #name[w] = #t;
                    }
                },
                Place::Store(..) | Place::Add(..) => {
                    let op = if matches!(place, Place::Add(..)) { quote!(+=) } else { quote!(=) };
                    let place = place.lane_tokens();
                    quote! {
                        for w in 0..W {
                            #place[w] #op #t;
                        }
                    }
                }
            })
        });
        lets.chain(outs).collect()
    }

    /// `trig::sin_cos(x)` when let `k` is the sine of a pair, `x` written
    /// as `mode` says.
    fn pair_call(&self, k: usize, mode: Mode) -> Option<TokenStream> {
        pair_call(&self.runtime, &self.lets[k], self.pairs.contains(&k), mode)
    }
}

/// `runtime::trig::sin_cos(x)` for the sine `e = trig::sin(x)` of a pair
/// (`paired`), `x` written as `mode` says; `None` for any other let.
fn pair_call(runtime: &TokenStream, e: &R, paired: bool, mode: Mode) -> Option<TokenStream> {
    match e {
        R::Trig(_, "sin", x) if paired => {
            let x = x.tokens(mode);
            Some(quote!(#runtime::trig::sin_cos(#x)))
        }
        _ => None,
    }
}

/// `sin_cos_memo.sin_cos(slot, x)` for the sine `e = trig::sin(x)` (node
/// `sine`) of a pair whose argument depends on the point (`paired`), in a
/// body with a memo (see [`Inputs::sin_cos_memo`]); `None` otherwise.
fn memo_call(
    inputs: &Inputs<'_>,
    views: &HashMap<NodeId, View>,
    sine: NodeId,
    e: &R,
    paired: bool,
) -> Option<TokenStream> {
    let (R::Trig(_, "sin", x), true, Some(slots)) = (e, paired, inputs.sin_cos_memo) else { return None };
    let View::Method(_, args) = views.get(&sine)? else { return None };
    let argument = *args.first()?;
    let mut slots = slots.borrow_mut();
    let slot = match slots.iter().position(|&a| a == argument) {
        Some(slot) => slot,
        None => {
            slots.push(argument);
            slots.len() - 1
        }
    };
    let (slot, x) = (Literal::usize_unsuffixed(slot), x.tokens(Mode::Plain));
    Some(quote!(sin_cos_memo.sin_cos(#slot, #x)))
}

/// Whether let `k` is the cosine of a pair, bound with the sine before it
/// (`pairs`: the sines' indices).
fn is_pair_cosine(pairs: &HashSet<usize>, k: usize) -> bool {
    k > 0 && pairs.contains(&(k - 1))
}

/// The sine–cosine pairs among the nodes of a body: each member mapped to
/// `(sine, cosine)`.
fn sine_cosine_pairs(views: &HashMap<NodeId, View>) -> HashMap<NodeId, (NodeId, NodeId)> {
    let argument = |v: &View, name: &str| match v {
        View::Method(f, xs) if *f == name && xs.len() == 1 => Some(xs[0]),
        _ => None,
    };
    let cosines: HashMap<NodeId, NodeId> =
        views.iter().filter_map(|(&n, v)| argument(v, "cos").map(|x| (x, n))).collect();
    let mut pairs = HashMap::new();
    for (&n, v) in views {
        if let Some(&c) = argument(v, "sin").and_then(|x| cosines.get(&x)) {
            pairs.insert(n, (n, c));
            pairs.insert(c, (n, c));
        }
    }
    pairs
}

/// Where a rendered output is written: a `let`, or entry `i` (row `i`,
/// column `j` for a matrix) of the output `name`, stored or added to.
#[derive(Clone, Debug)]
enum Place {
    Let(Ident),
    Store(Ident, usize, Option<usize>),
    Add(Ident, usize, Option<usize>),
}

impl Place {
    /// `name[i]` or `name[(i, j)]`.
    fn tokens(&self) -> TokenStream {
        self.written(false)
    }

    /// `name[i]` or `name[j][i]` (lane storage, column-major), to be
    /// indexed by the lane.
    fn lane_tokens(&self) -> TokenStream {
        self.written(true)
    }

    fn written(&self, lanes: bool) -> TokenStream {
        match self {
            Place::Let(name) => quote!(#name),
            Place::Store(name, i, j) | Place::Add(name, i, j) => {
                let i = Literal::usize_unsuffixed(*i);
                match (j, lanes) {
                    (None, _) => quote!(#name[#i]),
                    (Some(j), false) => {
                        let j = Literal::usize_unsuffixed(*j);
                        quote!(#name[(#i, #j)])
                    }
                    (Some(j), true) => {
                        let j = Literal::usize_unsuffixed(*j);
                        quote!(#name[#j][#i])
                    }
                }
            }
        }
    }
}

/// Renders the inputs: `t`, `q[i]`, `v[i]`, `psi[j]`, `self.<parameter>`.
pub struct Inputs<'a> {
    /// Parameter field names, by index.
    pub parameters: &'a [Ident],
    /// The runtime crate's path (`::spark_runtime` unless the declaration
    /// says otherwise), for the functions generated code calls.
    pub runtime: &'a TokenStream,
    /// For the bodies that evaluate a stage point (a `sin_cos_memo:
    /// &mut SinCosMemo` in scope): the arguments of the sine–cosine pairs
    /// met so far, a pair's memo slot being its argument's place here,
    /// shared by the system's bodies so that each gives an angle the same
    /// slot. `None`: pairs are computed at every call.
    pub sin_cos_memo: Option<&'a RefCell<Vec<NodeId>>>,
}

impl Inputs<'_> {
    fn var(&self, v: Var) -> TokenStream {
        let lit = |i: u32| Literal::usize_unsuffixed(i as usize);
        match v {
            Var::Time => quote!(t),
            Var::Q(i) => {
                let i = lit(i);
                quote!(q[#i])
            }
            Var::V(i) => {
                let i = lit(i);
                quote!(v[#i])
            }
            Var::Psi(i) => {
                let i = lit(i);
                quote!(psi[#i])
            }
            Var::P(i) => match self.parameters.get(i as usize) {
                Some(p) => quote!(self.#p),
                None => quote!(f64::NAN),
            },
        }
    }
}

struct Emitter<'a> {
    views: HashMap<NodeId, View>,
    names: HashMap<NodeId, Ident>,
    order: HashMap<NodeId, usize>,
    inputs: &'a Inputs<'a>,
}

impl Emitter<'_> {
    fn render(&self, g: &Graph, n: NodeId, top: bool) -> R {
        if !top {
            if let Some(name) = self.names.get(&n) {
                return R::Shared(self.order[&n], quote!(#name));
            }
        }
        let sub = |x: NodeId| self.render(g, x, false);
        match &self.views[&n] {
            View::Leaf => match g.node(n) {
                Node::Var(v) => R::Var(*v, self.inputs.var(*v)),
                _ => R::Lit(g.as_const(n).unwrap_or(f64::NAN)),
            },
            View::Sum { terms, scaled, constant } => {
                let mut acc: Option<R> = None;
                let plain = terms.iter().map(|&(p, x)| (p, sub(x)));
                let scaled = scaled.iter().map(|&(p, c, x)| (p, bin('*', R::Lit(c), sub(x))));
                let mut negative = Vec::new();
                let mut positive = Vec::new();
                for (sign, t) in plain.chain(scaled) {
                    if sign {
                        positive.push(t);
                    } else {
                        negative.push(t);
                    }
                }
                for t in positive {
                    acc = Some(match acc {
                        None => t,
                        Some(a) => bin('+', a, t),
                    });
                }
                for t in negative {
                    acc = Some(match acc {
                        None => R::Neg(Box::new(t)),
                        Some(a) => bin('-', a, t),
                    });
                }
                let acc = acc.unwrap_or(R::Lit(0.0));
                if *constant > 0.0 {
                    bin('+', acc, R::Lit(*constant))
                } else if *constant < 0.0 {
                    bin('-', acc, R::Lit(-constant))
                } else {
                    acc
                }
            }
            View::Prod { num, den } => {
                let product = |xs: &[NodeId]| -> Option<R> { xs.iter().map(|&x| sub(x)).reduce(|a, b| bin('*', a, b)) };
                let numer = product(num).unwrap_or(R::Lit(1.0));
                match product(den) {
                    None => numer,
                    Some(d) => bin('/', numer, d),
                }
            }
            View::Neg(a) => R::Neg(Box::new(sub(*a))),
            View::Times(a, b) => bin('*', sub(*a), sub(*b)),
            View::Recip(a) => bin('/', R::Lit(1.0), sub(*a)),
            View::Method(name @ ("sin" | "cos"), xs) if xs.len() == 1 => {
                let runtime = self.inputs.runtime;
                R::Trig(quote!(#runtime::trig), name, Box::new(sub(xs[0])))
            }
            View::Method(name, xs) => R::Method(Box::new(sub(xs[0])), name, xs[1..].iter().map(|&x| sub(x)).collect()),
            View::Powi(a, k) => R::Powi(Box::new(sub(*a)), *k),
            View::Powf(a, e) => R::Method(Box::new(sub(*a)), "powf", vec![sub(*e)]),
        }
    }
}

/// Emits the body of one function computing `outputs`, sharing every common
/// subexpression between them.
pub fn emit(g: &mut Graph, outputs: &[(Target, NodeId)], inputs: &Inputs<'_>) -> Emitted {
    let prefixes = Prefixes::of(g, outputs.iter().map(|o| o.1));
    // Pass 1: views and reference counts, iteratively (deep graphs are fine).
    let mut views: HashMap<NodeId, View> = HashMap::new();
    let mut refs: HashMap<NodeId, usize> = HashMap::new();
    let mut order: Vec<NodeId> = Vec::new();
    for (target, root) in outputs {
        if matches!(target, Target::Store(..) | Target::Add(..)) && g.is_const(*root, 0.0) {
            continue;
        }
        let mut stack = vec![(*root, false)];
        while let Some((n, done)) = stack.pop() {
            if done {
                order.push(n);
                continue;
            }
            let count = refs.entry(n).or_insert(0);
            *count += 1;
            if *count > 1 {
                continue;
            }
            let v = view(g, n, &prefixes);
            stack.push((n, true));
            for c in v.children().into_iter().rev() {
                stack.push((c, false));
            }
            views.insert(n, v);
        }
    }
    // Pass 2: which nodes become `let`s, parameter-only ones first; both
    // members of a sine–cosine pair are, next to each other where the
    // first of them was (both follow their argument).
    let pairs = sine_cosine_pairs(&views);
    let bound = |n: &NodeId| {
        !matches!(views[n], View::Leaf) && (refs[n] >= 2 || g.deps(*n).parameters_only() || pairs.contains_key(n))
    };
    let mut lets: Vec<NodeId> = order.iter().copied().filter(|n| bound(n) && g.deps(*n).parameters_only()).collect();
    let scalar_lets = lets.len();
    lets.extend(order.iter().copied().filter(|n| bound(n) && !g.deps(*n).parameters_only()));
    let mut placed = HashSet::new();
    let mut paired_lets = HashSet::new();
    let mut ordered = Vec::with_capacity(lets.len());
    for n in lets {
        if !placed.insert(n) {
            continue;
        }
        match pairs.get(&n) {
            Some(&(sine, cosine)) => {
                placed.extend([sine, cosine]);
                paired_lets.insert(ordered.len());
                ordered.extend([sine, cosine]);
            }
            None => ordered.push(n),
        }
    }
    let lets = ordered;
    let mut em = Emitter { views, names: HashMap::new(), order: HashMap::new(), inputs };
    let mut lets_r = Vec::new();
    let mut outputs_r = Vec::new();
    let mut statements = Vec::new();
    let mut ops = 0;
    for (k, &n) in lets.iter().enumerate() {
        let e = em.render(g, n, true);
        ops += e.ops();
        let name = format_ident!("s{}", k);
        if let Some(call) = memo_call(inputs, &em.views, n, &e, paired_lets.contains(&k) && k >= scalar_lets)
            .or_else(|| pair_call(inputs.runtime, &e, paired_lets.contains(&k), Mode::Plain))
        {
            let cosine = format_ident!("s{}", k + 1);
            statements.push(quote!(let (#name, #cosine) = #call;));
        } else if !is_pair_cosine(&paired_lets, k) {
            let t = e.tokens(Mode::Plain);
            statements.push(quote!(let #name = #t;));
        } else {
            // The cosine, bound with its sine.
            statements.push(quote!());
        }
        em.names.insert(n, name);
        em.order.insert(n, k);
        lets_r.push(e);
    }
    for (target, root) in outputs {
        match target {
            Target::Let(name) => {
                let e = if g.is_const(*root, 0.0) { R::Lit(0.0) } else { em.render(g, *root, false) };
                ops += e.ops();
                let t = e.tokens(Mode::Plain);
                statements.push(quote!(let #name: f64 = #t;));
                outputs_r.push((Place::Let(name.clone()), Some(e)));
            }
            Target::Store(name, i, j) | Target::Add(name, i, j) => {
                let place = match target {
                    Target::Add(..) => Place::Add(name.clone(), *i, *j),
                    _ => Place::Store(name.clone(), *i, *j),
                };
                if g.is_const(*root, 0.0) {
                    outputs_r.push((place, None));
                    continue;
                }
                let e = em.render(g, *root, false);
                ops += e.ops();
                let (t, p) = (e.tokens(Mode::Plain), place.tokens());
                if matches!(target, Target::Add(..)) {
                    statements.push(quote!(#p += #t;));
                } else {
                    statements.push(quote!(#p = #t;));
                }
                outputs_r.push((place, Some(e)));
            }
        }
    }
    Emitted {
        statements,
        ops,
        shared: lets.len(),
        scalar_lets,
        lets: lets_r,
        let_nodes: lets,
        outputs: outputs_r,
        pairs: paired_lets,
        runtime: inputs.runtime.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::{emit, rank, Inputs, Target, KEPT_PREFIX};
    use crate::graph::{Fun, Graph, Node, NodeId, Var};
    use proc_macro2::{Ident, Span};

    /// A product of more than `KEPT_PREFIX` factors computes what its
    /// left-folded prefixes compute, bit for bit: the fold of its factors
    /// least variable first (its coefficient first of all). It makes nodes
    /// with fewer operands than the product has, and still reads a product
    /// of all but its last factor that the graph holds (`Π·v` reads `Π`).
    #[test]
    fn long_products_are_the_fold_of_their_prefixes() {
        let mut g = Graph::new();
        let (m, x, v) = (g.var(Var::P(0)), g.var(Var::Q(0)), g.var(Var::V(0)));
        let mut factors = vec![g.constant(0.75)];
        for i in 1..=150 {
            let c = g.constant(f64::from(i));
            factors.push(g.call(Fun::Atan2, &[m, c]));
            if i % 3 == 0 {
                let shifted = g.add2(x, c);
                factors.push(g.call(Fun::Sin, &[shifted]));
            }
        }
        let params = g.mul(&factors);
        let params_only: Vec<NodeId> = factors.iter().copied().filter(|&f| rank(&g, f) == 0).collect();
        let pi = g.mul(&params_only);
        let pi_v = g.mul2(pi, v);
        let mixed = g.mul2(params, v);
        let outputs = [params, pi, pi_v, mixed];
        let targets: Vec<(Target, NodeId)> = (0..outputs.len())
            .map(|i| (Target::Let(Ident::new(&format!("r{i}"), Span::call_site())), outputs[i]))
            .collect();
        let names = [Ident::new("m", Span::call_site())];
        let runtime = quote::quote!(::spark_runtime);
        let before = g.size();
        let emitted = emit(&mut g, &targets, &Inputs { parameters: &names, runtime: &runtime, sin_cos_memo: None });
        let made = g.size() - before;
        assert!(made < 2 * factors.len(), "emission makes {made} nodes and operands");
        let env = |var: Var| match var {
            Var::P(_) => 0.3,
            Var::Q(_) => -1.7,
            _ => 2.1,
        };
        let values = emitted.evaluate(&env);
        for (&n, value) in outputs.iter().zip(values) {
            let Node::Mul(xs) = g.node(n).clone() else { panic!("a product") };
            let mut items: Vec<NodeId> = xs.iter().copied().filter(|&x| g.as_const(x).is_none()).collect();
            items.sort_by_key(|&x| (rank(&g, x), x));
            let coefficient = g.as_const(xs[0]);
            let fold = coefficient
                .into_iter()
                .chain(items.iter().map(|&x| g.eval(x, &env)))
                .reduce(|a, b| a * b)
                .unwrap_or(1.0);
            assert!(xs.len() > KEPT_PREFIX);
            assert_eq!(value.to_bits(), fold.to_bits(), "{value} and {fold}");
        }
        // `Π·v` reads `Π`, bound once (parameter-only).
        assert!(emitted.let_nodes.contains(&pi));
    }

    /// The derivative `Σ_i Π_{j≠i} f_j` of a product of `k` factors (more
    /// than `KEPT_PREFIX`) shares the prefixes its products begin with:
    /// about `k²/2` multiplications, where products written out each on
    /// their own would take `k²`.
    #[test]
    fn long_products_share_the_prefixes_they_begin_with() {
        let mut g = Graph::new();
        let x = g.var(Var::Q(0));
        let k = 100;
        let factors: Vec<NodeId> = (1..=k)
            .map(|i| {
                let c = g.constant(f64::from(i));
                let shifted = g.add2(x, c);
                g.call(Fun::Sin, &[shifted])
            })
            .collect();
        let terms: Vec<NodeId> = (0..factors.len())
            .map(|i| {
                let others: Vec<NodeId> = factors.iter().enumerate().filter(|e| e.0 != i).map(|e| *e.1).collect();
                g.mul(&others)
            })
            .collect();
        let derivative = g.add(&terms);
        let targets = [(Target::Let(Ident::new("r", Span::call_site())), derivative)];
        let runtime = quote::quote!(::spark_runtime);
        let emitted = emit(&mut g, &targets, &Inputs { parameters: &[], runtime: &runtime, sin_cos_memo: None });
        let k = k as usize;
        // k·(k − 1)/2 multiplications, k − 1 additions, k sines and k
        // additions in their arguments.
        assert!(emitted.ops <= k * (k - 1) / 2 + 4 * k, "{} operations", emitted.ops);
    }
}
