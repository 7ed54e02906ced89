//! Reversible steps for the symmetric methods (Hairer & Söderlind): step
//! sizes `h = ε/ρ` from a step density along the solution, with `ε` taken
//! once from the tolerances at the initial state.

use super::{
    accept, first_step, is_symmetric, on_time_grid, step_floor, whole_run, AdaptiveError, AdaptiveOptions,
    AdaptiveReport, AdaptiveRun, Output, Recorder, Taken,
};
use crate::driver::{declared_events, Observer};
use crate::events::EventFunctions;
use crate::initial::consistent_acceleration;
use crate::step::{State, Stepper};
use crate::system::{NonholonomicSystem, Vector};

/// Integrates from `(t₀, q₀, v₀)` to `t_end` (either direction) with the
/// reversible step-size rule of Hairer & Söderlind (module docs) for the
/// step density `density(t, q, v) > 0` (steps per unit time, up to the
/// scale `ε`; it should be even in `v` for reversibility). `ε` comes from
/// the tolerances of `options` at the initial state; the step sizes are not
/// error-controlled afterwards. The last step is shortened to land on
/// `t_end`, or stretched by less than `max(min_step, 16 ulp of t_end)` where
/// the rule's step would stop just short of it (the only step outside the
/// symmetric rule). Only the symmetric methods are accepted
/// ([`is_symmetric`]). `options.max_step`, when set,
/// bounds every step (it bounds the density from below, which keeps the
/// rule reversible).
///
/// The events the system declares are located in every step and the
/// observer of the dense output ([`Observer::DENSE`]) sees each step's
/// continuous extension, exactly as in [`Stepper::integrate`]; a terminal
/// event ends the run at its time.
#[allow(clippy::too_many_arguments)]
pub fn integrate_reversible<Sys, O, F, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    density: F,
    options: &AdaptiveOptions,
    observer: &mut O,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    F: Fn(f64, &Vector<N>, &Vector<N>) -> f64,
{
    let events = declared_events::<Sys, N, M>();
    reversible_run(stepper, t0, q0, v0, t_end, &density, options, observer, events)
}

/// [`integrate_reversible`] locating the events of `events` instead of the
/// system's own (e.g. [`RuntimeEvents`](crate::RuntimeEvents), or
/// [`NoEvents`](crate::NoEvents) to ignore the declared ones).
#[allow(clippy::too_many_arguments)]
pub fn integrate_reversible_with_events<Sys, O, F, E, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    density: F,
    options: &AdaptiveOptions,
    observer: &mut O,
    events: &E,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    F: Fn(f64, &Vector<N>, &Vector<N>) -> f64,
    E: EventFunctions<Sys, N>,
{
    reversible_run(stepper, t0, q0, v0, t_end, &density, options, observer, events)
}

#[allow(clippy::too_many_arguments)]
fn reversible_run<Sys, O, F, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    density: &F,
    options: &AdaptiveOptions,
    observer: &mut O,
    events: &dyn EventFunctions<Sys, N>,
) -> Result<AdaptiveRun<N, M>, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    F: Fn(f64, &Vector<N>, &Vector<N>) -> f64,
{
    let method = stepper.tableau().method;
    if !is_symmetric(method) {
        return Err(AdaptiveError::NotSymmetric { method });
    }
    whole_run(
        stepper,
        t0,
        q0,
        v0,
        t_end,
        options,
        Output { wants_dense: O::DENSE, times: None },
        events,
        |stepper, state, rec| reversible_loop(stepper, state, t_end, density, options, rec, observer),
    )
}

/// `σ(y)` and `G(y) = σ̇(y)/σ(y)`, the derivative along the flow by a central
/// difference in the direction `(1, v, a)`.
fn density_and_rate<Sys, F, const N: usize, const M: usize>(
    sys: &Sys,
    density: &F,
    state: &State<N>,
) -> Result<(f64, f64), AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    F: Fn(f64, &Vector<N>, &Vector<N>) -> f64,
{
    let sigma = density(state.t, &state.q, &state.v);
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(AdaptiveError::InvalidDensity { t: state.t, sigma });
    }
    let a = consistent_acceleration(sys, state.t, &state.q, &state.v).map_or(Vector::zeros(), |(a, _)| a);
    // A time increment of 1e-5 of the local time scale 1/σ: the central
    // difference errs by O(δ²) relative, far below what the rule needs.
    let delta = 1e-5 / sigma;
    let plus = density(state.t + delta, &(state.q + delta * state.v), &(state.v + delta * a));
    let minus = density(state.t - delta, &(state.q - delta * state.v), &(state.v - delta * a));
    let rate = (plus - minus) / (2.0 * delta * sigma);
    if !rate.is_finite() {
        return Err(AdaptiveError::InvalidDensity { t: state.t, sigma: if plus.is_finite() { minus } else { plus } });
    }
    Ok((sigma, rate))
}

