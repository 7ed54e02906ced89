//! The integration driver: fixed steps or a list of output times (any sign,
//! any spacing), observers (energy, constraint residual, multipliers, or a
//! user callback), a serializable [`Trajectory`] and a per-run [`RunReport`].
//!
//! - [`trajectory`]: what a run returns ([`Sample`], [`RunReport`],
//!   [`Trajectory`]);
//! - [`observer`]: what sees every accepted step ([`Observer`]);
//! - [`failure`]: what happens when a step's Newton fails
//!   ([`FailurePolicy`]: halving, or rejection with an adapted sub-step);
//! - [`dense_run`]: the continuous extension of accepted steps (events, the
//!   observer of the dense output, `Sampled` times), shared with the
//!   tolerance-driven drivers;
//! - [`error`]: why a run failed ([`IntegrationError`]).

mod dense_run;
mod error;
mod failure;
mod observer;
mod trajectory;

pub use error::{IntegrationError, RejectionFloor, SubstepOverrun};
use failure::Budget;
pub(crate) use failure::StepCounts;
pub(crate) use observer::StepObserver;
pub use observer::{NoObserver, Observer};
pub(crate) use trajectory::sample_storage;
pub use trajectory::{check_record_size, record_memory_limit, RecordTooLarge, RunReport, Sample, Trajectory};
pub(crate) use trajectory::{recorded_steps, records_step};

use crate::events::EventFunctions;
use crate::initial::{consistent_velocity, ConsistencyPolicy};
use crate::rejection::RejectionPolicy;
use crate::step::{State, StepResult, Stepper};
use crate::system::{NonholonomicSystem, Vector};
pub(crate) use dense_run::{check_tableau, declared_events, Accepted, DenseRun};

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
    /// `t_{k+1} − t_k`; any nonzero spacing and either direction): the
    /// samples are step ends. [`Schedule::Sampled`] keeps `h` fixed instead
    /// and samples the times through the dense output.
    Times(&'a [f64]),
    /// Fixed steps of size `h` from `t₀` until the last of `times` is
    /// reached, with samples at `times` taken from the dense output
    /// ([`DenseStep`](crate::DenseStep)): the step size never changes to
    /// land on an output time. `times` are strictly monotone in the direction of `h`, the
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
    /// `t₀` in the direction of `h`). Step `k` ends at `t₀ + (k+1)·h`. A
    /// last step that would be shorter than the [`time_resolution`] at its
    /// start (a `t_end` on the grid computed in floats, as `t₀ + k·h`, that
    /// rounds past it) is not taken: the step before ends at `t_end`.
    Until {
        /// Step size.
        h: f64,
        /// Final time.
        t_end: f64,
    },
}

/// The largest step size a run takes: `√f64::MAX ≈ 1.34e154`. The Newton
/// matrix of a step carries `h²` (the `h²·â·a·∂F/∂q` blocks of every method
/// but symplectic Euler II), and beyond this `h²` overflows f64, so the
/// matrix holds infinities and NaNs and no step can succeed.
pub const MAX_STEP_SIZE: f64 = 1.340_780_792_994_259_6e154;

/// Whether the step size `h` can step from `t0`, or why not, with what to
/// change: `h` must be finite and nonzero, a normal number (for a
/// subnormal `h`, `|h| < f64::MIN_POSITIVE ≈ 2.2e-308`, `1/h` overflows in
/// the step's equations), at most [`MAX_STEP_SIZE`] in magnitude (beyond
/// it `h²` overflows in the step's Newton matrix), and at least
/// [`time_resolution`]`(t0)`, 16 units in the last place of `t0` (not
/// checked for a non-finite `t0`): the time of step `k` is `t0 + k·h`
/// rounded to `f64`, and with a step of a few units in the last place the
/// rounded times come out uneven and even repeat (from `t0 = 1e12`,
/// `h = 1e-4` steps 2 and 3 both end at `1e12 + 2.44e-4`), so the samples
/// would carry wrong times. At 16 units each time is off by at most 1/32
/// of a step, the floor the tolerance-driven drivers step down to.
/// [`Stepper::integrate`] checks the step size of every schedule with it
/// before the first step; front ends call it to refuse a step size up
/// front with the values they were given.
pub fn check_step_size(t0: f64, h: f64) -> Result<(), &'static str> {
    if h == 0.0 || !h.is_finite() {
        return Err("step size must be finite and nonzero");
    }
    if !h.is_normal() {
        return Err("step size is subnormal (|h| < 2.2e-308, where 1/h overflows); use |h| ≥ 2.2e-308");
    }
    if h.abs() > MAX_STEP_SIZE {
        return Err("step size is above 1.34e154, where h² overflows f64 in the step's Newton matrix; use a smaller \
             |h| (the step sizes of a problem are fractions of its time scale)");
    }
    if t0.is_finite() && h.abs() < time_resolution(t0) {
        return Err("step size is below the resolution of t at t0 (16 units in the last place of t0, where the \
             times t0 + k·h round to uneven or repeated values); use a larger |h| or a t0 nearer 0");
    }
    Ok(())
}

