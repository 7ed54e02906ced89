//! One integration run chosen at run time: which system, method, stage count,
//! step, interval, parameters and initial values.
//!
//! The systems, their defaults and the dispatch from run-time `(system, s)`
//! to the const-generic [`Stepper`](struct@spark_runtime::Stepper) live in [`crate::catalog`]; this module
//! says what one run does for a given stepper type ([`run_with`]).
//!
//! [`run`] (one run) and [`run_ensemble`] (one run per initial state, the
//! members in SIMD lane groups of the lane stepper, the groups in parallel)
//! are the non-generic entry points: `spark run` and the Python
//! extension module (`python/`) both call them, so every (system, s)
//! stepper is monomorphized once, in this crate, and the extension links
//! that code instead of compiling it again. [`files`] writes a run's
//! trajectory and figure.

mod ensemble;
pub mod files;

pub use ensemble::{run_ensemble, run_ensemble_with, EnsembleError, MAX_ENSEMBLE_THREADS};

use crate::catalog::{lookup, nearest, Dispatch, LookupError, StageVisitor, SystemEntry, SystemKind, SystemVisitor};
use crate::report::clock::thread_cpu_time;
use crate::report::format::exact;
use spark_runtime::{
    check_positive_kinetic_energy, consistent_velocity, event_rows, integrate_plan, AdaptiveReport, ConsistencyPolicy,
    EventRow, IntegrationError, LaneStatus, LaneStepper, Method, NewtonOptions, NonholonomicSystem, Observe, PlanError,
    RunOptions, RunPlan, State, Stepper, Stepping, Tableau, TableauError, Tolerance, Vector, DEFAULT_MAX_HALVINGS,
    LANES,
};
use std::time::{Duration, Instant};

/// The registered default initial values of `kind` (the paper's for its four
/// systems; for `mp7` the member `j = 0` of the §8.4 ensemble, see
/// [`mp7_initial_values`](crate::systems::paper::mp7_initial_values)).
pub fn paper_initial_values(kind: SystemKind) -> (Vec<f64>, Vec<f64>) {
    let e = kind.entry();
    (e.q0.to_vec(), e.v0.to_vec())
}

