//! The generic part of spark's Python bindings: one integration run and one
//! ensemble for any system type with literal `N`, `M`, `S`, `D`, the
//! conversion of requests (Python dicts) and results (NumPy arrays), and the
//! [`export_system!`] macro that turns a declared system into a Python
//! extension module.
//!
//! Every module built by `spark.compile` runs its one system with
//! [`integrate`] and [`ensemble`]. The `spark` extension module runs the
//! registered systems with `problems::run` (the code `spark run` uses,
//! compiled once in the `problems` crate) and shares this crate's request
//! parsing and result conversion, so both kinds of module read the same
//! requests and return the same dicts. The static facts `info()` shows are
//! in `facts`.

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::IntoPyArray;
use pyo3::exceptions::{PyOverflowError, PyTypeError, PyUnicodeEncodeError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use rayon::prelude::*;
use spark_runtime::{
    check_positive_kinetic_energy, consistent_velocity, event_rows, integrate_ensemble_until, integrate_plan,
    AdaptiveReport, ConsistencyPolicy, EnsembleRun, EventRow, Method, NewtonMode, NewtonOptions, NonholonomicSystem,
    Observe, Observer, RunOptions, RunPlan, Sample, State, StepError, Stepper, Stepping, Tableau, TableauError,
    Tolerance, Vector, DEFAULT_MAX_HALVINGS, MAX_HALVINGS,
};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, RecvTimeoutError};
use std::time::Duration;

mod facts;
pub use facts::{facts_to_py, system_info, SystemFacts};

pub use numpy;
pub use pyo3;

/// Largest `|g(t0, q0)|` accepted for a holonomic constraint (as `spark run`).
const POSITION_TOLERANCE: f64 = 1e-10;

/// Tolerance of the projection of an inconsistent `v0` (as `spark run --project-v0`).
pub const PROJECTION_TOLERANCE: f64 = 1e-12;

use spark_runtime::MAX_ENSEMBLE_THREADS as MAX_THREADS;

fn too_many_threads(t: i64) -> Failure {
    format!(
        "threads = {t} is more than {MAX_THREADS}, the most an ensemble starts; give 1 ≤ threads ≤ {MAX_THREADS} (at \
         most the number of cores)"
    )
}

/// One integration run, as read from the Python side.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegrateRequest {
    /// The method.
    pub method: Method,
    /// Stage count `s`.
    pub stages: usize,
    /// Step size.
    pub h: f64,
    /// Number of steps.
    pub steps: usize,
    /// Initial time.
    pub t0: f64,
    /// Initial coordinates (`N` entries).
    pub q0: Vec<f64>,
    /// Initial velocities (`N` entries).
    pub v0: Vec<f64>,
    /// Parameter overrides.
    pub parameters: Vec<(String, f64)>,
    /// Record every this many steps (and always the endpoints).
    pub every: usize,
    /// Newton settings.
    pub newton: NewtonOptions,
    /// Record the multipliers `ψ` at every sample.
    pub multipliers: bool,
    /// Replace an inconsistent `v0` by the nearest consistent one.
    pub project_v0: bool,
    /// How deep a step whose Newton iteration fails may be halved
    /// ([`RunOptions::max_halvings`]; `0` ends the run at the failure).
    pub max_halvings: u32,
    /// Tolerance-driven steps from `t0` to the tolerance's `t_end` instead
    /// of `steps` fixed steps `h` (which then do not apply).
    pub tolerance: Option<Tolerance>,
    /// Output times ([`RunPlan::times`]): the samples are the initial point
    /// and the state at each time; `every` does not apply.
    pub times: Option<Vec<f64>>,
    /// Locate the events the system declares ([`RunPlan::events`]).
    pub events: bool,
}

impl IntegrateRequest {
    /// How the run chooses its steps.
    pub fn stepping(&self) -> Stepping {
        Stepping::new(self.h, self.steps, self.tolerance)
    }

    /// The run as [`integrate_plan`] takes it.
    pub fn plan(&self) -> RunPlan<'_> {
        RunPlan { stepping: self.stepping(), times: self.times.as_deref(), events: self.events }
    }
}

/// An ensemble: the same run from many initial states.
#[derive(Clone, Debug, PartialEq)]
pub struct EnsembleRequest {
    /// Everything but the initial states (`q0`, `v0` empty).
    pub run: IntegrateRequest,
    /// Initial coordinates, member after member (`members × N`).
    pub q0s: Vec<f64>,
    /// Initial velocities, member after member (`members × N`).
    pub v0s: Vec<f64>,
    /// Number of members.
    pub members: usize,
    /// Worker threads (`None`: rayon's default, all cores or `RAYON_NUM_THREADS`).
    pub threads: Option<usize>,
}

/// A recorded run, row-major (`samples × N`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Columns {
    /// Number of coordinates.
    pub n: usize,
    /// Number of constraints.
    pub m: usize,
    /// Sample times.
    pub t: Vec<f64>,
    /// Coordinates, `samples × N`.
    pub q: Vec<f64>,
    /// Velocities, `samples × N`.
    pub v: Vec<f64>,
    /// Energy at each sample.
    pub energy: Vec<f64>,
    /// `max_i |k_i|` at each sample.
    pub constraint: Vec<f64>,
    /// Multipliers `ψ`, `samples × M` (empty unless asked for; NaN where
    /// the saddle matrix was singular).
    pub psi: Vec<f64>,
    /// `max_i |g_i(t, q)|` at each sample (empty without holonomic constraints).
    pub holonomic: Vec<f64>,
    /// Energy at the initial state.
    pub e0: f64,
    /// Steps taken.
    pub steps: usize,
    /// Mean Newton iterations per step.
    pub newton_iterations_mean: f64,
    /// Failed (sub-)steps that were halved (0 for a run of fixed steps `h`
    /// alone).
    pub rejected_steps: usize,
    /// Scheduled steps that needed at least one halving.
    pub steps_with_rejections: usize,
    /// Accepted sub-steps (`steps` when none was halved).
    pub substeps: usize,
    /// Smallest magnitude of an accepted sub-step (`|h|` when none was
    /// halved).
    pub smallest_step: f64,
    /// Wall time of [`integrate`] itself, in seconds (checks, stepper set-up,
    /// the steps and the columns): what a Rust caller pays, for measuring
    /// the overhead of the Python call around it.
    pub seconds: f64,
    /// The located events, in time order (empty unless asked for).
    pub events: Vec<EventRow>,
    /// The controller's statistics of a tolerance-driven run (`None` for
    /// fixed steps).
    pub controller: Option<AdaptiveReport>,
}

/// What went wrong, as the message a Python exception carries.
pub type Failure = String;

fn vector<const N: usize>(what: &str, x: &[f64]) -> Result<Vector<N>, Failure> {
    if x.len() != N {
        return Err(format!("{what} has {} entries but the system has {N} coordinates", x.len()));
    }
    if let Some(bad) = x.iter().find(|x| !x.is_finite()) {
        return Err(format!("{what} has a non-finite entry {bad:.3e}"));
    }
    Ok(Vector::<N>::from_column_slice(x))
}

