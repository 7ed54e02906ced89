//! Export for the independent CasADi cross-check (`casadi/`): seeded sample
//! points with every output of [`NonholonomicSystem`], plus the system's
//! neutral source text and parameter values, one whole SPARK step per
//! (system, method), and the hard cold steps of [`cold`] in every Newton
//! mode, as JSON with round-trip floats.
//!
//! The Python side rebuilds each system from the source text alone,
//! differentiates it with CasADi and compares. Nothing here derives anything:
//! it only evaluates the trait and the stepper and records what they returned.
//!
//! Which systems are checked comes from the catalogue: every
//! [`catalog::entries`] entry, under its command-line name, with its default
//! parameters, initial state and step size, visited through
//! [`catalog::visit_system`] and stepped through [`Dispatch::with_stages`].
//! The systems checked but not offered by `spark` are the one list
//! [`visit_extras`]. A new catalogue entry is therefore cross-checked without
//! a change here.
//!
//! Optional effects travel the same way: for a system with
//! `HAS_FORCING`, `HAS_NONIDEAL_FORCE` or `HAS_HOLONOMIC` the source carries
//! `f`, `N(ψ)` or `g` and every point carries what the effect methods
//! returned; steps of such systems are taken by the stepper with the effects
//! folded in, and carry the holonomic residual after the step.

use serde::Serialize;
use spark_runtime::{
    consistent_velocity, ConsistencyPolicy, Method, NonholonomicSystem, State, StepError, StepResult, Stepper,
    SystemError, Tableau, TableauError, TableauTable, Vector,
};

use crate::catalog::{self, Dispatch, DispatchError, StageVisitor, SystemEntry, SystemVisitor};

pub mod cold;
pub mod handwritten;
mod sample;
mod wire;

pub use sample::{export_system, SplitMix64, CLASSES};
pub use wire::*;

/// Format tag of the JSON document; the Python side refuses other versions.
pub const FORMAT: &str = "spark-casadi/1";

/// Largest stage count the step export takes: every method with every
/// stage count from its smallest up to this one.
pub const MAX_CHECKED_STAGES: usize = 3;

/// The whole document the exporter writes.
#[derive(Clone, Debug, Serialize)]
pub struct Document {
    /// Always [`FORMAT`].
    pub format: &'static str,
    /// Seed the sample points were drawn with.
    pub seed: u64,
    /// One entry per system (and one more per system with parameters, with
    /// the parameters varied).
    pub systems: Vec<SystemExport>,
    /// Whole-step results, one per (system, method, stage count).
    pub steps: Vec<StepExport>,
    /// Hard cold steps ([`cold`]), one per (system, method, stage count,
    /// Newton mode), solved or refused.
    pub cold_steps: Vec<cold::ColdStepExport>,
}

impl Document {
    /// Every system and step of the cross-check, with sample points drawn
    /// from `seed`.
    pub fn export(seed: u64) -> Result<Self, CrosscheckError> {
        Ok(Self {
            format: FORMAT,
            seed,
            systems: export_all_systems(seed)?,
            steps: export_all_steps()?,
            cold_steps: cold::export_cold_steps()?,
        })
    }
}

