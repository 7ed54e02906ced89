//! Simplifying constructors: every node the engine creates goes through
//! these, so the graph only ever holds canonical, simplified expressions.
//!
//! Rules, all exact for values where the input expression is defined:
//! - constant folding (including elementary functions of constants) when the
//!   result is finite;
//! - neutral and absorbing elements: `x + 0`, `x·1`, `x·0 = 0`, `x^1`, `x^0 = 1`;
//! - like terms: `2x + 3x = 5x`, `x − x = 0`, `−(−x) = x`;
//! - powers: `x·x = x²`, `x^a·x^b = x^(a+b)`, `(x^a)^n = x^(a·n)` and
//!   `(x·y)^n = x^n·y^n` for integer `n`;
//! - `ln(exp x) = x`, `exp(ln x) = x`;
//! - a number times a sum is distributed: `2(x + y) = 2x + 2y` (unless a
//!   coefficient would overflow).
//!
//! Nothing else is distributed or expanded, so that shared subexpressions stay
//! shared.

use crate::graph::{Fun, Graph, Node, NodeId};
use std::collections::HashMap;

mod product_chain;
pub(crate) use product_chain::{PartialProduct, ProductChain, KEPT_PARTIAL_PRODUCT};

/// `true` if `x` is an integer that `powi` can take.
pub fn is_int(x: f64) -> bool {
    x.fract() == 0.0 && x.abs() <= 1e9
}

/// The fold `((a + b) + c) + …` of a sum written in the source, kept as
/// its terms rather than as interned partial sums: each partial sum of a
/// chain of `k` terms is a node with all the terms before it, `k²/2`
/// operands in all (0.6 GB and 20 s of CPU to check a sum of 10 000 terms), and each
/// step of [`Graph::add`] goes through all of them.
///
/// The steps ([`Graph::sum_chain_push`]) make the nodes the fold of `add`
/// makes, in the same order, with the same coefficients (like terms are
/// added in the fold's order), and intern the partial sums of at most
/// [`KEPT_PARTIAL_SUM`] operands as the fold does; so the node ids, the
/// order of the operands of every sum and product (sorted by id) and the
/// emitted code are those of the fold.
pub(crate) struct SumChain {
    /// The constant term (0 when there is none).
    constant: f64,
    /// Each term's rest (the term without its coefficient) → its
    /// coefficient and the term's node ([`PENDING`] within a step for a
    /// rest new in it).
    terms: HashMap<NodeId, (f64, NodeId)>,
    /// Number of terms.
    len: usize,
    /// The most operands of a partial sum that is interned as the fold
    /// interns it ([`KEPT_PARTIAL_SUM`]).
    keep: usize,
    /// The graph is exhausted: every sum is the constant 0.
    dead: bool,
}

/// The partial sums of a [`SumChain`] of at most this many operands are
/// interned, as the fold interns them, at a cost bounded by it per step. So
/// the graph is the fold's exactly for every sum whose partial sums are
/// this small, and otherwise lacks only the longer partial sums: a node
/// made later that equals one of them (rare: a sum of over 64 operands
/// written out again) gets a later id than in the fold, which can change
/// the order of the operands of the sums and products made after it.
pub(crate) const KEPT_PARTIAL_SUM: usize = 64;

/// A placeholder for a term's node not made yet.
const PENDING: NodeId = NodeId(u32::MAX);

/// A partial sum of a [`SumChain`], as much of it as the lowering's checks
/// need: the node `add` returns when it is a single operand (a constant or
/// one term), or else the value of the sum's constant operand, if it has one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Partial {
    /// The partial sum is this node.
    Node(NodeId),
    /// A sum of several operands, its constant operand (if any) first.
    Sum {
        /// The constant operand.
        constant: Option<f64>,
    },
}

impl Graph {
    /// `a + b`.
    pub fn add2(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.add(&[a, b])
    }

    /// `a − b`.
    pub fn sub(&mut self, a: NodeId, b: NodeId) -> NodeId {
        let nb = self.neg(b);
        self.add(&[a, nb])
    }

