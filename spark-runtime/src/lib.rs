//! SPARK integrators for nonholonomic Lagrangian systems (L. O. Jay,
//! *Lagrange–d'Alembert SPARK integrators for nonholonomic Lagrangian
//! systems*): the system trait, the coefficient families, the stepper with
//! its Newton solver, initial-value handling and an integration driver.
//!
//! # Example
//! The nonholonomic particle of the paper's §8.1, written by hand
//! (`nonholonomic_system!` generates such implementations), integrated with
//! the 2-stage Gauss SPARK method:
//!
//! ```
//! use spark_runtime::{
//!     ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, RunOptions, Schedule, StageJacobians,
//!     StageValues, State, Structure, SystemError, SystemSource, Tableau, TimeDerivatives, Vector, Method,
//!     NoObserver,
//! };
//!
//! /// L = ½|v|² − q₁² − q₂², constraint v₃ − q₂ v₁ = 0.
//! struct Particle;
//! impl Particle {
//!     pub const N: usize = 3;
//!     pub const M: usize = 1;
//! }
//! type V3 = Vector<3>;
//! impl NonholonomicSystem<3, 1> for Particle {
//!     const STRUCTURE: Structure = Structure {
//!         lagrangian_autonomous: true,
//!         constraints_autonomous: true,
//!         constant_mass_matrix: true,
//!         separable: true,
//!         constraint_form: ConstraintForm::Linear,
//!     };
//!     const SOURCE: SystemSource = SystemSource {
//!         name: "Particle",
//!         coordinates: &["x", "y", "z"],
//!         parameters: &[],
//!         lagrangian: "(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2) (^ (v z) 2))) (+ (^ (q x) 2) (^ (q y) 2)))",
//!         constraints: &["(- (v z) (* (q y) (v x)))"],
//!     };
//!     const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };
//!     fn parameter_values(&self) -> Vec<f64> { vec![] }
//!     fn set_parameter(&mut self, name: &str, _: f64) -> Result<(), SystemError> {
//!         Err(SystemError::UnknownParameter { name: name.into(), known: String::new() })
//!     }
//!     fn lagrangian(&self, _: f64, q: &V3, v: &V3) -> f64 { 0.5 * v.norm_squared() - q[0] * q[0] - q[1] * q[1] }
//!     fn energy(&self, _: f64, q: &V3, v: &V3) -> f64 { 0.5 * v.norm_squared() + q[0] * q[0] + q[1] * q[1] }
//!     fn momentum(&self, _: f64, _: &V3, v: &V3) -> V3 { *v }
//!     fn force(&self, _: f64, q: &V3, _: &V3) -> V3 { V3::new(-2.0 * q[0], -2.0 * q[1], 0.0) }
//!     fn mass_matrix(&self, _: f64, _: &V3, _: &V3) -> Matrix<3, 3> { Matrix::identity() }
//!     fn constraint(&self, _: f64, q: &V3, v: &V3) -> Vector<1> { Vector::<1>::new(v[2] - q[1] * v[0]) }
//!     fn constraint_q(&self, _: f64, _: &V3, v: &V3) -> Matrix<1, 3> { Matrix::<1, 3>::new(0.0, -v[0], 0.0) }
//!     fn constraint_v(&self, _: f64, q: &V3, _: &V3) -> Matrix<1, 3> { Matrix::<1, 3>::new(-q[1], 0.0, 1.0) }
//!     fn time_derivatives(&self, _: f64, _: &V3, _: &V3) -> TimeDerivatives<3, 1> {
//!         TimeDerivatives { lagrangian_t: 0.0, momentum_t: V3::zeros(), force_t: V3::zeros(), constraint_t: Vector::zeros() }
//!     }
//!     fn stage_values(&self, t: f64, q: &V3, v: &V3, psi: &Vector<1>) -> StageValues<3, 1> {
//!         StageValues {
//!             momentum: *v,
//!             force: self.force(t, q, v),
//!             constraint: self.constraint(t, q, v),
//!             constraint_force: -(self.constraint_v(t, q, v).transpose() * psi),
//!         }
//!     }
//!     fn stage_jacobians(&self, t: f64, q: &V3, v: &V3, psi: &Vector<1>) -> (StageValues<3, 1>, StageJacobians<3, 1>) {
//!         let mut rq = Matrix::<3, 3>::zeros();
//!         rq[(0, 1)] = psi[0]; // R = −Kᵀψ = (q₂ψ, 0, −ψ)
//!         let jac = StageJacobians {
//!             momentum_q: Matrix::zeros(),
//!             mass: Matrix::identity(),
//!             force_q: Matrix::from_diagonal(&V3::new(-2.0, -2.0, 0.0)),
//!             force_v: Matrix::zeros(),
//!             constraint_q: self.constraint_q(t, q, v),
//!             constraint_v: self.constraint_v(t, q, v),
//!             constraint_force_q: rq,
//!             constraint_force_v: Matrix::zeros(),
//!         };
//!         (self.stage_values(t, q, v, psi), jac)
//!     }
//! }
//!
//! // `Stepper![Particle, 2]` is `Stepper<Particle, 3, 1, 2, 11>`: D = 2·(3+1)+3.
//! let mut stepper: spark_runtime::Stepper![Particle, 2] =
//!     spark_runtime::Stepper::new(Particle, Tableau::new(Method::Gauss).unwrap());
//! let (q0, v0) = (V3::new(1.0, 0.0, 0.0), V3::new(0.0, 1.0, 0.0));
//! let traj = stepper
//!     .integrate(0.0, &q0, &v0, Schedule::Fixed { h: 0.2, steps: 50 }, &RunOptions::default(), &mut NoObserver)
//!     .unwrap();
//! assert!(traj.report.max_constraint_residual <= 1e-14);
//! assert!(traj.report.max_energy_error < 1e-3);
//! // One step by hand:
//! let step = stepper.step(&State::new(0.0, q0, v0), 0.2).unwrap();
//! assert!((step.state.v[2] - step.state.q[1] * step.state.v[0]).abs() < 1e-15);
//! ```
#![warn(missing_docs)]

