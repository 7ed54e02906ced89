//! The JSON shapes of the cross-check's document: a system's neutral source,
//! its effect flags, every trait output at one sample point, and one whole
//! SPARK step. Plain data with serde; [`super::sample`] and
//! [`super::export_step`] fill them.

use serde::Serialize;
use spark_runtime::{NonholonomicSystem, OperationCounts, Structure, SystemSource, TableauTable};

/// The neutral source of a system, owned (see [`SystemSource`]).
#[derive(Clone, Debug, Serialize)]
pub struct SourceExport {
    /// The type's name.
    pub name: String,
    /// Coordinates, in order.
    pub coordinates: Vec<String>,
    /// Runtime parameters, in order.
    pub parameters: Vec<String>,
    /// `L` as an S-expression.
    pub lagrangian: String,
    /// `k_1..k_M` as S-expressions.
    pub constraints: Vec<String>,
    /// External force `f_1..f_N` (empty when absent).
    pub external_force: Vec<String>,
    /// Non-ideal constraint force `N_1..N_N`, may use `(psi j)` (empty when absent).
    pub nonideal_force: Vec<String>,
    /// Holonomic constraints `g_1..g_M`, `"0"` for nonholonomic rows (empty when absent).
    pub holonomic: Vec<String>,
    /// Declared events `g(t, q, v)`, in index order (empty when none).
    pub events: Vec<EventSourceExport>,
}

/// One declared event: its name, which crossings count, and its function.
#[derive(Clone, Debug, Serialize)]
pub struct EventSourceExport {
    /// The event's name.
    pub name: String,
    /// `Rising`, `Falling` or `Both`.
    pub direction: spark_runtime::Direction,
    /// Whether its first crossing ends a run.
    pub terminal: bool,
    /// The event function as an S-expression.
    pub function: String,
}

impl From<&spark_runtime::EventSpec> for EventSourceExport {
    fn from(e: &spark_runtime::EventSpec) -> Self {
        Self { name: e.name.to_owned(), direction: e.direction, terminal: e.terminal, function: e.source.to_owned() }
    }
}

impl From<&SystemSource> for SourceExport {
    fn from(s: &SystemSource) -> Self {
        Self {
            name: s.name.to_owned(),
            coordinates: s.coordinates.iter().map(|c| (*c).to_owned()).collect(),
            parameters: s.parameters.iter().map(|c| (*c).to_owned()).collect(),
            lagrangian: s.lagrangian.to_owned(),
            constraints: s.constraints.iter().map(|c| (*c).to_owned()).collect(),
            external_force: s.external_force.iter().map(|c| (*c).to_owned()).collect(),
            nonideal_force: s.nonideal_force.iter().map(|c| (*c).to_owned()).collect(),
            holonomic: s.holonomic.iter().map(|c| (*c).to_owned()).collect(),
            events: Vec::new(),
        }
    }
}

impl SourceExport {
    /// The source of `S` with its declared events.
    pub fn of<S: NonholonomicSystem<N, M>, const N: usize, const M: usize>() -> Self {
        Self { events: S::EVENTS.iter().map(EventSourceExport::from).collect(), ..Self::from(&S::SOURCE) }
    }
}

/// One system: source, parameters, structure facts, operation counts, points.
#[derive(Clone, Debug, Serialize)]
pub struct SystemExport {
    /// The system's name in the export: its command-line name, or its name in
    /// the extra list (the key steps refer to).
    pub name: String,
    /// Number of coordinates `N`.
    pub n: usize,
    /// Number of constraints `M`.
    pub m: usize,
    /// The neutral source text.
    pub source: SourceExport,
    /// Parameter values, in the order of `source.parameters`.
    pub parameter_values: Vec<f64>,
    /// Structure facts the generator claims (the Python side checks them).
    pub structure: Structure,
    /// `CONSTANT_STIFFNESS`: the generator's claim that `∂(∇_q L)/∂q` is a
    /// nonzero constant (checked beside the structure facts).
    pub constant_stiffness: bool,
    /// `DIAGONAL_STIFFNESS`: the claim that `∂(∇_q L)/∂q` is diagonal, not
    /// constant and not zero (checked beside the structure facts).
    pub diagonal_stiffness: bool,
    /// Operation counts of the generated code.
    pub operations: OperationCounts,
    /// Which optional effects the trait implementation declares.
    pub effects: EffectsExport,
    /// Sample points with every trait output.
    pub points: Vec<PointExport>,
    /// Points drawn but dropped because some output was not finite
    /// (e.g. `exp` of a huge coordinate); JSON cannot carry them.
    pub skipped_points: usize,
}

