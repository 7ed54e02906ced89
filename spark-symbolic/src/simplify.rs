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

/// `true` if `x` is an integer that `powi` can take.
pub fn is_int(x: f64) -> bool {
    x.fract() == 0.0 && x.abs() <= 1e9
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
    /// prefixes of every product this way, `k` of them for `k` factors.
    pub(crate) fn sub_product(&mut self, operands: &[NodeId]) -> NodeId {
        let constant = operands.first().filter(|&&x| self.as_const(x).is_some()).copied();
        let rest = &operands[usize::from(constant.is_some())..];
        if rest.len() < 2 {
            return self.mul(operands);
        }
        let mut xs: Vec<NodeId> = Vec::with_capacity(operands.len());
        xs.extend(constant);
        let from = xs.len();
        xs.extend_from_slice(rest);
        xs[from..].sort_unstable();
        self.intern(Node::Mul(xs.into()))
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
