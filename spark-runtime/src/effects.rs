//! Hand-written systems with optional effects (external forcing `f`, a
//! non-ideal constraint force `N`, a holonomic constraint imposed at velocity
//! level) and the drift report for holonomic constraints.
//!
//! They are references for the effect support of the stepper (its Jacobian
//! is checked against finite differences on them) and for generated scenes.

use crate::handwritten::Skate;
use crate::step::{State, StepResult};
use crate::system::{
    ConstraintForm, Matrix, NonholonomicSystem, NonidealJacobians, OperationCounts, StageJacobians, StageValues,
    Structure, SystemSource, TimeDerivatives, Vector,
};
use crate::tableau::Tableau;
use crate::SystemError;

/// Largest `|g_i(t,q)|` over `states`, the drift of the holonomic
/// constraints of `Sys` imposed at velocity level (`0` when `Sys` has none).
pub fn holonomic_drift<Sys, const N: usize, const M: usize>(sys: &Sys, states: &[State<N>]) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    if !Sys::HAS_HOLONOMIC {
        return 0.0;
    }
    states.iter().map(|s| sys.holonomic_residual(s.t, &s.q).amax()).fold(0.0, f64::max)
}

/// The work `h Σ_j b_j (f_j + N_j)ᵀV_j` of the external and non-ideal forces
/// over one step `step` taken from `start` with size `h`, at the stages
/// `Q_j = q₀ + h Σ_l a_jl V_l`, `T_j = t₀ + c_j h`: the right-hand side of
/// the discrete energy balance `E(t₁) − E(t₀) ≈ ∫ (f + N)ᵀv dt`.
pub fn effect_work<Sys, const N: usize, const M: usize, const S: usize>(
    sys: &Sys,
    tableau: &Tableau<S>,
    start: &State<N>,
    h: f64,
    step: &StepResult<N, M, S>,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut work = 0.0;
    for j in 0..S {
        let mut qj = start.q;
        for l in 0..S {
            qj += (h * tableau.a[j][l]) * step.stage_velocities[l];
        }
        let (tj, vj) = (start.t + tableau.c[j] * h, &step.stage_velocities[j]);
        let f = sys.external_force(tj, &qj, vj) + sys.nonideal_force(tj, &qj, vj, &step.stage_multipliers[j]);
        work += h * tableau.b[j] * f.dot(vj);
    }
    work
}

fn set_checked(name: &str, value: f64, known: &[&str], slot: Option<&mut f64>) -> Result<(), SystemError> {
    if !value.is_finite() {
        return Err(SystemError::NonFiniteParameter { name: name.to_string(), value });
    }
    match slot {
        Some(s) => {
            *s = value;
            Ok(())
        }
        None => Err(SystemError::UnknownParameter { name: name.to_string(), known: known.join(", ") }),
    }
}

