//! What the tolerance-driven and the reversible runs share around their
//! step-size rules: the checks before the first step, the recording of
//! accepted steps, and their continuous extension (events, the observer of
//! the dense output), which goes through the fixed-step driver's
//! [`DenseRun`] so that an accepted step is treated the same way by every
//! driver.

use super::{
    check_first_step, check_step_budget, resolution, AdaptiveError, AdaptiveOptions, AdaptiveReport, AdaptiveRun,
};
use crate::driver::{
    check_tableau, Accepted, DenseRun, Observe, Observer, RunReport, Sample, StepObserver, Trajectory,
};
use crate::events::EventFunctions;
use crate::initial::consistent_velocity;
use crate::step::{State, StepResult, Stepper};
use crate::system::{NonholonomicSystem, Vector};

/// Records samples, tracks the run's energy and constraint figures, and
/// carries the continuous extension of the accepted steps.
pub(super) struct Recorder<'a, Sys, const N: usize, const M: usize, const S: usize> {
    samples: Vec<Sample<N, M>>,
    run: RunReport,
    e0: Option<f64>,
    every: usize,
    observe: Observe,
    dense: DenseRun<'a, Sys, N, S>,
    /// Whether the run has events, an observer of the dense output or
    /// output times (otherwise no extension is built).
    dense_needed: bool,
    /// Whether the samples are output times taken from the continuous
    /// extension (then the accepted steps are not recorded).
    sampled: bool,
}

impl<Sys, const N: usize, const M: usize, const S: usize> Recorder<'_, Sys, N, M, S> {
    fn push(&mut self, s: Sample<N, M>) {
        self.run.track(&s, self.e0);
        self.samples.push(s);
    }
}

/// Where a tolerance-driven run records: at its accepted steps (per
/// `record_every`), or at output times taken from the continuous extension.
#[derive(Clone, Copy)]
pub(super) struct Output<'a> {
    pub(super) wants_dense: bool,
    pub(super) times: Option<&'a [f64]>,
}

/// Checks options and interval, projects `v₀` and prepares the stepper and
/// the continuous extension (`events`, the observer's when it wants it, the
/// output times).
#[allow(clippy::too_many_arguments)]
fn start<'a, Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    output: Output<'a>,
    events: &'a dyn EventFunctions<Sys, N>,
) -> Result<(State<N>, Recorder<'a, Sys, N, M, S>), AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let Output { wants_dense, times } = output;
    options.validate().map_err(AdaptiveError::InvalidOption)?;
    stepper.options().validate().map_err(AdaptiveError::InvalidOption)?;
    check_tableau(stepper.tableau(), wants_dense, events.specs().len(), times.is_some())
        .map_err(AdaptiveError::InvalidOption)?;
    if !t0.is_finite() || !t_end.is_finite() {
        return Err(AdaptiveError::InvalidInterval { t0, t_end, reason: "times must be finite" });
    }
    if t0 == t_end {
        return Err(AdaptiveError::InvalidInterval { t0, t_end, reason: "t_end must differ from t0" });
    }
    if !(t_end - t0).is_finite() {
        return Err(AdaptiveError::InvalidInterval {
            t0,
            t_end,
            reason: "t_end − t0 overflows f64 (above 1.8e308); integrate over a shorter interval",
        });
    }
    if (t_end - t0).abs() < resolution(t0) {
        return Err(AdaptiveError::InvalidInterval {
            t0,
            t_end,
            reason: "t_end − t0 is below the resolution of t at t0 (16 ulp of t0), the smallest step a run takes",
        });
    }
    check_step_budget(t0, t_end, options)?;
    check_first_step(t0, options)?;
    let v = consistent_velocity(stepper.system(), t0, q0, v0, options.consistency).map_err(AdaptiveError::Initial)?;
    stepper.reset_run();
    stepper.set_accepted_start_residual(options.consistency.tolerance());
    let state = State::new(t0, *q0, v);
    let first = stepper.sample(&state, &options.observe, 0);
    let e0 = first.energy;
    let dense = DenseRun::new(
        stepper.system(),
        stepper.tableau(),
        events,
        wants_dense,
        times,
        options.observe,
        e0,
        &state,
        options.max_events,
    );
    let mut rec = Recorder {
        samples: Vec::new(),
        run: RunReport { projected_initial_velocity: v != *v0, ..RunReport::default() },
        e0,
        every: options.record_every,
        observe: options.observe,
        dense_needed: dense.is_needed(),
        dense,
        sampled: times.is_some(),
    };
    rec.push(first);
    Ok((state, rec))
}

/// A whole run: [`start`], then the step-size rule `rule` from the start
/// state, then [`finish`]. The consistency tolerance `start` hands the
/// stepper (its accepted start residual) goes back to 0 whether the rule
/// succeeds or fails: it is 0 outside a run.
#[allow(clippy::too_many_arguments)]
pub(super) fn whole_run<Sys, R, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    options: &AdaptiveOptions,
    output: Output<'_>,
    events: &dyn EventFunctions<Sys, N>,
    rule: R,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    R: FnOnce(
        &mut Stepper<Sys, N, M, S, D>,
        State<N>,
        &mut Recorder<'_, Sys, N, M, S>,
    ) -> Result<AdaptiveReport, AdaptiveError>,
{
    let (state, mut rec) = start(stepper, t0, q0, v0, t_end, options, output, events)?;
    let result = rule(stepper, state, &mut rec);
    stepper.set_accepted_start_residual(0.0);
    let report = result?;
    Ok(finish::<Sys, N, M, S, D>(stepper, rec, report))
}

