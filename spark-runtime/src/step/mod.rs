//! The SPARK step (paper eq. 6.1): the [`Stepper`], the [`State`] it steps
//! and the [`StepResult`] it returns. The pieces of a step live beside it:
//! the starting guess (`guess`), the residual and Jacobian of eq. 6.1
//! (`equations`), Newton's method on them (`newton`) with its stopping rule
//! (`convergence`), the checks of a cold start (`cold_start`), the homotopy
//! in the step size of a step that Newton solves from none of its guesses
//! (`homotopy`), the energy guard (`energy_guard`) and the compensated
//! summation of `q` across steps (`compensation`).
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
//! system without them compiles to code with neither branch and pays
//! nothing for them).
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

#[cfg(test)]
mod affine_tests;
pub(crate) mod cold_start;
mod compensation;
mod convergence;
mod energy_guard;
mod equations;
mod guess;
mod homotopy;
mod lane_handover;
mod newton;

pub use newton::{Jacobian, NewtonMode, NewtonOptions};

pub(crate) use compensation::{two_sum_error, two_sum_error_of};
pub(crate) use convergence::{
    affine_along_lanes, moved_beyond, rounding_moved, too_slow, AffinePlan, Contraction, LANDING_LIMIT,
};
pub(crate) use energy_guard::{check_energy, energy_is_invariant, EnergyAnchor};
pub(crate) use guess::{extrapolation_degree, StepPolynomial, EXTRAPOLATION, MAX_EXTRAPOLATION_DEGREE, PAST};
pub(crate) use lane_handover::LaneContinuation;

use crate::error::{NewtonHistory, StepError};
use crate::linalg::decoupled::DecoupledMatrix;
use crate::linalg::newton_matrix::NewtonMatrix;
use crate::linalg::stiff_stages::kept_stiffness_points;
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::tableau::Tableau;
use cold_start::check_cold_start;
use compensation::Compensation;
use equations::{increment, split, Eval, EvalJac};
use guess::{Guess, Warm, SAFE_EXTRAPOLATION_DEGREE};
use homotopy::Homotopy;
use newton::{Solved, Unsolved};

/// A point `(t, q, v)` of the phase space.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct State<const N: usize> {
    /// Time.
    pub t: f64,
    /// Generalized coordinates.
    pub q: Vector<N>,
    /// Generalized velocities.
    pub v: Vector<N>,
}

