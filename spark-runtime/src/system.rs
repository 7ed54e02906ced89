//! The system trait: everything the SPARK stepper needs to know about a
//! nonholonomic Lagrangian system `L(t,q,v)`, `0 = k(t,q,v)`.
//!
//! `nonholonomic_system!` generates implementations of [`NonholonomicSystem`];
//! hand-written implementations are allowed (tests use them as references).
//! Sign conventions follow the paper (eq. 6.1): the *momentum* is
//! `p = ∇_v L`, the *force* is `F = ∇_q L`, and the *constraint force* of a
//! multiplier `ψ` is `R = −K(t,q,v)ᵀψ` with `K = k_v`.
//!
//! Optional effects (external forcing `f(t,q,v)`, a non-ideal constraint
//! force `N(t,q,v,ψ)`, holonomic drift residuals `g(t,q)`) are associated
//! consts plus default methods returning zeros, so existing implementations
//! compile unchanged and the stepper skips them on a constant branch.

use nalgebra::{SMatrix, SVector};

/// Column vector of `f64` with `N` entries, on the stack.
pub type Vector<const N: usize> = SVector<f64, N>;
/// `R × C` matrix of `f64`, on the stack.
pub type Matrix<const R: usize, const C: usize> = SMatrix<f64, R, C>;

/// How the constraints `k(t,q,v)` depend on the velocities `v`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum ConstraintForm {
    /// The system has no constraints (`M = 0`).
    None,
    /// `k = K(t,q) v`.
    Linear,
    /// `k = K(t,q) v + b(t,q)` with `b ≢ 0`.
    Affine,
    /// Anything else (Chetaev's rule, `K = ∂k/∂v`, applies).
    Nonlinear,
}

/// Structure facts the macro proved about a system; the runtime uses them to
/// skip work that cannot change.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Structure {
    /// `L` does not depend explicitly on `t`.
    pub lagrangian_autonomous: bool,
    /// `k` does not depend explicitly on `t`.
    pub constraints_autonomous: bool,
    /// `∇²_vv L` is independent of `(t,q,v)` (it may depend on parameters).
    pub constant_mass_matrix: bool,
    /// `∇_q L` is independent of `v` and `∇_v L` is independent of `q`
    /// (`L = T(t,v) − U(t,q)`), so `∂(∇_q L)/∂v = 0` and `∂(∇_v L)/∂q = 0`.
    pub separable: bool,
    /// How `k` depends on `v`.
    pub constraint_form: ConstraintForm,
}

impl Structure {
    /// Neither `L` nor `k` depends explicitly on time.
    pub const fn autonomous(&self) -> bool {
        self.lagrangian_autonomous && self.constraints_autonomous
    }
    /// `K = k_v` does not depend on `v` (no constraints, linear or affine).
    pub const fn constraint_matrix_velocity_free(&self) -> bool {
        !matches!(self.constraint_form, ConstraintForm::Nonlinear)
    }
}

/// Where a system's step equations are not affine in their unknowns, as
/// `nonholonomic_system!` proves it from the symbolic Jacobians.
///
/// The unknowns of a step fall into groups: coordinate `c` (numbered `c`:
/// the stage velocities `V_i[c]`, which `Q_i[c]` follows, and `v₁[c]`) and
/// constraint `j` (numbered `N + j`: its multipliers at every stage). The
/// residual's mixed second derivative in the unknowns of groups `a` and `b`
/// vanishes unless `(a, b)` is in [`pairs`](Self::pairs). So when a Newton
/// update leaves every group of some member of each pair unchanged, the
/// equations are affine along it, and an update computed with the exact
/// Jacobian at its starting iterate lands on the solution up to the linear
/// solve's round-off (see the stopping rule of [`Stepper::step`](crate::Stepper::step)).
///
/// A hand-written system may leave it out ([`NonholonomicSystem::NONLINEARITY`]
/// is `None`): its steps then confirm every update, as where the equations
/// are affine along none. A wrong declaration — a missing pair — makes the
/// stepper accept a step that is not converged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Nonlinearity {
    /// Pairs `(a, b)`, `a ≤ b`, of groups (coordinates `0..N`, constraints
    /// `N..N+M`) in which some function of the step — momentum, force,
    /// constraint, constraint force, external or non-ideal force — has a
    /// mixed second derivative that is not identically zero; `(a, a)` when
    /// it is not affine in group `a` alone.
    pub pairs: &'static [(u32, u32)],
    /// Some set of groups covers every pair, and its rows (the momentum
    /// rows of its coordinates, the constraint rows of its constraints) are
    /// affine in, and depend only on, its own groups. A Newton update with
    /// a matrix exact in those rows solves those groups exactly, so the next
    /// update, on factors evaluated at the new iterate, is accepted
    /// ([`affine_along`](crate::Stepper::step)): simplified Newton on the
    /// stage-decoupled matrix, whose refresh is cheap, refreshes its factors
    /// after a first update that was not, and when that update moved a
    /// curved pair it starts the next step from the refreshed factors (any
    /// factors of the matrix solve the cover's groups, whose rows are
    /// constant), saving the factorization at its guess. It only steers the
    /// iteration: a wrong `true` costs a factorization, never accuracy.
    pub closed_affine_cover: bool,
    /// Coordinates `c` whose column of the stiffness `∂F/∂q` is not
    /// identically zero: columns whose couplings between stages the
    /// stage-decoupled Newton matrix drops unless it keeps the stiffness.
    pub stiffness_columns: &'static [u32],
    /// Coordinates `c` whose column of `∂R/∂q` (`R = −Kᵀψ`, the constraint
    /// force) is not identically zero: columns whose couplings between
    /// stages the stage-decoupled Newton matrix drops.
    pub constraint_force_columns: &'static [u32],
}