/// Errors of a run; each says what to change.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The system name is not in the catalogue.
    #[error(transparent)]
    UnknownSystem(#[from] LookupError),
    /// A parameter name the system does not have.
    #[error(
        "system `{system}` has no parameter `{name}`{}; its parameters: {known} (see `spark list`)",
        crate::catalog::did_you_mean(.suggestion)
    )]
    UnknownParameter {
        /// The system.
        system: &'static str,
        /// The name given.
        name: String,
        /// The closest parameter name, if one is close.
        suggestion: Option<&'static str>,
        /// The system's parameters, comma-separated.
        known: String,
    },
    /// `q0` violates a holonomic constraint `g(t0, q0) = 0`.
    #[error(
        "q0 violates the holonomic constraint of `{system}`: max |g(t0, q0)| = {residual:.3e} > {tolerance:.1e}; \
         choose q0 on the constraint (default q0 = {default:?})"
    )]
    InconsistentPositions {
        /// The system.
        system: &'static str,
        /// `max_i |g_i(t0, q0)|`.
        residual: f64,
        /// The tolerance.
        tolerance: f64,
        /// The registered default `q0`.
        default: &'static [f64],
    },
    /// `v0` violates the constraints and projection was not asked for.
    #[error(
        "v0 violates the constraints of `{system}`: max |k(t0, q0, v0)| = {residual:.3e} > {tolerance:.1e}; \
         give a v0 with k = 0 or pass --project-v0 to use the nearest consistent one (default v0 = {default:?})"
    )]
    InconsistentVelocities {
        /// The system.
        system: &'static str,
        /// `max_i |k_i(t0, q0, v0)|`.
        residual: f64,
        /// The tolerance.
        tolerance: f64,
        /// The registered default `v0`.
        default: &'static [f64],
    },
    /// The method does not exist with this stage count.
    #[error(transparent)]
    Tableau(#[from] TableauError),
    /// The stage count is beyond what the command line instantiates.
    #[error("{method} with s = {stages} is not compiled into this program; supported: s = 1..={max}")]
    StagesNotCompiled {
        /// The method.
        method: Method,
        /// The stage count asked for.
        stages: usize,
        /// Largest compiled stage count.
        max: usize,
    },
    /// An initial vector has the wrong length.
    #[error("{what} has {got} entries but system `{system}` has {expected} coordinates ({coordinates})")]
    Dimension {
        /// `q0` or `v0`.
        what: &'static str,
        /// The system.
        system: &'static str,
        /// Entries given.
        got: usize,
        /// Entries needed.
        expected: usize,
        /// The coordinate names, comma-separated.
        coordinates: String,
    },
    /// A parameter was rejected by the system.
    #[error(transparent)]
    Parameter(#[from] spark_runtime::SystemError),
    /// The parameters make the kinetic energy not positive at the initial
    /// state (a negative mass or inertia).
    #[error("system `{system}`: {source}")]
    KineticEnergy {
        /// The system.
        system: &'static str,
        /// The directions and the negative parameters.
        source: spark_runtime::IndefiniteKineticEnergy,
    },
    /// The step size or step count is unusable.
    #[error("invalid run: {0}")]
    Invalid(String),
    /// The integration failed.
    #[error("{system} with {method} s = {stages}: {source}")]
    Integration {
        /// System key.
        system: &'static str,
        /// The method.
        method: Method,
        /// Stage count.
        stages: usize,
        /// What went wrong.
        source: IntegrationError,
    },
    /// A tolerance-driven run, or a run with output times or events, failed
    /// or was refused ([`spark_runtime::integrate_plan`]).
    #[error("{system} with {method} s = {stages}: {source}")]
    Plan {
        /// System key.
        system: &'static str,
        /// The method.
        method: Method,
        /// Stage count.
        stages: usize,
        /// What went wrong.
        source: PlanError,
    },
}

/// What to integrate and what to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RunSpec {
    /// The system.
    pub system: SystemKind,
    /// Parameter overrides `(name, value)`; others keep their defaults.
    pub parameters: Vec<(String, f64)>,
    /// The method.
    pub method: Method,
    /// Stage count `s`.
    pub stages: usize,
    /// Step size.
    pub h: f64,
    /// Number of steps (the final time is `t0 + steps·h`).
    pub steps: usize,
    /// Initial time.
    pub t0: f64,
    /// Initial coordinates.
    pub q0: Vec<f64>,
    /// Initial velocities (must satisfy the constraints to 1e-12).
    pub v0: Vec<f64>,
    /// Record a sample every this many steps (and always the endpoints).
    pub record_every: usize,
    /// Newton settings.
    pub newton: NewtonOptions,
    /// What to do with an initial velocity that violates the constraints.
    pub consistency: ConsistencyPolicy,
    /// Record the multipliers `ψ` at every sample ([`RunResult::psi`]).
    pub multipliers: bool,
    /// How deep a step whose Newton iteration fails may be halved
    /// ([`RunOptions::max_halvings`]; `0` ends the run at the failure). Each
    /// halving is counted in [`RunStats::rejected_steps`]. Fixed steps only.
    pub max_halvings: u32,
    /// Tolerance-driven steps from `t0` to the tolerance's `t_end` instead of
    /// the fixed steps `h`, `steps` (which then do not apply); the controller's
    /// statistics are in [`RunResult::controller`].
    pub tolerance: Option<Tolerance>,
    /// Output times: the samples are the initial point and the state at
    /// each time, from the continuous extension (the steps are not
    /// shortened to land on them), and the run ends at the last one;
    /// `record_every` does not apply. Strictly increasing (decreasing for a
    /// run backward), within the run's interval.
    pub times: Option<Vec<f64>>,
    /// Locate the events the system declares ([`RunResult::events`]); a
    /// terminal one ends the run. Without it a run locates none and costs
    /// the same whether the system declares events or not.
    pub events: bool,
}

