//! The paper's systems and the `spark` command-line program, in wings that
//! follow the pipeline. Each wing imports only the wings listed before it:
//!
//! - [`systems`]: every `nonholonomic_system!` declaration (the inputs);
//! - [`catalog`]: the one list of systems `spark` offers and the one
//!   run-time dispatch from `(system, s)` to the monomorphized stepper;
//! - [`report`]: output folders, figures, statistics, number formats, the
//!   thread-CPU clock and progress bars (it imports no other wing);
//! - [`run`]: one integration run, [`run::RunSpec`] → [`run::RunResult`],
//!   and its files;
//! - [`peers`]: the derivative providers and solvers SPARK is measured
//!   against (num-dual, finite differences, DOP853);
//! - [`casadi_export`]: the CasADi cross-check export of every system;
//! - [`experiments`]: the paper's figures, Poincaré sections, the stress
//!   suite and the work-precision study;
//! - [`cli`]: the `spark` command line (`bin/spark.rs` parses and calls it).

pub mod systems;

pub mod catalog;

pub mod report;

pub mod run;

pub mod casadi_export;
pub mod peers;

pub mod experiments;

pub mod cli;

/// The scene declarations, at the path the catalogue records for them
/// (`crate::scenes::RodPendulum` in `spark list`).
pub use systems::scenes;

/// The stress suite, at the path the integration tests (`tests/`) use.
pub use experiments::stress;

/// The generated scaling systems, at the path the integration tests
/// (`tests/`) use.
pub mod workprecision {
    pub use crate::systems::scaling as scaling_systems;
}
