//! The integration driver: fixed steps or a list of output times (any sign,
//! any spacing), observers (energy, constraint residual, multipliers, or a
//! user callback), a serializable [`Trajectory`] and a per-run [`RunReport`].

use crate::dense::{DenseBasis, DenseStep};
use crate::error::{OptionError, Sci, StepError};
use crate::events::{locate, Crossing, EventFunctions, EventRecord, NoEvents, SystemEvents, EVENT_SUBINTERVALS};
use crate::initial::{consistent_acceleration, consistent_velocity, ConsistencyPolicy};
use crate::rejection::RejectionPolicy;
use crate::step::{State, StepResult, Stepper};
use crate::system::{NonholonomicSystem, Vector};
use crate::tableau::Method;

/// Where to produce output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Schedule<'a> {
    /// `steps` steps of size `h` from `t₀` (negative `h` integrates backward).
    Fixed {
        /// Step size.
        h: f64,
        /// Number of steps.
        steps: usize,
    },
    /// Step from `t₀` to each of these times in turn (each step is
    /// `t_{k+1} − t_k`; any nonzero spacing and either direction).
    Times(&'a [f64]),
    /// Fixed steps of size `h` from `t₀` until the last of `times` is
    /// reached, with samples at `times` taken from the dense output
    /// ([`DenseStep`]): the step size never changes to land on an output
    /// time. `times` are strictly monotone in the direction of `h`, the
    /// first one not before `t₀`; the samples are the initial point and
    /// these times (`record_every` does not apply). The last step may end
    /// beyond the last time.
    Sampled {
        /// Step size.
        h: f64,
        /// Output times.
        times: &'a [f64],
    },
    /// Steps of size `h` from `t₀` to `t_end`, the last one shortened to
    /// land on `t_end` (`⌈(t_end − t₀)/h⌉` steps; `t_end` lies ahead of
    /// `t₀` in the direction of `h`). Step `k` ends at `t₀ + (k+1)·h`.
    Until {
        /// Step size.
        h: f64,
        /// Final time.
        t_end: f64,
    },
}

/// Which quantities the driver records at each output point. The energy
/// and the constraint residual, when observed, are also evaluated at every
/// accepted step that is not recorded (one evaluation of `E` and one of `k`
/// per step) for the extremes of [`RunReport`]; quantities not observed cost
/// nothing.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Observe {
    /// `E = ∇_v L · v − L`.
    pub energy: bool,
    /// `max_i |k_i(t, q, v)|`.
    pub constraint_residual: bool,
    /// The multiplier `ψ(t, q, v)` of the ψ-eliminated equations at the
    /// numerical state (costs a stage Jacobian and a small saddle solve).
    pub multipliers: bool,
}

impl Default for Observe {
    fn default() -> Self {
        Observe { energy: true, constraint_residual: true, multipliers: false }
    }
}

/// Options of one integration run.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunOptions {
    /// What to record.
    pub observe: Observe,
    /// Record every `record_every`-th step (and always the first and last
    /// point); `0` records only the endpoints.
    pub record_every: usize,
    /// How to treat an inconsistent initial velocity.
    pub consistency: ConsistencyPolicy,
    /// When a step fails (after its retry from the cold starting guess),
    /// retry it as two half steps, nested at most this many times (each
    /// halving counts as a rejected step); at most [`MAX_HALVINGS`]. Halving
    /// also stops where half a step no longer changes `t`. A run that
    /// succeeds without halving is bit-identical whatever this is: a
    /// halving happens only where the run would otherwise fail. With
    /// `max_halvings = 0` the run stops at the first step that fails.
    /// Applies under [`FailurePolicy::Halve`].
    pub max_halvings: u32,
    /// What to do when a step fails.
    #[serde(default)]
    pub on_failure: FailurePolicy,
}

/// What the driver does when the Newton iteration of a step fails. Either
/// way a failure that no smaller step can cure (a non-finite state, an
/// inconsistent start, an invalid option) ends the run at once, and a run
/// in which no step fails takes one sub-step per scheduled step under
/// either policy.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum FailurePolicy {
    /// Retry a warm-started step once from the cold starting guess (the
    /// consistent acceleration), then replace a step that still fails by
    /// two half steps, nested at most [`RunOptions::max_halvings`] levels
    /// deep (`0`: stop the run at the failure).
    #[default]
    Halve,
    /// Reject the failed (sub-)step and cover the rest of the scheduled
    /// step with sub-steps whose size halves after each rejection and
    /// doubles back after a run of accepted ones, never below the floor of
    /// the [`RejectionPolicy`]; the next scheduled step starts again at its
    /// own size. Giving up reports [`IntegrationError::Floor`].
    Reject(RejectionPolicy),
}