/// The `HAS_*` effect constants of a system (the Python side checks them
/// against the source: an effect in the source with its flag off would be
/// silently dropped by the stepper).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct EffectsExport {
    /// `HAS_FORCING`.
    pub forcing: bool,
    /// `HAS_NONIDEAL_FORCE`.
    pub nonideal: bool,
    /// `HAS_HOLONOMIC`.
    pub holonomic: bool,
    /// `HAS_EVENTS`.
    pub events: bool,
}

impl EffectsExport {
    /// The flags of `S`.
    pub fn of<S: NonholonomicSystem<N, M>, const N: usize, const M: usize>() -> Self {
        Self {
            forcing: S::HAS_FORCING,
            nonideal: S::HAS_NONIDEAL_FORCE,
            holonomic: S::HAS_HOLONOMIC,
            events: S::HAS_EVENTS,
        }
    }
}

/// One sample point and everything the trait returned there.
#[derive(Clone, Debug, Serialize)]
pub struct PointExport {
    /// Magnitude class the point was drawn from (`unit`, `tiny`, `huge`, `mixed`, …).
    pub class: String,
    /// Time.
    pub t: f64,
    /// Coordinates.
    pub q: Vec<f64>,
    /// Velocities.
    pub v: Vec<f64>,
    /// Multipliers given to the fused stage functions.
    pub psi: Vec<f64>,
    /// The trait's outputs.
    pub outputs: Outputs,
}

/// Every output of [`NonholonomicSystem`] at one point. Matrices are row-major
/// nested arrays (`rows × columns`, rows may be empty when `M = 0`).
#[derive(Clone, Debug, Serialize)]
pub struct Outputs {
    /// `lagrangian`.
    pub lagrangian: f64,
    /// `energy`.
    pub energy: f64,
    /// `momentum`.
    pub momentum: Vec<f64>,
    /// `force`.
    pub force: Vec<f64>,
    /// `mass_matrix`.
    pub mass_matrix: Vec<Vec<f64>>,
    /// `constraint`.
    pub constraint: Vec<f64>,
    /// `constraint_q`.
    pub constraint_q: Vec<Vec<f64>>,
    /// `constraint_v`.
    pub constraint_v: Vec<Vec<f64>>,
    /// `time_derivatives`.
    pub time_derivatives: TimeExport,
    /// `stage_values`.
    pub stage_values: StageValuesExport,
    /// `stage_jacobians`: the values it returned and the Jacobians.
    pub stage_jacobians: StageJacobiansExport,
    /// `external_force` and `external_force_jacobians` (only with `HAS_FORCING`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub external_force: Option<ForceExport>,
    /// `nonideal_force` and `nonideal_force_jacobians` at the point's `ψ`
    /// (only with `HAS_NONIDEAL_FORCE`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nonideal_force: Option<NonidealExport>,
    /// `holonomic_residual(t, q)` (only with `HAS_HOLONOMIC`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub holonomic_residual: Option<Vec<f64>>,
    /// `event_value` and `event_gradient` of every declared event (only
    /// with `HAS_EVENTS`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub events: Option<EventsExport>,
}

/// The declared events at one point, one row per event.
#[derive(Clone, Debug, Serialize)]
pub struct EventsExport {
    /// `event_value(i, t, q, v)`.
    pub value: Vec<f64>,
    /// `event_gradient(i, t, q, v)`.
    pub gradient: EventGradientExport,
}

/// [`spark_runtime::EventGradient`] of every event, stacked.
#[derive(Clone, Debug, Serialize)]
pub struct EventGradientExport {
    /// `g_i`.
    pub value: Vec<f64>,
    /// `∂g_i/∂t`.
    pub t: Vec<f64>,
    /// `∂g_i/∂q` (one row per event).
    pub q: Vec<Vec<f64>>,
    /// `∂g_i/∂v` (one row per event).
    pub v: Vec<Vec<f64>>,
}

/// An effect evaluated two ways: the plain method's value and what the fused
/// Jacobian method returned (`J`).
#[derive(Clone, Debug, Serialize)]
pub struct EffectExport<J> {
    /// `external_force(t, q, v)` or `nonideal_force(t, q, v, ψ)`.
    pub value: Vec<f64>,
    /// `external_force_jacobians(t, q, v)` or `nonideal_force_jacobians(t, q, v, ψ)`.
    pub jacobians: J,
}

