//! Robustness cases: steps too large for Newton (with and without the
//! rejection policy, [`large_steps`]), a stiff spring on the skate
//! ([`stiff_spring`]), nearly parallel constraint rows ([`near_singular`]),
//! a non-reversible oscillator ([`non_reversible`]), and bad input
//! ([`bad_input`]); the failure kinds they report are named here.

mod bad_input;
mod large_steps;
mod near_singular;
mod non_reversible;
mod stiff;

pub use bad_input::bad_input;
pub use large_steps::large_steps;
pub use near_singular::{near_singular, saddle_condition, CONDITION_WARNING};
pub use non_reversible::non_reversible;
pub use stiff::{stiff_spring, stiff_step_radius};

use spark_runtime::{IntegrationError, StepError};

/// A short name of a step failure's kind.
pub fn step_error_kind(e: &StepError) -> &'static str {
    match e {
        StepError::InvalidStep { .. } => "InvalidStep",
        StepError::Diverged { .. } => "Diverged",
        StepError::MaxIterations { .. } => "MaxIterations",
        StepError::SingularMatrix { .. } => "SingularMatrix",
        StepError::NonFinite { .. } => "NonFinite",
        StepError::EnergyDrift { .. } => "EnergyDrift",
        StepError::InconsistentInitialState { .. } => "InconsistentInitialState",
        StepError::InvalidOption(_) => "InvalidOption",
        StepError::InconsistentStart { .. } => "InconsistentStart",
        StepError::DependentConstraints { .. } => "DependentConstraints",
        StepError::NonFiniteInitialValue { .. } => "NonFiniteInitialValue",
        StepError::SingularInitialState { .. } => "SingularInitialState",
    }
}

/// The kind of a driver failure (`Step/<kind>`, `Floor/<kind>`, `SubstepBudget/<kind>`, `Initial/<kind>`,
/// `InvalidSchedule`, `InvalidOption`, `TooManyEvents`, `Stopped`).
pub fn integration_error_kind(e: &IntegrationError) -> String {
    match e {
        IntegrationError::InvalidSchedule(_) => "InvalidSchedule".into(),
        IntegrationError::InvalidOption(_) => "InvalidOption".into(),
        IntegrationError::Initial(s) => format!("Initial/{}", step_error_kind(s)),
        IntegrationError::Step { source, .. } => format!("Step/{}", step_error_kind(source)),
        IntegrationError::Floor { detail, .. } => format!("Floor/{}", step_error_kind(&detail.last)),
        IntegrationError::SubstepBudget { detail, .. } => format!("SubstepBudget/{}", step_error_kind(&detail.last)),
        IntegrationError::TooManyEvents { .. } => "TooManyEvents".into(),
        IntegrationError::Stopped { .. } => "Stopped".into(),
    }
}

/// Newton failures a smaller step may cure.
fn is_newton_failure(e: &IntegrationError) -> bool {
    matches!(
        e,
        IntegrationError::Step {
            source: StepError::Diverged { .. }
                | StepError::MaxIterations { .. }
                | StepError::SingularMatrix { .. }
                | StepError::NonFinite { .. },
            ..
        }
    )
}

/// The index and time of the step a driver failure names.
fn failed_index(e: &IntegrationError) -> String {
    match e {
        IntegrationError::Step { index, t, .. }
        | IntegrationError::Floor { index, t, .. }
        | IntegrationError::SubstepBudget { index, t, .. } => {
            format!("{index} (t = {t})")
        }
        _ => "—".into(),
    }
}
