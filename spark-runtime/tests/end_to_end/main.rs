//! Whole runs through the public API on systems declared with
//! `nonholonomic_system!` in this binary or in `spark_runtime::fixtures`:
//! systems a new user writes, the convergence orders of every method family,
//! the paper's experiments, and the errors a step meets at its start. The tests that need the catalogue of `problems`
//! live in the workspace's `tests/` crate.

mod newcomer_systems;
mod orders;
mod paper;
mod step_start;
