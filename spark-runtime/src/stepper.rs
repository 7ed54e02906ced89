//! The SPARK step (paper eq. 6.1) and its Newton solver.
//!
//! Unknowns `z = [V_1..V_S | μ_1..μ_S | v₁]` with `μ_i = hΨ_i` (scaling the
//! multipliers by `h` keeps every block of the Newton matrix `O(1)`), `D =
//! S(N+M)+N` of them. Equations, in this order:
//!
//! ```text
//! P_i − p₀ − hΣ_j â_ij F_j − hΣ_j ã_ij R_j = 0      i = 1..S      (S·N rows)
//! p₁  − p₀ − hΣ_j b̂_j F_j  − hΣ_j b̃_j R_j  = 0                    (N rows)
//! condition rows (ω-sums, §8.4 midpoint constraint, or Ψ_i − Ψ_{i+1})  ((S−1)·M rows)
//! k(t₁, q₁, v₁) = 0                                                (M rows)
//! ```
//!
//! with `Q_i = q₀ + hΣ_j a_ij V_j` and `q₁ = q₀ + hΣ_j b_j V_j` substituted,
//! so the exact Jacobian follows from the system's stage Jacobians by the
//! chain rule `∂Q_i/∂V_l = h a_il I`.
//!
//! Optional effects enter where the paper puts them: an external force
//! `f(t,q,v)` is added to `F` (weights `â`, `b̂`), a non-ideal constraint
//! force `N(t,q,v,ψ)` to `R` (weights `ã`, `b̃`, paper §3.3). Both are
//! folded into the stage values at the stage points only, behind
//! `if Sys::HAS_FORCING` / `if Sys::HAS_NONIDEAL_FORCE` (constants, so a
//! system without them compiles to exactly the code it had before).
//!
//! # Why a fourth const parameter `D`
//! The Newton matrix is `D × D` with `D = S(N+M)+N`, but stable Rust cannot
//! write `SMatrix<f64, {S*(N+M)+N}, _>` for generic `N, M, S` (that needs the
//! unstable `generic_const_exprs`). So `D` is a parameter of its own, checked
//! at compile time by an inline `const { assert!(D == S * (N + M) + N) }` in
//! [`Stepper::new`]; a wrong `D` is a compile error at monomorphization, not
//! a runtime failure. The [`Stepper!`](crate::Stepper!) macro computes `D`.

// Stage loops index several parallel arrays (c, a, b, stage values) with one index.
#![allow(clippy::needless_range_loop)]

use crate::convergence::{
    check_cold_start, check_energy, energy_is_invariant, scaled_update_norm, Contraction, EnergyAnchor, EnergyCheck,
};
use crate::decoupled::{DecoupledMatrix, Masses};
use crate::error::{IterationRecord, NewtonHistory, StepError, HISTORY_CAPACITY};
use crate::initial::consistent_acceleration_in;
use crate::newton::NewtonMatrix;
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::tableau::{ConditionRows, Tableau};

/// Full Newton (Jacobian re-evaluated every iteration) or simplified Newton
/// (Jacobian frozen at the starting guess for the whole step).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum NewtonMode {
    /// The exact Jacobian, evaluated and factored at every iterate.
    Full,
    /// One Newton matrix and factorization per step, refreshed at the
    /// current iterate only when the iteration on it grows or contracts too
    /// slowly (rate above 0.5, or too slow to reach the tolerance within the
    /// iteration limit) — large steps, stiff systems. Which matrix — the
    /// exact Jacobian or the stage-decoupled one — is
    /// [`NewtonOptions::jacobian`].
    Simplified,
}

/// Which Newton matrix simplified Newton factors (full Newton always uses
/// the exact Jacobian: that is what makes it full Newton).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Jacobian {
    /// The exact Jacobian `∂G/∂z`, factored densely (`D × D`).
    Exact,
    /// The stage-decoupled matrix: the exact Jacobian with the couplings
    /// between the velocity unknowns of different stages dropped and each
    /// stage's own velocity block replaced by its mass matrix, eliminated down
    /// to an `S·M × S·M` Schur complement in the multipliers (see
    /// `spark_runtime::decoupled` in the docs of the crate source). The step
    /// switches to [`Jacobian::Exact`] when the iteration contracts slower
    /// than 1/8 per update or the decoupled matrix is singular, and stays on
    /// the exact matrix for the next 32 steps.
    StageDecoupled,
    /// [`Jacobian::StageDecoupled`] when the structure facts make the dropped
    /// couplings `O(h²)` — `L = T(t,v) − U(t,q)` (separable), `K`
    /// independent of `v`, no forcing and no non-ideal constraint force —
    /// and [`Jacobian::Exact`] otherwise.
    #[default]
    Auto,
}

/// Newton solver settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NewtonOptions {
    /// Full or simplified Newton.
    pub mode: NewtonMode,
    /// Target for the estimated remaining error of the scaled unknowns
    /// (`|Δz_i| / (1 + |z_i|)`); default `16 ε ≈ 3.6e-15`.
    pub tolerance: f64,
    /// Updates below this level that stop contracting are round-off
    /// stagnation and are accepted; above it they count as divergence.
    pub stagnation_level: f64,
    /// Iteration limit (at most [`HISTORY_CAPACITY`]).
    pub max_iterations: usize,
    /// Extrapolate the starting guess from the previous step's stages when
    /// the new step continues it; otherwise start from the consistent
    /// acceleration at `(t₀, q₀, v₀)`.
    pub warm_start: bool,
    /// Degree (1..=3) of the polynomial extrapolating the solutions of
    /// previous equal steps to the next starting guess.
    pub extrapolation_degree: usize,
    /// Energy guard: when the structure facts make `E` a first integral
    /// (autonomous `L`, constraints absent or linear homogeneous in `v` —
    /// `k = K(t,q)v` may depend on `t` — and no external or non-ideal
    /// force), refuse with
    /// [`StepError::EnergyDrift`] a step that leaves `|E − E₀|` above this
    /// multiple of `|E₀| + |p₀·v₀|`, `E₀` taken where the chain of continued
    /// steps began. A sanity bound against unstable discrete maps (stiff
    /// modes beyond a method's stability range), not an accuracy control;
    /// `None` turns it off. Default `Some(1.0)`.
    #[serde(default = "default_energy_drift_limit")]
    pub energy_drift_limit: Option<f64>,
    /// Simplified Newton only: start a step that continues the previous one
    /// (same `h`, warm start) from the previous step's factorization instead
    /// of a fresh Jacobian, as long as it contracts well (rate ≤ 0.2 over
    /// the previous step; refreshed within a step like any simplified
    /// Newton Jacobian, see [`NewtonMode::Simplified`]).
    /// The converged solution is the same (to the tolerance); it trades one
    /// Jacobian + factorization per step for more, cheaper iterations. Off by
    /// default: measured on the skate and MP particles (Gauss s = 2, h = 0.05)
    /// an earlier step's factors contract at rate ≈ 0.1, so a step needs ≈ 7
    /// iterations instead of 2 and costs more than a fresh factorization.
    #[serde(default = "default_reuse")]
    pub reuse_factorization: bool,
    /// A step that starts cold — at a state that is not where the
    /// stepper's previous step ended — refuses with
    /// [`StepError::InconsistentStart`] a state whose constraint residual
    /// `|k_i(t,q,v)|` exceeds this multiple of the size of the terms of `k_i`
    /// (`Σ_j |K_ij v_j|` plus the velocity-free part, at least 1), and with
    /// [`StepError::DependentConstraints`] one where the constraint rows are
    /// dependent. Default `1e-12`, the default tolerance of
    /// [`ConsistencyPolicy`](crate::ConsistencyPolicy); continuing steps
    /// start where a step ended and skip both checks.
    #[serde(default = "default_consistency_tolerance")]
    pub consistency_tolerance: f64,
    /// Simplified Newton only: which Newton matrix to factor (default
    /// [`Jacobian::Auto`]). The converged step is the same to the tolerance
    /// whichever matrix the iteration uses; [`Jacobian::StageDecoupled`]
    /// with [`NewtonMode::Full`] is refused as an invalid option.
    #[serde(default)]
    pub jacobian: Jacobian,
}

fn default_energy_drift_limit() -> Option<f64> {
    Some(1.0)
}

fn default_reuse() -> bool {
    false
}

fn default_consistency_tolerance() -> f64 {
    1e-12
}

/// Largest contraction rate of a step with which simplified Newton keeps
/// its factorization for the next step.
const REUSE_RATE: f64 = 0.2;
/// Contraction rate above which an iteration on factors from an earlier
/// iterate (simplified Newton) triggers a fresh Jacobian.
const REFRESH_RATE: f64 = 0.5;
/// Contraction rate above which the stage-decoupled matrix gives way to the
/// exact one: a refresh cannot speed it up (the couplings it drops set the
/// rate), and at 1/8 per update it still needs no more iterations than the
/// exact matrix's factorization costs.
const DECOUPLED_RATE: f64 = 0.125;
/// Steps a stepper stays on the exact matrix after the stage-decoupled one
/// was slow or singular (the next steps are much like this one).
const EXACT_AFTER_DECOUPLED_FAILS: u32 = 32;