/// Values at one stage point `(T_i, Q_i, V_i, Ψ_i)`: what one residual
/// evaluation of the SPARK equations needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageValues<const N: usize, const M: usize> {
    /// `P = ∇_v L(t,q,v)`.
    pub momentum: Vector<N>,
    /// `F = ∇_q L(t,q,v)`.
    pub force: Vector<N>,
    /// `k(t,q,v)`.
    pub constraint: Vector<M>,
    /// `R = −K(t,q,v)ᵀ ψ`.
    pub constraint_force: Vector<N>,
    /// The sine–cosine pairs the generated functions computed at this
    /// point, kept for the next evaluation there (a cache: it changes no
    /// value and compares equal; hand-written systems leave it alone).
    pub sin_cos_memo: crate::trig::SinCosMemo,
}

/// First derivatives of the [`StageValues`] with respect to `q` and `v`:
/// what one Newton Jacobian needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageJacobians<const N: usize, const M: usize> {
    /// `∂(∇_v L)/∂q`.
    pub momentum_q: Matrix<N, N>,
    /// `∂(∇_v L)/∂v = ∇²_vv L`, the mass matrix.
    pub mass: Matrix<N, N>,
    /// `∂(∇_q L)/∂q`.
    pub force_q: Matrix<N, N>,
    /// `∂(∇_q L)/∂v`.
    pub force_v: Matrix<N, N>,
    /// `k_q`.
    pub constraint_q: Matrix<M, N>,
    /// `K = k_v`.
    pub constraint_v: Matrix<M, N>,
    /// `∂R/∂q = −∂(Kᵀψ)/∂q`.
    pub constraint_force_q: Matrix<N, N>,
    /// `∂R/∂v = −∂(Kᵀψ)/∂v`.
    pub constraint_force_v: Matrix<N, N>,
}

impl<const N: usize, const M: usize> StageValues<N, M> {
    /// All entries zero.
    pub fn zeros() -> Self {
        StageValues {
            momentum: Vector::zeros(),
            force: Vector::zeros(),
            constraint: Vector::zeros(),
            constraint_force: Vector::zeros(),
            sin_cos_memo: crate::trig::SinCosMemo::default(),
        }
    }
}

impl<const N: usize, const M: usize> StageJacobians<N, M> {
    /// All entries zero, as a value (`≈ 48·N²` bytes: for large `N` prefer
    /// [`boxed_zeros`](Self::boxed_zeros), which never touches the stack).
    pub fn zeros() -> Self {
        StageJacobians {
            momentum_q: Matrix::zeros(),
            mass: Matrix::zeros(),
            force_q: Matrix::zeros(),
            force_v: Matrix::zeros(),
            constraint_q: Matrix::zeros(),
            constraint_v: Matrix::zeros(),
            constraint_force_q: Matrix::zeros(),
            constraint_force_v: Matrix::zeros(),
        }
    }