/// The step size whose error estimate lies between ½ and 1 of the
/// tolerance at `state` (a few estimates, none kept), from which a
/// reversible run takes its scale `ε`.
///
/// Estimates above the tolerance shrink the step down to the floor, where
/// the run ends with [`AdaptiveError::StepSizeTooSmall`] as
/// [`integrate_adaptive`](super::integrate_adaptive) ends: a tolerance below
/// what round-off lets a step meet must not hand the run a scale it never
/// met. Growth is capped at [`MAX_GROWTHS`] rounds (noisy estimates can
/// step over the bracket back and forth); the step returned then is the
/// last one that met the tolerance.
fn calibrate_step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    state: &State<N>,
    dir: f64,
    max_step: f64,
    options: &AdaptiveOptions,
    report: &mut AdaptiveReport,
) -> Result<f64, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let k = (stepper.tableau().method.order_for(S, &Sys::STRUCTURE) + 1) as f64;
    let mut h = first_step(stepper.system(), state, options, max_step);
    // The last error estimate (∞ after a Newton failure; NaN before the first).
    let mut last_err = f64::NAN;
    let mut growths = 0;
    loop {
        let floor = step_floor(options, state.t);
        if h < floor {
            return Err(AdaptiveError::too_small(state.t, h, floor, last_err, None, *report));
        }
        match stepper.step_with_estimate(state, dir * h, options.rtol, options.atol) {
            Ok(est) => {
                report.solves += 3;
                report.newton_iterations += est.iterations;
                let err = est.scaled_error;
                last_err = err;
                if err > 1.0 {
                    h *= (options.safety * err.powf(-1.0 / k)).clamp(options.min_factor, 1.0);
                } else if err < 0.5 && h < max_step && growths < MAX_GROWTHS {
                    growths += 1;
                    let grow = if err == 0.0 { options.max_factor } else { options.safety * err.powf(-1.0 / k) };
                    h = (h * grow.clamp(1.0, options.max_factor)).min(max_step);
                } else {
                    break;
                }
            }
            Err(f) => {
                report.solves += f.solves + 1;
                if !f.error.is_curable() {
                    return Err(AdaptiveError::Step { t: state.t, source: f.error, partial: Box::new(*report) });
                }
                report.newton_failures += 1;
                last_err = f64::INFINITY;
                h *= 0.25;
            }
        }
        stepper.reset_run();
    }
    Ok(h)
}

/// Rounds of [`calibrate_step`] that grow the step.
const MAX_GROWTHS: usize = 30;

fn reversible_loop<Sys, O, F, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    mut state: State<N>,
    t_end: f64,
    density: &F,
    options: &AdaptiveOptions,
    rec: &mut Recorder<'_, Sys, N, M, S>,
    observer: &mut O,
) -> Result<AdaptiveReport, AdaptiveError>
where
    Sys: NonholonomicSystem<N, M>,
    O: Observer<N, M>,
    F: Fn(f64, &Vector<N>, &Vector<N>) -> f64,
{
    let dir = (t_end - state.t).signum();
    let span = (t_end - state.t).abs();
    let max_step = options.max_step.unwrap_or(span).min(span);
    let mut report = AdaptiveReport { smallest_step: f64::INFINITY, ..AdaptiveReport::default() };
    let h = calibrate_step(stepper, &state, dir, max_step, options, &mut report)?;
    stepper.reset_run();
    let (sigma0, g0) = density_and_rate(stepper.system(), density, &state)?;
    let epsilon = h * sigma0;
    report.epsilon = epsilon;
    // Lower bound of ρ that keeps every step within max_step.
    let rho_min = epsilon / max_step;
    let mut rho = sigma0 + 0.5 * epsilon * dir * g0;
    let mut attempts = 0usize;
    loop {
        let h = epsilon / rho.max(rho_min);
        let remaining = (t_end - state.t).abs();
        let floor = step_floor(options, state.t);
        // Land on t_end; a step that would leave less than the smallest
        // step behind (t accumulated in steps of 0.1 reaches 0.9999999999999999,
        // not 1) is stretched to t_end instead.
        let last = h >= remaining || remaining - h < step_floor(options, t_end);
        let this = if last { remaining } else { h };
        if this.is_nan() || this < floor {
            return Err(AdaptiveError::too_small(state.t, this, floor, f64::NAN, None, report));
        }
        // After the floor's test, as in the error-controlled loop.
        let this = if last { this } else { on_time_grid(state.t, dir * this).abs() };
        if attempts >= options.max_steps {
            return Err(AdaptiveError::too_many(attempts, state.t, t_end, report));
        }
        attempts += 1;
        report.solves += 1;
        let r = stepper.step_or_fail(&state, dir * this).map_err(|source| {
            let partial = Box::new(report);
            AdaptiveError::Step { t: state.t, source, partial }
        })?;
        report.newton_iterations += r.iterations;
        let pieces = [(dir * this, &r)];
        let taken = Taken { start: state, pieces: &pieces, this, iterations: r.iterations, last };
        let done;
        (state, done) = accept(stepper, rec, observer, &mut report, taken, t_end)?;
        if done {
            return Ok(report);
        }
        // The reversed run walks t backwards, so G changes sign with dir.
        let (_, g) = density_and_rate(stepper.system(), density, &state)?;
        rho += epsilon * dir * g;
    }
}