/// The finished run: the recorded samples, the report and the located events.
fn finish<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &Stepper<Sys, N, M, S, D>,
    mut rec: Recorder<'_, Sys, N, M, S>,
    report: AdaptiveReport,
) -> AdaptiveRun<N, M>
where
    Sys: NonholonomicSystem<N, M>,
{
    rec.run.steps = report.accepted;
    if rec.run.steps > 0 {
        rec.run.newton_iterations_mean = rec.run.newton_iterations_total as f64 / rec.run.steps as f64;
    }
    rec.run.events = rec.dense.located.len();
    let method = stepper.tableau().method;
    let events = std::mem::take(&mut rec.dense.located);
    AdaptiveRun { trajectory: Trajectory::of::<Sys>(method, S, rec.samples, rec.run, events), report }
}

/// An accepted step of magnitude `this` from `start`, taken as the pieces
/// `(size, result)` (one step, or the two half steps of a step with
/// estimate); the last piece ends the step. `last`: it lands on `t_end`.
pub(super) struct Taken<'r, const N: usize, const M: usize, const S: usize> {
    pub(super) start: State<N>,
    pub(super) pieces: &'r [(f64, &'r StepResult<N, M, S>)],
    pub(super) this: f64,
    pub(super) iterations: usize,
    pub(super) last: bool,
}

/// Accepts `step` (the last step lands exactly on `t_end`): hands each
/// piece's continuous extension to the events and the observer of the
/// dense output, counts the step in `report`, records and observes it.
/// Returns the state the next step starts from and whether the run ends
/// there (the last step, or a terminal event: then the state is the
/// event's, the step's last sample), or [`AdaptiveError::Stopped`] when
/// the observer asks to stop ([`Observer::stop_requested`]).
pub(super) fn accept<Sys, O, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    rec: &mut Recorder<'_, Sys, N, M, S>,
    observer: &mut O,
    report: &mut AdaptiveReport,
    step: Taken<'_, N, M, S>,
    t_end: f64,
) -> Result<(State<N>, bool), AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    let Some(&(_, result)) = step.pieces.last() else {
        return Ok((step.start, false));
    };
    let mut state = result.state;
    if step.last {
        state.t = t_end;
        stepper.retarget_warm_start(&state);
    }
    let terminal = rec.dense_needed && extend(stepper.system(), rec, observer, report.accepted, &step, &state);
    if rec.dense.too_many_events {
        let max_events = rec.dense.max_events;
        return Err(AdaptiveError::TooManyEvents { max_events, t: step.start.t, partial: Box::new(*report) });
    }
    let iterations = step.iterations;
    report.accepted += 1;
    report.smallest_step = report.smallest_step.min(step.this);
    report.largest_step = report.largest_step.max(step.this);
    let index = report.accepted;
    rec.run.newton_iterations_total += iterations;
    rec.run.newton_iterations_max = rec.run.newton_iterations_max.max(iterations);
    if let (true, Some(at)) = (terminal, rec.dense.terminal) {
        observer.observe(stepper.system(), &at, iterations);
        rec.run.terminal_event = rec.dense.terminal_event();
        // An output time at the event is its sample already.
        if !rec.sampled || !matches!(rec.samples.last(), Some(s) if s.t == at.t) {
            let s = stepper.sample(&at, &rec.observe, iterations);
            rec.push(s);
        }
        return Ok((at, true));
    }
    observer.observe(stepper.system(), &state, iterations);
    if !rec.sampled && (step.last || (rec.every != 0 && index.is_multiple_of(rec.every))) {
        let s = stepper.sample(&state, &rec.observe, iterations);
        rec.push(s);
    } else if rec.observe.energy || rec.observe.constraint_residual {
        // The report's extremes cover every accepted step, recorded or not
        // (as in a fixed-step run; the multipliers are not needed for them).
        let observe = Observe { multipliers: false, ..rec.observe };
        let s = stepper.sample(&state, &observe, iterations);
        rec.run.track(&s, rec.e0);
    }
    if !step.last && observer.stop_requested() {
        return Err(AdaptiveError::Stopped { t: state.t, partial: Box::new(*report) });
    }
    Ok((state, step.last))
}

/// The continuous extension of the pieces of accepted step `k`, the last
/// one ending at `end`: events located and the dense observer served as in
/// a fixed-step run ([`DenseRun::accepted`]). Whether a terminal event ends
/// the run in it.
fn extend<Sys, O, const N: usize, const M: usize, const S: usize>(
    sys: &Sys,
    rec: &mut Recorder<'_, Sys, N, M, S>,
    observer: &mut O,
    k: usize,
    step: &Taken<'_, N, M, S>,
    end: &State<N>,
) -> bool
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    let observer: &mut dyn StepObserver<Sys, N, M, S> = observer;
    let mut from = step.start;
    for (i, &(sub, result)) in step.pieces.iter().enumerate() {
        let to = if i + 1 == step.pieces.len() { *end } else { result.state };
        let at = Accepted { k, iterations: step.iterations, start: &from, end: &to, sub, result };
        if rec.dense.accepted(sys, at, observer, &mut rec.samples, &mut rec.run) {
            return true;
        }
        from = to;
    }
    false
}
