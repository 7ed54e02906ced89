//! The [`LaneStepper`]: `W` members of one ensemble (same system, method,
//! Newton options and step size) advanced in lock-step on fixed steps, with
//! a status per member.

use super::kernel::{Kernel, Outcome, Simd};
use crate::driver::{StepCounts, DEFAULT_MAX_HALVINGS, MAX_HALVINGS};
use crate::step::{NewtonOptions, State, Stepper};
use crate::system::NonholonomicSystem;
use crate::tableau::Tableau;
use crate::StepError;

/// Members per lane group of [`integrate_ensemble`](crate::integrate_ensemble):
/// one 512-bit (AVX-512) vector of `f64` per row, or two 256-bit (AVX2) ones
/// with two independent vectors in flight (eight lanes stepped 1.3× faster
/// per member than two groups of four in
/// `cargo bench -p spark-benches --bench lanes`).
pub const LANES: usize = 8;

/// Why a lane group cannot start.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LaneError {
    /// More members than lanes, or none.
    #[error("a lane group holds 1 to {lanes} members; got {members}")]
    MemberCount {
        /// Members asked for.
        members: usize,
        /// Lanes of the group.
        lanes: usize,
    },
    /// The members do not start at one time (they share the step times
    /// `t₀ + k·h`).
    #[error("member {member} starts at t = {t:.3e}, member 0 at t = {t0:.3e}; an ensemble shares its start time")]
    StartTimes {
        /// The member whose start time differs.
        member: usize,
        /// Its start time.
        t: f64,
        /// Member 0's start time.
        t0: f64,
    },
    /// The step size is one [`check_step_size`](crate::check_step_size)
    /// refuses: zero, not finite, subnormal, above
    /// [`MAX_STEP_SIZE`](crate::MAX_STEP_SIZE) or below the resolution of
    /// `t` at the start time.
    #[error("step size h = {h:.3e}: {reason}")]
    StepSize {
        /// The step size asked for.
        h: f64,
        /// What is wrong with it and what to use.
        reason: &'static str,
    },
    /// The caller asked the ensemble to stop
    /// ([`integrate_ensemble_until`](super::integrate_ensemble_until)).
    #[error("stopped by its caller after {steps} steps")]
    Stopped {
        /// Steps every running member of the group that saw the request had taken.
        steps: usize,
    },
}

/// How a member ended its steps: the step that failed and its error.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("step {step} from t = {t:.3e} failed: {error}")]
pub struct LaneFailure {
    /// Index of the failed step (0 = the first step from the start).
    pub step: usize,
    /// Time the failed step started from.
    pub t: f64,
    /// The stepper's error.
    pub error: StepError,
}

/// What recovering from failed steps cost a member: a step whose Newton
/// iteration fails is retried from the cold guess and halved as
/// [`Stepper::integrate`] does ([`LaneStepper::with_max_halvings`]), and
/// counted here as its run report counts it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LaneRecovery {
    /// Failures each followed by smaller sub-steps
    /// ([`RunReport::rejected_steps`](crate::RunReport::rejected_steps)).
    pub rejected_steps: usize,
    /// Steps with at least one such failure.
    pub steps_with_rejections: usize,
    /// Sub-steps beyond one per step: the halved steps' extra sub-steps.
    pub extra_substeps: usize,
    /// The smallest accepted sub-step's magnitude, 0 while no step was
    /// halved (every sub-step then has the step size).
    pub smallest_substep: f64,
}

impl LaneRecovery {
    /// Counts one step taken as `counts`.
    pub(crate) fn count<const N: usize>(&mut self, counts: &StepCounts<N>) {
        if counts.rejected > 0 {
            self.rejected_steps += counts.rejected;
            self.steps_with_rejections += 1;
            self.extra_substeps += counts.substeps.saturating_sub(1);
            if self.smallest_substep == 0.0 || counts.smallest < self.smallest_substep {
                self.smallest_substep = counts.smallest;
            }
        }
    }