impl Default for NewtonOptions {
    fn default() -> Self {
        NewtonOptions {
            mode: NewtonMode::Full,
            tolerance: 16.0 * f64::EPSILON,
            stagnation_level: 1e-12,
            max_iterations: 20,
            warm_start: true,
            extrapolation_degree: 2,
            reuse_factorization: default_reuse(),
            energy_drift_limit: default_energy_drift_limit(),
            consistency_tolerance: default_consistency_tolerance(),
            jacobian: Jacobian::Auto,
        }
    }
}

/// A point `(t, q, v)` of the phase space.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct State<const N: usize> {
    /// Time.
    pub t: f64,
    /// Generalized coordinates.
    pub q: Vector<N>,
    /// Generalized velocities.
    pub v: Vector<N>,
}

impl<const N: usize> State<N> {
    /// A state from its parts.
    pub fn new(t: f64, q: Vector<N>, v: Vector<N>) -> Self {
        State { t, q, v }
    }
}

/// The outcome of one successful step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepResult<const N: usize, const M: usize, const S: usize> {
    /// `(t₁, q₁, v₁)`.
    pub state: State<N>,
    /// Stage velocities `V_i`.
    pub stage_velocities: [Vector<N>; S],
    /// Stage multipliers `Ψ_i`.
    pub stage_multipliers: [Vector<M>; S],
    /// Newton iterations (updates applied to the unknowns).
    pub iterations: usize,
    /// Newton matrices evaluated and factored (full Newton: one per
    /// iteration; simplified Newton: once, plus refreshes and a switch from
    /// the stage-decoupled to the exact matrix; none when it reuses an
    /// earlier step's factors).
    pub factorizations: usize,
    /// Whether the starting guess came from the previous step.
    pub warm_started: bool,
}

/// How many previous solutions the starting-guess extrapolation keeps.
const PAST: usize = 4;

/// The previous steps, kept for extrapolating the next starting guess.
///
/// Updated in place after every step (a ring of the last solutions, not a
/// shifted array rebuilt per step: that copy was `PAST·D` doubles).
#[derive(Clone, Copy, Debug)]
struct Warm<const N: usize, const D: usize> {
    h: f64,
    end: State<N>,
    /// Solutions `z` of the last `depth` consecutive steps of size `h`; the
    /// most recent is `past[head]`, the one before `past[(head + 1) % PAST]`.
    past: [Vector<D>; PAST],
    head: usize,
    depth: usize,
}

impl<const N: usize, const D: usize> Warm<N, D> {
    /// The `k`-th most recent solution (`k < depth`).
    fn back(&self, k: usize) -> &Vector<D> {
        &self.past[(self.head + k) % PAST]
    }
}

/// An `S`-stage SPARK integrator for a system with `N` coordinates and `M`
/// constraints; `D` must equal `S(N+M)+N` (see the module docs). Name the
/// type with [`Stepper!`](crate::Stepper!) to have `D` computed for you.
///
/// A step allocates nothing on the heap: the Newton matrix, its factors and
/// the stage Jacobians are allocated once by [`Stepper::new`] (on the heap,
/// so the stepper's own size is `O(S·D)` and large `D` cannot overflow a
/// thread's stack); everything else is fixed-size nalgebra values.
#[derive(Clone, Debug)]
pub struct Stepper<Sys, const N: usize, const M: usize, const S: usize, const D: usize> {
    system: Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    warm: Option<Warm<N, D>>,
    /// The Newton matrix and its factors (heap, allocated once).
    newton: NewtonMatrix<N, M, S, D>,
    /// Stage Jacobians of the latest full evaluation (heap, allocated once:
    /// `(S+2)·8·N²` doubles would dominate the stepper's size).
    work: Box<EvalJac<N, M, S>>,
    /// Scratch for one `N × N` block of the Newton matrix while it is
    /// accumulated (heap, allocated once: a local `Matrix<N, N>` put
    /// `2·8·N²` bytes on the stack, 4.4 MiB at n = 513).
    block: Box<[f64]>,
    /// The stage-decoupled Newton matrix's factors (heap, allocated once).
    decoupled: DecoupledMatrix<N, M, S>,
    /// Steps left on the exact matrix after the stage-decoupled one was slow
    /// or singular ([`Jacobian::StageDecoupled`]).
    exact_steps_left: u32,
    /// The step size for which `newton` (or `decoupled`, when the flag is
    /// set) holds factors that simplified Newton may reuse on the next
    /// continuing step (`None`: evaluate afresh).
    reusable: Option<(f64, bool)>,
    /// Where the energy guard's chain of continued steps began.
    anchor: Option<EnergyAnchor<N>>,
    /// The Newton iterations of the latest step (kept here rather than in
    /// every [`StepResult`]: 32 records are ≈ 0.8 KB to move per step).
    history: NewtonHistory,
    /// Whether `newton`'s matrix holds the structural zeros and constant
    /// entries of this tableau and system; then [`Self::assemble_jacobian`]
    /// overwrites only the blocks that change.
    pattern_written: bool,
    /// The round-off the latest step's `q₁` could not hold (compensated
    /// summation, see [`Compensation`]).
    compensation: Option<Compensation<N>>,
    /// Whether `options` passed [`NewtonOptions::validate`]; cleared by
    /// every way of changing them, so the check runs once per change, not
    /// per step.
    options_checked: bool,
    /// While a driver runs: the consistency tolerance its policy already
    /// accepted the initial state with, so a cold start within the run is
    /// not refused for a residual the run's own check let through.
    accepted_start_residual: f64,
}

/// Compensated summation of `q₁ = q₀ + hΣ_j b_j V_j` across steps (Hairer,
/// Lubich & Wanner, GNI §VIII.5): `carry` is exactly `(q₀ + Δq) − q₁` for the
/// step that ended at `end`, added to the next step's increment when that
/// step starts at `end`.
///
/// Why: with `h` far below `|q|`, the rounding of `q₀ + Δq` has the same
/// sign over long stretches of steps (the increments change slowly), so it
/// accumulates linearly. Measured on the skate (Lobatto IIIA-B s = 3,
/// T = 10) before this and the separate summation of `Δq`: global error
/// ≈ 4e-16 per step, 5e-11 after 131072 steps; with both ≈ 2e-15 to 5e-15
/// at any step count (`examples/skate_drift.rs`).
#[derive(Clone, Copy, Debug)]
struct Compensation<const N: usize> {
    end: State<N>,
    carry: Vector<N>,
}

/// The part of a stepper's state that links a step to the previous one
/// (see [`Stepper::continuation`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Continuation<const N: usize, const D: usize> {
    warm: Option<Warm<N, D>>,
    anchor: Option<EnergyAnchor<N>>,
    compensation: Option<Compensation<N>>,
}

/// Everything one residual evaluation produced.
struct Eval<const N: usize, const M: usize, const S: usize> {
    stages: [StageValues<N, M>; S],
    end: StageValues<N, M>,
    mid: Option<StageValues<N, M>>,
}

/// Jacobians of one evaluation (only for full-Jacobian iterations).
/// Every `StageJacobians` is its own heap allocation made zeroed by
/// [`StageJacobians::boxed_zeros`] and written in place by
/// `stage_jacobians_into`, so neither building nor filling one puts its
/// `≈ 48·N²` bytes on the stack (n = 65, s = 2 overflowed a 2 MiB thread when
/// the stage arrays were built before boxing; n ≈ 120 did when the system
/// returned them by value).
#[derive(Clone, Debug)]
struct EvalJac<const N: usize, const M: usize, const S: usize> {
    stages: Box<[Box<StageJacobians<N, M>>]>,
    end: Box<StageJacobians<N, M>>,
    mid: Option<Box<StageJacobians<N, M>>>,
    /// `∂N/∂ψ` at the stages (only written when `Sys::HAS_NONIDEAL_FORCE`).
    nonideal_psi: Box<[Matrix<N, M>]>,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// Whether the structure facts make the couplings the stage-decoupled
    /// matrix drops `O(h²)` ([`Jacobian::Auto`]).
    const DECOUPLES: bool = Sys::STRUCTURE.separable
        && Sys::STRUCTURE.constraint_matrix_velocity_free()
        && !Sys::HAS_FORCING
        && !Sys::HAS_NONIDEAL_FORCE;

    /// Whether a stage-decoupled refresh may skip the full stage Jacobians:
    /// a constant mass matrix (factored once), no non-ideal force (its
    /// `∂N/∂ψ` comes with the full Jacobians), and constraint Jacobians small
    /// enough to be returned by value (`M·N ≤ 4096` entries, 32 KiB of stack).
    const LEAN_DECOUPLED: bool = Sys::STRUCTURE.constant_mass_matrix && !Sys::HAS_NONIDEAL_FORCE && M * N <= 4096;

    /// A stepper for `system` with the coefficients `tableau` and default
    /// Newton options. Fails to compile unless `D == S·(N+M)+N`.
    pub fn new(system: Sys, tableau: Tableau<S>) -> Self {
        const { assert!(D == S * (N + M) + N, "Stepper: D must equal S*(N+M)+N; use the Stepper! macro") };
        Stepper {
            system,
            tableau,
            options: NewtonOptions::default(),
            warm: None,
            newton: NewtonMatrix::new(),
            work: Box::new(EvalJac {
                stages: (0..S).map(|_| StageJacobians::boxed_zeros()).collect(),
                end: StageJacobians::boxed_zeros(),
                mid: None,
                nonideal_psi: vec![Matrix::zeros(); S].into_boxed_slice(),
            }),
            block: vec![0.0; N * N].into_boxed_slice(),
            decoupled: DecoupledMatrix::new(),
            exact_steps_left: 0,
            reusable: None,
            anchor: None,
            history: NewtonHistory::default(),
            pattern_written: false,
            compensation: None,
            options_checked: false,
            accepted_start_residual: 0.0,
        }
    }