/// The system with its parameter overrides applied.
pub fn configured<Sys, const N: usize, const M: usize>(parameters: &[(String, f64)]) -> Result<Sys, Failure>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let mut sys = Sys::default();
    for (name, value) in parameters {
        sys.set_parameter(name, *value).map_err(|e| e.to_string())?;
    }
    Ok(sys)
}

/// The checks of a request that need no system type: those of its steps
/// that `spark run` shares ([`RunPlan::check_steps`]), then the request's
/// own.
fn check_request(r: &IntegrateRequest) -> Result<(), Failure> {
    r.plan().check_steps(r.t0)?;
    if r.tolerance.is_none() && r.steps == 0 {
        return Err("steps must be at least 1".into());
    }
    if r.times.as_ref().is_some_and(|times| times.is_empty()) {
        return Err("t_eval holds no time; give at least one, or None to record at the steps".into());
    }
    if r.every == 0 {
        return Err("every must be at least 1 (1 records every step)".into());
    }
    let (min, max) = r.method.stage_range();
    if r.stages < min || r.stages > max {
        return Err(TableauError::UnsupportedStages { method: r.method, s: r.stages, min, max }.to_string());
    }
    Ok(())
}

/// Refuses a request whose recorded samples (`members` runs of `r`) would
/// not fit in memory ([`RunPlan::check_record_size`]): such a run would end
/// in an allocation failure, which aborts the Python process. Per sample it
/// counts the driver's record, the result columns and their NumPy copies.
fn check_record<const N: usize, const M: usize>(r: &IntegrateRequest, members: usize) -> Result<(), Failure> {
    let per_sample = std::mem::size_of::<Sample<N, M>>() as u64 + 2 * 8 * (2 * N + M + 4) as u64;
    r.plan().check_record_size(r.every, members, per_sample)
}

/// A message of the Rust library in the words of the Python API: the
/// keyword arguments of `System.integrate` where the message names an
/// option of the runtime or a flag of `spark run`.
pub fn python_words(message: &str) -> Failure {
    const WORDS: [(&str, &str); 13] = [
        ("(the limit: AdaptiveOptions::max_steps, `--max-steps` of `spark run`)", "(the limit: max_steps)"),
        (" (AdaptiveOptions::max_step, `--max-step` of `spark run`)", ""),
        (" (AdaptiveOptions::initial_step, `--first-step` of `spark run`)", ""),
        ("RunOptions::max_events; by default as many as fit", "as many as fit"),
        ("AdaptiveOptions::max_events; by default as many as fit", "as many as fit"),
        ("AdaptiveOptions::max_steps", "max_steps"),
        ("AdaptiveOptions::initial_step", "first_step"),
        ("AdaptiveOptions::max_step", "max_step"),
        ("AdaptiveOptions::rtol", "rtol"),
        ("AdaptiveOptions::atol", "atol"),
        (", lower AdaptiveOptions::min_step,", ","),
        ("`--max-halvings`", "max_halvings"),
        ("--project-v0", "project_v0=True"),
    ];
    WORDS.iter().fold(message.to_string(), |text, (rust, python)| text.replace(rust, python))
}

/// What to do about a `v0` that violates the constraints, in a run.
const PROJECT_HINT: &str = "give a v0 with k = 0 or pass project_v0=True to use the nearest consistent one";

/// The same in an ensemble, whose members start from their rows as given:
/// `spark.ensemble` takes no `project_v0`.
pub const ENSEMBLE_PROJECT_HINT: &str = "give the member a row of v0s with k = 0 (an ensemble integrates its \
                                         initial states as given; spark.integrate with project_v0=True returns the \
                                         nearest consistent v0 as run.v[0])";

/// Member `j`'s failure as an ensemble reports it: named, and without the
/// advice of a run that the ensemble does not take.
fn member_failure(j: usize, e: &str) -> Failure {
    format!("member {j}: {}", e.replace(PROJECT_HINT, ENSEMBLE_PROJECT_HINT))
}

/// How a request treats an inconsistent `v0`.
fn consistency(r: &IntegrateRequest) -> ConsistencyPolicy {
    if r.project_v0 {
        ConsistencyPolicy::Project { tolerance: PROJECTION_TOLERANCE }
    } else {
        ConsistencyPolicy::default()
    }
}

/// The initial state a run of `r` from `(q0, v0)` integrates: `q0` checked
/// against the holonomic constraints, `v0` checked (or projected, with
/// `project_v0`) against the constraints.
fn checked_start<Sys, const N: usize, const M: usize>(
    r: &IntegrateRequest,
    probe: &Sys,
    q0: &[f64],
    v0: &[f64],
) -> Result<(Vector<N>, Vector<N>), Failure>
where
    Sys: NonholonomicSystem<N, M>,
{
    let q0 = vector::<N>("q0", q0)?;
    let v0 = vector::<N>("v0", v0)?;
    if Sys::HAS_HOLONOMIC {
        let residual = probe.holonomic_residual(r.t0, &q0).amax();
        if residual.is_nan() || residual > POSITION_TOLERANCE {
            return Err(format!(
                "q0 violates the holonomic constraint: max |g(t0, q0)| = {residual:.3e} > {POSITION_TOLERANCE:.1e}; \
                 choose q0 on the constraint"
            ));
        }
    }
    let v0 = consistent_velocity(probe, r.t0, &q0, &v0, consistency(r)).map_err(|e| match e {
        StepError::InconsistentInitialState { residual, tolerance } => {
            format!(
                "v0 violates the constraints: max |k(t0, q0, v0)| = {residual:.3e} > {tolerance:.1e}; {PROJECT_HINT}"
            )
        }
        e => format!("initial state: {e}"),
    })?;
    // Parameters come from the user here: a negative mass or inertia is
    // refused rather than integrated into a motion no mechanical system has.
    check_positive_kinetic_energy(probe, r.t0, &q0, &v0).map_err(|e| e.to_string())?;
    Ok((q0, v0))
}