    /// The smallest sub-step of a run with steps of size `h`.
    pub fn smallest_step(&self, h: f64) -> f64 {
        if self.smallest_substep == 0.0 {
            h.abs()
        } else {
            self.smallest_substep.min(h.abs())
        }
    }
}

/// What a lane is doing.
#[derive(Clone, Debug, PartialEq)]
pub enum LaneStatus {
    /// Holds no member (the group has fewer members than lanes).
    Empty,
    /// Steps on.
    Running,
    /// Stopped at a failed step; its state is where that step started.
    Failed(Box<LaneFailure>),
}

/// `W` members of an ensemble stepped in lock-step with one step size `h`:
/// [`Self::advance`] takes one step of every running member. Each lane is
/// a [`Stepper`] of its own (see the `lanes` module docs), so a member's
/// states are bit for bit those of its stepper alone, stepped from the
/// same start with `t` pinned to `t₀ + k·h` after every step as
/// [`Stepper::integrate`] pins it.
#[derive(Clone, Debug)]
pub struct LaneStepper<Sys, const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> {
    system: Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    lanes: [Stepper<Sys, N, M, S, D>; W],
    /// The structure-of-arrays kernel (see the module docs), made at the
    /// first lane it can take; `kernel_refused` once its mass matrix was
    /// found singular.
    kernel: Option<Box<Kernel<N, M, S, D, W>>>,
    kernel_refused: bool,
    /// The instruction set the kernel is compiled for.
    simd: Simd,
    /// Whether the lanes may use the kernel at all ([`Self::without_kernel`]).
    kernel_enabled: bool,
    /// Whether this run's lanes use it: more than half the lanes hold a
    /// member (see [`Self::start`]).
    kernel_for_run: bool,
    states: [State<N>; W],
    status: [LaneStatus; W],
    iterations: [usize; W],
    total_iterations: [usize; W],
    /// Steps each lane took in the kernel since [`Self::start`].
    kernel_steps: [usize; W],
    /// What each lane's failed steps cost since [`Self::start`].
    recovery: [LaneRecovery; W],
    /// Halving levels of a failed step ([`Self::with_max_halvings`]).
    max_halvings: u32,
    t0: f64,
    h: f64,
    steps: usize,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize, const W: usize>
    LaneStepper<Sys, N, M, S, D, W>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    /// `W` lanes stepping `system` with `tableau` and `options`, all empty.
    pub fn new(system: Sys, tableau: Tableau<S>, options: NewtonOptions) -> Self {
        const { assert!(W >= 1, "LaneStepper: W must be at least 1") };
        LaneStepper {
            lanes: std::array::from_fn(|_| Stepper::new(system.clone(), tableau).with_options(options)),
            system,
            tableau,
            options,
            kernel: None,
            kernel_refused: false,
            simd: Simd::detect(),
            kernel_enabled: true,
            kernel_for_run: false,
            states: [State::new(0.0, nalgebra::zero(), nalgebra::zero()); W],
            status: std::array::from_fn(|_| LaneStatus::Empty),
            iterations: [0; W],
            total_iterations: [0; W],
            kernel_steps: [0; W],
            recovery: [LaneRecovery::default(); W],
            max_halvings: DEFAULT_MAX_HALVINGS,
            t0: 0.0,
            h: 0.0,
            steps: 0,
        }
    }

    /// The kernel compiled for `simd` or the widest set below it that this
    /// CPU has (to test every build of the kernel on one machine).
    #[cfg(test)]
    pub(super) fn with_simd(mut self, simd: Simd) -> Self {
        self.simd = simd.min(Simd::detect());
        self
    }

    /// Every lane steps alone, by its own stepper, never in the kernel:
    /// the same states, at the cost of one member after another (for
    /// comparisons; [`Self::start`] already leaves the kernel out where it
    /// does not pay).
    pub fn without_kernel(mut self) -> Self {
        self.kernel_enabled = false;
        self
    }

    /// A failed step is halved at most `max_halvings` levels deep (at most
    /// [`MAX_HALVINGS`]; 0 ends a member at its first failed step), as
    /// [`RunOptions::max_halvings`](crate::RunOptions::max_halvings) does
    /// for `integrate`; default [`DEFAULT_MAX_HALVINGS`].
    pub fn with_max_halvings(mut self, max_halvings: u32) -> Self {
        self.max_halvings = max_halvings.min(MAX_HALVINGS);
        self
    }

