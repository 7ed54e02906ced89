//! Hard cold steps: systems with strong velocity-dependent terms — a
//! magnetic term `b A(q)·v` in `L`, viscous damping `−c v`, drag nonlinear
//! in `v`, a forcing that depends on `t`, an affine constraint
//! `k = K(q)v + b(t, q)` — stepped once from their initial state, cold (no
//! earlier step), at step sizes where `h` times the force's rate (`b/m`,
//! `c/m`, `2c|v|/m`) is between 2 and 10: there the stepper's acceleration
//! guess `V_i = v0 + c_i h a0` is far from the solution.
//!
//! Every case is stepped with every Newton mode ([`NEWTON_MODES`]) and every
//! method of [`COLD_METHODS`]. A step the stepper refuses is exported with
//! its error instead of failing the export: `casadi/crosscheck.py` compares
//! each solved step with the root on the branch that starts at `h → 0`
//! (CasADi's continuation in `h`) and reports every refusal as a failure.

use serde::Serialize;
use spark_runtime::{
    consistent_velocity, nonholonomic_system, ConsistencyPolicy, Jacobian, Method, NewtonMode, NewtonOptions,
    NonholonomicSystem, State, Stepper, Tableau, TableauTable,
};

use super::sample::vec_of;
use super::{Case, CaseVisitor, CrosscheckError};
use crate::catalog::{Dispatch, StageVisitor};

nonholonomic_system! {
    /// A charged bead in the plane, in a harmonic trap and a magnetic field
    /// that decays away from the origin: `L = ½m|v|² + A(q)·v − κ|q|²/2` with
    /// `A = b(−y, x)/(2(1 + ε|q|²))`, so the field is `B = b/(1 + ε|q|²)²`.
    /// No constraint, no force: the velocity dependence is all in `L`
    /// (gyroscopic).
    pub struct MagneticBead {
        coordinates: [x, y],
        parameters: { m = 1.0, b = 14.0, eps = 0.25, kappa = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + b/2*(x*dot(y) - y*dot(x))/(1 + eps*(x^2 + y^2))
            - kappa/2*(x^2 + y^2),
    }
}

nonholonomic_system! {
    /// A bob on a massless rod, the rod imposed at velocity level
    /// (`k = x ẋ + y ẏ`), under gravity and viscous damping `f = −c v`.
    pub struct DampedRodBob {
        coordinates: [x, y],
        parameters: { m = 1.0, g = 9.81, c = 30.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) - m*g*y,
        constraints: [ x*dot(x) + y*dot(y) ],
        forces: { x: -c*dot(x), y: -c*dot(y) },
    }
}

nonholonomic_system! {
    /// The skate on an inclined plane with quadratic air drag on its centre,
    /// `f = −c √(ẋ² + ẏ² + δ²) (ẋ, ẏ)` (nonlinear in `v`), and a torque
    /// `−c_θ θ̇ (1 + θ̇²)` on its heading.
    pub struct DragSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.5, g = 9.81, beta = 0.5, c = 0.5, delta = 0.1, c_theta = 2.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        forces: {
            x: -c*sqrt(dot(x)^2 + dot(y)^2 + delta^2)*dot(x),
            y: -c*sqrt(dot(x)^2 + dot(y)^2 + delta^2)*dot(y),
            theta: -c_theta*dot(theta)*(1 + dot(theta)^2),
        },
    }
}

nonholonomic_system! {
    /// A Duffing oscillator in the plane, damped (`−c v`) and driven by
    /// `f₀ (cos νt, sin νt)`: a forcing that depends on `t`.
    pub struct DrivenDuffing {
        coordinates: [x, y],
        parameters: { m = 1.0, kappa = 4.0, alpha = 2.0, c = 10.0, f0 = 40.0, nu = 3.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) - kappa/2*(x^2 + y^2) - alpha/4*(x^2 + y^2)^2,
        forces: { x: -c*dot(x) + f0*cos(nu*t), y: -c*dot(y) + f0*sin(nu*t) },
    }
}

nonholonomic_system! {
    /// A Chaplygin sleigh on a conveyor belt that moves along `x` with speed
    /// `w(t) = u sin νt`: the blade does not slip sideways relative to the
    /// belt, `k = −sin θ (ẋ − w) + cos θ ẏ` (affine, `b(t, q) = u sin νt sin θ`),
    /// and the belt drags the sleigh viscously,
    /// `f = (−c(ẋ − w), −c ẏ, −c_θ θ̇)`.
    pub struct ConveyorSleigh {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.5, a = 0.5, c = 20.0, c_theta = 10.0, u = 2.0, nu = 2.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2 + a^2*dot(theta)^2
                         + 2*a*dot(theta)*(-dot(x)*sin(theta) + dot(y)*cos(theta)))
            + inertia/2*dot(theta)^2,
        constraints: [ -sin(theta)*(dot(x) - u*sin(nu*t)) + cos(theta)*dot(y) ],
        forces: { x: -c*(dot(x) - u*sin(nu*t)), y: -c*dot(y), theta: -c_theta*dot(theta) },
    }
}

