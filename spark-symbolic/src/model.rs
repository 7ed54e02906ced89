//! The symbolic model of one declaration: `L` and `k` lowered into the graph,
//! every derivative the runtime asks for, and the structure facts proved
//! from them (autonomy, constant mass matrix, separability, constraint form).

use crate::diff::Differentiator;
use crate::graph::{Deps, Graph, Node, NodeId, Var};
use crate::lower::Lowerer;
use crate::spec::{SpecError, SrcExpr, SystemSpec};
use proc_macro2::Span;
use std::collections::HashMap;

/// How the constraints depend on the velocities (mirrors
/// `spark_runtime::ConstraintForm`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ConstraintForm {
    /// No constraints.
    None,
    /// `k = K(t,q) v`.
    Linear,
    /// `k = K(t,q) v + b(t,q)`, `b ≢ 0`.
    Affine,
    /// Anything else.
    Nonlinear,
}

/// Structure facts (mirrors `spark_runtime::Structure`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Structure {
    /// `L` does not depend on `t`.
    pub lagrangian_autonomous: bool,
    /// `k` does not depend on `t`.
    pub constraints_autonomous: bool,
    /// `∇²_vv L` depends on parameters at most.
    pub constant_mass_matrix: bool,
    /// `∇_q L` free of `v` and `∇_v L` free of `q`.
    pub separable: bool,
    /// How `k` depends on `v`.
    pub constraint_form: ConstraintForm,
}

/// Row-major matrix of nodes.
pub type NodeMatrix = Vec<Vec<NodeId>>;

/// `L`, `k` and all their derivatives as graph nodes.
#[derive(Debug)]
pub struct Model {
    /// The graph holding every expression below.
    pub graph: Graph,
    /// Number of coordinates `N`.
    pub n: usize,
    /// Number of constraints `M`.
    pub m: usize,
    /// `L`.
    pub lagrangian: NodeId,
    /// `E = ∇_v L · v − L`.
    pub energy: NodeId,
    /// `P = ∇_v L`.
    pub momentum: Vec<NodeId>,
    /// `F = ∇_q L`.
    pub force: Vec<NodeId>,
    /// `k`.
    pub constraint: Vec<NodeId>,
    /// `R = −Kᵀψ`.
    pub constraint_force: Vec<NodeId>,
    /// `∂P/∂q` (`N × N`).
    pub momentum_q: NodeMatrix,
    /// `∂P/∂v = ∇²_vv L`.
    pub mass: NodeMatrix,
    /// `∂F/∂q`.
    pub force_q: NodeMatrix,
    /// `∂F/∂v`.
    pub force_v: NodeMatrix,
    /// `k_q` (`M × N`).
    pub constraint_q: NodeMatrix,
    /// `K = k_v` (`M × N`).
    pub constraint_v: NodeMatrix,
    /// `∂R/∂q`.
    pub constraint_force_q: NodeMatrix,
    /// `∂R/∂v`.
    pub constraint_force_v: NodeMatrix,
    /// `∂L/∂t`.
    pub lagrangian_t: NodeId,
    /// `∂P/∂t`.
    pub momentum_t: Vec<NodeId>,
    /// `∂F/∂t`.
    pub force_t: Vec<NodeId>,
    /// `k_t`.
    pub constraint_t: Vec<NodeId>,
    /// Proved structure (of `L` and `k`; the optional forces do not change it).
    pub structure: Structure,
    /// External force `f(t,q,v)`; empty when the system has none.
    pub external_force: Vec<NodeId>,
    /// `∂f/∂q` (empty when `f` is absent).
    pub external_force_q: NodeMatrix,
    /// `∂f/∂v`.
    pub external_force_v: NodeMatrix,
    /// Non-ideal constraint force `N(t,q,v,ψ)`; empty when absent.
    pub nonideal_force: Vec<NodeId>,
    /// `∂N/∂q`.
    pub nonideal_force_q: NodeMatrix,
    /// `∂N/∂v`.
    pub nonideal_force_v: NodeMatrix,
    /// `∂N/∂ψ` (`N × M`).
    pub nonideal_force_psi: NodeMatrix,
    /// Position-level residuals `g_i(t,q)` (zero for constraints not declared
    /// holonomic); empty when no constraint is.
    pub holonomic: Vec<NodeId>,
    /// Event functions `g_e(t,q,v)`, one per declared event.
    pub events: Vec<NodeId>,
    /// `∂g_e/∂t`.
    pub events_t: Vec<NodeId>,
    /// `∂g_e/∂q` (one row per event).
    pub events_q: NodeMatrix,
    /// `∂g_e/∂v`.
    pub events_v: NodeMatrix,
}