/// Equal when `t` and every component of `q` and `v` compare equal (so never
/// with a NaN), as a derived comparison would be. A step compares its start
/// with the previous step's end several times, so the comparisons are
/// combined with bitwise `&` rather than a branch each.
impl<const N: usize> PartialEq for State<N> {
    fn eq(&self, other: &Self) -> bool {
        let mut equal = self.t == other.t;
        for i in 0..N {
            equal &= (self.q[i] == other.q[i]) & (self.v[i] == other.v[i]);
        }
        equal
    }
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
    /// iteration, except a last update computed with the previous
    /// iteration's factors; simplified Newton: once, plus refreshes and a switch from
    /// the stage-decoupled to the exact matrix; none when it reuses an
    /// earlier step's factors).
    pub factorizations: usize,
    /// Whether the starting guess came from the previous step.
    pub warm_started: bool,
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
    warm: Option<Warm<D>>,
    /// The Newton matrix and its factors (heap, allocated once).
    newton: NewtonMatrix<N, M, S, D>,
    /// Stage Jacobians of the latest full evaluation (heap, allocated once:
    /// `(S+2)·8·N²` doubles would dominate the stepper's size).
    work: Box<EvalJac<N, M, S>>,
    /// The stage values of the latest evaluation (see `equations::Eval`).
    eval: Eval<N, M, S>,
    /// Scratch for one `N × N` block of the Newton matrix while it is
    /// accumulated (heap, allocated once: a local `Matrix<N, N>` put
    /// `2·8·N²` bytes on the stack, 4.4 MiB at n = 513).
    block: Box<[f64]>,
    /// The stage-decoupled Newton matrix's factors (heap, allocated once).
    decoupled: DecoupledMatrix<N, M, S>,
    /// The starting guess of a continuing Gauss step (`None` for the other
    /// families, which extrapolate across steps).
    step_polynomial: Option<StepPolynomial<S>>,
    /// The stage points whose stiffness the stage-decoupled matrix keeps
    /// (`kept_stiffness_points`; none unless `Sys::DIAGONAL_STIFFNESS`),
    /// fixed with the tableau.
    stiffness_points: [bool; S],
    /// Steps left on the exact matrix after the stage-decoupled one was slow
    /// or singular ([`Jacobian::StageDecoupled`]).
    exact_steps_left: u32,
    /// Full Newton's `‖Δz₁‖/‖Δz₀‖²` of the latest step with two updates
    /// (NaN before): it predicts whether the residual test after a step's
    /// first update can pass.
    quadratic: f64,
    /// The step size for which `newton` (or `decoupled`, when the flag is
    /// set) holds factors that simplified Newton may reuse on the next
    /// continuing step (`None`: evaluate afresh).
    reusable: Option<(f64, bool)>,
    /// The latest solve's first update moved a pair of groups the equations
    /// are curved in, on a system with a closed affine cover: a fresh first
    /// update of the next step would not land either, so simplified Newton
    /// on the stage-decoupled matrix starts it from the `reusable` factors
    /// (see `Stepper::newton`).
    cover_stale_first: bool,
    /// Steps solved from the cold guess after Newton failed from the guess
    /// extrapolated across steps, counted on that cold path only; the
    /// driver reports the difference over a run (`RunReport::cold_retries`).
    pub(crate) cold_retries: usize,
    /// The system's parameter terms
    /// ([`NonholonomicSystem::parameter_terms`]), which the residual and the
    /// energy guard read instead of recomputing them at every evaluation
    /// (heap, allocated once; empty for a system without any).
    terms: Box<[f64]>,
    /// [`Stepper::system_mut`] lent the system out, so `terms` may not be
    /// its terms any more: evaluations pass no terms (the system then
    /// computes its own) until the next step recomputes them.
    terms_stale: bool,
    /// Where the energy guard's chain of continued steps began: the chain
    /// that ends where `compensation` says the latest step ended (`None`
    /// after a step the guard did not check).
    anchor: Option<EnergyAnchor>,
    /// The Newton iterations of the latest step (kept here rather than in
    /// every [`StepResult`]: 32 records are ≈ 0.8 KB to move per step).
    history: NewtonHistory,
    /// Whether `newton`'s matrix holds the structural zeros and constant
    /// entries of this tableau and system; then [`Self::assemble_jacobian`]
    /// overwrites only the blocks that change.
    pattern_written: bool,
    /// Where the latest step ended and the round-off its `q₁` could not
    /// hold (compensated summation, see [`Compensation`]): a step from that
    /// state continues it, and takes over `warm` and `anchor` too, which
    /// belong to that end (`None` before a first step).
    compensation: Option<Compensation<N>>,
    /// Whether `options` passed [`NewtonOptions::validate`]; cleared by
    /// every way of changing them, so the check runs once per change, not
    /// per step.
    options_checked: bool,
    /// While a driver runs: the consistency tolerance its policy already
    /// accepted the initial state with, so a cold start within the run is
    /// not refused for a residual the run's own check let through.
    accepted_start_residual: f64,
    /// Tests only: confirm every update, as if the system declared no
    /// [`Nonlinearity`](crate::Nonlinearity), for references that do not
    /// rest on the affine acceptance they check.
    #[cfg(test)]
    always_confirm: bool,
}

