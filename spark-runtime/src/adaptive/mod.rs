//! Tolerance-driven stepping: a local error estimate for every coefficient
//! family, a PI step-size controller with `rtol`/`atol`, and a reversible
//! (symmetric) step-size rule for the symmetric methods.
//!
//! # The error estimate: step doubling
//! Every family is covered by one estimate that needs nothing of the
//! tableau but its order `p` ([`Method::order`](crate::Method::order)): a
//! step of size `h` is taken once whole (`y_h`) and once as two steps of
//! size `h/2` (`y_{h/2}`). With local error `C h^{p+1}` per step, the two
//! half steps err by `2C(h/2)^{p+1}` and `y_h − y_{h/2} ≈ C h^{p+1}(1 − 2^{−p})`,
//! so
//!
//! ```text
//! err ≈ (y_h − y_{h/2}) / (2^p − 1)
//! ```
//!
//! estimates the local error of `y_{h/2}`, the solution that is kept
//! (Richardson extrapolation is not applied: the kept state is a plain
//! result of the method, so the constraint `k(t, q, v) = 0` holds there to
//! Newton's tolerance and a symmetric method stays symmetric). An embedded
//! lower-order solution from the same stages would be cheaper, but it
//! estimates the error of the lower-order formula, which is orders of
//! magnitude above the error of a `2s`-order Gauss step and so cannot track
//! it. Step doubling costs three step solves per accepted step (1.5 times
//! the fixed-step cost of the same accepted states). The estimate is
//! measured in the RMS norm over `(q, v)` with weights
//! `atol + rtol·max(|y₀ᵢ|, |y₁ᵢ|)`.
//!
//! # The controller
//! [`integrate_adaptive`] accepts a step when the scaled error `err ≤ 1`
//! and proposes the next step by the PI rule of Gustafsson (Hairer–Wanner,
//! *Solving ODEs II*, §IV.2) with `k = p + 1`:
//!
//! ```text
//! h_new = h · clamp(safety · err^{−0.7/k} · err_prev^{0.4/k}, min_factor, max_factor)
//! ```
//!
//! (no growth right after a rejection). A rejected step is retried with
//! `h · max(min_factor, safety · err^{−1/k})`; a step whose Newton solve
//! fails is retried with a quarter of its size. Below
//! [`AdaptiveOptions::min_step`] the run stops with
//! [`AdaptiveError::StepSizeTooSmall`].
//!
//! # The reversible rule
//! [`integrate_reversible`] takes the step sizes from a user step density
//! `σ(t, q, v)` (steps per unit time; e.g. `r^{−3/2}` for an orbit) by the
//! explicit symmetric rule of Hairer & Söderlind (*Explicit, time
//! reversible, adaptive step size control*, SIAM J. Sci. Comput. 26, 2005):
//! with the time transformation `dt/dτ = 1/ρ` and `ρ' = G(y) = σ̇(y)/σ(y)`,
//!
//! ```text
//! ρ_{n+1/2} = ρ_{n−1/2} + ε G(y_n),     y_{n+1} = Φ_{ε/ρ_{n+1/2}}(y_n),
//! ```
//!
//! a map `(y_n, ρ_{n−1/2}) ↦ (y_{n+1}, ρ_{n+1/2})` that is reversible
//! whenever the step `Φ` is symmetric and `σ` is even in `v`. `G` is the
//! time derivative of `ln σ` along the flow, by a central difference of `σ`
//! in the direction `(1, v, a)` with the consistent acceleration `a`. The
//! scale `ε` follows from the tolerance: the first step size is chosen by
//! the error estimate above (`err` between ½ and 1), and `ε = h₀ σ(y₀)`.
//! Long runs then keep the bounded energy error of fixed steps, which the
//! error-controlled steps of [`integrate_adaptive`] lose (their step
//! sequence is not symmetric, so the energy error drifts).
//!
//! # Dense output and events
//! Every accepted step goes through the fixed-step driver's handling of a
//! continuous extension: a step with estimate as its two half steps (the
//! kept state is theirs), a reversible step whole. So an observer of the
//! dense output ([`Observer::DENSE`]) sees every accepted step, and the
//! events (the system's, or those given to [`integrate_adaptive_with_events`]
//! and [`integrate_reversible_with_events`]) are located and reported as by
//! [`Stepper::integrate`]; a terminal one ends the run at its time. A run
//! without either builds no extension.
//!
//! Neither driver touches the fixed-step path: a run of
//! [`Stepper::integrate`] does exactly what it does without this module.

mod reversible;
mod run;
#[cfg(test)]
mod tests;

pub use reversible::{integrate_reversible, integrate_reversible_with_events};

use crate::driver::{declared_events, Observe, Observer, Trajectory};
use crate::error::{Exact, OptionError, Sci, StepError};
use crate::events::EventFunctions;
use crate::initial::{consistent_acceleration, ConsistencyPolicy};
use crate::step::{State, StepResult, Stepper};
use crate::system::{NonholonomicSystem, Vector};
use crate::tableau::Method;
use run::{accept, whole_run, Output, Recorder, Taken};

