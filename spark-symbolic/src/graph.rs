//! The hash-consed expression graph: an arena of interned nodes, so that two
//! structurally identical subexpressions are always the same [`NodeId`].
//!
//! This module owns storage, interning and the raw node shapes. The public
//! constructors that keep every node in canonical, simplified form live in
//! [`crate::simplify`]; differentiation in [`crate::diff`].
//!
//! Canonical invariants (maintained by the constructors, relied upon by
//! simplification, differentiation and emission):
//! - `Const` holds a finite `f64` (never `-0.0`);
//! - `Add` has ≥ 2 operands, none of them `Add`, at most one `Const`
//!   (listed first), no two operands equal up to a constant factor;
//! - `Mul` has ≥ 2 operands, none of them `Mul`, at most one `Const`
//!   (listed first, never 0 or 1), no two operands with the same power base;
//! - operands of `Add`/`Mul` are otherwise sorted by [`NodeId`];
//! - `sqrt(x)` is `Pow(x, 0.5)`, `1/x` is `Pow(x, -1)`, `-x` is `Mul(-1, x)`.

use std::collections::HashMap;

/// Index of a node in a [`Graph`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(pub u32);

impl NodeId {
    /// Position in the arena.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// An independent variable of the generated functions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Var {
    /// The time `t`.
    Time,
    /// Coordinate `q_i`.
    Q(u32),
    /// Velocity `v_i`.
    V(u32),
    /// Runtime parameter `p_i` (a struct field).
    P(u32),
    /// Multiplier `ψ_j`.
    Psi(u32),
}

impl Var {
    /// The dependency bit of this variable's kind.
    pub fn dep(self) -> Deps {
        match self {
            Var::Time => Deps::T,
            Var::Q(_) => Deps::Q,
            Var::V(_) => Deps::V,
            Var::P(_) => Deps::P,
            Var::Psi(_) => Deps::PSI,
        }
    }
}

/// Which kinds of variables a node depends on (a bit set).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Deps(pub u8);

impl Deps {
    /// Depends on nothing (a constant).
    pub const NONE: Deps = Deps(0);
    /// Depends on `t`.
    pub const T: Deps = Deps(1);
    /// Depends on some `q_i`.
    pub const Q: Deps = Deps(2);
    /// Depends on some `v_i`.
    pub const V: Deps = Deps(4);
    /// Depends on some parameter.
    pub const P: Deps = Deps(8);
    /// Depends on some `ψ_j`.
    pub const PSI: Deps = Deps(16);
    /// Union.
    pub fn with(self, other: Deps) -> Deps {
        Deps(self.0 | other.0)
    }
    /// `true` if any kind in `kinds` is present.
    pub fn any(self, kinds: Deps) -> bool {
        self.0 & kinds.0 != 0
    }
    /// Depends on parameters at most: computable once per call.
    pub fn parameters_only(self) -> bool {
        self.0 & !Deps::P.0 == 0
    }
}

/// Elementary functions other than powers (`sqrt` is a power).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Fun {
    /// `exp`.
    Exp,
    /// Natural logarithm.
    Ln,
    /// `sin`.
    Sin,
    /// `cos`.
    Cos,
    /// `tan`.
    Tan,
    /// `sinh`.
    Sinh,
    /// `cosh`.
    Cosh,
    /// `tanh`.
    Tanh,
    /// `atan2(y, x)`.
    Atan2,
}

impl Fun {
    /// Evaluates on `f64` arguments (`args.len()` is the arity).
    pub fn eval(self, args: &[f64]) -> f64 {
        let x = args[0];
        match self {
            Fun::Exp => x.exp(),
            Fun::Ln => x.ln(),
            Fun::Sin => x.sin(),
            Fun::Cos => x.cos(),
            Fun::Tan => x.tan(),
            Fun::Sinh => x.sinh(),
            Fun::Cosh => x.cosh(),
            Fun::Tanh => x.tanh(),
            Fun::Atan2 => x.atan2(args[1]),
        }
    }
    /// The Rust method name (`x.sin()`, `y.atan2(x)`).
    pub fn method(self) -> &'static str {
        match self {
            Fun::Exp => "exp",
            Fun::Ln => "ln",
            Fun::Sin => "sin",
            Fun::Cos => "cos",
            Fun::Tan => "tan",
            Fun::Sinh => "sinh",
            Fun::Cosh => "cosh",
            Fun::Tanh => "tanh",
            Fun::Atan2 => "atan2",
        }
    }
}

/// One node. Operands are [`NodeId`]s of earlier nodes.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Node {
    /// A finite number, stored as its bits so that nodes can be hashed.
    Const(u64),
    /// An independent variable.
    Var(Var),
    /// Sum of ≥ 2 operands.
    Add(Box<[NodeId]>),
    /// Product of ≥ 2 operands.
    Mul(Box<[NodeId]>),
    /// `base ^ exponent`.
    Pow(NodeId, NodeId),
    /// Function call.
    Call(Fun, Box<[NodeId]>),
}

