//! Events: zeros of scalar functions `g(t, q, v)` located on the dense output
//! of each accepted step.
//!
//! A system declares its events in the DSL (`events: { name: expr, … }`,
//! see [`nonholonomic_system!`](crate::nonholonomic_system)), which generates
//! [`NonholonomicSystem::HAS_EVENTS`], [`NonholonomicSystem::EVENTS`],
//! [`NonholonomicSystem::event_value`] and
//! [`NonholonomicSystem::event_gradient`]; a run can also take events given
//! at run time ([`EventFunctions`], [`Stepper::integrate_with_events`](crate::Stepper::integrate_with_events)).
//!
//! # Detection and location
//! After each accepted step the driver compares the sign of every event
//! function at `EVENT_SUBINTERVALS + 1` equally spaced points of the step
//! (the ends are the step's own states; the inner points come from the dense
//! output, [`DenseStep`]). A sign change on a subinterval `(a, b]` — or a
//! value exactly zero at `b` after a nonzero value at `a` — is a crossing;
//! its direction is rising when the function was negative before, in the
//! direction the run goes (a backward run reports a function that increases
//! with `t` as falling). A
//! crossing whose direction the event asks for is located by Newton's method
//! on `t ↦ g(t, q(t), v(t))` along the interpolant, with the derivative
//! `g_t + g_q·q̇ + g_v·v̇`, kept inside the bracket by bisection: any Newton
//! iterate outside the bracket, or a bracket that does not halve in two
//! iterations, is replaced by the midpoint. Location stops when the bracket
//! or the Newton update is below [`event_time_tolerance`]: `1e-13·|h|` of
//! the step `h` that holds the crossing, in whatever units `t` has, and never
//! below four units in the last place of `t` (what a double can resolve).
//!
//! The subintervals of consecutive steps share their end points and the
//! value at a step's end is carried into the next step unchanged, so a zero
//! at a step boundary is reported once, by the step that ends there, and a
//! sign change between two evaluated points is never lost. Two crossings of
//! the same function inside one subinterval cancel and are not seen,
//! however far apart within it (the usual limit of sign-based detection), so
//! crossings less than a quarter of a step apart can be missed; a
//! tolerance-driven run hands each step over as its two half steps, whose
//! subintervals are an eighth of the step. A zero at the run's start
//! is not reported (no step ends there), and a NaN value has no sign: a
//! subinterval with a NaN at either end shows no crossing. Crossings of one
//! step are reported in time order; a terminal event ends the run at its
//! time, with the interpolated state there.

use crate::dense::DenseStep;
use crate::system::{NonholonomicSystem, Vector};

pub use crate::system::{Direction, EventGradient, EventSpec};

/// Sign checks per step: the step is split into this many equal subintervals.
pub const EVENT_SUBINTERVALS: usize = 4;

/// Tolerance in `t` of an event location, as a fraction of the step that
/// holds the crossing (`tol·|h|`).
pub const EVENT_TIME_TOLERANCE: f64 = 1e-13;

/// The tolerance in `t` of an event located near `t` in a step of size `h`:
/// [`EVENT_TIME_TOLERANCE`]`·|h|`, and at least four units in the last place
/// of `t` (a bracket narrower than that cannot be formed). It is a fraction
/// of the step, not of a unit of time, so that a system stated in other
/// units of time has its events located alike.
pub fn event_time_tolerance(t: f64, h: f64) -> f64 {
    let t = t.abs();
    (EVENT_TIME_TOLERANCE * h.abs()).max(4.0 * (t.next_up() - t))
}