    /// Loads the members `starts` (1 to `W`, one start time) for steps of
    /// size `h`; lanes beyond them stay empty. Every lane forgets its
    /// previous run, so the first step of each member starts cold and checks
    /// its state (an inconsistent one fails that member alone, with
    /// [`StepError::InconsistentStart`]). A member whose equations of motion
    /// are not finite at its start, or whose saddle matrix `[[W, Kᵀ],[K, 0]]`
    /// is singular there, fails alone before any step, with the error
    /// [`consistent_velocity`](crate::consistent_velocity) gives for it
    /// ([`StepError::NonFiniteInitialValue`],
    /// [`StepError::SingularInitialState`]). The kernel takes the members'
    /// steps only when they fill more than half the lanes: its step costs
    /// the same however few lanes hold a member.
    pub fn start(&mut self, starts: &[State<N>], h: f64) -> Result<(), LaneError> {
        if starts.is_empty() || starts.len() > W {
            return Err(LaneError::MemberCount { members: starts.len(), lanes: W });
        }
        let t0 = starts[0].t;
        // The step sizes `Stepper::integrate` refuses: zero, non-finite,
        // subnormal (where `1/h` overflows), too large for `h²`, or too
        // small to move `t0`.
        if let Err(reason) = crate::check_step_size(t0, h) {
            return Err(LaneError::StepSize { h, reason });
        }
        if let Some((member, s)) = starts.iter().enumerate().find(|(_, s)| s.t.to_bits() != t0.to_bits()) {
            return Err(LaneError::StartTimes { member, t: s.t, t0 });
        }
        (self.kernel, self.kernel_refused) = (None, false);
        // The kernel's step costs the same however few of its lanes hold a
        // member: half the lanes or fewer step faster each alone.
        self.kernel_for_run = self.kernel_enabled && starts.len() > W / 2;
        for (j, lane) in self.lanes.iter_mut().enumerate() {
            lane.reset_run();
            self.iterations[j] = 0;
            self.total_iterations[j] = 0;
            self.kernel_steps[j] = 0;
            self.recovery[j] = LaneRecovery::default();
            match starts.get(j) {
                Some(s) => {
                    self.states[j] = *s;
                    // What `Stepper::integrate` refuses up front (equations
                    // of motion not finite there, a singular saddle matrix)
                    // fails the member at its first step with the same error.
                    self.status[j] = match crate::initial::check_start(&self.system, s.t, &s.q, &s.v) {
                        Ok(()) => LaneStatus::Running,
                        Err(error) => LaneStatus::Failed(Box::new(LaneFailure { step: 0, t: s.t, error })),
                    };
                }
                None => self.status[j] = LaneStatus::Empty,
            }
        }
        (self.t0, self.h, self.steps) = (t0, h, 0);
        Ok(())
    }

    /// One step of size `h` of every running lane; a lane whose step fails
    /// stops there ([`LaneStatus::Failed`]) and the others go on. Returns
    /// how many lanes still run.
    pub fn advance(&mut self) -> usize {
        self.advance_by(1)
    }