impl RunSpec {
    /// A run of `system` with its registered defaults: initial state, step
    /// and final time.
    pub fn defaults(system: SystemKind, method: Method, stages: usize) -> Self {
        let e = system.entry();
        let steps = (e.t_end / e.h).round().max(1.0) as usize;
        let mut spec = RunSpec::paper(system, method, stages, e.h, steps);
        spec.t0 = e.t0;
        spec
    }

    /// A run of `system` from its registered (for the paper's systems: the
    /// paper's) initial values.
    pub fn paper(system: SystemKind, method: Method, stages: usize, h: f64, steps: usize) -> Self {
        let (q0, v0) = paper_initial_values(system);
        RunSpec {
            system,
            parameters: Vec::new(),
            method,
            stages,
            h,
            steps,
            t0: 0.0,
            q0,
            v0,
            record_every: 1,
            newton: NewtonOptions::default(),
            consistency: ConsistencyPolicy::default(),
            multipliers: false,
            max_halvings: DEFAULT_MAX_HALVINGS,
            tolerance: None,
            times: None,
            events: false,
        }
    }

    /// The end of the run's interval: `t0 + steps·h`, or the tolerance's
    /// `t_end` for tolerance-driven steps.
    pub fn t_end(&self) -> f64 {
        self.stepping().t_end(self.t0)
    }

    /// How the run chooses its steps.
    pub fn stepping(&self) -> Stepping {
        Stepping::new(self.h, self.steps, self.tolerance)
    }

    /// The run as [`spark_runtime::integrate_plan`] takes it.
    pub fn plan(&self) -> RunPlan<'_> {
        RunPlan { stepping: self.stepping(), times: self.times.as_deref(), events: self.events }
    }
}

/// A recorded run, column by column (no const generics, so results of all
/// systems share one type).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RunResult {
    /// System key.
    pub system: &'static str,
    /// Coordinate names.
    pub coordinates: Vec<String>,
    /// The method.
    pub method: Method,
    /// Stage count.
    pub stages: usize,
    /// Step size.
    pub h: f64,
    /// Sample times.
    pub t: Vec<f64>,
    /// `q[i][k]`: coordinate `i` at sample `k`.
    pub q: Vec<Vec<f64>>,
    /// `v[i][k]`: velocity `i` at sample `k`.
    pub v: Vec<Vec<f64>>,
    /// Energy at each sample.
    pub energy: Vec<f64>,
    /// `max_i |k_i|` at each sample.
    pub constraint: Vec<f64>,
    /// `max_i |g_i(t, q)|` at each sample, the drift of the holonomic
    /// constraints (empty when the system has none).
    pub holonomic: Vec<f64>,
    /// `psi[j][k]`: the multiplier `ψ_j` at sample `k`, recorded when
    /// [`RunSpec::multipliers`] asks for it (empty otherwise; NaN where the
    /// saddle matrix was singular).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub psi: Vec<Vec<f64>>,
    /// Statistics over every step (not only the samples).
    pub stats: RunStats,
    /// The events located, in time order (empty unless
    /// [`RunSpec::events`] asks for them).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<EventRow>,
    /// The controller's statistics of a tolerance-driven run (accepted and
    /// rejected steps, Newton failures, solves, smallest and largest step).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub controller: Option<AdaptiveReport>,
}

impl RunResult {
    /// The velocity the run started from, its first sample's (`None`
    /// without samples): `v0` projected onto the constraints when the run
    /// projects it.
    pub fn initial_velocity(&self) -> Option<Vec<f64>> {
        self.v.iter().map(|column| column.first().copied()).collect()
    }
}

