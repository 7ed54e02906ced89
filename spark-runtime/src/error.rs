//! Errors a user can act on.

/// Errors about a system's declaration or parameters.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SystemError {
    /// `set_parameter` was given a name the system does not declare.
    #[error("unknown parameter `{name}`; this system declares: {known}")]
    UnknownParameter {
        /// The name given.
        name: String,
        /// The declared parameters, comma-separated.
        known: String,
    },
    /// A parameter value is NaN or infinite.
    #[error("parameter `{name}` must be finite, got {value}")]
    NonFiniteParameter {
        /// The parameter.
        name: String,
        /// The value given.
        value: f64,
    },
}
