//! What the driver does when a step's Newton iteration fails: the halving
//! of [`FailurePolicy::Halve`](super::FailurePolicy::Halve) and the
//! rejection with an adapted sub-step of
//! [`FailurePolicy::Reject`](super::FailurePolicy::Reject), both within
//! [`RunOptions::max_substeps`](super::RunOptions::max_substeps) sub-steps
//! per scheduled step.

use super::*;
use crate::error::StepError;
use crate::rejection::RejectionPolicy;
use crate::step::{State, StepResult, Stepper};
use crate::system::NonholonomicSystem;

/// Why one scheduled step failed (see `Stepper::robust_step` and
/// `Stepper::rejecting_step`).
pub(crate) enum StepFailure {
    /// A failure no smaller step cures, or the last one once halving stops.
    Step(StepError),
    /// Rejections reached the floor of the [`RejectionPolicy`].
    Floor {
        /// Where the failing sub-step starts.
        substep_t: f64,
        /// The last sub-step size tried.
        h_tried: f64,
        /// The floor.
        floor: f64,
        /// Rejections within the step.
        rejections: usize,
        /// The last Newton failure.
        last: StepError,
    },
    /// Covering the step would take more than the sub-step budget.
    Budget {
        /// The budget.
        budget: usize,
        /// Sub-steps accepted.
        substeps: usize,
        /// Where the recovery stopped.
        substep_t: f64,
        /// The smallest accepted sub-step.
        smallest: f64,
        /// The last Newton failure.
        last: StepError,
    },
}

/// The limits of a recovery under [`FailurePolicy::Halve`](super::FailurePolicy::Halve).
#[derive(Clone, Copy)]
pub(super) struct Budget {
    /// [`RunOptions::max_halvings`](super::RunOptions::max_halvings).
    pub(super) max_halvings: u32,
    /// [`RunOptions::max_substeps`](super::RunOptions::max_substeps).
    pub(super) max_substeps: usize,
}

impl StepFailure {
    /// The budget ran out at `counts` with `last` the latest failure.
    fn budget<const N: usize>(budget: usize, counts: &StepCounts<N>, last: StepError) -> Self {
        StepFailure::Budget {
            budget,
            substeps: counts.substeps,
            substep_t: counts.state.t,
            smallest: counts.smallest,
            last,
        }
    }

    /// The run error of step `index` of size `h` from `t`.
    pub(super) fn into_error(self, index: usize, t: f64, h: f64, partial: RunReport) -> IntegrationError {
        let partial = Box::new(partial);
        match self {
            StepFailure::Step(source) => IntegrationError::Step { index, t, source, partial },
            StepFailure::Floor { substep_t, h_tried, floor, rejections, last } => IntegrationError::Floor {
                index,
                t,
                detail: Box::new(RejectionFloor { h, substep_t, h_tried, floor, rejections, last }),
                partial,
            },
            StepFailure::Budget { budget, substeps, substep_t, smallest, last } => IntegrationError::SubstepBudget {
                index,
                t,
                detail: Box::new(SubstepOverrun { h, budget, substeps, substep_t, smallest, last }),
                partial,
            },
        }
    }
}

/// The outcome of one scheduled step (see `Stepper::robust_step`).
pub(crate) struct StepCounts<const N: usize> {
    /// The state at the end of the step (its time not yet pinned).
    pub(crate) state: State<N>,
    /// Newton iterations over the accepted (sub-)steps.
    pub(crate) iterations: usize,
    /// Failures each followed by smaller sub-steps.
    pub(crate) rejected: usize,
    /// Accepted sub-steps.
    pub(crate) substeps: usize,
    /// Smallest magnitude of an accepted sub-step (0 before the first).
    pub(crate) smallest: f64,
    /// Retries from the cold guess.
    pub(crate) cold_retries: usize,
    /// The per-sub-step callback asked to stop (a terminal event).
    pub(crate) stopped: bool,
    /// The first attempt started from the previous step's solutions (the
    /// stepper continued into the step's start).
    pub(crate) warm: bool,
}

impl<const N: usize> StepCounts<N> {
    /// Nothing taken yet from `state`.
    pub(crate) fn start(state: &State<N>) -> Self {
        StepCounts {
            state: *state,
            iterations: 0,
            rejected: 0,
            substeps: 0,
            smallest: 0.0,
            cold_retries: 0,
            stopped: false,
            warm: false,
        }
    }