/// [`MagneticBead`] at `|q| = 1`: field `B = 8.96`, `h B/m ≈ 9`.
pub const MAGNETIC_BEAD: Case = Case { name: "cold-magnetic-bead", t0: 0.0, q0: &[0.8, 0.6], v0: &[0.3, -0.2], h: 1.0 };

/// [`DampedRodBob`]: `h c/m = 6`.
pub const DAMPED_ROD_BOB: Case =
    Case { name: "cold-damped-rod-bob", t0: 0.0, q0: &[0.6, -0.8], v0: &[0.8, 0.6], h: 0.2 };

/// [`DragSkate`] at speed 3 along its blade, `θ̇ = 0.5`: the drag's rate is
/// `h · 2c|v|/m = 1.5`, the torque's `h · c_θ(1 + 3θ̇²)/I = 3.5`.
pub const DRAG_SKATE: Case =
    Case { name: "cold-drag-skate", t0: 0.0, q0: &[0.0, 0.0, 0.4], v0: &[2.763_182_982, 1.168_255_01, 0.5], h: 0.5 };

/// [`DrivenDuffing`] from `t0 = 0.3`: `h c/m = 5`.
pub const DRIVEN_DUFFING: Case =
    Case { name: "cold-driven-duffing", t0: 0.3, q0: &[1.0, -0.5], v0: &[0.2, 0.4], h: 0.5 };

/// [`ConveyorSleigh`] from `t0 = 0.2` (the belt moving): `h c/m = 5`.
pub const CONVEYOR_SLEIGH: Case =
    Case { name: "cold-conveyor-sleigh", t0: 0.2, q0: &[0.0, 0.0, 0.7], v0: &[0.5, 0.3, -0.4], h: 0.25 };

/// Every hard cold case, in the order of [`visit_cold_cases`].
pub const COLD_CASES: [&Case; 5] = [&MAGNETIC_BEAD, &DAMPED_ROD_BOB, &DRAG_SKATE, &DRIVEN_DUFFING, &CONVEYOR_SLEIGH];

/// Calls `visitor` for every hard cold case, each with the stage dispatch of
/// a catalogue type of its shape.
pub fn visit_cold_cases<V: CaseVisitor>(visitor: &mut V) -> Result<(), CrosscheckError> {
    use crate::systems::scenes::{PointMass, RodPendulum, Sleigh};
    visitor.visit::<MagneticBead, PointMass, 2, 0>(&MAGNETIC_BEAD)?;
    visitor.visit::<DampedRodBob, RodPendulum, 2, 1>(&DAMPED_ROD_BOB)?;
    visitor.visit::<DragSkate, Sleigh, 3, 1>(&DRAG_SKATE)?;
    visitor.visit::<DrivenDuffing, PointMass, 2, 0>(&DRIVEN_DUFFING)?;
    visitor.visit::<ConveyorSleigh, Sleigh, 3, 1>(&CONVEYOR_SLEIGH)
}

/// The methods of the hard cold steps: Gauss s = 1..3, Lobatto IIIA-B and
/// IIIA-B-D s = 2, 3.
pub const COLD_METHODS: [(Method, usize); 7] = [
    (Method::Gauss, 1),
    (Method::Gauss, 2),
    (Method::Gauss, 3),
    (Method::LobattoIIIAB, 2),
    (Method::LobattoIIIAB, 3),
    (Method::LobattoIIIABD, 2),
    (Method::LobattoIIIABD, 3),
];

/// Every Newton mode of the stepper, by its label in the export: full
/// Newton, and simplified Newton on the exact and on the stage-decoupled
/// matrix (`Jacobian::Auto` picks one of these two).
pub const NEWTON_MODES: [(&str, NewtonMode, Jacobian); 3] = [
    ("full", NewtonMode::Full, Jacobian::Auto),
    ("simplified-exact", NewtonMode::Simplified, Jacobian::Exact),
    ("simplified-decoupled", NewtonMode::Simplified, Jacobian::StageDecoupled),
];

