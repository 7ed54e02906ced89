//! Step rejection as a failure policy of the driver
//! ([`FailurePolicy::Reject`]): when the Newton solve of a step fails, the
//! same interval is covered by sub-steps whose size is halved after every
//! failure (never below a floor) and doubled back after a run of successes;
//! the next scheduled step starts again at its own size.
//!
//! This owns the policy ([`RejectionPolicy`]) and two conveniences over
//! the driver's loop: one protected step ([`step_with_rejection`]) and a
//! run to a final time ([`integrate_with_rejection`], which is
//! [`Stepper::integrate`] with [`Schedule::Until`] under
//! [`FailurePolicy::Reject`]). Failures that a smaller step cannot cure
//! (a non-finite state, `h = 0`, an inconsistent initial state, a final
//! time behind the start) are returned at once, typed, before any step is
//! taken.
//!
//! The default policy [`FailurePolicy::Halve`] retries a failed step as two
//! half steps, nested; rejection differs in that the sub-step size adapts
//! within the interval (halve on failure, double back after successes) and
//! that giving up reports the floor reached and the last Newton failure.

use crate::driver::{FailurePolicy, IntegrationError, Observe, RunOptions, RunReport, Schedule, StepFailure};
use crate::error::{Sci, StepError};
use crate::events::NoEvents;
use crate::initial::{consistent_velocity, ConsistencyPolicy};
use crate::step::{State, StepResult, Stepper};
use crate::system::{NonholonomicSystem, Vector};

/// How far a step may be cut down and when it grows back.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RejectionPolicy {
    /// Largest number of successive halvings of the nominal step
    /// (the relative floor is `|h|·2^−max_halvings`).
    pub max_halvings: u32,
    /// Absolute floor of the sub-step magnitude; the effective floor is the
    /// larger of this and the relative one.
    pub min_step: f64,
    /// Successful sub-steps in a row after which the sub-step is doubled
    /// (never beyond the nominal step).
    pub regrow_after: usize,
}

impl Default for RejectionPolicy {
    fn default() -> Self {
        RejectionPolicy { max_halvings: 12, min_step: 1e-12, regrow_after: 2 }
    }
}

impl RejectionPolicy {
    /// Checks the policy's own fields.
    pub fn validate(&self) -> Result<(), RejectionError> {
        if !(self.min_step.is_finite() && self.min_step >= 0.0) {
            return Err(RejectionError::InvalidPolicy("min_step must be finite and non-negative"));
        }
        if self.max_halvings > 60 {
            return Err(RejectionError::InvalidPolicy("max_halvings must be at most 60"));
        }
        if self.regrow_after == 0 {
            return Err(RejectionError::InvalidPolicy("regrow_after must be at least 1"));
        }
        Ok(())
    }

    /// The smallest sub-step magnitude allowed for nominal step `h`.
    pub fn floor(&self, h: f64) -> f64 {
        (h.abs() * 0.5f64.powi(self.max_halvings as i32)).max(self.min_step)
    }
}

/// Why a protected step or run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RejectionError {
    /// The policy itself is unusable.
    #[error("invalid rejection policy: {0}")]
    InvalidPolicy(&'static str),
    /// The final time lies behind the start for the sign of `h`, or a time is not finite.
    #[error("invalid interval: t0 = {}, t_end = {}, h = {}: {reason}", Sci(*t0), Sci(*t_end), Sci(*h))]
    InvalidInterval {
        /// Start time.
        t0: f64,
        /// Requested final time.
        t_end: f64,
        /// Nominal step.
        h: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// A failure no smaller step can cure (bad input: `h = 0`, non-finite
    /// state, inconsistent initial state).
    #[error("{0}")]
    Input(#[source] StepError),
    /// Newton kept failing down to the smallest sub-step allowed.
    #[error(
        "step from t = {} (nominal h = {}) still fails with sub-step {} at the floor {} \
         after {rejections} rejections; last failure: {last}",
        Sci(*t),
        Sci(*h),
        Sci(*h_tried),
        Sci(*floor)
    )]
    Floor {
        /// Where the failing sub-step starts.
        t: f64,
        /// Nominal step size.
        h: f64,
        /// The last sub-step size tried.
        h_tried: f64,
        /// The floor (see [`RejectionPolicy::floor`]).
        floor: f64,
        /// Rejections in this nominal step.
        rejections: usize,
        /// The last Newton failure.
        last: Box<StepError>,
    },
}

/// The outcome of one protected nominal step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProtectedStep<const N: usize> {
    /// The state at `t₀ + h` (time pinned to exactly `t₀ + h`).
    pub state: State<N>,
    /// Accepted sub-steps (1 when the nominal step succeeded at once).
    pub substeps: usize,
    /// Failed attempts (each followed by a halving).
    pub rejections: usize,
    /// Smallest sub-step magnitude used.
    pub smallest_step: f64,
    /// Newton iterations over the accepted sub-steps.
    pub iterations: usize,
}