    /// All entries zero, allocated zeroed on the heap directly: no
    /// `StageJacobians` value is built on the stack, so this works for any
    /// `N` on any thread (a value of `N = 257` alone is 3.2 MiB, more than a
    /// 2 MiB thread stack).
    pub fn boxed_zeros() -> Box<Self> {
        let layout = std::alloc::Layout::new::<Self>();
        if layout.size() == 0 {
            return Box::new(Self::zeros());
        }
        // SAFETY: `Self` consists only of nalgebra `ArrayStorage<f64, R, C>`
        // matrices (plain `f64` arrays plus zero-sized markers), for which the
        // all-zero bit pattern is a valid value (every entry `0.0`). The
        // layout is `Self`'s and non-zero-sized, the pointer comes from the
        // global allocator with that layout (checked for null), so
        // `Box::from_raw` takes ownership of a valid, initialized allocation.
        unsafe {
            let ptr = std::alloc::alloc_zeroed(layout).cast::<Self>();
            if ptr.is_null() {
                std::alloc::handle_alloc_error(layout);
            }
            Box::from_raw(ptr)
        }
    }
}

/// Explicit time derivatives; all zero for an autonomous system.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeDerivatives<const N: usize, const M: usize> {
    /// `∂L/∂t`.
    pub lagrangian_t: f64,
    /// `∂(∇_v L)/∂t = ∇²_tv L`.
    pub momentum_t: Vector<N>,
    /// `∂(∇_q L)/∂t`.
    pub force_t: Vector<N>,
    /// `k_t`.
    pub constraint_t: Vector<M>,
}

/// Operation counts of the generated code (additions, multiplications,
/// divisions and elementary-function calls after simplification and CSE;
/// constant outputs cost nothing).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct OperationCounts {
    /// [`NonholonomicSystem::stage_values`].
    pub stage_values: usize,
    /// [`NonholonomicSystem::stage_jacobians`] (values and Jacobians together).
    pub stage_jacobians: usize,
    /// The bundle CasADi is compared with: `L`, `∇_q L`, `∇_v L`, `∇²_vv L`,
    /// `∂(∇_v L)/∂q`, `k`, `k_q`, `k_v`, `Kᵀψ` and its Jacobians in `q`, `v`.
    pub bundle: usize,
}

/// The user's source expressions in a neutral text form, so that an
/// independent tool (CasADi) can rebuild and differentiate them itself.
///
/// Expressions are prefix S-expressions over this grammar:
///
/// ```text
/// expr  := number | "t" | "pi" | "(q " name ")" | "(v " name ")" | "(p " name ")" | "(psi " index ")"
///        | "(" op expr+ ")"
/// op    := "+" | "*"                        (n-ary)
///        | "-" | "/" | "^" | "atan2"        (binary)
///        | "neg" | "sqrt" | "exp" | "ln" | "sin" | "cos" | "tan"
///        | "sinh" | "cosh" | "tanh"       (unary)
/// number:= a decimal literal that round-trips to the same f64
/// ```
/// `(q x)` is the coordinate `x`, `(v x)` its velocity, `(p m)` the runtime
/// parameter `m`, `(psi j)` the multiplier of constraint `j` (only in
/// [`SystemSource::nonideal_force`]); a named constant is written as its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SystemSource {
    /// The type's name.
    pub name: &'static str,
    /// Generalized coordinates, in order (`N` of them).
    pub coordinates: &'static [&'static str],
    /// Runtime parameters, in order (see [`NonholonomicSystem::parameter_values`]).
    pub parameters: &'static [&'static str],
    /// `L(t,q,v)`.
    pub lagrangian: &'static str,
    /// `k_1, …, k_M`.
    pub constraints: &'static [&'static str],
    /// External force `f_1, …, f_N` (empty when the system has none,
    /// [`NonholonomicSystem::HAS_FORCING`] false).
    pub external_force: &'static [&'static str],
    /// Non-ideal constraint force `N_1, …, N_N` (empty when absent). These
    /// expressions may also use `(psi j)`, the multiplier of constraint `j`
    /// (0-based, `0 ≤ j < M`).
    pub nonideal_force: &'static [&'static str],
    /// Position-level constraints `g_1, …, g_M` over `t` and `q` (empty when
    /// [`NonholonomicSystem::HAS_HOLONOMIC`] is false): entry `i` is `g_i`
    /// when `k_i = ∂g_i/∂t + ∂g_i/∂q · v`, and `"0"` for a genuinely
    /// nonholonomic constraint.
    pub holonomic: &'static [&'static str],
}

