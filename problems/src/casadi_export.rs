//! Export for the independent CasADi cross-check (`casadi/`): seeded sample
//! points with every output of [`NonholonomicSystem`], plus the system's
//! neutral source text and parameter values, as JSON with round-trip floats.
//!
//! The Python side rebuilds each system from the source text alone,
//! differentiates it with CasADi and compares. Nothing here derives anything:
//! it only evaluates the trait and records what it returned.
//!
//! Optional effects travel the same way: for a system with
//! `HAS_FORCING`, `HAS_NONIDEAL_FORCE` or `HAS_HOLONOMIC` the source carries
//! `f`, `N(ψ)` or `g` and every point carries what the effect methods
//! returned; steps of such systems are taken by the stepper with the effects
//! folded in, and carry the holonomic residual after the step.

use serde::Serialize;
use spark_runtime::{
    consistent_velocity, ConditionRows, ConsistencyPolicy, Matrix, Method, NonholonomicSystem, OperationCounts, State,
    Stepper, Structure, SystemSource, Tableau, Vector,
};

pub mod handwritten;

/// Format tag of the JSON document; the Python side refuses other versions.
pub const FORMAT: &str = "spark-casadi/1";

/// The whole document the exporter writes.
#[derive(Clone, Debug, Serialize)]
pub struct Document {
    /// Always [`FORMAT`].
    pub format: &'static str,
    /// Seed the sample points were drawn with.
    pub seed: u64,
    /// One entry per system.
    pub systems: Vec<SystemExport>,
    /// Whole-step results, one per (system, method) pair.
    pub steps: Vec<StepExport>,
}

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
    /// Registry name (the key steps refer to).
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

/// The external force: the plain method's value and the fused Jacobians.
#[derive(Clone, Debug, Serialize)]
pub struct ForceExport {
    /// `external_force(t, q, v)`.
    pub value: Vec<f64>,
    /// `external_force_jacobians(t, q, v)`.
    pub jacobians: ForceJacobiansExport,
}

/// `(f, ∂f/∂q, ∂f/∂v)` as returned together.
#[derive(Clone, Debug, Serialize)]
pub struct ForceJacobiansExport {
    /// `f`.
    pub value: Vec<f64>,
    /// `∂f/∂q`.
    pub q: Vec<Vec<f64>>,
    /// `∂f/∂v`.
    pub v: Vec<Vec<f64>>,
}

/// The non-ideal constraint force: the plain method's value and the fused Jacobians.
#[derive(Clone, Debug, Serialize)]
pub struct NonidealExport {
    /// `nonideal_force(t, q, v, ψ)`.
    pub value: Vec<f64>,
    /// `nonideal_force_jacobians(t, q, v, ψ)`.
    pub jacobians: NonidealJacobiansExport,
}

/// [`spark_runtime::NonidealJacobians`] as plain arrays.
#[derive(Clone, Debug, Serialize)]
pub struct NonidealJacobiansExport {
    /// `N`.
    pub value: Vec<f64>,
    /// `∂N/∂q`.
    pub q: Vec<Vec<f64>>,
    /// `∂N/∂v`.
    pub v: Vec<Vec<f64>>,
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

/// Coefficients of a SPARK method as the Python side rebuilds equations (6.1) from them.
#[derive(Clone, Debug, Serialize)]
pub struct TableauExport {
    /// Method name as the runtime reports it.
    pub name: String,
    /// Number of stages `s`.
    pub stages: usize,
    /// Nodes `c`.
    pub c: Vec<f64>,
    /// `A` (for `q`), row-major.
    pub a: Vec<Vec<f64>>,
    /// `Â` (for `F`).
    pub a_hat: Vec<Vec<f64>>,
    /// `Ã` (for `R`).
    pub a_tilde: Vec<Vec<f64>>,
    /// `b`.
    pub b: Vec<f64>,
    /// `b̂`.
    pub b_hat: Vec<f64>,
    /// `b̃`.
    pub b_tilde: Vec<f64>,
    /// The `s − 1` internal constraint conditions.
    pub conditions: Vec<ConditionExport>,
}

/// One internal constraint condition of a SPARK step.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ConditionExport {
    /// `0 = Σ_j ω_j K_j` (eq. 6.1e).
    Weights {
        /// `ω_j`.
        omega: Vec<f64>,
    },
    /// `0 = k(t0 + c h, q0 + h Σ_j α_j V_j, Σ_j β_j V_j)` (e.g. the modified
    /// Lobatto IIIA-B condition of §8.4: `c = ½`, `α = (½, 0)`, `β = (1, 0)`).
    Point {
        /// Time node.
        c: f64,
        /// Position weights `α_j`.
        alpha: Vec<f64>,
        /// Velocity weights `β_j`.
        beta: Vec<f64>,
    },
    /// `0 = Ψ_i − Ψ_j` (0-based stage indices; McLachlan–Perlmutter, eq. 7.3).
    MultiplierDifference {
        /// First stage.
        i: usize,
        /// Second stage.
        j: usize,
    },
}