/// One nominal step of size `h` from `state` under `policy`: tries `h`; on a
/// Newton failure covers `[t₀, t₀ + h]` with sub-steps that halve after each
/// failure and double back after `regrow_after` successes. The same
/// sub-step loop as the driver's under [`FailurePolicy::Reject`].
pub fn step_with_rejection<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    state: &State<N>,
    h: f64,
    policy: &RejectionPolicy,
) -> Result<ProtectedStep<N>, RejectionError>
where
    Sys: NonholonomicSystem<N, M>,
{
    policy.validate()?;
    let t_end = state.t + h;
    let counts = stepper
        .rejecting_step(
            state,
            h,
            t_end,
            policy,
            &mut |_: &Sys, _: &State<N>, _: &State<N>, _: f64, _: &StepResult<N, M, S>| false,
        )
        .map_err(|failure| match failure {
            StepFailure::Step(e) => RejectionError::Input(e),
            StepFailure::Floor { substep_t, h_tried, floor, rejections, last } => {
                RejectionError::Floor { t: substep_t, h, h_tried, floor, rejections, last: Box::new(last) }
            }
        })?;
    let mut out = ProtectedStep {
        state: counts.state,
        substeps: counts.substeps,
        rejections: counts.rejected,
        smallest_step: h.abs().min(counts.smallest),
        iterations: counts.iterations,
    };
    out.state.t = t_end;
    // The next nominal step continues this one: let it extrapolate from the
    // last accepted (sub-)step, whose end differs from ours only in `t`.
    stepper.retarget_warm_start(&out.state);
    Ok(out)
}

/// Statistics of a protected run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RejectionReport {
    /// Nominal steps completed.
    pub steps: usize,
    /// Accepted sub-steps over the run.
    pub substeps: usize,
    /// Failed attempts over the run.
    pub rejections: usize,
    /// Nominal steps that needed at least one rejection.
    pub rejected_steps: usize,
    /// Smallest sub-step magnitude used.
    pub smallest_step: f64,
    /// Newton iterations over all accepted sub-steps.
    pub iterations: usize,
}

/// A protected run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("protected run failed in nominal step {index} from t = {}: {source}", Sci(*t))]
pub struct RejectionRunError {
    /// Index of the failed nominal step (0-based; 0 also for input errors).
    pub index: usize,
    /// Its start time.
    pub t: f64,
    /// Why.
    #[source]
    pub source: RejectionError,
    /// Statistics up to the failure.
    pub partial: RejectionReport,
}

/// Integrates from `(t₀, q₀, v₀)` to `t_end` with nominal step `h` (the last
/// step shortened to land on `t_end`) under `policy`: [`Stepper::integrate`]
/// with [`Schedule::Until`] and [`FailurePolicy::Reject`], no samples but
/// the endpoints and no events. The initial velocity must satisfy the
/// constraints to `1e-12`; `t_end` must lie ahead of `t₀` in the direction
/// of `h`. `observer` sees every nominal step's end state and its Newton
/// iterations.
#[allow(clippy::too_many_arguments)]
pub fn integrate_with_rejection<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    h: f64,
    policy: &RejectionPolicy,
    mut observer: &mut dyn FnMut(&State<N>, usize),
) -> Result<(State<N>, RejectionReport), RejectionRunError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let fail = |source| RejectionRunError { index: 0, t: t0, source, partial: RejectionReport::default() };
    policy.validate().map_err(fail)?;
    let interval = |reason| fail(RejectionError::InvalidInterval { t0, t_end, h, reason });
    if !t0.is_finite() || !t_end.is_finite() {
        return Err(interval("times must be finite"));
    }
    if h == 0.0 || !h.is_finite() {
        return Err(interval("step size must be finite and nonzero"));
    }
    if (t_end - t0) * h.signum() < 0.0 {
        return Err(interval("the final time lies behind the start in the direction of h"));
    }
    consistent_velocity(stepper.system(), t0, q0, v0, ConsistencyPolicy::default())
        .map_err(|e| fail(RejectionError::Input(e)))?;
    if ((t_end - t0) / h).abs().ceil() > 1e12 {
        return Err(interval("more than 10¹² steps"));
    }
    let options = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        on_failure: FailurePolicy::Reject(*policy),
        ..RunOptions::default()
    };
    let schedule = Schedule::Until { h, t_end };
    let summary = |r: &RunReport| RejectionReport {
        steps: r.steps,
        substeps: r.substeps,
        rejections: r.rejected_steps,
        rejected_steps: r.steps_with_rejections,
        smallest_step: if r.smallest_step > 0.0 { h.abs().min(r.smallest_step) } else { h.abs() },
        iterations: r.newton_iterations_total,
    };
    match stepper.integrate_with_events(t0, q0, v0, schedule, &options, &mut observer, &NoEvents) {
        Ok(run) => {
            let end = run.last().unwrap_or(State::new(t0, *q0, *v0));
            Ok((end, summary(&run.report)))
        }
        Err(e) => Err(match e {
            IntegrationError::InvalidSchedule(reason) => interval(reason),
            IntegrationError::InvalidOption(o) => fail(RejectionError::Input(StepError::InvalidOption(Box::new(o)))),
            IntegrationError::Initial(e) => fail(RejectionError::Input(e)),
            IntegrationError::Step { index, t, source, partial } => {
                RejectionRunError { index, t, source: RejectionError::Input(source), partial: summary(&partial) }
            }
            IntegrationError::Floor { index, t, detail, partial } => {
                let d = *detail;
                RejectionRunError {
                    index,
                    t,
                    source: RejectionError::Floor {
                        t: d.substep_t,
                        h: d.h,
                        h_tried: d.h_tried,
                        floor: d.floor,
                        rejections: d.rejections,
                        last: Box::new(d.last),
                    },
                    partial: summary(&partial),
                }
            }
        }),
    }
}