    /// `−a`.
    pub fn neg(&mut self, a: NodeId) -> NodeId {
        let m1 = self.constant(-1.0);
        self.mul(&[m1, a])
    }

    /// `a · b`.
    pub fn mul2(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.mul(&[a, b])
    }

    /// `a / b`.
    pub fn div(&mut self, a: NodeId, b: NodeId) -> NodeId {
        let m1 = self.constant(-1.0);
        let inv = self.pow(b, m1);
        self.mul(&[a, inv])
    }

    /// `c · a` for a number `c`.
    pub fn scale(&mut self, c: f64, a: NodeId) -> NodeId {
        let c = self.constant(c);
        self.mul(&[c, a])
    }

    /// `a ^ n` for a number `n`.
    pub fn powc(&mut self, a: NodeId, n: f64) -> NodeId {
        let n = self.constant(n);
        self.pow(a, n)
    }

    /// Splits a term into `(coefficient, rest)` with `term = coefficient · rest`.
    pub fn split_coefficient(&mut self, term: NodeId) -> (f64, NodeId) {
        if let Node::Mul(xs) = self.node(term) {
            if let Some(c) = self.as_const(xs[0]) {
                let rest: Vec<NodeId> = xs[1..].to_vec();
                let rest = if rest.len() == 1 { rest[0] } else { self.intern(Node::Mul(rest.into())) };
                return (c, rest);
            }
        }
        (1.0, term)
    }

    /// `c · rest` for `rest` in canonical form, `c` not 0.
    fn with_coefficient(&mut self, c: f64, rest: NodeId) -> NodeId {
        if c == 1.0 {
            return rest;
        }
        let cn = self.constant(c);
        let mut xs = vec![cn];
        match self.node(rest) {
            Node::Mul(fs) => xs.extend(fs.iter().copied()),
            _ => xs.push(rest),
        }
        self.intern(Node::Mul(xs.into()))
    }

    /// Sum of any number of terms.
    pub fn add(&mut self, terms: &[NodeId]) -> NodeId {
        if self.exhausted() {
            return self.constant(0.0);
        }
        let mut flat = Vec::with_capacity(terms.len());
        for &t in terms {
            match self.node(t) {
                Node::Add(xs) => flat.extend(xs.iter().copied()),
                _ => flat.push(t),
            }
        }
        let mut constant = 0.0;
        let mut order: Vec<NodeId> = Vec::new();
        let mut coefs: HashMap<NodeId, f64> = HashMap::new();
        for t in flat {
            if let Some(c) = self.as_const(t) {
                constant += c;
                continue;
            }
            let (c, rest) = self.split_coefficient(t);
            match coefs.get_mut(&rest) {
                Some(acc) => *acc += c,
                None => {
                    order.push(rest);
                    coefs.insert(rest, c);
                }
            }
        }
        let mut out: Vec<NodeId> = Vec::new();
        for rest in order {
            let c = coefs[&rest];
            if c != 0.0 {
                out.push(self.with_coefficient(c, rest));
            }
        }
        out.sort();
        if constant != 0.0 || out.is_empty() {
            out.insert(0, self.constant(constant));
        }
        if out.len() == 1 {
            return out[0];
        }
        self.intern(Node::Add(out.into()))
    }

    /// Starts the fold `((first + b) + c) + …` of a chain written in the
    /// source (see [`SumChain`]). Splitting `first`'s terms is the first
    /// thing `add(&[first, b])` does, so the caller starts the chain after
    /// lowering `b`.
    pub(crate) fn sum_chain(&mut self, first: NodeId, keep: usize) -> SumChain {
        let mut chain = SumChain { constant: 0.0, terms: HashMap::new(), len: 0, keep, dead: self.exhausted() };
        if chain.dead {
            return chain;
        }
        let flat = match self.node(first) {
            Node::Add(xs) => xs.to_vec(),
            _ => vec![first],
        };
        for t in flat {
            if let Some(c) = self.as_const(t) {
                chain.constant += c;
                continue;
            }
            let (c, rest) = self.split_coefficient(t);
            // `first` is a canonical node: its terms have distinct rests and
            // nonzero coefficients, and each is `with_coefficient(c, rest)`.
            chain.terms.insert(rest, (c, t));
        }
        chain.len = chain.terms.len();
        chain
    }

