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
use crate::driver::{
    check_record_size, check_step_size, recorded_steps, IntegrationError, Observer, RunOptions, Schedule, Trajectory,
};
use crate::error::Exact;
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
    /// Tolerance-driven steps when a `tolerance` is given, else `steps`
    /// fixed steps of size `h`: how a front end's request (`spark run`'s
    /// flags, Python's keyword arguments) names its steps.
    pub fn new(h: f64, steps: usize, tolerance: Option<Tolerance>) -> Self {
        match tolerance {
            Some(tolerance) => Stepping::Tolerance(tolerance),
            None => Stepping::Fixed { h, steps },
        }
    }

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
    /// The checks of the steps of a run from `t0` that need no system, in
    /// the words every front end shares: a finite `t0`; for fixed steps a
    /// step size that [`check_step_size`] accepts; for a tolerance a finite
    /// `t_end` other than `t0` and at least one step attempt.
    pub fn check_steps(&self, t0: f64) -> Result<(), String> {
        if !t0.is_finite() {
            return Err(format!("initial time t0 = {t0:.3e} must be finite"));
        }
        match self.stepping {
            Stepping::Fixed { h, .. } => {
                if !(h.is_finite() && h != 0.0) {
                    return Err(format!("step size h = {h:.3e} must be finite and nonzero"));
                }
                check_step_size(t0, h).map_err(|why| format!("step size h = {h:.3e} from t0 = {t0:.3e}: {why}"))?;
            }
            Stepping::Tolerance(tolerance) => {
                if !tolerance.t_end.is_finite() || tolerance.t_end == t0 {
                    return Err(format!(
                        "a tolerance-driven run needs a finite t_end other than t0 = {t0:.3e} (got {:.3e})",
                        tolerance.t_end
                    ));
                }
                if tolerance.max_steps == 0 {
                    return Err("max_steps must be at least 1".into());
                }
            }
        }
        Ok(())
    }

    /// The times a run of this plan from `t0` records at when it runs to
    /// its end, recording every `record_every`-th step: `t0` and each
    /// output time, or for fixed steps `t0` and the scheduled end
    /// `t0 + (k+1)·h` of every step [`Stepper::integrate`] records. `None`
    /// for tolerance-driven steps without output times, which record at
    /// steps chosen as the run goes. For front ends that lay several runs
    /// on one time axis (the Python package's ensembles with events).
    pub fn recorded_times(&self, t0: f64, record_every: usize) -> Option<Vec<f64>> {
        match (self.times, self.stepping) {
            (Some(times), _) => Some(std::iter::once(t0).chain(times.iter().copied()).collect()),
            (None, Stepping::Tolerance(_)) => None,
            (None, Stepping::Fixed { h, steps }) => {
                let schedule = Schedule::Fixed { h, steps };
                let ends = recorded_steps(steps, record_every).map(|k| schedule.step(k, steps, t0, t0).1);
                Some(std::iter::once(t0).chain(ends).collect())
            }
        }
    }

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
        Exact(*t),
        Exact(*t0),
        Exact(*t_end)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn fixed(h: f64) -> RunPlan<'static> {
        RunPlan { stepping: Stepping::new(h, 10, None), times: None, events: false }
    }

    fn tolerance(t_end: f64, max_steps: usize) -> RunPlan<'static> {
        let tolerance = Tolerance { rtol: 1e-6, atol: 1e-6, first_step: None, max_step: None, max_steps, t_end };
        RunPlan { stepping: Stepping::new(f64::NAN, 0, Some(tolerance)), times: None, events: false }
    }

    /// Each refusal names the value and what to give instead; the step size
    /// and `steps` of a tolerance-driven request are not read.
    #[test]
    fn check_steps_refuses_what_no_system_can_run() {
        let refused = |plan: RunPlan<'_>, t0: f64| plan.check_steps(t0).expect_err("refused");
        assert!(refused(fixed(0.1), f64::NAN).contains("initial time t0 = NaN must be finite"));
        assert!(refused(fixed(0.0), 0.0).contains("step size h = 0.000e0 must be finite and nonzero"));
        assert!(refused(fixed(f64::INFINITY), 0.0).contains("must be finite and nonzero"));
        assert!(refused(fixed(1e-310), 0.0).contains("subnormal"));
        assert!(refused(fixed(1e-20), 1e10).contains("from t0 = 1.000e10"));
        assert!(refused(tolerance(1.0, 100), 1.0).contains("finite t_end other than t0 = 1.000e0 (got 1.000e0)"));
        assert!(refused(tolerance(f64::INFINITY, 100), 0.0).contains("finite t_end"));
        assert_eq!(refused(tolerance(1.0, 0), 0.0), "max_steps must be at least 1");
        assert_eq!(fixed(-0.1).check_steps(3.0), Ok(()));
        assert_eq!(tolerance(-1.0, 1).check_steps(0.0), Ok(()));
    }

    #[test]
    fn stepping_is_tolerance_driven_when_a_tolerance_is_given() {
        assert_eq!(Stepping::new(0.5, 4, None), Stepping::Fixed { h: 0.5, steps: 4 });
        assert_eq!(Stepping::new(0.5, 4, None).t_end(1.0), 3.0);
        let Stepping::Tolerance(t) = tolerance(2.0, 7).stepping else { panic!("a tolerance-driven plan") };
        assert_eq!(Stepping::new(0.5, 4, Some(t)).t_end(1.0), 2.0);
    }
}