/// Options of a tolerance-driven run.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdaptiveOptions {
    /// Relative tolerance of the local error (per component of `(q, v)`):
    /// 0 or in `[1e-15, 1)`.
    pub rtol: f64,
    /// Absolute tolerance of the local error (per component of `(q, v)`):
    /// in `[0, MAX_ABSOLUTE_TOLERANCE]` (≈ 1.34e154), positive when `rtol`
    /// is 0.
    pub atol: f64,
    /// Magnitude of the first step tried; `None` estimates it from the
    /// initial velocity and acceleration.
    pub initial_step: Option<f64>,
    /// Largest step magnitude; `None`: the whole interval.
    pub max_step: Option<f64>,
    /// Smallest step magnitude before the run gives up (the resolution of
    /// `t` is a floor in any case).
    pub min_step: f64,
    /// Safety factor of the step-size proposals, in `(0, 1]`.
    pub safety: f64,
    /// Smallest factor by which one proposal shrinks the step, in `(0, 1)`.
    pub min_factor: f64,
    /// Largest factor by which one proposal grows the step, `> 1`.
    pub max_factor: f64,
    /// Largest number of step attempts (accepted and rejected).
    pub max_steps: usize,
    /// Record every `record_every`-th accepted step (and always the first
    /// and last point); `0` records only the endpoints.
    pub record_every: usize,
    /// What to record.
    pub observe: Observe,
    /// How to treat an inconsistent initial velocity.
    pub consistency: ConsistencyPolicy,
    /// The most events the run keeps; locating one more ends it with
    /// [`AdaptiveError::TooManyEvents`]. `None`: as many as fit in
    /// [`record_memory_limit`](crate::record_memory_limit)
    /// ([`crate::events::max_located_events`]).
    #[serde(default)]
    pub max_events: Option<usize>,
}

impl Default for AdaptiveOptions {
    fn default() -> Self {
        AdaptiveOptions {
            rtol: 1e-6,
            atol: 1e-6,
            initial_step: None,
            max_step: None,
            min_step: 0.0,
            safety: 0.9,
            min_factor: 0.2,
            max_factor: 5.0,
            max_steps: 10_000_000,
            record_every: 1,
            observe: Observe::default(),
            consistency: ConsistencyPolicy::default(),
            max_events: None,
        }
    }
}

impl AdaptiveOptions {
    /// Checks every field against its allowed range.
    pub fn validate(&self) -> Result<(), OptionError> {
        check_tolerances(self.rtol, self.atol)?;
        if let Some(h) = self.initial_step {
            // A subnormal step overflows 1/h in the step's equations.
            if !(h.is_finite() && h >= f64::MIN_POSITIVE) {
                return Err(OptionError::float(
                    "AdaptiveOptions::initial_step",
                    h,
                    "finite and at least 2.2e-308 (a magnitude; None estimates it)",
                ));
            }
        }
        if let Some(h) = self.max_step {
            if h.is_nan() || h <= 0.0 {
                return Err(OptionError::float("AdaptiveOptions::max_step", h, "positive (None: no limit)"));
            }
        }
        if !(self.min_step.is_finite() && self.min_step >= 0.0) {
            return Err(OptionError::float("AdaptiveOptions::min_step", self.min_step, "finite and non-negative"));
        }
        if let Some(h) = self.max_step {
            if h < self.min_step {
                return Err(OptionError::float("AdaptiveOptions::max_step", h, "at least AdaptiveOptions::min_step"));
            }
        }
        if !(self.safety > 0.0 && self.safety <= 1.0) {
            return Err(OptionError::float("AdaptiveOptions::safety", self.safety, "in (0, 1]"));
        }
        if !(self.min_factor > 0.0 && self.min_factor < 1.0) {
            return Err(OptionError::float("AdaptiveOptions::min_factor", self.min_factor, "in (0, 1)"));
        }
        if !(self.max_factor > 1.0 && self.max_factor.is_finite()) {
            return Err(OptionError::float("AdaptiveOptions::max_factor", self.max_factor, "finite and above 1"));
        }
        if self.max_steps == 0 {
            return Err(OptionError::integer("AdaptiveOptions::max_steps", 0, "at least 1"));
        }
        self.consistency.validate()
    }
}

/// The largest absolute tolerance, `√f64::MAX ≈ 1.34e154`: no state with a
/// finite kinetic energy is that large (`|v|²` overflows beyond it), so an
/// absolute error bound above it bounds nothing.
pub const MAX_ABSOLUTE_TOLERANCE: f64 = 1.340_780_792_994_259_6e154;

/// Checks `rtol` and `atol` against their ranges: `rtol` is 0 or in
/// `[1e-15, 1)`, `atol` in `[0, MAX_ABSOLUTE_TOLERANCE]`, one of them
/// positive. Below 1e-15 relative the estimate is round-off, so such a
/// tolerance cannot be met; at 1 and above a relative error as large as
/// the state itself passes, so no digit of the solution is controlled and
/// the steps grow until Newton fails.
pub(crate) fn check_tolerances(rtol: f64, atol: f64) -> Result<(), OptionError> {
    if !(rtol.is_finite() && rtol >= 0.0) {
        return Err(OptionError::float("AdaptiveOptions::rtol", rtol, "0 or in [1e-15, 1)"));
    }
    if rtol > 0.0 && rtol < 1e-15 {
        return Err(OptionError::float(
            "AdaptiveOptions::rtol",
            rtol,
            "0 or in [1e-15, 1) (below 1e-15 the error estimate is round-off in double precision)",
        ));
    }
    if rtol >= 1.0 {
        return Err(OptionError::float(
            "AdaptiveOptions::rtol",
            rtol,
            "0 or in [1e-15, 1) (a relative error of 1 is as large as the state: no digit of the solution is \
             controlled)",
        ));
    }
    if !(atol.is_finite() && (0.0..=MAX_ABSOLUTE_TOLERANCE).contains(&atol)) {
        return Err(OptionError::float(
            "AdaptiveOptions::atol",
            atol,
            "in [0, 1.34e154] (above it, the largest state with a finite kinetic energy, it bounds nothing)",
        ));
    }
    if rtol == 0.0 && atol == 0.0 {
        return Err(OptionError::float("AdaptiveOptions::atol", atol, "positive when rtol is 0"));
    }
    Ok(())
}