/// The most a [`Graph`] may hold, counted as [`Graph::size`] (nodes plus
/// their operands) without the nodes of the source expressions themselves
/// ([`Graph::uncounted`]). Derivatives can swell far beyond the expression
/// written: the second derivative of a product of `k` factors in one
/// coordinate has about `k³` operands, so `dot(x)^2 + (x+1)*(x+2)*…*(x+150)`
/// (1 KB of text) reaches 4.6 million with the code generated, 12 MB of
/// Rust on which rustc runs out of stack, and 400 factors would take
/// gigabytes and minutes. The limit sits below that: the 400 coupled
/// coordinates of the Python tests reach about 5 % of it, the registered
/// systems far less, a product of 100 such factors 35 % (3.7 MB of code);
/// past it the declaration is an error ([`Graph::exhausted`]).
pub const MAX_GRAPH_SIZE: usize = 4_000_000;

/// The arena. Nodes are immutable once created; creating a node that already
/// exists returns the existing id.
#[derive(Clone, Debug, Default)]
pub struct Graph {
    nodes: Vec<Node>,
    deps: Vec<Deps>,
    index: HashMap<Node, NodeId>,
    /// The operands of every node, summed.
    operands: usize,
    /// The part of [`size`](Self::size) made while lowering source
    /// expressions ([`uncounted`](Self::uncounted)).
    exempt: usize,
    /// Inside [`uncounted`](Self::uncounted).
    lowering: bool,
    /// A node was refused for [`MAX_GRAPH_SIZE`].
    exhausted: bool,
}

impl Graph {
    /// An empty graph.
    pub fn new() -> Graph {
        Graph::default()
    }

    /// Number of distinct nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// `true` if no node was created yet.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Nodes plus their operands: what the graph's memory grows with.
    pub fn size(&self) -> usize {
        self.nodes.len() + self.operands
    }

    /// Runs `f` (the lowering of a source expression) with the nodes it
    /// makes not counted against [`MAX_GRAPH_SIZE`]: the source's size is
    /// bounded by the parser's limits, and the limit is for what
    /// differentiation and emission make of it.
    pub fn uncounted<T>(&mut self, f: impl FnOnce(&mut Graph) -> T) -> T {
        let outer = std::mem::replace(&mut self.lowering, true);
        let r = f(self);
        self.lowering = outer;
        r
    }

    /// `true` once a node was refused for [`MAX_GRAPH_SIZE`]. From then on
    /// every new node is the constant 0, so the work in progress ends
    /// quickly with meaningless results, which the caller discards for
    /// this flag.
    pub fn exhausted(&self) -> bool {
        self.exhausted
    }

    /// The node behind an id.
    pub fn node(&self, id: NodeId) -> &Node {
        &self.nodes[id.index()]
    }

    /// The variable kinds a node depends on.
    pub fn deps(&self, id: NodeId) -> Deps {
        self.deps[id.index()]
    }

    /// The value of a constant node.
    pub fn as_const(&self, id: NodeId) -> Option<f64> {
        match self.node(id) {
            Node::Const(bits) => Some(f64::from_bits(*bits)),
            _ => None,
        }
    }

    /// `true` if `id` is the constant `value`.
    pub fn is_const(&self, id: NodeId, value: f64) -> bool {
        self.as_const(id) == Some(value)
    }

    /// The id of `node` if the graph holds it, without adding it.
    pub(crate) fn find(&self, node: &Node) -> Option<NodeId> {
        self.index.get(node).copied()
    }

    /// Interns a node exactly as given (no simplification): callers must
    /// respect the canonical invariants of the module documentation.
    pub(crate) fn intern(&mut self, node: Node) -> NodeId {
        if self.exhausted {
            return self.zero();
        }
        if let Some(&id) = self.index.get(&node) {
            return id;
        }
        let operands = match &node {
            Node::Const(_) | Node::Var(_) => 0,
            Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => xs.len(),
            Node::Pow(..) => 2,
        };
        if !self.lowering && self.size() - self.exempt + 1 + operands > MAX_GRAPH_SIZE {
            self.exhausted = true;
            return self.zero();
        }
        self.operands += operands;
        if self.lowering {
            self.exempt += 1 + operands;
        }
        let deps = match &node {
            Node::Const(_) => Deps::NONE,
            Node::Var(v) => v.dep(),
            Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => {
                xs.iter().fold(Deps::NONE, |d, x| d.with(self.deps[x.index()]))
            }
            Node::Pow(b, e) => self.deps[b.index()].with(self.deps[e.index()]),
        };
        self.push(node, deps)
    }

    /// The constant 0, interned whatever the size of the graph.
    fn zero(&mut self) -> NodeId {
        let node = Node::Const(0.0f64.to_bits());
        match self.index.get(&node) {
            Some(&id) => id,
            None => self.push(node, Deps::NONE),
        }
    }

    /// Appends a node not yet in the graph, with its dependencies.
    fn push(&mut self, node: Node, deps: Deps) -> NodeId {
        let id = NodeId(u32::try_from(self.nodes.len()).expect("expression graph exceeds 2^32 nodes"));
        self.nodes.push(node.clone());
        self.deps.push(deps);
        self.index.insert(node, id);
        id
    }