    /// One step of the fold: the partial sum becomes `add(&[partial, term])`,
    /// making the nodes that call makes, in its order, except a partial sum
    /// of more than `keep` operands. Work proportional to `term`'s operands
    /// and `keep`, not to the partial sum's operands.
    pub(crate) fn sum_chain_push(&mut self, chain: &mut SumChain, term: NodeId) -> Partial {
        if self.exhausted() || chain.dead {
            chain.dead = true;
            return Partial::Node(self.constant(0.0));
        }
        let flat = match self.node(term) {
            Node::Add(xs) => xs.to_vec(),
            _ => vec![term],
        };
        // `add` goes through the partial sum's terms (sorted by id) and then
        // `term`'s, splits each, adds the coefficients of equal rests, and
        // then makes `with_coefficient(c, rest)` in that order. The partial
        // sum's splits and unchanged terms are nodes that exist already; the
        // nodes it makes are the changed terms, in the order of their old
        // ids, then `term`'s new ones.
        let mut met: Vec<(NodeId, NodeId)> = Vec::new();
        let mut fresh: Vec<NodeId> = Vec::new();
        for t in flat {
            if let Some(c) = self.as_const(t) {
                chain.constant += c;
                continue;
            }
            let (c, rest) = self.split_coefficient(t);
            match chain.terms.get_mut(&rest) {
                Some(entry) => {
                    if entry.1 != PENDING {
                        met.push((entry.1, rest));
                    }
                    entry.0 += c;
                }
                None => {
                    fresh.push(rest);
                    chain.terms.insert(rest, (c, PENDING));
                }
            }
        }
        met.sort_unstable();
        met.dedup();
        for rest in met.into_iter().map(|(_, rest)| rest).chain(fresh) {
            let c = chain.terms[&rest].0;
            if c == 0.0 {
                chain.terms.remove(&rest);
            } else {
                let t = self.with_coefficient(c, rest);
                chain.terms.insert(rest, (c, t));
            }
        }
        chain.len = chain.terms.len();
        let constant = (chain.constant != 0.0 || chain.len == 0).then(|| self.constant(chain.constant));
        match (constant, chain.len) {
            (Some(c), 0) => Partial::Node(c),
            (None, 1) => Partial::Node(chain.terms.values().next().map_or(term, |e| e.1)),
            (c, len) => {
                if len + usize::from(c.is_some()) <= chain.keep {
                    let mut out: Vec<NodeId> = c.into_iter().collect();
                    out.extend(chain.terms.values().map(|e| e.1));
                    out[usize::from(c.is_some())..].sort_unstable();
                    self.intern(Node::Add(out.into()));
                }
                Partial::Sum { constant: c.and_then(|c| self.as_const(c)) }
            }
        }
    }

    /// The node of the chain's sum: what the last `add` of the fold makes.
    pub(crate) fn sum_chain_finish(&mut self, chain: SumChain) -> NodeId {
        if chain.dead {
            return self.constant(0.0);
        }
        let mut out: Vec<NodeId> = chain.terms.values().map(|e| e.1).collect();
        out.sort();
        if chain.constant != 0.0 || out.is_empty() {
            out.insert(0, self.constant(chain.constant));
        }
        if out.len() == 1 {
            return out[0];
        }
        self.intern(Node::Add(out.into()))
    }

    /// Splits a factor into `(base, exponent)` with `factor = base ^ exponent`.
    fn split_power(&mut self, f: NodeId) -> (NodeId, NodeId) {
        match self.node(f) {
            Node::Pow(b, e) => (*b, *e),
            _ => (f, self.constant(1.0)),
        }
    }

