//! One integration run chosen at run time: which system, method, stage count,
//! step, interval and initial values. Owns the catalogue of the paper's
//! systems as seen by the command line and the single dispatch from run-time
//! choices to the const-generic [`Stepper`] instantiations.
//!
//! The stepper type depends on the system (through `N`, `M`) and on the stage
//! count `S` only; the method is a run-time [`Tableau`]. So the dispatch is a
//! `match` over systems × `S ∈ 1..=MAX_DISPATCH_STAGES`, written once in
//! [`dispatch!`].

use crate::systems::{
    AppellHamel, ChaplyginSleigh, DoublePendulum, McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate,
    TurntableSkate,
};
use spark_runtime::{
    consistent_velocity, ConsistencyPolicy, IntegrationError, Method, NewtonOptions, NonholonomicSystem, Observe,
    RunOptions, Schedule, Stepper, Tableau, TableauError, Vector,
};
use std::time::{Duration, Instant};

/// Largest stage count the command line can instantiate (each extra `S`
/// adds one monomorphized stepper per system; 5 covers Gauss up to order 10
/// and Lobatto up to order 8).
pub const MAX_DISPATCH_STAGES: usize = 5;

/// The systems the command line knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum SystemKind {
    /// Nonholonomic particle (paper §8.1).
    Particle,
    /// Skate on an inclined plane (paper §8.2).
    Skate,
    /// Mobile robot with fixed orientation and a potential (paper §8.3).
    Robot,
    /// McLachlan–Perlmutter particles, `n = 7` (paper §8.4).
    McLachlanPerlmutter7,
    /// Skate on a turning table: rheonomic affine constraint (not in the paper).
    Turntable,
    /// Appell–Hamel particle: constraint nonlinear in `v` (not in the paper).
    AppellHamel,
    /// Chaplygin sleigh on an inclined plane: `q`-dependent mass matrix (not in the paper).
    Sleigh,
    /// Planar double pendulum: no constraints (not in the paper).
    DoublePendulum,
}

/// Facts about one system for listings and defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SystemInfo {
    /// Command-line name.
    pub key: &'static str,
    /// The enum value.
    pub kind: SystemKind,
    /// One-line description.
    pub description: &'static str,
    /// The generated type's name.
    pub type_name: &'static str,
    /// Coordinate names.
    pub coordinates: Vec<String>,
    /// Number of constraints.
    pub constraints: usize,
    /// Runtime parameters with their default values.
    pub parameters: Vec<(String, f64)>,
    /// Default initial coordinates (the paper's where it has them).
    pub q0: Vec<f64>,
    /// Default initial velocities (the paper's where it has them).
    pub v0: Vec<f64>,
}

impl SystemKind {
    /// Every system, in paper order.
    pub const ALL: [SystemKind; 8] = [
        SystemKind::Particle,
        SystemKind::Skate,
        SystemKind::Robot,
        SystemKind::McLachlanPerlmutter7,
        SystemKind::Turntable,
        SystemKind::AppellHamel,
        SystemKind::Sleigh,
        SystemKind::DoublePendulum,
    ];

