//! The same SPARK stepper with stage Jacobians from central differences of
//! the (generated) stage values: what a user without derivative code would
//! do. Every other function is the wrapped system's own.

use spark_runtime::{
    Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemError, SystemSource,
    TimeDerivatives, Vector,
};

/// Wraps a system, replacing [`NonholonomicSystem::stage_jacobians`] by
/// central differences of [`NonholonomicSystem::stage_values`] (`4N` extra
/// evaluations; relative step `ε^{1/3}`, so Jacobian entries carry errors of
/// about `1e-10` relative and Newton converges linearly near the solution).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FiniteDifference<Sys>(pub Sys);

/// `ε^{1/3}`: balances truncation `O(δ²)` and rounding `O(ε/δ)`.
const RELATIVE_STEP: f64 = 6.055_454_452_393_343e-6;

fn column<const N: usize, const C: usize>(
    m: &mut Matrix<N, C>,
    j: usize,
    plus: &Vector<N>,
    minus: &Vector<N>,
    delta: f64,
) {
    for i in 0..N {
        m[(i, j)] = (plus[i] - minus[i]) / (2.0 * delta);
    }
}

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize> NonholonomicSystem<N, M> for FiniteDifference<Sys> {
    const STRUCTURE: Structure = Sys::STRUCTURE;
    const SOURCE: SystemSource = Sys::SOURCE;
    const OPERATIONS: OperationCounts = Sys::OPERATIONS;

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
        self.0.energy(t, q, v)
    }
    fn momentum(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        self.0.momentum(t, q, v)
    }
    fn force(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        self.0.force(t, q, v)
    }
    fn mass_matrix(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N> {
        self.0.mass_matrix(t, q, v)
    }
    fn constraint(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<M> {
        self.0.constraint(t, q, v)
    }
    fn constraint_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        self.0.constraint_q(t, q, v)
    }
    fn constraint_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        self.0.constraint_v(t, q, v)
    }
    fn time_derivatives(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> TimeDerivatives<N, M> {
        self.0.time_derivatives(t, q, v)
    }
    fn stage_values(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> StageValues<N, M> {
        self.0.stage_values(t, q, v, psi)
    }
    fn stage_values_into(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>, values: &mut StageValues<N, M>) {
        self.0.stage_values_into(t, q, v, psi, values)
    }

    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
    ) -> (StageValues<N, M>, StageJacobians<N, M>) {
        let values = self.0.stage_values(t, q, v, psi);
        let mut jac = StageJacobians::zeros();
        for j in 0..N {
            let delta = RELATIVE_STEP * q[j].abs().max(1.0);
            let (mut qp, mut qm) = (*q, *q);
            qp[j] += delta;
            qm[j] -= delta;
            // The exact spacing actually represented in floating point.
            let delta = 0.5 * (qp[j] - qm[j]);
            let (p, m) = (self.0.stage_values(t, &qp, v, psi), self.0.stage_values(t, &qm, v, psi));
            column(&mut jac.momentum_q, j, &p.momentum, &m.momentum, delta);
            column(&mut jac.force_q, j, &p.force, &m.force, delta);
            column(&mut jac.constraint_q, j, &p.constraint, &m.constraint, delta);
            column(&mut jac.constraint_force_q, j, &p.constraint_force, &m.constraint_force, delta);

            let delta = RELATIVE_STEP * v[j].abs().max(1.0);
            let (mut vp, mut vm) = (*v, *v);
            vp[j] += delta;
            vm[j] -= delta;
            let delta = 0.5 * (vp[j] - vm[j]);
            let (p, m) = (self.0.stage_values(t, q, &vp, psi), self.0.stage_values(t, q, &vm, psi));
            column(&mut jac.mass, j, &p.momentum, &m.momentum, delta);
            column(&mut jac.force_v, j, &p.force, &m.force, delta);
            column(&mut jac.constraint_v, j, &p.constraint, &m.constraint, delta);
            column(&mut jac.constraint_force_v, j, &p.constraint_force, &m.constraint_force, delta);
        }
        (values, jac)
    }
}
