//! The same SPARK stepper with derivatives from runtime forward-mode automatic
//! differentiation (`num-dual`) instead of the generated code.
//!
//! A user who does not want a code generator writes the Lagrangian and the
//! constraints once, generically over [`DualNum`], and wraps them in
//! [`AutoDiff`], which implements [`NonholonomicSystem`] by propagating dual
//! numbers through those functions: gradients with [`DualVec`], the three
//! second-derivative blocks of `L` (`vv`, `qq`, `vq`) and those of `ψ·k`
//! with [`Dual2Vec`] and [`HyperDualVec`], and `k_q`, `K` with dual Jacobians.
//! Seven dual evaluations per stage Jacobian, three per stage value set: the
//! usual way to get exact derivatives at run time without writing them.
//!
//! The adapter copies the structure facts of the generated twin, so the
//! stepper does exactly the same work; only the derivative code differs.

use crate::catalog::{Dispatch, SystemEntry, SystemKind};
use crate::systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};
use nalgebra::{Const, SVector};
use num_dual::{gradient, hessian, jacobian, partial_hessian, Dual2Vec, DualNum, DualVec, HyperDualVec};
use spark_runtime::{
    Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemError, SystemSource,
    TimeDerivatives, Vector,
};

/// A Lagrangian `L(t,q,v)` and constraints `k(t,q,v)` written once, generic
/// over the number type, so that dual numbers can flow through them.
pub trait DualLagrangian<const N: usize, const M: usize> {
    /// Structure facts (copied from the generated twin, so the stepper skips
    /// the same work).
    const STRUCTURE: Structure;
    /// Source text (copied from the generated twin).
    const SOURCE: SystemSource;
    /// `L(t,q,v)`.
    fn lagrangian<D: DualNum<f64> + Copy>(&self, t: D, q: &SVector<D, N>, v: &SVector<D, N>) -> D;
    /// `k(t,q,v)`.
    fn constraints<D: DualNum<f64> + Copy>(&self, t: D, q: &SVector<D, N>, v: &SVector<D, N>) -> SVector<D, M>;
    /// Current parameter values, in the order of `SOURCE.parameters`.
    fn parameter_values(&self) -> Vec<f64>;
    /// Sets a parameter by name.
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError>;
}

/// [`NonholonomicSystem`] with every derivative from `num-dual`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AutoDiff<L>(pub L);

fn lift<D: DualNum<f64> + Copy, const N: usize>(x: &Vector<N>) -> SVector<D, N> {
    x.map(D::from)
}

/// `ψ·k(t,q,v)`, whose `v`-gradient is `Kᵀψ`.
fn weighted<L, D, const N: usize, const M: usize>(
    l: &L,
    t: D,
    q: &SVector<D, N>,
    v: &SVector<D, N>,
    psi: &Vector<M>,
) -> D
where
    L: DualLagrangian<N, M>,
    D: DualNum<f64> + Copy,
{
    let k = l.constraints(t, q, v);
    (0..M).fold(D::zero(), |acc, i| acc + k[i] * psi[i])
}

type Grad<const N: usize> = DualVec<f64, f64, Const<N>>;
type Hess<const N: usize> = Dual2Vec<f64, f64, Const<N>>;
type Mixed<const N: usize> = HyperDualVec<f64, f64, Const<N>, Const<N>>;