/// Integrates one run with stepper type `Stepper<Sys, N, M, S, D>`: the same
/// steps, options and observations as `spark run` (`problems::run::run_with`).
///
/// `stop` set (by [`interruptible`], when the user interrupts) ends the run
/// after the step it is noticed at, with an error.
pub fn integrate<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    r: &IntegrateRequest,
    stop: &AtomicBool,
) -> Result<Columns, Failure>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let start = std::time::Instant::now();
    check_request(r)?;
    check_record::<N, M>(r, 1)?;
    let probe: Sys = configured(&r.parameters)?;
    let (q0, v0) = checked_start::<Sys, N, M>(r, &probe, &r.q0, &r.v0)?;
    let consistency = consistency(r);
    let tableau = Tableau::<S>::new(r.method).map_err(|e| e.to_string())?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(configured(&r.parameters)?, tableau).with_options(r.newton);
    let options = RunOptions {
        observe: Observe { energy: true, constraint_residual: true, multipliers: r.multipliers },
        record_every: r.every,
        consistency,
        max_halvings: r.max_halvings,
        ..RunOptions::default()
    };
    let planned = integrate_plan(&mut stepper, r.t0, &q0, &v0, &r.plan(), &options, &mut StopFlag(stop))
        .map_err(|e| python_words(&format!("{} s = {}: {e}", r.method, S)))?;
    let traj = planned.trajectory;
    let samples = &traj.samples;
    let k = samples.len();
    let mut out = Columns {
        n: N,
        m: M,
        t: Vec::with_capacity(k),
        q: Vec::with_capacity(k * N),
        v: Vec::with_capacity(k * N),
        energy: Vec::with_capacity(k),
        constraint: Vec::with_capacity(k),
        psi: Vec::new(),
        holonomic: Vec::new(),
        e0: probe.energy(r.t0, &q0, &v0),
        steps: traj.report.steps,
        newton_iterations_mean: traj.report.newton_iterations_mean,
        rejected_steps: traj.report.rejected_steps,
        steps_with_rejections: traj.report.steps_with_rejections,
        substeps: traj.report.substeps,
        smallest_step: traj.report.smallest_step,
        seconds: 0.0,
        events: event_rows::<Sys, N, M>(&traj.events),
        controller: planned.controller,
    };
    for s in samples {
        out.t.push(s.t);
        out.q.extend(s.q.iter());
        out.v.extend(s.v.iter());
        out.energy.push(s.energy.unwrap_or(f64::NAN));
        out.constraint.push(s.constraint_residual.unwrap_or(f64::NAN));
        if r.multipliers {
            match &s.multipliers {
                Some(psi) => out.psi.extend(psi.iter()),
                None => out.psi.extend(std::iter::repeat_n(f64::NAN, M)),
            }
        }
        if Sys::HAS_HOLONOMIC {
            out.holonomic.push(probe.holonomic_residual(s.t, &s.q).amax());
        }
    }
    out.seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

/// Integrates every member of `r`: in SIMD lane groups through
/// [`integrate_ensemble`](spark_runtime::integrate_ensemble) (the groups in parallel, rayon), each member's
/// columns computed from its samples as [`integrate`] computes them. A
/// member agrees with [`integrate`] for it alone to the Newton tolerance
/// per step, whatever the thread count.
///
/// The runs the lanes do not take go through [`integrate`] per member (in
/// parallel over members): a request for the multipliers `ψ`, a
/// tolerance-driven request, one with output times or events (as
/// `problems::run::run_ensemble`; each member is then its run alone bit
/// for bit, events included, and one that a terminal event ends stops
/// there alone), a request [`integrate`] rejects before
/// stepping, and a member whose lane fails (it runs again alone, so that it
/// gets [`integrate`]'s error; a lane retries a failed step cold and halves
/// it up to `max_halvings` levels as [`integrate`]'s driver does, and counts
/// its halvings as [`integrate`] counts them). Each member's
/// `seconds` is an equal share of the ensemble's wall time. `stop` ends
/// every member as in [`integrate`].
pub fn ensemble<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    r: &EnsembleRequest,
    stop: &AtomicBool,
) -> Result<Vec<Columns>, Failure>
where
    Sys: NonholonomicSystem<N, M> + Default + Clone + Send + Sync,
{
    if r.q0s.len() != r.members * N || r.v0s.len() != r.members * N {
        return Err(format!(
            "q0s and v0s must have shape (members, {N}) = ({}, {N}); got {} and {} numbers",
            r.members,
            r.q0s.len(),
            r.v0s.len()
        ));
    }
    check_record::<N, M>(&r.run, r.members)?;
    let member = |j: usize| IntegrateRequest {
        q0: r.q0s[j * N..(j + 1) * N].to_vec(),
        v0: r.v0s[j * N..(j + 1) * N].to_vec(),
        ..r.run.clone()
    };
    let alone = |j: usize| integrate::<Sys, N, M, S, D>(&member(j), stop).map_err(|e| member_failure(j, &e));
    let work = || -> Result<Vec<Columns>, Failure> {
        // The lanes take fixed steps recorded at the steps, without events.
        let planned = r.run.tolerance.is_some() || r.run.times.is_some() || r.run.events;
        let lanes = if r.run.multipliers || planned || check_request(&r.run).is_err() {
            None
        } else {
            configured::<Sys, N, M>(&r.run.parameters).ok().zip(Tableau::<S>::new(r.run.method).ok())
        };
        let Some((probe, tableau)) = lanes else {
            return (0..r.members).into_par_iter().map(alone).collect();
        };
        let start = std::time::Instant::now();
        let starts = (0..r.members)
            .map(|j| {
                let (q0, v0) = checked_start::<Sys, N, M>(&r.run, &probe, &member(j).q0, &member(j).v0)
                    .map_err(|e| member_failure(j, &e))?;
                Ok(State::new(r.run.t0, q0, v0))
            })
            .collect::<Result<Vec<State<N>>, Failure>>()?;
        let runs = integrate_ensemble_until::<Sys, N, M, S, D>(
            &probe,
            tableau,
            r.run.newton,
            &starts,
            r.run.h,
            r.run.steps,
            r.run.every,
            r.run.max_halvings,
            &|| stop.load(Ordering::Relaxed),
        )
        .map_err(|e| e.to_string())?;
        let seconds = start.elapsed().as_secs_f64() / r.members as f64;
        runs.into_par_iter()
            .enumerate()
            .map(|(j, run)| match run.failure {
                Some(_) => alone(j),
                None => Ok(lane_columns::<Sys, N, M>(&probe, &starts[j], &run, r.run.h, seconds)),
            })
            .collect()
    };
    match r.threads {
        None => work(),
        Some(0) => Err("threads must be at least 1".into()),
        Some(t) if t > MAX_THREADS => Err(too_many_threads(t as i64)),
        Some(t) => rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .map_err(|e| format!("could not start {t} worker threads: {e}"))?
            .install(work),
    }
}

/// The columns of one member's lane run, as [`integrate`] computes them
/// from its samples.
fn lane_columns<Sys, const N: usize, const M: usize>(
    probe: &Sys,
    start: &State<N>,
    run: &EnsembleRun<N>,
    h: f64,
    seconds: f64,
) -> Columns
where
    Sys: NonholonomicSystem<N, M>,
{
    let k = run.samples.len();
    let mut out = Columns {
        n: N,
        m: M,
        t: Vec::with_capacity(k),
        q: Vec::with_capacity(k * N),
        v: Vec::with_capacity(k * N),
        energy: Vec::with_capacity(k),
        constraint: Vec::with_capacity(k),
        psi: Vec::new(),
        holonomic: Vec::new(),
        e0: probe.energy(start.t, &start.q, &start.v),
        steps: run.steps,
        newton_iterations_mean: if run.steps > 0 { run.iterations as f64 / run.steps as f64 } else { 0.0 },
        rejected_steps: run.recovery.rejected_steps,
        steps_with_rejections: run.recovery.steps_with_rejections,
        substeps: run.steps + run.recovery.extra_substeps,
        smallest_step: run.recovery.smallest_step(h),
        seconds,
        events: Vec::new(),
        controller: None,
    };
    for s in &run.samples {
        out.t.push(s.t);
        out.q.extend(s.q.iter());
        out.v.extend(s.v.iter());
        out.energy.push(probe.energy(s.t, &s.q, &s.v));
        out.constraint.push(probe.constraint(s.t, &s.q, &s.v).amax());
        if Sys::HAS_HOLONOMIC {
            out.holonomic.push(probe.holonomic_residual(s.t, &s.q).amax());
        }
    }
    out
}

