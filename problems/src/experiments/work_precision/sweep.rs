//! The sweeps of one system: each `(method, s)` of the generated stepper
//! over step counts (fixed steps) and tolerances (adaptive), the same
//! stepper with num-dual and finite-difference derivatives, and DOP853, each
//! point timed by the median of repeats on the thread-CPU clock.

use super::{Point, Provider, WorkPrecisionConfig, WorkPrecisionError, SPARK_ADAPTIVE, SPARK_REVERSIBLE};
use crate::catalog::{Dispatch, StageVisitor};
use crate::peers::dual::{AutoDiff, DualTwin};
use crate::peers::finite_difference::FiniteDifference;
use crate::peers::ode;
use crate::report::clock::median_time;
use spark_runtime::{
    adaptive::is_symmetric, integrate_adaptive_with_events, integrate_reversible_with_events, AdaptiveError,
    AdaptiveOptions, AdaptiveRun, Method, NewtonOptions, NoEvents, NoObserver, NonholonomicSystem, Observe, RunOptions,
    Schedule, State, Stepper, Tableau, Vector,
};
use std::marker::PhantomData;

pub(super) fn errors<const N: usize>(q: &Vector<N>, v: &Vector<N>, q_ref: &Vector<N>, v_ref: &Vector<N>) -> (f64, f64) {
    ((q - q_ref).amax(), (v - v_ref).amax())
}

/// The context of one system's sweep.
pub(super) struct Ctx<'a, const N: usize> {
    pub(super) cfg: &'a WorkPrecisionConfig,
    pub(super) key: &'static str,
    pub(super) q0: Vector<N>,
    pub(super) v0: Vector<N>,
    pub(super) q_ref: Vector<N>,
    pub(super) v_ref: Vector<N>,
    /// The step density of the reversible runs ([`super::step_density`]).
    pub(super) density: Option<&'a super::DensityFn>,
}

/// Run options of a timed run: no observation, nothing recorded, and no
/// halving: a point of the diagram is a run of fixed steps `h` or none (a
/// halved step would put the error and time of smaller steps at `h`).
pub(super) fn unobserved() -> RunOptions {
    RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        max_halvings: 0,
        ..RunOptions::default()
    }
}

/// What one timed stepper run measured.
pub(super) struct Measured {
    pub(super) error_q: f64,
    pub(super) error_v: f64,
    pub(super) energy: f64,
    pub(super) iterations: f64,
    pub(super) wall: f64,
    pub(super) cpu: f64,
    pub(super) repeats: usize,
}

/// Runs `steps` steps of `stepper` once with energy observation (the
/// measured point's errors) and then times it; `None` if Newton failed.
pub(super) fn measure_stepper<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    ctx: &Ctx<'_, N>,
    stepper: &mut Stepper<Sys, N, M, S, D>,
    probe: &Sys,
    steps: usize,
) -> Option<Measured>
where
    Sys: NonholonomicSystem<N, M>,
{
    let h = ctx.cfg.final_time / steps as f64;
    let e0 = probe.energy(0.0, &ctx.q0, &ctx.v0);
    let mut max_e: f64 = 0.0;
    let mut observer = |s: &State<N>, _: usize| {
        max_e = max_e.max((probe.energy(s.t, &s.q, &s.v) - e0).abs());
    };
    let quiet = unobserved();
    let schedule = Schedule::Fixed { h, steps };
    // Timed without event location, like the peers: declared events are
    // for `spark section`.
    let traj = stepper
        .integrate_with_events(0.0, &ctx.q0, &ctx.v0, schedule, &quiet, &mut observer, &spark_runtime::NoEvents)
        .ok()?;
    let end = traj.last()?;
    let (eq, ev) = errors(&end.q, &end.v, &ctx.q_ref, &ctx.v_ref);
    if !(eq.is_finite() && ev.is_finite()) {
        return None;
    }
    let iterations = traj.report.newton_iterations_mean;
    let (wall, cpu, repeats) = median_time(ctx.cfg.repeats, ctx.cfg.min_timing, || {
        stepper
            .integrate_with_events(0.0, &ctx.q0, &ctx.v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents)
            .is_ok()
    })?;
    Some(Measured { error_q: eq, error_v: ev, energy: max_e, iterations, wall, cpu, repeats })
}

