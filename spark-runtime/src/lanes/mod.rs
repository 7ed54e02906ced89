//! Ensembles of one system, one method and one step size: `W` members
//! advanced together by a [`LaneStepper`] (`stepper`), whose
//! structure-of-arrays kernel (`kernel`, `lane_lu`) computes one Newton
//! iteration of every lane per pass, and whole ensembles spread over lane
//! groups and cores ([`integrate_ensemble`], `ensemble`).
//!
//! # What a lane computes
//! Every member (lane) has a full [`Stepper`](struct@crate::Stepper) of its
//! own: its warm start, energy anchor, round-off compensation and Newton
//! options belong to it alone. Where a member's next step takes the path
//! the kernel repeats — simplified Newton on the stage-decoupled matrix of
//! a system with a constant mass matrix (and, for a constant stiffness, a
//! diagonal one, whose stage couplings the kernel keeps coordinate by
//! coordinate as the steppers do), warm-started by extrapolation, the
//! path of every step but the first two of an ensemble like Fig. 8.4's —
//! the kernel takes it, with the same operations in the same order; any
//! other step, and any step in which the stepper would decide something
//! the kernel does not repeat (a slow contraction, a singular matrix, a
//! failure), the member's own stepper computes from the same continuation.
//! So each member's trajectory is bit for bit the one its stepper computes
//! alone, whatever the other lanes do. A step that fails is retried from
//! the cold guess and halved as `Stepper::integrate` does, by the member's
//! own stepper ([`LaneRecovery`] counts it); a member that fails even so
//! stops with its own [`StepError`](crate::StepError) while the others go
//! on. The
//! tests in this module compare every lane with its member stepped alone,
//! bit for bit, including steps the kernel hands back.
//!
//! # What it costs
//! The kernel's rows of `W` lanes vectorize (it is compiled for AVX-512 or
//! AVX2 where the CPU has it), and so do the system's stage values where
//! `nonholonomic_system!` generates them in lane form
//! ([`NonholonomicSystem::stage_values_in_lanes`](crate::NonholonomicSystem::stage_values_in_lanes),
//! `values`); a hand-written system's run lane by lane. Eight
//! McLachlan–Perlmutter members (`n = 7`, Lobatto IIIA-B `s = 2`,
//! `h = 0.05`, the settings of Fig. 8.4) step several times faster in
//! one group of eight lanes than one after another on one core
//! (`cargo bench -p spark-benches --bench lanes`; the figures are in
//! `docs/performance/README.md`). A kernel step costs the same
//! however many of its lanes hold a member, so a [`LaneStepper`] started
//! with half its lanes or fewer steps its members each alone
//! ([`LaneStepper::start`]).
//!
//! Throughput across cores comes from [`integrate_ensemble`], which runs
//! lane groups in parallel (rayon).

mod ensemble;
mod kernel;
mod lane_lu;
mod stepper;
#[cfg(test)]
mod tests;
pub(crate) mod values;

pub use ensemble::{integrate_ensemble, integrate_ensemble_until, EnsembleRun, MAX_ENSEMBLE_THREADS};
pub use stepper::{LaneError, LaneFailure, LaneRecovery, LaneStatus, LaneStepper, LANES};
pub use values::{LaneConstraintJacobians, LaneStageValues};