/// The resolution of time near `t`: `16·ε·|t|`, 16 units in the last place
/// of `t` at most. Steps below it do not advance time by their size: the
/// fixed-step schedules refuse them ([`check_step_size`]) and the
/// tolerance-driven drivers stop there.
pub fn time_resolution(t: f64) -> f64 {
    16.0 * f64::EPSILON * t.abs()
}

impl Schedule<'_> {
    /// The number of steps of a run from `t0`, or why the schedule cannot
    /// be run (not generic: compiled once, not once per system).
    fn steps(&self, t0: f64) -> Result<usize, IntegrationError> {
        Ok(match *self {
            Schedule::Fixed { h, steps } => {
                check_step_size(t0, h).map_err(IntegrationError::InvalidSchedule)?;
                if t0.is_finite() && !(t0 + steps as f64 * h).is_finite() {
                    return Err(IntegrationError::InvalidSchedule("the final time t0 + steps·h is not finite"));
                }
                steps
            }
            Schedule::Times(ts) => {
                if ts.iter().any(|t| !t.is_finite()) {
                    return Err(IntegrationError::InvalidSchedule("output times must be finite"));
                }
                // The smallest gap between consecutive times (zero exactly when
                // two are equal: finite differences do not underflow to 0) and
                // the largest (the largest step).
                let gap = std::iter::once(&t0).chain(ts.iter()).zip(ts.iter()).map(|(a, b)| (b - a).abs());
                let (smallest, largest) = gap.fold((f64::INFINITY, 0.0f64), |(lo, hi), g| (lo.min(g), hi.max(g)));
                if largest > MAX_STEP_SIZE {
                    return Err(IntegrationError::InvalidSchedule(
                        "consecutive output times lie more than 1.34e154 apart (a step where h² overflows f64 in the \
                         step's Newton matrix); use times closer together",
                    ));
                }
                match smallest {
                    0.0 => return Err(IntegrationError::InvalidSchedule("consecutive output times must differ")),
                    g if g < f64::MIN_POSITIVE => {
                        return Err(IntegrationError::InvalidSchedule(
                            "consecutive output times lie closer than 2.2e-308 (a subnormal step, where 1/h \
                             overflows); use times at least 2.2e-308 apart",
                        ))
                    }
                    _ => {}
                }
                ts.len()
            }
            Schedule::Sampled { h, times } => {
                check_step_size(t0, h).map_err(IntegrationError::InvalidSchedule)?;
                if times.iter().any(|t| !t.is_finite()) {
                    return Err(IntegrationError::InvalidSchedule("output times must be finite"));
                }
                // Signs, not products with h: (t − t0)·h underflows to 0 for
                // tiny gaps and steps.
                let dir = h.signum();
                if times.first().is_some_and(|&t| (t - t0) * dir < 0.0)
                    || times.windows(2).any(|w| (w[1] - w[0]) * dir <= 0.0)
                {
                    return Err(IntegrationError::InvalidSchedule(
                        "sampled output times must be strictly monotone in the direction of h, from t0 on",
                    ));
                }
                let Some(&last) = times.last() else { return Ok(0) };
                let span = (last - t0) / h;
                if !span.is_finite() || span >= usize::MAX as f64 {
                    return Err(IntegrationError::InvalidSchedule("too many steps of size h to reach the last time"));
                }
                // Step k ends at t0 + k·h as rounded, which can fall short of
                // the last time when ⌈(last − t0)/h⌉ rounds down (t0 = 0,
                // h = 0.2, last = 30.000000000000004: 150 steps end at 30.0);
                // the last time would then never be sampled.
                let mut steps = span.ceil() as usize;
                while (last - (t0 + steps as f64 * h)) * dir > 0.0 {
                    steps += 1;
                }
                steps
            }
            Schedule::Until { h, t_end } => {
                check_step_size(t0, h).map_err(IntegrationError::InvalidSchedule)?;
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
                // The last step runs from `t0 + (steps − 1)·h` as rounded to
                // `t_end`. A final time on the grid computed in floats can
                // lie a rounding past it (t0 = 0, h = 0.1, t_end = 0.1·3:
                // the quotient is 3.0000000000000004, and its ceiling asks
                // for a fourth step of size 0), or a few units in the last
                // place past it on purpose: a last step below the time's
                // resolution would be refused, or would not advance time by
                // its size. The step before it lands on `t_end` instead,
                // longer than `h` by less than that resolution.
                let mut steps = span.ceil() as usize;
                while steps > 1 {
                    let from = t0 + (steps - 1) as f64 * h;
                    if (t_end - from) * h.signum() > time_resolution(from) {
                        break;
                    }
                    steps -= 1;
                }
                steps
            }
        })
    }

    /// Step `k` of `steps` from time `t`, for a run that starts at `t0`: its
    /// size and the scheduled time it ends at.
    pub(crate) fn step(&self, k: usize, steps: usize, t0: f64, t: f64) -> (f64, f64) {
        match *self {
            Schedule::Fixed { h, .. } | Schedule::Sampled { h, .. } => (h, t0 + (k + 1) as f64 * h),
            Schedule::Times(ts) => (ts[k] - t, ts[k]),
            Schedule::Until { h, t_end } => {
                let target = if k + 1 == steps { t_end } else { t0 + (k + 1) as f64 * h };
                (target - t, target)
            }
        }
    }
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
    /// The most sub-steps that may cover one scheduled step once its Newton
    /// iteration has failed, under either [`FailurePolicy`] (at least 1).
    /// Halving `k` levels deep can take `2^k` sub-steps and rejection down
    /// to a floor of `|h|/f` up to `f` of them, each a Newton solve; a
    /// recovery that would need more ends the run with
    /// [`IntegrationError::SubstepBudget`] instead of working on. The
    /// default, [`DEFAULT_MAX_SUBSTEPS`], is never reached under the default
    /// policies.
    #[serde(default = "default_max_substeps")]
    pub max_substeps: usize,
    /// The most events the run keeps; locating one more ends it with
    /// [`IntegrationError::TooManyEvents`]. `None`: as many as fit in
    /// [`record_memory_limit`] ([`crate::events::max_located_events`]), so
    /// that a run whose events crowd in stops with an error instead of
    /// keeping them until memory runs out.
    #[serde(default)]
    pub max_events: Option<usize>,
}