/// One step with its error estimate (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatedStep<const N: usize> {
    /// The state after the two half steps (the one a run keeps).
    pub state: State<N>,
    /// The estimated local error of `state.q`: `(q_h − q_{h/2})/(2^p − 1)`.
    pub error_q: Vector<N>,
    /// The estimated local error of `state.v`.
    pub error_v: Vector<N>,
    /// The error in the weighted RMS norm (`≤ 1` meets the tolerance).
    pub scaled_error: f64,
    /// Newton iterations of the three solves.
    pub iterations: usize,
}

/// The weighted RMS norm of `(eq, ev)` with weights `atol + rtol·max(|a|, |b|)`.
/// A zero error counts zero whatever its weight: with `atol = 0` a component
/// that is zero at both ends has weight 0, and `0/0` would make the norm NaN
/// (every step rejected) for a coordinate that merely stays at rest. Where
/// the squares overflow the norm is `inf`, which [`initial_step`] reads as
/// "no usable scale".
fn scaled_norm<const N: usize>(
    eq: &Vector<N>,
    ev: &Vector<N>,
    a: &State<N>,
    b: &State<N>,
    rtol: f64,
    atol: f64,
) -> f64 {
    let sum = scaled_ratios(eq, ev, a, b, rtol, atol).fold(0.0, |sum, (rq, rv)| sum + (rq.powi(2) + rv.powi(2)));
    (sum / (2 * N).max(1) as f64).sqrt()
}

/// [`scaled_norm`] of a step's error estimate. Where the squares overflow
/// (an error above about 1e154 of a tiny tolerance, as `atol = 1e-300`
/// gives) the same norm is taken of the ratios over the largest one, so
/// that the estimate a failure reports is the finite number it is, not
/// `inf`; the controller shrinks the step by `min_factor` either way.
/// Below that it is [`scaled_norm`], bit for bit.
fn error_norm<const N: usize>(eq: &Vector<N>, ev: &Vector<N>, a: &State<N>, b: &State<N>, rtol: f64, atol: f64) -> f64 {
    let norm = scaled_norm(eq, ev, a, b, rtol, atol);
    if norm.is_finite() {
        return norm;
    }
    let ratios = scaled_ratios(eq, ev, a, b, rtol, atol);
    let largest = ratios.clone().fold(0.0, |m: f64, (rq, rv)| m.max(rq.abs()).max(rv.abs()));
    if !largest.is_finite() {
        return largest;
    }
    let scaled = ratios.fold(0.0, |sum, (rq, rv)| sum + ((rq / largest).powi(2) + (rv / largest).powi(2)));
    largest * (scaled / (2 * N).max(1) as f64).sqrt()
}

/// The ratios of [`scaled_norm`], `(eq_i / w_q,i, ev_i / w_v,i)` per coordinate.
fn scaled_ratios<'a, const N: usize>(
    eq: &'a Vector<N>,
    ev: &'a Vector<N>,
    a: &'a State<N>,
    b: &'a State<N>,
    rtol: f64,
    atol: f64,
) -> impl Iterator<Item = (f64, f64)> + Clone + 'a {
    (0..N).map(move |i| {
        let wq = atol + rtol * a.q[i].abs().max(b.q[i].abs());
        let wv = atol + rtol * a.v[i].abs().max(b.v[i].abs());
        (weighted(eq[i], wq), weighted(ev[i], wv))
    })
}

/// `e / w`, and 0 for `e = 0` (also where `w = 0`).
fn weighted(e: f64, w: f64) -> f64 {
    if e == 0.0 {
        0.0
    } else {
        e / w
    }
}

/// Which solve of a step with estimate failed.
#[derive(Clone, Debug, PartialEq)]
pub struct EstimateFailure {
    /// Step solves that succeeded before the failure.
    pub solves: usize,
    /// Newton iterations of those solves.
    pub iterations: usize,
    /// The failure.
    pub error: StepError,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// One step of size `h` from `state` with its local error estimate by
    /// step doubling (module docs): the whole step, then two half steps from
    /// `state`. The stepper continues from the half steps' end (a following
    /// step from `result.state` is warm-started), as if only they had been
    /// taken. On failure the stepper continues from `state` again. `rtol`
    /// and `atol` have the ranges of [`AdaptiveOptions::rtol`] and
    /// [`AdaptiveOptions::atol`] ([`StepError::InvalidOption`] otherwise).
    pub fn step_with_estimate(
        &mut self,
        state: &State<N>,
        h: f64,
        rtol: f64,
        atol: f64,
    ) -> Result<EstimatedStep<N>, EstimateFailure> {
        if let Err(e) = check_tolerances(rtol, atol) {
            return Err(EstimateFailure { solves: 0, iterations: 0, error: StepError::InvalidOption(Box::new(e)) });
        }
        self.estimate(state, h, rtol, atol).map(|(est, _)| est)
    }