/// Statistics of one run over every step.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RunStats {
    /// Steps taken.
    pub steps: usize,
    /// Initial energy `E0`.
    pub e0: f64,
    /// `max_k |E_k − E0|` over all steps.
    pub max_energy_error: f64,
    /// `max_k max_i |k_i(t_k, q_k, v_k)|` over all steps, initial state included.
    pub max_constraint_residual: f64,
    /// `max_k max_i |g_i(t_k, q_k)|` over all steps: the position-level
    /// drift of holonomic constraints imposed at velocity level (`None`
    /// when the system has none).
    pub max_holonomic_drift: Option<f64>,
    /// Mean Newton iterations per step.
    pub newton_iterations_mean: f64,
    /// Failed (sub-)steps that were halved: a run with any is not a run of
    /// fixed steps `h` alone ([`RunSpec::max_halvings`]).
    pub rejected_steps: usize,
    /// Scheduled steps that needed at least one halving.
    pub steps_with_rejections: usize,
    /// Accepted sub-steps: `steps` when no step was halved.
    pub substeps: usize,
    /// Smallest magnitude of an accepted sub-step (`|h|` when no step was
    /// halved).
    pub smallest_step: f64,
    /// Wall-clock time of the integration.
    #[serde(serialize_with = "seconds")]
    pub wall_time: Duration,
    /// CPU time of the integrating thread ([`thread_cpu_time`]; `None`
    /// where unavailable). Unlike the wall time it does not grow when
    /// other processes compete for the cores.
    #[serde(serialize_with = "maybe_seconds")]
    pub cpu_time: Option<Duration>,
}

fn maybe_seconds<S: serde::Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
    match d {
        Some(d) => s.serialize_f64(d.as_secs_f64()),
        None => s.serialize_none(),
    }
}

fn seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Called with the number of steps done since the previous call (every few
/// thousand steps and at the end), for progress bars; returns whether the
/// run goes on. `false` stops it within a few thousand steps, with
/// [`IntegrationError::Stopped`] as the run's error (for each member of an
/// ensemble): how a front end lets its user interrupt a long run.
pub type Tick<'a> = &'a (dyn Fn(u64) -> bool + Sync);

/// How often the progress callback fires.
const TICK_EVERY: usize = 4096;

/// Runs `spec`, calling `tick` as steps complete.
pub fn run(spec: &RunSpec, tick: Tick<'_>) -> Result<RunResult, RunError> {
    check_spec(spec)?;
    crate::catalog::visit_system(spec.system, RunSystem { spec, tick })
}

/// The checks of [`run`] that need no system type: those of its steps that
/// the Python package shares ([`RunPlan::check_steps`]), output times,
/// stage count, recorded size, parameter names.
fn check_spec(spec: &RunSpec) -> Result<(), RunError> {
    spec.plan().check_steps(spec.t0).map_err(RunError::Invalid)?;
    if let Some(times) = &spec.times {
        if times.is_empty() {
            return Err(RunError::Invalid(
                "no output time is given; give at least one, or none to record steps".into(),
            ));
        }
    }
    let (min, max) = spec.method.stage_range();
    if spec.stages < min || spec.stages > max {
        return Err(TableauError::UnsupportedStages { method: spec.method, s: spec.stages, min, max }.into());
    }
    check_record_size(spec, 1)?;
    check_parameters(spec.system.entry(), &spec.parameters)
}

/// Bytes one recorded sample of a run takes in memory for a system with
/// `n` coordinates and `m` constraints: the driver's record (time, state,
/// energy, residual, multipliers, iterations) and the result's columns.
pub fn bytes_per_sample(n: usize, m: usize) -> u64 {
    let (n, m) = (n as u64, m as u64);
    8 * (1 + 2 * n + 4 + m + 2) + 8 * (2 * n + 4)
}

/// Refuses `members` runs of `spec` whose recorded samples would not fit
/// in memory ([`RunPlan::check_record_size`]): such a run would step
/// until an allocation failure aborts the process. A run with output times
/// records one sample per time; a tolerance-driven run is counted at its
/// most step attempts.
pub fn check_record_size(spec: &RunSpec, members: usize) -> Result<(), RunError> {
    let entry = spec.system.entry();
    spec.plan()
        .check_record_size(spec.record_every, members, bytes_per_sample(entry.n, entry.m))
        .map_err(RunError::Invalid)
}

/// Looks `name` up in the catalogue and runs it with its defaults (the
/// shortest way to integrate a system by name).
pub fn run_by_name(name: &str, method: Method, stages: usize) -> Result<RunResult, RunError> {
    let kind = lookup(name)?.kind;
    run(&RunSpec::defaults(kind, method, stages), &|_| true)
}

/// Rejects parameter names the system does not have, with a suggestion,
/// and a parameter given twice (which value was meant is unknown).
pub fn check_parameters(entry: &'static SystemEntry, parameters: &[(String, f64)]) -> Result<(), RunError> {
    for (i, (name, _)) in parameters.iter().enumerate() {
        if parameters[..i].iter().any(|(n, _)| n == name) {
            return Err(RunError::Invalid(format!("parameter `{name}` is given twice; give each parameter once")));
        }
        if !entry.parameter_names.contains(&name.as_str()) {
            let known =
                if entry.parameter_names.is_empty() { "none".to_string() } else { entry.parameter_names.join(", ") };
            return Err(RunError::UnknownParameter {
                system: entry.name,
                name: name.clone(),
                suggestion: nearest(name, entry.parameter_names.iter().copied()),
                known,
            });
        }
    }
    Ok(())
}

/// Stage dispatch of [`run`] for one system type.
struct RunSystem<'a> {
    spec: &'a RunSpec,
    tick: Tick<'a>,
}

