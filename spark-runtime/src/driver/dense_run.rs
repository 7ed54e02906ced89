//! The continuous extension of a run's accepted (sub-)steps: event location,
//! the observer of the dense output and the `Sampled` output times. One home
//! for every driver: the fixed-step loop ([`Stepper::integrate`](crate::Stepper::integrate))
//! and the tolerance-driven and reversible runs ([`adaptive`](crate::adaptive))
//! hand each accepted step to [`DenseRun::accepted`].

use super::observer::StepObserver;
use super::trajectory::{sample_of, RunReport, Sample};
use super::Observe;
use crate::dense::{DenseBasis, DenseStep};
use crate::error::OptionError;
use crate::events::{
    locate, max_located_events, Crossing, EventFunctions, EventRecord, NoEvents, SystemEvents, EVENT_SUBINTERVALS,
};
use crate::step::{State, StepResult};
use crate::system::NonholonomicSystem;
use crate::tableau::Tableau;

/// The events a run of `Sys` locates by default: those it declares
/// ([`NonholonomicSystem::EVENTS`]), or [`NoEvents`] when it declares none
/// (decided at compile time by [`NonholonomicSystem::HAS_EVENTS`]).
pub(crate) fn declared_events<'a, Sys, const N: usize, const M: usize>() -> &'a dyn EventFunctions<Sys, N>
where
    Sys: NonholonomicSystem<N, M>,
{
    if Sys::HAS_EVENTS {
        &SystemEvents::<M>
    } else {
        &NoEvents
    }
}

/// One accepted sub-step of step `k` (the `k`-th scheduled step of a
/// fixed-step run, the `k`-th accepted step of an adaptive one): from
/// `start` to `end` (its time pinned when it ends the step) with size
/// `sub`; `iterations` counts the Newton iterations of the step so far.
pub(crate) struct Accepted<'a, const N: usize, const M: usize, const S: usize> {
    pub(crate) k: usize,
    pub(crate) iterations: usize,
    pub(crate) start: &'a State<N>,
    pub(crate) end: &'a State<N>,
    pub(crate) sub: f64,
    pub(crate) result: &'a StepResult<N, M, S>,
}

/// What a run keeps from step to step for the continuous extension of its
/// accepted sub-steps: the events it locates, the observer of the dense
/// output and the `Sampled` output times.
pub(crate) struct DenseRun<'a, Sys, const N: usize, const S: usize> {
    basis: DenseBasis<S>,
    events: &'a dyn EventFunctions<Sys, N>,
    /// Each event function's value at the end of the last accepted sub-step.
    previous: Vec<f64>,
    crossings: Vec<Crossing>,
    /// The events located so far, in time order.
    pub(crate) located: Vec<EventRecord<N>>,
    wants_dense: bool,
    sampled: Option<&'a [f64]>,
    /// The next of the `Sampled` times to record.
    next_time: usize,
    observe: Observe,
    /// The energy at the start, for the report's extremes.
    e0: Option<f64>,
    /// The state at the terminal event that ends the run, once located.
    pub(crate) terminal: Option<State<N>>,
    /// The most events the run keeps.
    pub(crate) max_events: usize,
    /// One more event than `max_events` was located: the run ends with an
    /// error at this step.
    pub(crate) too_many_events: bool,
}

/// Whether a run builds the continuous extension of its steps: for an
/// observer of the dense output, events, or `Schedule::Sampled` times.
pub(crate) fn needs_extension(wants_dense: bool, events: usize, sampled: bool) -> bool {
    wants_dense || events > 0 || sampled
}

/// What a run needs of its tableau before the first step
/// ([`Tableau::validate`]), and distinct nodes when it builds the
/// continuous extension ([`Tableau::validate_for_dense_output`]).
pub(crate) fn check_tableau<const S: usize>(
    tableau: &Tableau<S>,
    wants_dense: bool,
    events: usize,
    sampled: bool,
) -> Result<(), OptionError> {
    if needs_extension(wants_dense, events, sampled) {
        tableau.validate_for_dense_output()
    } else {
        tableau.validate()
    }
}

