//! The left-folded prefixes of the long products of one body: which of
//! them are nodes, so that products share them, without a node for every
//! prefix of every product.
//!
//! A product `a·b·c·d` is written `((a·b)·c)·d`, its factors least variable
//! first, and each prefix `a·b`, `a·b·c` of a product of at most
//! [`KEPT_PREFIX`] factors is a node, which CSE shares between the products
//! that begin alike. A prefix of `j` factors is a node of `j` operands, so
//! the prefixes of a product of `k` factors are `k²/2` operands (most of a
//! minute, and past the graph's limit, for 10 000 factors). A longer
//! product makes a node only of the prefixes that are worth one: one the
//! graph holds already, one that more of the body's long products begin
//! with than the product itself (found in a trie of them), and the prefix
//! of the factors less variable than its last (parameter-only prefixes are
//! hoisted); the other factors are multiplied in one by one, in the same
//! order, so the value is the same bit for bit.

use super::rank;
use crate::graph::{Graph, Node, NodeId};
use std::collections::{HashMap, HashSet};

/// The most factors (its coefficient included) of a product whose
/// left-folded prefixes are all nodes.
pub(crate) const KEPT_PREFIX: usize = 64;

/// A trie of the factor lists of the long products a body reaches.
pub(super) struct Prefixes {
    /// (position, next factor) → the position one factor deeper; position
    /// 0 is the empty prefix.
    next: HashMap<(usize, NodeId), usize>,
    /// How many of the long products begin with each position's prefix
    /// (are it, or longer).
    count: Vec<usize>,
}

impl Prefixes {
    /// The trie of the products of more than [`KEPT_PREFIX`] factors that
    /// `roots` reach through operands.
    pub(super) fn of(g: &Graph, roots: impl Iterator<Item = NodeId>) -> Prefixes {
        let mut trie = Prefixes { next: HashMap::new(), count: vec![0] };
        let mut seen = HashSet::new();
        let mut stack: Vec<NodeId> = roots.collect();
        while let Some(n) = stack.pop() {
            if !seen.insert(n) {
                continue;
            }
            match g.node(n) {
                Node::Const(_) | Node::Var(_) => {}
                Node::Add(xs) | Node::Call(_, xs) => stack.extend(xs.iter().copied()),
                Node::Pow(b, e) => stack.extend([*b, *e]),
                Node::Mul(xs) => {
                    stack.extend(xs.iter().copied());
                    let items = Self::items(g, xs);
                    if items.len() > KEPT_PREFIX {
                        trie.insert(&items);
                    }
                    // A sum writes its terms' coefficients apart, the
                    // products without them.
                    if items.len() > KEPT_PREFIX + 1 && items[0] == xs[0] && g.as_const(xs[0]).is_some() {
                        trie.insert(&items[1..]);
                    }
                }
            }
        }
        trie
    }

    /// The factors the view of the product of `xs` writes, in its order:
    /// least variable first, its coefficient first of all (none for −1:
    /// the view writes the negation of the positive product), without the
    /// powers with negative exponents (its denominator).
    fn items(g: &Graph, xs: &[NodeId]) -> Vec<NodeId> {
        let coef = g.as_const(xs[0]).filter(|&c| c != 1.0 && c != -1.0).map(|_| xs[0]);
        let mut items: Vec<NodeId> = xs
            .iter()
            .copied()
            .filter(|&x| match g.node(x) {
                Node::Const(_) => false,
                Node::Pow(_, e) => !g.as_const(*e).is_some_and(|e| e < 0.0),
                _ => true,
            })
            .collect();
        items.sort_by_key(|&x| (rank(g, x), x));
        coef.into_iter().chain(items).collect()
    }

    fn insert(&mut self, items: &[NodeId]) {
        let mut at = 0;
        for &x in items {
            let fresh = self.count.len();
            at = *self.next.entry((at, x)).or_insert(fresh);
            if at == fresh {
                self.count.push(0);
            }
            self.count[at] += 1;
        }
    }

    /// The factors a product of more than [`KEPT_PREFIX`] factors `items`
    /// (in the order its view writes them) is written with, folded from the
    /// left: the prefix of all but the last factor when the graph holds it
    /// already; else the longer of the longest prefix that more of the
    /// body's long products begin with than begin with `items` (two at
    /// least), and the prefix of the factors less variable than the last,
    /// as a node; then the other factors one by one. A product makes at
    /// most one node here; the nodes a prefix's own view makes are at
    /// places where more products share it, or less variable, so the nodes
    /// made have fewer operands in all than the body's products.
    pub(super) fn factors(&self, g: &mut Graph, mut items: Vec<NodeId>) -> Vec<NodeId> {
        let last = items.len() - 1;
        if let Some(prefix) = g.find_sub_product(&items[..last]) {
            return vec![prefix, items[last]];
        }
        // How many products begin with each prefix, as far as the trie has
        // them: `begin[j - 1]` for the prefix of `j` factors.
        let mut begin = Vec::with_capacity(items.len());
        let mut at = 0;
        for &x in &items {
            match self.next.get(&(at, x)) {
                Some(&next) => {
                    at = next;
                    begin.push(self.count[next]);
                }
                None => break,
            }
        }
        let own = if begin.len() == items.len() { begin[last] } else { 0 };
        let shared = (2..=begin.len().min(last)).rev().find(|&j| begin[j - 1] > own.max(1)).unwrap_or(0);
        let r = rank(g, items[last]);
        let less_variable = items.iter().take_while(|&&x| rank(g, x) < r).count();
        let head = shared.max(less_variable);
        if head >= 2 {
            let prefix = g.sub_product(&items[..head]);
            items.splice(..head, [prefix]);
        }
        items
    }
}