fn gradient(g: &mut Graph, d: &mut Differentiator, f: NodeId, vars: &[Var]) -> Vec<NodeId> {
    vars.iter().map(|&x| d.diff(g, f, x)).collect()
}

fn jacobian(g: &mut Graph, d: &mut Differentiator, fs: &[NodeId], vars: &[Var]) -> NodeMatrix {
    fs.iter().map(|&f| gradient(g, d, f, vars)).collect()
}

/// Replaces every variable of the kinds in `kinds` by zero.
pub fn substitute_zero(g: &mut Graph, node: NodeId, kinds: Deps, memo: &mut HashMap<NodeId, NodeId>) -> NodeId {
    if !g.deps(node).any(kinds) {
        return node;
    }
    if let Some(&r) = memo.get(&node) {
        return r;
    }
    let r = match g.node(node).clone() {
        Node::Const(_) => node,
        Node::Var(v) => {
            if v.dep().any(kinds) {
                g.constant(0.0)
            } else {
                node
            }
        }
        Node::Add(xs) => {
            let ys: Vec<NodeId> = xs.iter().map(|&x| substitute_zero(g, x, kinds, memo)).collect();
            g.add(&ys)
        }
        Node::Mul(xs) => {
            let ys: Vec<NodeId> = xs.iter().map(|&x| substitute_zero(g, x, kinds, memo)).collect();
            g.mul(&ys)
        }
        Node::Pow(b, e) => {
            let b = substitute_zero(g, b, kinds, memo);
            let e = substitute_zero(g, e, kinds, memo);
            g.pow(b, e)
        }
        Node::Call(f, xs) => {
            let ys: Vec<NodeId> = xs.iter().map(|&x| substitute_zero(g, x, kinds, memo)).collect();
            g.call(f, &ys)
        }
    };
    memo.insert(node, r);
    r
}

/// Degree of positive homogeneity of `x` in the velocities, if `x` is
/// homogeneous (`x(λv) = λ^d x(v)` for `λ > 0`).
fn velocity_degree(g: &Graph, x: NodeId, depth: usize) -> Option<f64> {
    if !g.deps(x).any(Deps::V) {
        return Some(0.0);
    }
    if depth > 500 {
        return None;
    }
    match g.node(x) {
        Node::Var(Var::V(_)) => Some(1.0),
        Node::Mul(xs) => xs.iter().map(|&f| velocity_degree(g, f, depth + 1)).sum(),
        Node::Add(xs) => {
            let d = velocity_degree(g, xs[0], depth + 1)?;
            xs[1..].iter().all(|&t| velocity_degree(g, t, depth + 1) == Some(d)).then_some(d)
        }
        Node::Pow(b, e) if !g.deps(*e).any(Deps::V) => {
            let e = g.as_const(*e)?;
            Some(velocity_degree(g, *b, depth + 1)? * e)
        }
        _ => None,
    }
}

/// `E = ∇_v L · v − L`, term by term: a term of `L` homogeneous of degree
/// `d` in `v` contributes `(d − 1)·term` (Euler's relation), so that the
/// energy of `T₂ − U` reads `T₂ + U`; other terms are differentiated.
fn energy(g: &mut Graph, d: &mut Differentiator, lagrangian: NodeId, vs: &[Var]) -> NodeId {
    let terms: Vec<NodeId> = match g.node(lagrangian) {
        Node::Add(xs) => xs.to_vec(),
        _ => vec![lagrangian],
    };
    let mut out = Vec::with_capacity(terms.len());
    for term in terms {
        match velocity_degree(g, term, 0) {
            Some(deg) => out.push(g.scale(deg - 1.0, term)),
            None => {
                let mut parts: Vec<NodeId> = vs
                    .iter()
                    .map(|&v| {
                        let dv = d.diff(g, term, v);
                        let vn = g.var(v);
                        g.mul2(dv, vn)
                    })
                    .collect();
                parts.push(g.neg(term));
                out.push(g.add(&parts));
            }
        }
    }
    g.add(&out)
}

/// Rows `kj` and `kl` of `K` are proportional: every 2 × 2 minor
/// `K_ja K_lb − K_jb K_la` simplifies to zero (neither row is zero: `build`
/// rejects constraints free of velocities).
fn proportional_rows(g: &mut Graph, kj: &[NodeId], kl: &[NodeId]) -> bool {
    let n = kj.len();
    for a in 0..n {
        for b in (a + 1)..n {
            let left = g.mul2(kj[a], kl[b]);
            let right = g.mul2(kj[b], kl[a]);
            let minor = g.sub(left, right);
            if !g.is_const(minor, 0.0) {
                return false;
            }
        }
    }
    true
}

/// The span of the first token of `e` as written (the leftmost leaf or
/// prefix operator), where an error about the whole expression points.
fn first_token(e: &SrcExpr) -> Span {
    match e {
        SrcExpr::Binary(_, a, _, _) => first_token(a),
        other => other.span(),
    }
}