/// Why the export failed; every message names the system (and the method).
#[derive(Debug, thiserror::Error)]
pub enum CrosscheckError {
    /// A system rejected a parameter its own source declares.
    #[error("{system}: setting a varied parameter: {source}")]
    Parameter {
        /// The system's name in the export.
        system: String,
        /// What the system said.
        source: SystemError,
    },
    /// A case's initial state does not have `N` entries.
    #[error("{system}: the initial state has {q} coordinates and {v} velocities; the system has N = {n}")]
    StateLength {
        /// The system's name in the export.
        system: String,
        /// Length of `q0`.
        q: usize,
        /// Length of `v0`.
        v: usize,
        /// `N`.
        n: usize,
    },
    /// The initial velocity could not be projected onto the constraints.
    #[error("{system}: projecting v0 onto the constraints: {source}")]
    Projection {
        /// The system's name in the export.
        system: String,
        /// What the projection said.
        source: StepError,
    },
    /// The stepper failed on the exported step.
    #[error("{system}, {method} s={stages}: {source}")]
    Step {
        /// The system's name in the export.
        system: String,
        /// The method's key.
        method: &'static str,
        /// The stage count.
        stages: usize,
        /// What the stepper said.
        source: StepError,
    },
    /// The method does not exist with this stage count.
    #[error("{system}: {source}")]
    Tableau {
        /// The system's name in the export.
        system: String,
        /// What the tableau said.
        source: TableauError,
    },
    /// The stage count is not compiled into the dispatch.
    #[error("{system}, {method}: {source}")]
    Dispatch {
        /// The system's name in the export.
        system: String,
        /// The method's key.
        method: &'static str,
        /// What the dispatch said.
        source: DispatchError,
    },
    /// Several steps failed (one line each).
    #[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Several(Vec<CrosscheckError>),
}

/// One system as the cross-check sees it: its name in the export and the
/// state its steps start from. Its parameters are those of `Default`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Case {
    /// Name in the export (the command-line name for catalogue systems).
    pub name: &'static str,
    /// Initial time.
    pub t0: f64,
    /// Initial coordinates.
    pub q0: &'static [f64],
    /// Initial velocities (projected onto the constraints before the step).
    pub v0: &'static [f64],
    /// Step size.
    pub h: f64,
}

impl From<&SystemEntry> for Case {
    fn from(e: &SystemEntry) -> Self {
        Self { name: e.name, t0: e.t0, q0: e.q0, v0: e.v0, h: e.h }
    }
}

impl Case {
    /// `(q0, v0)` as vectors, or an error if either does not have `N` entries.
    pub fn state<const N: usize>(&self) -> Result<(Vector<N>, Vector<N>), CrosscheckError> {
        if self.q0.len() != N || self.v0.len() != N {
            let (q, v) = (self.q0.len(), self.v0.len());
            return Err(CrosscheckError::StateLength { system: self.name.to_owned(), q, v, n: N });
        }
        Ok((Vector::<N>::from_column_slice(self.q0), Vector::<N>::from_column_slice(self.v0)))
    }
}

/// Work generic in the type of one checked system.
///
/// `Host` lends its stage dispatch ([`Dispatch::with_stages`]): the
/// stepper's unknown count `D = S(N + M) + N` depends on `N`, `M` and `S`
/// alone, so any catalogue type of the same shape maps a run-time stage count
/// to the right `(S, D)` for `Sys`. For catalogue systems `Host` is `Sys`.
pub trait CaseVisitor {
    /// Does the work for `Sys`.
    fn visit<Sys, Host, const N: usize, const M: usize>(&mut self, case: &Case) -> Result<(), CrosscheckError>
    where
        Sys: NonholonomicSystem<N, M> + Default + Clone,
        Host: Dispatch<N, M>;
}

/// Calls `visitor` for every catalogue entry, then for [`visit_extras`].
pub fn visit_cases<V: CaseVisitor>(visitor: &mut V) -> Result<(), CrosscheckError> {
    struct Catalogue<'a, V>(&'a mut V);
    impl<V: CaseVisitor> SystemVisitor for Catalogue<'_, V> {
        type Output = Result<(), CrosscheckError>;
        fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
            self,
            entry: &'static SystemEntry,
        ) -> Self::Output {
            self.0.visit::<Sys, Sys, N, M>(&Case::from(entry))
        }
    }
    for entry in catalog::entries() {
        catalog::visit_system(entry.kind, Catalogue(&mut *visitor))?;
    }
    visit_extras(visitor)
}

/// The hand-written [`handwritten::Rheonomic`]: explicit time dependence of
/// `L` and `k`, a non-separable `L` and a constraint nonlinear in `v`, with
/// derivatives worked out by hand (the checker checked against code that
/// owes nothing to the macro). Starts at `t0 ≠ 0` so that the time
/// dependence enters the step.
pub const RHEONOMIC: Case = Case { name: "rheonomic-hand", t0: 0.1, q0: &[0.3, -0.2], v0: &[0.5, 0.1], h: 0.05 };

