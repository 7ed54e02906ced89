//! Why a run failed: [`IntegrationError`] and the detail of a rejection
//! that reached its floor.

use super::RunReport;
use crate::error::{OptionError, Sci, StepError};

/// An integration run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum IntegrationError {
    /// The schedule is unusable.
    #[error("invalid schedule: {0}")]
    InvalidSchedule(&'static str),
    /// A run or Newton option is out of range (checked before any step).
    #[error("{0}")]
    InvalidOption(OptionError),
    /// The initial state was rejected or could not be projected.
    #[error("initial state: {0}")]
    Initial(#[source] StepError),
    /// A step failed (after any retries).
    #[error("step {index} from t = {} failed: {source}", Sci(*t))]
    Step {
        /// Index of the failed step (0-based).
        index: usize,
        /// Its start time.
        t: f64,
        /// Why.
        source: StepError,
        /// The trajectory up to the failure.
        partial: Box<RunReport>,
    },
    /// Under [`FailurePolicy::Reject`](crate::FailurePolicy::Reject), Newton kept failing down to the
    /// smallest sub-step allowed.
    #[error(
        "step {index} from t = {} (h = {}) still fails at t = {} with sub-step {} at the floor {} \
         after {} rejections; last failure: {}",
        Sci(*t),
        Sci(detail.h),
        Sci(detail.substep_t),
        Sci(detail.h_tried),
        Sci(detail.floor),
        detail.rejections,
        detail.last
    )]
    Floor {
        /// Index of the failed step (0-based).
        index: usize,
        /// Its start time.
        t: f64,
        /// Where and how the rejections ended.
        detail: Box<RejectionFloor>,
        /// The run statistics up to the failure.
        partial: Box<RunReport>,
    },
    /// Covering a failed step would take more than
    /// [`RunOptions::max_substeps`](super::RunOptions::max_substeps)
    /// sub-steps: the step size is far too large for the problem there, or
    /// the budget too small for the halving or rejection depth allowed.
    #[error(
        "step {index} from t = {} (h = {}) needs more than {} sub-steps to recover (raise \
         RunOptions::max_substeps or take smaller steps): {} accepted up to t = {}, the smallest {}; last failure: {}",
        Sci(*t),
        Sci(detail.h),
        detail.budget,
        detail.substeps,
        Sci(detail.substep_t),
        Sci(detail.smallest),
        detail.last
    )]
    SubstepBudget {
        /// Index of the failed step (0-based).
        index: usize,
        /// Its start time.
        t: f64,
        /// How far the recovery got.
        detail: Box<SubstepOverrun>,
        /// The run statistics up to the failure.
        partial: Box<RunReport>,
    },
    /// The run located more events than it keeps
    /// ([`RunOptions::max_events`](super::RunOptions::max_events)).
    #[error("{}", crate::events::too_many_events("RunOptions::max_events", *max_events, *t))]
    TooManyEvents {
        /// The most events the run keeps.
        max_events: usize,
        /// The start of the step in which one more was located.
        t: f64,
        /// The run statistics up to there.
        partial: Box<RunReport>,
    },
    /// The observer asked the run to stop
    /// ([`Observer::stop_requested`](super::Observer::stop_requested)).
    #[error("stopped by its observer after {steps} steps, at t = {}", Sci(*t))]
    Stopped {
        /// Steps accepted, the last one included.
        steps: usize,
        /// Where the last one ended.
        t: f64,
        /// The run statistics up to there.
        partial: Box<RunReport>,
    },
}

/// How a step under [`FailurePolicy::Reject`](crate::FailurePolicy::Reject) reached the floor.
#[derive(Clone, Debug, PartialEq)]
pub struct RejectionFloor {
    /// The step size.
    pub h: f64,
    /// Where the failing sub-step starts.
    pub substep_t: f64,
    /// The last sub-step size tried.
    pub h_tried: f64,
    /// The floor (see [`RejectionPolicy::floor`](crate::RejectionPolicy::floor)).
    pub floor: f64,
    /// Rejections within the step.
    pub rejections: usize,
    /// The last Newton failure.
    pub last: StepError,
}

/// How a recovering step ran out of [`RunOptions::max_substeps`](super::RunOptions::max_substeps).
#[derive(Clone, Debug, PartialEq)]
pub struct SubstepOverrun {
    /// The step size.
    pub h: f64,
    /// The budget.
    pub budget: usize,
    /// Sub-steps accepted within the step.
    pub substeps: usize,
    /// Where the recovery stopped.
    pub substep_t: f64,
    /// The smallest accepted sub-step (0 when none was accepted).
    pub smallest: f64,
    /// The last Newton failure.
    pub last: StepError,
}
