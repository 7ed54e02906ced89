//! Seeded sample points and every trait output of a system there: the
//! derivative half of the cross-check. Nothing here derives anything; it
//! evaluates [`NonholonomicSystem`] and records what it returned.

use spark_runtime::{Matrix, NonholonomicSystem, SystemError, Vector};

use super::wire::{
    EffectJacobiansExport, EffectsExport, EventGradientExport, EventsExport, ForceExport, NonidealExport,
    NonidealJacobiansExport, Outputs, PointExport, SourceExport, StageJacobiansExport, StageValuesExport, SystemExport,
    TimeExport,
};

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

pub(super) fn vec_of<const K: usize>(x: &Vector<K>) -> Vec<f64> {
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
fn outputs_at<S, const N: usize, const M: usize>(
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
            jacobians: EffectJacobiansExport { value: vec_of(&f), q: rows_of(&fq), v: rows_of(&fv) },
        }
    });
    let nonideal_force = S::HAS_NONIDEAL_FORCE.then(|| {
        let nj = system.nonideal_force_jacobians(t, q, v, psi);
        NonidealExport {
            value: vec_of(&system.nonideal_force(t, q, v, psi)),
            jacobians: NonidealJacobiansExport {
                state: EffectJacobiansExport { value: vec_of(&nj.value), q: rows_of(&nj.q), v: rows_of(&nj.v) },
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
        constant_stiffness: S::CONSTANT_STIFFNESS,
        diagonal_stiffness: S::DIAGONAL_STIFFNESS,
        operations: S::OPERATIONS,
        effects: EffectsExport::of::<S, N, M>(),
        points,
        skipped_points: skipped,
    }
}

/// Seed-derived per-system seed, so adding a system does not move the others' points.
pub(super) fn system_seed(seed: u64, name: &str) -> u64 {
    name.bytes().fold(seed ^ 0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// A copy of `system` with every parameter multiplied by a seeded factor in
/// `[0.5, 1.5)`; `Ok(None)` if the system has no parameters, `Err` if it
/// rejects one of the parameter names its own source declares.
pub(super) fn with_varied_parameters<S, const N: usize, const M: usize>(
    system: &S,
    seed: u64,
) -> Result<Option<S>, SystemError>
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
        varied.set_parameter(name, value * factor)?;
    }
    Ok(Some(varied))
}