fn grad_v<L: DualLagrangian<N, M>, const N: usize, const M: usize>(
    l: &L,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> (f64, Vector<N>) {
    gradient(|vd: SVector<Grad<N>, N>| l.lagrangian(Grad::<N>::from(t), &lift(q), &vd), *v)
}
fn grad_q<L: DualLagrangian<N, M>, const N: usize, const M: usize>(
    l: &L,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> (f64, Vector<N>) {
    gradient(|qd: SVector<Grad<N>, N>| l.lagrangian(Grad::<N>::from(t), &qd, &lift(v)), *q)
}
fn jac_v<L: DualLagrangian<N, M>, const N: usize, const M: usize>(
    l: &L,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> (Vector<M>, Matrix<M, N>) {
    jacobian(|vd: SVector<Grad<N>, N>| l.constraints(Grad::<N>::from(t), &lift(q), &vd), *v)
}
fn jac_q<L: DualLagrangian<N, M>, const N: usize, const M: usize>(
    l: &L,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> (Vector<M>, Matrix<M, N>) {
    jacobian(|qd: SVector<Grad<N>, N>| l.constraints(Grad::<N>::from(t), &qd, &lift(v)), *q)
}

impl<L: DualLagrangian<N, M>, const N: usize, const M: usize> NonholonomicSystem<N, M> for AutoDiff<L> {
    const STRUCTURE: Structure = L::STRUCTURE;
    const SOURCE: SystemSource = L::SOURCE;
    const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };

    fn parameter_values(&self) -> Vec<f64> {
        self.0.parameter_values()
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        self.0.set_parameter(name, value)
    }
    fn lagrangian(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        self.0.lagrangian(t, q, v)
    }
    fn energy(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        let (l, p) = grad_v(&self.0, t, q, v);
        p.dot(v) - l
    }
    fn momentum(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        grad_v(&self.0, t, q, v).1
    }
    fn force(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        grad_q(&self.0, t, q, v).1
    }
    fn mass_matrix(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N> {
        hessian(|vd: SVector<Hess<N>, N>| self.0.lagrangian(Hess::<N>::from(t), &lift(q), &vd), *v).2
    }
    fn constraint(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<M> {
        self.0.constraints(t, q, v)
    }
    fn constraint_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        jac_q(&self.0, t, q, v).1
    }
    fn constraint_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        jac_v(&self.0, t, q, v).1
    }
    fn time_derivatives(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> TimeDerivatives<N, M> {
        if L::STRUCTURE.autonomous() {
            return TimeDerivatives {
                lagrangian_t: 0.0,
                momentum_t: Vector::zeros(),
                force_t: Vector::zeros(),
                constraint_t: Vector::zeros(),
            };
        }
        type T1 = DualVec<f64, f64, Const<1>>;
        type Tv<const N: usize> = HyperDualVec<f64, f64, Const<N>, Const<1>>;
        let ts = SVector::<f64, 1>::new(t);
        let (_, lt) = gradient(|td: SVector<T1, 1>| self.0.lagrangian(td[0], &lift(q), &lift(v)), ts);
        let (_, _, _, pt) = partial_hessian(
            |vd: SVector<Tv<N>, N>, td: SVector<Tv<N>, 1>| self.0.lagrangian(td[0], &lift(q), &vd),
            *v,
            ts,
        );
        let (_, _, _, ft) = partial_hessian(
            |qd: SVector<Tv<N>, N>, td: SVector<Tv<N>, 1>| self.0.lagrangian(td[0], &qd, &lift(v)),
            *q,
            ts,
        );
        let (_, kt) = jacobian(|td: SVector<T1, 1>| self.0.constraints(td[0], &lift(q), &lift(v)), ts);
        TimeDerivatives {
            lagrangian_t: lt[0],
            momentum_t: pt.column(0).into_owned(),
            force_t: ft.column(0).into_owned(),
            constraint_t: kt.column(0).into_owned(),
        }
    }

    fn stage_values(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> StageValues<N, M> {
        let (_, momentum) = grad_v(&self.0, t, q, v);
        let (_, force) = grad_q(&self.0, t, q, v);
        let (constraint, k_v) = jac_v(&self.0, t, q, v);
        StageValues { momentum, force, constraint, constraint_force: -(k_v.transpose() * psi), ..StageValues::zeros() }
    }

    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
    ) -> (StageValues<N, M>, StageJacobians<N, M>) {
        let l = &self.0;
        let (_, momentum, mass) =
            hessian(|vd: SVector<Hess<N>, N>| l.lagrangian(Hess::<N>::from(t), &lift(q), &vd), *v);
        let (_, force, force_q) =
            hessian(|qd: SVector<Hess<N>, N>| l.lagrangian(Hess::<N>::from(t), &qd, &lift(v)), *q);
        // d2[i][j] = ∂²L/∂v_i∂q_j = ∂p_i/∂q_j.
        let (_, _, _, momentum_q) = partial_hessian(
            |vd: SVector<Mixed<N>, N>, qd: SVector<Mixed<N>, N>| l.lagrangian(Mixed::<N>::from(t), &qd, &vd),
            *v,
            *q,
        );
        let (constraint, constraint_v) = jac_v(&self.0, t, q, v);
        let (_, constraint_q) = jac_q(&self.0, t, q, v);
        let (_, kt_psi, kt_psi_v) =
            hessian(|vd: SVector<Hess<N>, N>| weighted(l, Hess::<N>::from(t), &lift(q), &vd, psi), *v);
        let (_, _, _, kt_psi_q) = partial_hessian(
            |vd: SVector<Mixed<N>, N>, qd: SVector<Mixed<N>, N>| weighted(l, Mixed::<N>::from(t), &qd, &vd, psi),
            *v,
            *q,
        );
        let values = StageValues { momentum, force, constraint, constraint_force: -kt_psi, ..StageValues::zeros() };
        let jacobians = StageJacobians {
            momentum_q,
            mass,
            force_q,
            force_v: momentum_q.transpose(),
            constraint_q,
            constraint_v,
            constraint_force_q: -kt_psi_q,
            constraint_force_v: -kt_psi_v,
        };
        (values, jacobians)
    }
}

fn unknown(name: &str, known: &[&str]) -> SystemError {
    SystemError::UnknownParameter { name: name.to_string(), known: known.join(", ") }
}

/// Sets `name` among `(names, slots)`, or names the known ones.
fn set_named(names: &[&str], slots: &mut [&mut f64], name: &str, value: f64) -> Result<(), SystemError> {
    match names.iter().position(|n| *n == name) {
        Some(i) => {
            *slots[i] = value;
            Ok(())
        }
        None => Err(unknown(name, names)),
    }
}

/// The nonholonomic particle (§8.1), written generically.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DualParticle;

impl DualLagrangian<3, 1> for DualParticle {
    const STRUCTURE: Structure = <NonholonomicParticle as NonholonomicSystem<3, 1>>::STRUCTURE;
    const SOURCE: SystemSource = <NonholonomicParticle as NonholonomicSystem<3, 1>>::SOURCE;
    fn lagrangian<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 3>, v: &SVector<D, 3>) -> D {
        (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) * 0.5 - (q[0] * q[0] + q[1] * q[1])
    }
    fn constraints<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 3>, v: &SVector<D, 3>) -> SVector<D, 1> {
        SVector::<D, 1>::new(v[2] - q[1] * v[0])
    }
    fn parameter_values(&self) -> Vec<f64> {
        Vec::new()
    }
    fn set_parameter(&mut self, name: &str, _value: f64) -> Result<(), SystemError> {
        Err(unknown(name, &[]))
    }
}

/// The skate on an inclined plane (§8.2), written generically.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DualSkate {
    /// Mass.
    pub m: f64,
    /// Moment of inertia.
    pub inertia: f64,
    /// Gravity.
    pub g: f64,
    /// Inclination.
    pub beta: f64,
}

impl Default for DualSkate {
    fn default() -> Self {
        DualSkate { m: 1.0, inertia: 1.0, g: 1.0, beta: std::f64::consts::FRAC_PI_2 }
    }
}

impl DualLagrangian<3, 1> for DualSkate {
    const STRUCTURE: Structure = <Skate as NonholonomicSystem<3, 1>>::STRUCTURE;
    const SOURCE: SystemSource = <Skate as NonholonomicSystem<3, 1>>::SOURCE;
    fn lagrangian<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 3>, v: &SVector<D, 3>) -> D {
        (v[0] * v[0] + v[1] * v[1]) * (0.5 * self.m)
            + v[2] * v[2] * (0.5 * self.inertia)
            + q[0] * (self.m * self.g * self.beta.sin())
    }
    fn constraints<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 3>, v: &SVector<D, 3>) -> SVector<D, 1> {
        SVector::<D, 1>::new(q[2].cos() * v[1] - q[2].sin() * v[0])
    }
    fn parameter_values(&self) -> Vec<f64> {
        vec![self.m, self.inertia, self.g, self.beta]
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        let names = ["m", "inertia", "g", "beta"];
        set_named(&names, &mut [&mut self.m, &mut self.inertia, &mut self.g, &mut self.beta], name, value)
    }
}