/// A mechanical system with `N` generalized coordinates and `M` ideal
/// nonholonomic constraints, with every derivative the SPARK stepper needs.
///
/// All functions are pure and allocation-free. `stage_values` and
/// `stage_jacobians` are fused: they share common subexpressions between all
/// their outputs.
pub trait NonholonomicSystem<const N: usize, const M: usize> {
    /// Structure facts proved at compile time.
    const STRUCTURE: Structure;
    /// The user's source expressions, in neutral text.
    const SOURCE: SystemSource;
    /// Operation counts of the generated code (zero for hand-written systems).
    const OPERATIONS: OperationCounts;
    /// A structure fact beside [`STRUCTURE`](Self::STRUCTURE):
    /// `L` is separable and its stiffness `∂(∇_q L)/∂q` is a constant matrix,
    /// not identically zero (a quadratic potential; the matrix may depend on
    /// parameters). The stage-decoupled Newton matrix then keeps the
    /// couplings between stages that this matrix makes, instead of dropping
    /// them with the other `O(h²)` terms; `nonholonomic_system!` proves it.
    /// A wrong `true` costs convergence speed, never accuracy: the matrix
    /// only steers the iteration.
    const CONSTANT_STIFFNESS: bool = false;
    /// A structure fact beside [`STRUCTURE`](Self::STRUCTURE): `L` is
    /// separable and its stiffness `∂(∇_q L)/∂q` is a diagonal matrix that
    /// depends on the configuration (a potential that is a sum of
    /// functions of one coordinate each). With a constant diagonal mass
    /// matrix, the stage-decoupled Newton matrix then keeps the couplings
    /// between stages made by the stiffness at each stage point, evaluated
    /// at every refresh. As for [`CONSTANT_STIFFNESS`](Self::CONSTANT_STIFFNESS),
    /// a wrong `true` costs convergence speed, never accuracy.
    const DIAGONAL_STIFFNESS: bool = false;
    /// Where the step's equations are not affine in their unknowns
    /// ([`Nonlinearity`]); `nonholonomic_system!` proves it. `None` (the
    /// default) claims nothing: every Newton update is confirmed.
    const NONLINEARITY: Option<Nonlinearity> = None;

    /// The diagonal of the stiffness `F_q = ∂(∇_q L)/∂q` at `(t, q, v)`
    /// alone, when the system provides it: `nonholonomic_system!` does for
    /// a [`DIAGONAL_STIFFNESS`](Self::DIAGONAL_STIFFNESS) system, whose
    /// stage-decoupled refresh reads it at each stage point. `None` (the
    /// default): the refresh takes it from the stage Jacobians.
    fn stiffness_diagonal(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Option<Vector<N>> {
        let _ = (t, q, v);
        None
    }

    /// Current values of the runtime parameters, in the order of
    /// [`SystemSource::parameters`].
    fn parameter_values(&self) -> Vec<f64>;
    /// Sets a runtime parameter by name; `Err` names the known parameters.
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), crate::SystemError>;