/// Step counts `n₀·2^k` up to the configured maximum (and to the largest
/// that fits in `usize`, for a maximum near `usize::MAX`).
pub(super) fn step_counts(cfg: &WorkPrecisionConfig) -> Vec<usize> {
    let mut v = Vec::new();
    let mut n = Some(cfg.min_steps.max(1));
    while let Some(steps) = n.filter(|&n| n <= cfg.max_steps) {
        v.push(steps);
        n = steps.checked_mul(2);
    }
    v
}

/// Builds a [`Point`] from one measured run.
pub(super) fn point<const N: usize>(
    ctx: &Ctx<'_, N>,
    solver: &str,
    label: &str,
    stages: usize,
    steps: usize,
    m: Measured,
) -> Point {
    let mut p = Point {
        system: ctx.key.to_string(),
        solver: solver.to_string(),
        method: label.to_string(),
        stages,
        setting: ctx.cfg.final_time / steps as f64,
        steps,
        error_q: m.error_q,
        error_v: m.error_v,
        energy_error: m.energy,
        wall_time: m.wall,
        cpu_time: m.cpu,
        time_per_step: 0.0,
        newton_iterations: m.iterations,
        repeats: m.repeats,
    };
    p.time_per_step = p.time() / steps as f64;
    p
}

/// Sweeps one `(method, S)` with the generated code over the step counts
/// and returns the step counts it measured (the peers reuse them, so they
/// run at equal accuracy).
pub(super) fn sweep_generated<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    ctx: &Ctx<'_, N>,
    method: Method,
    points: &mut Vec<Point>,
) -> Result<Vec<usize>, WorkPrecisionError>
where
    Sys: Dispatch<N, M>,
{
    let tableau = Tableau::<S>::new(method)?;
    let label = method.label(S);
    let opts = NewtonOptions { mode: ctx.cfg.newton, ..NewtonOptions::default() };
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(Sys::default(), tableau).with_options(opts);
    let probe = Sys::default();
    let mut used = Vec::new();
    for steps in step_counts(ctx.cfg) {
        let Some(m) = measure_stepper(ctx, &mut stepper, &probe, steps) else { continue };
        let p = point(ctx, Provider::Generated.label(), &label, S, steps, m);
        used.push(steps);
        let stop = p.error() < ctx.cfg.floor_error || p.time() > ctx.cfg.max_run_time.as_secs_f64();
        points.push(p);
        if stop {
            break;
        }
    }
    sweep_adaptive(ctx, &mut stepper, &probe, &label, points);
    if let Some(density) = ctx.density.filter(|_| is_symmetric(method)) {
        // The branch is on a constant: the reversible driver is compiled
        // only for the systems the catalogue marks `steps: reversible`.
        if !Sys::REVERSIBLE_STEPS {
            return Err(WorkPrecisionError::Invalid(format!(
                "`{}` has a step density, but its catalogue entry is not marked `steps: reversible`",
                ctx.key
            )));
        }
        sweep_reversible(ctx, &mut stepper, &probe, &label, density, points);
    }
    Ok(used)
}

/// Sweeps the tolerance-driven driver over the configured tolerances
/// (`rtol = atol`), stopping like the fixed-step sweep at the error floor
/// or the run-time limit.
pub(super) fn sweep_adaptive<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    ctx: &Ctx<'_, N>,
    stepper: &mut Stepper<Sys, N, M, S, D>,
    probe: &Sys,
    label: &str,
    points: &mut Vec<Point>,
) where
    Sys: NonholonomicSystem<N, M>,
{
    let t1 = ctx.cfg.final_time;
    let (q0, v0) = (ctx.q0, ctx.v0);
    let energy = |s: &State<N>| probe.energy(s.t, &s.q, &s.v);
    sweep_tolerances(ctx, &energy, (label, S), SPARK_ADAPTIVE, points, &mut |options, mut observer| {
        // Like the fixed-step sweeps: no events (a declared section event
        // would add its location to the timed work).
        integrate_adaptive_with_events(stepper, 0.0, &q0, &v0, t1, options, &mut observer, &NoEvents)
    });
}