    /// Replaces the Newton options (builder style).
    pub fn with_options(mut self, options: NewtonOptions) -> Self {
        self.options = options;
        self.options_checked = false;
        self
    }

    /// The Newton options.
    pub fn options(&self) -> &NewtonOptions {
        &self.options
    }

    /// Mutable access to the Newton options.
    pub fn options_mut(&mut self) -> &mut NewtonOptions {
        self.options_checked = false;
        &mut self.options
    }

    /// The system.
    pub fn system(&self) -> &Sys {
        &self.system
    }

    /// Mutable access to the system (e.g. to change parameters); forgets the
    /// warm start.
    pub fn system_mut(&mut self) -> &mut Sys {
        self.warm = None;
        self.reusable = None;
        self.decoupled.invalidate();
        self.anchor = None;
        self.compensation = None;
        &mut self.system
    }

    /// The coefficients.
    pub fn tableau(&self) -> &Tableau<S> {
        &self.tableau
    }

    /// The Newton iterations of the latest step, successful or not (a
    /// failed step's error carries its own copy).
    pub fn last_history(&self) -> &NewtonHistory {
        &self.history
    }

    /// Whether a step from `state` would be warm-started.
    pub(crate) fn is_warm_for(&self, state: &State<N>) -> bool {
        self.options.warm_start && self.warm.as_ref().is_some_and(|w| w.end == *state)
    }

    /// Declares that `state` (the last step's result with its time pinned to
    /// the schedule) continues the last step.
    pub(crate) fn retarget_warm_start(&mut self, state: &State<N>) {
        if let Some(w) = self.warm.as_mut() {
            w.end = *state;
        }
        if let Some(a) = self.anchor.as_mut() {
            a.end = *state;
        }
        if let Some(c) = self.compensation.as_mut() {
            c.end = *state;
        }
    }

    /// The compensation `state.q` carries when a step continues the latest
    /// one there, else zero.
    fn carry_for(&self, state: &State<N>) -> Vector<N> {
        match self.compensation.as_ref().filter(|c| c.end == *state) {
            Some(c) => c.carry,
            None => Vector::zeros(),
        }
    }

    /// Forgets the previous step, so the next step starts cold. The
    /// round-off compensation of the previous step's end (see the crate's
    /// step docs) is kept: it belongs to that state, not to the guess.
    pub fn reset_warm_start(&mut self) {
        self.warm = None;
        self.reusable = None;
    }

    /// What the next step takes over from the latest one (warm start,
    /// energy anchor, round-off compensation), for a driver that tries
    /// steps it may discard: [`Self::restore_continuation`] puts it back.
    pub(crate) fn continuation(&self) -> Continuation<N, D> {
        Continuation { warm: self.warm, anchor: self.anchor, compensation: self.compensation }
    }

    /// Puts back what [`Self::continuation`] saved. The factorization is
    /// not part of it (the discarded steps overwrote it), so simplified
    /// Newton evaluates afresh on the next step.
    pub(crate) fn restore_continuation(&mut self, saved: &Continuation<N, D>) {
        self.warm = saved.warm;
        self.anchor = saved.anchor;
        self.compensation = saved.compensation;
        self.reusable = None;
    }

    /// Forgets everything earlier steps left behind — the warm start, the
    /// reusable factorization, the energy guard's anchor and the round-off
    /// compensation — so that the next step computes exactly what it would
    /// on a fresh stepper (a new run from a given initial state).
    pub(crate) fn reset_run(&mut self) {
        self.reset_warm_start();
        self.exact_steps_left = 0;
        self.anchor = None;
        self.compensation = None;
    }

    /// Sets the consistency tolerance a driver's policy accepted the
    /// run's initial state with (0 outside a run).
    pub(crate) fn set_accepted_start_residual(&mut self, tolerance: f64) {
        self.accepted_start_residual = tolerance;
    }

    /// Checks the Newton options once after they changed
    /// ([`NewtonOptions::validate`]).
    pub(crate) fn check_options(&mut self) -> Result<(), StepError> {
        if !self.options_checked {
            self.options.validate().map_err(|e| StepError::InvalidOption(Box::new(e)))?;
            self.options_checked = true;
        }
        Ok(())
    }

    /// One SPARK step of size `h` (negative `h` integrates backward) from a
    /// consistent `state`. Returns `(t₀+h, q₁, v₁)` with the stage values.
    ///
    /// A step that starts where the stepper's previous step ended continues
    /// it and trusts its state. Any other start is checked first (one
    /// stage-Jacobian evaluation): a state that violates the constraints is
    /// refused with [`StepError::InconsistentStart`] (see
    /// [`NewtonOptions::consistency_tolerance`]), dependent constraint rows
    /// with [`StepError::DependentConstraints`].
    ///
    /// Newton stops when an update is within [`NewtonOptions::tolerance`]
    /// (scaled, `|Δz_i|/(1+|z_i|)`), or when the error left after it is,
    /// estimated from a contraction rate: for full Newton the ratio of its
    /// last two updates, for simplified Newton a rate earned over three
    /// updates on the same frozen factors. A converged step agrees with the
    /// tightly converged solution of its equations to the tolerance in both
    /// modes.
    ///
    /// The first step after the Newton options were set or changed checks
    /// them ([`NewtonOptions::validate`]): an out-of-range field is a
    /// [`StepError::InvalidOption`].
    pub fn step(&mut self, state: &State<N>, h: f64) -> Result<StepResult<N, M, S>, StepError> {
        let t0 = state.t;
        self.check_options()?;
        if h == 0.0 || !h.is_finite() {
            return Err(StepError::InvalidStep { t: t0, h, reason: "step size must be finite and nonzero" });
        }
        if !t0.is_finite() || state.q.iter().chain(state.v.iter()).any(|x| !x.is_finite()) {
            return Err(StepError::InvalidStep { t: t0, h, reason: "state is not finite" });
        }
        if !(t0 + h).is_finite() || t0 + h == t0 {
            return Err(StepError::InvalidStep { t: t0, h, reason: "step size is below the resolution of t" });
        }
        // A state where the previous step ended is consistent by
        // construction; any other start pays for the checks.
        if !self.compensation.as_ref().is_some_and(|c| c.end == *state) {
            let mut vals = StageValues::zeros();
            let tolerance = self.options.consistency_tolerance.max(self.accepted_start_residual);
            check_cold_start::<Sys, N, M>(&self.system, state, h, tolerance, &mut vals, &mut self.work.end)?;
        }
        let (mut z, warm_started) = self.starting_guess(state, h);
        let carry = self.carry_for(state);
        let factorizations = self.newton(state, &carry, h, &mut z)?;
        let iterations = self.history.len();
        let (v, mu) = split::<N, M, S, D>(&z);
        // The increment is summed on its own and added once; what q₁ cannot
        // hold of it is carried to the next step (see `Compensation`).
        let dq = increment(&carry, h, &self.tableau.b, &v);
        let q1 = state.q + dq;
        let carry = two_sum_error(&state.q, &dq, &q1);
        let v1 = z.fixed_rows::<N>(S * (N + M)).into_owned();
        let end = State { t: t0 + h, q: q1, v: v1 };
        // The update norm propagates NaN, so this catches only overflow of
        // q₁ = q₀ + hΣb_jV_j; never return a non-finite state as a success.
        if !end.q.iter().chain(end.v.iter()).all(|x| x.is_finite()) {
            return Err(StepError::NonFinite { t: t0, h, stage: "step result", history: Box::new(self.history) });
        }
        if let (Some(limit), true) = (self.options.energy_drift_limit, energy_is_invariant::<Sys, N, M>()) {
            match check_energy::<Sys, N, M>(&self.system, self.anchor.as_ref(), state, &end, limit) {
                EnergyCheck::Accept(a) => self.anchor = Some(a),
                EnergyCheck::Drift(a, energy) => {
                    return Err(StepError::EnergyDrift { t: t0, h, energy0: a.energy, energy, bound: limit * a.scale });
                }
            }
        }
        match self.warm.as_mut().filter(|w| w.end == *state && w.h == h) {
            Some(w) => {
                w.head = (w.head + PAST - 1) % PAST;
                w.past[w.head] = z;
                w.depth = (w.depth + 1).min(PAST);
                w.end = end;
            }
            None => {
                let mut past = [Vector::<D>::zeros(); PAST];
                past[0] = z;
                self.warm = Some(Warm { h, end, past, head: 0, depth: 1 });
            }
        }
        self.compensation = Some(Compensation { end, carry });
        let mut psi = mu;
        for p in psi.iter_mut() {
            *p /= h;
        }
        Ok(StepResult {
            state: end,
            stage_velocities: v,
            stage_multipliers: psi,
            iterations,
            factorizations,
            warm_started,
        })
    }