    /// [`step_with_estimate`](Self::step_with_estimate) with the results of
    /// the two half steps (what their continuous extensions need).
    pub(crate) fn estimate(
        &mut self,
        state: &State<N>,
        h: f64,
        rtol: f64,
        atol: f64,
    ) -> Result<(EstimatedStep<N>, Halves<N, M, S>), EstimateFailure> {
        let saved = self.continuation();
        let mut iterations = 0;
        let mut solves = 0;
        let fail = |this: &mut Self, solves: usize, iterations: usize, error: StepError| {
            this.restore_continuation(&saved);
            EstimateFailure { solves, iterations, error }
        };
        let whole = match self.step_or_fail(state, h) {
            Ok(r) => r.state,
            Err(e) => return Err(fail(self, solves, iterations, e)),
        };
        iterations += self.last_history().len();
        solves += 1;
        self.restore_continuation(&saved);
        // The midpoint on the time grid, so that the half steps' sizes are
        // the times they advance (see `on_time_grid`).
        let half = on_time_grid(state.t, 0.5 * h);
        let first = match self.step_or_fail(state, half) {
            Ok(r) => r,
            Err(e) => return Err(fail(self, solves, iterations, e)),
        };
        iterations += self.last_history().len();
        solves += 1;
        let second = match self.step_or_fail(&first.state, h - half) {
            Ok(r) => r,
            Err(e) => return Err(fail(self, solves, iterations, e)),
        };
        iterations += self.last_history().len();
        let end = second.state;
        let p = self.tableau().method.order_for(S, &Sys::STRUCTURE) as i32;
        let denominator = 2f64.powi(p) - 1.0;
        let error_q = (whole.q - end.q) / denominator;
        let error_v = (whole.v - end.v) / denominator;
        let scaled_error = error_norm(&error_q, &error_v, state, &end, rtol, atol);
        let sizes = [half, h - half];
        Ok((
            EstimatedStep { state: end, error_q, error_v, scaled_error, iterations },
            Halves { results: [first, second], sizes },
        ))
    }
}

/// The two half steps of a step with estimate: their results (the second
/// ends at the kept state) and their signed sizes.
pub(crate) struct Halves<const N: usize, const M: usize, const S: usize> {
    results: [StepResult<N, M, S>; 2],
    sizes: [f64; 2],
}

/// Statistics of a tolerance-driven run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdaptiveReport {
    /// Accepted steps.
    pub accepted: usize,
    /// Steps rejected because the error estimate exceeded the tolerance.
    pub rejected: usize,
    /// Steps rejected because a Newton solve failed.
    pub newton_failures: usize,
    /// Step solves, successful or not (the cost: three per attempt with an
    /// estimate, one per step of a reversible run).
    pub solves: usize,
    /// Newton iterations over all solves.
    pub newton_iterations: usize,
    /// Smallest accepted step magnitude.
    pub smallest_step: f64,
    /// Largest accepted step magnitude.
    pub largest_step: f64,
    /// The scale `ε` of a reversible run's step sizes `h = ε/ρ` (0 otherwise).
    pub epsilon: f64,
}

/// A tolerance-driven run: the trajectory at the accepted steps (its
/// [`RunReport`](crate::RunReport) counts accepted steps and their Newton iterations) and the
/// controller's statistics.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdaptiveRun<const N: usize, const M: usize> {
    /// The recorded points.
    pub trajectory: Trajectory<N, M>,
    /// The controller's statistics.
    pub report: AdaptiveReport,
}

