//! What accuracy costs in time: work-precision sweeps of every SPARK method
//! on any registered system ([`crate::catalog`]), with peers measured in the
//! same run.
//!
//! For one system this module integrates from its registered (for the
//! paper's systems: the paper's) initial values to
//! a final time `T` with `n = n₀·2^k` steps for every method family and stage
//! count, measures the global error in `q` and `v` at `T` against the
//! independent Gragg–Bulirsch–Stoer reference
//! ([`spark_runtime::reference`]), the largest energy error along the run,
//! and the wall time of a run (median of repeats, observers off). Peers run
//! on the same systems in the same process, so their ratios survive a noisy
//! machine:
//! - the same stepper with `num-dual` derivatives ([`crate::peers::dual`])
//!   and with central-difference Jacobians ([`crate::peers::finite_difference`]),
//!   at the same step counts (so at equal accuracy);
//! - `ode_solvers`' DOP853 on the ψ-eliminated ODE ([`crate::peers::ode`])
//!   over a tolerance sweep;
//! - CasADi-generated C in two variants (CasADi's Newton iteration with its
//!   QR solve; CasADi's residual and dense Jacobian with a hand-written LU
//!   Newton) on the paper's systems, and SciPy `solve_ivp` (DOP853, Radau)
//!   on every system without external or non-ideal forces, by running
//!   `casadi/peers/peers.py` ([`external`]);
//! - the same generated stepper driven by tolerances
//!   ([`spark_runtime::integrate_adaptive`], every method) and by the
//!   reversible step-size rule ([`spark_runtime::integrate_reversible`],
//!   symmetric methods on systems with a step density, [`step_density`]).
//!
//! [`report`] turns the points into CSV, Markdown tables and figures;
//! [`per_step`] times SPARK and the Newton-LU peer per step at the paper's
//! step sizes.

pub mod adaptive_energy;
pub mod external;
pub mod flops;
pub mod per_step;
pub mod report;
pub mod scaling;
mod sweep;

use crate::catalog::{
    visit_system, Dispatch, StageVisitor, SystemEntry, SystemKind, SystemVisitor, MAX_DISPATCH_STAGES,
};
use crate::peers::dual::{visit_twin, DualTwin, TwinVisitor};
use crate::systems::NonholonomicParticle;
use spark_runtime::reference::{self, ReferenceOptions};
use spark_runtime::TableauTable;
use spark_runtime::{Method, NewtonMode, NonholonomicSystem, Tableau, TableauError, Vector};
use std::marker::PhantomData;
use std::path::PathBuf;
use std::time::Duration;
use sweep::{sweep_dop853, Ctx, Sweep, SweepWithPeers};

/// Which derivative code drives the SPARK stepper.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum Provider {
    /// The code `nonholonomic_system!` generated.
    Generated,
    /// Runtime forward-mode AD (`num-dual`) of a generic Lagrangian.
    NumDual,
    /// Generated stage values, Jacobians by central differences.
    FiniteDifference,
}

impl Provider {
    /// The solver label used in tables and figures.
    pub const fn label(self) -> &'static str {
        match self {
            Provider::Generated => "SPARK (generated)",
            Provider::NumDual => "SPARK + num-dual",
            Provider::FiniteDifference => "SPARK + finite differences",
        }
    }
}

/// Solver label of the generated-code SPARK runs with tolerance-driven
/// steps ([`spark_runtime::integrate_adaptive`]); their
/// [`Point::setting`] is `rtol = atol`, [`Point::steps`] the accepted steps.
pub const SPARK_ADAPTIVE: &str = "SPARK adaptive (generated)";

/// Solver label of the generated-code SPARK runs with the reversible
/// step-size rule ([`spark_runtime::integrate_reversible`], symmetric
/// methods, systems with a [`step_density`]); their [`Point::setting`] is the
/// `rtol = atol` that fixes the scale `ε`, [`Point::steps`] the steps.
pub const SPARK_REVERSIBLE: &str = "SPARK reversible adaptive (generated)";