    /// The starting guess. When this step continues earlier steps of the
    /// same size, the stage unknowns are extrapolated across steps by the
    /// polynomial through the last solutions (the stage values are smooth
    /// functions of `t₀` for fixed `h`, whatever the method's stage order:
    /// for Lobatto IIIA-B, `V₁ = V₂ ≈ v(t₀ + h/2)` is not `v` at the nodes).
    /// After a change of step size, the interpolating polynomial through the
    /// previous stage values at the nodes `c_j` is evaluated at the new nodes.
    /// Without a previous step: `V_i = v₀ + c_i h a₀`, `Ψ_i = ψ₀` from the
    /// consistent acceleration and multiplier.
    fn starting_guess(&mut self, state: &State<N>, h: f64) -> (Vector<D>, bool) {
        let c = &self.tableau.c;
        let mut z = Vector::<D>::zeros();
        if let Some(w) = self.warm.as_ref().filter(|w| self.options.warm_start && w.end == *state) {
            if w.h == h && w.depth >= 2 {
                // Newton backward differences: degree d uses d + 1 solutions.
                const COEFFS: [[f64; PAST]; PAST - 1] =
                    [[2.0, -1.0, 0.0, 0.0], [3.0, -3.0, 1.0, 0.0], [4.0, -6.0, 4.0, -1.0]];
                let degree = (w.depth - 1).min(self.options.extrapolation_degree.clamp(1, PAST - 1));
                for (k, coef) in COEFFS[degree - 1].iter().enumerate().take(degree + 1) {
                    z += *coef * w.back(k);
                }
                return (z, true);
            }
            let r = h / w.h;
            if r.abs() <= 4.0 {
                // Interpolating polynomial through the previous stage values
                // (nodes c_j in units of the previous step), evaluated at the
                // new stage times θ = 1 + c_i r and at the new end θ = 1 + r.
                let lagrange = |theta: f64, j: usize| -> f64 {
                    let mut l = 1.0;
                    for k in 0..S {
                        if k != j {
                            l *= (theta - c[k]) / (c[j] - c[k]);
                        }
                    }
                    l
                };
                let distinct = (0..S).all(|j| (0..j).all(|k| c[k] != c[j]));
                let last = w.back(0);
                for i in 0..=S {
                    let theta = if i < S { 1.0 + c[i] * r } else { 1.0 + r };
                    let mut vi = Vector::<N>::zeros();
                    let mut mi = Vector::<M>::zeros();
                    for j in 0..S {
                        let l = if distinct { lagrange(theta, j) } else { 1.0 / S as f64 };
                        vi += l * last.fixed_rows::<N>(j * N);
                        mi += l * last.fixed_rows::<M>(S * N + j * M);
                    }
                    if i < S {
                        z.fixed_rows_mut::<N>(i * N).copy_from(&vi);
                        // μ = hΨ: rescale to the new step size.
                        z.fixed_rows_mut::<M>(S * N + i * M).copy_from(&(mi * r));
                    } else {
                        z.fixed_rows_mut::<N>(S * (N + M)).copy_from(&vi);
                    }
                }
                return (z, true);
            }
        }
        // Scratch: the work storage's end-point Jacobians (heap, so no N×N
        // matrix goes on the stack); every full evaluation rewrites them
        // before the Newton matrix reads them.
        let mut vals = StageValues::zeros();
        let (a0, psi0) =
            consistent_acceleration_in(&self.system, state.t, &state.q, &state.v, &mut vals, &mut self.work.end)
                .unwrap_or((Vector::zeros(), Vector::zeros()));
        for i in 0..S {
            z.fixed_rows_mut::<N>(i * N).copy_from(&(state.v + (c[i] * h) * a0));
            z.fixed_rows_mut::<M>(S * N + i * M).copy_from(&(psi0 * h));
        }
        z.fixed_rows_mut::<N>(S * (N + M)).copy_from(&(state.v + h * a0));
        (z, false)
    }

    /// The Newton matrix of a step of size `h` from `state`, evaluated and
    /// assembled at the step's starting guess, with that guess's residual.
    ///
    /// For benchmarks and diagnostics of the linear algebra alone: time
    /// [`NewtonMatrix::factor`] and [`NewtonMatrix::solve_in_place`] on a
    /// clone. The stepper's warm start is left as it was.
    pub fn newton_matrix(&mut self, state: &State<N>, h: f64) -> (&NewtonMatrix<N, M, S, D>, Vector<D>) {
        let (z, _) = self.starting_guess(state, h);
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let carry = self.carry_for(state);
        let ev = Self::evaluate(&self.system, &self.tableau, state, &carry, h, &z, Some(&mut *self.work));
        let g = Self::residual(&self.tableau, &p0, h, &z, &ev);
        self.assemble_jacobian(h);
        self.reusable = None;
        (&self.newton, g)
    }

    /// Evaluates the stage points of `z`, optionally with Jacobians.
    fn evaluate(
        system: &Sys,
        tab: &Tableau<S>,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        jac: Option<&mut EvalJac<N, M, S>>,
    ) -> Eval<N, M, S> {
        let (v, mu) = split::<N, M, S, D>(z);
        let v1 = z.fixed_rows::<N>(S * (N + M)).into_owned();
        let zero_m = Vector::<M>::zeros();
        let mut ev = Eval { stages: [StageValues::zeros(); S], end: StageValues::zeros(), mid: None };
        let q1 = state.q + increment(carry, h, &tab.b, &v);
        let t1 = state.t + h;
        let mid_point = || {
            let tm = state.t + 0.5 * h;
            (tm, state.q + (carry + (0.5 * h) * v[0]))
        };
        let stage_q = |i: usize| state.q + increment(carry, h, &tab.a[i], &v);
        match jac {
            Some(jac) => {
                for i in 0..S {
                    let psi = mu[i] / h;
                    let (ti, qi) = (state.t + tab.c[i] * h, stage_q(i));
                    // In place, into the heap work storage: no N×N value on the stack.
                    let (vals, jac_i) = (&mut ev.stages[i], &mut *jac.stages[i]);
                    system.stage_jacobians_into(ti, &qi, &v[i], &psi, vals, jac_i);
                    if Sys::HAS_FORCING {
                        system.add_external_force_jacobians(ti, &qi, &v[i], vals, jac_i);
                    }
                    if Sys::HAS_NONIDEAL_FORCE {
                        let psi_jac = &mut jac.nonideal_psi[i];
                        system.add_nonideal_force_jacobians(ti, &qi, &v[i], &psi, vals, jac_i, psi_jac);
                    }
                }
                system.stage_jacobians_into(t1, &q1, &v1, &zero_m, &mut ev.end, &mut jac.end);
                if tab.conditions == ConditionRows::MidpointConstraint {
                    let (tm, qm) = mid_point();
                    let mj = jac.mid.get_or_insert_with(StageJacobians::boxed_zeros);
                    let mv = ev.mid.insert(StageValues::zeros());
                    system.stage_jacobians_into(tm, &qm, &v[0], &zero_m, mv, mj);
                }
            }
            None => {
                for i in 0..S {
                    let psi = mu[i] / h;
                    let (ti, qi) = (state.t + tab.c[i] * h, stage_q(i));
                    ev.stages[i] = system.stage_values(ti, &qi, &v[i], &psi);
                    if Sys::HAS_FORCING {
                        ev.stages[i].force += system.external_force(ti, &qi, &v[i]);
                    }
                    if Sys::HAS_NONIDEAL_FORCE {
                        ev.stages[i].constraint_force += system.nonideal_force(ti, &qi, &v[i], &psi);
                    }
                }
                ev.end = system.stage_values(t1, &q1, &v1, &zero_m);
                if tab.conditions == ConditionRows::MidpointConstraint {
                    let (tm, qm) = mid_point();
                    ev.mid = Some(system.stage_values(tm, &qm, &v[0], &zero_m));
                }
            }
        }
        ev
    }