/// `dg/dt = g_t + g_q·v` of a node `g(t,q,…)` over `n` coordinates.
fn total_time_derivative(g: &mut Graph, d: &mut Differentiator, node: NodeId, n: usize) -> NodeId {
    let mut terms = vec![d.diff(g, node, Var::Time)];
    for i in 0..n as u32 {
        let gq = d.diff(g, node, Var::Q(i));
        let vi = g.var(Var::V(i));
        terms.push(g.mul2(gq, vi));
    }
    g.add(&terms)
}

/// An error on the struct's name once `g` has outgrown
/// [`MAX_GRAPH_SIZE`](crate::graph::MAX_GRAPH_SIZE).
pub(crate) fn check_graph_size(spec: &SystemSpec, g: &Graph) -> Result<(), SpecError> {
    if !g.exhausted() {
        return Ok(());
    }
    Err(SpecError {
        span: spec.name.span(),
        message: format!(
            "the derivatives of `{}` grow beyond the engine's limit of {} nodes and operands \
             (spark_symbolic::graph::MAX_GRAPH_SIZE): differentiating twice multiplies the size of long products \
             and deep nestings (the second derivative of a product of k factors in one coordinate has about k³ \
             operands); expand such products, or split the expression using parameters",
            spec.name,
            crate::graph::MAX_GRAPH_SIZE
        ),
    })
}

/// The constraint rows `k`, in order, and for each holonomic row its
/// position-level `g` (`None` for a row written at velocity level). A
/// holonomic row's `k = g_t + g_q·v` is formed on the graph.
fn constraint_rows(
    g: &mut Graph,
    d: &mut Differentiator,
    lower: &mut Lowerer,
    spec: &SystemSpec,
) -> Result<(Vec<NodeId>, Vec<Option<NodeId>>), SpecError> {
    let mut rows = Vec::with_capacity(spec.constraints.len());
    let mut positions = Vec::with_capacity(spec.constraints.len());
    for c in &spec.constraints {
        let node = lower.lower(g, &c.expr)?;
        if !c.holonomic {
            rows.push(node);
            positions.push(None);
            continue;
        }
        if g.deps(node).any(Deps::V) || g.deps(node).any(Deps::PSI) {
            return Err(SpecError {
                span: c.expr.span(),
                message: "a holonomic constraint g(t, q) = 0 may not involve velocities".into(),
            });
        }
        rows.push(total_time_derivative(g, d, node, spec.coordinates.len()));
        positions.push(Some(node));
    }
    Ok((rows, positions))
}

/// The residuals `g` of the holonomic rows (0 for the others); empty when
/// no row is holonomic.
fn holonomic_residuals(g: &mut Graph, positions: &[Option<NodeId>]) -> Vec<NodeId> {
    if positions.iter().all(Option::is_none) {
        return Vec::new();
    }
    positions.iter().map(|p| p.unwrap_or_else(|| g.constant(0.0))).collect()
}

/// The longest velocity-level form of a holonomic constraint, in
/// characters, that its error message quotes.
const MAX_QUOTED_DERIVATIVE: usize = 400;

/// Rejects a constraint row free of velocities: it is holonomic (the error
/// suggests its velocity-level form) or constrains no motion at all.
fn reject_velocity_free_rows(
    g: &mut Graph,
    d: &mut Differentiator,
    spec: &SystemSpec,
    constraint: &[NodeId],
    constraint_v: &NodeMatrix,
) -> Result<(), SpecError> {
    for (j, row) in constraint_v.iter().enumerate() {
        if !row.iter().all(|&x| g.is_const(x, 0.0)) {
            continue;
        }
        // Suggest the velocity-level constraint dg/dt = g_t + g_q·v.
        let gdot = total_time_derivative(g, d, constraint[j], spec.coordinates.len());
        let number = j + 1;
        let holonomic = spec.constraints[j].holonomic;
        if holonomic || !g.deps(gdot).any(Deps::V) {
            // No coordinate enters: differentiating gives no velocity
            // either, so no velocity-level form exists to suggest.
            let what = if holonomic {
                format!("constraint {number} comes from a holonomic constraint g(t) = 0 that involves no coordinate")
            } else if g.is_const(constraint[j], 0.0) {
                format!("constraint {number} is identically 0")
            } else if g.deps(constraint[j]).any(Deps::T) {
                format!(
                    "constraint {number} depends only on the time `t` (and parameters), not on the coordinates or \
                     velocities"
                )
            } else {
                format!("constraint {number} involves neither the coordinates nor the velocities")
            };
            return Err(SpecError {
                span: spec.constraints[j].span,
                message: format!(
                    "{what}: no motion can satisfy or violate it, so it cannot be a velocity constraint (and its \
                     time derivative has no velocity either); remove it"
                ),
            });
        }
        // A long derivative is not quoted: a message should stay readable
        // whatever the size of the declaration.
        let derivative = crate::pretty::dsl_text(g, spec, gdot);
        let derivative = if derivative.chars().count() <= MAX_QUOTED_DERIVATIVE {
            format!(": `{derivative}`")
        } else {
            format!(" ({} characters long, too long to quote here)", derivative.chars().count())
        };
        let hint = format!(
            "write its time derivative instead, the velocity-level constraint g_t + g_q·v{derivative} (or declare \
             `name: holonomic(g)` under `effects:` and select it in a scene, which imposes that derivative and \
             reports the drift of g)"
        );
        return Err(SpecError {
            span: spec.constraints[j].span,
            message: format!(
                "constraint {number} does not depend on the velocities: it is holonomic (a position constraint \
                 g(t, q) = 0), which this integrator does not take directly; {hint}"
            ),
        });
    }
    Ok(())
}