    /// `k` steps of every running lane: the states are those of `k` calls
    /// of [`Self::advance`]. Returns how many lanes still run.
    pub fn advance_by(&mut self, k: usize) -> usize {
        for i in self.steps..self.steps + k {
            let t = self.t0 + i as f64 * self.h;
            let t_next = self.t0 + (i + 1) as f64 * self.h;
            let outcomes = match self.kernel.as_deref_mut() {
                Some(kernel) => kernel.step(&self.system, &self.tableau, &self.options, t, t_next),
                None => [Outcome::Idle; W],
            };
            for (j, outcome) in outcomes.into_iter().enumerate() {
                match outcome {
                    Outcome::Stepped(iterations) => {
                        self.kernel_steps[j] += 1;
                        self.iterations[j] = iterations;
                        self.total_iterations[j] += iterations;
                    }
                    Outcome::HandBack => {
                        if let Some(kernel) = self.kernel.as_deref_mut() {
                            let c = kernel.give(j, t);
                            self.lanes[j].resume_lane(&c);
                            self.states[j] = c.end;
                        }
                        self.step_alone(j, i);
                    }
                    Outcome::Idle => {
                        if matches!(self.status[j], LaneStatus::Running) {
                            self.step_alone(j, i);
                        }
                    }
                }
            }
        }
        self.steps += k;
        let t = self.t0 + self.steps as f64 * self.h;
        let mut running = 0;
        for j in 0..W {
            if let Some(kernel) = self.kernel.as_deref().filter(|kn| kn.holds(j)) {
                self.states[j] = kernel.state(j, t);
            }
            running += usize::from(matches!(self.status[j], LaneStatus::Running));
        }
        running
    }

    /// Step `i` of lane `j` by its own stepper; hands the lane to the
    /// kernel when its next step takes the kernel's path.
    fn step_alone(&mut self, j: usize, i: usize) {
        let (lane, state) = (&mut self.lanes[j], &mut self.states[j]);
        let t_target = self.t0 + (i + 1) as f64 * self.h;
        match lane.scheduled_step(state, self.h, t_target, self.max_halvings) {
            Ok(counts) => {
                // As the driver does: t pinned to the schedule, and the
                // pinned state declared the continuation of the step.
                *state = State { t: t_target, ..counts.state };
                lane.retarget_warm_start(state);
                self.iterations[j] = counts.iterations;
                self.total_iterations[j] += counts.iterations;
                self.recovery[j].count(&counts);
            }
            Err(error) => {
                let failure = LaneFailure { step: i, t: state.t, error };
                self.status[j] = LaneStatus::Failed(Box::new(failure));
                return;
            }
        }
        let Some(c) = lane.lane_continuation(state, self.h) else { return };
        if !self.kernel_for_run {
            return;
        }
        if self.kernel.is_none() && !self.kernel_refused {
            self.kernel = Kernel::new(&self.system, &self.tableau, state, self.h, self.simd).map(Box::new);
            self.kernel_refused = self.kernel.is_none();
        }
        if let Some(kernel) = self.kernel.as_deref_mut() {
            kernel.take(j, &c);
        }
    }

    /// Steps taken since [`Self::start`].
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The state of lane `j`: where its latest step ended (its start before
    /// any step; where the failed step started for a failed lane).
    /// `None` when `j ≥ W`.
    pub fn state(&self, j: usize) -> Option<&State<N>> {
        self.states.get(j)
    }

    /// The status of lane `j` (`None` when `j ≥ W`).
    pub fn status(&self, j: usize) -> Option<&LaneStatus> {
        self.status.get(j)
    }

    /// Newton iterations of lane `j`'s latest successful step (`None` when
    /// `j ≥ W`).
    pub fn iterations(&self, j: usize) -> Option<usize> {
        self.iterations.get(j).copied()
    }

    /// Newton iterations of lane `j`'s successful steps since
    /// [`Self::start`] (`None` when `j ≥ W`).
    pub fn total_iterations(&self, j: usize) -> Option<usize> {
        self.total_iterations.get(j).copied()
    }

    /// How many of lane `j`'s steps since [`Self::start`] the
    /// structure-of-arrays kernel took (the rest its own stepper took; see
    /// the module docs). `None` when `j ≥ W`.
    pub fn kernel_steps(&self, j: usize) -> Option<usize> {
        self.kernel_steps.get(j).copied()
    }

    /// What lane `j`'s failed steps since [`Self::start`] cost: its
    /// retries, halvings and smallest sub-step (`None` when `j ≥ W`).
    pub fn recovery(&self, j: usize) -> Option<&LaneRecovery> {
        self.recovery.get(j)
    }

    /// The stepper of lane `j`: its options, system and latest Newton
    /// history (`None` when `j ≥ W`).
    pub fn lane(&self, j: usize) -> Option<&Stepper<Sys, N, M, S, D>> {
        self.lanes.get(j)
    }
}
