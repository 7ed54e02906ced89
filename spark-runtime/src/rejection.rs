//! The step-rejection policy of the driver ([`FailurePolicy::Reject`]):
//! when the Newton solve of a step fails, the same interval is covered by
//! sub-steps whose size is halved after every failure (never below a
//! floor) and doubled back after a run of successes; the next scheduled
//! step starts again at its own size.
//!
//! A run under this policy is [`Stepper::integrate`](crate::Stepper::integrate)
//! with `RunOptions { on_failure: FailurePolicy::Reject(policy), .. }`: one
//! loop, one [`RunReport`](crate::RunReport) (its `substeps`,
//! `rejected_steps`, `steps_with_rejections` and `smallest_step` count the
//! sub-steps) and one error type ([`IntegrationError`](crate::IntegrationError),
//! with [`IntegrationError::Floor`](crate::IntegrationError::Floor) when the
//! sub-steps reach the floor). Failures that a smaller step cannot cure (a
//! non-finite state, an inconsistent initial state, an invalid schedule or
//! policy) are returned at once, typed, before any step is taken.
//!
//! The default policy [`FailurePolicy::Halve`] retries a failed step as two
//! half steps, nested; rejection differs in that the sub-step size adapts
//! within the interval (halve on failure, double back after successes) and
//! that giving up reports the floor reached and the last Newton failure.

#[cfg(doc)]
use crate::driver::FailurePolicy;

/// How far a step may be cut down and when it grows back.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RejectionPolicy {
    /// Largest number of successive halvings of the nominal step
    /// (the relative floor is `|h|·2^−max_halvings`; at most
    /// [`MAX_HALVINGS`](crate::MAX_HALVINGS)).
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
    /// The smallest sub-step magnitude allowed for nominal step `h`.
    pub fn floor(&self, h: f64) -> f64 {
        (h.abs() * 0.5f64.powi(self.max_halvings as i32)).max(self.min_step)
    }
}