/// Largest [`RunOptions::max_halvings`]: a step is cut to at most `2⁻⁶⁰` of
/// its size (the same bound as [`RejectionPolicy`](crate::RejectionPolicy)).
pub const MAX_HALVINGS: u32 = 60;

/// The default [`RunOptions::max_halvings`]: a step that Newton cannot solve
/// is covered by at most 16 sub-steps before the run reports the failure.
/// Enough for the step sizes where a constraint nonlinear in `v` (the speed
/// `|v| = c`) first defeats Newton, while a step size that is wrong for the
/// problem is still reported after a bounded amount of work.
pub const DEFAULT_MAX_HALVINGS: u32 = 4;

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            observe: Observe::default(),
            record_every: 1,
            consistency: ConsistencyPolicy::default(),
            max_halvings: DEFAULT_MAX_HALVINGS,
            on_failure: FailurePolicy::Halve,
        }
    }
}

/// One recorded point of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample<const N: usize, const M: usize> {
    /// Time.
    pub t: f64,
    /// Coordinates.
    pub q: Vector<N>,
    /// Velocities.
    pub v: Vector<N>,
    /// Energy, when observed.
    pub energy: Option<f64>,
    /// `max_i |k_i(t,q,v)|`, when observed.
    pub constraint_residual: Option<f64>,
    /// `ψ(t,q,v)`, when observed (`None` also if the saddle matrix was singular).
    pub multipliers: Option<Vector<M>>,
    /// Newton iterations of the step that produced this point (0 at the start).
    pub newton_iterations: usize,
}

/// Statistics of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunReport {
    /// Accepted steps.
    pub steps: usize,
    /// Newton iterations over all accepted steps.
    pub newton_iterations_total: usize,
    /// Mean Newton iterations per accepted step.
    pub newton_iterations_mean: f64,
    /// Largest Newton iteration count of one step.
    pub newton_iterations_max: usize,
    /// Rejected (sub-)steps: each Newton failure followed by smaller
    /// sub-steps (a halving, or a rejection under [`FailurePolicy::Reject`]).
    pub rejected_steps: usize,
    /// Accepted sub-steps: one per scheduled step that succeeds at once,
    /// more where failures cut it.
    #[serde(default)]
    pub substeps: usize,
    /// Scheduled steps that needed at least one rejected sub-step.
    #[serde(default)]
    pub steps_with_rejections: usize,
    /// Smallest magnitude of an accepted sub-step (0 before the first).
    #[serde(default)]
    pub smallest_step: f64,
    /// Steps started cold (no usable previous step to extrapolate from),
    /// retried cold or halved.
    pub cold_starts: usize,
    /// Warm-started (sub-)steps whose Newton failed and that were retried
    /// once from the cold starting guess (the consistent acceleration) before
    /// any halving: an extrapolated guess can lie outside Newton's basin
    /// where the cold one does not.
    #[serde(default)]
    pub cold_retries: usize,
    /// Largest `max_i |k_i|` over the initial point, every accepted step
    /// (recorded or not) and the samples (0 if not observed: see
    /// [`Observe::constraint_residual`]).
    pub max_constraint_residual: f64,
    /// Largest `|E − E₀|` over the initial point, every accepted step
    /// (recorded or not) and the samples (0 if not observed: see
    /// [`Observe::energy`]).
    pub max_energy_error: f64,
    /// Whether `v₀` was projected onto the constraints.
    pub projected_initial_velocity: bool,
    /// Events located (see [`Trajectory::events`]).
    #[serde(default)]
    pub events: usize,
    /// The terminal event that ended the run, by index, if any.
    #[serde(default)]
    pub terminal_event: Option<usize>,
}

/// A recorded solution with its provenance; serializes to JSON (serde) and CSV.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Trajectory<const N: usize, const M: usize> {
    /// The system's type name.
    pub system: String,
    /// Coordinate names.
    pub coordinates: Vec<String>,
    /// The method.
    pub method: Method,
    /// Number of stages.
    pub stages: usize,
    /// The recorded points.
    pub samples: Vec<Sample<N, M>>,
    /// Run statistics.
    pub report: RunReport,
    /// The located events in time order (empty for systems without events).
    #[serde(default = "Vec::new")]
    pub events: Vec<EventRecord<N>>,
}