/// Implements the Lagrangian and constraint parts of the trait by delegating
/// to the wrapped [`Skate`] in field `skate`.
macro_rules! delegate_skate {
    () => {
        const STRUCTURE: Structure = <Skate as NonholonomicSystem<3, 1>>::STRUCTURE;
        const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };
        fn lagrangian(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> f64 {
            self.skate.lagrangian(t, q, v)
        }
        fn energy(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> f64 {
            self.skate.energy(t, q, v)
        }
        fn momentum(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<3> {
            self.skate.momentum(t, q, v)
        }
        fn force(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<3> {
            self.skate.force(t, q, v)
        }
        fn mass_matrix(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Matrix<3, 3> {
            self.skate.mass_matrix(t, q, v)
        }
        fn constraint(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<1> {
            self.skate.constraint(t, q, v)
        }
        fn constraint_q(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Matrix<1, 3> {
            self.skate.constraint_q(t, q, v)
        }
        fn constraint_v(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> Matrix<1, 3> {
            self.skate.constraint_v(t, q, v)
        }
        fn time_derivatives(&self, t: f64, q: &Vector<3>, v: &Vector<3>) -> TimeDerivatives<3, 1> {
            self.skate.time_derivatives(t, q, v)
        }
        fn stage_values(&self, t: f64, q: &Vector<3>, v: &Vector<3>, psi: &Vector<1>) -> StageValues<3, 1> {
            self.skate.stage_values(t, q, v, psi)
        }
        fn stage_jacobians(
            &self,
            t: f64,
            q: &Vector<3>,
            v: &Vector<3>,
            psi: &Vector<1>,
        ) -> (StageValues<3, 1>, StageJacobians<3, 1>) {
            self.skate.stage_jacobians(t, q, v, psi)
        }
    };
}

/// The skate (§8.2) driven by a torque `τ` about its vertical axis and
/// viscously damped: `f = (−c v₁, −c v₂, τ − c v₃)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrivenSkate {
    /// The conservative skate.
    pub skate: Skate,
    /// Viscous damping coefficient `c`.
    pub damping: f64,
    /// Drive torque `τ`.
    pub torque: f64,
}

impl Default for DrivenSkate {
    fn default() -> Self {
        DrivenSkate { skate: Skate::default(), damping: 0.3, torque: 0.5 }
    }
}

const DRIVEN_PARAMETERS: &[&str] = &["m", "inertia", "g", "beta", "c", "tau"];

impl NonholonomicSystem<3, 1> for DrivenSkate {
    delegate_skate!();
    const SOURCE: SystemSource = SystemSource {
        name: "DrivenSkate",
        external_force: &["(neg (* (p c) (v x)))", "(neg (* (p c) (v y)))", "(- (p tau) (* (p c) (v theta)))"],
        parameters: DRIVEN_PARAMETERS,
        ..<Skate as NonholonomicSystem<3, 1>>::SOURCE
    };
    const HAS_FORCING: bool = true;

    fn parameter_values(&self) -> Vec<f64> {
        let s = &self.skate;
        vec![s.m, s.inertia, s.g, s.beta, self.damping, self.torque]
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        let slot = match name {
            "m" => Some(&mut self.skate.m),
            "inertia" => Some(&mut self.skate.inertia),
            "g" => Some(&mut self.skate.g),
            "beta" => Some(&mut self.skate.beta),
            "c" => Some(&mut self.damping),
            "tau" => Some(&mut self.torque),
            _ => None,
        };
        set_checked(name, value, DRIVEN_PARAMETERS, slot)
    }
    fn external_force(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Vector<3> {
        Vector::<3>::new(-self.damping * v[0], -self.damping * v[1], self.torque - self.damping * v[2])
    }
    fn external_force_jacobians(
        &self,
        t: f64,
        q: &Vector<3>,
        v: &Vector<3>,
    ) -> (Vector<3>, Matrix<3, 3>, Matrix<3, 3>) {
        (self.external_force(t, q, v), Matrix::zeros(), Matrix::identity() * -self.damping)
    }
}

/// The skate with smoothed dry friction along the blade, proportional to the
/// magnitude of the lateral constraint force (paper §3.3):
///
/// `N(q,v,ψ) = −μ · √(ψ² + δ²) · u/√(u² + ε²) · e`, with the blade direction
/// `e = (cos q₃, sin q₃, 0)` and the sliding speed `u = e·v`.
///
/// `√(ψ²+δ²)` smooths `|ψ|` (the normal force of the blade) and
/// `u/√(u²+ε²)` smooths `sign(u)`, so `N` is C^∞ and Newton converges; as
/// `δ, ε → 0` it tends to Coulomb friction `−μ|ψ| sign(u) e`. The friction
/// does negative work: `Nᵀv = −μ√(ψ²+δ²) u²/√(u²+ε²) ≤ 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionSkate {
    /// The conservative skate.
    pub skate: Skate,
    /// Friction coefficient `μ`.
    pub mu: f64,
    /// Smoothing of `|ψ|`.
    pub delta: f64,
    /// Smoothing of `sign(u)`.
    pub epsilon: f64,
}

impl Default for FrictionSkate {
    fn default() -> Self {
        FrictionSkate { skate: Skate::default(), mu: 0.2, delta: 1e-3, epsilon: 1e-2 }
    }
}

const FRICTION_PARAMETERS: &[&str] = &["m", "inertia", "g", "beta", "mu", "delta", "epsilon"];

impl NonholonomicSystem<3, 1> for FrictionSkate {
    delegate_skate!();
    const SOURCE: SystemSource = SystemSource {
        name: "FrictionSkate",
        // −μ √(ψ₀² + δ²) · u/√(u² + ε²) · e with u = cos θ ẋ + sin θ ẏ.
        nonideal_force: &[
            concat!(
                "(neg (* (p mu) (sqrt (+ (^ (psi 0) 2) (^ (p delta) 2))) ",
                "(/ (+ (* (cos (q theta)) (v x)) (* (sin (q theta)) (v y))) ",
                "(sqrt (+ (^ (+ (* (cos (q theta)) (v x)) (* (sin (q theta)) (v y))) 2) (^ (p epsilon) 2)))) ",
                "(cos (q theta))))"
            ),
            concat!(
                "(neg (* (p mu) (sqrt (+ (^ (psi 0) 2) (^ (p delta) 2))) ",
                "(/ (+ (* (cos (q theta)) (v x)) (* (sin (q theta)) (v y))) ",
                "(sqrt (+ (^ (+ (* (cos (q theta)) (v x)) (* (sin (q theta)) (v y))) 2) (^ (p epsilon) 2)))) ",
                "(sin (q theta))))"
            ),
            "0",
        ],
        parameters: FRICTION_PARAMETERS,
        ..<Skate as NonholonomicSystem<3, 1>>::SOURCE
    };
    const HAS_NONIDEAL_FORCE: bool = true;

    fn parameter_values(&self) -> Vec<f64> {
        let s = &self.skate;
        vec![s.m, s.inertia, s.g, s.beta, self.mu, self.delta, self.epsilon]
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        let slot = match name {
            "m" => Some(&mut self.skate.m),
            "inertia" => Some(&mut self.skate.inertia),
            "g" => Some(&mut self.skate.g),
            "beta" => Some(&mut self.skate.beta),
            "mu" => Some(&mut self.mu),
            "delta" => Some(&mut self.delta),
            "epsilon" => Some(&mut self.epsilon),
            _ => None,
        };
        set_checked(name, value, FRICTION_PARAMETERS, slot)
    }
    fn nonideal_force(&self, t: f64, q: &Vector<3>, v: &Vector<3>, psi: &Vector<1>) -> Vector<3> {
        self.nonideal_force_jacobians(t, q, v, psi).value
    }
    fn nonideal_force_jacobians(
        &self,
        _: f64,
        q: &Vector<3>,
        v: &Vector<3>,
        psi: &Vector<1>,
    ) -> NonidealJacobians<3, 1> {
        let (s, c) = q[2].sin_cos();
        let e = Vector::<3>::new(c, s, 0.0);
        let e_theta = Vector::<3>::new(-s, c, 0.0);
        let u = e.dot(v);
        let u_theta = e_theta.dot(v);
        let w = (u * u + self.epsilon * self.epsilon).sqrt();
        let sign = u / w;
        let dsign = self.epsilon * self.epsilon / (w * w * w);
        let a = (psi[0] * psi[0] + self.delta * self.delta).sqrt();
        let value = -self.mu * a * sign * e;
        let mut dq = Matrix::<3, 3>::zeros();
        dq.set_column(2, &(-self.mu * a * (dsign * u_theta * e + sign * e_theta)));
        let dv = -self.mu * a * dsign * e * e.transpose();
        let dpsi = Matrix::<3, 1>::from_column_slice((-self.mu * psi[0] / a * sign * e).as_slice());
        NonidealJacobians { value, q: dq, v: dv, psi: dpsi }
    }
}

/// A planar pendulum of length `ℓ` as a point mass with the holonomic
/// constraint `g = ½(x² + y² − ℓ²) = 0` imposed at velocity level
/// (`k = x ẋ + y ẏ`, paper §5.1): `L = ½m(ẋ² + ẏ²) − m g₀ y`. The stepper
/// keeps `k = 0`; `g` drifts and is reported by
/// [`holonomic_residual`](NonholonomicSystem::holonomic_residual).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RodPendulum {
    /// Mass.
    pub m: f64,
    /// Gravity.
    pub gravity: f64,
    /// Rod length.
    pub length: f64,
}

impl Default for RodPendulum {
    fn default() -> Self {
        RodPendulum { m: 1.0, gravity: 1.0, length: 1.0 }
    }
}

const ROD_PARAMETERS: &[&str] = &["m", "g", "ell"];

impl NonholonomicSystem<2, 1> for RodPendulum {
    const STRUCTURE: Structure = Structure {
        lagrangian_autonomous: true,
        constraints_autonomous: true,
        constant_mass_matrix: true,
        separable: true,
        constraint_form: ConstraintForm::Linear,
    };
    const SOURCE: SystemSource = SystemSource {
        name: "RodPendulum",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &["(* 0.5 (- (+ (^ (q x) 2) (^ (q y) 2)) (^ (p ell) 2)))"],
        coordinates: &["x", "y"],
        parameters: ROD_PARAMETERS,
        lagrangian: "(- (* (/ (p m) 2) (+ (^ (v x) 2) (^ (v y) 2))) (* (p m) (p g) (q y)))",
        constraints: &["(+ (* (q x) (v x)) (* (q y) (v y)))"],
    };
    const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };
    const HAS_HOLONOMIC: bool = true;

    fn parameter_values(&self) -> Vec<f64> {
        vec![self.m, self.gravity, self.length]
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        let slot = match name {
            "m" => Some(&mut self.m),
            "g" => Some(&mut self.gravity),
            "ell" => Some(&mut self.length),
            _ => None,
        };
        set_checked(name, value, ROD_PARAMETERS, slot)
    }
    fn lagrangian(&self, _: f64, q: &Vector<2>, v: &Vector<2>) -> f64 {
        0.5 * self.m * v.norm_squared() - self.m * self.gravity * q[1]
    }
    fn energy(&self, _: f64, q: &Vector<2>, v: &Vector<2>) -> f64 {
        0.5 * self.m * v.norm_squared() + self.m * self.gravity * q[1]
    }
    fn momentum(&self, _: f64, _: &Vector<2>, v: &Vector<2>) -> Vector<2> {
        self.m * v
    }
    fn force(&self, _: f64, _: &Vector<2>, _: &Vector<2>) -> Vector<2> {
        Vector::<2>::new(0.0, -self.m * self.gravity)
    }
    fn mass_matrix(&self, _: f64, _: &Vector<2>, _: &Vector<2>) -> Matrix<2, 2> {
        Matrix::identity() * self.m
    }
    fn constraint(&self, _: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<1> {
        Vector::<1>::new(q.dot(v))
    }
    fn constraint_q(&self, _: f64, _: &Vector<2>, v: &Vector<2>) -> Matrix<1, 2> {
        v.transpose()
    }
    fn constraint_v(&self, _: f64, q: &Vector<2>, _: &Vector<2>) -> Matrix<1, 2> {
        q.transpose()
    }
    fn time_derivatives(&self, _: f64, _: &Vector<2>, _: &Vector<2>) -> TimeDerivatives<2, 1> {
        TimeDerivatives {
            lagrangian_t: 0.0,
            momentum_t: Vector::zeros(),
            force_t: Vector::zeros(),
            constraint_t: Vector::zeros(),
        }
    }
    fn stage_values(&self, t: f64, q: &Vector<2>, v: &Vector<2>, psi: &Vector<1>) -> StageValues<2, 1> {
        StageValues {
            momentum: self.momentum(t, q, v),
            force: self.force(t, q, v),
            constraint: self.constraint(t, q, v),
            constraint_force: -psi[0] * q,
        }
    }
    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<2>,
        v: &Vector<2>,
        psi: &Vector<1>,
    ) -> (StageValues<2, 1>, StageJacobians<2, 1>) {
        let jac = StageJacobians {
            momentum_q: Matrix::zeros(),
            mass: self.mass_matrix(t, q, v),
            force_q: Matrix::zeros(),
            force_v: Matrix::zeros(),
            constraint_q: self.constraint_q(t, q, v),
            constraint_v: self.constraint_v(t, q, v),
            constraint_force_q: Matrix::identity() * -psi[0],
            constraint_force_v: Matrix::zeros(),
        };
        (self.stage_values(t, q, v, psi), jac)
    }
    fn holonomic_residual(&self, _: f64, q: &Vector<2>) -> Vector<1> {
        Vector::<1>::new(0.5 * (q.norm_squared() - self.length * self.length))
    }
}

#[cfg(test)]
mod tests;
