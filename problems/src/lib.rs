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
//! - [`crosscheck`]: the CasADi cross-check export of every catalogue entry;
//! - [`experiments`]: the paper's figures, Poincaré sections, the stress
//!   suite and the work-precision study;
//! - [`cli`]: the `spark` command line (`bin/spark.rs` parses and calls it).

pub mod systems;

pub mod catalog;

pub mod report;

pub mod run;

pub mod crosscheck;
pub mod peers;

pub mod experiments;

pub mod cli;
