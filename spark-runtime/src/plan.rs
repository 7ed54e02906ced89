//! A run as a front end asks for it at run time (`spark run`, the Python
//! package): fixed steps or tolerance-driven steps, recorded at the steps
//! or at output times from the continuous extension, with or without the
//! events the system declares. The choice has one home, so that every
//! front end runs the same request the same way: [`integrate_plan`] hands
//! it to [`Stepper::integrate_with_events`], [`integrate_adaptive_with_events`]
//! or [`integrate_adaptive_at`].

use crate::adaptive::{
    integrate_adaptive_at, integrate_adaptive_with_events, AdaptiveError, AdaptiveOptions, AdaptiveReport,
};
use crate::driver::{check_record_size, IntegrationError, Observer, RunOptions, Schedule, Trajectory};
use crate::error::Sci;
use crate::events::{EventFunctions, EventRecord, NoEvents, SystemEvents};
use crate::step::Stepper;
use crate::system::{NonholonomicSystem, Vector};

/// Tolerance-driven steps: the local error estimate and the PI controller
/// of [`adaptive`](crate::adaptive), from `t0` to `t_end`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Tolerance {
    /// Relative tolerance of the local error (per component of `(q, v)`).
    pub rtol: f64,
    /// Absolute tolerance of the local error (per component of `(q, v)`).
    pub atol: f64,
    /// Magnitude of the first step tried (`None`: estimated from the
    /// initial velocity and acceleration).
    pub first_step: Option<f64>,
    /// Largest step magnitude (`None`: the whole interval).
    pub max_step: Option<f64>,
    /// The most step attempts, accepted and rejected
    /// ([`AdaptiveOptions::max_steps`]): what bounds the work and the
    /// recorded samples of a run whose steps are not known in advance.
    pub max_steps: usize,
    /// The final time, which the last step lands on.
    pub t_end: f64,
}

/// How a planned run chooses its steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stepping {
    /// `steps` steps of size `h` (a step whose Newton iteration fails is
    /// halved per [`RunOptions::max_halvings`]).
    Fixed {
        /// Step size (negative integrates backward).
        h: f64,
        /// Number of steps.
        steps: usize,
    },
    /// Step sizes chosen for a tolerance.
    Tolerance(Tolerance),
}

impl Stepping {
    /// The end of the interval the steps cover: `t0 + steps·h` for fixed
    /// steps, `t_end` for tolerance-driven ones.
    pub fn t_end(&self, t0: f64) -> f64 {
        match *self {
            Stepping::Fixed { h, steps } => t0 + steps as f64 * h,
            Stepping::Tolerance(tolerance) => tolerance.t_end,
        }
    }
}

/// One run: its steps, where it records and whether it locates events.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunPlan<'a> {
    /// How the steps are chosen.
    pub stepping: Stepping,
    /// Output times: the samples are the initial point and the state at
    /// each of these times, from the continuous extension of the step that
    /// holds it (the steps are not shortened to land on them), and the run
    /// ends at the last one. `None` records at the steps
    /// ([`RunOptions::record_every`]). Strictly monotone, within the
    /// interval of [`stepping`](Self::stepping).
    pub times: Option<&'a [f64]>,
    /// Locate the events the system declares ([`NonholonomicSystem::EVENTS`]);
    /// a terminal one ends the run. `false` locates none, so the run costs
    /// what a run of a system without events costs.
    pub events: bool,
}

impl RunPlan<'_> {
    /// Checks that `members` runs of this plan, recording every
    /// `record_every`-th step at `bytes_per_sample` bytes a sample, fit
    /// within [`record_memory_limit`](crate::record_memory_limit), before
    /// they start: a run with output times records one sample per time,
    /// fixed steps their step count, a tolerance-driven run at most its
    /// step limit (`max_steps`), which the message names.
    pub fn check_record_size(&self, record_every: usize, members: usize, bytes_per_sample: u64) -> Result<(), String> {
        let (steps, every) = match (self.times, self.stepping) {
            (Some(times), _) => (times.len(), 1),
            (None, Stepping::Tolerance(tolerance)) => (tolerance.max_steps, record_every),
            (None, Stepping::Fixed { steps, .. }) => (steps, record_every),
        };
        check_record_size(steps, every, members, bytes_per_sample).map_err(|e| match (self.times, self.stepping) {
            (None, Stepping::Tolerance(_)) => {
                format!("{e} (a tolerance-driven run is counted at its step limit, max_steps: lower it)")
            }
            _ => e.to_string(),
        })
    }
}

/// A planned run's result: the trajectory (samples, report, located events)
/// and, for tolerance-driven steps, the controller's statistics.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedRun<const N: usize, const M: usize> {
    /// The recorded samples, the run's report and the located events.
    pub trajectory: Trajectory<N, M>,
    /// Accepted and rejected steps, solves and step sizes of a
    /// tolerance-driven run (`None` for fixed steps).
    pub controller: Option<AdaptiveReport>,
}