/// A set of event functions evaluated for a system `Sys`.
pub trait EventFunctions<Sys, const N: usize> {
    /// The declarations, in index order.
    fn specs(&self) -> &[EventSpec];
    /// `g_index(t, q, v)`.
    fn value(&self, system: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64;
    /// `g_index` with its derivatives.
    fn gradient(&self, system: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N>;
}

/// The events a system with `M` constraints declares ([`NonholonomicSystem::EVENTS`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemEvents<const M: usize>;

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize> EventFunctions<Sys, N> for SystemEvents<M> {
    fn specs(&self) -> &[EventSpec] {
        Sys::EVENTS
    }
    fn value(&self, system: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        system.event_value(index, t, q, v)
    }
    fn gradient(&self, system: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N> {
        system.event_gradient(index, t, q, v)
    }
}

/// No events (what a system without events runs with).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoEvents;

impl<Sys, const N: usize> EventFunctions<Sys, N> for NoEvents {
    fn specs(&self) -> &[EventSpec] {
        &[]
    }
    fn value(&self, _: &Sys, _: usize, _: f64, _: &Vector<N>, _: &Vector<N>) -> f64 {
        0.0
    }
    fn gradient(&self, _: &Sys, _: usize, _: f64, _: &Vector<N>, _: &Vector<N>) -> EventGradient<N> {
        EventGradient::zeros()
    }
}

/// Events given at run time: declarations with a function for the value and
/// one for the value with its derivatives.
pub struct RuntimeEvents<'a, const N: usize> {
    /// The declarations.
    pub specs: &'a [EventSpec],
    /// `(index, t, q, v) ↦ g_index(t, q, v)` with its derivatives.
    pub gradient: &'a dyn Fn(usize, f64, &Vector<N>, &Vector<N>) -> EventGradient<N>,
}

impl<Sys, const N: usize> EventFunctions<Sys, N> for RuntimeEvents<'_, N> {
    fn specs(&self) -> &[EventSpec] {
        self.specs
    }
    fn value(&self, _: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        (self.gradient)(index, t, q, v).value
    }
    fn gradient(&self, _: &Sys, index: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N> {
        (self.gradient)(index, t, q, v)
    }
}

/// One located event.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EventRecord<const N: usize> {
    /// Index of the event in its declarations.
    pub index: usize,
    /// Its name.
    pub name: String,
    /// Whether the function rose through zero (`false`: fell).
    pub rising: bool,
    /// Time of the zero.
    pub t: f64,
    /// Coordinates there (dense output).
    pub q: Vector<N>,
    /// Velocities there (dense output).
    pub v: Vector<N>,
    /// The event function's value there (after location; `≈ 0`).
    pub residual: f64,
    /// Index of the accepted step in which it was found (0-based).
    pub step: usize,
}

/// The most events a run of a system with events `specs` keeps when its
/// options set no limit: as many as fit in
/// [`record_memory_limit`](crate::record_memory_limit), at the bytes each
/// takes as an [`EventRecord`] and again as a front end's row of it
/// ([`EventRow`](crate::EventRow): its name, coordinates and velocities on
/// the heap). Unlike the samples, whose count is known before the run
/// starts, the events are counted as they are located.
pub fn max_located_events<const N: usize>(specs: &[EventSpec]) -> usize {
    let name = specs.iter().map(|spec| spec.name.len()).max().unwrap_or(0);
    let record = std::mem::size_of::<EventRecord<N>>() + name;
    let row = std::mem::size_of::<crate::EventRow>() + name + 2 * 8 * N;
    usize::try_from(crate::record_memory_limit() / (record + row) as u64).unwrap_or(usize::MAX)
}

/// The message of a run that located more than `max_events` events, one
/// more in the step from `t`; `option` names the limit's option
/// (`RunOptions::max_events` or `AdaptiveOptions::max_events`).
pub(crate) fn too_many_events(option: &str, max_events: usize, t: f64) -> String {
    format!(
        "the run located more than {max_events} events, the most it keeps ({option}; by default as \
         many as fit in 4 GiB or half the available memory), in the step from t = {}; run over a shorter interval, \
         or declare rarer events or a terminal one",
        crate::error::Sci(t)
    )
}

/// A crossing found inside one step, before it is turned into a record.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Crossing {
    pub(crate) index: usize,
    pub(crate) rising: bool,
    pub(crate) t: f64,
}

/// Locates the zero of event `index` on `(a, b]` (values `ga`, `gb` of
/// opposite sign, or `gb = 0`) along the dense output of `step`.
pub(crate) fn locate<Sys, E: EventFunctions<Sys, N> + ?Sized, const N: usize, const S: usize>(
    events: &E,
    system: &Sys,
    index: usize,
    step: &DenseStep<'_, N, S>,
    a: (f64, f64),
    b: (f64, f64),
) -> f64 {
    locate_zero(a, b, step.h, &mut |t| {
        let value = step.value_at(t);
        let g = events.gradient(system, index, t, &value.state.q, &value.state.v);
        (g.value, g.t + g.q.dot(&value.q_dot) + g.v.dot(&value.v_dot))
    })
}

/// The root finding of [`locate`] on the values it evaluates: `eval(t)` is
/// the event function and its time derivative along the dense output at `t`
/// (not generic: compiled once, not once per system and method).
fn locate_zero((a, ga): (f64, f64), (b, gb): (f64, f64), h: f64, eval: &mut dyn FnMut(f64) -> (f64, f64)) -> f64 {
    if gb == 0.0 {
        return b;
    }
    // Bracket [lo, hi] in increasing t with the sign at lo.
    let (mut lo, mut hi, g_lo) = if a < b { (a, b, ga) } else { (b, a, gb) };
    let negative_at_lo = g_lo < 0.0;
    // Secant start.
    let mut t = a - ga * (b - a) / (gb - ga);
    if !(t > lo && t < hi) {
        t = 0.5 * (lo + hi);
    }
    // Bracket widths of the previous two iterations: Newton is trusted while
    // the bracket at least halves every two iterations.
    let mut widths = [hi - lo; 2];
    for _ in 0..200 {
        let tol = event_time_tolerance(t, h);
        let (value, slope) = eval(t);
        if value == 0.0 {
            return t;
        }
        if (value < 0.0) == negative_at_lo {
            lo = t;
        } else {
            hi = t;
        }
        if hi - lo <= tol {
            return 0.5 * (lo + hi);
        }
        let stalled = hi - lo > 0.5 * widths[0];
        widths = [widths[1], hi - lo];
        let newton = t - value / slope;
        if newton.is_finite() && newton > lo && newton < hi && !stalled {
            if (newton - t).abs() <= tol {
                return newton;
            }
            t = newton;
        } else {
            t = 0.5 * (lo + hi);
        }
    }
    t
}
