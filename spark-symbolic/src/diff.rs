//! Exact symbolic differentiation on the hash-consed graph, memoized per
//! `(node, variable)` so that shared subexpressions are differentiated once
//! and derivatives of derivatives reuse earlier results.

use crate::graph::{Fun, Graph, Node, NodeId, Var};
use std::collections::HashMap;

/// A differentiator: the graph plus a memo of derivatives already taken.
#[derive(Debug, Default)]
pub struct Differentiator {
    memo: HashMap<(NodeId, Var), NodeId>,
}

impl Differentiator {
    /// A differentiator with an empty memo.
    pub fn new() -> Differentiator {
        Differentiator::default()
    }

    /// `∂ node / ∂ var`, simplified.
    pub fn diff(&mut self, g: &mut Graph, node: NodeId, var: Var) -> NodeId {
        // Past the graph's limit every result is discarded: end the work
        // at once rather than walk the rest of a swollen expression.
        if !g.deps(node).any(var.dep()) || g.exhausted() {
            return g.constant(0.0);
        }
        if let Some(&d) = self.memo.get(&(node, var)) {
            return d;
        }
        let d = match g.node(node).clone() {
            Node::Const(_) => g.constant(0.0),
            Node::Var(v) => g.constant(if v == var { 1.0 } else { 0.0 }),
            Node::Add(xs) => {
                let ds: Vec<NodeId> = xs.iter().map(|&x| self.diff(g, x, var)).collect();
                g.add(&ds)
            }
            Node::Mul(xs) => {
                let mut terms = Vec::new();
                for i in 0..xs.len() {
                    let di = self.diff(g, xs[i], var);
                    if g.is_const(di, 0.0) {
                        continue;
                    }
                    let mut fs: Vec<NodeId> = xs.iter().enumerate().filter(|&(j, _)| j != i).map(|(_, &x)| x).collect();
                    fs.push(di);
                    terms.push(g.mul(&fs));
                }
                g.add(&terms)
            }
            Node::Pow(b, e) => {
                let db = self.diff(g, b, var);
                let de = self.diff(g, e, var);
                let mut terms = Vec::new();
                if !g.is_const(db, 0.0) {
                    // e · b^(e−1) · b'
                    let one = g.constant(1.0);
                    let em1 = g.sub(e, one);
                    let p = g.pow(b, em1);
                    terms.push(g.mul(&[e, p, db]));
                }
                if !g.is_const(de, 0.0) {
                    // b^e · ln(b) · e'
                    let lnb = g.call(Fun::Ln, &[b]);
                    terms.push(g.mul(&[node, lnb, de]));
                }
                g.add(&terms)
            }
            Node::Call(f, xs) => {
                let x = xs[0];
                let dx = self.diff(g, x, var);
                let outer = match f {
                    Fun::Exp => node,
                    Fun::Ln => g.powc(x, -1.0),
                    Fun::Sin => g.call(Fun::Cos, &[x]),
                    Fun::Cos => {
                        let s = g.call(Fun::Sin, &[x]);
                        g.neg(s)
                    }
                    Fun::Tan => {
                        // 1 + tan² reuses the tan node already computed.
                        let t2 = g.powc(node, 2.0);
                        let one = g.constant(1.0);
                        g.add(&[one, t2])
                    }
                    Fun::Sinh => g.call(Fun::Cosh, &[x]),
                    Fun::Cosh => g.call(Fun::Sinh, &[x]),
                    Fun::Tanh => {
                        // sech² = cosh⁻², not 1 − tanh²: where |x| is large,
                        // tanh rounds towards ±1 and 1 − tanh² loses the
                        // digits of sech², while cosh⁻² keeps them.
                        let c = g.call(Fun::Cosh, &[x]);
                        g.powc(c, -2.0)
                    }
                    Fun::Atan2 => {
                        // d atan2(y, x) = (x dy − y dx) / (x² + y²)
                        let (y, x) = (xs[0], xs[1]);
                        let dy = dx;
                        let dxx = self.diff(g, x, var);
                        let x2 = g.powc(x, 2.0);
                        let y2 = g.powc(y, 2.0);
                        let r2 = g.add(&[x2, y2]);
                        let a = g.mul(&[x, dy]);
                        let b = g.mul(&[y, dxx]);
                        let num = g.sub(a, b);
                        let d = g.div(num, r2);
                        self.memo.insert((node, var), d);
                        return d;
                    }
                };
                g.mul(&[outer, dx])
            }
        };
        self.memo.insert((node, var), d);
        d
    }
}