/// One located event without the system's dimension in its type: what a
/// front end returns (a row of `spark run`'s `events.csv`, a Python
/// `spark.Event`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EventRow {
    /// The event's name, as the system declares it.
    pub name: String,
    /// Its index among the system's events.
    pub index: usize,
    /// Whether the event function rose through zero (`false`: fell).
    pub rising: bool,
    /// Whether the event is terminal (when located, it ended the run).
    pub terminal: bool,
    /// Time of the zero.
    pub t: f64,
    /// Coordinates there.
    pub q: Vec<f64>,
    /// Velocities there.
    pub v: Vec<f64>,
    /// Index of the accepted step that holds it (0-based).
    pub step: usize,
}

/// The events a run of `Sys` located, as rows with each declaration's
/// terminal flag.
pub fn event_rows<Sys, const N: usize, const M: usize>(events: &[EventRecord<N>]) -> Vec<EventRow>
where
    Sys: NonholonomicSystem<N, M>,
{
    events
        .iter()
        .map(|e| EventRow {
            name: e.name.clone(),
            index: e.index,
            rising: e.rising,
            terminal: Sys::EVENTS.get(e.index).is_some_and(|spec| spec.terminal),
            t: e.t,
            q: e.q.iter().copied().collect(),
            v: e.v.iter().copied().collect(),
            step: e.step,
        })
        .collect()
}

/// Why a planned run failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// The plan asks for events of a system that declares none.
    #[error(
        "the system declares no events; declare them in its definition (`events: {{ name: rising(expr), … }}`) \
         or run without events"
    )]
    NoDeclaredEvents,
    /// An output time lies outside the run's interval.
    #[error(
        "output time t = {} lies outside the interval from t0 = {} to t_end = {}; give times within it",
        Sci(*t),
        Sci(*t0),
        Sci(*t_end)
    )]
    TimeOutsideInterval {
        /// The output time.
        t: f64,
        /// The start.
        t0: f64,
        /// The end of the interval.
        t_end: f64,
    },
    /// A fixed-step run failed.
    #[error(transparent)]
    Fixed(#[from] IntegrationError),
    /// A tolerance-driven run failed.
    #[error(transparent)]
    Tolerance(#[from] AdaptiveError),
}

/// Integrates from `(t₀, q₀, v₀)` as `plan` asks, with `options` (what to
/// record, `record_every` when the plan has no output times, the treatment
/// of an inconsistent `v₀`, and for fixed steps the failure policy) and
/// `observer` after every accepted step. The stepper's Newton options
/// apply to every step solve.
pub fn integrate_plan<Sys, O, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    plan: &RunPlan<'_>,
    options: &RunOptions,
    observer: &mut O,
) -> Result<PlannedRun<N, M>, PlanError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    if plan.events && !Sys::HAS_EVENTS {
        return Err(PlanError::NoDeclaredEvents);
    }
    if let Some(times) = plan.times {
        let t_end = plan.stepping.t_end(t0);
        let (low, high) = (t0.min(t_end), t0.max(t_end));
        if let Some(&t) = times.iter().find(|&&t| t.is_finite() && !(low..=high).contains(&t)) {
            return Err(PlanError::TimeOutsideInterval { t, t0, t_end });
        }
    }
    if plan.events {
        run_plan(stepper, t0, q0, v0, plan, options, observer, &SystemEvents::<M>)
    } else {
        run_plan(stepper, t0, q0, v0, plan, options, observer, &NoEvents)
    }
}

#[allow(clippy::too_many_arguments)]
fn run_plan<Sys, O, E, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    plan: &RunPlan<'_>,
    options: &RunOptions,
    observer: &mut O,
    events: &E,
) -> Result<PlannedRun<N, M>, PlanError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    E: EventFunctions<Sys, N>,
{
    match plan.stepping {
        Stepping::Fixed { h, steps } => {
            let schedule = match plan.times {
                Some(times) => Schedule::Sampled { h, times },
                None => Schedule::Fixed { h, steps },
            };
            let trajectory = stepper.integrate_with_events(t0, q0, v0, schedule, options, observer, events)?;
            Ok(PlannedRun { trajectory, controller: None })
        }
        Stepping::Tolerance(Tolerance { rtol, atol, first_step, max_step, max_steps, t_end }) => {
            let adaptive = AdaptiveOptions {
                rtol,
                atol,
                initial_step: first_step,
                max_step,
                max_steps,
                record_every: options.record_every,
                observe: options.observe,
                consistency: options.consistency,
                ..AdaptiveOptions::default()
            };
            let run = match plan.times {
                Some(times) => integrate_adaptive_at(stepper, t0, q0, v0, times, &adaptive, observer, events)?,
                None => integrate_adaptive_with_events(stepper, t0, q0, v0, t_end, &adaptive, observer, events)?,
            };
            Ok(PlannedRun { trajectory: run.trajectory, controller: Some(run.report) })
        }
    }
}
