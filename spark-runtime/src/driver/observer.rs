//! What sees every accepted step: the [`Observer`] trait, the empty
//! observer and closures as observers, and the object-safe view of an
//! observer the driver loop takes ([`StepObserver`]).

use crate::dense::DenseStep;
use crate::events::EventRecord;
use crate::step::State;
use crate::system::NonholonomicSystem;

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
    /// The observer watches the accepted steps ([`observe`](Self::observe)
    /// and [`stop_requested`](Self::stop_requested)). When `false` the
    /// driver calls neither ([`NoObserver`]); the default is `true`.
    const STEPS: bool = true;
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
    /// Called with each event the driver locates, in time order, as it is
    /// added to the run's [`Trajectory::events`](crate::Trajectory::events)
    /// (before [`observe`](Self::observe) sees the step it lies in). With
    /// [`stop_requested`](Self::stop_requested) it bounds what a run
    /// collects: the events of a run are kept in memory, and a front end can
    /// end a run whose events would not fit. The default ignores it.
    fn observe_event(&mut self, event: &EventRecord<N>) {
        let _ = event;
    }
    /// Asked after each accepted step, once [`observe`](Self::observe) has
    /// seen it: `true` ends the run there with
    /// [`IntegrationError::Stopped`](crate::IntegrationError::Stopped) (or
    /// [`AdaptiveError::Stopped`](crate::AdaptiveError::Stopped)). This is
    /// how a front end lets its user interrupt a long run; a run that should
    /// end at a state of the system declares a terminal event instead. The
    /// default never stops.
    fn stop_requested(&mut self) -> bool {
        false
    }
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl<const N: usize, const M: usize> Observer<N, M> for NoObserver {
    const STEPS: bool = false;
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, _: &State<N>, _: usize) {}
}

impl<const N: usize, const M: usize, F: FnMut(&State<N>, usize)> Observer<N, M> for F {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, state: &State<N>, iterations: usize) {
        self(state, iterations)
    }
}

/// What the driver loop sees of an [`Observer`] once the system and the
/// stage count are fixed. Object safe: the loop takes `&mut dyn
/// StepObserver`, so it is compiled once per system and method rather than
/// once for every observer type (each closure is a type of its own), at the
/// price of one indirect call per accepted step.
pub(crate) trait StepObserver<Sys, const N: usize, const M: usize, const S: usize> {
    /// [`Observer::DENSE`].
    fn wants_dense(&self) -> bool;
    /// [`Observer::STEPS`].
    fn wants_steps(&self) -> bool;
    /// [`Observer::observe`], then [`Observer::stop_requested`]: whether
    /// the run ends here.
    fn accepted(&mut self, system: &Sys, state: &State<N>, iterations: usize) -> bool;
    /// [`Observer::observe_dense`].
    fn dense_step(&mut self, step: &DenseStep<'_, N, S>);
    /// [`Observer::observe_event`].
    fn event(&mut self, event: &EventRecord<N>);
}

impl<Sys, O, const N: usize, const M: usize, const S: usize> StepObserver<Sys, N, M, S> for O
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
{
    fn wants_dense(&self) -> bool {
        O::DENSE
    }

    fn wants_steps(&self) -> bool {
        O::STEPS
    }

    fn accepted(&mut self, system: &Sys, state: &State<N>, iterations: usize) -> bool {
        self.observe(system, state, iterations);
        self.stop_requested()
    }

    fn dense_step(&mut self, step: &DenseStep<'_, N, S>) {
        self.observe_dense(step)
    }

    fn event(&mut self, event: &EventRecord<N>) {
        self.observe_event(event)
    }
}