/// A step density `σ(q)` (steps per unit time, up to the scale `ε`) of the
/// reversible runs.
pub type DensityFn = dyn Fn(&[f64]) -> f64 + Send + Sync;

/// An owned [`DensityFn`].
pub type StepDensity = Box<DensityFn>;

/// The step density of the reversible runs on `kind`, for the systems with
/// a known local time scale: `orbit`'s Kepler time scale `r^{3/2}` gives
/// `σ = (x² + y² + ε²)^{−3/4}` (even in `v`, as reversibility needs). The
/// paper's systems have nearly constant time scales, on which the rule
/// reduces to fixed steps; they have none. A system with a density is
/// marked `steps: reversible` in the catalogue, which compiles the
/// reversible driver for it.
pub fn step_density(kind: SystemKind) -> Option<StepDensity> {
    match kind {
        SystemKind::Orbit => {
            let softening = crate::systems::OrbitParticle::default().parameter_values()[1];
            Some(Box::new(move |q: &[f64]| (q[0] * q[0] + q[1] * q[1] + softening * softening).powf(-0.75)))
        }
        _ => None,
    }
}

/// One measured run.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Point {
    /// System key.
    pub system: String,
    /// Who integrated: e.g. `SPARK (generated)`, `SciPy`, `CasADi C`.
    pub solver: String,
    /// Method label, e.g. `Gauss s=2` or `DOP853`.
    pub method: String,
    /// Stage count (0 for the ODE solvers).
    pub stages: usize,
    /// Step size (fixed-step methods) or tolerance (adaptive ones).
    pub setting: f64,
    /// Steps taken.
    pub steps: usize,
    /// `max_i |q_i(T) − q_ref,i(T)|`.
    pub error_q: f64,
    /// `max_i |v_i(T) − v_ref,i(T)|`.
    pub error_v: f64,
    /// Largest `|E − E₀|` along the run (NaN where not measured).
    pub energy_error: f64,
    /// Median wall time of one run in seconds.
    pub wall_time: f64,
    /// Median CPU time of the measuring thread for one run in seconds: what
    /// the run costs when other jobs compete for the cores (NaN if unknown).
    pub cpu_time: f64,
    /// [`Point::time`]` / steps`.
    pub time_per_step: f64,
    /// Mean Newton iterations per step (NaN where not applicable).
    pub newton_iterations: f64,
    /// Timed repeats behind the median.
    pub repeats: usize,
}

impl Point {
    /// The global error `max(error_q, error_v)`.
    pub fn error(&self) -> f64 {
        self.error_q.max(self.error_v)
    }
    /// The cost of one run used in tables and figures: the thread's CPU time
    /// where measured (robust against other jobs on the machine), else the
    /// wall time.
    pub fn time(&self) -> f64 {
        if self.cpu_time.is_finite() && self.cpu_time > 0.0 {
            self.cpu_time
        } else {
            self.wall_time
        }
    }
}

/// The shortest final time `T` a sweep accepts: the reference solution's
/// steps cannot be shorter than the resolution of `t` near 0, `4ε ≈ 8.9e-16`
/// (it refuses them as too small), so over a shorter interval no error can
/// be measured.
pub const MIN_FINAL_TIME: f64 = 1e-15;

/// The longest final time `T` a sweep accepts, 1000 times the default
/// `T = 10`: the reference solution gives up after
/// [`ReferenceOptions::max_steps`] (10⁶) step attempts, which it reaches on
/// the skate near `T = 2·10⁴` (9 s) and on the sleigh near `T = 3.3·10³`; a
/// longer interval only runs longer before it fails.
pub const MAX_FINAL_TIME: f64 = 1e4;

/// The most timed repeats per point (the repeats of short runs already stop
/// at 1000): each repeat is a whole run, and a count near `usize::MAX` never
/// ends.
pub const MAX_REPEATS: usize = 1000;