/// A tolerance-driven run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AdaptiveError {
    /// An option is out of range (checked before any step).
    #[error("{0}")]
    InvalidOption(OptionError),
    /// The interval is unusable.
    #[error("invalid interval t0 = {}, t_end = {}: {reason}", Exact(*t0), Exact(*t_end))]
    InvalidInterval {
        /// Start.
        t0: f64,
        /// End.
        t_end: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// The output times of [`integrate_adaptive_at`] are unusable.
    #[error("invalid output times: {reason}")]
    InvalidOutputTimes {
        /// What is wrong.
        reason: &'static str,
    },
    /// The initial state was rejected or could not be projected.
    #[error("initial state: {0}")]
    Initial(#[source] StepError),
    /// A failure no smaller step can cure (e.g. a non-finite state).
    #[error("step from t = {} failed: {source}", Sci(*t))]
    Step {
        /// Where.
        t: f64,
        /// Why.
        source: StepError,
        /// Statistics up to the failure.
        partial: Box<AdaptiveReport>,
    },
    /// The controller asked for a step below the smallest allowed one.
    #[error(
        "step from t = {} needs h = {} below the smallest step {}{}{}",
        Sci(*t),
        Sci(*h),
        Sci(*min_step),
        why_too_small(*scaled_error, last_newton.as_deref()),
        too_small_advice(*t, *min_step)
    )]
    StepSizeTooSmall {
        /// Where.
        t: f64,
        /// The step proposed.
        h: f64,
        /// The floor (`min_step`, or the resolution of `t`).
        min_step: f64,
        /// The last scaled error estimate (∞ after a Newton failure, NaN
        /// when no estimate asked for the step: the first step, or the
        /// steps of a reversible run).
        scaled_error: f64,
        /// The last Newton failure, if the last attempt failed in Newton.
        last_newton: Option<Box<StepError>>,
        /// Statistics up to the failure.
        partial: Box<AdaptiveReport>,
    },
    /// `max_steps` attempts did not reach the final time.
    #[error(
        "{attempts} step attempts (the limit: AdaptiveOptions::max_steps, `--max-steps` of `spark run`) reached \
         t = {} of t_end = {}; raise the limit or loosen the tolerance",
        Exact(*t),
        Exact(*t_end)
    )]
    TooManySteps {
        /// Attempts made.
        attempts: usize,
        /// Time reached.
        t: f64,
        /// Requested end.
        t_end: f64,
        /// Statistics up to the failure.
        partial: Box<AdaptiveReport>,
    },
    /// The given first step is below the smallest step a run takes at
    /// `t0` (`min_step`, or the resolution of `t` there): refused before
    /// the first step, which would fail at once.
    #[error(
        "the first step, first_step = {} (AdaptiveOptions::initial_step, `--first-step` of `spark run`), is below {}, \
         the smallest step a run takes from t0 = {}; give a first step of at least that, or none to let the run \
         estimate it",
        Sci(*first_step),
        floor_words(*floor, *t0),
        Sci(*t0)
    )]
    FirstStepTooSmall {
        /// The first step asked for (capped by `max_step`).
        first_step: f64,
        /// The smallest step a run takes at `t0`.
        floor: f64,
        /// Start of the run.
        t0: f64,
    },
    /// The largest step allowed cannot reach `t_end` within `max_steps`
    /// steps, whatever the tolerance: refused before the first step, so
    /// that the run does not spend its attempts to find out.
    #[error(
        "the largest step, max_step = {} (AdaptiveOptions::max_step, `--max-step` of `spark run`), needs at least {} \
         steps from t0 = {} to t_end = {}, more than the {max_steps} step attempts allowed (the limit: \
         AdaptiveOptions::max_steps, `--max-steps` of `spark run`); raise max_step or the limit",
        Sci(*max_step),
        Sci(*needed),
        Exact(*t0),
        Exact(*t_end)
    )]
    MaxStepTooSmall {
        /// The largest step allowed.
        max_step: f64,
        /// The fewest steps of at most `max_step` from `t0` to `t_end`.
        needed: f64,
        /// The step limit ([`AdaptiveOptions::max_steps`]).
        max_steps: usize,
        /// Start of the run.
        t0: f64,
        /// Requested end.
        t_end: f64,
    },
    /// The run located more events than it keeps
    /// ([`AdaptiveOptions::max_events`]).
    #[error("{}", crate::events::too_many_events("AdaptiveOptions::max_events", *max_events, *t))]
    TooManyEvents {
        /// The most events the run keeps.
        max_events: usize,
        /// The start of the step in which one more was located.
        t: f64,
        /// Statistics up to there.
        partial: Box<AdaptiveReport>,
    },
    /// The observer asked the run to stop
    /// ([`crate::Observer::stop_requested`]).
    #[error("stopped by its observer at t = {}", Sci(*t))]
    Stopped {
        /// Where the last accepted step ended.
        t: f64,
        /// Statistics up to there.
        partial: Box<AdaptiveReport>,
    },
    /// The reversible rule needs a positive, finite step density.
    #[error("the step density σ = {} at t = {} is not finite and positive", Sci(*sigma), Sci(*t))]
    InvalidDensity {
        /// Where.
        t: f64,
        /// The value.
        sigma: f64,
    },
    /// The reversible rule needs a symmetric method.
    #[error(
        "{method} is not symmetric; reversible stepping needs Gauss, Lobatto IIIA-B or the Lobatto IIIB-A LDA method"
    )]
    NotSymmetric {
        /// The method of the stepper.
        method: Method,
    },
}

impl AdaptiveError {
    /// A step of magnitude `h` from `t` below the smallest allowed one,
    /// with the error estimate and the Newton failure that asked for it.
    fn too_small(
        t: f64,
        h: f64,
        min_step: f64,
        scaled_error: f64,
        last_newton: Option<StepError>,
        report: AdaptiveReport,
    ) -> Self {
        let (last_newton, partial) = (last_newton.map(Box::new), Box::new(report));
        AdaptiveError::StepSizeTooSmall { t, h, min_step, scaled_error, last_newton, partial }
    }

    /// The step limit reached at `t` after `attempts` attempts, short of
    /// `t_end`.
    fn too_many(attempts: usize, t: f64, t_end: f64, report: AdaptiveReport) -> Self {
        AdaptiveError::TooManySteps { attempts, t, t_end, partial: Box::new(report) }
    }
}

