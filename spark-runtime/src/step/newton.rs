//! Newton's method on the step's equations: the options ([`NewtonMode`],
//! [`Jacobian`], [`NewtonOptions`]), the iteration with its refreshes of a
//! simplified Newton matrix and its fall-back from the stage-decoupled to
//! the exact matrix, and the typed errors it ends with.

use super::convergence::{
    affine_along, full_newton_accepts_residual, rounding_moved, too_slow, AffinePlan, Contraction,
};
use super::equations::Derivatives;
use super::Stepper;
use crate::error::{IterationRecord, NewtonHistory, Sci, StepError, HISTORY_CAPACITY};
use crate::linalg::{largest_magnitude, weigh_and_norm, weighted_update_norm};
use crate::system::{NonholonomicSystem, Vector};
use crate::State;

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
    /// `linalg/decoupled.rs` in the crate source). For a system with a
    /// constant stiffness ([`NonholonomicSystem::CONSTANT_STIFFNESS`], a
    /// quadratic potential) and a constant mass matrix it keeps the
    /// couplings that stiffness makes between stages, factored once per step
    /// size. The step
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
    /// (`|Δz_i| / (1 + |z_i|)`, `z` the iterate after the first update on
    /// the current factors); default `16 ε ≈ 3.6e-15`. The scale is
    /// relative for unknowns above 1 and absolute below: for a system whose
    /// velocities are of order `λ < 1` in its units, `tolerance × λ` keeps
    /// the relative accuracy that the default gives at order 1
    /// (`docs/guarantees.md`, "Units"). It lies in `[0, 1)`: 1 or more would
    /// accept an update with no correct digit.
    pub tolerance: f64,
    /// Updates below this level that stop contracting are round-off
    /// stagnation and are accepted; above it they count as divergence.
    /// Scaled like [`tolerance`](Self::tolerance), it is the error a step
    /// accepted this way can carry, since an iteration that stops
    /// contracting has no rate to vouch for the digits past its update:
    /// keep it near the round-off of the step's equations (default 1e-12;
    /// about `ε · cond` for an ill-conditioned step), in `[0, 1)`.
    pub stagnation_level: f64,
    /// Iteration limit (at most [`HISTORY_CAPACITY`]).
    pub max_iterations: usize,
    /// Start from the previous steps when the new step continues them —
    /// for Gauss methods with `s ≥ 3` the polynomial through the previous
    /// step's velocities `v₀, V₁…V_s, v₁`, for the other methods the
    /// extrapolation of the previous solutions — otherwise from the
    /// consistent acceleration at `(t₀, q₀, v₀)`.
    pub warm_start: bool,
    /// Degree (1..=5) of the polynomial extrapolating the solutions of
    /// previous equal steps to the next starting guess (the methods without
    /// the Gauss step polynomial, see [`warm_start`](Self::warm_start)): the
    /// velocities' increments `V_i − v₀`, `v₁ − v₀` and the multipliers,
    /// from the latest `degree + 1` steps (fewer at the start of a chain).
    /// Default 5: at the paper's step sizes it takes 0.6–0.8 fewer
    /// stage-decoupled updates per step than degree 3 on the particle and
    /// the McLachlan–Perlmutter particles (docs/performance, "The starting
    /// guess"). Degrees above 3 are used only after a step whose update
    /// ratio is at most 1e-2 (above, the guess across steps is poor), and a
    /// step that Newton fails from them is solved again from the guess of
    /// degree 3, so the higher degree costs a failed attempt where it is
    /// far off, never a failure.
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
            extrapolation_degree: 5,
            reuse_factorization: default_reuse(),
            energy_drift_limit: default_energy_drift_limit(),
            consistency_tolerance: default_consistency_tolerance(),
            jacobian: Jacobian::Auto,
        }
    }
}

/// Why [`Stepper::newton`] returned no solution: the step failed, or
/// simplified Newton's factors at the starting guess contracted too slowly
/// to trust the iteration, which then solves the step again from the guess
/// as full Newton.
#[derive(Debug)]
pub(super) enum Unsolved {
    Failed(StepError),
    /// With the factorizations the abandoned iteration made.
    RestartInFullNewton {
        factorizations: usize,
    },
}

impl From<StepError> for Unsolved {
    fn from(e: StepError) -> Self {
        Unsolved::Failed(e)
    }
}