impl SystemVisitor for RunSystem<'_> {
    type Output = Result<RunResult, RunError>;
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        _: &'static SystemEntry,
    ) -> Self::Output {
        let (method, stages) = (self.spec.method, self.spec.stages);
        Sys::with_stages(
            stages,
            RunStages::<Sys> { spec: self.spec, tick: self.tick, system: std::marker::PhantomData },
        )
        .map_err(|e| RunError::StagesNotCompiled { method, stages, max: e.max })?
    }
}

struct RunStages<'a, Sys> {
    spec: &'a RunSpec,
    tick: Tick<'a>,
    system: std::marker::PhantomData<Sys>,
}

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for RunStages<'_, Sys> {
    type Output = Result<RunResult, RunError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        run_with::<Sys, N, M, S, D>(self.spec, self.tick)
    }
}

fn vector<const N: usize>(what: &'static str, entry: &SystemEntry, x: &[f64]) -> Result<Vector<N>, RunError> {
    if x.len() != N {
        return Err(RunError::Dimension {
            what,
            system: entry.name,
            got: x.len(),
            expected: N,
            coordinates: entry.coordinates.join(", "),
        });
    }
    if let Some(bad) = x.iter().find(|x| !x.is_finite()) {
        return Err(RunError::Invalid(format!("{what} has a non-finite entry {bad:.3e}")));
    }
    Ok(Vector::<N>::from_column_slice(x))
}

/// Largest `|g(t0, q0)|` accepted for a holonomic constraint.
const POSITION_TOLERANCE: f64 = 1e-10;

/// The per-step observer of [`run_with`]: the largest holonomic drift
/// `max |g|` over the steps and a progress tick every [`TICK_EVERY`] steps.
struct RunObserver<'a> {
    tick: Tick<'a>,
    count: usize,
    max_holonomic_drift: f64,
    /// What the latest tick answered.
    go_on: bool,
}

impl<const N: usize, const M: usize> spark_runtime::Observer<N, M> for RunObserver<'_> {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, system: &Sys, s: &spark_runtime::State<N>, _: usize) {
        if Sys::HAS_HOLONOMIC {
            self.max_holonomic_drift = self.max_holonomic_drift.max(system.holonomic_residual(s.t, &s.q).amax());
        }
        self.count += 1;
        if self.count.is_multiple_of(TICK_EVERY) {
            self.go_on = (self.tick)(TICK_EVERY as u64);
        }
    }
    fn stop_requested(&mut self) -> bool {
        !self.go_on
    }
}

/// `Sys` with the parameter overrides of `spec`.
fn configured<Sys, const N: usize, const M: usize>(spec: &RunSpec) -> Result<Sys, RunError>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let mut sys = Sys::default();
    for (name, value) in &spec.parameters {
        sys.set_parameter(name, *value)?;
    }
    Ok(sys)
}