/// The external force `f`.
pub type ForceExport = EffectExport<EffectJacobiansExport>;

/// The non-ideal constraint force `N`.
pub type NonidealExport = EffectExport<NonidealJacobiansExport>;

/// `(f, ∂f/∂q, ∂f/∂v)` (or the same of `N`) as returned together.
#[derive(Clone, Debug, Serialize)]
pub struct EffectJacobiansExport {
    /// The effect's value.
    pub value: Vec<f64>,
    /// Its Jacobian in `q`.
    pub q: Vec<Vec<f64>>,
    /// Its Jacobian in `v`.
    pub v: Vec<Vec<f64>>,
}

/// [`spark_runtime::NonidealJacobians`] as plain arrays: `N`, `∂N/∂q`,
/// `∂N/∂v` and `∂N/∂ψ`.
#[derive(Clone, Debug, Serialize)]
pub struct NonidealJacobiansExport {
    /// `N`, `∂N/∂q`, `∂N/∂v`.
    #[serde(flatten)]
    pub state: EffectJacobiansExport,
    /// `∂N/∂ψ` (`N × M`).
    pub psi: Vec<Vec<f64>>,
}

/// [`spark_runtime::TimeDerivatives`] as plain arrays.
#[derive(Clone, Debug, Serialize)]
pub struct TimeExport {
    /// `∂L/∂t`.
    pub lagrangian_t: f64,
    /// `∂(∇_v L)/∂t`.
    pub momentum_t: Vec<f64>,
    /// `∂(∇_q L)/∂t`.
    pub force_t: Vec<f64>,
    /// `k_t`.
    pub constraint_t: Vec<f64>,
}

/// [`spark_runtime::StageValues`] as plain arrays.
#[derive(Clone, Debug, Serialize)]
pub struct StageValuesExport {
    /// `∇_v L`.
    pub momentum: Vec<f64>,
    /// `∇_q L`.
    pub force: Vec<f64>,
    /// `k`.
    pub constraint: Vec<f64>,
    /// `−Kᵀψ`.
    pub constraint_force: Vec<f64>,
}

/// [`spark_runtime::StageJacobians`] (with the values returned beside them).
#[derive(Clone, Debug, Serialize)]
pub struct StageJacobiansExport {
    /// The values `stage_jacobians` returned.
    pub values: StageValuesExport,
    /// `∂(∇_v L)/∂q`.
    pub momentum_q: Vec<Vec<f64>>,
    /// `∇²_vv L`.
    pub mass: Vec<Vec<f64>>,
    /// `∂(∇_q L)/∂q`.
    pub force_q: Vec<Vec<f64>>,
    /// `∂(∇_q L)/∂v`.
    pub force_v: Vec<Vec<f64>>,
    /// `k_q`.
    pub constraint_q: Vec<Vec<f64>>,
    /// `k_v`.
    pub constraint_v: Vec<Vec<f64>>,
    /// `∂R/∂q`.
    pub constraint_force_q: Vec<Vec<f64>>,
    /// `∂R/∂v`.
    pub constraint_force_v: Vec<Vec<f64>>,
}

/// One step of the Rust stepper from a given state.
#[derive(Clone, Debug, Serialize)]
pub struct StepExport {
    /// Name of the system (a key of [`super::Document::systems`]).
    pub system: String,
    /// The method.
    pub method: TableauTable,
    /// Initial time.
    pub t0: f64,
    /// Step size.
    pub h: f64,
    /// Initial coordinates.
    pub q0: Vec<f64>,
    /// Initial velocities.
    pub v0: Vec<f64>,
    /// Coordinates after the step.
    pub q1: Vec<f64>,
    /// Velocities after the step.
    pub v1: Vec<f64>,
    /// Stage multipliers `Ψ_1..Ψ_s`, one row per stage.
    pub psi: Vec<Vec<f64>>,
    /// Stage velocities `V_1..V_s`, one row per stage (empty if the stepper does not expose them).
    pub stage_velocities: Vec<Vec<f64>>,
    /// `holonomic_residual(t1, q1)` after the step (only with `HAS_HOLONOMIC`).
    pub holonomic_residual: Option<Vec<f64>>,
}