/// What a converged Newton solve reports to its step.
pub(super) struct Solved {
    pub(super) factorizations: usize,
    /// The largest ratio of consecutive updates on the final factors (NaN
    /// for full Newton) and whether they were the stage-decoupled matrix's:
    /// the next step's prior (`Warm::rate`).
    pub(super) rate: (f64, bool),
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// Which matrix simplified Newton factors: the stage-decoupled one where
    /// the options and structure facts ask for it (the caller also waits out
    /// `EXACT_AFTER_DECOUPLED_FAILS` steps after it was slow or singular).
    fn wants_decoupled(&self) -> bool {
        self.options.mode == NewtonMode::Simplified
            && match self.options.jacobian {
                Jacobian::Exact => false,
                Jacobian::StageDecoupled => true,
                Jacobian::Auto => Self::DECOUPLES,
            }
    }

    /// Assembles and factors the exact Jacobian at the latest evaluation; a
    /// failure is recorded in the history with the iteration's `residual`
    /// and returned as a singular (or non-finite) Newton matrix.
    fn factor_exact(&mut self, state: &State<N>, h: f64, residual: f64) -> Result<(), StepError> {
        let t = state.t;
        self.assemble_jacobian(h);
        let Err(s) = self.newton.factor() else { return Ok(()) };
        self.history.push(IterationRecord { residual, update: f64::NAN, rate: f64::NAN });
        Err(if self.newton.matrix().iter().all(|x| x.is_finite()) {
            let matrix = self.newton.matrix();
            let mut detail =
                singular_detail::<N, M, S>(s.column, s.pivot, matrix.column(s.column).amax(), Sys::SOURCE.coordinates);
            // Column-major, as the factorization holds it.
            let entries: Vec<f64> = matrix.iter().copied().collect();
            let by_scale = crate::linalg::singular_only_by_scale(&entries, D);
            detail.push_str(&if by_scale {
                let (smallest, largest) = crate::linalg::magnitude_range(&entries);
                format!(
                    " (the matrix is regular once its rows and columns are scaled to unit size: its entries span \
                     {} to {}, too far apart for elimination in double precision, so the magnitudes are out of \
                     range, not a mass or a constraint; the step starts at max |q| = {}, max |v| = {}: rescale the \
                     units so that q, v and h v are nearer 1, or reduce h)",
                    Sci(smallest),
                    Sci(largest),
                    Sci(state.q.amax()),
                    Sci(state.v.amax())
                )
            } else {
                " (a V column points at the mass matrix ∇²_vv L — a zero mass or inertia parameter? — a hΨ column at \
                 dependent or vanishing constraint rows ∂k/∂v)"
                    .to_string()
            });
            StepError::SingularMatrix { t, h, detail: detail.into(), history: Box::new(self.history) }
        } else {
            StepError::NonFinite { t, h, stage: "Jacobian", history: Box::new(self.history) }
        })
    }

    /// The residual at `z` and its largest magnitude, evaluated with the
    /// stage Jacobians (`jacobians == Some(true)`), with the constraint
    /// Jacobians of a lean stage-decoupled refresh (`Some(false)`) or alone
    /// (`None`), written into `g`; a non-finite residual is recorded in the
    /// history and returned as an error.
    #[allow(clippy::too_many_arguments)]
    fn iteration_residual(
        &mut self,
        state: &State<N>,
        carry: &Vector<N>,
        p0: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        jacobians: Option<bool>,
        g: &mut Vector<D>,
    ) -> Result<f64, StepError> {
        let derivatives = match jacobians {
            Some(true) => Derivatives::Full(&mut *self.work),
            Some(false) => Derivatives::Constraint {
                constraint_v: &mut self.decoupled.constraint_v,
                constraint_q: &mut self.decoupled.constraint_q,
            },
            None => Derivatives::None,
        };
        let terms = super::usable_terms(&self.terms, self.terms_stale);
        Self::evaluate(&self.system, terms, &self.tableau, state, carry, h, z, derivatives, &mut self.eval);
        Self::residual(&self.tableau, p0, h, z, &self.eval, g);
        // One pass for both: the largest magnitude, and the finiteness test
        // (a NaN raises the flag, an infinity is the largest). As a fold
        // with `f64::max` this pass would be a tenth of an mp7 step of the
        // stage-decoupled iteration at h = 0.3125 (see `largest_and_nan`,
        // the scalar form of `largest_magnitude`).
        let (largest, nan) = largest_magnitude(g.as_slice(), None);
        let finite = !nan && largest <= f64::MAX;
        if !finite {
            self.history.push(IterationRecord { residual: f64::NAN, update: f64::NAN, rate: f64::NAN });
            return Err(StepError::NonFinite { t: state.t, h, stage: "residual", history: Box::new(self.history) });
        }
        Ok(largest)
    }