/// An integration run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum IntegrationError {
    /// The schedule is unusable.
    #[error("invalid schedule: {0}")]
    InvalidSchedule(&'static str),
    /// A run or Newton option is out of range (checked before any step).
    #[error("{0}")]
    InvalidOption(OptionError),
    /// The initial state was rejected or could not be projected.
    #[error("initial state: {0}")]
    Initial(#[source] StepError),
    /// A step failed (after any retries).
    #[error("step {index} from t = {} failed: {source}", Sci(*t))]
    Step {
        /// Index of the failed step (0-based).
        index: usize,
        /// Its start time.
        t: f64,
        /// Why.
        source: StepError,
        /// The trajectory up to the failure.
        partial: Box<RunReport>,
    },
    /// Under [`FailurePolicy::Reject`], Newton kept failing down to the
    /// smallest sub-step allowed.
    #[error(
        "step {index} from t = {} (h = {}) still fails at t = {} with sub-step {} at the floor {} \
         after {} rejections; last failure: {}",
        Sci(*t),
        Sci(detail.h),
        Sci(detail.substep_t),
        Sci(detail.h_tried),
        Sci(detail.floor),
        detail.rejections,
        detail.last
    )]
    Floor {
        /// Index of the failed step (0-based).
        index: usize,
        /// Its start time.
        t: f64,
        /// Where and how the rejections ended.
        detail: Box<RejectionFloor>,
        /// The run statistics up to the failure.
        partial: Box<RunReport>,
    },
}

/// How a step under [`FailurePolicy::Reject`] reached the floor.
#[derive(Clone, Debug, PartialEq)]
pub struct RejectionFloor {
    /// The step size.
    pub h: f64,
    /// Where the failing sub-step starts.
    pub substep_t: f64,
    /// The last sub-step size tried.
    pub h_tried: f64,
    /// The floor (see [`RejectionPolicy::floor`]).
    pub floor: f64,
    /// Rejections within the step.
    pub rejections: usize,
    /// The last Newton failure.
    pub last: StepError,
}

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
}

impl StepFailure {
    /// The run error of step `index` of size `h` from `t`.
    fn into_error(self, index: usize, t: f64, h: f64, partial: RunReport) -> IntegrationError {
        let partial = Box::new(partial);
        match self {
            StepFailure::Step(source) => IntegrationError::Step { index, t, source, partial },
            StepFailure::Floor { substep_t, h_tried, floor, rejections, last } => IntegrationError::Floor {
                index,
                t,
                detail: Box::new(RejectionFloor { h, substep_t, h_tried, floor, rejections, last }),
                partial,
            },
        }
    }
}

/// Largest sample storage (bytes) `integrate` reserves before the run.
const RESERVE_BYTES: usize = 1 << 20;

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
    cold_retries: usize,
    /// The per-sub-step callback asked to stop (a terminal event).
    stopped: bool,
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

/// Receives every accepted step (not only recorded ones) together with the
/// system being integrated, so that it can evaluate the system's own
/// quantities (energy, constraints, holonomic drift) at each step.
///
/// A closure `FnMut(&State<N>, usize)` is an observer that ignores the
/// system. An observer written as a type implements
/// [`observe`](Self::observe) for every system of dimension `(N, M)`, which
/// it sees through [`NonholonomicSystem`].
pub trait Observer<const N: usize, const M: usize> {
    /// The observer wants the continuous extension of every accepted
    /// (sub-)step ([`observe_dense`](Self::observe_dense)). When `false`
    /// (the default) the driver builds none for it.
    const DENSE: bool = false;
    /// Called after each accepted step with the system, the new state and
    /// the Newton iteration count.
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, system: &Sys, state: &State<N>, iterations: usize);
    /// Called with the continuous extension of each accepted (sub-)step,
    /// before [`observe`](Self::observe), when [`DENSE`](Self::DENSE) is
    /// true: sample it anywhere in the step with [`DenseStep::state_at`].
    /// When a terminal event ends the run inside a step, the extension
    /// covers the step up to the event only ([`DenseStep::end`] is the state
    /// at the event).
    fn observe_dense<const S: usize>(&mut self, step: &DenseStep<'_, N, S>) {
        let _ = step;
    }
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl<const N: usize, const M: usize> Observer<N, M> for NoObserver {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, _: &State<N>, _: usize) {}
}