/// Sweeps the reversible step-size rule over the configured tolerances (the
/// tolerance fixes the scale `ε` at the initial state), like
/// [`sweep_adaptive`]. Steps are bounded by the fixed-step sweep's largest,
/// `T/n₀`: the scale is calibrated at the initial state only, and a loose
/// tolerance there can ask for a step the rest of the run cannot take.
pub(super) fn sweep_reversible<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    ctx: &Ctx<'_, N>,
    stepper: &mut Stepper<Sys, N, M, S, D>,
    probe: &Sys,
    label: &str,
    density: &super::DensityFn,
    points: &mut Vec<Point>,
) where
    Sys: NonholonomicSystem<N, M>,
{
    let t1 = ctx.cfg.final_time;
    let (q0, v0) = (ctx.q0, ctx.v0);
    let sigma = |_: f64, q: &Vector<N>, _: &Vector<N>| density(q.as_slice());
    let max_step = t1 / ctx.cfg.min_steps.max(1) as f64;
    let energy = |s: &State<N>| probe.energy(s.t, &s.q, &s.v);
    sweep_tolerances(ctx, &energy, (label, S), SPARK_REVERSIBLE, points, &mut |options, mut observer| {
        let options = AdaptiveOptions { max_step: Some(max_step), ..*options };
        integrate_reversible_with_events(stepper, 0.0, &q0, &v0, t1, sigma, &options, &mut observer, &NoEvents)
    });
}

/// One observer type for the measured and the timed runs of
/// [`sweep_tolerances`]: the largest energy error, or nothing.
type EnergyObserver<'o, const N: usize> = &'o mut dyn FnMut(&State<N>, usize);

/// Runs `drive` (one tolerance-driven integration over `[0, T]`) at each
/// configured tolerance: once observing the energy (the point's errors),
/// then timed unobserved; stops at the error floor, the run-time limit, or
/// the first tolerance the driver cannot meet within the fixed-step sweep's
/// step budget (every tighter one needs more steps). A run that fails
/// otherwise (a Newton failure, a step below the smallest allowed) skips its
/// tolerance only. `energy` is the system's energy at a state; `(label,
/// stages)` name the method. Generic in the dimensions only: compiled once
/// per `(N, M)`, not once per system and method.
fn sweep_tolerances<const N: usize, const M: usize>(
    ctx: &Ctx<'_, N>,
    energy: &dyn Fn(&State<N>) -> f64,
    (label, stages): (&str, usize),
    solver: &str,
    points: &mut Vec<Point>,
    drive: &mut dyn FnMut(&AdaptiveOptions, EnergyObserver<'_, N>) -> Result<AdaptiveRun<N, M>, AdaptiveError>,
) {
    let e0 = energy(&State::new(0.0, ctx.q0, ctx.v0));
    let quiet = AdaptiveOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..AdaptiveOptions::default()
    };
    for &tol in &ctx.cfg.tolerances {
        // The step budget of the fixed-step sweep; a tolerance that needs
        // more, and every tighter one, is not measured.
        let options = AdaptiveOptions { rtol: tol, atol: tol, max_steps: ctx.cfg.max_steps.max(1), ..quiet };
        let mut max_e: f64 = 0.0;
        let mut observer = |s: &State<N>, _: usize| {
            max_e = max_e.max((energy(s) - e0).abs());
        };
        let run = match drive(&options, &mut observer) {
            Ok(run) => run,
            Err(AdaptiveError::TooManySteps { .. }) => break,
            Err(_) => continue,
        };
        let Some(end) = run.trajectory.last() else { continue };
        let (eq, ev) = errors(&end.q, &end.v, &ctx.q_ref, &ctx.v_ref);
        if !(eq.is_finite() && ev.is_finite()) {
            continue;
        }
        let Some((wall, cpu, repeats)) = median_time(ctx.cfg.repeats, ctx.cfg.min_timing, || {
            drive(&options, &mut |_: &State<N>, _: usize| {}).is_ok()
        }) else {
            continue;
        };
        let m = Measured {
            error_q: eq,
            error_v: ev,
            energy: max_e,
            iterations: run.report.newton_iterations as f64 / run.report.solves.max(1) as f64,
            wall,
            cpu,
            repeats,
        };
        let mut p = point(ctx, solver, label, stages, run.report.accepted, m);
        p.setting = tol;
        let stop = p.error() < ctx.cfg.floor_error || p.time() > ctx.cfg.max_run_time.as_secs_f64();
        points.push(p);
        if stop {
            break;
        }
    }
}

