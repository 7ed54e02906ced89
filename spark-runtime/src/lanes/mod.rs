//! Ensembles of one system, one method and one step size: `W` members
//! advanced in lock-step by a [`LaneStepper`] (`stepper`), and whole
//! ensembles spread over lane groups and cores ([`integrate_ensemble`],
//! `ensemble`).
//!
//! # What a lane is
//! Every member (lane) is a full [`Stepper`](struct@crate::Stepper) of its
//! own: its warm start, energy anchor, round-off compensation and Newton
//! history belong to it alone, and [`LaneStepper::advance`] takes one step of
//! every running lane from its own state. So each member's trajectory is
//! bit for bit the one its stepper computes alone — the same operations in
//! the same order, whatever the other lanes do — and a member that fails
//! (divergence, an inconsistent start, energy drift) stops with its own
//! [`StepError`](crate::StepError) while the others go on.
//!
//! # Why the lanes step scalar code
//! A profile of one step of the McLachlan–Perlmutter particles (`n = 7`,
//! `m = 1`, Lobatto IIIA-B `s = 2`, `h = 0.05`, simplified Newton on the
//! stage-decoupled matrix, 3.5 iterations per step; `perf record` on a
//! release build, shared machine) puts the system's own code
//! (`stage_values`, the energy) at ≈ 6 % of a step, the stage-decoupled
//! solve at ≈ 25 %, its factorization at ≈ 10 %, copies of fixed-size
//! values at ≈ 10 % and the rest — the starting guess, the residual and the
//! Newton bookkeeping, inlined into the step — at ≈ 45 %. Advancing four
//! members per AVX2 instruction therefore needs every one of those parts
//! in structure-of-arrays form, including the Newton loop's decisions
//! (convergence, refreshes, the fall-back to the exact matrix) replayed
//! per lane with masks; a vectorized linear algebra alone bounds the gain
//! at ≈ 1.4× (Amdahl on the 35 % it covers). The lock-step structure here
//! is the place such a stepper goes: [`LaneStepper::advance`] is the one
//! function that would change, and the tests in this module compare every
//! lane with its member stepped alone, bit for bit.
//!
//! Stepped scalar, lanes neither gain nor lose on one core: eight members
//! of those particles in lanes took 0.85× and 1.06× of the time of the same
//! members stepped one after another in two runs of
//! `cargo bench -p spark-runtime --bench lanes` on a loaded machine (the
//! difference is noise).
//!
//! Throughput across cores comes from [`integrate_ensemble`], which runs
//! lane groups in parallel (rayon).

mod ensemble;
mod kernel;
mod lane_lu;
mod stepper;
#[cfg(test)]
mod tests;

pub use ensemble::{integrate_ensemble, EnsembleRun};
pub use stepper::{LaneError, LaneFailure, LaneStatus, LaneStepper, LANES};
