//! Where the step's equations are not affine in their unknowns: the pairs
//! of variable groups whose mixed second derivative in some function of the
//! step is not identically zero, and the coordinates whose position enters
//! the force or the constraint force (the columns the stage-decoupled
//! Newton matrix approximates).
//!
//! The SPARK residual is a sum of the momentum `p`, the force `F`, the
//! constraint `k`, the constraint force `R = −Kᵀψ` and the optional external
//! and non-ideal forces, each evaluated at points `(t, Q, V, Ψ)` that are
//! affine in the step's unknowns, coordinate by coordinate: `Q_i` and `V_i`
//! of coordinate `c` depend only on the stage velocities of coordinate `c`,
//! `Ψ_i` of constraint `j` only on the multipliers of constraint `j`. So the
//! unknowns fall into groups (coordinate `c`, numbered `c`; constraint `j`,
//! numbered `N + j`), and the residual's second derivative in the unknowns
//! of groups `a` and `b` vanishes unless some first derivative `∂g/∂x`, `x`
//! in group `a`, depends on a variable of group `b`. The pairs are read off
//! the model's Jacobian entries: exact where the simplifier proves an entry
//! free of a variable, conservative where it does not.
//!
//! The runtime uses them to accept a Newton update that moved no unknown
//! of a curved pair: the equations are affine along it, so an update
//! computed with the exact matrix at its starting iterate lands on the
//! solution up to the linear solve's round-off.

use crate::graph::{Graph, Node, NodeId, Var};
use crate::model::{Model, NodeMatrix};
use std::collections::BTreeSet;

/// The nonlinearity of one model (mirrors `spark_runtime::Nonlinearity`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Nonlinearity {
    /// Pairs `(a, b)`, `a ≤ b`, of groups (coordinates `0..N`, constraints
    /// `N..N+M`) in which some function of the step has a mixed second
    /// derivative that is not identically zero; `(a, a)` when it is not
    /// affine in group `a` alone. Sorted.
    pub pairs: Vec<(u32, u32)>,
    /// Some set of groups covers every pair, and its rows (the momentum
    /// rows of its coordinates, the constraint rows of its constraints) are
    /// affine in, and depend only on, its own groups.
    pub closed_affine_cover: bool,
    /// Coordinates `c` whose column of the stiffness `∂F/∂q` is not
    /// identically zero. Sorted.
    pub stiffness_columns: Vec<u32>,
    /// Coordinates `c` whose column of `∂R/∂q` (`R = −Kᵀψ`) is not
    /// identically zero. Sorted.
    pub constraint_force_columns: Vec<u32>,
}

/// The group of a variable: coordinate `i` for `q_i` and `v_i`, `n + j` for
/// `ψ_j`; `None` for the time and the parameters (not unknowns of a step).
fn group(var: Var, n: usize) -> Option<u32> {
    match var {
        Var::Q(i) | Var::V(i) => Some(i),
        Var::Psi(j) => Some(n as u32 + j),
        Var::Time | Var::P(_) => None,
    }
}

/// Which variable an entry of a Jacobian block differentiates by.
#[derive(Clone, Copy)]
enum By {
    /// Coordinate `c` of the entry's column (`∂/∂q_c` or `∂/∂v_c`).
    Column,
    /// The multiplier of the entry's column (`∂N/∂ψ`).
    MultiplierColumn,
    /// The multiplier of the entry's row (`K` read as `−∂R/∂ψ`).
    MultiplierRow,
}

/// The groups each node depends on, memoized over the graph.
struct Groups<'g> {
    graph: &'g Graph,
    n: usize,
    memo: Vec<Option<Box<[u32]>>>,
}

impl<'g> Groups<'g> {
    fn new(graph: &'g Graph, n: usize) -> Self {
        Groups { graph, n, memo: vec![None; graph.len()] }
    }

