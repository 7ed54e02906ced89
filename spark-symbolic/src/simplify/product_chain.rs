//! The fold `((a · b) · c) · …` of a product written in the source, kept as
//! its factors once it is long, rather than as interned partial products:
//! each partial product of a chain of `k` factors is a node with all the
//! factors before it, `k²/2` operands in all, and each step of
//! [`Graph::mul`] goes through all of them.
//!
//! The steps ([`Graph::product_chain_push`]) make the nodes the fold of
//! `mul` makes, in the same order, with the same coefficients (multiplied
//! in the fold's order), and intern the partial products of at most
//! [`KEPT_PARTIAL_PRODUCT`] operands as the fold does; so the node ids, the
//! order of the operands of every sum and product (sorted by id) and the
//! emitted code are those of the fold.

use crate::graph::{Graph, Node, NodeId};
use std::collections::HashMap;

/// The partial products of a [`ProductChain`] of at most this many
/// operands are interned, as the fold interns them. So the graph is the
/// fold's exactly for every product whose partial products are this small,
/// and otherwise lacks only the longer partial products: a node made later
/// that equals one of them (a product of over 64 factors written out
/// again) gets a later id than in the fold, which can change the order of
/// the operands of the sums and products made after it.
pub(crate) const KEPT_PARTIAL_PRODUCT: usize = 64;

/// A product `first · b · c · …` being folded (see the module documentation).
pub(crate) struct ProductChain {
    state: State,
    /// The most operands of a partial product that is interned.
    keep: usize,
}

enum State {
    /// The partial product is this node, made by `mul` itself.
    Node(NodeId),
    /// A product of more than `keep` operands, not interned.
    Long(Long),
    /// The graph is exhausted: every product is the constant 0.
    Dead,
}

/// A canonical product kept as its parts.
struct Long {
    /// The coefficient (1 when the product has no number among its operands).
    coef: f64,
    /// Each factor's base → the factor (`base` itself or `base ^ e`).
    factors: HashMap<NodeId, NodeId>,
    /// How many factors are not powers (their exponent is the constant 1).
    plain: usize,
}

/// What the lowering's checks need of a partial product.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum PartialProduct {
    /// The partial product is this node.
    Node(NodeId),
    /// A product of more than `keep` operands (not interned) whose
    /// coefficient is not a finite number, or is.
    Long {
        /// The coefficient is not a finite number.
        nonfinite: bool,
    },
}

impl Graph {
    /// The base of a canonical factor and, when it is a power, its exponent.
    fn base_of(&self, f: NodeId) -> (NodeId, Option<NodeId>) {
        match self.node(f) {
            Node::Pow(b, e) => (*b, Some(*e)),
            _ => (f, None),
        }
    }

    /// The chain's state for the node `r` of a partial product: its parts
    /// when it is a product of more than `keep` operands.
    fn product_state(&self, r: NodeId, keep: usize) -> State {
        match self.node(r) {
            Node::Mul(xs) if xs.len() > keep => {
                let coef = self.as_const(xs[0]);
                let mut long = Long { coef: coef.unwrap_or(1.0), factors: HashMap::new(), plain: 0 };
                for &x in &xs[usize::from(coef.is_some())..] {
                    let (base, e) = self.base_of(x);
                    long.plain += usize::from(e.is_none());
                    if long.factors.insert(base, x).is_some() {
                        // Two factors of one base (`mul` can leave
                        // `(x^a)^½ · (x^a)^½ = x^a` beside `x`): the next
                        // `mul` merges them, so it takes this step too.
                        return State::Node(r);
                    }
                }
                State::Long(long)
            }
            _ => State::Node(r),
        }
    }

    /// Starts the fold `((first · b) · c) · …` of a chain written in the
    /// source. The caller starts the chain after lowering `b`, as
    /// `mul(&[first, b])` looks at `first` after `b` is made.
    pub(crate) fn product_chain(&mut self, first: NodeId, keep: usize) -> ProductChain {
        if self.exhausted() {
            return ProductChain { state: State::Dead, keep };
        }
        ProductChain { state: self.product_state(first, keep), keep }
    }

