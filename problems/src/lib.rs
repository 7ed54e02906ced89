//! The paper's systems and the `spark` command-line program, in wings that
//! follow the pipeline. Each wing imports only the wings listed before it:
//!
//! - [`systems`]: every `nonholonomic_system!` declaration (the inputs);
//! - [`catalog`]: the one list of systems `spark` offers and the one
//!   run-time dispatch from `(system, s)` to the monomorphized stepper;
//! - [`run`]: one integration run, [`run::RunSpec`] → [`run::RunResult`];
//! - [`peers`]: the derivative providers and solvers SPARK is measured
//!   against (num-dual, finite differences, DOP853);
//! - [`casadi_export`]: the CasADi cross-check export of every system;
//! - [`report`]: figures, output folders, statistics, number formats, the
//!   thread clock and progress bars;
//! - [`experiments`]: the paper's figures, Poincaré sections, the stress
//!   suite and the work-precision study;
//! - [`cli`]: the `spark` command line (`bin/spark.rs` parses and calls it).

pub mod systems;

pub mod catalog;

pub mod run;

pub mod casadi_export;
pub mod peers;

pub mod report;

pub mod experiments;

pub mod cli;

/// The scene declarations, at the path the catalogue records for them
/// (`crate::systems::scenes::RodPendulum` in `spark list`).
pub use systems::scenes;

/// The stress suite, at the path the integration tests (`tests/`) use.
pub use experiments::stress;

/// The generated scaling systems, at the path the integration tests
/// (`tests/`) use.
pub mod workprecision {
    pub use crate::systems::scaling as scaling_systems;
}