/// The initial velocity a run of `spec` from `(q0, v0)` integrates: `q0`
/// checked against the holonomic constraints, `v0` checked (or projected)
/// against the constraints by [`RunSpec::consistency`].
fn checked_start<Sys, const N: usize, const M: usize, const S: usize>(
    spec: &RunSpec,
    probe: &Sys,
    q0: &Vector<N>,
    v0: &Vector<N>,
) -> Result<Vector<N>, RunError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let entry = spec.system.entry();
    let key = entry.name;
    if Sys::HAS_HOLONOMIC {
        let residual = probe.holonomic_residual(spec.t0, q0).amax();
        if residual.is_nan() || residual > POSITION_TOLERANCE {
            return Err(RunError::InconsistentPositions {
                system: key,
                residual,
                tolerance: POSITION_TOLERANCE,
                default: entry.q0,
            });
        }
    }
    let v = consistent_velocity(probe, spec.t0, q0, v0, spec.consistency).map_err(|e| match e {
        spark_runtime::StepError::InconsistentInitialState { residual, tolerance } => {
            RunError::InconsistentVelocities { system: key, residual, tolerance, default: entry.v0 }
        }
        e => {
            RunError::Integration { system: key, method: spec.method, stages: S, source: IntegrationError::Initial(e) }
        }
    })?;
    // Parameters come from the user here: a negative mass or inertia is
    // refused rather than integrated into a motion no mechanical system has.
    check_positive_kinetic_energy(probe, spec.t0, q0, &v)
        .map_err(|source| RunError::KineticEnergy { system: key, source })?;
    Ok(v)
}

/// The generic run: one stepper type, fixed steps, per-step observation.
pub fn run_with<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    spec: &RunSpec,
    tick: Tick<'_>,
) -> Result<RunResult, RunError>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let entry = spec.system.entry();
    let key = entry.name;
    let q0 = vector::<N>("q0", entry, &spec.q0)?;
    let v0 = vector::<N>("v0", entry, &spec.v0)?;
    // A second instance checks the initial state before the stepper owns
    // the first one.
    let probe = configured::<Sys, N, M>(spec)?;
    let tableau = Tableau::<S>::new(spec.method)?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(configured(spec)?, tableau).with_options(spec.newton);
    // Check (or project) v0 here, so that E0 and the initial residual refer
    // to the state actually integrated.
    let v0 = checked_start::<Sys, N, M, S>(spec, &probe, &q0, &v0)?;
    let drift = |t: f64, q: &Vector<N>| if Sys::HAS_HOLONOMIC { probe.holonomic_residual(t, q).amax() } else { 0.0 };
    let e0 = probe.energy(spec.t0, &q0, &v0);
    // The driver's report covers energy and residual at every step; the
    // observer adds the holonomic drift and the progress ticks.
    let mut observer = RunObserver { tick, count: 0, max_holonomic_drift: drift(spec.t0, &q0), go_on: true };
    let options = RunOptions {
        observe: Observe { energy: true, constraint_residual: true, multipliers: spec.multipliers },
        record_every: spec.record_every,
        consistency: spec.consistency,
        max_halvings: spec.max_halvings,
        ..RunOptions::default()
    };
    let start = Instant::now();
    let cpu_start = thread_cpu_time();
    // Events are located only when the spec asks for them, so a run of a
    // system that declares events costs the same as one of a system that
    // declares none.
    let planned = integrate_plan(&mut stepper, spec.t0, &q0, &v0, &spec.plan(), &options, &mut observer).map_err(
        |e| match e {
            PlanError::Fixed(source) => RunError::Integration { system: key, method: spec.method, stages: S, source },
            source => RunError::Plan { system: key, method: spec.method, stages: S, source },
        },
    )?;
    let (traj, controller) = (planned.trajectory, planned.controller);
    let wall_time = start.elapsed();
    let cpu_time = match (cpu_start, thread_cpu_time()) {
        (Some(a), Some(b)) if b >= a => Some(b - a),
        _ => None,
    };
    let _ = tick((observer.count % TICK_EVERY) as u64);
    let holonomic =
        if Sys::HAS_HOLONOMIC { traj.samples.iter().map(|s| drift(s.t, &s.q)).collect() } else { Vec::new() };
    let stats = RunStats {
        steps: traj.report.steps,
        e0,
        max_energy_error: traj.report.max_energy_error,
        max_constraint_residual: traj.report.max_constraint_residual,
        max_holonomic_drift: Sys::HAS_HOLONOMIC.then_some(observer.max_holonomic_drift),
        newton_iterations_mean: traj.report.newton_iterations_mean,
        rejected_steps: traj.report.rejected_steps,
        steps_with_rejections: traj.report.steps_with_rejections,
        substeps: traj.report.substeps,
        smallest_step: traj.report.smallest_step,
        wall_time,
        cpu_time,
    };
    let mut result = run_result(spec, S, Sys::SOURCE.coordinates, &traj.samples, holonomic, stats);
    result.events = event_rows::<Sys, N, M>(&traj.events);
    result.controller = controller;
    Ok(result)
}