impl<const N: usize, const M: usize, F: FnMut(&State<N>, usize)> Observer<N, M> for F {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, state: &State<N>, iterations: usize) {
        self(state, iterations)
    }
}

impl<const N: usize, const M: usize> Trajectory<N, M> {
    /// A trajectory of `Sys` (its name and coordinate names from the
    /// system's source) taken with `method` of `stages` stages.
    pub(crate) fn of<Sys: NonholonomicSystem<N, M>>(
        method: Method,
        stages: usize,
        samples: Vec<Sample<N, M>>,
        report: RunReport,
        events: Vec<EventRecord<N>>,
    ) -> Self {
        let source = Sys::SOURCE;
        Trajectory {
            system: source.name.to_string(),
            coordinates: source.coordinates.iter().map(|c| c.to_string()).collect(),
            method,
            stages,
            samples,
            report,
            events,
        }
    }

    /// The last recorded state.
    pub fn last(&self) -> Option<State<N>> {
        self.samples.last().map(|s| State { t: s.t, q: s.q, v: s.v })
    }

    /// CSV with a header `t, q_<name>…, v_<name>…, energy, constraint_residual, psi_1…, newton_iterations`
    /// (unobserved columns are empty).
    pub fn write_csv<W: std::io::Write>(&self, writer: W) -> Result<(), csv::Error> {
        let mut w = csv::Writer::from_writer(writer);
        let mut header = vec!["t".to_string()];
        header.extend(self.coordinates.iter().map(|c| format!("q_{c}")));
        header.extend(self.coordinates.iter().map(|c| format!("v_{c}")));
        header.push("energy".into());
        header.push("constraint_residual".into());
        header.extend((1..=M).map(|i| format!("psi_{i}")));
        header.push("newton_iterations".into());
        w.write_record(&header)?;
        let opt = |x: Option<f64>| x.map(|v| format!("{v:e}")).unwrap_or_default();
        for s in &self.samples {
            let mut rec = Vec::with_capacity(header.len());
            rec.push(format!("{:e}", s.t));
            rec.extend(s.q.iter().chain(s.v.iter()).map(|x| format!("{x:e}")));
            rec.push(opt(s.energy));
            rec.push(opt(s.constraint_residual));
            for i in 0..M {
                rec.push(opt(s.multipliers.map(|p| p[i])));
            }
            rec.push(s.newton_iterations.to_string());
            w.write_record(&rec)?;
        }
        w.flush()?;
        Ok(())
    }

    /// The CSV text (see [`Trajectory::write_csv`]).
    pub fn to_csv_string(&self) -> Result<String, csv::Error> {
        let mut buf = Vec::new();
        self.write_csv(&mut buf)?;
        Ok(String::from_utf8_lossy(&buf).into_owned())
    }

    /// Pretty JSON of the whole trajectory.
    pub fn to_json_string(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(self)
    }
}

impl RunReport {
    /// Counts one scheduled step taken as `counts`; `warm_before`: whether
    /// its first attempt was warm-started.
    fn count<const N: usize>(&mut self, counts: &StepCounts<N>, warm_before: bool) {
        if !warm_before || counts.rejected > 0 || counts.cold_retries > 0 {
            self.cold_starts += 1;
        }
        self.steps += 1;
        self.rejected_steps += counts.rejected;
        self.substeps += counts.substeps;
        self.steps_with_rejections += usize::from(counts.rejected > 0);
        if self.smallest_step == 0.0 || counts.smallest < self.smallest_step {
            self.smallest_step = counts.smallest;
        }
        self.cold_retries += counts.cold_retries;
        self.newton_iterations_total += counts.iterations;
        self.newton_iterations_max = self.newton_iterations_max.max(counts.iterations);
    }
}

/// Storage for the samples of a run of `steps` steps recording every
/// `every`-th (or at the `sampled` times): reserved for the expected samples
/// up to a bounded size; beyond it the storage grows as samples arrive
/// (amortized, only when recording).
fn sample_storage<const N: usize, const M: usize>(
    sampled: Option<&[f64]>,
    steps: usize,
    every: usize,
) -> Vec<Sample<N, M>> {
    let expected = match sampled {
        Some(times) => times.len() + 1,
        None => steps.checked_div(every).map_or(2, |n| n.saturating_add(2)),
    };
    let bound = (RESERVE_BYTES / std::mem::size_of::<Sample<N, M>>().max(1)).max(2);
    Vec::with_capacity(expected.min(bound))
}