    /// One step of the fold: the partial product becomes
    /// `mul(&[partial, term])`, making the nodes that call makes, in its
    /// order, except a partial product of more than `keep` operands. Once
    /// the partial product is long, work proportional to `term`'s operands,
    /// not to the partial product's.
    pub(crate) fn product_chain_push(&mut self, chain: &mut ProductChain, term: NodeId) -> PartialProduct {
        if self.exhausted() {
            chain.state = State::Dead;
        }
        let long = match &mut chain.state {
            State::Dead => return PartialProduct::Node(self.constant(0.0)),
            State::Node(acc) => {
                let r = self.mul(&[*acc, term]);
                chain.state = self.product_state(r, chain.keep);
                return PartialProduct::Node(r);
            }
            State::Long(long) => long,
        };
        // `mul` takes `term`'s operands last first (a stack), then the
        // partial product's; it multiplies the numbers in that order and
        // splits every other factor into base and exponent (making the
        // constant 1 for a factor that is not a power).
        let flat: Vec<NodeId> = match self.node(term) {
            Node::Mul(xs) => xs.iter().rev().copied().collect(),
            _ => vec![term],
        };
        let mut coef = 1.0;
        let mut order: Vec<NodeId> = Vec::new();
        let mut exps: HashMap<NodeId, Vec<NodeId>> = HashMap::new();
        for f in flat {
            if let Node::Const(_) = self.node(f) {
                coef *= self.as_const(f).unwrap_or(f64::NAN);
                continue;
            }
            let (b, e) = self.split_power(f);
            exps.entry(b)
                .or_insert_with(|| {
                    order.push(b);
                    Vec::new()
                })
                .push(e);
        }
        if long.plain > 0 {
            self.constant(1.0);
        }
        if long.coef != 1.0 {
            coef *= long.coef;
        }
        if coef == 0.0 {
            let zero = self.constant(0.0);
            chain.state = State::Node(zero);
            return PartialProduct::Node(zero);
        }
        // The bases met in `term` come first in `mul`'s order and are the
        // only ones whose factor it makes anew; the others' `pow(base, e)`
        // is the factor they have.
        let mut made: Vec<(NodeId, NodeId)> = Vec::with_capacity(order.len());
        let mut again = false;
        // A factor whose base is not the one it was made for (`(x^a)^½ ·
        // (x^a)^½ = x^a`, of base `x`) may share its base with another.
        let mut odd = false;
        for &b in &order {
            let mut es = exps.remove(&b).unwrap_or_default();
            if let Some(&f) = long.factors.get(&b) {
                let e = match self.node(f) {
                    Node::Pow(_, e) => *e,
                    _ => self.constant(1.0),
                };
                es.push(e);
            }
            let e = if es.len() == 1 { es[0] } else { self.add(&es) };
            let f = self.pow(b, e);
            match self.node(f) {
                Node::Const(_) => coef *= self.as_const(f).unwrap_or(f64::NAN),
                Node::Mul(_) => again = true,
                _ => odd |= self.base_of(f).0 != b,
            }
            made.push((b, f));
        }
        if again {
            // A power that is a product (`(x·y)^½ · (x·y)^½`): `mul` starts
            // again from its factors, the partial product's last.
            let mut out: Vec<NodeId> = made.iter().map(|&(_, f)| f).filter(|&f| self.as_const(f).is_none()).collect();
            let mut rest: Vec<NodeId> =
                long.factors.iter().filter(|(b, _)| !made.iter().any(|m| m.0 == **b)).map(|(_, &f)| f).collect();
            rest.sort_unstable_by(|a, b| b.cmp(a));
            out.extend(rest);
            let c = self.constant(coef);
            out.push(c);
            let r = self.mul(&out);
            chain.state = self.product_state(r, chain.keep);
            return PartialProduct::Node(r);
        }
        for (b, f) in made {
            let old = if self.as_const(f).is_some() { long.factors.remove(&b) } else { long.factors.insert(b, f) };
            long.plain -= usize::from(old.is_some_and(|o| self.base_of(o).1.is_none()));
            long.plain += usize::from(self.as_const(f).is_none() && self.base_of(f).1.is_none());
        }
        long.coef = coef;
        let len = long.factors.len();
        if odd || coef == 0.0 || len <= 1 || len + usize::from(coef != 1.0) <= chain.keep {
            let out: Vec<NodeId> = long.factors.values().copied().collect();
            let r = self.mul_factors(coef, out);
            chain.state = self.product_state(r, chain.keep);
            return PartialProduct::Node(r);
        }
        if coef != 1.0 {
            // `mul` makes the coefficient's node before the product's.
            self.constant(coef);
        }
        PartialProduct::Long { nonfinite: !coef.is_finite() }
    }

