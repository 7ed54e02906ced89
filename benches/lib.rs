//! The criterion benchmarks of `spark-runtime` (`runtime/`: one step, the
//! Newton stopping rule, the LU kernels, the driver's cost, ensembles in
//! lanes) and of `problems` (`problems/`: the catalogue's systems against the
//! peers, scenes). Run one with `cargo bench -p spark-benches --bench NAME`.
//!
//! The library holds only what several benches share and criterion does
//! not touch ([`paper`]); the crate exists so that criterion is built for
//! `cargo bench` only, not by the test command.

#[path = "common/paper.rs"]
pub mod paper;