/// The columns of a run's samples as a [`RunResult`] (generic in the
/// dimensions only: compiled once per `(N, M)`, not once per system and
/// method).
fn run_result<const N: usize, const M: usize>(
    spec: &RunSpec,
    stages: usize,
    coordinates: &[&str],
    samples: &[spark_runtime::Sample<N, M>],
    holonomic: Vec<f64>,
    stats: RunStats,
) -> RunResult {
    let column = |f: &dyn Fn(&spark_runtime::Sample<N, M>) -> f64| samples.iter().map(f).collect::<Vec<f64>>();
    RunResult {
        system: spec.system.entry().name,
        coordinates: coordinates.iter().map(|c| c.to_string()).collect(),
        method: spec.method,
        stages,
        h: spec.h,
        t: column(&|s| s.t),
        q: (0..N).map(|i| column(&|s| s.q[i])).collect(),
        v: (0..N).map(|i| column(&|s| s.v[i])).collect(),
        energy: column(&|s| s.energy.unwrap_or(f64::NAN)),
        constraint: column(&|s| s.constraint_residual.unwrap_or(f64::NAN)),
        holonomic,
        psi: if spec.multipliers {
            (0..M).map(|j| column(&|s| s.multipliers.as_ref().map_or(f64::NAN, |psi| psi[j]))).collect()
        } else {
            Vec::new()
        },
        stats,
        events: Vec::new(),
        controller: None,
    }
}

/// What the report says of the steps that were halved: a run with any is
/// not a run of fixed steps `h` alone.
fn halvings(s: &RunStats) -> String {
    if s.rejected_steps == 0 {
        return "none".into();
    }
    format!(
        "{} of {} steps, covered by {} sub-steps in all ({} halvings, smallest sub-step {}); \
         `--max-halvings 0` makes such a step an error",
        s.steps_with_rejections,
        s.steps,
        s.substeps,
        s.rejected_steps,
        exact(s.smallest_step)
    )
}

/// What the report says of the located events: how many of each, and the
/// terminal one that ended the run.
fn events_summary(events: &[EventRow]) -> String {
    if events.is_empty() {
        return "none (events.csv has the header only)".into();
    }
    let mut counts: Vec<(&str, usize)> = Vec::new();
    for e in events {
        match counts.iter_mut().find(|(name, _)| *name == e.name) {
            Some((_, k)) => *k += 1,
            None => counts.push((&e.name, 1)),
        }
    }
    let each: Vec<String> = counts.iter().map(|(name, k)| format!("`{name}` {k}")).collect();
    let mut text = format!("{} in events.csv: {}", events.len(), each.join(", "));
    if let Some(last) = events.last().filter(|e| e.terminal) {
        text.push_str(&format!("; the terminal event `{}` ended the run at t = {}", last.name, exact(last.t)));
    }
    text
}