    /// The constant `value` (`-0.0` is stored as `0.0`).
    pub fn constant(&mut self, value: f64) -> NodeId {
        let value = if value == 0.0 { 0.0 } else { value };
        self.intern(Node::Const(value.to_bits()))
    }

    /// The variable `var`.
    pub fn var(&mut self, var: Var) -> NodeId {
        self.intern(Node::Var(var))
    }

    /// For every node, `true` if it is or contains a constant that is not a
    /// finite number. Folding can make one (`1e308·1e308`, or the
    /// coefficient `1e300·1e300` of the second derivative of `x^1e300`);
    /// generated code cannot write it, so a model refuses any expression
    /// that reaches one. One pass: operands precede the nodes using them.
    pub fn nonfinite_nodes(&self) -> Vec<bool> {
        let mut bad = vec![false; self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            bad[i] = match node {
                Node::Const(bits) => !f64::from_bits(*bits).is_finite(),
                Node::Var(_) => false,
                Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => xs.iter().any(|x| bad[x.index()]),
                Node::Pow(b, e) => bad[b.index()] || bad[e.index()],
            };
        }
        bad
    }

    /// `true` if `id` is a constant that is not a finite number, or an
    /// operation with such a constant among its operands (where folding puts
    /// a number that overflowed: the leading coefficient of a product, the
    /// constant term of a sum).
    pub fn has_nonfinite_operand(&self, id: NodeId) -> bool {
        let nonfinite = |x: &NodeId| self.as_const(*x).is_some_and(|v| !v.is_finite());
        match self.node(id) {
            Node::Const(_) => nonfinite(&id),
            Node::Var(_) => false,
            Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => xs.iter().any(nonfinite),
            Node::Pow(b, e) => nonfinite(b) || nonfinite(e),
        }
    }

    /// `true` if `id` depends on the variable `var` (exact, by traversal).
    pub fn depends_on(&self, id: NodeId, var: Var) -> bool {
        if !self.deps(id).any(var.dep()) {
            return false;
        }
        let mut seen = vec![false; self.nodes.len()];
        let mut stack = vec![id];
        while let Some(n) = stack.pop() {
            if std::mem::replace(&mut seen[n.index()], true) || !self.deps(n).any(var.dep()) {
                continue;
            }
            match self.node(n) {
                Node::Const(_) => {}
                Node::Var(v) => {
                    if *v == var {
                        return true;
                    }
                }
                Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => stack.extend(xs.iter().copied()),
                Node::Pow(b, e) => stack.extend([*b, *e]),
            }
        }
        false
    }

    /// Evaluates nodes at a point; `env` gives each variable's value.
    /// Results are memoized in `cache` (indexed by node, sized on demand).
    pub fn eval_with(&self, id: NodeId, env: &dyn Fn(Var) -> f64, cache: &mut Vec<Option<f64>>) -> f64 {
        if cache.len() < self.nodes.len() {
            cache.resize(self.nodes.len(), None);
        }
        // Iterative post-order so that deep graphs cannot overflow the stack.
        let mut stack = vec![(id, false)];
        while let Some((n, expanded)) = stack.pop() {
            if cache[n.index()].is_some() {
                continue;
            }
            let children: Vec<NodeId> = match self.node(n) {
                Node::Const(_) | Node::Var(_) => Vec::new(),
                Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => xs.to_vec(),
                Node::Pow(b, e) => vec![*b, *e],
            };
            if !expanded && children.iter().any(|c| cache[c.index()].is_none()) {
                stack.push((n, true));
                stack.extend(children.iter().map(|&c| (c, false)));
                continue;
            }
            let get = |c: &NodeId| cache[c.index()].unwrap_or(f64::NAN);
            let value = match self.node(n) {
                Node::Const(bits) => f64::from_bits(*bits),
                Node::Var(v) => env(*v),
                Node::Add(xs) => xs.iter().map(get).sum(),
                Node::Mul(xs) => xs.iter().map(get).product(),
                Node::Pow(b, e) => pow_f64(get(b), get(e)),
                Node::Call(f, xs) => {
                    let args: Vec<f64> = xs.iter().map(get).collect();
                    f.eval(&args)
                }
            };
            cache[n.index()] = Some(value);
        }
        cache[id.index()].unwrap_or(f64::NAN)
    }

    /// Evaluates one node at a point (see [`Graph::eval_with`]).
    pub fn eval(&self, id: NodeId, env: &dyn Fn(Var) -> f64) -> f64 {
        self.eval_with(id, env, &mut Vec::new())
    }
}

/// `b^e` the way generated code computes it: integer exponents exactly by
/// `powi`, `0.5` as `sqrt`, otherwise `powf`.
pub fn pow_f64(b: f64, e: f64) -> f64 {
    if e == 0.5 {
        b.sqrt()
    } else if e == -0.5 {
        1.0 / b.sqrt()
    } else if e.fract() == 0.0 && e.abs() <= i32::MAX as f64 {
        b.powi(e as i32)
    } else {
        b.powf(e)
    }
}