impl TableauExport {
    /// The coefficients of `tableau`, with its condition rows spelled out as
    /// the equations the paper writes (so the Python side needs no knowledge
    /// of the runtime's enum).
    pub fn of<const S: usize>(tableau: &Tableau<S>) -> Self {
        let rows = |m: &[[f64; S]; S]| m.iter().map(|r| r.to_vec()).collect::<Vec<_>>();
        let conditions = (0..S.saturating_sub(1))
            .map(|i| match tableau.conditions {
                ConditionRows::Omega => ConditionExport::Weights { omega: tableau.omega[i].to_vec() },
                // Paper §8.4: 0 = k(t0 + h/2, q0 + (h/2) V_1, V_1).
                ConditionRows::MidpointConstraint => ConditionExport::Point {
                    c: 0.5,
                    alpha: (0..S).map(|j| if j == 0 { 0.5 } else { 0.0 }).collect(),
                    beta: (0..S).map(|j| if j == 0 { 1.0 } else { 0.0 }).collect(),
                },
                ConditionRows::EqualMultipliers => ConditionExport::MultiplierDifference { i, j: i + 1 },
            })
            .collect();
        Self {
            name: tableau.method.name().to_owned(),
            stages: S,
            c: tableau.c.to_vec(),
            a: rows(&tableau.a),
            a_hat: rows(&tableau.a_hat),
            a_tilde: rows(&tableau.a_tilde),
            b: tableau.b.to_vec(),
            b_hat: tableau.b_hat.to_vec(),
            b_tilde: tableau.b_tilde.to_vec(),
            conditions,
        }
    }
}

/// One step of the Rust stepper from a given state.
#[derive(Clone, Debug, Serialize)]
pub struct StepExport {
    /// Registry name of the system (a key of [`Document::systems`]).
    pub system: String,
    /// The method.
    pub method: TableauExport,
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

/// A small seeded generator (SplitMix64): reproducible samples without a
/// dependency; statistical quality is irrelevant here.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator with this seed.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[-1, 1)`.
    pub fn symmetric(&mut self) -> f64 {
        // 53 random bits -> [0,1) exactly representable.
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        2.0 * u - 1.0
    }
}

/// Magnitude classes of the sample points: `(class, scale, count)`.
/// `mixed` draws a separate power-of-ten scale for every component.
pub const CLASSES: &[(&str, f64, usize)] = &[
    ("unit", 1.0, 8),
    ("tiny", 1e-8, 2),
    ("small", 1e-3, 2),
    ("large", 1e2, 2),
    ("huge", 1e4, 2),
    ("mixed", f64::NAN, 6),
];

fn draw(rng: &mut SplitMix64, scale: f64) -> f64 {
    if scale.is_nan() {
        // Scale 10^e with e uniform in [-8, 4].
        let e = (rng.next_u64() % 13) as i32 - 8;
        rng.symmetric() * 10f64.powi(e)
    } else {
        rng.symmetric() * scale
    }
}

fn vec_of<const K: usize>(x: &Vector<K>) -> Vec<f64> {
    x.iter().copied().collect()
}

fn rows_of<const R: usize, const C: usize>(x: &Matrix<R, C>) -> Vec<Vec<f64>> {
    (0..R).map(|i| (0..C).map(|j| x[(i, j)]).collect()).collect()
}

fn stage_values_export<const N: usize, const M: usize>(s: &spark_runtime::StageValues<N, M>) -> StageValuesExport {
    StageValuesExport {
        momentum: vec_of(&s.momentum),
        force: vec_of(&s.force),
        constraint: vec_of(&s.constraint),
        constraint_force: vec_of(&s.constraint_force),
    }
}