/// The report of one run as Markdown: the setting, the energy error, the
/// constraint residual, the holonomic drift (for systems with holonomic
/// constraints), Newton iterations and timing.
pub fn run_report(result: &RunResult, spec: &RunSpec) -> String {
    use std::fmt::Write;
    let entry = spec.system.entry();
    let s = &result.stats;
    let mut out = String::new();
    let _ = writeln!(out, "# {} — {} s = {}\n", entry.name, result.method, result.stages);
    let _ = writeln!(out, "{} ({}, N = {}, M = {})\n", entry.description, entry.type_name, entry.n, entry.m);
    let _ = writeln!(out, "| quantity | value |\n|---|---|");
    // A `|` inside a cell (`max |E − E0|`) is escaped, or it would end the cell.
    let row = |out: &mut String, k: &str, v: String| {
        let _ = writeln!(out, "| {} | {} |", k.replace('|', "\\|"), v.replace('|', "\\|"));
    };
    // Where the run ended: the last sample (a terminal event, output
    // times) or the end of its interval.
    let t_end = result.t.last().copied().unwrap_or_else(|| spec.t_end());
    match (&spec.tolerance, &result.controller) {
        (Some(tol), Some(c)) => {
            row(
                &mut out,
                "steps (tolerance-driven)",
                format!(
                    "{} accepted, step sizes {} … {} (t = {} … {}); rtol = {}, atol = {}",
                    c.accepted,
                    exact(c.smallest_step),
                    exact(c.largest_step),
                    exact(spec.t0),
                    exact(t_end),
                    exact(tol.rtol),
                    exact(tol.atol)
                ),
            );
            row(
                &mut out,
                "steps rejected",
                format!(
                    "{} by the error estimate, {} by a failed Newton iteration; {} step solves in all",
                    c.rejected, c.newton_failures, c.solves
                ),
            );
        }
        _ => row(
            &mut out,
            "steps × h",
            format!("{} × {} (t = {} … {})", s.steps, exact(spec.h), exact(spec.t0), exact(t_end)),
        ),
    }
    if let Some(times) = &spec.times {
        row(
            &mut out,
            "samples",
            format!(
                "the initial point and {} output times ({} … {}) from the continuous extension",
                times.len(),
                exact(times[0]),
                exact(times[times.len() - 1])
            ),
        );
    }
    if !spec.parameters.is_empty() {
        let p: Vec<String> = spec.parameters.iter().map(|(n, v)| format!("{n} = {}", exact(*v))).collect();
        row(&mut out, "parameters set", p.join(", "));
    }
    row(&mut out, "q0", format!("{:?}", spec.q0));
    let integrated = result.initial_velocity();
    if integrated.as_deref().is_none_or(|v| v == spec.v0.as_slice()) {
        row(&mut out, "v0", format!("{:?}", spec.v0));
    } else {
        row(&mut out, "v0 (given)", format!("{:?}", spec.v0));
        row(
            &mut out,
            "v0 (projected onto the constraints, integrated)",
            format!("{:?}", integrated.unwrap_or_default()),
        );
    }
    row(&mut out, "E0", exact(s.e0));
    let conserved = entry.structure.autonomous() && !entry.effects.does_work();
    row(
        &mut out,
        "max |E − E0|",
        if conserved {
            format!("{:.3e}", s.max_energy_error)
        } else {
            format!(
                "{:.3e} (energy is not conserved by this system: forcing, friction or time dependence)",
                s.max_energy_error
            )
        },
    );
    row(&mut out, "max |k| (constraint residual)", format!("{:.3e}", s.max_constraint_residual));
    if let Some(g) = s.max_holonomic_drift {
        row(&mut out, "max |g| (holonomic drift, position level)", format!("{g:.3e}"));
    }
    let iterations = if spec.tolerance.is_some() {
        "Newton iterations per accepted step (mean, over its three solves)"
    } else {
        "Newton iterations per step (mean)"
    };
    row(&mut out, iterations, format!("{:.2}", s.newton_iterations_mean));
    if spec.tolerance.is_none() {
        row(&mut out, "steps halved (Newton failed at h)", halvings(s));
    }
    if spec.events {
        row(&mut out, "events located", events_summary(&result.events));
    }
    row(&mut out, "wall time", format!("{:.3} s", s.wall_time.as_secs_f64()));
    if let Some(c) = s.cpu_time {
        row(&mut out, "CPU time of the integrating thread", format!("{:.3} s", c.as_secs_f64()));
    }
    out
}