/// `R = −Kᵀψ`, one entry per coordinate.
fn constraint_force(g: &mut Graph, constraint_v: &NodeMatrix, n: usize) -> Vec<NodeId> {
    let mut r = Vec::with_capacity(n);
    for i in 0..n {
        let terms: Vec<NodeId> = constraint_v
            .iter()
            .enumerate()
            .map(|(j, row)| {
                let psi = g.var(Var::Psi(j as u32));
                g.mul2(row[i], psi)
            })
            .collect();
        let s = g.add(&terms);
        r.push(g.neg(s));
    }
    r
}

/// The structure facts of `L` and `k` (the optional forces do not change
/// them).
fn prove_structure(
    g: &mut Graph,
    lagrangian: NodeId,
    constraint: &[NodeId],
    constraint_v: &NodeMatrix,
    momentum: &[NodeId],
    force: &[NodeId],
    mass: &NodeMatrix,
) -> Structure {
    let free_of = |g: &Graph, xs: &[NodeId], kinds: Deps| xs.iter().all(|&x| !g.deps(x).any(kinds));
    let constraint_form = if constraint.is_empty() {
        ConstraintForm::None
    } else if constraint_v.iter().all(|row| free_of(g, row, Deps::V)) {
        let mut memo = HashMap::new();
        let b: Vec<NodeId> = constraint.iter().map(|&k| substitute_zero(g, k, Deps::V, &mut memo)).collect();
        if b.iter().all(|&x| g.is_const(x, 0.0)) {
            ConstraintForm::Linear
        } else {
            ConstraintForm::Affine
        }
    } else {
        ConstraintForm::Nonlinear
    };
    Structure {
        lagrangian_autonomous: !g.deps(lagrangian).any(Deps::T),
        constraints_autonomous: free_of(g, constraint, Deps::T),
        constant_mass_matrix: mass.iter().all(|row| row.iter().all(|&x| g.deps(x).parameters_only())),
        separable: free_of(g, force, Deps::V) && free_of(g, momentum, Deps::Q),
        constraint_form,
    }
}

/// The components of a force block (`None` = 0); empty when absent.
fn lower_components(g: &mut Graph, lower: &mut Lowerer, xs: &[Option<SrcExpr>]) -> Result<Vec<NodeId>, SpecError> {
    xs.iter()
        .map(|x| match x {
            Some(x) => lower.lower(g, x),
            None => Ok(g.constant(0.0)),
        })
        .collect()
}

impl Model {
    /// Whether `L` is separable and its stiffness `∂(∇_q L)/∂q` is a
    /// constant matrix (it may depend on parameters) that is not identically
    /// zero, as for a quadratic potential: the stage-decoupled Newton matrix
    /// then keeps the couplings it makes between stages exactly.
    pub fn constant_stiffness(&self) -> bool {
        let g = &self.graph;
        let entries = || self.force_q.iter().flatten();
        self.structure.separable
            && entries().all(|&x| g.deps(x).parameters_only())
            && !entries().all(|&x| g.is_const(x, 0.0))
    }

    /// Whether `L` is separable and its stiffness `∂(∇_q L)/∂q` is diagonal
    /// (every off-diagonal entry simplifies to 0), depends on the
    /// configuration and is not identically zero, as for a potential that is
    /// a sum of functions of one coordinate each (the mobile robot's
    /// `10 sin φ`): the stage-decoupled Newton matrix then keeps the
    /// couplings between stages that the stiffness at each stage point makes.
    pub fn diagonal_stiffness(&self) -> bool {
        let g = &self.graph;
        let off_diagonal_zero = self
            .force_q
            .iter()
            .enumerate()
            .all(|(r, row)| row.iter().enumerate().all(|(c, &x)| r == c || g.is_const(x, 0.0)));
        self.structure.separable
            && off_diagonal_zero
            && !self.constant_stiffness()
            && !self.force_q.iter().flatten().all(|&x| g.is_const(x, 0.0))
    }