/// Every trait output of `system` at `(t, q, v, ψ)`.
pub fn outputs_at<S, const N: usize, const M: usize>(
    system: &S,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    psi: &Vector<M>,
) -> Outputs
where
    S: NonholonomicSystem<N, M>,
{
    let td = system.time_derivatives(t, q, v);
    let sv = system.stage_values(t, q, v, psi);
    let (jv, jj) = system.stage_jacobians(t, q, v, psi);
    let external_force = S::HAS_FORCING.then(|| {
        let (f, fq, fv) = system.external_force_jacobians(t, q, v);
        ForceExport {
            value: vec_of(&system.external_force(t, q, v)),
            jacobians: ForceJacobiansExport { value: vec_of(&f), q: rows_of(&fq), v: rows_of(&fv) },
        }
    });
    let nonideal_force = S::HAS_NONIDEAL_FORCE.then(|| {
        let nj = system.nonideal_force_jacobians(t, q, v, psi);
        NonidealExport {
            value: vec_of(&system.nonideal_force(t, q, v, psi)),
            jacobians: NonidealJacobiansExport {
                value: vec_of(&nj.value),
                q: rows_of(&nj.q),
                v: rows_of(&nj.v),
                psi: rows_of(&nj.psi),
            },
        }
    });
    let holonomic_residual = S::HAS_HOLONOMIC.then(|| vec_of(&system.holonomic_residual(t, q)));
    let events = S::HAS_EVENTS.then(|| {
        let gradients: Vec<_> = (0..S::EVENTS.len()).map(|i| system.event_gradient(i, t, q, v)).collect();
        EventsExport {
            value: (0..S::EVENTS.len()).map(|i| system.event_value(i, t, q, v)).collect(),
            gradient: EventGradientExport {
                value: gradients.iter().map(|g| g.value).collect(),
                t: gradients.iter().map(|g| g.t).collect(),
                q: gradients.iter().map(|g| vec_of(&g.q)).collect(),
                v: gradients.iter().map(|g| vec_of(&g.v)).collect(),
            },
        }
    });
    Outputs {
        lagrangian: system.lagrangian(t, q, v),
        energy: system.energy(t, q, v),
        momentum: vec_of(&system.momentum(t, q, v)),
        force: vec_of(&system.force(t, q, v)),
        mass_matrix: rows_of(&system.mass_matrix(t, q, v)),
        constraint: vec_of(&system.constraint(t, q, v)),
        constraint_q: rows_of(&system.constraint_q(t, q, v)),
        constraint_v: rows_of(&system.constraint_v(t, q, v)),
        time_derivatives: TimeExport {
            lagrangian_t: td.lagrangian_t,
            momentum_t: vec_of(&td.momentum_t),
            force_t: vec_of(&td.force_t),
            constraint_t: vec_of(&td.constraint_t),
        },
        stage_values: stage_values_export(&sv),
        stage_jacobians: StageJacobiansExport {
            values: stage_values_export(&jv),
            momentum_q: rows_of(&jj.momentum_q),
            mass: rows_of(&jj.mass),
            force_q: rows_of(&jj.force_q),
            force_v: rows_of(&jj.force_v),
            constraint_q: rows_of(&jj.constraint_q),
            constraint_v: rows_of(&jj.constraint_v),
            constraint_force_q: rows_of(&jj.constraint_force_q),
            constraint_force_v: rows_of(&jj.constraint_force_v),
        },
        external_force,
        nonideal_force,
        holonomic_residual,
        events,
    }
}

fn outputs_finite(o: &Outputs) -> bool {
    let json = serde_json::to_value(o);
    // serde_json writes non-finite floats as null; finding one means a
    // non-finite output.
    fn finite(v: &serde_json::Value) -> bool {
        match v {
            serde_json::Value::Null => false,
            serde_json::Value::Array(a) => a.iter().all(finite),
            serde_json::Value::Object(m) => m.values().all(finite),
            _ => true,
        }
    }
    json.map(|v| finite(&v)).unwrap_or(false)
}

/// Samples `system` at the points of [`CLASSES`] drawn from `seed` and
/// records every trait output there.
pub fn export_system<S, const N: usize, const M: usize>(name: &str, system: &S, seed: u64) -> SystemExport
where
    S: NonholonomicSystem<N, M>,
{
    let mut rng = SplitMix64::new(seed);
    let mut points = Vec::new();
    let mut skipped = 0;
    for &(class, scale, count) in CLASSES {
        for _ in 0..count {
            let t = draw(&mut rng, scale);
            let q = Vector::<N>::from_fn(|_, _| draw(&mut rng, scale));
            let v = Vector::<N>::from_fn(|_, _| draw(&mut rng, scale));
            let psi = Vector::<M>::from_fn(|_, _| draw(&mut rng, scale));
            let outputs = outputs_at(system, t, &q, &v, &psi);
            if outputs_finite(&outputs) {
                points.push(PointExport {
                    class: class.to_owned(),
                    t,
                    q: vec_of(&q),
                    v: vec_of(&v),
                    psi: vec_of(&psi),
                    outputs,
                });
            } else {
                skipped += 1;
            }
        }
    }
    SystemExport {
        name: name.to_owned(),
        n: N,
        m: M,
        source: SourceExport::of::<S, N, M>(),
        parameter_values: system.parameter_values(),
        structure: S::STRUCTURE,
        operations: S::OPERATIONS,
        effects: EffectsExport::of::<S, N, M>(),
        points,
        skipped_points: skipped,
    }
}