/// The recorded point at `state`.
fn sample_of<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    state: &State<N>,
    observe: &Observe,
    iterations: usize,
) -> Sample<N, M>
where
    Sys: NonholonomicSystem<N, M>,
{
    Sample {
        t: state.t,
        q: state.q,
        v: state.v,
        energy: observe.energy.then(|| sys.energy(state.t, &state.q, &state.v)),
        constraint_residual: observe.constraint_residual.then(|| sys.constraint(state.t, &state.q, &state.v).amax()),
        multipliers: if observe.multipliers {
            consistent_acceleration(sys, state.t, &state.q, &state.v).map(|(_, psi)| psi)
        } else {
            None
        },
        newton_iterations: iterations,
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    pub(crate) fn sample(&self, state: &State<N>, observe: &Observe, iterations: usize) -> Sample<N, M> {
        sample_of(self.system(), state, observe, iterations)
    }

    /// One step of size `h` from `state`. A warm-started attempt that fails
    /// is retried once from the cold guess; a sub-step that still fails is
    /// replaced by two half steps, at most `max_halvings` levels deep and
    /// only while half of it still changes `t`. Iterative, with the pending
    /// sub-steps in a fixed array: no recursion, no heap.
    ///
    /// `on_step(system, start, end, h, result)` sees every accepted
    /// sub-step (the last one with its end time pinned to `t_target`); when
    /// it returns `true` the step stops there.
    fn robust_step<F>(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        max_halvings: u32,
        on_step: &mut F,
    ) -> Result<StepCounts<N>, StepFailure>
    where
        F: FnMut(&Sys, &State<N>, &State<N>, f64, &StepResult<N, M, S>) -> bool,
    {
        let max_halvings = max_halvings.min(MAX_HALVINGS);
        // Sub-steps still to take, the next one last, with their halving
        // level. A failure replaces its entry by its two halves one level
        // deeper, so the levels increase strictly up the array but for a
        // pair at the top: `MAX_HALVINGS + 1` entries suffice.
        let mut pending = [(0.0f64, 0u32); MAX_HALVINGS as usize + 1];
        pending[0] = (h, 0);
        let mut len = 1;
        let mut out = StepCounts::start(state);
        while len > 0 {
            let (sub, level) = pending[len - 1];
            let warm = self.is_warm_for(&out.state);
            let result = match self.step(&out.state, sub) {
                Err(e) if warm && e.is_curable() => {
                    out.cold_retries += 1;
                    self.reset_warm_start();
                    self.step(&out.state, sub)
                }
                other => other,
            };
            match result {
                Ok(r) => {
                    len -= 1;
                    let mut end = r.state;
                    if len == 0 {
                        end.t = t_target;
                    }
                    let stop = on_step(self.system(), &out.state, &end, sub, &r);
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
    /// [`RejectionPolicy::floor`]. `on_step` as in `robust_step`.
    pub(crate) fn rejecting_step<F>(
        &mut self,
        state: &State<N>,
        h: f64,
        t_target: f64,
        policy: &RejectionPolicy,
        on_step: &mut F,
    ) -> Result<StepCounts<N>, StepFailure>
    where
        F: FnMut(&Sys, &State<N>, &State<N>, f64, &StepResult<N, M, S>) -> bool,
    {
        let t_end = state.t + h;
        let floor = policy.floor(h);
        let mut out = StepCounts::start(state);
        let mut sub = h;
        let mut successes = 0usize;
        // Sub-steps end within a few ulps of t_end; what is left below that
        // is rounding of the accumulated times, not a step to take.
        let slack = 8.0 * f64::EPSILON * t_end.abs().max(h.abs());
        loop {
            let remaining = t_end - out.state.t;
            if out.substeps > 0 && remaining * h.signum() <= slack {
                break;
            }
            let this = if sub.abs() >= remaining.abs() { remaining } else { sub };
            match self.step(&out.state, this) {
                Ok(r) => {
                    let mut end = r.state;
                    if (t_end - r.state.t) * h.signum() <= slack {
                        end.t = t_target;
                    }
                    let stop = on_step(self.system(), &out.state, &end, this, &r);
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
                }
            }
        }
        Ok(out)
    }

    /// Integrates from `(t₀, q₀, v₀)` over `schedule`, checking (or projecting)
    /// the initial velocity first, recording samples per `options` and
    /// calling `observer` after every accepted step. The events the system
    /// declares ([`NonholonomicSystem::EVENTS`]) are located in every step
    /// and reported in [`Trajectory::events`]; a terminal one ends the run
    /// at its time (see [`events`](crate::events)).
    ///
    /// The run and Newton options are checked first
    /// ([`RunOptions::validate`], [`NewtonOptions::validate`](crate::NewtonOptions::validate));
    /// an out-of-range one is an [`IntegrationError::InvalidOption`]. Every
    /// run starts afresh: nothing an earlier run left in this stepper (warm
    /// start, energy anchor, round-off compensation) reaches it, so a reused
    /// stepper returns bit for bit what a fresh one does. This is the one
    /// loop that advances a run: a failed step is handled per
    /// [`RunOptions::on_failure`] (by default retried once from the cold
    /// starting guess when it was warm-started, then halved per
    /// [`RunOptions::max_halvings`]); the error reports the last failure. Sample storage is reserved up to 1 MiB and grows as
    /// samples arrive, so the step count alone never allocates.
    pub fn integrate<O: Observer<N, M>>(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut O,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        if Sys::HAS_EVENTS {
            self.integrate_with_events(t0, q0, v0, schedule, options, observer, &SystemEvents::<M>)
        } else {
            self.integrate_with_events(t0, q0, v0, schedule, options, observer, &NoEvents)
        }
    }

    /// [`integrate`](Self::integrate) locating the events of `events`
    /// instead of the system's own (e.g. [`RuntimeEvents`](crate::RuntimeEvents)
    /// given at run time, or [`NoEvents`] to ignore the declared ones).
    #[allow(clippy::too_many_arguments)]
    pub fn integrate_with_events<O: Observer<N, M>, E: EventFunctions<Sys, N>>(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut O,
        events: &E,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        options.validate().map_err(IntegrationError::InvalidOption)?;
        self.options().validate().map_err(IntegrationError::InvalidOption)?;
        let steps = match schedule {
            Schedule::Fixed { h, steps } => {
                if h == 0.0 || !h.is_finite() {
                    return Err(IntegrationError::InvalidSchedule("step size must be finite and nonzero"));
                }
                if t0.is_finite() && !(t0 + steps as f64 * h).is_finite() {
                    return Err(IntegrationError::InvalidSchedule("the final time t0 + steps·h is not finite"));
                }
                steps
            }
            Schedule::Times(ts) => {
                if ts.iter().any(|t| !t.is_finite()) {
                    return Err(IntegrationError::InvalidSchedule("output times must be finite"));
                }
                if std::iter::once(&t0).chain(ts.iter()).zip(ts.iter()).any(|(a, b)| a == b) {
                    return Err(IntegrationError::InvalidSchedule("consecutive output times must differ"));
                }
                ts.len()
            }
            Schedule::Sampled { h, times } => {
                if h == 0.0 || !h.is_finite() {
                    return Err(IntegrationError::InvalidSchedule("step size must be finite and nonzero"));
                }
                if times.iter().any(|t| !t.is_finite()) {
                    return Err(IntegrationError::InvalidSchedule("output times must be finite"));
                }
                if times.first().is_some_and(|&t| (t - t0) * h < 0.0)
                    || times.windows(2).any(|w| (w[1] - w[0]) * h <= 0.0)
                {
                    return Err(IntegrationError::InvalidSchedule(
                        "sampled output times must be strictly monotone in the direction of h, from t0 on",
                    ));
                }
                let span = times.last().map_or(0.0, |&t| (t - t0) / h);
                if !span.is_finite() || span >= usize::MAX as f64 {
                    return Err(IntegrationError::InvalidSchedule("too many steps of size h to reach the last time"));
                }
                span.ceil() as usize
            }
            Schedule::Until { h, t_end } => {
                if h == 0.0 || !h.is_finite() {
                    return Err(IntegrationError::InvalidSchedule("step size must be finite and nonzero"));
                }
                if !t_end.is_finite() {
                    return Err(IntegrationError::InvalidSchedule("the final time must be finite"));
                }
                if (t_end - t0) * h.signum() < 0.0 {
                    return Err(IntegrationError::InvalidSchedule(
                        "the final time lies behind the start in the direction of h",
                    ));
                }
                let span = ((t_end - t0) / h).abs();
                if !span.is_finite() || span >= usize::MAX as f64 {
                    return Err(IntegrationError::InvalidSchedule("too many steps of size h to reach the final time"));
                }
                span.ceil() as usize
            }
        };
        let v0c =
            consistent_velocity(self.system(), t0, q0, v0, options.consistency).map_err(IntegrationError::Initial)?;
        // A run depends on its inputs only: nothing of an earlier run (warm
        // start, energy anchor, round-off carry) reaches its first step.
        self.reset_run();
        let accepted = match options.consistency {
            ConsistencyPolicy::Error { tolerance } | ConsistencyPolicy::Project { tolerance } => tolerance,
        };
        self.set_accepted_start_residual(accepted);
        let result = self.run_steps(t0, q0, v0, v0c, steps, schedule, options, observer, events);
        self.set_accepted_start_residual(0.0);
        result
    }

    /// The stepping loop of [`Stepper::integrate`], from the checked initial
    /// velocity `v0c`.
    #[allow(clippy::too_many_arguments)]
    fn run_steps<O: Observer<N, M>, E: EventFunctions<Sys, N>>(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        v0c: Vector<N>,
        steps: usize,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut O,
        events: &E,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        let mut report = RunReport { projected_initial_velocity: v0c != *v0, ..RunReport::default() };
        let every = options.record_every;
        let sampled = match schedule {
            Schedule::Sampled { times, .. } => Some(times),
            _ => None,
        };
        let mut samples = sample_storage::<N, M>(sampled, steps, every);
        let mut state = State { t: t0, q: *q0, v: v0c };
        let first = self.sample(&state, &options.observe, 0);
        let e0 = first.energy;
        let track = |s: &Sample<N, M>, report: &mut RunReport| {
            if let Some(r) = s.constraint_residual {
                report.max_constraint_residual = report.max_constraint_residual.max(r);
            }
            if let (Some(e), Some(e0)) = (s.energy, e0) {
                report.max_energy_error = report.max_energy_error.max((e - e0).abs());
            }
        };
        track(&first, &mut report);
        samples.push(first);
        // The report's extremes cover every accepted step, recorded or not:
        // the energy and the residual (no multipliers) at the steps not
        // recorded, only when the run observes them.
        let per_step = options.observe.energy || options.observe.constraint_residual;
        let per_step_observe = Observe { multipliers: false, ..options.observe };
        // Dense output and events: nothing of this runs (the branches are on
        // constants) for a system without events, an observer without dense
        // output and a schedule that is not `Sampled`.
        let specs = events.specs();
        let dense = O::DENSE || !specs.is_empty() || sampled.is_some();
        let basis = DenseBasis::new(self.tableau());
        let mut located: Vec<EventRecord<N>> = Vec::new();
        let mut crossings: Vec<Crossing> = Vec::with_capacity(specs.len());
        let mut previous: Vec<f64> = specs
            .iter()
            .enumerate()
            .map(|(i, _)| events.value(self.system(), i, state.t, &state.q, &state.v))
            .collect();
        let mut next_time = 0usize;
        let mut terminal: Option<State<N>> = None;
        for k in 0..steps {
            let (h, t_target) = match schedule {
                Schedule::Fixed { h, .. } | Schedule::Sampled { h, .. } => (h, t0 + (k + 1) as f64 * h),
                Schedule::Times(ts) => (ts[k] - state.t, ts[k]),
                Schedule::Until { h, t_end } => {
                    let target = if k + 1 == steps { t_end } else { t0 + (k + 1) as f64 * h };
                    (target - state.t, target)
                }
            };
            let warm_before = self.is_warm_for(&state);
            let step_iterations = &mut 0usize;
            let mut on_step = |sys: &Sys, start: &State<N>, end: &State<N>, sub: f64, r: &StepResult<N, M, S>| {
                if !dense {
                    return false;
                }
                *step_iterations += r.iterations;
                let piece = DenseStep::new(&basis, start, end, sub, r);
                let mut stop_at = None;
                if !specs.is_empty() {
                    crossings.clear();
                    find_crossings(events, sys, &piece, &mut previous, &mut crossings);
                    for c in crossings.iter() {
                        let at = piece.state_at(c.t);
                        let spec = &specs[c.index];
                        located.push(EventRecord {
                            index: c.index,
                            name: spec.name.to_string(),
                            rising: c.rising,
                            t: c.t,
                            q: at.q,
                            v: at.v,
                            residual: events.value(sys, c.index, at.t, &at.q, &at.v),
                            step: k,
                        });
                        if spec.terminal {
                            stop_at = Some(at);
                            break;
                        }
                    }
                }
                if O::DENSE {
                    // A terminal event ends the run inside this step: the
                    // observer sees the extension up to the event only.
                    match stop_at {
                        Some(at) => observer.observe_dense(&piece.until(at.t)),
                        None => observer.observe_dense(&piece),
                    }
                }
                if let Some(times) = sampled {
                    let forward = sub > 0.0;
                    let limit = stop_at.map_or(end.t, |s| s.t);
                    while let Some(&t) = times.get(next_time) {
                        if (forward && t > limit) || (!forward && t < limit) {
                            break;
                        }
                        let s = sample_of(sys, &piece.state_at(t), &options.observe, *step_iterations);
                        track(&s, &mut report);
                        samples.push(s);
                        next_time += 1;
                    }
                }
                if stop_at.is_some() {
                    terminal = stop_at;
                    return true;
                }
                false
            };
            let counts = match options.on_failure {
                FailurePolicy::Halve => self.robust_step(&state, h, t_target, options.max_halvings, &mut on_step),
                FailurePolicy::Reject(policy) => self.rejecting_step(&state, h, t_target, &policy, &mut on_step),
            }
            .map_err(|failure| failure.into_error(k, state.t, h, report))?;
            let (mut next, iters) = (counts.state, counts.iterations);
            // Accumulating t0 + Σh drifts; pin t to the scheduled value.
            next.t = t_target;
            report.count(&counts, warm_before);
            if let Some(at) = terminal {
                observer.observe(self.system(), &at, iters);
                report.terminal_event = located.last().map(|e| e.index);
                if sampled.is_none() || !matches!(samples.last(), Some(s) if s.t == at.t) {
                    let s = self.sample(&at, &options.observe, iters);
                    track(&s, &mut report);
                    samples.push(s);
                }
                state = at;
                break;
            }
            observer.observe(self.system(), &next, iters);
            let last = k + 1 == steps;
            if sampled.is_none() && (last || (every != 0 && (k + 1) % every == 0)) {
                let s = self.sample(&next, &options.observe, iters);
                track(&s, &mut report);
                samples.push(s);
            } else if per_step {
                track(&self.sample(&next, &per_step_observe, iters), &mut report);
            }
            state = next;
            self.retarget_warm_start(&state);
        }
        let _ = state;
        report.events = located.len();
        if report.steps > 0 {
            report.newton_iterations_mean = report.newton_iterations_total as f64 / report.steps as f64;
        }
        Ok(Trajectory::of::<Sys>(self.tableau().method, S, samples, report, located))
    }
}

/// Appends the crossings of `piece` (each located, in time order) to
/// `crossings`, updating each event's last value in `previous`.
fn find_crossings<Sys, E, const N: usize, const S: usize>(
    events: &E,
    sys: &Sys,
    piece: &DenseStep<'_, N, S>,
    previous: &mut [f64],
    crossings: &mut Vec<Crossing>,
) where
    E: EventFunctions<Sys, N> + ?Sized,
{
    let specs = events.specs();
    let (ta, tb) = (piece.start.t, piece.end.t);
    for (index, spec) in specs.iter().enumerate() {
        let mut a = (ta, previous[index]);
        for k in 1..=EVENT_SUBINTERVALS {
            let (t, at) = if k == EVENT_SUBINTERVALS {
                (tb, piece.end)
            } else {
                let t = ta + (tb - ta) * (k as f64 / EVENT_SUBINTERVALS as f64);
                (t, piece.state_at(t))
            };
            let b = (t, events.value(sys, index, t, &at.q, &at.v));
            let crossed = a.1 != 0.0 && (b.1 == 0.0 || (a.1 < 0.0) != (b.1 < 0.0)) && !b.1.is_nan();
            let rising = a.1 < 0.0;
            if crossed && spec.direction.accepts(rising) {
                let t = locate(events, sys, index, piece, a, b);
                crossings.push(Crossing { index, rising, t });
            }
            a = b;
        }
        previous[index] = a.1;
    }
    let forward = tb > ta;
    crossings.sort_by(|x, y| {
        let order = x.t.total_cmp(&y.t);
        if forward {
            order
        } else {
            order.reverse()
        }
    });
}