/// An instance of the exception class `class` of the Python module `module`,
/// carrying `message`; `fallback(message)` when the class cannot be found.
/// Both classes spark raises are Python classes: `SparkError` of the
/// extension module and `ArgumentError` of the `spark` package.
fn error_of_class(
    py: Python<'_>,
    module: &str,
    class: &str,
    message: String,
    fallback: impl FnOnce(String) -> PyErr,
) -> PyErr {
    match py.import(module).and_then(|m| m.getattr(class)) {
        Ok(class) => match class.call1((message.clone(),)) {
            Ok(instance) => PyErr::from_value(instance),
            Err(e) => e,
        },
        Err(_) => fallback(message),
    }
}

/// `spark.SparkError` with `message` (the class lives in `spark._native`, so
/// errors of every compiled module are the same Python class).
pub fn spark_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    error_of_class(py, "spark._native", "SparkError", message.into(), pyo3::exceptions::PyRuntimeError::new_err)
}

/// `spark.ArgumentError` with `message`: an argument outside the range the
/// request takes (a `SparkError` and a `ValueError`, defined by the `spark`
/// package); `spark.SparkError` when the package's class cannot be found.
pub fn argument_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    error_of_class(py, "spark", "ArgumentError", message.into(), |message| spark_error(py, message))
}

/// The refusal of a str that UTF-8 cannot encode (`what` names it): a lone
/// surrogate such as `"\ud800"` cannot become a Rust string.
fn not_unicode(py: Python<'_>, what: &str) -> PyErr {
    argument_error(
        py,
        format!(
            "{what} holds a lone surrogate, which UTF-8 cannot encode: it is no valid Unicode text; remove it (text \
             decoded with errors=\"surrogateescape\" keeps undecodable bytes as such surrogates)"
        ),
    )
}

/// `x` as a Rust string: [`not_unicode`] for a str UTF-8 cannot encode,
/// `TypeError` naming `what` for anything but a str.
pub fn text(x: &Bound<'_, PyAny>, what: &str) -> PyResult<String> {
    x.extract::<String>().map_err(|e| {
        if e.is_instance_of::<PyUnicodeEncodeError>(x.py()) {
            not_unicode(x.py(), &format!("{what} = {}", short(x)))
        } else {
            PyTypeError::new_err(format!("{what} = {} is not a string", short(x)))
        }
    })
}

/// Refuses a stage count that `method` does not have or that `what` (the
/// program or module) has no stepper compiled for, up to `max`.
pub fn check_stages(py: Python<'_>, r: &IntegrateRequest, max: usize, what: &str) -> PyResult<()> {
    let (method, s) = (r.method, r.stages);
    if s > max {
        return Err(argument_error(
            py,
            format!("{method} with s = {s} is not compiled into {what}; supported: s = 1..={max}"),
        ));
    }
    let (min, most) = method.stage_range();
    if s < min || s > most {
        return Err(argument_error(py, TableauError::UnsupportedStages { method, s, min, max: most }.to_string()));
    }
    Ok(())
}

fn get<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Option<T>> {
    match d.get_item(key)? {
        None => Ok(None),
        Some(v) if v.is_none() => Ok(None),
        Some(v) => v.extract::<T>().map(Some).map_err(|e| {
            let e: PyErr = e.into();
            if e.is_instance_of::<PyUnicodeEncodeError>(d.py()) {
                return not_unicode(d.py(), &format!("`{key}` = {}", short(&v)));
            }
            // A float where a whole number is meant (`steps` = 2.5) is a
            // value out of range, as the package refuses it, not a wrong type.
            if std::any::type_name::<T>() == "i64" && v.is_instance_of::<pyo3::types::PyFloat>() {
                return argument_error(d.py(), format!("`{key}` = {} must be a whole number, an int", short(&v)));
            }
            // PyO3's overflow message ("too large to convert to C long")
            // names no argument and no range.
            if e.is_instance_of::<PyOverflowError>(d.py()) {
                let range = match std::any::type_name::<T>() {
                    "i64" => format!("the 64-bit integers the request takes ({} … {})", i64::MIN, i64::MAX),
                    "f64" => "the floats (magnitude below 1.8e308)".to_string(),
                    _ => format!("what the request takes ({})", e.value(d.py())),
                };
                return argument_error(d.py(), format!("`{key}` = {} is outside {range}", short(&v)));
            }
            PyTypeError::new_err(format!("`{key}`: {}", e.value(d.py())))
        }),
    }
}

/// `repr(v)`, cut when long (an int such as `10**400` would fill the message).
fn short(v: &Bound<'_, PyAny>) -> String {
    let r = v.repr().map(|r| r.to_string()).unwrap_or_else(|_| "?".into());
    let n = r.chars().count();
    if n <= 40 {
        r
    } else {
        let head: String = r.chars().take(12).collect();
        let tail: String = r.chars().skip(n - 6).collect();
        format!("{head}…{tail} ({n} characters)")
    }
}

use pyo3::conversion::FromPyObjectOwned;

/// The value of `key`, which the request must carry: its absence (or
/// `None`) is the caller's bad argument, named with what gives it.
fn required<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<T> {
    get(d, key)?.ok_or_else(|| {
        let what = match key {
            "h" | "steps" => {
                " (a run of fixed steps takes `h` and `steps`; a tolerance-driven one `rtol`/`atol` and \
                              `t_end`)"
            }
            "q0s" | "v0s" => " (the members' initial states, one row of N numbers each)",
            _ => "",
        };
        argument_error(d.py(), format!("the request has no `{key}`{what}; give it"))
    })
}