    /// Newton's method on `G(z) = 0` from the starting guess `z`, with the
    /// `prior` of that guess ([`Guess`](super::guess::Guess)); records the
    /// iterations in `self.history`.
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
    /// Full Newton tests every new iterate before it evaluates and factors
    /// a Jacobian there: it evaluates the residual (needed for the next
    /// update anyway) and solves it with the factors of the previous
    /// iterate, one pair of triangular solves. That update `δ` is a
    /// simplified Newton update on fresh factors, contracting at
    /// `θ = O(‖Δz_prev‖)`; when it is within the tolerance (and at most half
    /// the update before it), `δ` is applied and the solve ends with the
    /// error `θ/(1 − θ)·‖δ‖` left, no factorization paying for the
    /// confirmation (see [`full_newton_accepts_residual`]).
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
    pub(super) fn newton(
        &mut self,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        z: &mut Vector<D>,
        prior: (f64, bool),
        full_newton: bool,
    ) -> Result<Solved, Unsolved> {
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
        let simplified = opts.mode == NewtonMode::Simplified && !full_newton;
        let mut decoupled = simplified && self.wants_decoupled() && self.exact_steps_left == 0;
        if !full_newton {
            self.exact_steps_left = self.exact_steps_left.saturating_sub(1);
        }
        // `stale`: the factors of this step's matrix come from an earlier step.
        let stale = self.starts_stale(state, h, decoupled);
        self.reusable = None;
        // Whether the next step starts from this one's factors (a closed
        // affine cover whose first update does not land; see below).
        let mut cover_stale_first = false;
        let mut refresh = !stale;
        // Iteration at which the current factors were computed, and whether
        // that was a refresh within this step (simplified Newton only).
        let (mut factored_at, mut refreshed) = (0usize, false);
        let mut max_rate = 0.0f64;
        let mut factorizations = 0usize;
        // Simplified Newton's floor under its contraction estimate: what the
        // previous step of this chain earned on the same kind of matrix.
        let (prior_rate, prior_decoupled) = prior;
        let prior = |decoupled: bool| if simplified && decoupled == prior_decoupled { prior_rate } else { f64::NAN };
        let mut monitor = Contraction::FRESH;
        let mut g = Vector::<D>::zeros();
        // The update norm's weights, taken at the first update on each set
        // of factors (`weighted_update_norm`).
        let mut weights = Vector::<D>::zeros();
        let result = 'solve: {
            for k in 0..max_iter {
                // After the first update, the latest step's ratio
                // ‖Δz₁‖/‖Δz₀‖² predicts whether the test can pass (see
                // `worth_testing`); later updates are always tested.
                let c = if k == 1 { self.quadratic } else { f64::NAN };
                if !simplified
                    && k > 0
                    && worth_testing(c, prev_update, opts.tolerance)
                    && self.accepts_on_residual(state, carry, &p0, h, z, (&weights, prev_update))?
                {
                    break 'solve Ok(());
                }
                let fresh = refresh || !simplified;
                if refresh && k > 0 {
                    refreshed = true;
                }
                refresh = false;
                // A lean decoupled refresh needs only the constraint Jacobians,
                // evaluated with the residual, not the stage Jacobians of a
                // full evaluation.
                let lean = fresh && decoupled && Self::LEAN_DECOUPLED;
                let jacobians = fresh.then_some(!lean);
                let residual = self.iteration_residual(state, carry, &p0, h, z, jacobians, &mut g)?;
                if fresh {
                    factorizations += 1;
                    monitor = Contraction::fresh(prior(decoupled));
                    factored_at = k;
                    if decoupled && self.factor_decoupled(state, carry, h, z, lean).is_err() {
                        decoupled = false;
                        self.exact_steps_left = EXACT_AFTER_DECOUPLED_FAILS;
                    }
                }
                if fresh && !decoupled {
                    self.factor_exact(state, h, residual)?;
                }
                if decoupled {
                    self.decoupled.solve_in_place(&mut g);
                } else {
                    self.newton.solve_in_place(&mut g);
                }
                // The update is measured against the iterate it leads to and
                // applied once it is kept: only iterations on factors from an
                // earlier iterate may be undone, and an undone one is never
                // applied (no copy of `z` to restore).
                let update = if fresh || k == 0 {
                    weigh_and_norm(&g, z, &mut weights)
                } else {
                    weighted_update_norm(&g, &weights)
                };
                let rate = update / prev_update;
                monitor.record(update);
                self.history.push(IterationRecord { residual, update, rate });
                if rate.is_finite() {
                    max_rate = max_rate.max(rate);
                }
                let converged = monitor.converged_in(simplified, update, rate, opts.tolerance);
                if !fresh {
                    // Factors from an earlier iterate that grow or contract too
                    // slowly (see `too_slow`): a fresh Jacobian at the last good
                    // iterate, simplified Newton's standard remedy. Not when this
                    // iteration is accepted anyway, at round-off level, or on the
                    // first iteration of an earlier step's factors (no rate yet).
                    let remaining = (max_iter - 1 - k) as i32;
                    let round_off = update <= opts.stagnation_level;
                    let first_stale = k == 0 && update.is_finite();
                    if !converged
                        && !round_off
                        && !first_stale
                        && too_slow(&monitor, decoupled, update, rate, remaining, opts.tolerance)
                    {
                        let growing = rate.is_nan() || rate >= 1.0;
                        // The current factors are those of this step's
                        // starting guess: factored in this step, at its first
                        // iterate.
                        let at_guess = !stale && factored_at == 0;
                        if at_guess && (growing || !decoupled) {
                            // Factors at the starting guess that contract
                            // this slowly say the guess is far from the
                            // solution, where iterating on and refreshing at
                            // the iterates can settle on another root of the
                            // step's equations (a bead in a breathing bowl,
                            // Lobatto IIIA-B-D s = 2 at h = 0.25, from a
                            // first update of 7.5: `v₁` 17 from full
                            // Newton's). Full Newton from the guess solves
                            // the step instead.
                            return Err(Unsolved::RestartInFullNewton { factorizations });
                        }
                        if decoupled {
                            // The dropped couplings are not small at this
                            // step: continue with the exact matrix from the
                            // last good iterate.
                            decoupled = false;
                            self.exact_steps_left = EXACT_AFTER_DECOUPLED_FAILS;
                            if !growing {
                                *z -= g;
                            }
                            refresh = true;
                            prev_update = f64::NAN;
                            continue;
                        }
                        if growing && refreshed && factored_at + 1 == k {
                            // Even a Jacobian refreshed at the previous iterate did
                            // not contract: give up as full Newton would.
                            return Err(Unsolved::Failed(if update.is_finite() {
                                StepError::Diverged { t, h, history: Box::new(self.history) }
                            } else {
                                fail_nonfinite("update", &self.history)
                            }));
                        }
                        if !growing {
                            *z -= g;
                        }
                        refresh = true;
                        prev_update = f64::NAN;
                        continue;
                    }
                }
                if !update.is_finite() {
                    return Err(fail_nonfinite("update", &self.history).into());
                }
                // Tested before the update is applied: the end point is
                // read at both iterates.
                let lands = !converged
                    && fresh
                    && self.lands_on_solution((&g, update), &weights, decoupled)
                    && self.end_point_stays(state, carry, h, (z, &g, &weights), decoupled);
                *z -= g;
                if converged || lands {
                    break 'solve Ok(());
                }
                if k > 0 && rate >= 1.0 {
                    if update <= opts.stagnation_level {
                        break 'solve Ok(());
                    }
                    return Err(StepError::Diverged { t, h, history: Box::new(self.history) }.into());
                }
                prev_update = update;
                if decoupled && k == 0 && Self::affine_rule(true).is_some_and(|n| n.closed_affine_cover) {
                    // The first update solved the groups of a closed affine
                    // cover exactly — on any factors of this matrix, whose
                    // rows for those groups are constant —, so on factors at
                    // this iterate the next update is accepted by
                    // `lands_on_solution`. Only the stage-decoupled matrix
                    // refreshes for it: its refresh is the constraint
                    // Jacobians and a small complement, where the exact
                    // matrix's is a Jacobian and a dense LU, which costs more
                    // than the updates it saves (measured in
                    // docs/performance, "Updates along which the step's
                    // equations are affine").
                    //
                    // A fresh first update that did not land moved a curved
                    // pair; so did a stale one that would not have landed on
                    // fresh factors. The next step's first update, from a
                    // guess as far off, will too, and cannot land: it starts
                    // from this refresh's factors instead of factoring at its
                    // guess.
                    cover_stale_first = fresh || !self.lands_on_solution((&g, update), &weights, decoupled);
                    refresh = true;
                    prev_update = f64::NAN;
                }
            }
            Err(StepError::MaxIterations { t, h, history: Box::new(self.history) })
        };
        if result.is_ok() {
            self.remember_solve(simplified && max_rate <= REUSE_RATE, h, decoupled);
            self.cover_stale_first = cover_stale_first;
        }
        let rate = (if simplified { monitor.observed() } else { f64::NAN }, decoupled);
        result.map(|()| Solved { factorizations, rate }).map_err(Unsolved::Failed)
    }

    /// Full Newton's acceptance before a new Jacobian: the residual at the
    /// new iterate `z`, solved with the factors of the previous one, is a
    /// simplified Newton update; when it is within the tolerance it is
    /// applied and ends the solve before a new Jacobian is evaluated and
    /// factored (see "Stopping"). It is measured with the weights of the
    /// update before it, on the same factors, and compared with that
    /// update's norm. Returns whether it did.
    fn accepts_on_residual(
        &mut self,
        state: &State<N>,
        carry: &Vector<N>,
        p0: &Vector<N>,
        h: f64,
        z: &mut Vector<D>,
        (weights, prev_update): (&Vector<D>, f64),
    ) -> Result<bool, StepError> {
        let mut g = Vector::<D>::zeros();
        let residual = self.iteration_residual(state, carry, p0, h, z, None, &mut g)?;
        self.newton.solve_in_place(&mut g);
        let update = weighted_update_norm(&g, weights);
        if !full_newton_accepts_residual(update, prev_update, self.options.tolerance) {
            return Ok(false);
        }
        *z -= g;
        self.history.push(IterationRecord { residual, update, rate: update / prev_update });
        Ok(true)
    }

    /// Whether the update `g` (scaled by `weights`), computed with factors
    /// evaluated at the iterate it started from, ends the solve because
    /// the equations are affine in what it moved beyond the tolerance
    /// ([`affine_along`], on the system's [`Nonlinearity`](crate::Nonlinearity)).
    #[inline]
    fn lands_on_solution(&self, (g, norm): (&Vector<D>, f64), weights: &Vector<D>, decoupled: bool) -> bool {
        #[cfg(test)]
        if self.always_confirm {
            return false;
        }
        match Self::affine_rule(decoupled) {
            Some(nonlinearity) => {
                let plan = Self::affine_plan(decoupled, decoupled && self.decoupled.keeps_stiffness());
                affine_along::<N, M, S, D>((g, norm), weights, self.options.tolerance, &nonlinearity, plan)
            }
            None => false,
        }
    }

    /// Whether the update `g` of `z` (applied as `z − g`, scaled by
    /// `weights`) moves no rounded coordinate of the end point `q₁` that
    /// [`AffinePlan::keeps_position`] names by more than it accounts for
    /// ([`rounding_moved`]): `q₁` is the state the step returns, and its
    /// constraints hold where the iteration evaluated them.
    fn end_point_stays(
        &self,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        (z, g, weights): (&Vector<D>, &Vector<D>, &Vector<D>),
        decoupled: bool,
    ) -> bool {
        let plan = Self::affine_plan(decoupled, decoupled && self.decoupled.keeps_stiffness());
        let b = &self.tableau.b;
        // A coordinate whose stage velocities the update left exactly as
        // they were (the skate's heading) keeps its position.
        let moves = |c: usize| plan.keeps_position(c) && (0..S).any(|j| g[j * N + c] != 0.0);
        (0..N).filter(|&c| moves(c)).all(|c| {
            let (mut old, mut new, mut shift, mut weight) = (carry[c], carry[c], 0.0, 0.0f64);
            for j in 0..S {
                let k = h * b[j];
                old += k * z[j * N + c];
                new += k * (z[j * N + c] - g[j * N + c]);
                shift += k * g[j * N + c];
                weight = weight.max(weights[j * N + c]);
            }
            !rounding_moved(state.q[c] + old, state.q[c] + new, shift, weight, self.options.tolerance)
        })
    }

    /// The nonlinearity an update of the exact (or, `decoupled`, the
    /// stage-decoupled) matrix may be accepted on ([`affine_along`]): the
    /// system's, when it declares one. The stage-decoupled matrix qualifies
    /// only where the structure facts make it the exact Jacobian with the
    /// force terms of some columns dropped (`DECOUPLES`).
    pub(crate) fn affine_rule(decoupled: bool) -> Option<crate::Nonlinearity> {
        Sys::NONLINEARITY.filter(|_| !decoupled || Self::DECOUPLES)
    }

    /// [`AffinePlan`]s of the system's nonlinearity: the exact matrix, the
    /// stage-decoupled one without and with the stiffness kept.
    const AFFINE_PLANS: [AffinePlan; 3] = match &Sys::NONLINEARITY {
        Some(nonlinearity) => [
            AffinePlan::new::<N, M>(nonlinearity, false, false),
            AffinePlan::new::<N, M>(nonlinearity, true, false),
            AffinePlan::new::<N, M>(nonlinearity, true, true),
        ],
        None => [AffinePlan::UNUSED; 3],
    };

    /// The [`AffinePlan`] of the exact matrix, or (`decoupled`) of the
    /// stage-decoupled one keeping the stiffness when `stiffness_kept`:
    /// borrowed from the constant, which a step reads twice (a copy of the
    /// three plans each time cost more than the test it feeds).
    #[inline(always)]
    pub(crate) fn affine_plan(decoupled: bool, stiffness_kept: bool) -> &'static AffinePlan {
        &Self::AFFINE_PLANS[if !decoupled {
            0
        } else if stiffness_kept {
            2
        } else {
            1
        }]
    }

    /// Whether simplified Newton starts a step from `state` with size `h`
    /// on the factors of the previous step (on the stage-decoupled matrix
    /// when `decoupled`): with [`NewtonOptions::reuse_factorization`], or
    /// for a closed affine cover whose previous first update moved a curved
    /// pair (`cover_stale_first`), when that step left factors of this kind
    /// and size and the step continues it warm.
    pub(crate) fn starts_stale(&self, state: &State<N>, h: f64, decoupled: bool) -> bool {
        self.options.mode == NewtonMode::Simplified
            && (self.options.reuse_factorization || (decoupled && self.cover_stale_first))
            && self.reusable == Some((h, decoupled))
            && self.is_warm_for(state)
    }

    /// What a converged solve leaves for the next step: simplified Newton's
    /// factors when they contracted fast enough to reuse (`reuse`), and full
    /// Newton's quadratic constant `‖Δz₁‖/‖Δz₀‖²` (see `worth_testing`).
    fn remember_solve(&mut self, reuse: bool, h: f64, decoupled: bool) {
        if reuse {
            self.reusable = Some((h, decoupled));
        }
        if self.options.mode == NewtonMode::Full && self.history.len() >= 2 {
            let r = self.history.iterations();
            self.quadratic = r[1].update / (r[0].update * r[0].update);
        }
    }
}