/// The same stepper with num-dual and with finite-difference derivatives,
/// at the step counts the generated sweep used.
pub(super) fn sweep_peers<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    ctx: &Ctx<'_, N>,
    method: Method,
    used: &[usize],
    points: &mut Vec<Point>,
) -> Result<(), WorkPrecisionError>
where
    Sys: NonholonomicSystem<N, M> + DualTwin<N, M> + Default + Clone,
{
    let tableau = Tableau::<S>::new(method)?;
    let label = method.label(S);
    let twin = <Sys as DualTwin<N, M>>::Twin::default();
    let opts = NewtonOptions { mode: ctx.cfg.newton, ..NewtonOptions::default() };
    let mut ad = Stepper::<AutoDiff<_>, N, M, S, D>::new(AutoDiff(twin), tableau).with_options(opts);
    let ad_probe = AutoDiff(<Sys as DualTwin<N, M>>::Twin::default());
    let mut fd =
        Stepper::<FiniteDifference<Sys>, N, M, S, D>::new(FiniteDifference(Sys::default()), tableau).with_options(opts);
    let fd_probe = FiniteDifference(Sys::default());
    for &steps in used {
        if let Some(m) = measure_stepper(ctx, &mut ad, &ad_probe, steps) {
            points.push(point(ctx, Provider::NumDual.label(), &label, S, steps, m));
        }
        if let Some(m) = measure_stepper(ctx, &mut fd, &fd_probe, steps) {
            points.push(point(ctx, Provider::FiniteDifference.label(), &label, S, steps, m));
        }
    }
    Ok(())
}

/// One `(method, S)` sweep of `Sys` through the catalogue's stage dispatch;
/// `PEERS` adds the num-dual and finite-difference runs (only for types
/// with a num-dual twin, see [`SweepWithPeers`]).
pub(super) struct Sweep<'c, 'p, Sys, const N: usize> {
    pub(super) ctx: &'c Ctx<'c, N>,
    pub(super) method: Method,
    pub(super) points: &'p mut Vec<Point>,
    pub(super) system: PhantomData<Sys>,
}

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for Sweep<'_, '_, Sys, N> {
    type Output = Result<(), WorkPrecisionError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        sweep_generated::<Sys, N, M, S, D>(self.ctx, self.method, self.points).map(|_| ())
    }
}

/// [`Sweep`] plus the same-stepper peers.
pub(super) struct SweepWithPeers<'c, 'p, Sys, const N: usize>(pub(super) Sweep<'c, 'p, Sys, N>);

impl<Sys: Dispatch<N, M> + DualTwin<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M>
    for SweepWithPeers<'_, '_, Sys, N>
{
    type Output = Result<(), WorkPrecisionError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        let Sweep { ctx, method, points, .. } = self.0;
        let used = sweep_generated::<Sys, N, M, S, D>(ctx, method, points)?;
        sweep_peers::<Sys, N, M, S, D>(ctx, method, &used, points)
    }
}

/// Sweeps DOP853 (`ode_solvers`) over the configured tolerances.
pub(super) fn sweep_dop853<Sys, const N: usize, const M: usize, const Y: usize>(
    ctx: &Ctx<'_, N>,
    points: &mut Vec<Point>,
) where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let sys = Sys::default();
    let t1 = ctx.cfg.final_time;
    for &tol in &ctx.cfg.tolerances {
        let Ok(run) = ode::dop853::<Sys, N, M, Y>(&sys, 0.0, &ctx.q0, &ctx.v0, t1, tol, tol) else { continue };
        let (eq, ev) = errors(&run.q, &run.v, &ctx.q_ref, &ctx.v_ref);
        let Some((wall, cpu, repeats)) = median_time(ctx.cfg.repeats, ctx.cfg.min_timing, || {
            ode::dop853::<Sys, N, M, Y>(&sys, 0.0, &ctx.q0, &ctx.v0, t1, tol, tol).is_ok()
        }) else {
            continue;
        };
        let mut p = Point {
            system: ctx.key.to_string(),
            solver: "ode_solvers (Rust)".into(),
            method: "DOP853".into(),
            stages: 0,
            setting: tol,
            steps: run.steps,
            error_q: eq,
            error_v: ev,
            energy_error: f64::NAN,
            wall_time: wall,
            cpu_time: cpu,
            time_per_step: 0.0,
            newton_iterations: f64::NAN,
            repeats,
        };
        p.time_per_step = p.time() / run.steps.max(1) as f64;
        points.push(p);
    }
}