/// The scene [`crate::systems::scenes::AppellHamelSprung`]: the cord constraint
/// (nonlinear in `v`) with a horizontal spring, so that the motion is not
/// polynomial in `t`. Starts on the cone `ż² = a²(ẋ² + ẏ²)`, falling.
pub const APPELL_HAMEL_SPRUNG: Case =
    Case { name: "appell-hamel-sprung", t0: 0.0, q0: &[0.1, 0.2, 0.3], v0: &[0.8, 0.6, -0.5], h: 0.1 };

/// The systems the cross-check covers that `spark` does not offer on its
/// command line: [`RHEONOMIC`] and [`APPELL_HAMEL_SPRUNG`]. Each borrows the
/// stage dispatch of a catalogue type of its shape (see [`CaseVisitor`]).
pub fn visit_extras<V: CaseVisitor>(visitor: &mut V) -> Result<(), CrosscheckError> {
    visitor.visit::<handwritten::Rheonomic, crate::systems::scenes::RodPendulum, 2, 1>(&RHEONOMIC)?;
    visitor.visit::<crate::systems::scenes::AppellHamelSprung, crate::systems::scenes::AppellHamelCord, 3, 1>(
        &APPELL_HAMEL_SPRUNG,
    )
}

/// Every (method, stage count) the step export takes: each method from its
/// smallest stage count up to [`MAX_CHECKED_STAGES`] (Gauss s = 1..3,
/// Lobatto IIIA-B and IIIA-B-D s = 2..3, symplectic Euler I and II, modified
/// Lobatto IIIA-B and McLachlan–Perlmutter's LDA).
pub fn checked_methods() -> Vec<(Method, usize)> {
    Method::ALL
        .into_iter()
        .flat_map(|m| {
            let (min, max) = m.stage_range();
            (min..=max.min(MAX_CHECKED_STAGES)).map(move |s| (m, s))
        })
        .collect()
}

/// Every system the cross-check covers ([`visit_cases`], then the hard cold
/// cases of [`cold::visit_cold_cases`]), exported with
/// `seed`: once with its default parameters and again with every parameter
/// moved off its default, so that special values (β = π/2, unit masses) hide
/// nothing and `set_parameter` is exercised.
pub fn export_all_systems(seed: u64) -> Result<Vec<SystemExport>, CrosscheckError> {
    struct Samples {
        seed: u64,
        out: Vec<SystemExport>,
    }
    impl CaseVisitor for Samples {
        fn visit<Sys, Host, const N: usize, const M: usize>(&mut self, case: &Case) -> Result<(), CrosscheckError>
        where
            Sys: NonholonomicSystem<N, M> + Default + Clone,
            Host: Dispatch<N, M>,
        {
            let system = Sys::default();
            self.out.push(export_system::<Sys, N, M>(case.name, &system, sample::system_seed(self.seed, case.name)));
            let label = format!("{} (varied parameters)", case.name);
            let varied_seed = sample::system_seed(self.seed, &label);
            let varied = sample::with_varied_parameters::<Sys, N, M>(&system, varied_seed)
                .map_err(|source| CrosscheckError::Parameter { system: case.name.to_owned(), source })?;
            if let Some(varied) = varied {
                self.out.push(export_system::<Sys, N, M>(&label, &varied, varied_seed));
            }
            Ok(())
        }
    }
    let mut samples = Samples { seed, out: Vec::new() };
    visit_cases(&mut samples)?;
    cold::visit_cold_cases(&mut samples)?;
    Ok(samples.out)
}