/// The parameter terms to evaluate with: none (the system then computes its
/// own) while they may be stale (see `Stepper::terms_stale`).
fn usable_terms(terms: &[f64], stale: bool) -> &[f64] {
    if stale {
        &[]
    } else {
        terms
    }
}

/// The part of a stepper's state that links a step to the previous one
/// (see [`Stepper::continuation`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Continuation<const N: usize, const D: usize> {
    warm: Option<Warm<D>>,
    anchor: Option<EnergyAnchor>,
    compensation: Option<Compensation<N>>,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// Whether the structure facts make the couplings the stage-decoupled
    /// matrix drops `O(h²)` ([`Jacobian::Auto`]).
    pub(crate) const DECOUPLES: bool = Sys::STRUCTURE.separable
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
        let mut terms = vec![0.0; Sys::PARAMETER_TERMS].into_boxed_slice();
        system.parameter_terms(&mut terms);
        Stepper {
            system,
            terms,
            terms_stale: false,
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
            eval: Eval::zeros(),
            block: vec![0.0; N * N].into_boxed_slice(),
            decoupled: DecoupledMatrix::new(Sys::CONSTANT_STIFFNESS || Sys::DIAGONAL_STIFFNESS),
            step_polynomial: StepPolynomial::new(&tableau),
            stiffness_points: if Sys::DIAGONAL_STIFFNESS { kept_stiffness_points(&tableau) } else { [false; S] },
            exact_steps_left: 0,
            quadratic: f64::NAN,
            reusable: None,
            cover_stale_first: false,
            cold_retries: 0,
            anchor: None,
            history: NewtonHistory::default(),
            pattern_written: false,
            compensation: None,
            options_checked: false,
            accepted_start_residual: 0.0,
            #[cfg(test)]
            always_confirm: false,
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
        self.terms_stale = true;
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

    /// Whether a step from `state` continues the latest step (it starts
    /// where that step ended).
    pub(crate) fn continues(&self, state: &State<N>) -> bool {
        self.compensation.as_ref().is_some_and(|c| c.end == *state)
    }

    /// Whether a step from `state` would be warm-started.
    pub(crate) fn is_warm_for(&self, state: &State<N>) -> bool {
        self.options.warm_start && self.warm.is_some() && self.continues(state)
    }

    /// Declares that `state` (the last step's result with its time pinned to
    /// the schedule) continues the last step.
    pub(crate) fn retarget_warm_start(&mut self, state: &State<N>) {
        if let Some(c) = self.compensation.as_mut() {
            c.end = *state;
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
        self.quadratic = f64::NAN;
        self.anchor = None;
        self.compensation = None;
    }

    /// Sets the consistency tolerance a driver's policy accepted the
    /// run's initial state with (0 outside a run).
    pub(crate) fn set_accepted_start_residual(&mut self, tolerance: f64) {
        self.accepted_start_residual = tolerance;
    }

    /// Checks the Newton options once after they changed
    /// ([`NewtonOptions::validate`]), and the tableau with them
    /// ([`Tableau::validate`]: its fields are public, so it may have been
    /// built by hand).
    pub(crate) fn check_options(&mut self) -> Result<(), StepError> {
        if !self.options_checked {
            self.tableau.validate().map_err(|e| StepError::InvalidOption(Box::new(e)))?;
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
    /// (scaled, `|Δz_i|/(1+|z_i|)` at the first iterate on the current
    /// factors), or when the error left after it is,
    /// estimated from a contraction rate: for full Newton the ratio of its
    /// last two updates, for simplified Newton a rate earned over three
    /// updates on the same frozen factors. Full Newton also stops, before
    /// it evaluates and factors a new Jacobian, when the residual at the
    /// new iterate solved with the previous iterate's factors is an update
    /// within the tolerance (that update is applied). An update computed
    /// with factors evaluated at the iterate it starts from also ends the
    /// solve when the step's equations are affine along it: for every pair
    /// of groups of unknowns in which the system's [`Nonlinearity`](crate::Nonlinearity)
    /// (proved by `nonholonomic_system!`) says they are curved, one group
    /// moved within the tolerance. A converged step
    /// agrees with the tightly converged solution of its equations to the
    /// tolerance in both modes.
    ///
    /// The first step after the Newton options were set or changed checks
    /// them ([`NewtonOptions::validate`]): an out-of-range field is a
    /// [`StepError::InvalidOption`].
    ///
    /// A step that Newton solves from none of its guesses (under
    /// velocity-dependent forces that change the velocity by much more
    /// than itself within `h`, the cold guess `V_i = v₀ + c_i h a₀`
    /// overshoots) is followed along its branch of solutions from `h = 0`
    /// (a homotopy in the step size, at most 32 solves), so the root it
    /// returns is the one connected to the solution of small steps. Where
    /// that branch does not reach `h`, the step fails with the error of the
    /// solve at `h`. The drivers (`integrate`, the adaptive and ensemble
    /// runs) do not follow branches: they halve a step that fails, which
    /// costs fewer solves and gives a more accurate step.
    #[inline]
    pub fn step(&mut self, state: &State<N>, h: f64) -> Result<StepResult<N, M, S>, StepError> {
        self.solve_step(state, h, true)
    }

    /// [`step`](Self::step) without the homotopy of a step that fails from
    /// every guess: the drivers' step, which halve such a step instead.
    #[inline]
    pub(crate) fn step_or_fail(&mut self, state: &State<N>, h: f64) -> Result<StepResult<N, M, S>, StepError> {
        self.solve_step(state, h, false)
    }

    /// The step, following the branch of solutions from `h = 0` when
    /// `follow_branch` and Newton fails from every guess. Out of line, so
    /// that its one call of the Newton solve stays inlined in it.
    #[inline(never)]
    fn solve_step(&mut self, state: &State<N>, h: f64, follow_branch: bool) -> Result<StepResult<N, M, S>, StepError> {
        let t0 = state.t;
        self.check_options()?;
        if self.terms_stale {
            self.system.parameter_terms(&mut self.terms);
            self.terms_stale = false;
        }
        // Zero, non-finite, subnormal and too large step sizes, with the
        // reason of `check_step_size` (whose test of `t0 + h` follows below).
        if !h.is_normal() || h.abs() > crate::driver::MAX_STEP_SIZE {
            let reason =
                crate::driver::check_step_size(f64::NAN, h).err().unwrap_or("step size is not a normal number");
            return Err(StepError::InvalidStep { t: t0, h, reason });
        }
        // A state where the previous step ended (bit for bit, so without
        // NaN) is finite and consistent by construction; any other start
        // pays for the checks.
        let continued = self.compensation.as_ref().filter(|c| c.end == *state);
        if continued.is_none() && !(t0.is_finite() && is_finite(&state.q, &state.v)) {
            return Err(StepError::InvalidStep { t: t0, h, reason: "state is not finite" });
        }
        if !(t0 + h).is_finite() || t0 + h == t0 {
            return Err(StepError::InvalidStep { t: t0, h, reason: "step size is below the resolution of t" });
        }
        let carry = match continued {
            Some(c) => c.carry,
            None => {
                let mut vals = StageValues::zeros();
                let tolerance = self.options.consistency_tolerance.max(self.accepted_start_residual);
                check_cold_start::<Sys, N, M>(&self.system, state, h, tolerance, &mut vals, &mut self.work.end)?;
                Vector::zeros()
            }
        };
        // The warm start and the energy anchor belong to that state too.
        let continues = continued.is_some();
        let Guess { mut z, warm: mut warm_started, mut prior, mut degree } = self.starting_guess(state, h, continues);
        // An extrapolation of high degree is the closer guess while the
        // solution is smooth on the scale of h, and can be far off where it
        // is not: a step it fails is solved again from the guess of degree
        // `SAFE_EXTRAPOLATION_DEGREE`, so that the higher degree never turns
        // a step that one solves into a failure. (One call of the solve, in
        // a loop: a second call site makes LLVM leave it out of line.)
        let (mut full_newton, mut abandoned) = (false, 0);
        // The homotopy in the step size (`homotopy`) of a step that fails
        // from the cold guess, and the step size being solved.
        let (mut path, mut h_solve) = (None::<Box<Homotopy<D>>>, h);
        let Solved { factorizations, rate } = loop {
            match self.newton(state, &carry, h_solve, &mut z, prior, full_newton) {
                Err(Unsolved::RestartInFullNewton { factorizations }) => {
                    // The same guess again, solved by full Newton.
                    match &path {
                        Some(running) => z = running.guess(),
                        None => Guess { z, degree, .. } = self.repeated_guess(state, h, continues && warm_started),
                    }
                    (full_newton, abandoned) = (true, abandoned + factorizations);
                }
                Err(_) if degree > SAFE_EXTRAPOLATION_DEGREE => {
                    Guess { z, degree, .. } = self.safe_degree_guess(state, h, continues);
                }
                // A guess extrapolated across steps is far off where the
                // solution turns on the scale of `h`, and Newton from it can
                // diverge where it converges from the consistent
                // acceleration at the step's start: the step is solved again
                // from that cold guess, in the mode it was asked for, before
                // it fails.
                Err(_) if warm_started => {
                    Guess { z, warm: warm_started, degree, .. } = self.cold_guess(state, h);
                    full_newton = false;
                    self.cold_retries += 1;
                }
                // The cold guess can lie beyond Newton's reach where
                // velocity-dependent forces change the velocity by much more
                // than itself within `h`: the step is followed from `h = 0`
                // along its branch of solutions, in the mode it was asked
                // for, and fails where that branch does not reach `h`.
                Err(Unsolved::Failed(e)) if follow_branch => {
                    (h_solve, z) = self.homotopy_after_failure(&mut path, state, h, e)?;
                    (full_newton, prior) = (false, (f64::NAN, false));
                }
                Err(Unsolved::Failed(e)) => return Err(e),
                Ok(solved) if path.is_some() => match self.homotopy_after_solve(&mut path, h, &z)? {
                    Some(next) => {
                        abandoned += solved.factorizations;
                        (h_solve, z) = next;
                        full_newton = false;
                    }
                    None => break solved,
                },
                Ok(solved) => break solved,
            }
        };
        let factorizations = factorizations + abandoned;
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
        if !is_finite(&end.q, &end.v) {
            return Err(StepError::NonFinite { t: t0, h, stage: "step result", history: Box::new(self.history) });
        }
        if let (Some(limit), true) = (self.options.energy_drift_limit, energy_is_invariant::<Sys, N, M>()) {
            let e1 = self.system.energy_with_terms(&self.terms, end.t, &end.q, &end.v);
            // A refused step leaves the stepper's anchor as it was.
            let mut anchor = self.anchor.filter(|_| continues);
            if let Err(d) = check_energy::<Sys, N, M>(&self.system, &mut anchor, state, &end, e1, limit) {
                let (energy0, bound) = (d.anchor.energy, limit * d.anchor.scale);
                return Err(StepError::EnergyDrift { t: t0, h, energy0, energy: d.energy, bound });
            }
            self.anchor = anchor;
        } else {
            // No chain ends here: the next checked step begins one.
            self.anchor = None;
        }
        Warm::remember(&mut self.warm, continues, h, z, rate);
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
}

/// Whether every component of `q` and `v` is finite: one comparison per
/// component, combined without a branch or a chain of dependent additions.
#[inline(always)]
fn is_finite<const N: usize>(q: &Vector<N>, v: &Vector<N>) -> bool {
    let mut finite = true;
    for i in 0..N {
        finite &= q[i].is_finite() & v[i].is_finite();
    }
    finite
}