    /// The node of the chain's product: what the last `mul` of the fold makes.
    pub(crate) fn product_chain_finish(&mut self, chain: ProductChain) -> NodeId {
        match chain.state {
            State::Dead => self.constant(0.0),
            State::Node(r) => r,
            State::Long(long) => {
                let out: Vec<NodeId> = long.factors.into_values().collect();
                self.mul_factors(long.coef, out)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{PartialProduct, KEPT_PARTIAL_PRODUCT};
    use crate::graph::{Fun, Graph, Node, NodeId, Var};
    use proptest::prelude::*;
    use std::collections::HashSet;

    /// A factor of a chain, built on a graph: a number, a variable, a
    /// variable times a number, a power of a variable or of a product, a
    /// sine (of a variable shifted by a number, so that long chains have
    /// many distinct bases), a nested sum or product, a negation.
    #[derive(Clone, Debug)]
    enum Factor {
        Num(f64),
        Var(u32),
        Scaled(f64, u32),
        Power(u32, f64),
        PowerOfProduct(u32, u32, f64),
        Sine(u32, u8),
        Sum(Vec<Factor>),
        Product(Vec<Factor>),
        Neg(Box<Factor>),
    }

    fn var(g: &mut Graph, i: u32) -> NodeId {
        g.var([Var::Q(0), Var::V(0), Var::Q(1), Var::P(0)][i as usize])
    }

    fn build(g: &mut Graph, f: &Factor) -> NodeId {
        match f {
            Factor::Num(c) => g.constant(*c),
            Factor::Var(i) => var(g, *i),
            Factor::Scaled(c, i) => {
                let x = var(g, *i);
                g.scale(*c, x)
            }
            Factor::Power(i, e) => {
                let x = var(g, *i);
                g.powc(x, *e)
            }
            Factor::PowerOfProduct(i, j, e) => {
                let (x, y) = (var(g, *i), var(g, *j));
                let xy = g.mul2(x, y);
                g.powc(xy, *e)
            }
            Factor::Sine(i, k) => {
                let x = var(g, *i);
                let k = g.constant(f64::from(*k));
                let shifted = g.add2(x, k);
                g.call(Fun::Sin, &[shifted])
            }
            Factor::Sum(fs) => {
                let xs: Vec<NodeId> = fs.iter().map(|f| build(g, f)).collect();
                g.add(&xs)
            }
            Factor::Product(fs) => {
                let xs: Vec<NodeId> = fs.iter().map(|f| build(g, f)).collect();
                g.mul(&xs)
            }
            Factor::Neg(f) => {
                let x = build(g, f);
                g.neg(x)
            }
        }
    }

    fn arb_factor() -> impl Strategy<Value = Factor> {
        // Few variables and exponents, so that bases meet, merge and cancel.
        let number = prop_oneof![Just(0.0), Just(1.0), Just(-1.0), Just(2.0), Just(0.5), Just(-3.0), Just(1e300)];
        let exponent = prop_oneof![Just(2.0), Just(-1.0), Just(0.5), Just(-0.5), Just(1.5), Just(-2.0)];
        let leaf = prop_oneof![
            number.clone().prop_map(Factor::Num),
            (0u32..4).prop_map(Factor::Var),
            (number, 0u32..4).prop_map(|(c, i)| Factor::Scaled(c, i)),
            (0u32..4, exponent.clone()).prop_map(|(i, e)| Factor::Power(i, e)),
            (0u32..4, 0u32..4, exponent).prop_map(|(i, j, e)| Factor::PowerOfProduct(i, j, e)),
            (0u32..4, 0u8..3).prop_map(|(i, k)| Factor::Sine(i, k)),
        ];
        leaf.prop_recursive(2, 12, 3, |inner| {
            prop_oneof![
                prop::collection::vec(inner.clone(), 2..4).prop_map(Factor::Sum),
                prop::collection::vec(inner.clone(), 2..4).prop_map(Factor::Product),
                inner.prop_map(|f| Factor::Neg(Box::new(f))),
            ]
        })
    }

    /// Factors of a long chain: mostly sines of many shifts (distinct
    /// bases, more than `KEPT_PARTIAL_PRODUCT` of them), some of them
    /// divided by again, and the factors of [`arb_factor`].
    fn arb_long_chain() -> impl Strategy<Value = Vec<(bool, Factor)>> {
        let factor = prop_oneof![
            4 => (0u32..4, 0u8..60).prop_map(|(i, k)| Factor::Sine(i, k)),
            1 => arb_factor(),
        ];
        prop::collection::vec((prop::bool::weighted(0.1), factor), 60..140)
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

    /// What the fold and the chain made of `first */ rest…`.
    struct Made {
        folded: Graph,
        chained: Graph,
        /// The fold's product and partial products.
        product: NodeId,
        partials: Vec<NodeId>,
        /// The chain's product and what it reported of each partial product.
        chain_product: NodeId,
        reported: Vec<PartialProduct>,
    }

    /// Multiplies `first */ rest…` by the fold of `mul2`/`div` and by a
    /// chain that interns the partial products of at most `keep` operands,
    /// each in a graph of its own, as the lowering does.
    fn fold_and_chain(first: &Factor, rest: &[(bool, Factor)], keep: usize) -> Made {
        let mut folded = Graph::default();
        let mut acc = build(&mut folded, first);
        let mut partials = Vec::new();
        for (divide, f) in rest {
            let b = build(&mut folded, f);
            acc = if *divide { folded.div(acc, b) } else { folded.mul2(acc, b) };
            partials.push(acc);
        }
        let mut chained = Graph::default();
        let first_node = build(&mut chained, first);
        let mut chain = None;
        let mut reported = Vec::new();
        for (divide, f) in rest {
            let b = build(&mut chained, f);
            let term = if *divide {
                let m1 = chained.constant(-1.0);
                chained.pow(b, m1)
            } else {
                b
            };
            let c = chain.get_or_insert_with(|| chained.product_chain(first_node, keep));
            reported.push(chained.product_chain_push(c, term));
        }
        let chain_product = chained.product_chain_finish(chain.expect("one step at least"));
        Made { folded, chained, product: acc, partials, chain_product, reported }
    }

    /// The chain makes the fold's product and reports each partial product
    /// (its node, or for a long one whether its coefficient is finite); its
    /// graph is the fold's without the partial products of more than `keep`
    /// operands, in the fold's order unless a node equal to one of those
    /// was made later.
    fn check_against_fold(m: &Made, keep: usize) -> Result<(), TestCaseError> {
        let (f, c) = (&m.folded, &m.chained);
        prop_assert_eq!(text(f, m.product), text(c, m.chain_product));
        let mut skipped = HashSet::new();
        for (&p, r) in m.partials.iter().zip(&m.reported) {
            match *r {
                PartialProduct::Node(x) => prop_assert_eq!(text(f, p), text(c, x)),
                PartialProduct::Long { nonfinite } => {
                    prop_assert!(matches!(f.node(p), Node::Mul(xs) if xs.len() > keep));
                    prop_assert_eq!(nonfinite, f.has_nonfinite_operand(p));
                    skipped.insert(text(f, p));
                }
            }
        }
        let folded: Vec<String> = (0..f.len()).map(|i| text(f, NodeId(i as u32))).collect();
        let chained: Vec<String> = (0..c.len()).map(|i| text(c, NodeId(i as u32))).collect();
        let made: HashSet<&String> = chained.iter().collect();
        for t in &folded {
            prop_assert!(made.contains(t) || skipped.contains(t), "the chain lacks {} ", t);
        }
        if !chained.iter().any(|t| skipped.contains(t)) {
            let kept: Vec<&String> = folded.iter().filter(|t| made.contains(t)).collect();
            prop_assert_eq!(kept, chained.iter().collect::<Vec<_>>());
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// A chain `f0 */ f1 */ …` whose partial products are interned
        /// (at most `KEPT_PARTIAL_PRODUCT` operands) makes exactly the graph
        /// of the fold of `mul2`/`div`: the same nodes with the same ids,
        /// and the same product.
        #[test]
        fn product_chains_make_the_graph_of_the_fold(
            first in arb_factor(),
            rest in prop::collection::vec((any::<bool>(), arb_factor()), 1..12),
        ) {
            let m = fold_and_chain(&first, &rest, KEPT_PARTIAL_PRODUCT);
            prop_assert_eq!(m.folded.len(), m.chained.len());
            for i in 0..m.folded.len() {
                let x = NodeId(i as u32);
                prop_assert_eq!(m.folded.node(x), m.chained.node(x), "node {}", i);
            }
            prop_assert_eq!(m.product, m.chain_product);
            for (&p, &r) in m.partials.iter().zip(&m.reported) {
                prop_assert_eq!(PartialProduct::Node(p), r);
            }
        }

        /// Keeping only partial products of at most 0 to 3 operands, a
        /// chain makes the fold's nodes but the longer partial products,
        /// and the fold's product.
        #[test]
        fn product_chains_without_long_partial_products_make_the_fold_without_them(
            first in arb_factor(),
            rest in prop::collection::vec((any::<bool>(), arb_factor()), 1..12),
            keep in 0usize..4,
        ) {
            let m = fold_and_chain(&first, &rest, keep);
            check_against_fold(&m, keep)?;
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Chains of over `KEPT_PARTIAL_PRODUCT` distinct factors make the
        /// fold's nodes but its partial products of more operands than that.
        #[test]
        fn long_product_chains_make_the_fold_without_its_long_partial_products(
            first in arb_factor(),
            rest in arb_long_chain(),
        ) {
            let m = fold_and_chain(&first, &rest, KEPT_PARTIAL_PRODUCT);
            check_against_fold(&m, KEPT_PARTIAL_PRODUCT)?;
        }
    }
}