    /// Counts an accepted sub-step of size `h` ending at `end`.
    fn accept(&mut self, end: State<N>, iterations: usize, h: f64) {
        self.state = end;
        self.iterations += iterations;
        self.substeps += 1;
        if self.smallest == 0.0 || h.abs() < self.smallest {
            self.smallest = h.abs();
        }
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// One step of size `h` from `state`. A warm-started attempt that fails
    /// is retried once from the cold guess; a sub-step that still fails is
    /// replaced by two half steps, at most `budget.max_halvings` levels
    /// deep, only while half of it still changes `t` and while the
    /// sub-steps taken and pending stay within `budget.max_substeps`.
    ///
    /// `on_step(system, start, end_t, h, result)` sees every accepted
    /// sub-step, `end_t` the time of its end (the last one's pinned to
    /// `t_target`); when it returns `true` the step stops there.
    ///
    /// A step that succeeds at once costs one call of [`Stepper::step`] and
    /// nothing more: the retry and the halving are set up only after a
    /// failure, in `recover`.
    pub(super) fn robust_step<F>(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        budget: Budget,
        on_step: &mut F,
    ) -> Result<StepCounts<N>, StepFailure>
    where
        F: FnMut(&Sys, &State<N>, f64, f64, &StepResult<N, M, S>) -> bool,
    {
        // Borrowed where accepted: the step's result is not moved out of
        // the `Result` (a copy of every stage value) on the common path.
        match self.step_or_fail(state, h) {
            Ok(ref r) => {
                let stopped = on_step(self.system(), state, t_target, h, r);
                Ok(StepCounts {
                    state: r.state,
                    iterations: r.iterations,
                    rejected: 0,
                    substeps: 1,
                    smallest: h.abs(),
                    cold_retries: 0,
                    stopped,
                    warm: r.warm_started,
                })
            }
            // A failed step leaves what it continued in place, so whether
            // the attempt was warm is still known after it.
            Err(first) => {
                let warm = self.is_warm_for(state);
                self.recover(state, h, t_target, budget, warm, first, on_step)
            }
        }
    }

    /// One scheduled step of size `h` ending at `t_target`, as
    /// [`Stepper::integrate`] takes it under [`RunOptions`] with
    /// `max_halvings` and otherwise the defaults (`FailurePolicy::Halve`,
    /// nothing observed): the lane stepper's step of a member, so that an
    /// ensemble member recovers where its solo run does. Returns the step's
    /// counts (the end's time not pinned); a failure gives the error of the
    /// last attempt (where the sub-step budget ran out, `integrate`'s
    /// error says so instead).
    pub(crate) fn scheduled_step(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        max_halvings: u32,
    ) -> Result<StepCounts<N>, StepError> {
        let budget = Budget { max_halvings, max_substeps: DEFAULT_MAX_SUBSTEPS };
        match self.robust_step(state, h, t_target, budget, &mut |_, _, _, _, _| false) {
            Ok(counts) => Ok(counts),
            Err(StepFailure::Step(last) | StepFailure::Floor { last, .. } | StepFailure::Budget { last, .. }) => {
                Err(last)
            }
        }
    }

    /// The rest of [`robust_step`](Self::robust_step) after its first
    /// attempt failed with `first`: the cold retry, then the halving.
    /// Iterative, with the pending sub-steps in a fixed array: no
    /// recursion, no heap.
    #[cold]
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn recover<F>(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        budget: Budget,
        warm: bool,
        first: StepError,
        on_step: &mut F,
    ) -> Result<StepCounts<N>, StepFailure>
    where
        F: FnMut(&Sys, &State<N>, f64, f64, &StepResult<N, M, S>) -> bool,
    {
        let max_halvings = budget.max_halvings.min(MAX_HALVINGS);
        // Sub-steps still to take, the next one last, with their halving
        // level. A failure replaces its entry by its two halves one level
        // deeper, so the levels increase strictly up the array but for a
        // pair at the top: `MAX_HALVINGS + 1` entries suffice.
        let mut pending = [(0.0f64, 0u32); MAX_HALVINGS as usize + 1];
        pending[0] = (h, 0);
        let mut len = 1;
        let mut out = StepCounts { warm, ..StepCounts::start(state) };
        // The outcome of the whole step's attempt, already taken once.
        let mut taken = Some((warm, first));
        while len > 0 {
            let (sub, level) = pending[len - 1];
            let (warm, attempt) = match taken.take() {
                Some((warm, first)) => (warm, Err(first)),
                None => (self.is_warm_for(&out.state), self.step_or_fail(&out.state, sub)),
            };
            let result = match attempt {
                Err(e) if warm && e.is_curable() => {
                    out.cold_retries += 1;
                    self.reset_warm_start();
                    self.step_or_fail(&out.state, sub)
                }
                other => other,
            };
            match result {
                Ok(r) => {
                    len -= 1;
                    let end_t = if len == 0 { t_target } else { r.state.t };
                    let stop = on_step(self.system(), &out.state, end_t, sub, &r);
                    out.accept(r.state, r.iterations, sub);
                    if stop {
                        out.stopped = true;
                        return Ok(out);
                    }
                }
                Err(e) if !e.is_curable() || level >= max_halvings => return Err(StepFailure::Step(e)),
                Err(e) => {
                    let half = 0.5 * sub;
                    if out.state.t + half == out.state.t {
                        return Err(StepFailure::Step(e));
                    }
                    // Every pending entry, the two halves among them, is
                    // at least one more sub-step.
                    if out.substeps.saturating_add(len + 1) > budget.max_substeps {
                        return Err(StepFailure::budget(budget.max_substeps, &out, e));
                    }
                    out.rejected += 1;
                    self.reset_warm_start();
                    pending[len - 1] = (sub - half, level + 1);
                    pending[len] = (half, level + 1);
                    len += 1;
                }
            }
        }
        Ok(out)
    }

    /// One step of size `h` from `state` under [`FailurePolicy::Reject`]:
    /// tries `h`; on a Newton failure covers `[t₀, t₀ + h]` with sub-steps
    /// that halve after each failure (the halved one started cold) and
    /// double back after `regrow_after` accepted ones, never below
    /// [`RejectionPolicy::floor`] and in at most `max_substeps` sub-steps.
    /// `on_step` as in `robust_step`.
    pub(super) fn rejecting_step<F>(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        policy: &RejectionPolicy,
        max_substeps: usize,
        on_step: &mut F,
    ) -> Result<StepCounts<N>, StepFailure>
    where
        F: FnMut(&Sys, &State<N>, f64, f64, &StepResult<N, M, S>) -> bool,
    {
        let t_end = state.t + h;
        let floor = policy.floor(h);
        let mut out = StepCounts { warm: self.is_warm_for(state), ..StepCounts::start(state) };
        let mut sub = h;
        let mut successes = 0usize;
        let mut last_failure = None;
        // Sub-steps end within a few ulps of t_end; what is left below that
        // is rounding of the accumulated times, not a step to take.
        let slack = 8.0 * f64::EPSILON * t_end.abs().max(h.abs());
        loop {
            let remaining = t_end - out.state.t;
            if out.substeps > 0 && remaining * h.signum() <= slack {
                break;
            }
            // The step is not covered yet, so a failure has happened and
            // the rest needs at least one more sub-step.
            if out.substeps >= max_substeps {
                if let Some(e) = last_failure.take() {
                    return Err(StepFailure::budget(max_substeps, &out, e));
                }
            }
            let this = if sub.abs() >= remaining.abs() { remaining } else { sub };
            match self.step_or_fail(&out.state, this) {
                Ok(r) => {
                    let end_t = if (t_end - r.state.t) * h.signum() <= slack { t_target } else { r.state.t };
                    let stop = on_step(self.system(), &out.state, end_t, this, &r);
                    out.accept(r.state, r.iterations, this);
                    if stop {
                        out.stopped = true;
                        return Ok(out);
                    }
                    successes += 1;
                    if successes >= policy.regrow_after && sub.abs() < h.abs() {
                        sub = (2.0 * sub).clamp(-h.abs(), h.abs());
                        successes = 0;
                    }
                }
                Err(e) if !e.is_curable() => return Err(StepFailure::Step(e)),
                Err(e) => {
                    out.rejected += 1;
                    successes = 0;
                    self.reset_warm_start();
                    let next = 0.5 * this;
                    if next.abs() < floor {
                        return Err(StepFailure::Floor {
                            substep_t: out.state.t,
                            h_tried: this,
                            floor,
                            rejections: out.rejected,
                            last: e,
                        });
                    }
                    sub = next;
                    last_failure = Some(e);
                }
            }
        }
        Ok(out)
    }
}