/// Reads the common fields of a request dict (everything but the initial
/// states): `method`, `s`, `h`, `steps`, `t0`, `params`, `every`, `newton`,
/// `newton_tol`, `multipliers`, `project_v0`, `max_halvings`; for a
/// tolerance-driven run `rtol`, `atol`, `first_step`, `max_step`,
/// `max_steps` and `t_end` instead of `h`, `steps` and `max_halvings`;
/// output times `t_eval` and `events`.
pub fn read_request(py: Python<'_>, d: &Bound<'_, PyDict>) -> PyResult<IntegrateRequest> {
    let method: String = required(d, "method")?;
    let method: Method = method.parse().map_err(|e: spark_runtime::TableauError| argument_error(py, e.to_string()))?;
    let newton_mode: String = get(d, "newton")?.unwrap_or_else(|| "full".into());
    let mode = match newton_mode.to_ascii_lowercase().as_str() {
        "full" => NewtonMode::Full,
        "simplified" => NewtonMode::Simplified,
        other => return Err(argument_error(py, format!("newton = `{other}`: write \"full\" or \"simplified\""))),
    };
    let mut newton = NewtonOptions { mode, ..NewtonOptions::default() };
    if let Some(tol) = get::<f64>(d, "newton_tol")? {
        if !(tol > 0.0 && tol < 1.0) {
            return Err(argument_error(
                py,
                format!("newton_tol = {tol:.3e} must lie in (0, 1): the largest update accepted, relative to 1 + |z|"),
            ));
        }
        newton.tolerance = tol;
        newton.stagnation_level = newton.stagnation_level.max(tol);
    }
    let parameters: Vec<(String, f64)> = match d.get_item("params")? {
        Some(p) if !p.is_none() => {
            let p = p.cast_into::<PyDict>().map_err(|_| PyTypeError::new_err("`params` must be a dict"))?;
            let mut v = Vec::new();
            for (k, x) in p.iter() {
                let name = text(&k, "params key")?;
                let value = x.extract::<f64>().map_err(|e| {
                    let what = format!("params[{}] = {}", short(&k), short(&x));
                    if e.is_instance_of::<PyOverflowError>(py) {
                        argument_error(py, format!("{what} is outside the floats (magnitude below 1.8e308)"))
                    } else {
                        PyTypeError::new_err(format!("{what} is not a number: {}", e.value(py)))
                    }
                })?;
                if !value.is_finite() {
                    return Err(argument_error(py, format!("parameter `{name}` = {value:.3e} must be finite")));
                }
                v.push((name, value));
            }
            v
        }
        _ => Vec::new(),
    };
    let t0: f64 = get(d, "t0")?.unwrap_or(0.0);
    if !t0.is_finite() {
        return Err(not_a_time(py, "t0", t0));
    }
    let tolerance = read_tolerance(py, d, t0)?;
    let steps: i64 = if tolerance.is_some() { 1 } else { required(d, "steps")? };
    let every: i64 = get(d, "every")?.unwrap_or(1);
    let stages: i64 = required(d, "s")?;
    for (name, value) in [("steps", steps), ("every", every), ("s", stages)] {
        if value < 1 {
            return Err(argument_error(py, format!("{name} = {value} must be at least 1")));
        }
    }
    let times: Option<Vec<f64>> = get(d, "t_eval")?;
    let max_halvings: i64 = get(d, "max_halvings")?.unwrap_or(DEFAULT_MAX_HALVINGS as i64);
    if !(0..=MAX_HALVINGS as i64).contains(&max_halvings) {
        return Err(argument_error(
            py,
            format!(
                "max_halvings = {max_halvings} must lie in 0..={MAX_HALVINGS} (0 ends the run at the first step whose \
                 Newton iteration fails)"
            ),
        ));
    }
    let max_halvings = max_halvings as u32;
    if tolerance.is_none() && d.get_item("t_end")?.is_some_and(|v| !v.is_none()) {
        // A request of fixed steps runs `steps` steps of `h`: a `t_end`
        // beside them would be ignored, and the run end elsewhere.
        return Err(argument_error(
            py,
            "`t_end` applies to a tolerance-driven request (rtol/atol); a request of fixed steps ends after `steps` \
             steps of `h`: drop t_end",
        ));
    }
    let r = IntegrateRequest {
        method,
        stages: stages as usize,
        h: if tolerance.is_some() { f64::NAN } else { required(d, "h")? },
        steps: if tolerance.is_some() { 0 } else { steps as usize },
        t0,
        q0: get(d, "q0")?.unwrap_or_default(),
        v0: get(d, "v0")?.unwrap_or_default(),
        parameters,
        every: every as usize,
        newton,
        multipliers: get(d, "multipliers")?.unwrap_or(false),
        project_v0: get(d, "project_v0")?.unwrap_or(false),
        max_halvings,
        tolerance,
        times,
        events: get(d, "events")?.unwrap_or(false),
    };
    // The steps' own checks (a step size that cannot step from t0, a
    // tolerance-driven t_end at t0) concern the caller's arguments alone:
    // refused here, before the run, rather than as its failure.
    r.plan().check_steps(r.t0).map_err(|e| argument_error(py, python_words(&e)))?;
    Ok(r)
}

/// Refuses, as the caller's bad arguments, an initial state of a run of a
/// system of `n` coordinates whose `q0` or `v0` does not have `n` entries
/// or holds one that is not finite: before the run, rather than as its
/// failure.
pub fn check_initial_state(py: Python<'_>, r: &IntegrateRequest, n: usize) -> PyResult<()> {
    for (what, x) in [("q0", &r.q0), ("v0", &r.v0)] {
        if x.len() != n {
            return Err(argument_error(
                py,
                format!(
                    "{what} has {} entries but the system has {n} coordinates; give one entry per coordinate",
                    x.len()
                ),
            ));
        }
        if let Some(i) = x.iter().position(|x| !x.is_finite()) {
            return Err(argument_error(py, format!("{what}[{i}] = {} is not finite; give a finite {what}", x[i])));
        }
    }
    Ok(())
}

/// Refuses, as the caller's bad arguments, the initial states of an
/// ensemble of a system of `n` coordinates whose rows do not have `n`
/// entries or that hold one that is not finite: before any member runs,
/// rather than as one member's failure after the members before it ran.
pub fn check_members(py: Python<'_>, r: &EnsembleRequest, n: usize) -> PyResult<()> {
    let width = r.q0s.len() / r.members.max(1);
    if width != n || r.q0s.len() != r.members * n || r.v0s.len() != r.members * n {
        return Err(argument_error(
            py,
            format!("q0s and v0s must have shape (members, {n}) = ({}, {n}); got rows of {width} numbers", r.members),
        ));
    }
    for (what, x) in [("q0s", &r.q0s), ("v0s", &r.v0s)] {
        if let Some(k) = x.iter().position(|x| !x.is_finite()) {
            let (j, i) = (k / n, k % n);
            return Err(argument_error(
                py,
                format!("{what}[{j}, {i}] = {} is not finite (member {j}); give finite initial states", x[k]),
            ));
        }
    }
    Ok(())
}

/// The tolerance of a request with `rtol` or `atol` (the missing one takes
/// the given one's value), which then needs `t_end` and takes neither `h`,
/// `steps` nor `max_halvings`; `None` for a run of fixed steps.
fn read_tolerance(py: Python<'_>, d: &Bound<'_, PyDict>, t0: f64) -> PyResult<Option<Tolerance>> {
    let rtol: Option<f64> = get(d, "rtol")?;
    let atol: Option<f64> = get(d, "atol")?;
    let (rtol, atol) = match (rtol, atol) {
        (None, None) => return Ok(None),
        (Some(r), None) => (r, r),
        (None, Some(a)) => (a, a),
        (Some(r), Some(a)) => (r, a),
    };
    for key in ["h", "steps", "max_halvings"] {
        if d.get_item(key)?.is_some_and(|v| !v.is_none()) {
            return Err(argument_error(
                py,
                format!(
                    "`{key}` does not apply to a tolerance-driven run (rtol/atol): the controller chooses the \
                     steps; drop {key} or drop rtol and atol"
                ),
            ));
        }
    }
    let t_end: f64 = get(d, "t_end")?.ok_or_else(|| {
        argument_error(
            py,
            format!("a tolerance-driven run (rtol/atol) needs t_end, the end of the run from t0 = {t0:e}"),
        )
    })?;
    if !t_end.is_finite() {
        return Err(not_a_time(py, "t_end", t_end));
    }
    let max_steps: i64 = get(d, "max_steps")?.unwrap_or(DEFAULT_MAX_STEPS as i64);
    if max_steps < 1 {
        return Err(argument_error(py, format!("max_steps = {max_steps} must be at least 1")));
    }
    Ok(Some(Tolerance {
        rtol,
        atol,
        first_step: get(d, "first_step")?,
        max_step: get(d, "max_step")?,
        max_steps: max_steps as usize,
        t_end,
    }))
}