    /// Rejects declarations whose equations of motion cannot determine the
    /// accelerations at any point, because the SPARK Newton matrix (and the
    /// saddle-point matrix `[[∇²_vv L, Kᵀ],[K, 0]]` of paper assumption 2.4)
    /// is singular by construction:
    ///
    /// - more constraints than coordinates (`M > N`);
    /// - a coordinate whose velocity appears neither in the mass matrix nor
    ///   in any constraint: the column of `v₁[i]` in the step's Newton matrix
    ///   is `[∇²_vv L; K]` column `i`, identically zero;
    /// - `∇²_vv L ≡ 0` (no velocity term in `L`, or only linear ones): the
    ///   momenta do not depend on the velocities, against the regularity the
    ///   methods assume (paper §2). With no velocity term at all, the
    ///   `(s + 1)N` momentum rows are linear combinations of the `sN` values
    ///   `F_j + R_j`, so the Newton matrix is singular for every tableau;
    /// - fewer velocities with inertia than `N − M`: the columns of `v₁` are
    ///   `[∇²_vv L; K]`, whose rank is at most the number of nonzero columns
    ///   of `∇²_vv L` plus `M`;
    /// - a coordinate without inertia whose velocity a constraint fixes: the
    ///   saddle-point matrix may be regular, but the step's momentum rows of
    ///   that coordinate are dependent (Gauss: exactly, up to the quadrature
    ///   error of its momentum), so Newton fails or returns a wrong step;
    /// - two constraints whose rows of `K = ∂k/∂v` are proportional (every
    ///   2 × 2 minor simplifies to 0), so `K` never has full rank.
    ///
    /// Only structural zeros and identities the simplifier proves are used,
    /// so a declaration that passes may still be singular at some points
    /// (the runtime reports those), but one that fails is singular everywhere.
    pub fn check_determined(&self, spec: &SystemSpec) -> Result<(), SpecError> {
        let name = spec.name.to_string();
        let (n, m) = (self.n, self.m);
        if m > n {
            return Err(SpecError {
                span: spec.constraints[n].span,
                message: format!(
                    "`{name}` has {m} constraints on {n} coordinates: at most {n} velocity constraints can be \
                     independent, so the matrix [[∇²_vv L, Kᵀ],[K, 0]] is singular everywhere and no step can be \
                     solved; remove the constraints that follow from the others (constraint {} onwards is one too many)",
                    n + 1
                ),
            });
        }
        let g = &self.graph;
        if self.mass.iter().flatten().all(|&x| g.is_const(x, 0.0)) {
            let how = if self.momentum.iter().all(|&p| g.is_const(p, 0.0)) {
                "has no velocity term"
            } else {
                "is at most linear in the velocities"
            };
            let c = &spec.coordinates[0].name;
            return Err(SpecError {
                span: first_token(&spec.lagrangian),
                message: format!(
                    "the Lagrangian of `{name}` {how}, so its mass matrix ∇²_vv L is identically 0: the momenta ∇_v L \
                     do not depend on the velocities, and the integrators need a regular Lagrangian (∇²_vv L \
                     nonsingular, paper §2) for the momentum equations of a step to determine its velocities; add \
                     a kinetic energy, e.g. `m/2*dot({c})^2 + …` for every coordinate (with a parameter `m`)"
                ),
            });
        }
        for (i, coordinate) in spec.coordinates.iter().enumerate() {
            let no_mass = (0..n).all(|j| g.is_const(self.mass[j][i], 0.0));
            let no_constraint = self.constraint_v.iter().all(|row| g.is_const(row[i], 0.0));
            if no_mass && no_constraint {
                let c = &coordinate.name;
                let how = if g.is_const(self.momentum[i], 0.0) {
                    format!("`dot({c})` appears neither in the Lagrangian nor in any constraint")
                } else {
                    format!(
                        "the Lagrangian is at most linear in `dot({c})` (∂²L/∂dot({c})∂dot(q) = 0) and no constraint \
                         involves `dot({c})`"
                    )
                };
                return Err(SpecError {
                    span: coordinate.span,
                    message: format!(
                        "coordinate `{c}` of `{name}` has no inertia: {how}, so nothing determines its acceleration \
                         and the Newton matrix of every step is singular; give it a kinetic energy term, e.g. \
                         `+ inertia/2*dot({c})^2` (with a parameter `inertia`), constrain its velocity, or remove it"
                    ),
                });
            }
        }
        // The columns of v₁ are [∇²_vv L; K]: their rank is at most the
        // number of nonzero columns of ∇²_vv L plus M.
        let (inertial, inert): (Vec<usize>, Vec<usize>) =
            (0..n).partition(|&i| (0..n).any(|j| !g.is_const(self.mass[j][i], 0.0)));
        if inertial.len() + m < n {
            let names = |ix: &[usize], velocity: bool| {
                let one = |i: usize| {
                    let c = &spec.coordinates[i].name;
                    if velocity {
                        format!("`dot({c})`")
                    } else {
                        format!("`{c}`")
                    }
                };
                ix.iter().map(|&i| one(i)).collect::<Vec<_>>().join(", ")
            };
            let example = &spec.coordinates[inert[0]].name;
            let count =
                |k: usize, one: &str, many: &str| if k == 1 { format!("1 {one}") } else { format!("{k} {many}") };
            let constraints = count(m, "constraint", "constraints");
            let inertia = count(inertial.len(), "velocity", "velocities");
            let what = format!(
                "the mass matrix ∇²_vv L of `{name}` involves only {}, and {inertia} with inertia plus {constraints}",
                names(&inertial, true)
            );
            let coordinates = count(inert.len(), "coordinate", "coordinates");
            return Err(SpecError {
                span: first_token(&spec.lagrangian),
                message: format!(
                    "{what} cannot determine {n} accelerations, so the \
                     matrix [[∇²_vv L, Kᵀ],[K, 0]] is singular everywhere and no step can be solved; give the \
                     {coordinates} {} a kinetic energy term, e.g. `+ inertia/2*dot({example})^2` (with a parameter \
                     `inertia`), or constrain more velocities",
                    names(&inert, false),
                ),
            });
        }
        // A constraint that fixes the velocity of a coordinate `c` without
        // inertia determines the motion but not a step: `c`'s component of
        // `∇_v L` is a function of `(t, q)` alone, and for Gauss (`Â = Ã = A`,
        // `b̂ = b̃ = b`) the momentum row of `c` at the step's end is `bᵀA⁻¹`
        // times its stage rows up to the quadrature error of that function, so
        // the Newton matrix is singular, or so ill-conditioned that a step it
        // solves lands anywhere on a family of near-solutions.
        for (i, coordinate) in spec.coordinates.iter().enumerate() {
            if (0..n).all(|j| g.is_const(self.mass[j][i], 0.0)) {
                let c = &coordinate.name;
                let how = if g.is_const(self.momentum[i], 0.0) {
                    format!("`dot({c})` appears only in constraints")
                } else {
                    format!("the Lagrangian is at most linear in `dot({c})` (∂²L/∂dot({c})∂dot(q) = 0)")
                };
                return Err(SpecError {
                    span: coordinate.span,
                    message: format!(
                        "coordinate `{c}` of `{name}` has no inertia: {how}, so the mass matrix ∇²_vv L is singular \
                         everywhere. A constraint fixes the velocity of `{c}` but not the step: the integrators need a \
                         regular Lagrangian (∇²_vv L nonsingular, paper §2), and without it the momentum equations of \
                         `{c}` at the stages and at the step's end are dependent, so the Newton matrix of a step is \
                         singular or so ill-conditioned that a step it solves is wrong; give `{c}` a kinetic energy \
                         term, e.g. `+ inertia/2*dot({c})^2` (with a parameter `inertia`), or remove it and compute \
                         it from the other coordinates after the run"
                    ),
                });
            }
        }
        // The minors are built in a scratch copy: the graph handed to code
        // generation stays exactly what `build` made.
        let mut scratch = (m > 1).then(|| self.graph.clone());
        for j in 0..m {
            for l in 0..j {
                let what = if self.constraint[j] == self.constraint[l] {
                    "is the same expression as"
                } else if scratch
                    .as_mut()
                    .is_some_and(|g| proportional_rows(g, &self.constraint_v[j], &self.constraint_v[l]))
                {
                    "has its row of K = ∂k/∂v proportional to that of"
                } else {
                    continue;
                };
                return Err(SpecError {
                    span: spec.constraints[j].span,
                    message: format!(
                        "constraint {} of `{name}` {what} constraint {}: dependent constraints make the matrix \
                         [[∇²_vv L, Kᵀ],[K, 0]] singular everywhere; remove one of them",
                        j + 1,
                        l + 1
                    ),
                });
            }
        }
        Ok(())
    }

