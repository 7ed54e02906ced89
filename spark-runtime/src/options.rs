//! Range checks of the user-facing options, run once before the steps that
//! use them (never per step): an out-of-range option is reported as an
//! [`OptionError`] naming it and its allowed range, not as a failure of the
//! initial state or of the discrete map that it would otherwise cause.

use crate::driver::{FailurePolicy, RunOptions, MAX_HALVINGS};
use crate::error::{OptionError, HISTORY_CAPACITY};
use crate::initial::ConsistencyPolicy;
use crate::rejection::RejectionPolicy;
use crate::step::{Jacobian, NewtonMode, NewtonOptions, MAX_EXTRAPOLATION_DEGREE};

impl NewtonOptions {
    /// Checks every field against its allowed range: `tolerance` in `[0, 1)`
    /// (it bounds the relative size of the last update, so 1 or more accepts
    /// an update with no correct digit), `stagnation_level` in `[0, 1)`
    /// (for the same reason: an update at or below it that no longer
    /// contracts ends the iteration as converged), `max_iterations` in
    /// `1..=HISTORY_CAPACITY`, `extrapolation_degree` in `1..=MAX_EXTRAPOLATION_DEGREE`,
    /// `energy_drift_limit` (when set) finite and positive, and no
    /// [`Jacobian::StageDecoupled`] with [`NewtonMode::Full`].
    pub fn validate(&self) -> Result<(), OptionError> {
        if !(self.tolerance >= 0.0 && self.tolerance < 1.0) {
            return Err(OptionError::float(
                "NewtonOptions::tolerance",
                self.tolerance,
                "in [0, 1): it bounds the last update relative to 1 + |z|, so 1 or more \
                 accepts an update with no correct digit (0 iterates to round-off stagnation)",
            ));
        }
        if !(self.stagnation_level >= 0.0 && self.stagnation_level < 1.0) {
            return Err(OptionError::float(
                "NewtonOptions::stagnation_level",
                self.stagnation_level,
                "in [0, 1): an iteration that stops contracting with an update at or below it ends as \
                 converged, so 1 or more accepts a diverging update with no correct digit",
            ));
        }
        if !(1..=HISTORY_CAPACITY).contains(&self.max_iterations) {
            return Err(OptionError::integer(
                "NewtonOptions::max_iterations",
                self.max_iterations as u64,
                "between 1 and HISTORY_CAPACITY = 32",
            ));
        }
        if !(1..=MAX_EXTRAPOLATION_DEGREE).contains(&self.extrapolation_degree) {
            return Err(OptionError::integer(
                "NewtonOptions::extrapolation_degree",
                self.extrapolation_degree as u64,
                "between 1 and MAX_EXTRAPOLATION_DEGREE = 5",
            ));
        }
        if self.consistency_tolerance.is_nan() || self.consistency_tolerance < 0.0 {
            return Err(OptionError::float(
                "NewtonOptions::consistency_tolerance",
                self.consistency_tolerance,
                "non-negative (not NaN; infinity accepts any starting state)",
            ));
        }
        if self.mode == NewtonMode::Full && self.jacobian == Jacobian::StageDecoupled {
            return Err(OptionError {
                option: "NewtonOptions::jacobian",
                value: "StageDecoupled".into(),
                allowed: "Exact or Auto with NewtonMode::Full (full Newton uses the exact Jacobian; \
                          choose NewtonMode::Simplified for the stage-decoupled matrix)",
            });
        }
        if let Some(limit) = self.energy_drift_limit {
            if !(limit.is_finite() && limit > 0.0) {
                return Err(OptionError::float(
                    "NewtonOptions::energy_drift_limit",
                    limit,
                    "finite and positive (None turns the energy guard off)",
                ));
            }
        }
        Ok(())
    }
}

impl ConsistencyPolicy {
    /// Checks the tolerance: non-negative and not NaN (`+∞` accepts any
    /// initial velocity).
    pub fn validate(&self) -> Result<(), OptionError> {
        let (option, tolerance) = match *self {
            ConsistencyPolicy::Error { tolerance } => ("ConsistencyPolicy::Error::tolerance", tolerance),
            ConsistencyPolicy::Project { tolerance } => ("ConsistencyPolicy::Project::tolerance", tolerance),
        };
        // NaN is refused too: every residual compares false against it.
        if tolerance.is_nan() || tolerance < 0.0 {
            return Err(OptionError::float(option, tolerance, "non-negative (not NaN)"));
        }
        Ok(())
    }
}

impl RunOptions {
    /// Checks the consistency policy, `max_halvings ≤ MAX_HALVINGS`,
    /// `max_substeps ≥ 1` and the [`RejectionPolicy`] of
    /// [`FailurePolicy::Reject`].
    pub fn validate(&self) -> Result<(), OptionError> {
        self.consistency.validate()?;
        if let FailurePolicy::Reject(policy) = self.on_failure {
            policy.validate()?;
        }
        if self.max_halvings > MAX_HALVINGS {
            return Err(OptionError::integer(
                "RunOptions::max_halvings",
                u64::from(self.max_halvings),
                "at most MAX_HALVINGS = 60",
            ));
        }
        if self.max_substeps == 0 {
            return Err(OptionError::integer("RunOptions::max_substeps", 0, "at least 1"));
        }
        Ok(())
    }
}

impl RejectionPolicy {
    /// Checks `min_step` (finite, non-negative), `max_halvings ≤ 60` and
    /// `regrow_after ≥ 1` ([`RunOptions::validate`] checks the policy of
    /// [`FailurePolicy::Reject`] with this).
    pub fn validate(&self) -> Result<(), OptionError> {
        if !(self.min_step.is_finite() && self.min_step >= 0.0) {
            return Err(OptionError::float("RejectionPolicy::min_step", self.min_step, "finite and non-negative"));
        }
        if self.max_halvings > MAX_HALVINGS {
            return Err(OptionError::integer(
                "RejectionPolicy::max_halvings",
                u64::from(self.max_halvings),
                "at most MAX_HALVINGS = 60",
            ));
        }
        if self.regrow_after == 0 {
            return Err(OptionError::integer("RejectionPolicy::regrow_after", 0, "at least 1"));
        }
        Ok(())
    }
}
