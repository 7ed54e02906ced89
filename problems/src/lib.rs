//! The paper's systems and the `spark` command-line program, in wings that
//! follow the pipeline. Each wing imports only the wings listed before it:
//!
//! - [`systems`]: every `nonholonomic_system!` declaration (the inputs);
//! - [`catalog`]: the one list of systems `spark` offers and the one
//!   run-time dispatch from `(system, s)` to the monomorphized stepper;
//! - [`children`]: child processes (the Python peers) that end with the
//!   program, also on a signal (it imports no other wing);
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
//!
//! The crate feature `full` (on by default) compiles the whole catalogue,
//! the peers, the CasADi export and the experiments beyond the paper. Without
//! it (`--no-default-features`) the crate holds the paper's systems,
//! `spark list`, `spark run` and `spark paper`, and builds in a fraction of
//! the time: every catalogue system is monomorphized for every stage count
//! and the experiments it runs (the per-step table, Poincaré sections and
//! reversible sweeps only for the systems the catalogue and their setups
//! name), and that is nearly all of the crate's build.

pub mod systems;

pub mod catalog;

pub mod children;

pub mod report;

pub mod run;

#[cfg(feature = "full")]
pub mod crosscheck;
#[cfg(feature = "full")]
pub mod peers;

pub mod experiments;

pub mod cli;