    /// The SPARK residual `G(z)` (see the module docs for the row layout).
    fn residual(tab: &Tableau<S>, p0: &Vector<N>, h: f64, z: &Vector<D>, ev: &Eval<N, M, S>) -> Vector<D> {
        let mut g = Vector::<D>::zeros();
        let mut row = |i: usize, weights_hat: &[f64; S], weights_tilde: &[f64; S], momentum: &Vector<N>| {
            let mut r = momentum - p0;
            for j in 0..S {
                if weights_hat[j] != 0.0 {
                    r -= (h * weights_hat[j]) * ev.stages[j].force;
                }
                if weights_tilde[j] != 0.0 {
                    r -= (h * weights_tilde[j]) * ev.stages[j].constraint_force;
                }
            }
            g.fixed_rows_mut::<N>(i * N).copy_from(&r);
        };
        for i in 0..S {
            row(i, &tab.a_hat[i], &tab.a_tilde[i], &ev.stages[i].momentum);
        }
        row(S, &tab.b_hat, &tab.b_tilde, &ev.end.momentum);
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    let mut k = Vector::<M>::zeros();
                    for j in 0..S {
                        k += tab.omega[r][j] * ev.stages[j].constraint;
                    }
                    g.fixed_rows_mut::<M>(base + r * M).copy_from(&k);
                }
            }
            ConditionRows::MidpointConstraint => {
                if let Some(mid) = &ev.mid {
                    g.fixed_rows_mut::<M>(base).copy_from(&mid.constraint);
                }
            }
            ConditionRows::EqualMultipliers => {
                for r in 0..S.saturating_sub(1) {
                    let d = z.fixed_rows::<M>(S * N + r * M) - z.fixed_rows::<M>(S * N + (r + 1) * M);
                    g.fixed_rows_mut::<M>(base + r * M).copy_from(&d);
                }
            }
        }
        g.fixed_rows_mut::<M>(D - M).copy_from(&ev.end.constraint);
        g
    }

    /// The exact Jacobian `∂G/∂z`, skipping blocks the structure facts prove zero.
    fn assemble_jacobian(&mut self, h: f64) {
        let jac = &self.work;
        let tab = self.tableau;
        let st = Sys::STRUCTURE;
        // L = T(v) − U(q): ∂P/∂q = 0 and ∂F/∂v = 0 (unless a force f(t,q,v)
        // is added to F).
        let separable = st.separable && !Sys::HAS_FORCING;
        // K independent of v and no non-ideal force: ∂R/∂v = 0.
        let k_velocity_free = st.constraint_matrix_velocity_free() && !Sys::HAS_NONIDEAL_FORCE;
        if !self.pattern_written {
            // Which blocks are written below depends only on the tableau and
            // the structure facts, both fixed for this stepper: the structural
            // zeros and the constant entries are written once, and every later
            // assembly overwrites exactly the blocks that change (zeroing the
            // whole D×D matrix per iteration cost more than the blocks).
            self.newton.clear();
            if tab.conditions == ConditionRows::EqualMultipliers {
                let mut j = self.newton.matrix_mut();
                let base = S * N + N;
                for r in 0..S.saturating_sub(1) {
                    for d in 0..M {
                        j[(base + r * M + d, S * N + r * M + d)] = 1.0;
                        j[(base + r * M + d, S * N + (r + 1) * M + d)] = -1.0;
                    }
                }
            }
            self.pattern_written = true;
        }
        let mut j = self.newton.matrix_mut();
        let h2 = h * h;
        // Momentum rows: stage rows i < S use (a_i, â_i, ã_i); the p₁ row uses
        // (b, b̂, b̃) with its momentum evaluated at the end point. Each block
        // is accumulated in a contiguous local N×N matrix and stored once
        // (nalgebra's `zip_apply` on the strided D×D view went entry by entry:
        // ≈ 12 % of all instructions of an mp7 Gauss s = 4 step). Every entry
        // sees the same operations in the same order as before, so the matrix
        // is bit for bit the same.
        for i in 0..=S {
            let (a_row, ah_row, at_row) =
                if i < S { (&tab.a[i], &tab.a_hat[i], &tab.a_tilde[i]) } else { (&tab.b, &tab.b_hat, &tab.b_tilde) };
            let pq = if i < S { &jac.stages[i].momentum_q } else { &jac.end.momentum_q };
            for l in 0..S {
                // Small blocks accumulate in a fixed 2 KiB stack array: LLVM sees
                // that it aliases nothing and vectorizes the axpys (measured: the
                // heap scratch alone gave back the ≈ 5 % a step had gained at
                // N ≤ 7). Larger blocks use the heap scratch, so a step's stack
                // stays independent of N.
                let mut local = [0.0f64; SMALL_BLOCK];
                let blk: &mut [f64] = if N * N <= SMALL_BLOCK { &mut local[..N * N] } else { &mut self.block[..N * N] };
                if i == l {
                    blk.copy_from_slice(jac.stages[l].mass.as_slice());
                } else {
                    blk.fill(0.0);
                }
                if !separable {
                    if a_row[l] != 0.0 {
                        axpy(blk, h * a_row[l], pq);
                    }
                    if ah_row[l] != 0.0 {
                        axpy(blk, -h * ah_row[l], &jac.stages[l].force_v);
                    }
                }
                if !k_velocity_free && at_row[l] != 0.0 {
                    axpy(blk, -h * at_row[l], &jac.stages[l].constraint_force_v);
                }
                for m in 0..S {
                    let aml = tab.a[m][l];
                    if aml == 0.0 {
                        continue;
                    }
                    if ah_row[m] != 0.0 {
                        axpy(blk, -h2 * ah_row[m] * aml, &jac.stages[m].force_q);
                    }
                    if at_row[m] != 0.0 {
                        axpy(blk, -h2 * at_row[m] * aml, &jac.stages[m].constraint_force_q);
                    }
                }
                for c in 0..N {
                    j.fixed_view_mut::<N, 1>(i * N, l * N + c).as_mut_slice().copy_from_slice(&blk[c * N..(c + 1) * N]);
                }
                // ∂(−h ã_il R_l)/∂μ_l = ã_il K_lᵀ (R_l = −K_lᵀ μ_l / h);
                // with N(ψ = μ/h) also −ã_il ∂N_l/∂ψ.
                if at_row[l] != 0.0 {
                    let mut kt = j.fixed_view_mut::<N, M>(i * N, S * N + l * M);
                    kt.tr_copy_from(&jac.stages[l].constraint_v);
                    if Sys::HAS_NONIDEAL_FORCE {
                        kt -= &jac.nonideal_psi[l];
                    }
                    kt *= at_row[l];
                }
            }
        }
        // ∂p₁/∂v₁.
        j.fixed_view_mut::<N, N>(S * N, S * (N + M)).copy_from(&jac.end.mass);
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for l in 0..S {
                        let mut blk = tab.omega[r][l] * jac.stages[l].constraint_v;
                        for m in 0..S {
                            let c = tab.omega[r][m] * tab.a[m][l];
                            if c != 0.0 {
                                blk += (h * c) * jac.stages[m].constraint_q;
                            }
                        }
                        j.fixed_view_mut::<M, N>(base + r * M, l * N).copy_from(&blk);
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                if let Some(mj) = &jac.mid {
                    let blk = mj.constraint_v + (0.5 * h) * mj.constraint_q;
                    j.fixed_view_mut::<M, N>(base, 0).copy_from(&blk);
                }
            }
            // Constant ±1 entries, written with the structural zeros.
            ConditionRows::EqualMultipliers => {}
        }
        for l in 0..S {
            j.fixed_view_mut::<M, N>(D - M, l * N).copy_from(&((h * tab.b[l]) * jac.end.constraint_q));
        }
        j.fixed_view_mut::<M, N>(D - M, S * (N + M)).copy_from(&jac.end.constraint_v);
    }

    /// Factors the stage-decoupled matrix at `z`. `lean`: the latest
    /// evaluation computed no stage Jacobians, so the constraint Jacobians
    /// are evaluated here (and the constant mass matrix once, while its
    /// factors are not kept); otherwise they are copied from `self.work`.
    fn factor_decoupled(
        &mut self,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        lean: bool,
    ) -> Result<(), crate::linalg::Singular> {
        let tab = &self.tableau;
        let dec = &mut self.decoupled;
        let work = &mut *self.work;
        if !lean {
            for i in 0..S {
                dec.constraint_v[i] = work.stages[i].constraint_v;
                dec.constraint_q[i] = work.stages[i].constraint_q;
            }
            dec.constraint_v[S] = work.end.constraint_v;
            dec.constraint_q[S] = work.end.constraint_q;
            if let Some(mj) = &work.mid {
                dec.constraint_v[S + 1] = mj.constraint_v;
                dec.constraint_q[S + 1] = mj.constraint_q;
            }
            let masses = Masses::PerPoint { stages: &work.stages, end: &work.end };
            let nonideal = Sys::HAS_NONIDEAL_FORCE.then_some(&work.nonideal_psi[..]);
            return dec.factor(tab, h, masses, nonideal);
        }
        let (v, _) = split::<N, M, S, D>(z);
        let v1 = z.fixed_rows::<N>(S * (N + M)).into_owned();
        let sys = &self.system;
        for i in 0..S {
            let (ti, qi) = (state.t + tab.c[i] * h, state.q + increment(carry, h, &tab.a[i], &v));
            dec.constraint_v[i] = sys.constraint_v(ti, &qi, &v[i]);
            dec.constraint_q[i] = sys.constraint_q(ti, &qi, &v[i]);
        }
        let (t1, q1) = (state.t + h, state.q + increment(carry, h, &tab.b, &v));
        dec.constraint_v[S] = sys.constraint_v(t1, &q1, &v1);
        dec.constraint_q[S] = sys.constraint_q(t1, &q1, &v1);
        if tab.conditions == ConditionRows::MidpointConstraint {
            let (tm, qm) = (state.t + 0.5 * h, state.q + (carry + (0.5 * h) * v[0]));
            dec.constraint_v[S + 1] = sys.constraint_v(tm, &qm, &v[0]);
            dec.constraint_q[S + 1] = sys.constraint_q(tm, &qm, &v[0]);
        }
        if dec.has_constant_mass() {
            return dec.factor(tab, h, Masses::Cached, None);
        }
        // The mass matrix is constant: one evaluation into the heap work
        // storage (no N×N value on the stack) gives it for every block.
        let mut vals = StageValues::zeros();
        sys.stage_jacobians_into(t1, &q1, &v1, &Vector::zeros(), &mut vals, &mut work.end);
        dec.factor(tab, h, Masses::Constant(&work.end.mass), None)
    }

    /// Newton's method on `G(z) = 0`; records the iterations in `self.history`
    /// and returns the number of factorizations.
    ///
    /// # Stopping
    /// Every update `Δz` is computed with some factors `F` of a Newton
    /// matrix. With the error `e = z − z*` and the contraction `θ = ‖I − F⁻¹J̄‖`
    /// of those factors (`J̄` the mean Jacobian between `z` and `z*`),
    /// `(1 − θ)‖e‖ ≤ ‖Δz‖` and the error left after the update is at most
    /// `θ/(1 − θ)·‖Δz‖`. So an update within the tolerance ends the solve
    /// whenever `θ ≤ ½`: the simplified Newton refresh guarantees that bound
    /// for its frozen factors, and full Newton's fresh factors contract at
    /// `θ = O(‖Δz_prev‖)`.
    ///
    /// Simplified Newton factors the exact Jacobian or the stage-decoupled
    /// matrix ([`Jacobian`]); the latter gives way to the exact one when the
    /// rate it sustains over two updates exceeds `DECOUPLED_RATE`, when its
    /// updates grow, or when it cannot reach the tolerance within the
    /// iteration limit.
    ///
    /// Larger updates end the solve only on a contraction rate the iteration
    /// has earned (see [`Contraction`]): three updates on the same factors,
    /// because the first ratio on new factors can be far below `θ` (unknowns
    /// entering linearly, the multipliers, are corrected at once, and the
    /// first update is mostly theirs).
    fn newton(&mut self, state: &State<N>, carry: &Vector<N>, h: f64, z: &mut Vector<D>) -> Result<usize, StepError> {
        let t = state.t;
        let opts = self.options;
        let p0 = self.system.momentum(t, &state.q, &state.v);
        let max_iter = opts.max_iterations.clamp(1, HISTORY_CAPACITY);
        self.history.clear();
        // The latest applied update (whatever its factors), for divergence
        // and stagnation.
        let mut prev_update = f64::NAN;
        let fail_nonfinite =
            |stage, history: &NewtonHistory| StepError::NonFinite { t, h, stage, history: Box::new(*history) };
        let simplified = opts.mode == NewtonMode::Simplified;
        // Which matrix this step factors: the stage-decoupled one where the
        // options and structure facts ask for it, unless it was slow or
        // singular within the last `EXACT_AFTER_DECOUPLED_FAILS` steps.
        let wants_decoupled = simplified
            && match opts.jacobian {
                Jacobian::Exact => false,
                Jacobian::StageDecoupled => true,
                Jacobian::Auto => Self::DECOUPLES,
            };
        let mut decoupled = wants_decoupled && self.exact_steps_left == 0;
        self.exact_steps_left = self.exact_steps_left.saturating_sub(1);
        // `stale`: the factors of this step's matrix come from an earlier step.
        let stale =
            simplified && opts.reuse_factorization && self.reusable == Some((h, decoupled)) && self.is_warm_for(state);
        self.reusable = None;
        let mut refresh = !stale;
        // Iteration at which the current factors were computed, and whether
        // that was a refresh within this step (simplified Newton only).
        let (mut factored_at, mut refreshed) = (0usize, false);
        let mut max_rate = 0.0f64;
        let mut factorizations = 0usize;
        let mut monitor = Contraction::FRESH;
        let result = 'solve: {
            for k in 0..max_iter {
                let fresh = refresh || !simplified;
                if refresh && k > 0 {
                    refreshed = true;
                }
                refresh = false;
                // A lean decoupled refresh needs only the constraint Jacobians
                // (below), not the stage Jacobians of a full evaluation.
                let lean = fresh && decoupled && Self::LEAN_DECOUPLED;
                let full_jacobians = fresh && !lean;
                let ev = Self::evaluate(
                    &self.system,
                    &self.tableau,
                    state,
                    carry,
                    h,
                    z,
                    full_jacobians.then_some(&mut *self.work),
                );
                let mut g = Self::residual(&self.tableau, &p0, h, z, &ev);
                let residual = g.amax();
                if !g.iter().all(|x| x.is_finite()) {
                    self.history.push(IterationRecord { residual: f64::NAN, update: f64::NAN, rate: f64::NAN });
                    return Err(fail_nonfinite("residual", &self.history));
                }
                if fresh {
                    factorizations += 1;
                    monitor = Contraction::FRESH;
                    factored_at = k;
                    if decoupled && self.factor_decoupled(state, carry, h, z, lean).is_err() {
                        decoupled = false;
                        self.exact_steps_left = EXACT_AFTER_DECOUPLED_FAILS;
                    }
                }
                if fresh && !decoupled {
                    self.assemble_jacobian(h);
                    if let Err(s) = self.newton.factor() {
                        self.history.push(IterationRecord { residual, update: f64::NAN, rate: f64::NAN });
                        return Err(if self.newton.matrix().iter().all(|x| x.is_finite()) {
                            StepError::SingularMatrix {
                                t,
                                h,
                                detail: singular_detail::<N, M, S>(
                                    s.column,
                                    s.pivot,
                                    self.newton.matrix().column(s.column).amax(),
                                ),
                                history: Box::new(self.history),
                            }
                        } else {
                            fail_nonfinite("Jacobian", &self.history)
                        });
                    }
                }
                if decoupled {
                    self.decoupled.solve_in_place(&mut g);
                } else {
                    self.newton.solve_in_place(&mut g);
                }
                // Only iterations on factors from an earlier iterate may be undone.
                let z_before = if fresh { None } else { Some(*z) };
                *z -= g;
                let update = scaled_update_norm(&g, z);
                let rate = update / prev_update;
                monitor.record(update);
                self.history.push(IterationRecord { residual, update, rate });
                if rate.is_finite() {
                    max_rate = max_rate.max(rate);
                }
                if let Some(z_before) = z_before {
                    // Factors from an earlier iterate (this step's frozen
                    // Jacobian, or an earlier step's) that grow, contract slower
                    // than REFRESH_RATE, or too slowly to reach the tolerance
                    // within the iteration limit: take a fresh Jacobian at the
                    // last good iterate (the standard remedy of simplified
                    // Newton) instead of crawling into MaxIterations or reporting
                    // a divergence full Newton would not have. Not when this
                    // iteration is accepted below anyway, nor at round-off level
                    // (no Jacobian helps there), nor on the first iteration of an
                    // earlier step's factors (no rate yet).
                    let remaining = (max_iter - 1 - k) as i32;
                    // The stage-decoupled matrix is judged on the rate it keeps
                    // to over two updates (one ratio says little), and gives
                    // way to the exact matrix: a refresh of it cannot change
                    // the rate its dropped couplings set.
                    let (judged, limit) =
                        if decoupled { (monitor.sustained(), DECOUPLED_RATE) } else { (rate, REFRESH_RATE) };
                    let too_slow = rate.is_nan()
                        || rate >= 1.0
                        || judged > limit
                        || update * judged.powi(remaining + 1) / (1.0 - judged) > opts.tolerance;
                    let converged = monitor.converged(update, opts.tolerance);
                    let round_off = update <= opts.stagnation_level;
                    let first_stale = k == 0 && update.is_finite();
                    if too_slow && !converged && !round_off && !first_stale {
                        let growing = rate.is_nan() || rate >= 1.0;
                        if decoupled {
                            // The dropped couplings are not small at this
                            // step: continue with the exact matrix from the
                            // last good iterate.
                            decoupled = false;
                            self.exact_steps_left = EXACT_AFTER_DECOUPLED_FAILS;
                            if growing {
                                *z = z_before;
                            }
                            refresh = true;
                            prev_update = f64::NAN;
                            continue;
                        }
                        if growing && refreshed && factored_at + 1 == k {
                            // Even a Jacobian refreshed at the previous iterate did
                            // not contract: give up as full Newton would.
                            return Err(if update.is_finite() {
                                StepError::Diverged { t, h, history: Box::new(self.history) }
                            } else {
                                fail_nonfinite("update", &self.history)
                            });
                        }
                        if growing {
                            *z = z_before;
                        }
                        refresh = true;
                        prev_update = f64::NAN;
                        continue;
                    }
                }
                if !update.is_finite() {
                    return Err(fail_nonfinite("update", &self.history));
                }
                let converged = if simplified {
                    monitor.converged(update, opts.tolerance)
                } else {
                    full_newton_converged(update, rate, opts.tolerance)
                };
                if converged {
                    break 'solve Ok(());
                }
                if k > 0 && rate >= 1.0 {
                    if update <= opts.stagnation_level {
                        break 'solve Ok(());
                    }
                    return Err(StepError::Diverged { t, h, history: Box::new(self.history) });
                }
                prev_update = update;
            }
            Err(StepError::MaxIterations { t, h, history: Box::new(self.history) })
        };
        if result.is_ok() && simplified && max_rate <= REUSE_RATE {
            self.reusable = Some((h, decoupled));
        }
        result.map(|()| factorizations)
    }
}