/// The refusal of a time `key` (`t0`, `t_end`) that is NaN or infinite: a
/// run starts and ends at finite times.
fn not_a_time(py: Python<'_>, key: &str, t: f64) -> PyErr {
    argument_error(py, format!("`{key}` = {t} is not a finite time; give a finite {key} (magnitude below 1.8e308)"))
}

/// The most step attempts of a tolerance-driven run when the request gives
/// none (`max_steps`).
pub const DEFAULT_MAX_STEPS: usize = 1_000_000;

/// Reads an ensemble request: the common fields plus `q0s`, `v0s` (2-D
/// arrays or nested lists, one row per member) and `threads`.
pub fn read_ensemble(py: Python<'_>, d: &Bound<'_, PyDict>) -> PyResult<EnsembleRequest> {
    let run = read_request(py, d)?;
    let rows = |key: &str| -> PyResult<Vec<Vec<f64>>> { required(d, key) };
    let (q0s, v0s) = (rows("q0s")?, rows("v0s")?);
    if q0s.len() != v0s.len() {
        return Err(argument_error(
            py,
            format!("q0s has {} rows but v0s has {}; give one row of each per member", q0s.len(), v0s.len()),
        ));
    }
    if q0s.is_empty() {
        return Err(argument_error(py, "an ensemble needs at least one member"));
    }
    let threads: Option<i64> = get(d, "threads")?;
    if let Some(t) = threads {
        if t < 1 {
            return Err(argument_error(py, format!("threads = {t} must be at least 1")));
        }
        if t > MAX_THREADS as i64 {
            return Err(argument_error(py, too_many_threads(t)));
        }
    }
    let width = q0s[0].len();
    if let Some(j) = q0s.iter().chain(v0s.iter()).position(|r| r.len() != width) {
        let (what, row) = if j < q0s.len() { ("q0s", j) } else { ("v0s", j - q0s.len()) };
        return Err(argument_error(
            py,
            format!(
                "row {row} of {what} has {} numbers but row 0 of q0s has {width}; give rows of one length, N",
                if what == "q0s" { q0s[row].len() } else { v0s[row].len() }
            ),
        ));
    }
    Ok(EnsembleRequest {
        members: q0s.len(),
        q0s: q0s.concat(),
        v0s: v0s.concat(),
        threads: threads.map(|t| t as usize),
        run,
    })
}

/// One run as a dict of NumPy arrays (`t`, `q`, `v`, `energy`,
/// `constraint`, `psi`, `holonomic`), statistics, `events` (a list of
/// dicts: `name`, `index`, `rising`, `terminal`, `t`, `q`, `v`, `step`)
/// and `controller` (a dict of the controller's statistics, or `None`).
pub fn columns_to_py<'py>(py: Python<'py>, c: Columns) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let k = c.t.len();
    let shape2 = |x: Vec<f64>, w: usize| Array2::from_shape_vec((k, w), x).map_err(|e| spark_error(py, e.to_string()));
    d.set_item("t", Array1::from_vec(c.t).into_pyarray(py))?;
    d.set_item("q", shape2(c.q, c.n)?.into_pyarray(py))?;
    d.set_item("v", shape2(c.v, c.n)?.into_pyarray(py))?;
    d.set_item("energy", Array1::from_vec(c.energy).into_pyarray(py))?;
    d.set_item("constraint", Array1::from_vec(c.constraint).into_pyarray(py))?;
    if !c.psi.is_empty() || c.m == 0 {
        d.set_item("psi", shape2(c.psi, c.m)?.into_pyarray(py))?;
    }
    if !c.holonomic.is_empty() {
        d.set_item("holonomic", Array1::from_vec(c.holonomic).into_pyarray(py))?;
    }
    d.set_item("e0", c.e0)?;
    d.set_item("steps", c.steps)?;
    d.set_item("newton_iterations_mean", c.newton_iterations_mean)?;
    d.set_item("rejected_steps", c.rejected_steps)?;
    d.set_item("steps_with_rejections", c.steps_with_rejections)?;
    d.set_item("substeps", c.substeps)?;
    d.set_item("smallest_step", c.smallest_step)?;
    d.set_item("rust_seconds", c.seconds)?;
    d.set_item("events", events_to_py(py, c.events)?)?;
    match c.controller {
        None => d.set_item("controller", py.None())?,
        Some(a) => {
            let controller = PyDict::new(py);
            controller.set_item("accepted", a.accepted)?;
            controller.set_item("rejected", a.rejected)?;
            controller.set_item("newton_failures", a.newton_failures)?;
            controller.set_item("solves", a.solves)?;
            controller.set_item("newton_iterations", a.newton_iterations)?;
            controller.set_item("smallest_step", a.smallest_step)?;
            controller.set_item("largest_step", a.largest_step)?;
            d.set_item("controller", controller)?;
        }
    }
    Ok(d)
}