/// What asked for a step below the floor, for [`AdaptiveError::StepSizeTooSmall`]:
/// the last error estimate, the last Newton failure, or nothing (NaN: no
/// estimate was made).
fn why_too_small(scaled_error: f64, last_newton: Option<&StepError>) -> String {
    match last_newton {
        Some(e) => format!(" (error estimate {} of the tolerance; last Newton failure: {e})", Sci(scaled_error)),
        None if scaled_error.is_nan() => String::new(),
        None => format!(" (error estimate {} of the tolerance)", Sci(scaled_error)),
    }
}

/// What to change when a step falls below `floor` at `t`. Where the floor
/// is the resolution of `t` (16 units in the last place), far from
/// `t = 0`, the steps the problem needs are shorter than the times `f64`
/// tells apart there, whatever the tolerance: the run has to start nearer
/// `t = 0`. Within about 6e-294 of `t = 0` it is the smallest normal step,
/// which only a looser tolerance lifts the steps above. Otherwise the floor
/// is `AdaptiveOptions::min_step`.
fn too_small_advice(t: f64, floor: f64) -> String {
    if floor == resolution(t) && normal_floor(t) {
        " (2.2e-308, the smallest normal step: below it 1/h overflows in the step's equations); loosen rtol/atol, \
         or check the system for a singularity"
            .to_string()
    } else if floor > 0.0 && floor == resolution(t) {
        format!(
            " (16 units in the last place of t: the resolution of t at |t| = {}, below which a step does not \
             advance time by its size); run nearer t = 0 (for a system without explicit time dependence a shift \
             of t0 changes nothing else), or loosen rtol/atol if the error estimate asked for the step",
            Sci(t.abs())
        )
    } else {
        "; loosen rtol/atol, lower AdaptiveOptions::min_step, or check the system for a singularity".to_string()
    }
}

/// Refuses a run from `t0` to `t_end` whose largest step
/// ([`AdaptiveOptions::max_step`]) cannot get there within
/// [`AdaptiveOptions::max_steps`] steps. A step advances `t` by at most
/// `max_step` plus what rounding to the grid of `t` adds (half a unit in
/// the last place of `t`), and only the last one by up to 1 % more
/// (stretched rather than leave a sliver): so at least
/// `|t_end − t0| / (max_step + ε·max(|t0|, |t_end|)) − 0.01` steps are
/// needed, however the controller chooses them.
pub(super) fn check_step_budget(t0: f64, t_end: f64, options: &AdaptiveOptions) -> Result<(), AdaptiveError> {
    let Some(max_step) = options.max_step else { return Ok(()) };
    let slack = f64::EPSILON * t0.abs().max(t_end.abs());
    let needed = ((t_end - t0).abs() / (max_step + slack) - 0.01).ceil();
    if needed > options.max_steps as f64 {
        return Err(AdaptiveError::MaxStepTooSmall { max_step, needed, max_steps: options.max_steps, t0, t_end });
    }
    Ok(())
}

/// Refuses a given first step ([`AdaptiveOptions::initial_step`], capped
/// by `max_step`) below the floor every step of a run from `t0` keeps to:
/// [`AdaptiveOptions::min_step`], or where larger the resolution of `t` at
/// `t0` (16 units in its last place, the smallest step that advances time
/// by its size). Far from `t = 0` a first step that suits a run near it
/// lies below that resolution; without this the run fails on its first
/// attempt with [`AdaptiveError::StepSizeTooSmall`], whose advice cannot
/// tell that the step was the caller's.
pub(super) fn check_first_step(t0: f64, options: &AdaptiveOptions) -> Result<(), AdaptiveError> {
    let Some(given) = options.initial_step else { return Ok(()) };
    let first_step = options.max_step.map_or(given, |max_step| given.min(max_step));
    let floor = step_floor(options, t0);
    if first_step < floor {
        return Err(AdaptiveError::FirstStepTooSmall { first_step, floor, t0 });
    }
    Ok(())
}

/// The floor of [`AdaptiveError::FirstStepTooSmall`] in words: the
/// resolution of `t` at `t0`, or `AdaptiveOptions::min_step`.
fn floor_words(floor: f64, t0: f64) -> String {
    if floor == resolution(t0) && normal_floor(t0) {
        format!("{} (the smallest normal step, below which 1/h overflows in the step's equations)", Sci(floor))
    } else if floor == resolution(t0) {
        format!("{} (16 units in the last place of t0, the resolution of t there)", Sci(floor))
    } else {
        format!("min_step = {} (AdaptiveOptions::min_step)", Sci(floor))
    }
}

/// Whether the method's step is symmetric (`Φ_{−h} = Φ_h^{−1}`).
pub fn is_symmetric(method: Method) -> bool {
    matches!(method, Method::Gauss | Method::LobattoIIIAB | Method::LobattoIIIBALda)
}

/// The first step magnitude when none is given (Hairer–Nørsett–Wanner,
/// *Solving ODEs I*, §II.4): `0.01·‖y₀‖/‖y₀'‖` in the weighted norm, with
/// `y₀' = (v₀, a₀)` from the consistent acceleration.
fn initial_step<Sys, const N: usize, const M: usize>(sys: &Sys, state: &State<N>, options: &AdaptiveOptions) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let a0 = consistent_acceleration(sys, state.t, &state.q, &state.v).map_or(Vector::zeros(), |(a, _)| a);
    let d0 = scaled_norm(&state.q, &state.v, state, state, options.rtol, options.atol);
    let d1 = scaled_norm(&state.v, &a0, state, state, options.rtol, options.atol);
    if d0 < 1e-5 || d1 < 1e-5 || !d1.is_finite() {
        1e-6
    } else {
        0.01 * d0 / d1
    }
}