    /// The product of some operands of one canonical product (its
    /// constant, if among them, first), at least two of them not constant:
    /// already canonical once sorted, so interned without the work of
    /// [`mul`](Self::mul) (which it equals). Emission takes the left-folded
    /// prefixes of a product this way, `k` of them for `k` factors (fewer
    /// for a product longer than [`crate::emit::KEPT_PREFIX`]).
    pub(crate) fn sub_product(&mut self, operands: &[NodeId]) -> NodeId {
        match Self::sub_product_node(self, operands) {
            Some(node) => self.intern(node),
            None => self.mul(operands),
        }
    }

    /// The node [`sub_product`](Self::sub_product) makes of `operands`, if
    /// the graph holds it already: looked up, not added.
    pub(crate) fn find_sub_product(&self, operands: &[NodeId]) -> Option<NodeId> {
        self.find(&Self::sub_product_node(self, operands)?)
    }

    /// The canonical product of some operands of one canonical product,
    /// unless fewer than two of them are not constant.
    fn sub_product_node(&self, operands: &[NodeId]) -> Option<Node> {
        let constant = operands.first().filter(|&&x| self.as_const(x).is_some()).copied();
        let rest = &operands[usize::from(constant.is_some())..];
        if rest.len() < 2 {
            return None;
        }
        let mut xs: Vec<NodeId> = Vec::with_capacity(operands.len());
        xs.extend(constant);
        let from = xs.len();
        xs.extend_from_slice(rest);
        xs[from..].sort_unstable();
        Some(Node::Mul(xs.into()))
    }

    /// Product of any number of factors.
    pub fn mul(&mut self, factors: &[NodeId]) -> NodeId {
        if self.exhausted() {
            return self.constant(0.0);
        }
        let mut coef = 1.0;
        let mut order: Vec<NodeId> = Vec::new();
        let mut exps: HashMap<NodeId, Vec<NodeId>> = HashMap::new();
        let mut pending: Vec<NodeId> = factors.to_vec();
        while let Some(f) = pending.pop() {
            match self.node(f) {
                Node::Mul(xs) => pending.extend(xs.iter().copied()),
                Node::Const(_) => coef *= self.as_const(f).unwrap_or(f64::NAN),
                _ => {
                    let (b, e) = self.split_power(f);
                    exps.entry(b).or_insert_with(|| {
                        order.push(b);
                        Vec::new()
                    });
                    if let Some(v) = exps.get_mut(&b) {
                        v.push(e);
                    }
                }
            }
        }
        if coef == 0.0 {
            return self.constant(0.0);
        }
        let mut out: Vec<NodeId> = Vec::new();
        let mut again = false;
        for b in order {
            let es = exps.remove(&b).unwrap_or_default();
            let e = if es.len() == 1 { es[0] } else { self.add(&es) };
            let f = self.pow(b, e);
            match self.node(f) {
                Node::Const(_) => coef *= self.as_const(f).unwrap_or(f64::NAN),
                Node::Mul(_) => {
                    again = true;
                    out.push(f);
                }
                _ => out.push(f),
            }
        }
        if again {
            let c = self.constant(coef);
            out.push(c);
            return self.mul(&out);
        }
        self.mul_factors(coef, out)
    }

    /// The product of a coefficient and canonical factors with distinct
    /// bases (none a product or a number): the last part of [`mul`](Self::mul).
    pub(crate) fn mul_factors(&mut self, coef: f64, mut out: Vec<NodeId>) -> NodeId {
        if coef == 0.0 {
            return self.constant(0.0);
        }
        out.sort();
        if out.is_empty() {
            return self.constant(coef);
        }
        if coef != 1.0 && out.len() == 1 {
            let sum = match self.node(out[0]) {
                Node::Add(terms) => Some(terms.clone()),
                _ => None,
            };
            // A number times a sum is distributed (as SymPy does), so that
            // `−(−a − b)` reads `a + b` and like terms meet; not where a
            // term's coefficient would overflow (`1e10·(1e300 − x)`), which
            // would put a number that is not finite into the graph.
            let leading = |t: &NodeId| match self.node(*t) {
                Node::Const(bits) => f64::from_bits(*bits),
                Node::Mul(xs) => self.as_const(xs[0]).unwrap_or(1.0),
                _ => 1.0,
            };
            if let Some(terms) = sum.filter(|terms| terms.iter().all(|t| (coef * leading(t)).is_finite())) {
                let c = self.constant(coef);
                let scaled: Vec<NodeId> = terms.iter().map(|&t| self.mul(&[c, t])).collect();
                return self.add(&scaled);
            }
        }
        if coef != 1.0 {
            out.insert(0, self.constant(coef));
        }
        if out.len() == 1 {
            return out[0];
        }
        self.intern(Node::Mul(out.into()))
    }