/// How far above the tolerance a predicted next update may be for full
/// Newton to still test the residual at the new iterate before factorizing.
const TEST_MARGIN: f64 = 100.0;

/// Whether full Newton tests the residual at the new iterate (the latest
/// update `update`) with the previous factors: unless the latest step's
/// `c = ‖Δz₁‖/‖Δz₀‖²` predicts a next update `c·update²` more than
/// `TEST_MARGIN` times the tolerance, when the test would cost a residual
/// evaluation and a solve for nothing. The prediction only decides whether
/// to test, never whether to stop. `c` is not a clean quadratic constant:
/// the first update removes the multipliers' error at once, so `‖Δz₁‖/‖Δz₀‖²`
/// can be far larger than the constant of later updates; it predicts the
/// second update from the first, and only there is it used. A NaN
/// prediction tests.
fn worth_testing(c: f64, update: f64, tolerance: f64) -> bool {
    let predicted = c * update * update;
    predicted.is_nan() || predicted <= TEST_MARGIN * tolerance
}

/// Describes a failed pivot: the column, its unknown of `z` (1-based stage
/// and component as in the paper: `V_i[d]`, `hΨ_i[d]` or `v1[d]`) with the
/// coordinate of a velocity by its declared name (from `coordinates`, when
/// the system declares them), the pivot
/// and the column's largest magnitude `scale`. The name spares the reader
/// the mapping from the 0-based column to the 1-based component.
fn singular_detail<const N: usize, const M: usize, const S: usize>(
    column: usize,
    pivot: f64,
    scale: f64,
    coordinates: &[&str],
) -> String {
    let velocity_of =
        |c: usize| coordinates.get(c).map_or_else(String::new, |name| format!(", the velocity of `{name}`"));
    let name = if column < S * N {
        format!("V_{}[{}]{}", column / N + 1, column % N + 1, velocity_of(column % N))
    } else if column < S * (N + M) {
        let c = column - S * N;
        format!("hΨ_{}[{}]", c / M + 1, c % M + 1)
    } else {
        let c = column - S * (N + M);
        format!("v1[{}]{}", c + 1, velocity_of(c))
    };
    format!("column {column} ({name}): pivot {pivot:.3e} is below 64 eps x its largest entry {scale:.3e}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::paper::{MobileRobot, MpParticles, Particle};
    use crate::Method;
    use crate::{NonholonomicSystem, Tableau};

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
    /// too slowly: with it the robot at h = 1 (Gauss s = 2) diverges at its
    /// seventh step, the particle at h = 0.7 runs into the iteration limit at
    /// its fourth, while full Newton solves both. Refreshing the Jacobian at the
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

    /// The extrapolation of degree 5 is solved again from degree 3 where
    /// Newton fails from it, so it never fails a step that degree 3 solves:
    /// at step sizes where the guess across steps is poor (the robot at
    /// h = 1, the particle at h = 0.7, the McLachlan–Perlmutter particles
    /// at h = 0.6) every step of degree 3's run is solved with degree 5
    /// too, in both Newton modes, to the same end within the tolerance's
    /// reach.
    #[test]
    fn a_high_extrapolation_degree_never_fails_a_step_the_safe_degree_solves() {
        fn same<
            Sys: NonholonomicSystem<N, M> + Clone,
            const N: usize,
            const M: usize,
            const S: usize,
            const D: usize,
        >(
            sys: Sys,
            start: State<N>,
            h: f64,
            steps: usize,
        ) {
            let tab = Tableau::<S>::new(Method::Gauss).unwrap();
            for mode in [NewtonMode::Full, NewtonMode::Simplified] {
                let at = |degree| NewtonOptions { mode, extrapolation_degree: degree, ..NewtonOptions::default() };
                let mut safe = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tab).with_options(at(3));
                let mut high = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tab).with_options(at(5));
                let (mut a, mut b) = (start, start);
                for k in 0..steps {
                    let Ok(ra) = safe.step(&a, h) else { break };
                    let rb = high.step(&b, h).unwrap_or_else(|e| panic!("{mode:?} step {k}: {e}"));
                    (a, b) = (ra.state, rb.state);
                }
                let name = Sys::SOURCE.name;
                assert!((a.q - b.q).amax() < 1e-8 && (a.v - b.v).amax() < 1e-8, "{name} {mode:?}: {a:?} vs {b:?}");
            }
        }
        let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        same::<_, 4, 2, 2, 16>(MobileRobot::default(), robot, 1.0, 20);
        let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        same::<_, 3, 1, 2, 11>(Particle, particle, 0.7, 20);
        let q0 = Vector::<7>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
        same::<_, 7, 1, 2, 23>(MpParticles, State::new(0.0, q0, Vector::zeros()), 0.6, 20);
    }

    /// A step whose equations even refreshed Jacobians cannot solve is still
    /// a typed divergence with its history, not an endless refresh.
    #[test]
    fn hopeless_simplified_steps_still_diverge() {
        let simplified = NewtonOptions { mode: NewtonMode::Simplified, energy_drift_limit: None, ..Default::default() };
        let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let mut st = Stepper::<_, 4, 2, 2, 16>::new(MobileRobot::default(), tab).with_options(simplified);
        let err = run(&mut st, robot, 3.0, 20).expect_err("h = 3 is beyond Newton's reach here");
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
    use crate::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
    use crate::Method;
    use crate::{NonholonomicSystem, StepResult, Tableau};

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

    /// Runs `steps` warm-started full Newton steps of size `h` with the
    /// default options; before each, solves the same step (same stepper
    /// state, so the same starting guess) to the round-off floor. Returns
    /// the largest scaled distance of `q₁`, `v₁` and `μ = hΨ`
    /// (`|a − b| / (1 + |b|)`), and the iterations and factorizations of the
    /// default steps.
    fn against_tight<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
        sys: Sys,
        method: Method,
        start: State<N>,
        h: f64,
        steps: usize,
    ) -> Option<(f64, usize, usize)>
    where
        Sys: NonholonomicSystem<N, M> + Clone,
    {
        let scaled = |a: f64, b: f64| (a - b).abs() / (1.0 + b.abs());
        let opts = NewtonOptions { mode: NewtonMode::Full, ..NewtonOptions::default() };
        let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).ok()?).with_options(opts);
        let (mut s, mut worst, mut iterations, mut factorizations) = (start, 0.0f64, 0, 0);
        for _ in 0..steps {
            let mut reference = st.clone();
            *reference.options_mut() = tight();
            let b = reference.step(&s, h).unwrap();
            let a = st.step(&s, h).unwrap();
            let states = a.state.q.iter().zip(b.state.q.iter()).chain(a.state.v.iter().zip(b.state.v.iter()));
            let mu = (0..S).flat_map(|i| a.stage_multipliers[i].iter().zip(b.stage_multipliers[i].iter()));
            worst =
                states.map(|(x, y)| scaled(*x, *y)).chain(mu.map(|(x, y)| scaled(h * x, h * y))).fold(worst, f64::max);
            (iterations, factorizations) = (iterations + a.iterations, factorizations + a.factorizations);
            s = a.state;
        }
        Some((worst, iterations, factorizations))
    }

    /// Full Newton with the default tolerance returns steps as accurate as
    /// the tightly converged ones (within 1e-14 in `q₁`, `v₁` and `μ = hΨ`),
    /// on the paper's systems at the catalogue's step sizes, cold and warm,
    /// with Gauss s = 1..3 and Lobatto IIIA-B and IIIA-B-D s = 2..4.
    #[test]
    fn full_newton_steps_agree_with_tight_solves() {
        let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let q0 = Vector::<7>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
        let m0 = State::new(0.0, q0, Vector::<7>::zeros());
        let mut failures = Vec::new();
        macro_rules! check {
            ($name:literal, $sys:expr, $start:expr, $h:expr, $n:literal, $m:literal) => {
                for method in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
                    let results = [
                        (1, against_tight::<_, $n, $m, 1, { $n + $m + $n }>($sys, method, $start, $h, 20)),
                        (2, against_tight::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>($sys, method, $start, $h, 20)),
                        (3, against_tight::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>($sys, method, $start, $h, 20)),
                        (4, against_tight::<_, $n, $m, 4, { 4 * ($n + $m) + $n }>($sys, method, $start, $h, 20)),
                    ];
                    for (s, (worst, ..)) in results.into_iter().filter_map(|(s, r)| Some((s, r?))) {
                        if worst.is_nan() || worst > 1e-14 {
                            failures.push(format!("{} {method:?} s = {s}: {worst:.3e}", $name));
                        }
                    }
                }
            };
        }
        check!("particle", Particle, p0, 0.2, 3, 1);
        check!("skate", Skate::default(), s0, 0.1, 3, 1);
        check!("robot", MobileRobot::default(), r0, 0.2, 4, 2);
        check!("mp7", MpParticles, m0, 0.05, 7, 1);
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }

    /// A warm-started full Newton step whose update lands within the
    /// tolerance of the solution stops on the residual there, solved with
    /// the factors it already has: on the skate (Gauss s = 2, h = 0.1) and
    /// the particle (Lobatto IIIA-B s = 3, h = 0.2) no step factors a
    /// Jacobian only to find its update within the tolerance. A step pays
    /// one factorization per update less than it applies, or as many when
    /// its last update, larger than the tolerance, ended the solve on the
    /// contraction rate.
    #[test]
    fn full_newton_pays_no_confirming_factorization() {
        fn check<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const S: usize, const D: usize>(
            sys: Sys,
            method: Method,
            start: State<N>,
            h: f64,
        ) {
            let opts = NewtonOptions { mode: NewtonMode::Full, ..NewtonOptions::default() };
            let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap()).with_options(opts);
            let (mut s, mut warm) = (start, 0);
            for k in 0..50 {
                let r = st.step(&s, h).unwrap();
                if r.warm_started {
                    warm += 1;
                    let (name, history) = (Sys::SOURCE.name, st.last_history().iterations());
                    let last = history.last().map_or(f64::NAN, |x| x.update);
                    if r.factorizations == r.iterations {
                        assert!(last > opts.tolerance, "{name}, step {k}: a confirming factorization {history:?}");
                    } else {
                        assert_eq!(r.factorizations + 1, r.iterations, "{name}, step {k}: {history:?}");
                    }
                }
                s = r.state;
            }
            assert!(warm >= 48, "{warm} warm-started steps");
        }
        let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        check::<_, 3, 1, 2, 11>(Skate::default(), Method::Gauss, s0, 0.1);
        let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        check::<_, 3, 1, 3, 15>(Particle, Method::LobattoIIIAB, p0, 0.2);
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