    /// `L(t,q,v)`.
    fn lagrangian(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64;
    /// `E = ∇_v L · v − L`.
    fn energy(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64;
    /// `∇_v L`.
    fn momentum(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N>;
    /// `∇_q L`.
    fn force(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N>;
    /// `∇²_vv L`.
    fn mass_matrix(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N>;
    /// `k(t,q,v)`.
    fn constraint(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<M>;
    /// `k_q(t,q,v)`.
    fn constraint_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N>;
    /// `K = k_v(t,q,v)`.
    fn constraint_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N>;
    /// Explicit time derivatives (zeros when autonomous).
    fn time_derivatives(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> TimeDerivatives<N, M>;

    /// Fused: everything one residual evaluation needs at a stage point.
    fn stage_values(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> StageValues<N, M>;
    /// Fused, in place: writes [`stage_values`](Self::stage_values) into
    /// `values` (every entry is overwritten). The stepper's residual calls
    /// this form on its work storage: a returned `StageValues` is copied
    /// into place by a `memcpy` call once it outgrows the registers (14 %
    /// of an mp7 step of the stage-decoupled iteration). The default calls
    /// `stage_values`; `nonholonomic_system!` generates the in-place body.
    fn stage_values_into(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>, values: &mut StageValues<N, M>) {
        *values = self.stage_values(t, q, v, psi);
    }
    /// Fused: values and Jacobians at a stage point.
    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
    ) -> (StageValues<N, M>, StageJacobians<N, M>);
    /// Fused, in place: writes the values and Jacobians at a stage point into
    /// `values` and `jacobians` (every entry is overwritten; the previous
    /// contents do not matter).
    ///
    /// Same results as [`stage_jacobians`](Self::stage_jacobians), without
    /// returning `≈ 48·N²` bytes by value: the stepper calls this form with
    /// heap-allocated destinations, so a step's stack use stays `O(N)` for
    /// generated systems. The default calls `stage_jacobians` (hand-written
    /// systems need not implement it; their stack use stays `O(N²)`).
    fn stage_jacobians_into(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
        jacobians: &mut StageJacobians<N, M>,
    ) {
        (*values, *jacobians) = self.stage_jacobians(t, q, v, psi);
    }

    /// Fused: the stage values with the constraint Jacobians `k_q` and
    /// `K = k_v` at one point, written into the caller's storage — what a
    /// refresh of the stage-decoupled Newton matrix of a system with a
    /// constant mass matrix needs, in one evaluation whose shared
    /// subexpressions (the trigonometry of a rolling constraint, say) are
    /// computed once. The default makes the three separate calls;
    /// `nonholonomic_system!` generates the fused body.
    #[allow(clippy::too_many_arguments)]
    fn stage_values_and_constraint_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
        constraint_q: &mut Matrix<M, N>,
        constraint_v: &mut Matrix<M, N>,
    ) {
        *values = self.stage_values(t, q, v, psi);
        *constraint_q = self.constraint_q(t, q, v);
        *constraint_v = self.constraint_v(t, q, v);
    }

    /// The momentum and the constraint at `(t, q, v)`, written into
    /// `values` — what the SPARK residual reads at a step's end point and at
    /// the midpoint of the methods with a midpoint constraint; the forces
    /// there enter no equation, and this leaves `values.force` and
    /// `values.constraint_force` unspecified. Bit for bit what
    /// [`stage_values_into`](Self::stage_values_into) writes there (at any
    /// `ψ`: neither depends on it). The default calls it with `ψ = 0`;
    /// `nonholonomic_system!` generates a body with the two alone, so that
    /// the end point skips the force's work (the mobile robot's `cos φ`).
    fn end_point_values_into(&self, t: f64, q: &Vector<N>, v: &Vector<N>, values: &mut StageValues<N, M>) {
        self.stage_values_into(t, q, v, &Vector::zeros(), values);
    }

    /// [`end_point_values_into`](Self::end_point_values_into) and the
    /// constraint Jacobians `k_q`, `K = k_v` there, as
    /// [`stage_values_and_constraint_jacobians`](Self::stage_values_and_constraint_jacobians)
    /// computes them (the stage-decoupled matrix's refresh).
    fn end_point_values_and_constraint_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        values: &mut StageValues<N, M>,
        constraint_q: &mut Matrix<M, N>,
        constraint_v: &mut Matrix<M, N>,
    ) {
        self.stage_values_and_constraint_jacobians(t, q, v, &Vector::zeros(), values, constraint_q, constraint_v);
    }

    /// [`stage_values`](Self::stage_values) of `W` lanes at once, for the
    /// lane kernel (`crate::lanes`): lane `w` is the point
    /// `(t, q[·][w], v[·][w], psi[·][w])`, and its values go to
    /// `values.*[·][w]` — with `jacobians`, also `k_q` and `K = k_v`, as
    /// [`stage_values_and_constraint_jacobians`](Self::stage_values_and_constraint_jacobians)
    /// computes them — for every lane with `lanes[w]`. The entries of the
    /// other lanes are unspecified afterwards: an implementation may leave
    /// them or compute them from those lanes' inputs, whatever is cheaper.
    ///
    /// Each lane's values are bit for bit what the scalar functions return
    /// at its point. The default evaluates the lanes with `lanes[w]` one by
    /// one through the scalar functions; `nonholonomic_system!` generates a
    /// body whose every operation is one loop over all the lanes, which
    /// vectorizes.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn stage_values_in_lanes<const W: usize>(
        &self,
        t: f64,
        q: &[[f64; W]; N],
        v: &[[f64; W]; N],
        psi: &[[f64; W]; M],
        lanes: &[bool; W],
        values: &mut crate::lanes::LaneStageValues<N, M, W>,
        jacobians: Option<&mut crate::lanes::LaneConstraintJacobians<N, M, W>>,
    ) {
        crate::lanes::values::lane_by_lane(self, t, q, v, psi, lanes, values, jacobians);
    }

    /// [`end_point_values_into`](Self::end_point_values_into) of `W` lanes
    /// at once, as [`stage_values_in_lanes`](Self::stage_values_in_lanes)
    /// is [`stage_values`](Self::stage_values) (with `jacobians`, also
    /// `k_q` and `K = k_v`): the momentum and the constraint of every lane
    /// with `lanes[w]`, bit for bit the scalar ones; `values.force` and
    /// `values.constraint_force` are left unspecified. The default calls
    /// `stage_values_in_lanes` with `ψ = 0`; `nonholonomic_system!`
    /// generates the two alone in lane form, so that the lane kernel's end
    /// point skips the forces' work, as the stepper's does.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn end_point_values_in_lanes<const W: usize>(
        &self,
        t: f64,
        q: &[[f64; W]; N],
        v: &[[f64; W]; N],
        lanes: &[bool; W],
        values: &mut crate::lanes::LaneStageValues<N, M, W>,
        jacobians: Option<&mut crate::lanes::LaneConstraintJacobians<N, M, W>>,
    ) {
        self.stage_values_in_lanes(t, q, v, &[[0.0; W]; M], lanes, values, jacobians);
    }

    /// [`energy`](Self::energy) of `W` lanes at once (lane `w` at
    /// `(t, q[·][w], v[·][w])`), for every lane with `lanes[w]`; the other
    /// lanes' entries are unspecified. Each is bit for bit the scalar
    /// energy. The default evaluates the lanes with `lanes[w]` one by one
    /// (the others are `NaN`); `nonholonomic_system!` generates a body that
    /// computes every lane in one loop per operation.
    #[inline(always)]
    fn energy_in_lanes<const W: usize>(
        &self,
        t: f64,
        q: &[[f64; W]; N],
        v: &[[f64; W]; N],
        lanes: &[bool; W],
    ) -> [f64; W] {
        crate::lanes::values::energy_lane_by_lane(self, t, q, v, lanes)
    }

    // ---- Parameter terms (none by default). ----

    /// How many parameter terms [`parameter_terms`](Self::parameter_terms)
    /// writes: the parameter-only subexpressions of the functions a step
    /// evaluates at every iterate (the skate's `m g sin β`). `0` (the
    /// default) when there are none.
    const PARAMETER_TERMS: usize = 0;

    /// Writes the [`PARAMETER_TERMS`](Self::PARAMETER_TERMS) parameter terms
    /// into `terms[..PARAMETER_TERMS]` (nothing when `terms` is shorter),
    /// for the `*_with_terms` functions. They depend on the parameters
    /// alone: a caller computes them once per change of the parameters
    /// instead of at every evaluation, as the stepper does.
    fn parameter_terms(&self, terms: &mut [f64]) {
        let _ = terms;
    }

    /// [`energy`](Self::energy) with the parameter terms `terms` given
    /// (as [`parameter_terms`](Self::parameter_terms) wrote them for the
    /// current parameters): the same bits, without recomputing them. With
    /// a `terms` shorter than [`PARAMETER_TERMS`](Self::PARAMETER_TERMS) it
    /// computes its own. The default calls `energy`; `nonholonomic_system!`
    /// generates a body that reads the terms.
    fn energy_with_terms(&self, terms: &[f64], t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        let _ = terms;
        self.energy(t, q, v)
    }

    /// [`stage_values_into`](Self::stage_values_into) with the parameter
    /// terms given (see [`energy_with_terms`](Self::energy_with_terms)).
    #[allow(clippy::too_many_arguments)]
    fn stage_values_with_terms(
        &self,
        terms: &[f64],
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
    ) {
        let _ = terms;
        self.stage_values_into(t, q, v, psi, values);
    }

    /// [`stage_values_and_constraint_jacobians`](Self::stage_values_and_constraint_jacobians)
    /// with the parameter terms given (see
    /// [`energy_with_terms`](Self::energy_with_terms)).
    #[allow(clippy::too_many_arguments)]
    fn stage_values_and_constraint_jacobians_with_terms(
        &self,
        terms: &[f64],
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
        constraint_q: &mut Matrix<M, N>,
        constraint_v: &mut Matrix<M, N>,
    ) {
        let _ = terms;
        self.stage_values_and_constraint_jacobians(t, q, v, psi, values, constraint_q, constraint_v);
    }

    /// [`end_point_values_into`](Self::end_point_values_into) with the
    /// parameter terms given (see [`energy_with_terms`](Self::energy_with_terms)).
    fn end_point_values_with_terms(
        &self,
        terms: &[f64],
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        values: &mut StageValues<N, M>,
    ) {
        let _ = terms;
        self.end_point_values_into(t, q, v, values);
    }

    /// [`end_point_values_and_constraint_jacobians`](Self::end_point_values_and_constraint_jacobians)
    /// with the parameter terms given (see [`energy_with_terms`](Self::energy_with_terms)).
    #[allow(clippy::too_many_arguments)]
    fn end_point_values_and_constraint_jacobians_with_terms(
        &self,
        terms: &[f64],
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        values: &mut StageValues<N, M>,
        constraint_q: &mut Matrix<M, N>,
        constraint_v: &mut Matrix<M, N>,
    ) {
        let _ = terms;
        self.end_point_values_and_constraint_jacobians(t, q, v, values, constraint_q, constraint_v);
    }

    /// [`stage_jacobians_into`](Self::stage_jacobians_into) with the
    /// parameter terms given (see [`energy_with_terms`](Self::energy_with_terms)).
    #[allow(clippy::too_many_arguments)]
    fn stage_jacobians_with_terms(
        &self,
        terms: &[f64],
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
        jacobians: &mut StageJacobians<N, M>,
    ) {
        let _ = terms;
        self.stage_jacobians_into(t, q, v, psi, values, jacobians);
    }

    // ---- Optional effects (all default to "absent"; see the module docs). ----

    /// The system has an external generalized force `f(t,q,v)`
    /// ([`external_force`](Self::external_force)). When `false` the stepper
    /// never calls the forcing methods (the branch is on a constant).
    const HAS_FORCING: bool = false;
    /// The system has a non-ideal constraint force `N(t,q,v,ψ)`
    /// ([`nonideal_force`](Self::nonideal_force)), paper §3.3.
    const HAS_NONIDEAL_FORCE: bool = false;
    /// Some constraints are time derivatives of holonomic constraints
    /// `g(t,q) = 0` ([`holonomic_residual`](Self::holonomic_residual)).
    const HAS_HOLONOMIC: bool = false;

    /// External generalized force `f(t,q,v)`: enters the momentum equations
    /// beside `F = ∇_q L` with the same weights `â`, `b̂` (forced discrete
    /// Lagrange–d'Alembert). Zero by default.
    fn external_force(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        let _ = (t, q, v);
        Vector::zeros()
    }
    /// `f`, `∂f/∂q`, `∂f/∂v` together. Zero by default.
    fn external_force_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
    ) -> (Vector<N>, Matrix<N, N>, Matrix<N, N>) {
        let _ = (t, q, v);
        (Vector::zeros(), Matrix::zeros(), Matrix::zeros())
    }
    /// Adds the external force and its Jacobians to a stage evaluation in
    /// place: `f` to `values.force`, `∂f/∂q` to `jacobians.force_q`, `∂f/∂v`
    /// to `jacobians.force_v` (how the stepper folds `f` into `F`). The
    /// default goes through [`external_force_jacobians`](Self::external_force_jacobians);
    /// generated systems add entry by entry without an `N × N` temporary.
    fn add_external_force_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        values: &mut StageValues<N, M>,
        jacobians: &mut StageJacobians<N, M>,
    ) {
        let (f, fq, fv) = self.external_force_jacobians(t, q, v);
        values.force += f;
        jacobians.force_q += fq;
        jacobians.force_v += fv;
    }
    /// Non-ideal constraint force `N(t,q,v,ψ)`: the total constraint force
    /// is `R = −Kᵀψ + N`, entering with the weights `ã`, `b̃`. Zero by default.
    fn nonideal_force(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> Vector<N> {
        let _ = (t, q, v, psi);
        Vector::zeros()
    }
    /// `N`, `∂N/∂q`, `∂N/∂v`, `∂N/∂ψ` together. Zero by default.
    fn nonideal_force_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
    ) -> NonidealJacobians<N, M> {
        let _ = (t, q, v, psi);
        NonidealJacobians { value: Vector::zeros(), q: Matrix::zeros(), v: Matrix::zeros(), psi: Matrix::zeros() }
    }
    /// Adds the non-ideal constraint force and its Jacobians to a stage
    /// evaluation in place: `N` to `values.constraint_force`, `∂N/∂q` to
    /// `jacobians.constraint_force_q`, `∂N/∂v` to
    /// `jacobians.constraint_force_v`; `∂N/∂ψ` is written (not added) to
    /// `psi_jacobian`. The default goes through
    /// [`nonideal_force_jacobians`](Self::nonideal_force_jacobians);
    /// generated systems write entry by entry without `N × N` temporaries.
    #[allow(clippy::too_many_arguments)]
    fn add_nonideal_force_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
        values: &mut StageValues<N, M>,
        jacobians: &mut StageJacobians<N, M>,
        psi_jacobian: &mut Matrix<N, M>,
    ) {
        let nj = self.nonideal_force_jacobians(t, q, v, psi);
        values.constraint_force += nj.value;
        jacobians.constraint_force_q += nj.q;
        jacobians.constraint_force_v += nj.v;
        *psi_jacobian = nj.psi;
    }
    /// The system declares events ([`EVENTS`](Self::EVENTS)): zeros of
    /// functions `g(t,q,v)` the driver locates on the dense output. When
    /// `false` the driver never evaluates an event function or the dense
    /// output for them (the branch is on a constant).
    const HAS_EVENTS: bool = false;
    /// The event declarations, in index order (empty by default).
    const EVENTS: &'static [EventSpec] = &[];
    /// The value `g_index(t,q,v)` of event `index`. Zero by default.
    fn event_value(&self, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        let _ = (index, t, q, v);
        0.0
    }
    /// `g_index` with `∂g/∂t`, `∂g/∂q`, `∂g/∂v`. Zero by default.
    fn event_gradient(&self, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N> {
        let _ = (index, t, q, v);
        EventGradient::zeros()
    }
    /// Position-level residuals for drift reporting: entry `i` is `g_i(t,q)`
    /// when constraint `i` is `k_i = ∂g_i/∂t + ∂g_i/∂q · v` of a holonomic
    /// constraint `g_i = 0`, and `0` for a genuinely nonholonomic one.
    fn holonomic_residual(&self, t: f64, q: &Vector<N>) -> Vector<M> {
        let _ = (t, q);
        Vector::zeros()
    }
}

/// A non-ideal constraint force and its first derivatives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NonidealJacobians<const N: usize, const M: usize> {
    /// `N(t,q,v,ψ)`.
    pub value: Vector<N>,
    /// `∂N/∂q`.
    pub q: Matrix<N, N>,
    /// `∂N/∂v`.
    pub v: Matrix<N, N>,
    /// `∂N/∂ψ`.
    pub psi: Matrix<N, M>,
}