    /// `base ^ exponent`.
    pub fn pow(&mut self, base: NodeId, exponent: NodeId) -> NodeId {
        let e = self.as_const(exponent);
        if e == Some(0.0) {
            return self.constant(1.0);
        }
        if e == Some(1.0) {
            return base;
        }
        if let Some(b) = self.as_const(base) {
            if b == 1.0 {
                return base;
            }
            if let Some(e) = e {
                let v = crate::graph::pow_f64(b, e);
                if v.is_finite() {
                    return self.constant(v);
                }
            }
        }
        if let Some(n) = e.filter(|&n| is_int(n)) {
            match self.node(base).clone() {
                Node::Pow(b, inner) => {
                    let ne = self.constant(n);
                    let prod = self.mul(&[inner, ne]);
                    return self.pow(b, prod);
                }
                Node::Mul(xs) => {
                    let fs: Vec<NodeId> = xs.iter().map(|&x| self.pow(x, exponent)).collect();
                    return self.mul(&fs);
                }
                _ => {}
            }
        }
        self.intern(Node::Pow(base, exponent))
    }

    /// `sqrt(a)`, represented as `a ^ 0.5`.
    pub fn sqrt(&mut self, a: NodeId) -> NodeId {
        self.powc(a, 0.5)
    }

    /// An elementary function call.
    pub fn call(&mut self, f: Fun, args: &[NodeId]) -> NodeId {
        let consts: Option<Vec<f64>> = args.iter().map(|&a| self.as_const(a)).collect();
        if let Some(cs) = consts {
            let v = f.eval(&cs);
            if v.is_finite() {
                return self.constant(v);
            }
        }
        match (f, self.node(args[0])) {
            (Fun::Ln, Node::Call(Fun::Exp, xs)) => return xs[0],
            (Fun::Exp, Node::Call(Fun::Ln, xs)) => return xs[0],
            _ => {}
        }
        self.intern(Node::Call(f, args.into()))
    }
}

#[cfg(test)]
mod tests {
    use crate::graph::{Fun, Graph, Node, NodeId, Var};
    use proptest::prelude::*;

    /// A term of a chain, built on a graph: a number, a variable times a
    /// number, a product, a power, a call, a nested sum, or a negation.
    #[derive(Clone, Debug)]
    enum Term {
        Num(f64),
        Scaled(f64, u32),
        Product(f64, u32, u32),
        Power(u32, f64),
        Sine(u32),
        Sum(Vec<Term>),
        Neg(Box<Term>),
    }

    fn build(g: &mut Graph, t: &Term) -> NodeId {
        let var = |g: &mut Graph, i: u32| g.var([Var::Q(0), Var::V(0), Var::Q(1), Var::V(1)][i as usize]);
        match t {
            Term::Num(c) => g.constant(*c),
            Term::Scaled(c, i) => {
                let x = var(g, *i);
                g.scale(*c, x)
            }
            Term::Product(c, i, j) => {
                let (x, y) = (var(g, *i), var(g, *j));
                let xy = g.mul2(x, y);
                g.scale(*c, xy)
            }
            Term::Power(i, e) => {
                let x = var(g, *i);
                g.powc(x, *e)
            }
            Term::Sine(i) => {
                let x = var(g, *i);
                g.call(Fun::Sin, &[x])
            }
            Term::Sum(ts) => {
                let xs: Vec<NodeId> = ts.iter().map(|t| build(g, t)).collect();
                g.add(&xs)
            }
            Term::Neg(t) => {
                let x = build(g, t);
                g.neg(x)
            }
        }
    }