/// Settings of a work-precision run.
#[derive(Clone, Debug, PartialEq)]
pub struct WorkPrecisionConfig {
    /// Systems to measure.
    pub systems: Vec<SystemKind>,
    /// Output folder.
    pub out: PathBuf,
    /// Final time `T`.
    pub final_time: f64,
    /// Smallest step count `n₀` of the sweep.
    pub min_steps: usize,
    /// Largest step count of the sweep.
    pub max_steps: usize,
    /// A sweep stops once a run takes longer than this.
    pub max_run_time: Duration,
    /// A sweep stops once the error is below this (round-off floor).
    pub floor_error: f64,
    /// Timed repeats per point (at least; short runs repeat until
    /// [`WorkPrecisionConfig::min_timing`] of total time).
    pub repeats: usize,
    /// Smallest total timed duration per point.
    pub min_timing: Duration,
    /// Methods `(method, s)` also run with the num-dual and
    /// finite-difference derivative providers and exported to CasADi.
    pub peer_methods: Vec<(Method, usize)>,
    /// Tolerances of the DOP853 and SciPy sweeps.
    pub tolerances: Vec<f64>,
    /// Python interpreter with casadi and scipy (`None`: skip those peers).
    pub python: Option<PathBuf>,
    /// The CasADi/SciPy peer script.
    pub peers_script: PathBuf,
    /// Target errors of the "cheapest method" table.
    pub targets: Vec<f64>,
    /// Newton mode of every SPARK-stepper series (generated, num-dual,
    /// finite differences); the CasADi C peers always do full Newton.
    pub newton: NewtonMode,
}

impl WorkPrecisionConfig {
    /// The full measurement: all paper systems, `T = 10`, steps from 2 to
    /// 2¹⁷, peers on Gauss s = 2 and 4 and Lobatto IIIA-B s = 3. The step
    /// counts start at 2 so that a high-order method's curve reaches the
    /// loosest target error from above: the time to reach an error is
    /// interpolated between the points on either side of it, and a curve
    /// whose first point is already below the target is charged that
    /// point's cost.
    pub fn full(out: impl Into<PathBuf>) -> Self {
        WorkPrecisionConfig {
            systems: SystemKind::ALL.iter().copied().filter(|k| k.entry().paper).collect(),
            out: out.into(),
            final_time: 10.0,
            min_steps: 2,
            max_steps: 1 << 17,
            max_run_time: Duration::from_millis(400),
            floor_error: 2e-13,
            repeats: 5,
            min_timing: Duration::from_millis(20),
            peer_methods: vec![(Method::Gauss, 2), (Method::Gauss, 4), (Method::LobattoIIIAB, 3)],
            tolerances: (3..=13).map(|k| 10f64.powi(-k)).collect(),
            python: Some(PathBuf::from("casadi/.venv/bin/python")),
            peers_script: PathBuf::from("casadi/peers/peers.py"),
            targets: vec![1e-4, 1e-8, 1e-12],
            newton: NewtonMode::Full,
        }
    }

    /// A seconds-long smoke run of every code path (tests, CI).
    pub fn quick(out: impl Into<PathBuf>) -> Self {
        WorkPrecisionConfig {
            final_time: 1.0,
            min_steps: 4,
            max_steps: 64,
            max_run_time: Duration::from_millis(50),
            repeats: 1,
            min_timing: Duration::ZERO,
            peer_methods: vec![(Method::Gauss, 2)],
            tolerances: vec![1e-4, 1e-8],
            python: None,
            ..Self::full(out)
        }
    }
}

/// Every method family the sweep covers, with each of its stage counts up
/// to [`MAX_DISPATCH_STAGES`].
pub fn method_variants() -> Vec<(Method, usize)> {
    use Method::*;
    [Gauss, LobattoIIIAB, LobattoIIIABD, SymplecticEulerI, SymplecticEulerII, LobattoIIIBALda]
        .into_iter()
        .flat_map(|m| {
            let (lo, hi) = m.stage_range();
            (lo..=hi.min(MAX_DISPATCH_STAGES)).map(move |s| (m, s))
        })
        .collect()
}