/// The magnitude of a run's first step from `state`: the given
/// [`AdaptiveOptions::initial_step`], or the estimate of [`initial_step`]
/// raised to the smallest step a run takes there (far from `t = 0` the
/// estimate can lie below the resolution of `t`, and the controller then
/// starts from that floor rather than give up before its first estimate),
/// at most `max_step`.
pub(super) fn first_step<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    state: &State<N>,
    options: &AdaptiveOptions,
    max_step: f64,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let h = match options.initial_step {
        Some(h) => h,
        None => initial_step(sys, state, options).max(step_floor(options, state.t)),
    };
    h.min(max_step)
}

/// The signed step `h` from `t` rounded to the time grid: the difference
/// between `t` and the `f64` nearest `t + h`, which is what the step's end
/// time advances by. A step integrated over `h` itself but stamped
/// `t + h` rounded would carry a time off by up to half a unit in the last
/// place of `t`, and over many steps far from `t = 0` the errors add up
/// (from `t = 1e12` to `1e12 + 10` at `rtol = 1e-8`, a skate turning at
/// unit rate reached the end having turned 9.998). Near `t = 0` it changes
/// `h` by round-off only.
pub(crate) fn on_time_grid(t: f64, h: f64) -> f64 {
    (t + h) - t
}

/// The fixed-step drivers' [`time_resolution`](crate::driver::time_resolution)
/// of `t`, and at least the smallest normal number: near `t = 0` the
/// resolution of `t` is subnormal, and a subnormal step overflows `1/h` in
/// the step's equations, so `Stepper::step` refuses it: the controller
/// stops at this floor with `StepSizeTooSmall` rather than propose a step
/// the stepper refuses.
fn resolution(t: f64) -> f64 {
    crate::driver::time_resolution(t).max(f64::MIN_POSITIVE)
}

/// Whether the floor of a step at `t` is the smallest normal number rather
/// than the resolution of `t` (only within about 6e-294 of `t = 0`).
fn normal_floor(t: f64) -> bool {
    crate::driver::time_resolution(t) < f64::MIN_POSITIVE
}

/// The smallest step a run takes at `t`, the floor of every step size the
/// controller chooses: [`AdaptiveOptions::min_step`], or where larger the
/// resolution of `t` (16 units in its last place, below which a step does
/// not advance time by its size).
pub(super) fn step_floor(options: &AdaptiveOptions, t: f64) -> f64 {
    options.min_step.max(resolution(t))
}

/// Integrates from `(t₀, q₀, v₀)` to `t_end` (either direction) with step
/// sizes chosen by the PI controller on the step-doubling error estimate
/// (module docs), landing exactly on `t_end`. `observer` sees every
/// accepted step with its Newton iterations (of the three solves), and,
/// when it asks for it ([`Observer::DENSE`]), the continuous extension of
/// each of its two half steps. The events the system declares are located
/// in every accepted step and reported in the trajectory, exactly as by
/// [`Stepper::integrate`]; a terminal one ends the run at its time.
///
/// Every run starts afresh (as [`Stepper::integrate`]); the options are
/// checked first ([`AdaptiveOptions::validate`]).
pub fn integrate_adaptive<Sys, O, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    observer: &mut O,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    adaptive_run(stepper, t0, q0, v0, t_end, options, observer, declared_events::<Sys, N, M>(), None)
}

/// [`integrate_adaptive`] locating the events of `events` instead of the
/// system's own (e.g. [`RuntimeEvents`](crate::RuntimeEvents), or
/// [`NoEvents`](crate::NoEvents) to ignore the declared ones).
#[allow(clippy::too_many_arguments)]
pub fn integrate_adaptive_with_events<Sys, O, E, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    observer: &mut O,
    events: &E,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    E: EventFunctions<Sys, N>,
{
    adaptive_run(stepper, t0, q0, v0, t_end, options, observer, events, None)
}

/// [`integrate_adaptive_with_events`] recording the state at the output
/// times `times` instead of at the accepted steps: the run goes from `t₀` to
/// the last of `times` with the step sizes of the controller (which never
/// shortens a step to land on an output time), and each time is sampled
/// from the continuous extension of the accepted step that holds it, as
/// [`Schedule::Sampled`](crate::Schedule::Sampled) samples a fixed-step run.
/// The samples are the initial point and each time (a terminal event
/// ends the run, and the samples, at its time, adding the state there).
/// `times` are finite, strictly monotone, the first one not before `t₀`
/// and the last one not at `t₀`; `record_every` does not apply.
#[allow(clippy::too_many_arguments)]
pub fn integrate_adaptive_at<Sys, O, E, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    times: &[f64],
    options: &AdaptiveOptions,
    observer: &mut O,
    events: &E,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    E: EventFunctions<Sys, N>,
{
    let t_end = check_output_times(t0, times)?;
    adaptive_run(stepper, t0, q0, v0, t_end, options, observer, events, Some(times))
}