/// Located events as a list of dicts: `name`, `index`, `rising`,
/// `terminal`, `t`, `q`, `v`, `step`.
fn events_to_py(py: Python<'_>, events: Vec<EventRow>) -> PyResult<Bound<'_, PyList>> {
    let list = PyList::empty(py);
    for e in events {
        let row = PyDict::new(py);
        row.set_item("name", e.name)?;
        row.set_item("index", e.index)?;
        row.set_item("rising", e.rising)?;
        row.set_item("terminal", e.terminal)?;
        row.set_item("t", e.t)?;
        row.set_item("q", Array1::from_vec(e.q).into_pyarray(py))?;
        row.set_item("v", Array1::from_vec(e.v).into_pyarray(py))?;
        row.set_item("step", e.step)?;
        list.append(row)?;
    }
    Ok(list)
}

/// The times every member of an ensemble of `r` records at, as its run
/// alone records them ([`RunPlan::recorded_times`]). `None` for a
/// tolerance-driven ensemble without output times, whose members record
/// at their own accepted steps.
fn common_times(r: &IntegrateRequest) -> Option<Vec<f64>> {
    r.plan().recorded_times(r.t0, r.every)
}

/// Member `j`'s run `c` on the ensemble's common `times`. A run that went
/// to its end recorded at exactly these times and is returned as it is. A
/// run that a terminal event ended recorded a prefix of them and then the
/// event's state at its time: it keeps the samples at the times of that
/// prefix (the event's own sample too when its time is one of them) and
/// gets NaN at the later times. Anything else is a failure: the member
/// recorded at other times than the ensemble's.
fn on_common_times(j: usize, mut c: Columns, times: &[f64]) -> Result<Columns, Failure> {
    let same = |a: &f64, b: &f64| a.to_bits() == b.to_bits();
    let kept = c.t.iter().zip(times).take_while(|(a, b)| same(a, b)).count();
    if kept == times.len() && c.t.len() == kept {
        return Ok(c);
    }
    let ended = c.events.last().zip(c.t.last()).is_some_and(|(e, t)| e.terminal && same(&e.t, t));
    if !ended || kept + 1 < c.t.len() {
        return Err(format!(
            "member {j} recorded {} samples at times other than the ensemble's {} (a bug: please report it)",
            c.t.len(),
            times.len()
        ));
    }
    let (n, m, k) = (c.n, c.m, times.len());
    let pad = |x: &mut Vec<f64>, width: usize| {
        x.truncate(kept * width);
        x.resize(k * width, f64::NAN);
    };
    c.t = times.to_vec();
    pad(&mut c.q, n);
    pad(&mut c.v, n);
    pad(&mut c.energy, 1);
    pad(&mut c.constraint, 1);
    if !c.psi.is_empty() {
        pad(&mut c.psi, m);
    }
    if !c.holonomic.is_empty() {
        pad(&mut c.holonomic, 1);
    }
    Ok(c)
}

/// The members of an ensemble of `r` on common sample times, with the time
/// each member's run ended (its last sample's, before any NaN is added).
/// Without events every member records at the same times; with events a
/// member that a terminal event ended is put on the ensemble's times by
/// [`on_common_times`].
pub fn ensemble_members(r: &IntegrateRequest, runs: Vec<Columns>) -> Result<(Vec<f64>, Vec<Columns>), Failure> {
    let t_stop = runs.iter().map(|c| c.t.last().copied().unwrap_or(f64::NAN)).collect();
    let runs = match common_times(r) {
        Some(times) if r.events => {
            runs.into_iter().enumerate().map(|(j, c)| on_common_times(j, c, &times)).collect::<Result<_, _>>()?
        }
        _ => runs,
    };
    Ok((t_stop, runs))
}

/// An ensemble of `r` as a dict: `t` (samples), `q`, `v` (members ×
/// samples × N), `energy`, `constraint` (members × samples), `e0`, `steps`
/// (accepted steps), `newton_iterations_mean`, `rejected_steps`,
/// `smallest_step`, `t_stop` (the time each member's run ended: a terminal
/// event's, or the end of the run) (members), `events` (per member, a list
/// of its located events as `columns_to_py` gives them; empty lists
/// without events), and for tolerance-driven members `controller`, a dict
/// of the controller's statistics with one entry per member (`None` for
/// fixed steps). A member that a terminal event ended is NaN at the
/// sample times after it ([`ensemble_members`]).
pub fn ensemble_to_py<'py>(py: Python<'py>, r: &IntegrateRequest, runs: Vec<Columns>) -> PyResult<Bound<'py, PyDict>> {
    let (t_stop, runs) = ensemble_members(r, runs).map_err(|e| spark_error(py, e))?;
    let d = PyDict::new(py);
    let members = runs.len();
    let (k, n) = runs.first().map_or((0, 0), |c| (c.t.len(), c.n));
    if runs.iter().any(|c| c.t.len() != k) {
        return Err(spark_error(py, "ensemble members recorded different sample counts"));
    }
    let mut q = Vec::with_capacity(members * k * n);
    let mut v = Vec::with_capacity(members * k * n);
    let mut energy = Vec::with_capacity(members * k);
    let mut constraint = Vec::with_capacity(members * k);
    let mut e0 = Vec::with_capacity(members);
    let mut iterations = Vec::with_capacity(members);
    let mut rejected = Vec::with_capacity(members);
    let mut smallest = Vec::with_capacity(members);
    let mut steps = Vec::with_capacity(members);
    let t = runs.first().map(|c| c.t.clone()).unwrap_or_default();
    if runs.iter().any(|c| c.t != t) {
        return Err(spark_error(py, "ensemble members recorded their samples at different times"));
    }
    let reports: Option<Vec<AdaptiveReport>> = runs.iter().map(|c| c.controller).collect();
    let events = PyList::empty(py);
    for c in runs {
        events.append(events_to_py(py, c.events)?)?;
        steps.push(c.steps as u64);
        rejected.push(c.rejected_steps as u64);
        smallest.push(c.smallest_step);
        q.extend(c.q);
        v.extend(c.v);
        energy.extend(c.energy);
        constraint.extend(c.constraint);
        e0.push(c.e0);
        iterations.push(c.newton_iterations_mean);
    }
    let err = |e: numpy::ndarray::ShapeError| spark_error(py, e.to_string());
    d.set_item("t", Array1::from_vec(t).into_pyarray(py))?;
    d.set_item("q", Array3::from_shape_vec((members, k, n), q).map_err(err)?.into_pyarray(py))?;
    d.set_item("v", Array3::from_shape_vec((members, k, n), v).map_err(err)?.into_pyarray(py))?;
    d.set_item("energy", Array2::from_shape_vec((members, k), energy).map_err(err)?.into_pyarray(py))?;
    d.set_item("constraint", Array2::from_shape_vec((members, k), constraint).map_err(err)?.into_pyarray(py))?;
    d.set_item("e0", Array1::from_vec(e0).into_pyarray(py))?;
    d.set_item("newton_iterations_mean", Array1::from_vec(iterations).into_pyarray(py))?;
    d.set_item("rejected_steps", Array1::from_vec(rejected).into_pyarray(py))?;
    d.set_item("smallest_step", Array1::from_vec(smallest).into_pyarray(py))?;
    d.set_item("steps", Array1::from_vec(steps).into_pyarray(py))?;
    d.set_item("t_stop", Array1::from_vec(t_stop).into_pyarray(py))?;
    d.set_item("events", events)?;
    match reports {
        Some(reports) if members > 0 => {
            let count = |f: fn(&AdaptiveReport) -> usize| {
                Array1::from_iter(reports.iter().map(|a| f(a) as u64)).into_pyarray(py)
            };
            let size = |f: fn(&AdaptiveReport) -> f64| Array1::from_iter(reports.iter().map(f)).into_pyarray(py);
            let controller = PyDict::new(py);
            controller.set_item("accepted", count(|a| a.accepted))?;
            controller.set_item("rejected", count(|a| a.rejected))?;
            controller.set_item("newton_failures", count(|a| a.newton_failures))?;
            controller.set_item("solves", count(|a| a.solves))?;
            controller.set_item("newton_iterations", count(|a| a.newton_iterations))?;
            controller.set_item("smallest_step", size(|a| a.smallest_step))?;
            controller.set_item("largest_step", size(|a| a.largest_step))?;
            d.set_item("controller", controller)?;
        }
        _ => d.set_item("controller", py.None())?,
    }
    Ok(d)
}

/// An observer that asks the run to stop once `stop` is set.
struct StopFlag<'a>(&'a AtomicBool);