    /// Lowers `spec` and takes every derivative. Fails with a span on the
    /// offending expression (bad constant, holonomic constraint), or on the
    /// struct's name when the derivatives outgrow
    /// [`MAX_GRAPH_SIZE`](crate::graph::MAX_GRAPH_SIZE).
    pub fn build(spec: &SystemSpec) -> Result<Model, SpecError> {
        let mut g = Graph::new();
        let built = Self::build_in(spec, &mut g);
        // Past the limit the graph answers every new node with 0: whatever
        // the build concluded from that (an error too) is meaningless.
        check_graph_size(spec, &g)?;
        let mut model = built?;
        model.graph = g;
        model.reject_nonfinite(spec)?;
        Ok(model)
    }

    /// [`build`](Self::build) in the graph `g`; the model's own graph is
    /// left empty.
    fn build_in(spec: &SystemSpec, g: &mut Graph) -> Result<Model, SpecError> {
        let n = spec.coordinates.len();
        let m = spec.constraints.len();
        if n == 0 {
            return Err(SpecError {
                span: spec.name.span(),
                message: "a system needs at least one generalized coordinate".into(),
            });
        }
        let mut lower = Lowerer::new(spec);
        let mut d = Differentiator::new();
        let lagrangian = lower.lower(g, &spec.lagrangian)?;
        let (constraint, positions) = constraint_rows(g, &mut d, &mut lower, spec)?;
        let qs: Vec<Var> = (0..n as u32).map(Var::Q).collect();
        let vs: Vec<Var> = (0..n as u32).map(Var::V).collect();
        let momentum = gradient(g, &mut d, lagrangian, &vs);
        let force = gradient(g, &mut d, lagrangian, &qs);
        let constraint_q = jacobian(g, &mut d, &constraint, &qs);
        let constraint_v = jacobian(g, &mut d, &constraint, &vs);
        reject_velocity_free_rows(g, &mut d, spec, &constraint, &constraint_v)?;
        let r = constraint_force(g, &constraint_v, n);
        let momentum_q = jacobian(g, &mut d, &momentum, &qs);
        let mass = jacobian(g, &mut d, &momentum, &vs);
        let force_q = jacobian(g, &mut d, &force, &qs);
        let force_v = jacobian(g, &mut d, &force, &vs);
        let constraint_force_q = jacobian(g, &mut d, &r, &qs);
        let constraint_force_v = jacobian(g, &mut d, &r, &vs);
        let lagrangian_t = d.diff(g, lagrangian, Var::Time);
        let momentum_t: Vec<NodeId> = momentum.iter().map(|&p| d.diff(g, p, Var::Time)).collect();
        let force_t: Vec<NodeId> = force.iter().map(|&f| d.diff(g, f, Var::Time)).collect();
        let constraint_t: Vec<NodeId> = constraint.iter().map(|&k| d.diff(g, k, Var::Time)).collect();
        let energy = energy(g, &mut d, lagrangian, &vs);
        let structure = prove_structure(g, lagrangian, &constraint, &constraint_v, &momentum, &force, &mass);
        // The optional effects are lowered last, so that a declaration without
        // them builds exactly the graph (and node order) it would build alone.
        let external_force = lower_components(g, &mut lower, &spec.external_force)?;
        let nonideal_force = lower_components(g, &mut lower, &spec.nonideal_force)?;
        for (i, &f) in external_force.iter().enumerate() {
            if g.deps(f).any(Deps::PSI) {
                let span = spec.external_force[i].as_ref().map_or(spec.name.span(), |x| x.span());
                return Err(SpecError {
                    span,
                    message: "an external force may not depend on multipliers; declare it as a non-ideal force".into(),
                });
            }
        }
        let psis: Vec<Var> = (0..m as u32).map(Var::Psi).collect();
        let external_force_q = jacobian(g, &mut d, &external_force, &qs);
        let external_force_v = jacobian(g, &mut d, &external_force, &vs);
        let nonideal_force_q = jacobian(g, &mut d, &nonideal_force, &qs);
        let nonideal_force_v = jacobian(g, &mut d, &nonideal_force, &vs);
        let nonideal_force_psi = jacobian(g, &mut d, &nonideal_force, &psis);
        let holonomic = holonomic_residuals(g, &positions);
        let mut events = Vec::with_capacity(spec.events.len());
        for e in &spec.events {
            events.push(lower.lower(g, &e.expr)?);
        }
        let events_t: Vec<NodeId> = events.iter().map(|&x| d.diff(g, x, Var::Time)).collect();
        let events_q = jacobian(g, &mut d, &events, &qs);
        let events_v = jacobian(g, &mut d, &events, &vs);
        Ok(Model {
            graph: Graph::new(),
            n,
            m,
            lagrangian,
            energy,
            momentum,
            force,
            constraint,
            constraint_force: r,
            momentum_q,
            mass,
            force_q,
            force_v,
            constraint_q,
            constraint_v,
            constraint_force_q,
            constraint_force_v,
            lagrangian_t,
            momentum_t,
            force_t,
            constraint_t,
            structure,
            external_force,
            external_force_q,
            external_force_v,
            nonideal_force,
            nonideal_force_q,
            nonideal_force_v,
            nonideal_force_psi,
            holonomic,
            events,
            events_t,
            events_q,
            events_v,
        })
    }

