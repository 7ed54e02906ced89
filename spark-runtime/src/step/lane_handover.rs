//! The handover between a [`Stepper`] and the structure-of-arrays kernel of
//! a lane group (`crate::lanes`): what links a stepper's next step to its
//! previous ones, taken out of the stepper and put back, so that the kernel
//! and the stepper can take turns on one member's steps.
//!
//! The kernel repeats, operation for operation, one path of
//! [`Stepper::step`]: simplified Newton on a fresh stage-decoupled matrix
//! with a constant mass matrix (the lean refresh), from an extrapolated
//! starting guess. [`Stepper::lane_kernel_ready`] says when the stepper's
//! next step takes that path up to its first decision the kernel does not
//! make (a slow rate, a singular matrix, a failure): the kernel then hands
//! the step back, and the stepper computes it from the same continuation.

use super::compensation::Compensation;
use super::guess::{Warm, PAST};
use super::{EnergyAnchor, Jacobian, NewtonMode, Stepper};
use crate::system::{NonholonomicSystem, Vector};
use crate::State;

/// What links a member's next step to its previous ones (see the module
/// docs): the state where the latest step ended, the round-off its `q`
/// carries, the energy guard's anchor and the solutions of the latest
/// steps of size `h`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LaneContinuation<const N: usize, const D: usize> {
    /// Where the latest step ended (its time pinned to the schedule).
    pub(crate) end: State<N>,
    /// The size of the latest steps.
    pub(crate) h: f64,
    /// `(q₀ + Δq) − q₁` of the latest step (compensated summation).
    pub(crate) carry: Vector<N>,
    /// The energy guard's anchor of the chain that ends at `end` (`None`
    /// with the guard off, before a check, or for a chain that ends
    /// elsewhere).
    pub(crate) anchor: Option<EnergyAnchor>,
    /// Solutions `z` of the latest `depth` steps, most recent first.
    pub(crate) past: [Vector<D>; PAST],
    /// How many of `past` hold solutions (at least 2 for the kernel).
    pub(crate) depth: usize,
    /// The largest ratio of consecutive updates the latest step earned on
    /// its final factors (NaN for none), and whether those were the
    /// stage-decoupled matrix's: the next step's prior (`Warm::rate`). A
    /// step handed back can end on the exact matrix, where the prior of an
    /// exact-matrix step is the floor, as in the member's stepper alone.
    pub(crate) rate: (f64, bool),
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// Whether the system's structure lets the lane kernel step it at all:
    /// a stage-decoupled matrix whose velocity blocks are one constant mass
    /// matrix (coupled by a constant stiffness only coordinate by
    /// coordinate, which the kernel checks when it is made), no external
    /// and no non-ideal force.
    pub(crate) const LANE_KERNEL: bool =
        Self::LEAN_DECOUPLED && Sys::STRUCTURE.constant_mass_matrix && !Sys::HAS_FORCING && !Sys::HAS_NONIDEAL_FORCE;

    /// Whether the next step from `state` with size `h` starts on the path
    /// the lane kernel repeats (see the module docs): simplified Newton on
    /// the stage-decoupled matrix, refreshed at every step (no reuse of an
    /// earlier step's factors), not waiting out a fall-back to the exact
    /// matrix, warm-started by extrapolation from at least two solutions of
    /// steps of size `h`, continuing the step that ended at `state`, with
    /// options already checked.
    pub(crate) fn lane_kernel_ready(&self, state: &State<N>, h: f64) -> bool {
        let o = &self.options;
        let decoupled = match o.jacobian {
            Jacobian::Exact => false,
            Jacobian::StageDecoupled => true,
            Jacobian::Auto => Self::DECOUPLES,
        };
        Self::LANE_KERNEL
            && self.options_checked
            && o.mode == NewtonMode::Simplified
            && decoupled
            && !o.reuse_factorization
            && !self.starts_stale(state, h, decoupled)
            && o.warm_start
            && self.exact_steps_left == 0
            && self.warm.as_ref().is_some_and(|w| w.h == h && w.depth >= 2)
            && self.continues(state)
    }

    /// The continuation of the step that ended at `state`, when
    /// [`Self::lane_kernel_ready`] holds for it.
    pub(crate) fn lane_continuation(&self, state: &State<N>, h: f64) -> Option<LaneContinuation<N, D>> {
        if !self.lane_kernel_ready(state, h) {
            return None;
        }
        let (w, c) = (self.warm.as_ref()?, self.compensation.as_ref()?);
        let past = std::array::from_fn(|k| if k < w.depth { *w.back(k) } else { Vector::zeros() });
        Some(LaneContinuation {
            end: *state,
            h,
            carry: c.carry,
            anchor: self.anchor,
            past,
            depth: w.depth,
            rate: w.rate,
        })
    }

    /// Takes over a continuation the lane kernel built: the next step from
    /// `c.end` computes exactly what it would had this stepper taken the
    /// kernel's steps itself.
    pub(crate) fn resume_lane(&mut self, c: &LaneContinuation<N, D>) {
        self.warm = Some(Warm { h: c.h, past: c.past, head: 0, depth: c.depth.min(PAST), rate: c.rate });
        self.compensation = Some(Compensation { end: c.end, carry: c.carry });
        self.anchor = c.anchor;
        self.reusable = None;
        self.exact_steps_left = 0;
    }
}