    fn arb_term() -> impl Strategy<Value = Term> {
        // Few variables and coefficients, so that like terms meet and cancel.
        let coefficient = prop_oneof![Just(1.0), Just(-1.0), Just(2.0), Just(-2.0), Just(0.5), Just(1e-300), Just(3.0)];
        let leaf = prop_oneof![
            prop_oneof![Just(0.0), Just(1.0), Just(-1.0), Just(2.5), Just(0.1), Just(0.2)].prop_map(Term::Num),
            (coefficient.clone(), 0u32..4).prop_map(|(c, i)| Term::Scaled(c, i)),
            (coefficient, 0u32..4, 0u32..4).prop_map(|(c, i, j)| Term::Product(c, i, j)),
            (0u32..4, prop_oneof![Just(2.0), Just(-1.0), Just(0.5)]).prop_map(|(i, e)| Term::Power(i, e)),
            (0u32..4).prop_map(Term::Sine),
        ];
        leaf.prop_recursive(2, 12, 4, |inner| {
            prop_oneof![
                prop::collection::vec(inner.clone(), 2..4).prop_map(Term::Sum),
                inner.prop_map(|t| Term::Neg(Box::new(t))),
            ]
        })
    }

    /// The text of a node with the operands of sums and products in the
    /// order of their texts: equal for the same expression whatever the ids.
    fn text(g: &Graph, x: NodeId) -> String {
        let list = |xs: &[NodeId]| {
            let mut ts: Vec<String> = xs.iter().map(|&x| text(g, x)).collect();
            ts.sort();
            ts.join(" ")
        };
        match g.node(x) {
            Node::Const(bits) => format!("{:?}", f64::from_bits(*bits)),
            Node::Var(v) => format!("{v:?}"),
            Node::Add(xs) => format!("(+ {})", list(xs)),
            Node::Mul(xs) => format!("(* {})", list(xs)),
            Node::Pow(b, e) => format!("(^ {} {})", text(g, *b), text(g, *e)),
            Node::Call(f, xs) => format!("({f:?} {})", xs.iter().map(|&x| text(g, x)).collect::<Vec<_>>().join(" ")),
        }
    }

    /// Sums `first ± rest…` by the fold of `add2`/`sub` and by a chain that
    /// keeps the partial sums of at most `keep` operands, each in a graph of
    /// its own; returns both graphs, both sums and the partial sums of
    /// each step (as the fold's nodes and as the chain reports them).
    #[allow(clippy::type_complexity)]
    fn fold_and_chain(
        first: &Term,
        rest: &[(bool, Term)],
        keep: usize,
    ) -> (Graph, Graph, NodeId, NodeId, Vec<NodeId>, Vec<super::Partial>) {
        let mut folded = Graph::default();
        let mut acc = build(&mut folded, first);
        let mut partials = Vec::new();
        for (subtract, t) in rest {
            let b = build(&mut folded, t);
            acc = if *subtract { folded.sub(acc, b) } else { folded.add2(acc, b) };
            partials.push(acc);
        }
        let mut chained = Graph::default();
        let first_node = build(&mut chained, first);
        let mut chain = None;
        let mut reported = Vec::new();
        for (subtract, t) in rest {
            let b = build(&mut chained, t);
            let term = if *subtract { chained.neg(b) } else { b };
            let c = chain.get_or_insert_with(|| chained.sum_chain(first_node, keep));
            reported.push(chained.sum_chain_push(c, term));
        }
        let sum = chained.sum_chain_finish(chain.expect("one step at least"));
        (folded, chained, acc, sum, partials, reported)
    }