/// The last of the output times `times` of a run from `t0`, once they are
/// checked: finite, strictly monotone in the direction from `t0` to the
/// last one, the first not before `t0`, the last not at `t0`.
fn check_output_times(t0: f64, times: &[f64]) -> Result<f64, AdaptiveError> {
    let bad = |reason| Err(AdaptiveError::InvalidOutputTimes { reason });
    let Some(&last) = times.last() else { return bad("no output time is given") };
    if times.iter().any(|t| !t.is_finite()) {
        return bad("output times must be finite");
    }
    if last == t0 {
        return bad("the last output time is t0: there is nothing to integrate");
    }
    // Signs, not products: (t − t0)·dir underflows for tiny gaps.
    let dir = (last - t0).signum();
    if (times[0] - t0) * dir < 0.0 || times.windows(2).any(|w| (w[1] - w[0]) * dir <= 0.0) {
        return bad("output times must be strictly monotone, from t0 on, in the direction of the last one");
    }
    Ok(last)
}

#[allow(clippy::too_many_arguments)]
fn adaptive_run<Sys, O, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    observer: &mut O,
    events: &dyn EventFunctions<Sys, N>,
    times: Option<&[f64]>,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    let output = Output { wants_dense: O::DENSE, times };
    whole_run(stepper, t0, q0, v0, t_end, options, output, events, |stepper, state, rec| {
        adaptive_loop(stepper, state, t_end, options, rec, observer)
    })
}

fn adaptive_loop<Sys, O, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    mut state: State<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    rec: &mut Recorder<'_, Sys, N, M, S>,
    observer: &mut O,
) -> Result<AdaptiveReport, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    let dir = (t_end - state.t).signum();
    let span = (t_end - state.t).abs();
    let max_step = options.max_step.unwrap_or(span).min(span);
    let k = (stepper.tableau().method.order_for(S, &Sys::STRUCTURE) + 1) as f64;
    let (alpha, beta) = (0.7 / k, 0.4 / k);
    let mut report = AdaptiveReport { smallest_step: f64::INFINITY, ..AdaptiveReport::default() };
    let mut h = first_step(stepper.system(), &state, options, max_step);
    let mut err_prev = 1.0f64;
    // The last error estimate (∞ after a Newton failure; NaN before the first).
    let mut last_err = f64::NAN;
    let mut rejected_last = false;
    let mut attempts = 0usize;
    loop {
        let remaining = (t_end - state.t).abs();
        // Land on t_end; stretch a step that would leave a sliver behind.
        let last = h >= remaining || remaining - h < 0.01 * h;
        let this = if last { remaining } else { h };
        let floor = step_floor(options, state.t);
        if this < floor {
            return Err(AdaptiveError::too_small(state.t, this, floor, last_err, None, report));
        }
        // After the floor's test: rounding moves a step at the floor by half
        // a unit in the last place of t at most.
        let this = if last { this } else { on_time_grid(state.t, dir * this).abs() };
        if attempts >= options.max_steps {
            return Err(AdaptiveError::too_many(attempts, state.t, t_end, report));
        }
        attempts += 1;
        // A rejected attempt must not leave the stepper continuing from its
        // discarded end: the retry from `state` keeps its warm start and the
        // round-off compensation of `state`.
        let saved = stepper.continuation();
        let step = stepper.estimate(&state, dir * this, options.rtol, options.atol);
        match step {
            Ok((est, halves)) => {
                report.solves += 3;
                report.newton_iterations += est.iterations;
                let err = est.scaled_error;
                last_err = err;
                if err <= 1.0 {
                    let [first, second] = &halves.results;
                    let pieces = [(halves.sizes[0], first), (halves.sizes[1], second)];
                    let taken = Taken { start: state, pieces: &pieces, this, iterations: est.iterations, last };
                    let done;
                    (state, done) = accept(stepper, rec, observer, &mut report, taken, t_end)?;
                    if done {
                        return Ok(report);
                    }
                    let mut factor = if err == 0.0 {
                        options.max_factor
                    } else {
                        options.safety * err.powf(-alpha) * err_prev.powf(beta)
                    };
                    factor = factor.clamp(options.min_factor, options.max_factor);
                    if rejected_last {
                        factor = factor.min(1.0);
                    }
                    h = (this * factor).min(max_step);
                    err_prev = err.max(1e-4);
                    rejected_last = false;
                } else if err.is_finite() {
                    stepper.restore_continuation(&saved);
                    report.rejected += 1;
                    let factor = (options.safety * err.powf(-1.0 / k)).clamp(options.min_factor, 1.0);
                    h = this * factor;
                    rejected_last = true;
                } else {
                    stepper.restore_continuation(&saved);
                    report.rejected += 1;
                    h = this * options.min_factor;
                    rejected_last = true;
                }
            }
            Err(f) => {
                report.solves += f.solves + 1;
                report.newton_iterations += f.iterations + f.error.history().map_or(0, |h| h.len());
                if !f.error.is_curable() {
                    return Err(AdaptiveError::Step { t: state.t, source: f.error, partial: Box::new(report) });
                }
                report.newton_failures += 1;
                last_err = f64::INFINITY;
                stepper.reset_warm_start();
                h = 0.25 * this;
                rejected_last = true;
                let floor = step_floor(options, state.t);
                if h < floor {
                    return Err(AdaptiveError::too_small(state.t, h, floor, f64::INFINITY, Some(f.error), report));
                }
            }
        }
    }
}