/// Errors of a work-precision run.
#[derive(Debug, thiserror::Error)]
pub enum WorkPrecisionError {
    /// The reference solution failed.
    #[error("reference solution of {system} over [0, {final_time:.3e}]: {source}{}", reference_hint(source))]
    Reference {
        /// System key.
        system: &'static str,
        /// The final time `T` it was to reach.
        final_time: f64,
        /// Cause.
        source: reference::ReferenceError,
    },
    /// A tableau could not be built.
    #[error(transparent)]
    Tableau(#[from] spark_runtime::TableauError),
    /// Output could not be written.
    #[error(transparent)]
    Output(#[from] crate::report::files::OutputError),
    /// A figure could not be drawn.
    #[error(transparent)]
    Plot(#[from] crate::report::plot::PlotError),
    /// The external peers failed.
    #[error("external peers (CasADi C, SciPy): {0}")]
    External(String),
    /// Invalid settings.
    #[error("invalid work-precision settings: {0}")]
    Invalid(String),
}

/// What a user of the sweep can change when the reference solution fails:
/// its tolerances and step limit are fixed, the final time is not.
fn reference_hint(e: &reference::ReferenceError) -> &'static str {
    match e {
        reference::ReferenceError::TooManySteps { .. } | reference::ReferenceError::StepSizeTooSmall { .. } => {
            " (in a work-precision sweep the reference's tolerances and step limit are fixed: measure over a \
             shorter final time, --t-end)"
        }
        reference::ReferenceError::NonFinite { .. } | reference::ReferenceError::NonFiniteState { .. } => {
            " (a work-precision sweep starts from the system's default state, which leaves the finite numbers \
             before this final time: measure over a shorter final time, --t-end)"
        }
        _ => "",
    }
}

/// The reference end state and the run's starting point.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Problem {
    /// System key.
    pub system: &'static str,
    /// Initial coordinates.
    pub q0: Vec<f64>,
    /// Initial velocities.
    pub v0: Vec<f64>,
    /// Final time.
    pub final_time: f64,
    /// Reference `q(T)`.
    pub q_ref: Vec<f64>,
    /// Reference `v(T)`.
    pub v_ref: Vec<f64>,
}

/// Everything measured on one system.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SystemMeasurement {
    /// The problem solved.
    pub problem: Problem,
    /// Every measured run.
    pub points: Vec<Point>,
    /// Why a peer was not measured, if one was not.
    pub missing: Vec<String>,
    /// Operation counts of the generated code.
    pub operations: spark_runtime::OperationCounts,
    /// `N`, `M`.
    pub dimensions: (usize, usize),
}

/// Sweeps one `(method, s)` of one system; the catalogue's stage dispatch
/// underneath picks the monomorphized stepper.
type SweepFn<'f, const N: usize> =
    dyn Fn(&Ctx<'_, N>, Method, usize, bool, &mut Vec<Point>) -> Result<(), WorkPrecisionError> + 'f;

/// The stage dispatch error as a work-precision error.
fn not_compiled(e: crate::catalog::DispatchError) -> WorkPrecisionError {
    WorkPrecisionError::Invalid(e.to_string())
}

/// Measures one system: reference, SPARK sweeps (with the same-stepper peers
/// where `sweep` runs them), DOP853.
fn measure_system<Sys, const N: usize, const M: usize, const Y: usize>(
    entry: &'static SystemEntry,
    cfg: &WorkPrecisionConfig,
    progress: &dyn Fn(&str),
    sweep: &SweepFn<'_, N>,
    twin: bool,
) -> Result<SystemMeasurement, WorkPrecisionError>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let key = entry.name;
    let (q0, v0) = (Vector::<N>::from_column_slice(entry.q0), Vector::<N>::from_column_slice(entry.v0));
    let sys = Sys::default();
    progress(&format!("{key}: reference solution"));
    let exact = reference::integrate(&sys, 0.0, &q0, &v0, cfg.final_time, &ReferenceOptions::default())
        .map_err(|source| WorkPrecisionError::Reference { system: key, final_time: cfg.final_time, source })?;
    let (q_ref, v_ref) = (exact.q[0], exact.v[0]);
    let density = step_density(entry.kind);
    let ctx = Ctx { cfg, key, q0, v0, q_ref, v_ref, density: density.as_deref() };
    let mut points = Vec::new();
    let mut missing = Vec::new();
    for (method, s) in method_variants() {
        progress(&format!("{key}: {}", method.label(s)));
        let peers = twin && cfg.peer_methods.contains(&(method, s));
        sweep(&ctx, method, s, peers, &mut points)?;
    }
    if !twin {
        missing.push(format!(
            "num-dual and finite-difference peers: only for the paper's systems (they need a hand-written num-dual \
             twin); not run for `{key}`"
        ));
    }
    if Sys::HAS_FORCING || Sys::HAS_NONIDEAL_FORCE {
        // The DOP853 peer's right-hand side (peers::ode) has no f or N.
        missing.push(format!(
            "ode_solvers DOP853: its right-hand side has no external or non-ideal force; not run for `{key}`"
        ));
    } else {
        progress(&format!("{key}: ode_solvers DOP853"));
        sweep_dop853::<Sys, N, M, Y>(&ctx, &mut points);
    }
    let problem = Problem {
        system: key,
        q0: q0.iter().copied().collect(),
        v0: v0.iter().copied().collect(),
        final_time: cfg.final_time,
        q_ref: q_ref.iter().copied().collect(),
        v_ref: v_ref.iter().copied().collect(),
    };
    Ok(SystemMeasurement { problem, points, missing, operations: Sys::OPERATIONS, dimensions: (N, M) })
}