/// One SPARK step of `method` with `S` stages (`D = S(N+M)+N`, see
/// [`Stepper`]) from `(t0, q0, v0)`, with the stepper's default Newton
/// options and a cold start. `v0` is first made consistent (projected onto
/// `k(t0, q0, ·) = 0`) so that the step starts where the stepper expects.
#[allow(clippy::too_many_arguments)]
pub fn export_step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    name: &str,
    system: &Sys,
    method: Method,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    h: f64,
) -> Result<StepExport, String>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let tableau = Tableau::<S>::new(method).map_err(|e| e.to_string())?;
    let v0 = consistent_velocity(system, t0, q0, v0, ConsistencyPolicy::Project { tolerance: 0.0 })
        .map_err(|e| format!("{name}: projecting v0: {e}"))?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(system.clone(), tableau);
    let r = stepper.step(&State::new(t0, *q0, v0), h).map_err(|e| format!("{name}, {} s={S}: {e}", method.name()))?;
    Ok(StepExport {
        system: name.to_owned(),
        method: TableauExport::of(&tableau),
        t0,
        h,
        q0: vec_of(q0),
        v0: vec_of(&v0),
        q1: vec_of(&r.state.q),
        v1: vec_of(&r.state.v),
        psi: r.stage_multipliers.iter().map(vec_of).collect(),
        stage_velocities: r.stage_velocities.iter().map(vec_of).collect(),
        holonomic_residual: Sys::HAS_HOLONOMIC.then(|| vec_of(&system.holonomic_residual(r.state.t, &r.state.q))),
    })
}

/// Exports one step of every method the cross-check covers (Gauss s = 1..3,
/// Lobatto IIIA-B and IIIA-B-D s = 2..3, symplectic Euler I and II, modified
/// Lobatto IIIA-B and McLachlan–Perlmutter's LDA) for a system type with
/// inherent `N` and `M` constants; `@dims N, M;` first names them for a type
/// without (e.g. the hand-written systems of [`spark_runtime::effects`]).
#[macro_export]
macro_rules! casadi_steps_for {
    ($out:expr, $name:expr, $ty:ty, $sys:expr, $t0:expr, $q0:expr, $v0:expr, $h:expr) => {
        $crate::casadi_steps_for!(@dims <$ty>::N, <$ty>::M; $out, $name, $ty, $sys, $t0, $q0, $v0, $h)
    };
    (@dims $n:expr, $m:expr; $out:expr, $name:expr, $ty:ty, $sys:expr, $t0:expr, $q0:expr, $v0:expr, $h:expr) => {{
        use spark_runtime::Method;
        use $crate::casadi_export::export_step;
        const N: usize = $n;
        const M: usize = $m;
        let (sys, t0, q0, v0, h): (&$ty, f64, _, _, f64) = (&$sys, $t0, &$q0, &$v0, $h);
        $out.push(export_step::<$ty, N, M, 1, { N + M + N }>($name, sys, Method::Gauss, t0, q0, v0, h));
        $out.push(export_step::<$ty, N, M, 2, { 2 * (N + M) + N }>($name, sys, Method::Gauss, t0, q0, v0, h));
        $out.push(export_step::<$ty, N, M, 3, { 3 * (N + M) + N }>($name, sys, Method::Gauss, t0, q0, v0, h));
        for method in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            $out.push(export_step::<$ty, N, M, 2, { 2 * (N + M) + N }>($name, sys, method, t0, q0, v0, h));
            $out.push(export_step::<$ty, N, M, 3, { 3 * (N + M) + N }>($name, sys, method, t0, q0, v0, h));
        }
        for method in [Method::SymplecticEulerI, Method::SymplecticEulerII] {
            $out.push(export_step::<$ty, N, M, 1, { N + M + N }>($name, sys, method, t0, q0, v0, h));
        }
        for method in [Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
            $out.push(export_step::<$ty, N, M, 2, { 2 * (N + M) + N }>($name, sys, method, t0, q0, v0, h));
        }
    }};
}