    /// The sorted groups `id` depends on (iterative post-order, so deep
    /// graphs cannot overflow the stack).
    fn of(&mut self, id: NodeId) -> &[u32] {
        let mut stack = vec![(id, false)];
        while let Some((node, expanded)) = stack.pop() {
            if self.memo[node.index()].is_some() {
                continue;
            }
            let children: Vec<NodeId> = match self.graph.node(node) {
                Node::Const(_) | Node::Var(_) => Vec::new(),
                Node::Add(xs) | Node::Mul(xs) | Node::Call(_, xs) => xs.to_vec(),
                Node::Pow(b, e) => vec![*b, *e],
            };
            if !expanded && children.iter().any(|c| self.memo[c.index()].is_none()) {
                stack.push((node, true));
                stack.extend(children.iter().map(|&c| (c, false)));
                continue;
            }
            let mut set = BTreeSet::new();
            if let Node::Var(v) = self.graph.node(node) {
                set.extend(group(*v, self.n));
            }
            for c in &children {
                set.extend(self.memo[c.index()].as_deref().unwrap_or(&[]).iter().copied());
            }
            self.memo[node.index()] = Some(set.into_iter().collect());
        }
        self.memo[id.index()].as_deref().unwrap_or(&[])
    }
}

impl Nonlinearity {
    /// Reads the pairs and the positions off `model`'s first derivatives.
    pub fn of(model: &Model) -> Nonlinearity {
        let (n, m) = (model.n, model.m);
        let mut groups = Groups::new(&model.graph, n);
        let mut pairs = BTreeSet::new();
        // Every Jacobian block of a function of the step, with what names
        // the variable each entry differentiates by and whether its rows
        // are the constraint rows (the others: the momentum rows of a
        // coordinate).
        let blocks = [
            (&model.momentum_q, By::Column, false),
            (&model.mass, By::Column, false),
            (&model.force_q, By::Column, false),
            (&model.force_v, By::Column, false),
            (&model.constraint_q, By::Column, true),
            (&model.constraint_v, By::Column, true),
            (&model.constraint_force_q, By::Column, false),
            (&model.constraint_force_v, By::Column, false),
            (&model.external_force_q, By::Column, false),
            (&model.external_force_v, By::Column, false),
            (&model.nonideal_force_q, By::Column, false),
            (&model.nonideal_force_v, By::Column, false),
            (&model.nonideal_force_psi, By::MultiplierColumn, false),
            // `∂R_c/∂ψ_j = −K_jc`: entry (j, c) of `K` is also the
            // derivative of coordinate `c`'s constraint force by `ψ_j`.
            (&model.constraint_v, By::MultiplierRow, false),
        ];
        // The groups the rows of each group depend on, and whether they are
        // affine (every first derivative free of the unknowns).
        let mut row_deps = vec![BTreeSet::new(); n + m];
        let mut row_affine = vec![true; n + m];
        for (block, by, constraint_rows) in blocks {
            for (r, row) in block.iter().enumerate() {
                for (c, &entry) in row.iter().enumerate() {
                    let (row_group, a) = match by {
                        By::Column if constraint_rows => (n + r, c as u32),
                        By::Column => (r, c as u32),
                        By::MultiplierColumn => (r, (n + c) as u32),
                        By::MultiplierRow => (c, (n + r) as u32),
                    };
                    if model.graph.is_const(entry, 0.0) {
                        continue;
                    }
                    let depends = groups.of(entry);
                    row_affine[row_group] &= depends.is_empty();
                    row_deps[row_group].insert(a);
                    for &b in depends {
                        row_deps[row_group].insert(b);
                        pairs.insert((a.min(b), a.max(b)));
                    }
                }
            }
        }
        // The largest set of groups with affine rows that depend on its own
        // groups only: remove any group whose rows reach outside, until
        // none does.
        let mut closed: BTreeSet<u32> = (0..n + m).filter(|&g| row_affine[g]).map(|g| g as u32).collect();
        while let Some(&g) = closed.iter().find(|&&g| !row_deps[g as usize].is_subset(&closed)) {
            closed.remove(&g);
        }
        let closed_affine_cover = pairs.iter().all(|(a, b)| closed.contains(a) || closed.contains(b));
        debug_assert!(pairs.iter().all(|&(_, b)| (b as usize) < n + m));
        let columns = |block: &NodeMatrix| -> Vec<u32> {
            let nonzero = |c: usize| block.iter().any(|row| !model.graph.is_const(row[c], 0.0));
            (0..n).filter(|&c| nonzero(c)).map(|c| c as u32).collect()
        };
        Nonlinearity {
            pairs: pairs.into_iter().collect(),
            closed_affine_cover,
            stiffness_columns: columns(&model.force_q),
            constraint_force_columns: columns(&model.constraint_force_q),
        }
    }
}