    /// The command-line name.
    pub const fn key(self) -> &'static str {
        match self {
            SystemKind::Particle => "particle",
            SystemKind::Skate => "skate",
            SystemKind::Robot => "robot",
            SystemKind::McLachlanPerlmutter7 => "mp7",
            SystemKind::Turntable => "turntable",
            SystemKind::AppellHamel => "appell-hamel",
            SystemKind::Sleigh => "sleigh",
            SystemKind::DoublePendulum => "double-pendulum",
        }
    }

    /// Parses a command-line name (see [`SystemKind::key`]).
    pub fn parse(name: &str) -> Result<Self, RunError> {
        let key = name.trim().to_ascii_lowercase();
        SystemKind::ALL
            .into_iter()
            .find(|k| k.key() == key)
            .ok_or_else(|| RunError::UnknownSystem { name: name.to_string() })
    }

    /// Description, sizes, parameters and the paper's initial values.
    pub fn info(self) -> SystemInfo {
        fn facts<Sys: NonholonomicSystem<N, M> + Default, const N: usize, const M: usize>(
            kind: SystemKind,
            description: &'static str,
        ) -> SystemInfo {
            let sys = Sys::default();
            let src = Sys::SOURCE;
            let (q0, v0) = paper_initial_values(kind);
            SystemInfo {
                key: kind.key(),
                kind,
                description,
                type_name: src.name,
                coordinates: src.coordinates.iter().map(|c| c.to_string()).collect(),
                constraints: M,
                parameters: src.parameters.iter().map(|p| p.to_string()).zip(sys.parameter_values()).collect(),
                q0,
                v0,
            }
        }
        match self {
            SystemKind::Particle => facts::<NonholonomicParticle, 3, 1>(
                self,
                "nonholonomic particle, L = |v|²/2 − q1² − q2², v3 − q2 v1 = 0 (§8.1)",
            ),
            SystemKind::Skate => {
                facts::<Skate, 3, 1>(self, "skate on an inclined plane, cos(θ) ẏ − sin(θ) ẋ = 0 (§8.2)")
            }
            SystemKind::Robot => facts::<MobileRobot, 4, 2>(
                self,
                "mobile robot with fixed orientation and potential 10 sin(q4), two rolling constraints (§8.3)",
            ),
            SystemKind::McLachlanPerlmutter7 => facts::<McLachlanPerlmutter7, 7, 1>(
                self,
                "McLachlan–Perlmutter particles, n = 7, chaotic, v1 + q5 v5 + q6 v6 + q7 v7 = 0 (§8.4)",
            ),
            SystemKind::Turntable => facts::<TurntableSkate, 3, 1>(
                self,
                "skate on a table turning at ω(t) = ω0(1 + ε sin νt): rheonomic affine constraint, energy not conserved",
            ),
            SystemKind::AppellHamel => facts::<AppellHamel, 3, 1>(
                self,
                "Appell–Hamel particle under gravity, v3² − a²(v1² + v2²) = 0 (nonlinear in v)",
            ),
            SystemKind::Sleigh => facts::<ChaplyginSleigh, 3, 1>(
                self,
                "Chaplygin sleigh on an inclined plane: q-dependent mass matrix, no sideways slip",
            ),
            SystemKind::DoublePendulum => {
                facts::<DoublePendulum, 2, 0>(self, "planar double pendulum, no constraints, non-separable L")
            }
        }
    }
}

/// The paper's initial values (for `mp7`: the member `j = 0` of the §8.4
/// ensemble, see [`mp7_initial_values`]); for the systems not in the paper,
/// consistent values chosen here.
pub fn paper_initial_values(kind: SystemKind) -> (Vec<f64>, Vec<f64>) {
    match kind {
        SystemKind::Particle => (vec![1.0, 0.0, 0.0], vec![0.0, 1.0, 0.0]),
        SystemKind::Skate => (vec![0.0; 3], vec![0.0, 0.0, 1.0]),
        SystemKind::Robot => (vec![0.0; 4], vec![1.0, 0.0, 0.0, 1.0]),
        SystemKind::McLachlanPerlmutter7 => mp7_initial_values(0, 9),
        // Not from the paper: consistent values chosen for this program.
        SystemKind::Turntable => (vec![1.0, 0.0, 0.0], vec![0.5, 1.0, 0.5]),
        // Falling (v3 < 0): rising would stop at v = 0, where K = ∂k/∂v
        // vanishes and the method's Newton matrix is singular.
        SystemKind::AppellHamel => (vec![0.0; 3], vec![1.0, 0.0, -0.5]),
        SystemKind::Sleigh => (vec![0.0; 3], vec![1.0, 0.0, 0.5]),
        SystemKind::DoublePendulum => (vec![1.0, 0.5], vec![0.0, 0.0]),
    }
}

/// Initial values `j` of the §8.4 ensemble with `J + 1` members:
/// `q = (α_j, 0.6, 0.4, 0.2, 1, 1, 1)`, `v = (0, β_j, 0, 0, 0, 0, 0)` with
/// `α_j = cos(jπ/(2J))`, `β_j = sin(jπ/(2J))`.
///
/// The paper prints six velocity entries `(0, β_j, 0, 0, 0, 0)` for `n = 7`.
/// Reading them as `v = (0, β_j, 0, 0, 0, 0, 0)` is the consistent choice:
/// the constraint `v1 + q5 v5 + q6 v6 + q7 v7 = 0` holds, and
/// `E = β_j²/2 + (α_j² + 3.56 + 1 + 0.56)/2 = 3.06` for every `j`, as the
/// paper states.
pub fn mp7_initial_values(j: usize, big_j: usize) -> (Vec<f64>, Vec<f64>) {
    let theta = if big_j == 0 { 0.0 } else { j as f64 * std::f64::consts::PI / (2.0 * big_j as f64) };
    let (alpha, beta) = (theta.cos(), theta.sin());
    (vec![alpha, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0], vec![0.0, beta, 0.0, 0.0, 0.0, 0.0, 0.0])
}

