//! SPARK integrators for nonholonomic Lagrangian systems.
#![warn(missing_docs)]

mod error;
pub mod reference;
pub mod system;

pub use error::SystemError;
pub use spark_macros::nonholonomic_system;
pub use system::{
    ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemSource,
    TimeDerivatives, Vector,
};

#[doc(hidden)]
pub mod __private {
    //! Re-exports for generated code; not a public API.
    pub use nalgebra;
}
