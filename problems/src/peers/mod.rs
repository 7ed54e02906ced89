//! Alternative derivative providers and solvers that the SPARK stepper's
//! generated code is measured against (see `docs/performance/README.md`).
//!
//! - [`dual`]: the same stepper with every derivative from runtime
//!   forward-mode automatic differentiation (`num-dual`), from a Lagrangian
//!   and constraints written once as generic functions;
//! - [`finite_difference`]: the same stepper with stage Jacobians from
//!   central differences of the generated stage values;
//! - [`ode`]: the ψ-eliminated ODE (paper eq. 2.3) as a first-order system,
//!   integrated with the `ode_solvers` crate's DOP853.

pub mod dual;
pub mod finite_difference;
pub mod ode;