#[cfg(test)]
impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The residual and the assembled Jacobian at `z` (for derivative tests).
    pub(crate) fn residual_and_jacobian(
        &mut self,
        state: &State<N>,
        h: f64,
        z: &Vector<D>,
    ) -> (Vector<D>, Matrix<D, D>) {
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let carry = self.carry_for(state);
        let ev = Self::evaluate(&self.system, &self.tableau, state, &carry, h, z, Some(&mut *self.work));
        let g = Self::residual(&self.tableau, &p0, h, z, &ev);
        self.assemble_jacobian(h);
        (g, self.newton.matrix().into_owned())
    }

    /// For the stage-decoupled matrix's tests: the residual `g` at `z`, the
    /// stage-decoupled matrix written out densely from the exact Jacobian
    /// (velocity blocks between different stages zeroed, each stage's own
    /// velocity block replaced by its mass matrix), and the solve of `g` by
    /// [`DecoupledMatrix`] (`lean`: from the constraint Jacobians alone).
    pub(crate) fn decoupled_solve(
        &mut self,
        state: &State<N>,
        h: f64,
        z: &Vector<D>,
        lean: bool,
    ) -> Result<(Vector<D>, Matrix<D, D>, Vector<D>), crate::linalg::Singular> {
        let (g, mut approx) = self.residual_and_jacobian(state, h, z);
        for i in 0..=S {
            for l in 0..=S {
                let col = if l < S { l * N } else { S * (N + M) };
                let mass = match (i == l, i < S) {
                    (false, _) => Matrix::<N, N>::zeros(),
                    (true, true) => self.work.stages[i].mass,
                    (true, false) => self.work.end.mass,
                };
                approx.fixed_view_mut::<N, N>(i * N, col).copy_from(&mass);
            }
        }
        if lean {
            self.decoupled.invalidate();
        }
        let carry = self.carry_for(state);
        self.factor_decoupled(state, &carry, h, z, lean)?;
        let mut x = g;
        self.decoupled.solve_in_place(&mut x);
        Ok((g, approx, x))
    }

    /// Steps left on the exact matrix after the stage-decoupled one failed.
    pub(crate) fn exact_steps_left(&self) -> u32 {
        self.exact_steps_left
    }

    /// The residual at `z`.
    pub(crate) fn residual_at(&self, state: &State<N>, h: f64, z: &Vector<D>) -> Vector<D> {
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let ev = Self::evaluate(&self.system, &self.tableau, state, &self.carry_for(state), h, z, None);
        Self::residual(&self.tableau, &p0, h, z, &ev)
    }
}