impl<'a, Sys, const N: usize, const S: usize> DenseRun<'a, Sys, N, S> {
    /// A run from `start` with the coefficients `tableau`, locating
    /// `events`, handing the extension to the observer when `wants_dense`
    /// and recording the `sampled` times (with `observe`; `e0` is the
    /// starting energy for the report's extremes).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new<const M: usize>(
        sys: &Sys,
        tableau: &Tableau<S>,
        events: &'a dyn EventFunctions<Sys, N>,
        wants_dense: bool,
        sampled: Option<&'a [f64]>,
        observe: Observe,
        e0: Option<f64>,
        start: &State<N>,
        max_events: Option<usize>,
    ) -> Self
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let specs = events.specs();
        DenseRun {
            basis: DenseBasis::new(tableau),
            events,
            previous: (0..specs.len()).map(|i| events.value(sys, i, start.t, &start.q, &start.v)).collect(),
            crossings: Vec::with_capacity(specs.len()),
            located: Vec::new(),
            wants_dense,
            sampled,
            next_time: 0,
            observe,
            e0,
            terminal: None,
            max_events: max_events.unwrap_or_else(|| if specs.is_empty() { 0 } else { max_located_events::<N>(specs) }),
            too_many_events: false,
        }
    }

    /// Whether the run needs the continuous extension at all: without
    /// events, an observer of the dense output or `Sampled` times,
    /// [`accepted`](Self::accepted) need not be called.
    pub(crate) fn is_needed(&self) -> bool {
        needs_extension(self.wants_dense, self.events.specs().len(), self.sampled.is_some())
    }

    /// The index of the terminal event that ended the run, if one did.
    pub(crate) fn terminal_event(&self) -> Option<usize> {
        self.terminal.and(self.located.last().map(|e| e.index))
    }

    /// Builds the continuous extension of sub-step `at`, locates the events
    /// in it, hands it to the observer of the dense output and records the
    /// `Sampled` times it covers. Returns `true` when a terminal event ends
    /// the run in it (the event's state is then [`Self::terminal`]), or
    /// when it holds one event more than the run keeps
    /// ([`Self::too_many_events`]: the driver ends the run with an error). Out of
    /// line: a run that needs none of this never calls it.
    #[inline(never)]
    pub(crate) fn accepted<const M: usize>(
        &mut self,
        sys: &Sys,
        at: Accepted<'_, N, M, S>,
        observer: &mut dyn StepObserver<Sys, N, M, S>,
        samples: &mut Vec<Sample<N, M>>,
        report: &mut RunReport,
    ) -> bool
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let events = self.events;
        let specs = events.specs();
        let piece = DenseStep::new(&self.basis, at.start, at.end, at.sub, at.result);
        let mut stop_at = None;
        if !specs.is_empty() {
            self.crossings.clear();
            find_crossings(events, sys, &piece, &mut self.previous, &mut self.crossings);
            for c in self.crossings.iter() {
                if self.located.len() >= self.max_events {
                    self.too_many_events = true;
                    return true;
                }
                let state = piece.state_at(c.t);
                let spec = &specs[c.index];
                let record = EventRecord {
                    index: c.index,
                    name: spec.name.to_string(),
                    rising: c.rising,
                    t: c.t,
                    q: state.q,
                    v: state.v,
                    residual: events.value(sys, c.index, state.t, &state.q, &state.v),
                    step: at.k,
                };
                observer.event(&record);
                self.located.push(record);
                if spec.terminal {
                    stop_at = Some(state);
                    break;
                }
            }
        }
        if self.wants_dense {
            // A terminal event ends the run inside this step: the
            // observer sees the extension up to the event only.
            match stop_at {
                Some(stop) => observer.dense_step(&piece.until(stop.t)),
                None => observer.dense_step(&piece),
            }
        }
        if let Some(times) = self.sampled {
            let forward = at.sub > 0.0;
            let limit = stop_at.map_or(at.end.t, |s| s.t);
            while let Some(&t) = times.get(self.next_time) {
                if (forward && t > limit) || (!forward && t < limit) {
                    break;
                }
                let s = sample_of(sys, &piece.state_at(t), &self.observe, at.iterations);
                report.track(&s, self.e0);
                samples.push(s);
                self.next_time += 1;
            }
        }
        if stop_at.is_some() {
            self.terminal = stop_at;
            return true;
        }
        false
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
            // A NaN has no sign: a subinterval with a NaN end shows no
            // crossing (NaN < 0 is false, which would read it as positive).
            let signed = !a.1.is_nan() && !b.1.is_nan();
            let crossed = signed && a.1 != 0.0 && (b.1 == 0.0 || (a.1 < 0.0) != (b.1 < 0.0));
            let rising = a.1 < 0.0;
            if crossed && spec.direction.accepts(rising) {
                let t = locate(events, sys, index, piece, a, b);
                crossings.push(Crossing { index, rising, t });
            }
            a = b;
        }
        previous[index] = a.1;
    }
    sort_in_time(crossings, tb > ta);
}

/// Orders `crossings` by time in the direction of the run (not generic:
/// compiled once, not once per system and method).
fn sort_in_time(crossings: &mut [Crossing], forward: bool) {
    crossings.sort_by(|x, y| {
        let order = x.t.total_cmp(&y.t);
        if forward {
            order
        } else {
            order.reverse()
        }
    });
}