/// One cold step of one Newton mode: the start, and what the stepper returned.
#[derive(Clone, Debug, Serialize)]
pub struct ColdStepExport {
    /// Name of the system (a key of [`super::Document::systems`]).
    pub system: String,
    /// The method.
    pub method: TableauTable,
    /// The Newton mode's label ([`NEWTON_MODES`]).
    pub newton: &'static str,
    /// Initial time.
    pub t0: f64,
    /// Step size.
    pub h: f64,
    /// Initial coordinates.
    pub q0: Vec<f64>,
    /// Initial velocities (projected onto the constraints).
    pub v0: Vec<f64>,
    /// The step, when the stepper solved it.
    pub solved: Option<ColdSolution>,
    /// The stepper's error, when it refused the step.
    pub error: Option<String>,
}

/// A solved cold step.
#[derive(Clone, Debug, Serialize)]
pub struct ColdSolution {
    /// Coordinates after the step.
    pub q1: Vec<f64>,
    /// Velocities after the step.
    pub v1: Vec<f64>,
    /// Stage multipliers `Ψ_1..Ψ_s`, one row per stage.
    pub psi: Vec<Vec<f64>>,
    /// Stage velocities `V_1..V_s`, one row per stage.
    pub stage_velocities: Vec<Vec<f64>>,
    /// Newton updates the step took.
    pub iterations: usize,
    /// Newton matrices the step factored.
    pub factorizations: usize,
}

/// Every hard cold step: each case of [`visit_cold_cases`], method of
/// [`COLD_METHODS`] and mode of [`NEWTON_MODES`]. A step the stepper refuses
/// is recorded with its error; only a malformed case fails the export.
pub fn export_cold_steps() -> Result<Vec<ColdStepExport>, CrosscheckError> {
    #[derive(Default)]
    struct Steps(Vec<ColdStepExport>);
    impl CaseVisitor for Steps {
        fn visit<Sys, Host, const N: usize, const M: usize>(&mut self, case: &Case) -> Result<(), CrosscheckError>
        where
            Sys: NonholonomicSystem<N, M> + Default + Clone,
            Host: Dispatch<N, M>,
        {
            let (q0, v0) = case.state::<N>()?;
            let system = Sys::default();
            let v0 = consistent_velocity(&system, case.t0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 0.0 })
                .map_err(|source| CrosscheckError::Projection { system: case.name.to_owned(), source })?;
            for (method, stages) in COLD_METHODS {
                let take = TakeColdSteps { case, system: &system, method, q0: &q0, v0: &v0 };
                let steps = Host::with_stages(stages, take).map_err(|source| CrosscheckError::Dispatch {
                    system: case.name.to_owned(),
                    method: method.key(),
                    source,
                })??;
                self.0.extend(steps);
            }
            Ok(())
        }
    }
    let mut steps = Steps::default();
    visit_cold_cases(&mut steps)?;
    Ok(steps.0)
}

/// The cold steps of one method in every Newton mode, generic in the stage
/// count.
struct TakeColdSteps<'a, Sys, const N: usize> {
    case: &'a Case,
    system: &'a Sys,
    method: Method,
    q0: &'a spark_runtime::Vector<N>,
    v0: &'a spark_runtime::Vector<N>,
}

impl<Host, Sys, const N: usize, const M: usize> StageVisitor<Host, N, M> for TakeColdSteps<'_, Sys, N>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    type Output = Result<Vec<ColdStepExport>, CrosscheckError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        let c = self.case;
        let tableau = Tableau::<S>::new(self.method)
            .map_err(|source| CrosscheckError::Tableau { system: c.name.to_owned(), source })?;
        let start = State::new(c.t0, *self.q0, *self.v0);
        let mut out = Vec::with_capacity(NEWTON_MODES.len());
        for (label, mode, jacobian) in NEWTON_MODES {
            let options = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
            let mut stepper = Stepper::<Sys, N, M, S, D>::new(self.system.clone(), tableau).with_options(options);
            let (solved, error) = match stepper.step(&start, c.h) {
                Ok(r) => (
                    Some(ColdSolution {
                        q1: vec_of(&r.state.q),
                        v1: vec_of(&r.state.v),
                        psi: r.stage_multipliers.iter().map(vec_of).collect(),
                        stage_velocities: r.stage_velocities.iter().map(vec_of).collect(),
                        iterations: r.iterations,
                        factorizations: r.factorizations,
                    }),
                    None,
                ),
                Err(e) => (None, Some(e.to_string())),
            };
            out.push(ColdStepExport {
                system: c.name.to_owned(),
                method: TableauTable::of(&tableau),
                newton: label,
                t0: c.t0,
                h: c.h,
                q0: vec_of(self.q0),
                v0: vec_of(self.v0),
                solved,
                error,
            });
        }
        Ok(out)
    }
}