/// Errors of a run; each says what to change.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The system name is not in the catalogue.
    #[error(
        "unknown system `{name}`; known: particle, skate, robot, mp7, turntable, appell-hamel, sleigh, \
         double-pendulum (see `spark list`)"
    )]
    UnknownSystem {
        /// The name given.
        name: String,
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
    #[error("{what} has {got} entries but system `{system}` has {expected} coordinates")]
    Dimension {
        /// `q0` or `v0`.
        what: &'static str,
        /// The system.
        system: &'static str,
        /// Entries given.
        got: usize,
        /// Entries needed.
        expected: usize,
    },
    /// A parameter was rejected by the system.
    #[error(transparent)]
    Parameter(#[from] spark_runtime::SystemError),
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
}

impl RunSpec {
    /// A run of `system` from the paper's initial values.
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
        }
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
    /// Statistics over every step (not only the samples).
    pub stats: RunStats,
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
    /// Mean Newton iterations per step.
    pub newton_iterations_mean: f64,
    /// Wall-clock time of the integration.
    #[serde(serialize_with = "seconds")]
    pub wall_time: Duration,
    /// CPU time of the integrating thread (Linux `/proc/thread-self/schedstat`;
    /// `None` where unavailable). Unlike the wall time it does not grow when
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

/// CPU time consumed so far by the calling thread, from the first field of
/// `/proc/thread-self/schedstat` (nanoseconds on the CPU).
fn thread_cpu_time() -> Option<Duration> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = text.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

fn seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Called with the number of steps done since the previous call (every few
/// thousand steps and at the end), for progress bars.
pub type Tick<'a> = &'a (dyn Fn(u64) + Sync);

/// How often the progress callback fires.
const TICK_EVERY: usize = 4096;

/// The one place that maps run-time `(system, s)` to a concrete stepper type.
macro_rules! dispatch {
    (@stages $sys:ty, $spec:expr, $tick:expr) => {
        match $spec.stages {
            1 => dispatch!(@one $sys, 1, $spec, $tick),
            2 => dispatch!(@one $sys, 2, $spec, $tick),
            3 => dispatch!(@one $sys, 3, $spec, $tick),
            4 => dispatch!(@one $sys, 4, $spec, $tick),
            5 => dispatch!(@one $sys, 5, $spec, $tick),
            s => Err(RunError::StagesNotCompiled { method: $spec.method, stages: s, max: MAX_DISPATCH_STAGES }),
        }
    };
    (@one $sys:ty, $s:literal, $spec:expr, $tick:expr) => {
        run_with::<$sys, { <$sys>::N }, { <$sys>::M }, $s, { $s * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
            $spec, $tick,
        )
    };
    ($spec:expr, $tick:expr) => {{
        let spec: &RunSpec = $spec;
        match spec.system {
            SystemKind::Particle => dispatch!(@stages NonholonomicParticle, spec, $tick),
            SystemKind::Skate => dispatch!(@stages Skate, spec, $tick),
            SystemKind::Robot => dispatch!(@stages MobileRobot, spec, $tick),
            SystemKind::McLachlanPerlmutter7 => dispatch!(@stages McLachlanPerlmutter7, spec, $tick),
            SystemKind::Turntable => dispatch!(@stages TurntableSkate, spec, $tick),
            SystemKind::AppellHamel => dispatch!(@stages AppellHamel, spec, $tick),
            SystemKind::Sleigh => dispatch!(@stages ChaplyginSleigh, spec, $tick),
            SystemKind::DoublePendulum => dispatch!(@stages DoublePendulum, spec, $tick),
        }
    }};
}

/// Runs `spec`, calling `tick` as steps complete.
pub fn run(spec: &RunSpec, tick: Tick<'_>) -> Result<RunResult, RunError> {
    if !(spec.h.is_finite() && spec.h != 0.0) {
        return Err(RunError::Invalid(format!("step size h = {} must be finite and nonzero", spec.h)));
    }
    let (min, max) = spec.method.stage_range();
    if spec.stages < min || spec.stages > max {
        return Err(TableauError::UnsupportedStages { method: spec.method, s: spec.stages, min, max }.into());
    }
    dispatch!(spec, tick)
}

fn vector<const N: usize>(what: &'static str, system: &'static str, x: &[f64]) -> Result<Vector<N>, RunError> {
    if x.len() != N {
        return Err(RunError::Dimension { what, system, got: x.len(), expected: N });
    }
    Ok(Vector::<N>::from_column_slice(x))
}

/// The generic run: one stepper type, fixed steps, per-step observation.
fn run_with<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    spec: &RunSpec,
    tick: Tick<'_>,
) -> Result<RunResult, RunError>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let key = spec.system.key();
    let make = || -> Result<Sys, RunError> {
        let mut sys = Sys::default();
        for (name, value) in &spec.parameters {
            sys.set_parameter(name, *value)?;
        }
        Ok(sys)
    };
    let q0 = vector::<N>("q0", key, &spec.q0)?;
    let v0 = vector::<N>("v0", key, &spec.v0)?;
    // A second instance evaluates energy and constraints in the observer,
    // which cannot borrow the stepper's system while the stepper runs.
    let probe = make()?;
    let tableau = Tableau::<S>::new(spec.method)?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(make()?, tableau).with_options(spec.newton);
    // Check (or project) v0 here, so that E0 and the initial residual refer
    // to the state actually integrated.
    let v0 = consistent_velocity(&probe, spec.t0, &q0, &v0, spec.consistency).map_err(|e| RunError::Integration {
        system: key,
        method: spec.method,
        stages: S,
        source: IntegrationError::Initial(e),
    })?;
    let e0 = probe.energy(spec.t0, &q0, &v0);
    let mut max_e: f64 = 0.0;
    let mut max_k: f64 = probe.constraint(spec.t0, &q0, &v0).amax();
    let mut count = 0usize;
    let mut observer = |s: &spark_runtime::State<N>, _iters: usize| {
        max_e = max_e.max((probe.energy(s.t, &s.q, &s.v) - e0).abs());
        max_k = max_k.max(probe.constraint(s.t, &s.q, &s.v).amax());
        count += 1;
        if count.is_multiple_of(TICK_EVERY) {
            tick(TICK_EVERY as u64);
        }
    };
    let options = RunOptions {
        observe: Observe { energy: true, constraint_residual: true, multipliers: false },
        record_every: spec.record_every,
        consistency: spec.consistency,
        ..RunOptions::default()
    };
    let start = Instant::now();
    let cpu_start = thread_cpu_time();
    let traj = stepper
        .integrate(spec.t0, &q0, &v0, Schedule::Fixed { h: spec.h, steps: spec.steps }, &options, &mut observer)
        .map_err(|source| RunError::Integration { system: key, method: spec.method, stages: S, source })?;
    let wall_time = start.elapsed();
    let cpu_time = match (cpu_start, thread_cpu_time()) {
        (Some(a), Some(b)) if b >= a => Some(b - a),
        _ => None,
    };
    tick((count % TICK_EVERY) as u64);
    let samples = &traj.samples;
    let column = |f: &dyn Fn(&spark_runtime::Sample<N, M>) -> f64| samples.iter().map(f).collect::<Vec<f64>>();
    Ok(RunResult {
        system: key,
        coordinates: Sys::SOURCE.coordinates.iter().map(|c| c.to_string()).collect(),
        method: spec.method,
        stages: S,
        h: spec.h,
        t: column(&|s| s.t),
        q: (0..N).map(|i| column(&|s| s.q[i])).collect(),
        v: (0..N).map(|i| column(&|s| s.v[i])).collect(),
        energy: column(&|s| s.energy.unwrap_or(f64::NAN)),
        constraint: column(&|s| s.constraint_residual.unwrap_or(f64::NAN)),
        stats: RunStats {
            steps: traj.report.steps,
            e0,
            max_energy_error: max_e,
            max_constraint_residual: max_k,
            newton_iterations_mean: traj.report.newton_iterations_mean,
            wall_time,
            cpu_time,
        },
    })
}