/// The mobile robot (§8.3), written generically.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DualRobot {
    /// Mass.
    pub m: f64,
    /// Moment of inertia of the body.
    pub inertia: f64,
    /// Moment of inertia of the wheel.
    pub inertia_wheel: f64,
    /// Wheel radius.
    pub ell: f64,
}

impl Default for DualRobot {
    fn default() -> Self {
        DualRobot { m: 1.0, inertia: 1.0, inertia_wheel: 1.0, ell: 1.0 }
    }
}

impl DualLagrangian<4, 2> for DualRobot {
    const STRUCTURE: Structure = <MobileRobot as NonholonomicSystem<4, 2>>::STRUCTURE;
    const SOURCE: SystemSource = <MobileRobot as NonholonomicSystem<4, 2>>::SOURCE;
    fn lagrangian<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 4>, v: &SVector<D, 4>) -> D {
        (v[0] * v[0] + v[1] * v[1]) * (0.5 * self.m)
            + v[2] * v[2] * (0.5 * self.inertia)
            + v[3] * v[3] * (1.5 * self.inertia_wheel)
            - q[3].sin() * 10.0
    }
    fn constraints<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 4>, v: &SVector<D, 4>) -> SVector<D, 2> {
        SVector::<D, 2>::new(v[0] - q[2].cos() * v[3] * self.ell, v[1] - q[2].sin() * v[3] * self.ell)
    }
    fn parameter_values(&self) -> Vec<f64> {
        vec![self.m, self.inertia, self.inertia_wheel, self.ell]
    }
    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        let names = ["m", "inertia", "inertia_wheel", "ell"];
        set_named(&names, &mut [&mut self.m, &mut self.inertia, &mut self.inertia_wheel, &mut self.ell], name, value)
    }
}