/// Describes a failed pivot: the column, its unknown of `z` (1-based stage
/// and component as in the paper: `V_i[d]`, `hΨ_i[d]` or `v1[d]`), the pivot
/// and the column's largest magnitude `scale`.
fn singular_detail<const N: usize, const M: usize, const S: usize>(column: usize, pivot: f64, scale: f64) -> Box<str> {
    let name = if column < S * N {
        format!("V_{}[{}]", column / N + 1, column % N + 1)
    } else if column < S * (N + M) {
        let c = column - S * N;
        format!("hΨ_{}[{}]", c / M + 1, c % M + 1)
    } else {
        format!("v1[{}]", column - S * (N + M) + 1)
    };
    format!("column {column} ({name}): pivot {pivot:.3e} is below 64 eps x its largest entry {scale:.3e}")
        .into_boxed_str()
}

/// Full Newton's stopping rule: the update itself, or the error left after
/// it estimated as `θ/(1−θ)·‖Δz‖` from the ratio `θ` of the last two updates,
/// is within `tolerance`. Each update of full Newton uses a fresh Jacobian, so
/// the ratio is that of the iteration itself, and it can only overstate the
/// error left by a quadratically converging one; at stiff steps, where the
/// updates reach their round-off floor above the tolerance, it stops before
/// round-off makes them grow. Simplified Newton uses the rate it has earned on
/// its frozen factors instead ([`Contraction::converged`]).
fn full_newton_converged(update: f64, rate: f64, tolerance: f64) -> bool {
    update <= tolerance || (rate < 1.0 && update * rate / (1.0 - rate) <= tolerance)
}

/// Largest `N·N` whose Newton-matrix blocks are accumulated on the stack.
const SMALL_BLOCK: usize = 256;

/// `acc += coef · x`, entry by entry on contiguous storage (nalgebra's
/// `zip_apply` on a strided view of the D×D matrix did not vectorize);
/// `acc` is an `N·N` block scratch (column-major).
#[inline(always)]
fn axpy<const N: usize>(acc: &mut [f64], coef: f64, x: &Matrix<N, N>) {
    for (a, x) in acc[..N * N].iter_mut().zip(x.as_slice()) {
        *a += coef * x;
    }
}

/// `carry + Σ_j (h c_j) V_j`: the increment of `q` summed on its own (at
/// the size of `hV`), so that adding it to `q₀` rounds once at the size of
/// `q` instead of once per stage — those `S` roundings of nearly the same
/// increments every step were the systematic part of the drift.
#[inline(always)]
fn increment<const N: usize, const S: usize>(carry: &Vector<N>, h: f64, c: &[f64; S], v: &[Vector<N>; S]) -> Vector<N> {
    let mut d = *carry;
    for j in 0..S {
        if c[j] != 0.0 {
            d += (h * c[j]) * v[j];
        }
    }
    d
}

/// `(a + b) − s` exactly for `s = fl(a + b)`, per component (Knuth's
/// TwoSum: no assumption on the magnitudes of `a` and `b`).
#[inline(always)]
fn two_sum_error<const N: usize>(a: &Vector<N>, b: &Vector<N>, s: &Vector<N>) -> Vector<N> {
    Vector::<N>::from_fn(|i, _| {
        let bb = s[i] - a[i];
        (a[i] - (s[i] - bb)) + (b[i] - bb)
    })
}

/// Splits `z` into stage velocities and scaled multipliers `μ_i = hΨ_i`.
fn split<const N: usize, const M: usize, const S: usize, const D: usize>(
    z: &Vector<D>,
) -> ([Vector<N>; S], [Vector<M>; S]) {
    let mut v = [Vector::<N>::zeros(); S];
    let mut mu = [Vector::<M>::zeros(); S];
    for i in 0..S {
        v[i] = z.fixed_rows::<N>(i * N).into_owned();
        mu[i] = z.fixed_rows::<M>(S * N + i * M).into_owned();
    }
    (v, mu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::handwritten::{MobileRobot, Particle};
    use crate::Method;

    /// Runs `steps` steps of size `h`; the states, or the first error.
    fn run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
        st: &mut Stepper<Sys, N, M, S, D>,
        start: State<N>,
        h: f64,
        steps: usize,
    ) -> Result<(State<N>, bool), StepError>
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let mut s = start;
        let mut refreshed = false;
        for _ in 0..steps {
            s = st.step(&s, h)?.state;
            // A refresh restarts the rate: NaN after the first iteration.
            refreshed |= st.last_history().iterations().iter().skip(1).any(|r| r.rate.is_nan());
        }
        Ok((s, refreshed))
    }

    /// Large steps where the Jacobian frozen at the starting guess contracts
    /// too slowly: the robot at h = 1 (Gauss s = 2) diverged at its seventh
    /// step, the particle at h = 0.7 ran into the iteration limit at its
    /// fourth, while full Newton solves both. Refreshing the Jacobian at the
    /// current iterate reaches full Newton's solution.
    #[test]
    fn simplified_newton_refreshes_a_slow_jacobian() {
        let simplified = NewtonOptions { mode: NewtonMode::Simplified, energy_drift_limit: None, ..Default::default() };
        let full = NewtonOptions { mode: NewtonMode::Full, ..simplified };
        let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let mut a = Stepper::<_, 4, 2, 2, 16>::new(MobileRobot::default(), tab).with_options(full);
        let mut b = Stepper::<_, 4, 2, 2, 16>::new(MobileRobot::default(), tab).with_options(simplified);
        let (ra, _) = run(&mut a, robot, 1.0, 20).expect("full Newton");
        let (rb, refreshed) = run(&mut b, robot, 1.0, 20).expect("simplified Newton with refresh");
        assert!(refreshed, "the robot at h = 1 must need a refresh");
        assert!((ra.q - rb.q).amax() < 1e-10 && (ra.v - rb.v).amax() < 1e-10, "{ra:?} vs {rb:?}");

        let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        let mut a = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab).with_options(full);
        let mut b = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab).with_options(simplified);
        let (ra, _) = run(&mut a, particle, 0.7, 20).expect("full Newton");
        let (rb, refreshed) = run(&mut b, particle, 0.7, 20).expect("simplified Newton with refresh");
        assert!(refreshed, "the particle at h = 0.7 must need a refresh");
        assert!((ra.q - rb.q).amax() < 1e-10 && (ra.v - rb.v).amax() < 1e-10, "{ra:?} vs {rb:?}");
    }

    /// A step whose equations even refreshed Jacobians cannot solve is still
    /// a typed divergence with its history, not an endless refresh.
    #[test]
    fn hopeless_simplified_steps_still_diverge() {
        let simplified = NewtonOptions { mode: NewtonMode::Simplified, energy_drift_limit: None, ..Default::default() };
        let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let mut st = Stepper::<_, 4, 2, 2, 16>::new(MobileRobot::default(), tab).with_options(simplified);
        let err = run(&mut st, robot, 2.0, 20).expect_err("h = 2 is beyond Newton's reach here");
        let StepError::Diverged { history, .. } = &err else { panic!("{err}") };
        assert!(history.len() < NewtonOptions::default().max_iterations, "{err}");
        assert_eq!(format!("{:?}", st.last_history()), format!("{history:?}"));
    }

    /// Normal steps never refresh: one Jacobian per step, on the exact and
    /// on the stage-decoupled matrix.
    #[test]
    fn paper_steps_keep_one_jacobian_per_step() {
        for jacobian in [Jacobian::Exact, Jacobian::StageDecoupled] {
            let simplified = NewtonOptions { mode: NewtonMode::Simplified, jacobian, ..Default::default() };
            let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
            let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
            let mut st = Stepper::<_, 4, 2, 3, 22>::new(MobileRobot::default(), tab).with_options(simplified);
            let (_, refreshed) = run(&mut st, robot, 0.2, 50).unwrap();
            assert!(!refreshed, "{jacobian:?}");
        }
    }
}