/// The default [`RunOptions::max_substeps`]: `2^12`, as many sub-steps as
/// the default [`RejectionPolicy`](crate::RejectionPolicy) floor can take
/// and 256 times the default halving's 16.
pub const DEFAULT_MAX_SUBSTEPS: usize = 1 << 12;

fn default_max_substeps() -> usize {
    DEFAULT_MAX_SUBSTEPS
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
            max_substeps: DEFAULT_MAX_SUBSTEPS,
            max_events: None,
        }
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
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
    /// [`RunOptions::max_halvings`]); the error reports the last failure.
    /// Sample storage is reserved up to 1 MiB and grows as samples arrive,
    /// so the step count alone never allocates.
    ///
    /// The loop sees the observer and the events through trait objects
    /// ([`Observer`] behind an object-safe view, [`EventFunctions`] as
    /// `&dyn`), so it is compiled once per system and method, whatever the
    /// observer and the events; what that costs at run time is one
    /// indirect call per accepted step and per event-function evaluation.
    pub fn integrate<O: Observer<N, M>>(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut O,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        self.run(t0, q0, v0, schedule, options, observer, declared_events::<Sys, N, M>())
    }

    /// [`integrate`](Self::integrate) locating the events of `events`
    /// instead of the system's own (e.g. [`RuntimeEvents`](crate::RuntimeEvents)
    /// given at run time, or [`NoEvents`](crate::NoEvents) to ignore the declared ones).
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
        self.run(t0, q0, v0, schedule, options, observer, events)
    }

    /// [`integrate_with_events`](Self::integrate_with_events) with the
    /// observer and the events as trait objects (the public entry points
    /// are generic only to take them; from here on everything is compiled
    /// once per system and method): checks the options and the schedule,
    /// then runs the steps.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut dyn StepObserver<Sys, N, M, S>,
        events: &dyn EventFunctions<Sys, N>,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        options.validate().map_err(IntegrationError::InvalidOption)?;
        self.options().validate().map_err(IntegrationError::InvalidOption)?;
        let sampled = matches!(schedule, Schedule::Sampled { .. });
        check_tableau(self.tableau(), observer.wants_dense(), events.specs().len(), sampled)
            .map_err(IntegrationError::InvalidOption)?;
        let steps = schedule.steps(t0)?;
        let v0c =
            consistent_velocity(self.system(), t0, q0, v0, options.consistency).map_err(IntegrationError::Initial)?;
        // A run depends on its inputs only: nothing of an earlier run (warm
        // start, energy anchor, round-off carry) reaches its first step.
        self.reset_run();
        self.set_accepted_start_residual(options.consistency.tolerance());
        let result = self.run_steps(t0, q0, v0, v0c, steps, schedule, options, observer, events);
        self.set_accepted_start_residual(0.0);
        result
    }

    /// The stepping loop of [`Stepper::integrate`], from the checked initial
    /// velocity `v0c`.
    #[allow(clippy::too_many_arguments)]
    fn run_steps(
        &mut self,
        t0: f64,
        q0: &Vector<N>,
        v0: &Vector<N>,
        v0c: Vector<N>,
        steps: usize,
        schedule: Schedule<'_>,
        options: &RunOptions,
        observer: &mut dyn StepObserver<Sys, N, M, S>,
        events: &dyn EventFunctions<Sys, N>,
    ) -> Result<Trajectory<N, M>, IntegrationError> {
        let mut report = RunReport { projected_initial_velocity: v0c != *v0, ..RunReport::default() };
        // The steps that retried their cold guess themselves count into the
        // report once, when it is handed out: nothing on an accepted step.
        let cold_retries0 = self.cold_retries;
        let every = options.record_every;
        let sampled = match schedule {
            Schedule::Sampled { times, .. } => Some(times),
            _ => None,
        };
        let mut samples = sample_storage::<N, M>(sampled, steps, every);
        let mut state = State { t: t0, q: *q0, v: v0c };
        let first = self.sample(&state, &options.observe, 0);
        let e0 = first.energy;
        let track = |s: &Sample<N, M>, report: &mut RunReport| report.track(s, e0);
        track(&first, &mut report);
        samples.push(first);
        // The samples of a `Sampled` run are the initial point and each
        // requested time. A time at t0 is recorded by the first step's
        // extension, which returns its start bit for bit; when it is the only
        // time no step is taken, so it is recorded here.
        if steps == 0 && sampled.is_some_and(|times| !times.is_empty()) {
            samples.push(first);
        }
        // The report's extremes cover every accepted step, recorded or not:
        // the energy and the residual (no multipliers) at the steps not
        // recorded, only when the run observes them.
        let per_step = options.observe.energy || options.observe.constraint_residual;
        let per_step_observe = Observe { multipliers: false, ..options.observe };
        // Dense output and events: for a run without events, without an
        // observer of the dense output and without a `Sampled` schedule
        // nothing of this runs but one test per accepted sub-step of a flag
        // set here, once per run; no continuous extension is built and no
        // event function is evaluated.
        let mut dense_run = DenseRun::new(
            self.system(),
            self.tableau(),
            events,
            observer.wants_dense(),
            sampled,
            options.observe,
            e0,
            &state,
            options.max_events,
        );
        let dense = dense_run.is_needed();
        // An observer that watches no step (`Observer::STEPS`) is not
        // called: one indirect call a step less.
        let watched = observer.wants_steps();
        for k in 0..steps {
            let (h, t_target) = schedule.step(k, steps, t0, state.t);
            let mut step_iterations = 0usize;
            // The test of `dense` is all a sub-step costs here when the run
            // needs no continuous extension; the rest is out of line.
            let mut on_step = |sys: &Sys, start: &State<N>, end_t: f64, sub: f64, r: &StepResult<N, M, S>| {
                dense && {
                    step_iterations += r.iterations;
                    let end = &State { t: end_t, ..r.state };
                    let at = Accepted { k, iterations: step_iterations, start, end, sub, result: r };
                    dense_run.accepted(sys, at, observer, &mut samples, &mut report)
                }
            };
            let taken = match options.on_failure {
                FailurePolicy::Halve => {
                    let budget = Budget { max_halvings: options.max_halvings, max_substeps: options.max_substeps };
                    self.robust_step(&state, h, t_target, budget, &mut on_step)
                }
                FailurePolicy::Reject(policy) => {
                    self.rejecting_step(&state, h, t_target, &policy, options.max_substeps, &mut on_step)
                }
            };
            // Matched rather than mapped: the accepted outcome is not moved
            // into a second `Result`, and the error is built only on failure.
            let counts = match taken {
                Ok(counts) => counts,
                Err(failure) => {
                    report.cold_retries += self.cold_retries.wrapping_sub(cold_retries0);
                    return Err(failure.into_error(k, state.t, h, report));
                }
            };
            let (end_t, iters) = (counts.state.t, counts.iterations);
            report.count(&counts);
            if dense_run.too_many_events {
                report.cold_retries += self.cold_retries.wrapping_sub(cold_retries0);
                report.events = dense_run.located.len();
                let max_events = dense_run.max_events;
                return Err(IntegrationError::TooManyEvents { max_events, t: state.t, partial: Box::new(report) });
            }
            if let Some(at) = dense_run.terminal {
                // The run ends here whatever the observer asks.
                let _ = watched && observer.accepted(self.system(), &at, iters);
                report.terminal_event = dense_run.terminal_event();
                if sampled.is_none() || !matches!(samples.last(), Some(s) if s.t == at.t) {
                    let s = self.sample(&at, &options.observe, iters);
                    track(&s, &mut report);
                    samples.push(s);
                }
                state = at;
                break;
            }
            // The step's end, its time pinned to the scheduled value
            // (accumulating t0 + Σh drifts).
            state = counts.state;
            state.t = t_target;
            let stop = watched && observer.accepted(self.system(), &state, iters);
            let last = k + 1 == steps;
            if sampled.is_none() && records_step(k, steps, every) {
                let s = self.sample(&state, &options.observe, iters);
                track(&s, &mut report);
                samples.push(s);
            } else if per_step {
                track(&self.sample(&state, &per_step_observe, iters), &mut report);
            }
            // The stepper continues from the step's own end; when pinning
            // moved its time, it learns that the pinned state continues it.
            if state.t.to_bits() != end_t.to_bits() {
                self.retarget_warm_start(&state);
            }
            if stop && !last {
                report.cold_retries += self.cold_retries.wrapping_sub(cold_retries0);
                return Err(IntegrationError::Stopped { steps: k + 1, t: state.t, partial: Box::new(report) });
            }
        }
        let _ = state;
        report.cold_retries += self.cold_retries.wrapping_sub(cold_retries0);
        report.events = dense_run.located.len();
        if report.steps > 0 {
            report.newton_iterations_mean = report.newton_iterations_total as f64 / report.steps as f64;
        }
        Ok(Trajectory::of::<Sys>(self.tableau().method, S, samples, report, dense_run.located))
    }
}