    /// Refuses a model whose derivatives hold a number beyond the range of
    /// f64: differentiation multiplies exponents into coefficients, so a
    /// finite declaration such as `x^1e300` has the coefficient
    /// `1e300·(1e300 − 1) = inf` in its second derivative, which generated
    /// code cannot write. The error points at the expression whose
    /// derivatives overflow.
    fn reject_nonfinite(&self, spec: &SystemSpec) -> Result<(), SpecError> {
        let bad = self.graph.nonfinite_nodes();
        let some = |ids: &[NodeId]| ids.iter().any(|x| bad[x.index()]);
        let matrix = |m: &NodeMatrix| m.iter().any(|row| some(row));
        let row = |m: &NodeMatrix, i: usize| m.get(i).is_some_and(|row| some(row));
        let at = |ids: &[NodeId], i: usize| ids.get(i).is_some_and(|x| bad[x.index()]);
        let refuse = |span: Span, what: &str| SpecError {
            span,
            message: format!(
                "differentiating {what} gives a number beyond the range of f64 (±1.8e308): the derivatives \
                 multiply exponents and constants into their coefficients (the second derivative of `x^1e300` \
                 has the coefficient 1e300·(1e300 − 1)), so the generated code would compute `inf` or `NaN`; \
                 use smaller exponents and constants (rescale the units)"
            ),
        };
        if some(&[self.lagrangian, self.energy, self.lagrangian_t])
            || [&self.momentum, &self.force, &self.momentum_t, &self.force_t].into_iter().any(|v| some(v))
            || [&self.momentum_q, &self.mass, &self.force_q, &self.force_v].into_iter().any(matrix)
        {
            return Err(refuse(first_token(&spec.lagrangian), "the Lagrangian"));
        }
        for (j, c) in spec.constraints.iter().enumerate() {
            if at(&self.constraint, j)
                || at(&self.constraint_t, j)
                || row(&self.constraint_q, j)
                || row(&self.constraint_v, j)
            {
                return Err(refuse(c.span, &format!("constraint {}", j + 1)));
            }
        }
        if some(&self.constraint_force)
            || some(&self.holonomic)
            || matrix(&self.constraint_force_q)
            || matrix(&self.constraint_force_v)
        {
            // The force −Kᵀψ mixes the rows: find the row whose own second
            // derivatives (or position-level form) overflow, on a copy.
            let holonomic_row =
                |k: usize| (0..spec.constraints.len()).filter(|&j| spec.constraints[j].holonomic).nth(k);
            let mut g = self.graph.clone();
            let mut d = Differentiator::new();
            let vars: Vec<Var> = (0..self.n as u32).flat_map(|i| [Var::Q(i), Var::V(i)]).collect();
            let row = (0..self.m)
                .find(|&j| {
                    let kv = self.constraint_v.get(j).cloned().unwrap_or_default();
                    let second = jacobian(&mut g, &mut d, &kv, &vars);
                    let bad = g.nonfinite_nodes();
                    second.iter().flatten().any(|x| bad[x.index()])
                })
                .or_else(|| self.holonomic.iter().position(|x| bad[x.index()]).and_then(holonomic_row));
            return Err(match row.and_then(|j| spec.constraints.get(j).map(|c| (j, c))) {
                Some((j, c)) => refuse(c.span, &format!("constraint {}", j + 1)),
                None => refuse(spec.constraints.first().map_or(spec.name.span(), |c| c.span), "the constraints"),
            });
        }
        let forces = |source: &[Option<SrcExpr>], values: &[NodeId], matrices: &[&NodeMatrix]| match (0..values.len())
            .find(|&i| at(values, i) || matrices.iter().any(|m| row(m, i)))
        {
            Some(i) => {
                let span = source.get(i).and_then(Option::as_ref).map_or(spec.name.span(), first_token);
                Err(refuse(span, "this force"))
            }
            None => Ok(()),
        };
        forces(&spec.external_force, &self.external_force, &[&self.external_force_q, &self.external_force_v])?;
        forces(
            &spec.nonideal_force,
            &self.nonideal_force,
            &[&self.nonideal_force_q, &self.nonideal_force_v, &self.nonideal_force_psi],
        )?;
        for (i, e) in spec.events.iter().enumerate() {
            if at(&self.events, i) || at(&self.events_t, i) || row(&self.events_q, i) || row(&self.events_v, i) {
                return Err(refuse(first_token(&e.expr), &format!("event `{}`", e.name.name)));
            }
        }
        // Anything else code generation reads was built from the above.
        Ok(())
    }
}