/// Which zero crossings of an event function count (the declaration of
/// events is part of a system; [`events`](crate::events) locates them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Direction {
    /// From negative to non-negative.
    Rising,
    /// From positive to non-positive.
    Falling,
    /// Both.
    Both,
}

impl Direction {
    /// Whether a crossing with `rising` (true: − to +) counts.
    pub const fn accepts(self, rising: bool) -> bool {
        match self {
            Direction::Rising => rising,
            Direction::Falling => !rising,
            Direction::Both => true,
        }
    }
}

/// Declaration of one event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct EventSpec {
    /// Its name.
    pub name: &'static str,
    /// Which crossings count.
    pub direction: Direction,
    /// Whether the first crossing ends the run (`false`: crossings are
    /// counted and reported).
    pub terminal: bool,
    /// The event function in the neutral text form of
    /// [`SystemSource`] (empty for run-time events).
    pub source: &'static str,
}

/// An event function and its first derivatives at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EventGradient<const N: usize> {
    /// `g(t, q, v)`.
    pub value: f64,
    /// `∂g/∂t`.
    pub t: f64,
    /// `∂g/∂q`.
    pub q: Vector<N>,
    /// `∂g/∂v`.
    pub v: Vector<N>,
}

impl<const N: usize> EventGradient<N> {
    /// All zero.
    pub fn zeros() -> Self {
        EventGradient { value: 0.0, t: 0.0, q: Vector::zeros(), v: Vector::zeros() }
    }
}