mod driver;
mod error;
pub mod handwritten;
mod initial;
mod linalg;
pub mod reference;
pub mod rejection;
mod stepper;
pub mod system;
pub mod tableau;
#[cfg(test)]
mod tests;

pub use driver::{
    IntegrationError, NoObserver, Observe, Observer, RunOptions, RunReport, Sample, Schedule, Trajectory,
};
pub use error::{IterationRecord, NewtonHistory, StepError, SystemError, HISTORY_CAPACITY};
pub use initial::{consistent_acceleration, consistent_velocity, ConsistencyPolicy};
pub use rejection::{
    integrate_with_rejection, step_with_rejection, ProtectedStep, RejectionError, RejectionPolicy, RejectionReport,
    RejectionRunError,
};
pub use spark_macros::nonholonomic_system;
pub use stepper::{NewtonMode, NewtonOptions, State, StepResult, Stepper};
pub use system::{
    ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemSource,
    TimeDerivatives, Vector,
};
pub use tableau::{CoefficientFamily, ConditionRows, Method, Tableau, TableauError, MAX_STAGES};

/// Names the [`Stepper`](struct@crate::Stepper) type of system `Sys` with `s` stages, computing the
/// Newton dimension `D = s(N+M)+N` from the inherent constants `Sys::N` and
/// `Sys::M` (which `nonholonomic_system!` emits; hand-written systems add
/// `impl Sys { pub const N: usize = …; pub const M: usize = …; }`).
///
/// ```ignore
/// let stepper: spark_runtime::Stepper![Skate, 3] = Stepper::new(skate, Tableau::new(Method::Gauss)?);
/// ```
#[macro_export]
macro_rules! Stepper {
    [$sys:ty, $s:expr $(,)?] => {
        $crate::Stepper<
            $sys,
            { <$sys>::N },
            { <$sys>::M },
            { $s },
            { ($s) * (<$sys>::N + <$sys>::M) + <$sys>::N },
        >
    };
}

#[doc(hidden)]
pub mod __private {
    //! Re-exports for generated code; not a public API.
    pub use nalgebra;
}