    /// What a chain reports of a partial sum the fold makes: its node if it
    /// is a single operand, else its constant operand (as bits: NaN is not
    /// equal to itself).
    fn expected_report(folded: &Graph, partial: NodeId) -> (Option<String>, Option<u64>) {
        match folded.node(partial) {
            Node::Add(xs) => (None, folded.as_const(xs[0]).map(f64::to_bits)),
            _ => (Some(text(folded, partial)), None),
        }
    }

    fn report(chained: &Graph, r: super::Partial) -> (Option<String>, Option<u64>) {
        match r {
            super::Partial::Node(x) => (Some(text(chained, x)), None),
            super::Partial::Sum { constant } => (None, constant.map(f64::to_bits)),
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// A chain `t0 ± t1 ± …` whose partial sums are interned (at most
        /// `KEPT_PARTIAL_SUM` operands) makes exactly the graph of the fold
        /// of `add2`/`sub`: the same nodes with the same ids, and the same
        /// sum; each step reports the partial sum the fold has.
        #[test]
        fn sum_chains_make_the_graph_of_the_fold(
            first in arb_term(),
            rest in prop::collection::vec((any::<bool>(), arb_term()), 1..12),
        ) {
            let (folded, chained, acc, sum, partials, reported) =
                fold_and_chain(&first, &rest, super::KEPT_PARTIAL_SUM);
            prop_assert_eq!(folded.len(), chained.len());
            for i in 0..folded.len() {
                let x = NodeId(i as u32);
                prop_assert_eq!(folded.node(x), chained.node(x), "node {}", i);
            }
            prop_assert_eq!(acc, sum);
            for (&p, &r) in partials.iter().zip(&reported) {
                prop_assert_eq!(expected_report(&folded, p), report(&chained, r));
            }
        }

        /// Without interning any partial sum, a chain still makes the
        /// fold's sum (its operands may be in another order where a node
        /// equals a partial sum the chain lacks) and reports its partial
        /// sums.
        #[test]
        fn sum_chains_without_partial_sums_make_the_sum_of_the_fold(
            first in arb_term(),
            rest in prop::collection::vec((any::<bool>(), arb_term()), 1..12),
        ) {
            let (folded, chained, acc, sum, partials, reported) = fold_and_chain(&first, &rest, 0);
            prop_assert_eq!(text(&folded, acc), text(&chained, sum));
            for (&p, &r) in partials.iter().zip(&reported) {
                prop_assert_eq!(expected_report(&folded, p), report(&chained, r));
            }
        }
    }

    /// Every left-folded prefix that emission takes of a product, in its
    /// order (least variable first), is the node `mul` makes of it: with and
    /// without a coefficient, with a sum and a negative power among the
    /// factors, and for a coefficient with one factor (which `mul`
    /// distributes over a sum).
    #[test]
    fn sub_products_equal_the_canonical_products() {
        let mut g = Graph::default();
        let (x, y, z) = (g.var(Var::V(0)), g.var(Var::V(1)), g.var(Var::Q(0)));
        let one = g.constant(1.0);
        let sum = g.add(&[one, x, z]);
        let sine = g.call(Fun::Sin, &[z]);
        let shifted = g.add(&[one, y]);
        let inverse = g.powc(shifted, -1.0);
        let square = g.powc(z, 2.0);
        for coefficient in [1.0, -3.5] {
            let c = g.constant(coefficient);
            let product = g.mul(&[c, x, sum, sine, inverse, square, y]);
            let Node::Mul(operands) = g.node(product).clone() else { panic!("not a product") };
            let mut operands: Vec<NodeId> = operands.to_vec();
            // Reversed after the coefficient: another order than the graph's.
            let from = usize::from(coefficient != 1.0);
            operands[from..].reverse();
            for k in 2..=operands.len() {
                let (fast, canonical) = (g.sub_product(&operands[..k]), g.mul(&operands[..k]));
                assert_eq!(fast, canonical, "prefix of {k} operands");
            }
        }
        let c = g.constant(2.0);
        let distributed = g.mul(&[c, sum]);
        assert_eq!(g.sub_product(&[c, sum]), distributed);
    }
}