/// The per-system half of [`measure`], through the catalogue.
struct MeasureVisitor<'a> {
    cfg: &'a WorkPrecisionConfig,
    progress: &'a dyn Fn(&str),
}

impl SystemVisitor for MeasureVisitor<'_> {
    type Output = Result<SystemMeasurement, WorkPrecisionError>;
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        entry: &'static SystemEntry,
    ) -> Self::Output {
        let sweep = |ctx: &Ctx<'_, N>, method: Method, s: usize, _peers: bool, points: &mut Vec<Point>| {
            Sys::with_stages(s, Sweep::<Sys, N> { ctx, method, points, system: PhantomData }).map_err(not_compiled)?
        };
        measure_system::<Sys, N, M, Y>(entry, self.cfg, self.progress, &sweep, false)
    }
}

impl TwinVisitor for MeasureVisitor<'_> {
    type Output = Result<SystemMeasurement, WorkPrecisionError>;
    fn visit<Sys: Dispatch<N, M> + DualTwin<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        entry: &'static SystemEntry,
    ) -> Self::Output {
        let sweep = |ctx: &Ctx<'_, N>, method: Method, s: usize, peers: bool, points: &mut Vec<Point>| {
            let plain = Sweep::<Sys, N> { ctx, method, points, system: PhantomData };
            if peers {
                Sys::with_stages(s, SweepWithPeers(plain)).map_err(not_compiled)?
            } else {
                Sys::with_stages(s, plain).map_err(not_compiled)?
            }
        };
        measure_system::<Sys, N, M, Y>(entry, self.cfg, self.progress, &sweep, true)
    }
}

/// Tableau exports of the peer methods (for the CasADi step).
fn peer_tableaux(cfg: &WorkPrecisionConfig) -> Result<Vec<TableauTable>, WorkPrecisionError> {
    /// The tableau of one method with `S` stages.
    struct Export(Method);
    impl StageVisitor<NonholonomicParticle, 3, 1> for Export {
        type Output = Result<TableauTable, TableauError>;
        fn visit<const S: usize, const D: usize>(self) -> Self::Output {
            Ok(TableauTable::of(&Tableau::<S>::new(self.0)?))
        }
    }
    // Any catalogued type carries the stage dispatch; the tableau does not
    // depend on the system.
    cfg.peer_methods
        .iter()
        .map(|&(method, s)| Ok(NonholonomicParticle::with_stages(s, Export(method)).map_err(not_compiled)??))
        .collect()
}