/// One SPARK step per system ([`visit_cases`]) and method
/// ([`checked_methods`]), from the system's initial state and step size.
/// Every failure is reported, not only the first.
pub fn export_all_steps() -> Result<Vec<StepExport>, CrosscheckError> {
    #[derive(Default)]
    struct Steps {
        out: Vec<StepExport>,
        errors: Vec<CrosscheckError>,
    }
    impl CaseVisitor for Steps {
        fn visit<Sys, Host, const N: usize, const M: usize>(&mut self, case: &Case) -> Result<(), CrosscheckError>
        where
            Sys: NonholonomicSystem<N, M> + Default + Clone,
            Host: Dispatch<N, M>,
        {
            let (q0, v0) = case.state::<N>()?;
            let system = Sys::default();
            for (method, stages) in checked_methods() {
                let step = TakeStep { case, system: &system, method, q0: &q0, v0: &v0 };
                let result = Host::with_stages(stages, step).map_err(|source| CrosscheckError::Dispatch {
                    system: case.name.to_owned(),
                    method: method.key(),
                    source,
                });
                match result.and_then(|r| r) {
                    Ok(step) => self.out.push(step),
                    Err(e) => self.errors.push(e),
                }
            }
            Ok(())
        }
    }
    let mut steps = Steps::default();
    visit_cases(&mut steps)?;
    match steps.errors.len() {
        0 => Ok(steps.out),
        1 => Err(steps.errors.remove(0)),
        _ => Err(CrosscheckError::Several(steps.errors)),
    }
}

/// One step of `method` from a case's initial state, generic in the stage
/// count (a [`StageVisitor`] for any host of the system's shape).
struct TakeStep<'a, Sys, const N: usize> {
    case: &'a Case,
    system: &'a Sys,
    method: Method,
    q0: &'a Vector<N>,
    v0: &'a Vector<N>,
}

impl<Host, Sys, const N: usize, const M: usize> StageVisitor<Host, N, M> for TakeStep<'_, Sys, N>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    type Output = Result<StepExport, CrosscheckError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        let c = self.case;
        export_step::<Sys, N, M, S, D>(c.name, self.system, self.method, c.t0, self.q0, self.v0, c.h)
    }
}

/// One SPARK step of `method` with `S` stages (`D = S(N+M)+N`, see
/// [`Stepper`](struct@spark_runtime::Stepper)) from `(t0, q0, v0)`, with the stepper's default Newton
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
) -> Result<StepExport, CrosscheckError>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let tableau =
        Tableau::<S>::new(method).map_err(|source| CrosscheckError::Tableau { system: name.to_owned(), source })?;
    let v0 = consistent_velocity(system, t0, q0, v0, ConsistencyPolicy::Project { tolerance: 0.0 })
        .map_err(|source| CrosscheckError::Projection { system: name.to_owned(), source })?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(system.clone(), tableau);
    let r = stepper.step(&State::new(t0, *q0, v0), h).map_err(|source| CrosscheckError::Step {
        system: name.to_owned(),
        method: method.key(),
        stages: S,
        source,
    })?;
    let holonomic = Sys::HAS_HOLONOMIC.then(|| sample::vec_of(&system.holonomic_residual(r.state.t, &r.state.q)));
    Ok(step_export(name, &tableau, (t0, h), (q0, &v0), &r, holonomic))
}

/// The [`StepExport`] of step `r` from `(t0, q0, v0)` (generic in the
/// dimensions and the stage count only: compiled once per `(N, M, S)`, not
/// once per system).
fn step_export<const N: usize, const M: usize, const S: usize>(
    name: &str,
    tableau: &Tableau<S>,
    (t0, h): (f64, f64),
    (q0, v0): (&Vector<N>, &Vector<N>),
    r: &StepResult<N, M, S>,
    holonomic_residual: Option<Vec<f64>>,
) -> StepExport {
    use sample::vec_of;
    StepExport {
        system: name.to_owned(),
        method: TableauTable::of(tableau),
        t0,
        h,
        q0: vec_of(q0),
        v0: vec_of(v0),
        q1: vec_of(&r.state.q),
        v1: vec_of(&r.state.v),
        psi: r.stage_multipliers.iter().map(vec_of).collect(),
        stage_velocities: r.stage_velocities.iter().map(vec_of).collect(),
        holonomic_residual,
    }
}