/// McLachlan–Perlmutter's particles, `n = 7` (§8.4), written generically.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DualMp7;

impl DualLagrangian<7, 1> for DualMp7 {
    const STRUCTURE: Structure = <McLachlanPerlmutter7 as NonholonomicSystem<7, 1>>::STRUCTURE;
    const SOURCE: SystemSource = <McLachlanPerlmutter7 as NonholonomicSystem<7, 1>>::SOURCE;
    fn lagrangian<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 7>, v: &SVector<D, 7>) -> D {
        let kinetic = v.iter().fold(D::zero(), |acc, &x| acc + x * x);
        let square = q.iter().fold(D::zero(), |acc, &x| acc + x * x);
        let coupling = q[4] * q[4] * q[5] * q[5]
            + q[1] * q[1] * q[4] * q[4]
            + q[2] * q[2] * q[5] * q[5]
            + q[3] * q[3] * q[6] * q[6];
        (kinetic - square - coupling) * 0.5
    }
    fn constraints<D: DualNum<f64> + Copy>(&self, _t: D, q: &SVector<D, 7>, v: &SVector<D, 7>) -> SVector<D, 1> {
        SVector::<D, 1>::new(v[0] + q[4] * v[4] + q[5] * v[5] + q[6] * v[6])
    }
    fn parameter_values(&self) -> Vec<f64> {
        Vec::new()
    }
    fn set_parameter(&mut self, name: &str, _value: f64) -> Result<(), SystemError> {
        Err(unknown(name, &[]))
    }
}

/// Associates a generated system with its hand-written generic twin.
pub trait DualTwin<const N: usize, const M: usize> {
    /// The generic Lagrangian of the same system.
    type Twin: DualLagrangian<N, M> + Default;
}

impl DualTwin<3, 1> for NonholonomicParticle {
    type Twin = DualParticle;
}
impl DualTwin<3, 1> for Skate {
    type Twin = DualSkate;
}
impl DualTwin<4, 2> for MobileRobot {
    type Twin = DualRobot;
}
impl DualTwin<7, 1> for McLachlanPerlmutter7 {
    type Twin = DualMp7;
}

/// Work generic in a system type that has a num-dual twin.
pub trait TwinVisitor: Sized {
    /// What the work returns.
    type Output;
    /// Does the work for `Sys` (see [`crate::catalog::SystemVisitor`]).
    fn visit<Sys: Dispatch<N, M> + DualTwin<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        entry: &'static SystemEntry,
    ) -> Self::Output;
}

/// Calls `visitor` with the concrete type of `kind` when it has a num-dual
/// twin (the paper's four systems); gives the visitor back otherwise.
pub fn visit_twin<V: TwinVisitor>(kind: SystemKind, visitor: V) -> Result<V::Output, V> {
    let entry = kind.entry();
    Ok(match kind {
        SystemKind::Particle => visitor.visit::<NonholonomicParticle, 3, 1, 6>(entry),
        SystemKind::Skate => visitor.visit::<Skate, 3, 1, 6>(entry),
        SystemKind::Robot => visitor.visit::<MobileRobot, 4, 2, 8>(entry),
        SystemKind::McLachlanPerlmutter7 => visitor.visit::<McLachlanPerlmutter7, 7, 1, 14>(entry),
        _ => return Err(visitor),
    })
}