impl<const N: usize, const M: usize> Observer<N, M> for StopFlag<'_> {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, _: &State<N>, _: usize) {}
    fn stop_requested(&mut self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// How often the waiting Python thread checks for signals (Ctrl-C).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Stack of the thread a run works on: the size of a main thread's.
const WORKER_STACK: usize = 8 << 20;

/// Runs `work` on a thread of its own while the calling Python thread,
/// the GIL released, waits for it and checks Python's signal handlers
/// every `SIGNAL_POLL`: when one raises (Ctrl-C raises
/// `KeyboardInterrupt`) it sets `work`'s stop flag, waits for the run to
/// notice it (within a few thousand steps) and raises what the handler
/// raised. A failure of `work` becomes `SparkError`.
pub fn interruptible<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&AtomicBool) -> Result<T, Failure> + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    let flag = &stop;
    let (tx, mut rx) = channel();
    std::thread::scope(|scope| {
        let worker = std::thread::Builder::new()
            .name("spark-run".into())
            .stack_size(WORKER_STACK)
            .spawn_scoped(scope, move || {
                // The receiver is gone only when the caller has stopped waiting.
                let _ = tx.send(work(flag));
            })
            .map_err(|e| spark_error(py, format!("could not start the run's thread: {e}")))?;
        loop {
            // The receiver moves into the wait and back: it is `Send`, not `Sync`.
            let got;
            (rx, got) = py.detach(move || {
                let got = rx.recv_timeout(SIGNAL_POLL);
                (rx, got)
            });
            match got {
                Ok(result) => return result.map_err(|e| spark_error(py, e)),
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(raised) = py.check_signals() {
                        flag.store(true, Ordering::Relaxed);
                        // Joined here, so a panic in it is not re-raised by the scope.
                        let _ = py.detach(|| worker.join());
                        return Err(raised);
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    let _ = py.detach(|| worker.join());
                    return Err(spark_error(py, "the run's thread ended without a result (it panicked)".to_string()));
                }
            }
        }
    })
}

/// The largest stage count [`export_system!`] compiles a stepper for.
pub const MODULE_STAGES: usize = 5;

/// A list of strings as a Python list (for `names()`).
pub fn string_list<'py>(py: Python<'py>, items: &[&str]) -> PyResult<Bound<'py, PyList>> {
    PyList::new(py, items)
}

/// Declares the Python extension module `$module` for the system type
/// `$ty` with `N = $n`, `M = $m` (literals): `info()`, `integrate(request)`
/// and `ensemble(request)`, dispatching the stage count `s = 1..=5` to
/// literal `S` and `D = S(N+M)+N`. The modules `spark.compile` builds are
/// this macro applied to one declaration.
///
/// Every item it defines beside the module's init function starts with
/// `__spark_` (a prefix no struct name may take), so that any struct name
/// the declaration check accepts builds: a struct `info` would clash with
/// the module PyO3 generates for a `#[pyfunction] fn info`.
#[macro_export]
macro_rules! export_system {
    ($module:ident, $ty:ty, $n:literal, $m:literal) => {
        mod __spark_dispatch {
            use super::*;
            pub fn integrate(
                r: &$crate::IntegrateRequest,
                stop: &::std::sync::atomic::AtomicBool,
            ) -> ::core::result::Result<$crate::Columns, $crate::Failure> {
                match r.stages {
                    1 => $crate::integrate::<$ty, $n, $m, 1, { $n + $m + $n }>(r, stop),
                    2 => $crate::integrate::<$ty, $n, $m, 2, { 2 * ($n + $m) + $n }>(r, stop),
                    3 => $crate::integrate::<$ty, $n, $m, 3, { 3 * ($n + $m) + $n }>(r, stop),
                    4 => $crate::integrate::<$ty, $n, $m, 4, { 4 * ($n + $m) + $n }>(r, stop),
                    5 => $crate::integrate::<$ty, $n, $m, 5, { 5 * ($n + $m) + $n }>(r, stop),
                    s => ::core::result::Result::Err(::std::format!(
                        "s = {s} is not compiled into this module; supported: s = 1..=5"
                    )),
                }
            }
            pub fn ensemble(
                r: &$crate::EnsembleRequest,
                stop: &::std::sync::atomic::AtomicBool,
            ) -> ::core::result::Result<::std::vec::Vec<$crate::Columns>, $crate::Failure> {
                match r.run.stages {
                    1 => $crate::ensemble::<$ty, $n, $m, 1, { $n + $m + $n }>(r, stop),
                    2 => $crate::ensemble::<$ty, $n, $m, 2, { 2 * ($n + $m) + $n }>(r, stop),
                    3 => $crate::ensemble::<$ty, $n, $m, 3, { 3 * ($n + $m) + $n }>(r, stop),
                    4 => $crate::ensemble::<$ty, $n, $m, 4, { 4 * ($n + $m) + $n }>(r, stop),
                    5 => $crate::ensemble::<$ty, $n, $m, 5, { 5 * ($n + $m) + $n }>(r, stop),
                    s => ::core::result::Result::Err(::std::format!(
                        "s = {s} is not compiled into this module; supported: s = 1..=5"
                    )),
                }
            }
        }

        #[$crate::pyo3::pyfunction]
        #[pyo3(name = "info")]
        fn __spark_info(
            py: $crate::pyo3::Python<'_>,
        ) -> $crate::pyo3::PyResult<$crate::pyo3::Bound<'_, $crate::pyo3::types::PyDict>> {
            $crate::system_info::<$ty, $n, $m>(py)
        }

        #[$crate::pyo3::pyfunction]
        #[pyo3(name = "integrate")]
        fn __spark_integrate<'py>(
            py: $crate::pyo3::Python<'py>,
            request: &$crate::pyo3::Bound<'py, $crate::pyo3::types::PyDict>,
        ) -> $crate::pyo3::PyResult<$crate::pyo3::Bound<'py, $crate::pyo3::types::PyDict>> {
            let r = $crate::read_request(py, request)?;
            $crate::check_stages(py, &r, $crate::MODULE_STAGES, "this module")?;
            // A parameter name the system does not have is the caller's bad
            // argument: refused here, as the others, not as the run's failure.
            $crate::configured::<$ty, $n, $m>(&r.parameters).map_err(|e| $crate::argument_error(py, e))?;
            $crate::check_initial_state(py, &r, $n)?;
            let c = $crate::interruptible(py, |stop| __spark_dispatch::integrate(&r, stop))?;
            $crate::columns_to_py(py, c)
        }

        #[$crate::pyo3::pyfunction]
        #[pyo3(name = "ensemble")]
        fn __spark_ensemble<'py>(
            py: $crate::pyo3::Python<'py>,
            request: &$crate::pyo3::Bound<'py, $crate::pyo3::types::PyDict>,
        ) -> $crate::pyo3::PyResult<$crate::pyo3::Bound<'py, $crate::pyo3::types::PyDict>> {
            let r = $crate::read_ensemble(py, request)?;
            $crate::check_stages(py, &r.run, $crate::MODULE_STAGES, "this module")?;
            // As in `integrate`: before the members run, not as member 0's failure.
            $crate::configured::<$ty, $n, $m>(&r.run.parameters).map_err(|e| $crate::argument_error(py, e))?;
            $crate::check_members(py, &r, $n)?;
            let c = $crate::interruptible(py, |stop| __spark_dispatch::ensemble(&r, stop))?;
            $crate::ensemble_to_py(py, &r.run, c)
        }

        #[$crate::pyo3::pymodule]
        fn $module(m: &$crate::pyo3::Bound<'_, $crate::pyo3::types::PyModule>) -> $crate::pyo3::PyResult<()> {
            use $crate::pyo3::types::PyModuleMethods;
            m.add_function($crate::pyo3::wrap_pyfunction!(__spark_info, m)?)?;
            m.add_function($crate::pyo3::wrap_pyfunction!(__spark_integrate, m)?)?;
            m.add_function($crate::pyo3::wrap_pyfunction!(__spark_ensemble, m)?)?;
            Ok(())
        }
    };
}