/// The stopping rule and the checks of a cold start.
#[cfg(test)]
mod stop_tests {
    use super::*;
    use crate::handwritten::{MpParticles, Particle};
    use crate::Method;

    /// Full Newton to the round-off floor: with tolerance 0 it stops only
    /// where the updates stop shrinking.
    fn tight() -> NewtonOptions {
        NewtonOptions { tolerance: 0.0, max_iterations: HISTORY_CAPACITY, ..NewtonOptions::default() }
    }

    /// Largest difference of the states and multipliers of two steps.
    fn distance<const N: usize, const M: usize, const S: usize>(
        a: &StepResult<N, M, S>,
        b: &StepResult<N, M, S>,
    ) -> (f64, f64, f64) {
        let psi = (0..S).map(|i| (a.stage_multipliers[i] - b.stage_multipliers[i]).amax()).fold(0.0, f64::max);
        ((a.state.q - b.state.q).amax(), (a.state.v - b.state.v).amax(), psi)
    }

    /// McLachlan–Perlmutter particles from `v₀ = 0`, Lobatto IIIA-B-D s = 2,
    /// h = 0.1: the first update (mostly the multiplier) is followed by one
    /// 1.8e-7 times smaller, while the frozen Jacobian contracts at 3.5e-3.
    /// A stop on that first ratio leaves q₁ wrong by 4e-12, Ψ by 8e-10 and
    /// |k(t₁,q₁,v₁)| = 6.5e-14; both modes must match the tight solve.
    #[test]
    fn simplified_newton_does_not_stop_on_a_first_rate() {
        let q0 = Vector::<7>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
        let start = State::new(0.0, q0, Vector::<7>::zeros());
        let tab = Tableau::<2>::new(Method::LobattoIIIABD).unwrap();
        let step =
            |opts| Stepper::<_, 7, 1, 2, 23>::new(MpParticles, tab).with_options(opts).step(&start, 0.1).unwrap();
        let reference = step(tight());
        for (mode, jacobian) in [(NewtonMode::Full, Jacobian::Auto), (NewtonMode::Simplified, Jacobian::Exact)] {
            let r = step(NewtonOptions { mode, jacobian, ..NewtonOptions::default() });
            let (dq, dv, dpsi) = distance(&r, &reference);
            let k = MpParticles.constraint(r.state.t, &r.state.q, &r.state.v).amax();
            assert!(
                dq <= 1e-15 && dv <= 1e-15 && dpsi <= 1e-14 && k <= 1e-16,
                "{mode:?}: {dq:e} {dv:e} {dpsi:e} |k| {k:e}"
            );
        }
        // The stage-decoupled matrix contracts linearly (rate ≈ 1e-2 here),
        // so its last update is not far below the tolerance: it ends within
        // the tolerance 16ε of the tight solve in q, v and the unknowns
        // μ = hΨ, not orders of magnitude below it.
        let opts =
            NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::StageDecoupled, ..Default::default() };
        let r = step(opts);
        let (dq, dv, dpsi) = distance(&r, &reference);
        let k = MpParticles.constraint(r.state.t, &r.state.q, &r.state.v).amax();
        let tol = opts.tolerance;
        assert!(
            dq <= tol && dv <= tol && 0.1 * dpsi <= tol && k <= 1e-16,
            "decoupled: {dq:e} {dv:e} {dpsi:e} |k| {k:e}"
        );
    }

    /// A cold start from a state that violates the constraint is refused
    /// (solving the step would remove the inconsistent velocity with an
    /// impulse at its end); consistent states pass even at velocities
    /// of 1e6 whose residual is round-off of that size; a step that
    /// continues the previous one is not checked.
    #[test]
    fn cold_start_refuses_an_inconsistent_state() {
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab);
        // k = v₃ − q₂v₁ = 0.5.
        let bad = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(1.0, 0.0, 1.0));
        let err = st.step(&bad, 0.1).unwrap_err();
        let StepError::InconsistentStart { residual, tolerance, .. } = err else { panic!("{err}") };
        assert!(residual == 0.5 && tolerance == 1e-12 * 1.5, "{err}");
        assert!(err.to_string().contains("consistent_velocity"), "{err}");
        // Scaled by the size of the terms: |k| = 1.2e-10 next to terms of 1e6.
        let fast = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(1e6, 0.0, 0.5e6 + 1.2e-10));
        let r = st.step(&fast, 1e-7).unwrap();
        // Continuing from the end is not checked, even with a tolerance only
        // an exact zero meets.
        st.options_mut().consistency_tolerance = 0.0;
        assert!(st.step(&r.state, 1e-7).is_ok());
        // A cold start with that tolerance is checked.
        assert!(matches!(st.step(&fast, 1e-7), Err(StepError::InconsistentStart { .. })));
    }
}

/// Round-off over long runs (see [`Compensation`]).
#[cfg(test)]
mod drift_tests {
    use super::*;
    use crate::handwritten::Skate;
    use crate::{Method, NoObserver, Observe, RunOptions, Schedule};

    /// The skate from `q = 0`, `v = (0, 0, 1)` (β = π/2, unit parameters):
    /// `θ = t`, speed along the blade `sin t`, so `x = (1 − cos 2t)/4`,
    /// `y = t/2 − sin(2t)/4`.
    fn skate_exact(t: f64) -> (Vector<3>, Vector<3>) {
        let q = Vector::<3>::new((1.0 - (2.0 * t).cos()) / 4.0, t / 2.0 - (2.0 * t).sin() / 4.0, t);
        (q, Vector::<3>::new(t.sin() * t.cos(), t.sin() * t.sin(), 1.0))
    }

    /// 32768 steps of Lobatto IIIA-B s = 3 over T = 10 (truncation error
    /// ≈ 3e-16): the global error must stay at the round-off level of a
    /// random walk, `ε·√n·max|q|` ≈ 4e-13. Before the increment was summed on
    /// its own and compensated, the rounding of `q₀ + hΣb_jV_j` accumulated
    /// linearly: 1.2e-11 here (measured 1.8e-15 / 1.6e-15 after).
    #[test]
    fn long_fixed_step_runs_do_not_drift() {
        let (t_end, steps) = (10.0, 32768);
        let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
        let mut st = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab);
        let (q0, v0) = skate_exact(0.0);
        let quiet = RunOptions {
            observe: Observe { energy: false, constraint_residual: false, multipliers: false },
            record_every: 0,
            ..RunOptions::default()
        };
        let schedule = Schedule::Fixed { h: t_end / steps as f64, steps };
        let end = st.integrate(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver).unwrap().last().unwrap();
        let (q, v) = skate_exact(t_end);
        let bound = f64::EPSILON * (steps as f64).sqrt() * q.amax();
        let (eq, ev) = ((end.q - q).amax(), (end.v - v).amax());
        assert!(eq <= bound && ev <= bound, "error q {eq:.2e}, v {ev:.2e} above {bound:.2e}");
    }

    /// A step from a state other than the latest end carries nothing: the
    /// same step from the same state gives the same result whatever ran before
    /// (the warm start is off, so only the compensation could differ).
    #[test]
    fn compensation_applies_only_to_the_continued_state() {
        let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
        let cold = NewtonOptions { warm_start: false, ..NewtonOptions::default() };
        let (q0, v0) = skate_exact(0.0);
        let start = State::new(0.0, q0, v0);
        let mut fresh = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab).with_options(cold);
        let mut used = fresh.clone();
        let mut s = start;
        for _ in 0..100 {
            s = used.step(&s, 0.01).unwrap().state;
        }
        let a = fresh.step(&start, 0.01).unwrap().state;
        let b = used.step(&start, 0.01).unwrap().state;
        assert_eq!(a, b);
    }

    #[test]
    fn two_sum_error_is_exact_whichever_operand_is_larger() {
        let a = Vector::<2>::new(1.0, 1e-17);
        let b = Vector::<2>::new(1e-17, 1.0);
        let s = a + b;
        assert_eq!(s, Vector::<2>::new(1.0, 1.0));
        assert_eq!(two_sum_error(&a, &b, &s), Vector::<2>::new(1e-17, 1e-17));
        // 1 + 2⁻⁵³ + 2⁻⁶⁰ rounds up to 1 + 2⁻⁵²: the error is −2⁻⁵³ + 2⁻⁶⁰.
        let (x, y) = (Vector::<1>::new(1.0), Vector::<1>::new(2f64.powi(-53) + 2f64.powi(-60)));
        let s = x + y;
        assert_eq!(s[0], 1.0 + f64::EPSILON);
        assert_eq!(two_sum_error(&x, &y, &s)[0], -(2f64.powi(-53)) + 2f64.powi(-60));
    }
}