/// Seed-derived per-system seed, so adding a system does not move the others' points.
fn system_seed(seed: u64, name: &str) -> u64 {
    name.bytes().fold(seed ^ 0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// Every system the cross-check covers, exported with `seed`: all systems of
/// [`crate::systems`] and the hand-written [`handwritten::Rheonomic`], each
/// with its default parameters and again with varied parameters.
pub fn export_all_systems(seed: u64) -> Result<Vec<SystemExport>, String> {
    use crate::systems::*;
    let mut out = Vec::new();
    macro_rules! one {
        ($name:expr, $sys:expr) => {{
            let sys = $sys;
            out.push(export_system($name, &sys, system_seed(seed, $name)));
            // Again with every parameter moved off its default, so that
            // special values (β = π/2, unit masses) hide nothing and
            // `set_parameter` is exercised.
            let label = format!("{} (varied parameters)", $name);
            if let Some(varied) = with_varied_parameters(&sys, system_seed(seed, &label))? {
                out.push(export_system(&label, &varied, system_seed(seed, &label)));
            }
        }};
    }
    one!("NonholonomicParticle", NonholonomicParticle::default());
    one!("Skate", Skate::default());
    one!("MobileRobot", MobileRobot::default());
    one!("McLachlanPerlmutter7", McLachlanPerlmutter7::default());
    one!("McLachlanPerlmutter7Nonholonomic", McLachlanPerlmutter7Nonholonomic::default());
    one!("TurntableSkate", TurntableSkate::default());
    one!("AppellHamel", AppellHamel::default());
    one!("ChaplyginSleigh", ChaplyginSleigh::default());
    one!("DoublePendulum", DoublePendulum::default());
    one!("OrbitParticle", OrbitParticle::default());
    one!(HANDWRITTEN, handwritten::Rheonomic::default());
    // Systems declared with effects and scenes (scenes are plain
    // systems to the exporter: their SOURCE holds the selected effects).
    {
        use crate::scenes::*;
        one!("VerticalDisk", VerticalDisk::default());
        one!("BallOnTurntable", BallOnTurntable::default());
        one!("RodPendulum", RodPendulum::default());
        one!("BodyFree", BodyFree::default());
        one!("BodySprung", BodySprung::default());
        one!("BodySkating", BodySkating::default());
        one!("BodyRailed", BodyRailed::default());
        one!("BodyTethered", BodyTethered::default());
        one!("BodySkatingByHand", BodySkatingByHand::default());
        one!("SleighFree", SleighFree::default());
        one!("SleighDriven", SleighDriven::default());
        one!("SleighDamped", SleighDamped::default());
        one!("SleighDrivenDamped", SleighDrivenDamped::default());
        one!("SleighDrivenDampedByHand", SleighDrivenDampedByHand::default());
        one!("SkateOnBlade", SkateOnBlade::default());
        one!("SkateWithFriction", SkateWithFriction::default());
        one!("AppellHamelCord", AppellHamelCord::default());
        one!("AppellHamelSprung", AppellHamelSprung::default());
    }
    // Hand-written systems with effects (spark_runtime::effects): forcing,
    // a non-ideal force with ψ, a holonomic constraint at velocity level.
    {
        use spark_runtime::effects::{DrivenSkate, FrictionSkate, RodPendulum};
        one!(HANDWRITTEN_DRIVEN_SKATE, DrivenSkate::default());
        one!(HANDWRITTEN_FRICTION_SKATE, FrictionSkate::default());
        one!(HANDWRITTEN_ROD_PENDULUM, RodPendulum::default());
    }
    Ok(out)
}

/// A copy of `system` with every parameter multiplied by a seeded factor in
/// `[0.5, 1.5)`; `Ok(None)` if the system has no parameters, `Err` if it
/// rejects one of the parameter names its own source declares.
pub fn with_varied_parameters<S, const N: usize, const M: usize>(system: &S, seed: u64) -> Result<Option<S>, String>
where
    S: NonholonomicSystem<N, M> + Clone,
{
    if S::SOURCE.parameters.is_empty() {
        return Ok(None);
    }
    let mut rng = SplitMix64::new(seed);
    let mut varied = system.clone();
    for (name, value) in S::SOURCE.parameters.iter().zip(system.parameter_values()) {
        let factor = 1.0 + 0.5 * rng.symmetric();
        varied.set_parameter(name, value * factor).map_err(|e| format!("{}: {e}", S::SOURCE.name))?;
    }
    Ok(Some(varied))
}

/// Registry name of the hand-written reference system.
pub const HANDWRITTEN: &str = "Rheonomic (hand-written)";
/// Registry name of [`spark_runtime::effects::DrivenSkate`] (external force).
pub const HANDWRITTEN_DRIVEN_SKATE: &str = "DrivenSkate (hand-written)";
/// Registry name of [`spark_runtime::effects::FrictionSkate`] (non-ideal force).
pub const HANDWRITTEN_FRICTION_SKATE: &str = "FrictionSkate (hand-written)";
/// Registry name of [`spark_runtime::effects::RodPendulum`] (holonomic constraint).
pub const HANDWRITTEN_ROD_PENDULUM: &str = "RodPendulum (hand-written)";

/// One SPARK step per (system, method) pair, from the runtime's stepper.
///
/// The paper's systems start from the paper's initial values and step sizes;
/// the others from a generic state (projected onto the constraints) with a
/// step the default Newton solver converges on.
pub fn export_all_steps() -> Result<Vec<StepExport>, String> {
    use crate::systems::*;
    type V<const K: usize> = Vector<K>;
    let mut out: Vec<Result<StepExport, String>> = Vec::new();
    let j = 1.0 * std::f64::consts::PI / 18.0; // §8.4, j = 1 of J = 9
    casadi_steps_for!(
        out,
        "NonholonomicParticle",
        NonholonomicParticle,
        NonholonomicParticle::default(),
        0.0,
        V::<3>::new(1.0, 0.0, 0.0),
        V::<3>::new(0.0, 1.0, 0.0),
        0.2
    );
    casadi_steps_for!(out, "Skate", Skate, Skate::default(), 0.0, V::<3>::zeros(), V::<3>::new(0.0, 0.0, 1.0), 0.1);
    casadi_steps_for!(
        out,
        "MobileRobot",
        MobileRobot,
        MobileRobot::default(),
        0.0,
        V::<4>::zeros(),
        V::<4>::new(1.0, 0.0, 0.0, 1.0),
        0.2
    );
    casadi_steps_for!(
        out,
        "McLachlanPerlmutter7",
        McLachlanPerlmutter7,
        McLachlanPerlmutter7::default(),
        0.0,
        V::<7>::from_column_slice(&[j.cos(), 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        V::<7>::from_column_slice(&[0.0, j.sin(), 0.0, 0.0, 0.0, 0.0, 0.0]),
        0.05
    );
    casadi_steps_for!(
        out,
        "McLachlanPerlmutter7Nonholonomic",
        McLachlanPerlmutter7Nonholonomic,
        McLachlanPerlmutter7Nonholonomic::default(),
        0.0,
        V::<7>::from_column_slice(&[j.cos(), 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        V::<7>::from_column_slice(&[0.0, j.sin(), 0.0, 0.0, 0.0, 0.0, 0.0]),
        0.05
    );
    casadi_steps_for!(
        out,
        "TurntableSkate",
        TurntableSkate,
        TurntableSkate::default(),
        0.3,
        V::<3>::new(0.5, 0.2, 0.3),
        V::<3>::new(0.1, 0.4, 1.0),
        0.1
    );
    casadi_steps_for!(
        out,
        "AppellHamel",
        AppellHamel,
        AppellHamel::default(),
        0.0,
        V::<3>::zeros(),
        V::<3>::new(1.0, 0.0, 0.5),
        0.1
    );
    casadi_steps_for!(
        out,
        "ChaplyginSleigh",
        ChaplyginSleigh,
        ChaplyginSleigh::default(),
        0.0,
        V::<3>::new(0.0, 0.0, 0.4),
        V::<3>::new(1.0, 0.3, 0.5),
        0.1
    );
    casadi_steps_for!(
        out,
        "DoublePendulum",
        DoublePendulum,
        DoublePendulum::default(),
        0.0,
        V::<2>::new(0.5, -0.3),
        V::<2>::new(0.2, 0.1),
        0.05
    );
    casadi_steps_for!(
        out,
        "OrbitParticle",
        OrbitParticle,
        OrbitParticle::default(),
        0.0,
        V::<3>::new(1.0, 0.2, 0.0),
        V::<3>::new(0.1, 1.0, 0.02),
        0.05
    );
    casadi_steps_for!(
        out,
        HANDWRITTEN,
        handwritten::Rheonomic,
        handwritten::Rheonomic::default(),
        0.1,
        V::<2>::new(0.3, -0.2),
        V::<2>::new(0.5, 0.1),
        0.05
    );
    {
        use crate::scenes::*;
        let th: f64 = 0.4;
        casadi_steps_for!(
            out,
            "VerticalDisk",
            VerticalDisk,
            VerticalDisk::default(),
            0.0,
            V::<4>::new(0.2, -0.1, th, 0.0),
            V::<4>::new(1.3 * th.cos(), 1.3 * th.sin(), 0.7, 1.3),
            0.1
        );
        casadi_steps_for!(
            out,
            "BallOnTurntable",
            BallOnTurntable,
            BallOnTurntable::default(),
            0.2,
            V::<5>::new(0.5, 0.2, 0.1, 1.4, 0.3),
            V::<5>::new(0.3, -0.1, 0.2, 0.4, -0.3),
            0.05
        );
        casadi_steps_for!(
            out,
            "RodPendulum",
            RodPendulum,
            RodPendulum::default(),
            0.0,
            V::<2>::new(0.6, -0.8),
            V::<2>::new(0.8, 0.6),
            0.1
        );
        casadi_steps_for!(
            out,
            "BodyRailed",
            BodyRailed,
            BodyRailed::default(),
            0.1,
            V::<3>::new(0.5, 0.1, 0.3),
            V::<3>::new(0.5, 0.2, 0.7),
            0.05
        );
        casadi_steps_for!(
            out,
            "BodyTethered",
            BodyTethered,
            BodyTethered::default(),
            0.0,
            V::<3>::new(0.6, -0.8, 0.3),
            V::<3>::new(0.8, 0.6, 0.7),
            0.05
        );
        let (q0, v0) = (V::<3>::new(0.5, 0.1, 0.3), V::<3>::new(0.5, 0.2, 0.7));
        casadi_steps_for!(out, "BodyFree", BodyFree, BodyFree::default(), 0.1, q0, v0, 0.05);
        casadi_steps_for!(out, "BodySprung", BodySprung, BodySprung::default(), 0.1, q0, v0, 0.05);
        casadi_steps_for!(out, "BodySkating", BodySkating, BodySkating::default(), 0.1, q0, v0, 0.05);
        casadi_steps_for!(out, "BodySkatingByHand", BodySkatingByHand, BodySkatingByHand::default(), 0.1, q0, v0, 0.05);
        // Sleigh scenes: a generic heading, the velocity projected onto no-slip.
        let (q0, v0) = (V::<3>::new(0.1, -0.2, 0.3), V::<3>::new(1.0, 0.2, 0.5));
        casadi_steps_for!(out, "SleighFree", SleighFree, SleighFree::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(out, "SleighDriven", SleighDriven, SleighDriven::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(out, "SleighDamped", SleighDamped, SleighDamped::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(
            out,
            "SleighDrivenDamped",
            SleighDrivenDamped,
            SleighDrivenDamped::default(),
            0.0,
            q0,
            v0,
            0.1
        );
        casadi_steps_for!(
            out,
            "SleighDrivenDampedByHand",
            SleighDrivenDampedByHand,
            SleighDrivenDampedByHand::default(),
            0.0,
            q0,
            v0,
            0.1
        );
        let (th, speed, omega): (f64, f64, f64) = (0.7, 0.4, 0.9);
        let (q0, v0) = (V::<3>::new(0.1, -0.2, th), V::<3>::new(speed * th.cos(), speed * th.sin(), omega));
        casadi_steps_for!(out, "SkateOnBlade", SkateOnBlade, SkateOnBlade::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(out, "SkateWithFriction", SkateWithFriction, SkateWithFriction::default(), 0.0, q0, v0, 0.1);
        // On the cone ż² = a²(ẋ² + ẏ²) with a = ½, falling.
        let (q0, v0) = (V::<3>::new(0.1, 0.2, 0.3), V::<3>::new(0.8, 0.6, -0.5));
        casadi_steps_for!(out, "AppellHamelCord", AppellHamelCord, AppellHamelCord::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(out, "AppellHamelSprung", AppellHamelSprung, AppellHamelSprung::default(), 0.0, q0, v0, 0.1);
    }
    {
        use spark_runtime::effects::{DrivenSkate, FrictionSkate, RodPendulum};
        let (th, speed, omega): (f64, f64, f64) = (0.7, 0.4, 0.9);
        let q0 = V::<3>::new(0.1, -0.2, th);
        let v0 = V::<3>::new(speed * th.cos(), speed * th.sin(), omega);
        casadi_steps_for!(@dims 3, 1; out, HANDWRITTEN_DRIVEN_SKATE, DrivenSkate, DrivenSkate::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(@dims 3, 1; out, HANDWRITTEN_FRICTION_SKATE, FrictionSkate, FrictionSkate::default(), 0.0, q0, v0, 0.1);
        casadi_steps_for!(
            @dims 2, 1;
            out,
            HANDWRITTEN_ROD_PENDULUM,
            RodPendulum,
            RodPendulum::default(),
            0.0,
            V::<2>::new(0.6, -0.8),
            V::<2>::new(0.8, 0.6),
            0.1
        );
    }
    let errors: Vec<String> = out.iter().filter_map(|r| r.as_ref().err().cloned()).collect();
    if !errors.is_empty() {
        return Err(errors.join("\n"));
    }
    out.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names declared with `nonholonomic_system!` in `systems.rs`.
    fn declared_systems() -> Vec<String> {
        let text = include_str!("systems/paper.rs");
        let mut names = Vec::new();
        for chunk in text.split("nonholonomic_system! {").skip(1) {
            let after = chunk.split("struct").nth(1).expect("a struct in every invocation");
            let name: String = after.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            names.push(name);
        }
        names
    }

    #[test]
    fn every_declared_system_is_exported() {
        let exported: Vec<String> = export_all_systems(1).unwrap().into_iter().map(|s| s.name).collect();
        let declared = declared_systems();
        assert!(declared.len() >= 8, "found only {declared:?}");
        for name in &declared {
            assert!(exported.contains(name), "{name} is declared in systems.rs but not exported for CasADi");
        }
    }

    /// Scene names declared in `scenes.rs` (`scenes: { A = [..], B = [..] }`)
    /// and the structs declared there.
    fn declared_scene_types() -> Vec<String> {
        let text = include_str!("systems/scenes.rs");
        let mut names = Vec::new();
        for chunk in text.split("nonholonomic_system! {").skip(1) {
            let body = chunk.split("\n}").next().unwrap_or("");
            if let Some(scenes) = body.split("scenes: {").nth(1) {
                let list = scenes.split('}').next().unwrap_or("");
                for entry in list.split(']') {
                    if let Some((name, _)) = entry.split_once('=') {
                        let name = name.trim().trim_start_matches(',').trim();
                        if !name.is_empty() {
                            names.push(name.to_owned());
                        }
                    }
                }
            } else {
                let after = body.split("struct").nth(1).expect("a struct in every invocation");
                names.push(after.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect());
            }
        }
        names
    }

    #[test]
    fn every_scene_is_exported() {
        let exported: Vec<String> = export_all_systems(1).unwrap().into_iter().map(|s| s.name).collect();
        let declared = declared_scene_types();
        assert!(declared.len() >= 16, "found only {declared:?}");
        for name in &declared {
            assert!(exported.contains(name), "{name} is declared in scenes.rs but not exported for CasADi");
        }
    }

    #[test]
    fn every_system_takes_every_step() {
        let systems = export_all_systems(1).unwrap().iter().filter(|s| !s.name.contains("varied")).count();
        let steps = export_all_steps().expect("all steps succeed");
        // Gauss 1..3, IIIA-B 2..3, IIIA-B-D 2..3, Euler I, II, modified Lobatto, LDA.
        assert_eq!(steps.len(), 11 * systems);
        for st in &steps {
            assert_eq!(st.psi.len(), st.method.stages);
            assert_eq!(st.method.conditions.len(), st.method.stages - 1);
        }
    }

    #[test]
    fn effect_systems_export_their_effects_and_flags_match_sources() {
        let systems = export_all_systems(1).unwrap();
        for s in &systems {
            assert_eq!(s.effects.forcing, !s.source.external_force.is_empty(), "{}", s.name);
            assert_eq!(s.effects.nonideal, !s.source.nonideal_force.is_empty(), "{}", s.name);
            assert_eq!(s.effects.holonomic, !s.source.holonomic.is_empty(), "{}", s.name);
            for p in &s.points {
                assert_eq!(p.outputs.external_force.is_some(), s.effects.forcing);
                assert_eq!(p.outputs.nonideal_force.is_some(), s.effects.nonideal);
                assert_eq!(p.outputs.holonomic_residual.is_some(), s.effects.holonomic);
            }
        }
        let by = |name: &str| systems.iter().find(|s| s.name == name).expect(name);
        assert!(by(HANDWRITTEN_DRIVEN_SKATE).effects.forcing);
        let friction = by(HANDWRITTEN_FRICTION_SKATE);
        assert!(friction.effects.nonideal);
        assert!(friction.source.nonideal_force[0].contains("(psi 0)"));
        let n = friction.points[0].outputs.nonideal_force.as_ref().unwrap();
        assert_eq!((n.jacobians.psi.len(), n.jacobians.psi[0].len()), (3, 1));
        assert!(by(HANDWRITTEN_ROD_PENDULUM).effects.holonomic);
        let steps = export_all_steps().unwrap();
        for st in steps.iter().filter(|st| st.system == HANDWRITTEN_ROD_PENDULUM) {
            let g = st.holonomic_residual.as_ref().expect("holonomic residual after the step");
            assert!(g[0].abs() < 1e-2, "{}: drift {}", st.method.name, g[0]);
        }
    }

    #[test]
    fn splitmix_is_reproducible_and_in_range() {
        let mut a = SplitMix64::new(7);
        let mut b = SplitMix64::new(7);
        for _ in 0..1000 {
            let x = a.symmetric();
            assert_eq!(x, b.symmetric());
            assert!((-1.0..1.0).contains(&x));
        }
    }

    #[test]
    fn export_records_every_point_of_a_finite_system() {
        let sys = handwritten::Rheonomic::default();
        let e = export_system("rheonomic", &sys, 1);
        let expected: usize = CLASSES.iter().map(|c| c.2).sum();
        assert_eq!(e.points.len() + e.skipped_points, expected);
        assert_eq!(e.skipped_points, 0);
        assert_eq!(e.points[0].outputs.constraint_v.len(), 1);
        assert_eq!(e.points[0].outputs.constraint_v[0].len(), 2);
    }

    #[test]
    fn floats_round_trip_through_json() {
        let sys = handwritten::Rheonomic::default();
        let e = export_system("rheonomic", &sys, 3);
        let text = serde_json::to_string(&e).unwrap();
        let back: serde_json::Value = serde_json::from_str(&text).unwrap();
        for (i, p) in e.points.iter().enumerate() {
            let bp = &back["points"][i];
            assert_eq!(bp["outputs"]["lagrangian"].as_f64().unwrap().to_bits(), p.outputs.lagrangian.to_bits());
            for (j, x) in p.q.iter().enumerate() {
                assert_eq!(bp["q"][j].as_f64().unwrap().to_bits(), x.to_bits());
            }
        }
    }
}