/// Whether the ψ-eliminated ODE of the ODE-solver peers (DOP853, Radau)
/// describes `kind`: their right-hand side has no external or non-ideal
/// force.
fn has_ode_form(kind: SystemKind) -> bool {
    struct OdeForm;
    impl SystemVisitor for OdeForm {
        type Output = bool;
        fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
            self,
            _: &'static SystemEntry,
        ) -> bool {
            !(Sys::HAS_FORCING || Sys::HAS_NONIDEAL_FORCE)
        }
    }
    visit_system(kind, OdeForm)
}

/// Measures one system with every Rust solver and, when configured, the
/// external peers (CasADi C on the paper's systems; SciPy's DOP853 and
/// Radau on every system their ODE describes).
pub fn measure(
    kind: SystemKind,
    cfg: &WorkPrecisionConfig,
    progress: &dyn Fn(&str),
) -> Result<SystemMeasurement, WorkPrecisionError> {
    // The paper's systems have num-dual twins and run the same-stepper
    // peers; the others run SPARK, DOP853 and the SciPy solvers.
    let mut m = match visit_twin(kind, MeasureVisitor { cfg, progress }) {
        Ok(m) => m?,
        Err(visitor) => visit_system(kind, visitor)?,
    };
    let paper = kind.entry().paper;
    if !paper {
        let key = kind.key();
        if !has_ode_form(kind) {
            m.missing.push(format!(
                "CasADi C and SciPy: the CasADi C peers run only on the paper's systems (particle, skate, robot, \
                 mp7), and SciPy's right-hand side has no external or non-ideal force; not run for `{key}`"
            ));
            return Ok(m);
        }
        m.missing.push(format!(
            "CasADi C: the CasADi C peers run only on the paper's systems (particle, skate, robot, mp7); not run for \
             `{key}`"
        ));
    }
    let peers = if paper { "CasADi C and SciPy" } else { "SciPy" };
    match &cfg.python {
        None => m.missing.push(format!("{peers}: not run (no Python interpreter configured)")),
        Some(python) => {
            progress(&format!("{}: {peers} (external)", kind.key()));
            let tableaux = if paper { peer_tableaux(cfg)? } else { Vec::new() };
            match external::run(python, &cfg.peers_script, &cfg.out, kind, &m, &tableaux, cfg, paper) {
                Ok(mut pts) => m.points.append(&mut pts),
                Err(e) => m.missing.push(format!("{peers}: {e}")),
            }
        }
    }
    Ok(m)
}

/// Measures every configured system, writes CSV, tables and figures into
/// `cfg.out`, and returns the measurements.
pub fn run_work_precision(
    cfg: &WorkPrecisionConfig,
    progress: &dyn Fn(&str),
) -> Result<Vec<SystemMeasurement>, WorkPrecisionError> {
    if cfg.systems.is_empty() {
        return Err(WorkPrecisionError::Invalid("no systems selected".into()));
    }
    if !(MIN_FINAL_TIME..=MAX_FINAL_TIME).contains(&cfg.final_time)
        || cfg.min_steps == 0
        || cfg.max_steps < cfg.min_steps
        || !(1..=MAX_REPEATS).contains(&cfg.repeats)
    {
        return Err(WorkPrecisionError::Invalid(format!(
            "need {MIN_FINAL_TIME:e} ≤ T ≤ {MAX_FINAL_TIME:e}, 1 ≤ min_steps ≤ max_steps and 1 ≤ repeats ≤ \
             {MAX_REPEATS} (T = {:.3e}, steps {}..{}, repeats {})",
            cfg.final_time, cfg.min_steps, cfg.max_steps, cfg.repeats
        )));
    }
    // Created and locked before measuring; the files appear together at the
    // end, the summary last.
    let mut out = crate::report::files::OutputDir::open(&cfg.out)?;
    let mut all = Vec::new();
    for &kind in &cfg.systems {
        let m = measure(kind, cfg, progress)?;
        report::write_system(&m, cfg, &mut out)?;
        all.push(m);
    }
    report::write_summary(&all, cfg, &mut out)?;
    out.commit()?;
    Ok(all)
}
