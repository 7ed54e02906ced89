//! Hand-written systems with closed-form solutions or exact invariants.

use super::*;
use crate::system::{
    ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemSource,
    TimeDerivatives,
};

type F<const N: usize, T> = fn(f64, &Vector<N>, &Vector<N>) -> T;

/// A system given by its derivatives as plain functions; only the pieces
/// the reference solver reads are meaningful (force Jacobians are zero).
struct Analytic<const N: usize, const M: usize> {
    lagrangian: F<N, f64>,
    momentum: F<N, Vector<N>>,
    force: F<N, Vector<N>>,
    mass: F<N, Matrix<N, N>>,
    momentum_q: F<N, Matrix<N, N>>,
    momentum_t: F<N, Vector<N>>,
    constraint: F<N, Vector<M>>,
    constraint_q: F<N, Matrix<M, N>>,
    constraint_v: F<N, Matrix<M, N>>,
    constraint_t: F<N, Vector<M>>,
}

impl<const N: usize, const M: usize> NonholonomicSystem<N, M> for Analytic<N, M> {
    const STRUCTURE: Structure = Structure {
        lagrangian_autonomous: false,
        constraints_autonomous: false,
        constant_mass_matrix: false,
        separable: false,
        constraint_form: ConstraintForm::Nonlinear,
    };
    const SOURCE: SystemSource = SystemSource {
        name: "Analytic",
        coordinates: &[],
        parameters: &[],
        lagrangian: "0",
        constraints: &[],
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
    };
    const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };

    fn parameter_values(&self) -> Vec<f64> {
        Vec::new()
    }
    fn set_parameter(&mut self, name: &str, _value: f64) -> Result<(), crate::SystemError> {
        Err(crate::SystemError::UnknownParameter { name: name.into(), known: String::new() })
    }
    fn lagrangian(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        (self.lagrangian)(t, q, v)
    }
    fn energy(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        (self.momentum)(t, q, v).dot(v) - (self.lagrangian)(t, q, v)
    }
    fn momentum(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        (self.momentum)(t, q, v)
    }
    fn force(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        (self.force)(t, q, v)
    }
    fn mass_matrix(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N> {
        (self.mass)(t, q, v)
    }
    fn constraint(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<M> {
        (self.constraint)(t, q, v)
    }
    fn constraint_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        (self.constraint_q)(t, q, v)
    }
    fn constraint_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N> {
        (self.constraint_v)(t, q, v)
    }
    fn time_derivatives(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> TimeDerivatives<N, M> {
        TimeDerivatives {
            lagrangian_t: 0.0,
            momentum_t: (self.momentum_t)(t, q, v),
            force_t: Vector::zeros(),
            constraint_t: (self.constraint_t)(t, q, v),
        }
    }
    fn stage_values(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> StageValues<N, M> {
        StageValues {
            momentum: self.momentum(t, q, v),
            force: self.force(t, q, v),
            constraint: self.constraint(t, q, v),
            constraint_force: -self.constraint_v(t, q, v).transpose() * psi,
            ..StageValues::zeros()
        }
    }
    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<M>,
    ) -> (StageValues<N, M>, StageJacobians<N, M>) {
        let jac = StageJacobians {
            momentum_q: (self.momentum_q)(t, q, v),
            mass: self.mass_matrix(t, q, v),
            force_q: Matrix::zeros(),
            force_v: Matrix::zeros(),
            constraint_q: self.constraint_q(t, q, v),
            constraint_v: self.constraint_v(t, q, v),
            constraint_force_q: Matrix::zeros(),
            constraint_force_v: Matrix::zeros(),
        };
        (self.stage_values(t, q, v, psi), jac)
    }
}

/// `L = ½v² − ½q²`, no constraint: `q = cos t`.
fn oscillator() -> Analytic<1, 0> {
    Analytic {
        lagrangian: |_, q, v| 0.5 * v[0] * v[0] - 0.5 * q[0] * q[0],
        momentum: |_, _, v| *v,
        force: |_, q, _| -q,
        mass: |_, _, _| Matrix::identity(),
        momentum_q: |_, _, _| Matrix::zeros(),
        momentum_t: |_, _, _| Vector::zeros(),
        constraint: |_, _, _| Vector::zeros(),
        constraint_q: |_, _, _| Matrix::zeros(),
        constraint_v: |_, _, _| Matrix::zeros(),
        constraint_t: |_, _, _| Vector::zeros(),
    }
}

/// The paper's skate (§8.2) with `m = I = g = 1`, `β = π/2`:
/// `L = ½(v₁² + v₂² + v₃²) + q₁`, `k = cos q₃ v₂ − sin q₃ v₁`.
fn skate() -> Analytic<3, 1> {
    Analytic {
        lagrangian: |_, q, v| 0.5 * v.norm_squared() + q[0],
        momentum: |_, _, v| *v,
        force: |_, _, _| Vector::from([1.0, 0.0, 0.0]),
        mass: |_, _, _| Matrix::identity(),
        momentum_q: |_, _, _| Matrix::zeros(),
        momentum_t: |_, _, _| Vector::zeros(),
        constraint: |_, q, v| Vector::from([q[2].cos() * v[1] - q[2].sin() * v[0]]),
        constraint_q: |_, q, v| Matrix::from_row_slice(&[0.0, 0.0, -q[2].sin() * v[1] - q[2].cos() * v[0]]),
        constraint_v: |_, q, _| Matrix::from_row_slice(&[-q[2].sin(), q[2].cos(), 0.0]),
        constraint_t: |_, _, _| Vector::zeros(),
    }
}

/// Exact skate solution from `q0 = 0`, `v0 = (0, 0, 1)`: the heading turns
/// at unit rate and the speed along it is `sin t`.
fn skate_exact(t: f64) -> (Vector<3>, Vector<3>) {
    let q = Vector::from([(1.0 - (2.0 * t).cos()) / 4.0, t / 2.0 - (2.0 * t).sin() / 4.0, t]);
    let v = Vector::from([t.sin() * t.cos(), t.sin() * t.sin(), 1.0]);
    (q, v)
}

fn mass_of(t: f64) -> f64 {
    1.0 + 0.1 * t
}

/// Polar coordinates `(r, θ)`, `L = ½ m(t)(v_r² + r² v_θ²)` with
/// `m(t) = 1 + t/10`, rheonomic constraint `k = v_r − cos t`: exercises
/// `∂(∇_v L)/∂q`, `∂(∇_v L)/∂t`, `k_t` and a configuration-dependent mass
/// matrix. Exactly `r = r₀ + sin t` and `m(t) r² v_θ` is conserved.
fn polar() -> Analytic<2, 1> {
    Analytic {
        lagrangian: |t, q, v| 0.5 * mass_of(t) * (v[0] * v[0] + q[0] * q[0] * v[1] * v[1]),
        momentum: |t, q, v| mass_of(t) * Vector::from([v[0], q[0] * q[0] * v[1]]),
        force: |t, q, v| Vector::from([mass_of(t) * q[0] * v[1] * v[1], 0.0]),
        mass: |t, q, _| mass_of(t) * Matrix::from_row_slice(&[1.0, 0.0, 0.0, q[0] * q[0]]),
        momentum_q: |t, q, v| mass_of(t) * Matrix::from_row_slice(&[0.0, 0.0, 2.0 * q[0] * v[1], 0.0]),
        momentum_t: |_, q, v| 0.1 * Vector::from([v[0], q[0] * q[0] * v[1]]),
        constraint: |t, _, v| Vector::from([v[0] - t.cos()]),
        constraint_q: |_, _, _| Matrix::zeros(),
        constraint_v: |_, _, _| Matrix::from_row_slice(&[1.0, 0.0]),
        constraint_t: |t, _, _| Vector::from([t.sin()]),
    }
}

#[test]
fn oscillator_matches_cosine() {
    let times: Vec<f64> = (0..=40).map(|i| 0.5 * i as f64).collect();
    let sol = integrate_at(
        &oscillator(),
        0.0,
        &Vector::from([1.0]),
        &Vector::from([0.0]),
        &times,
        &ReferenceOptions::default(),
    )
    .unwrap();
    for (i, &t) in times.iter().enumerate() {
        assert!((sol.q[i][0] - t.cos()).abs() < 5e-14, "t={t}: {}", sol.q[i][0] - t.cos());
        assert!((sol.v[i][0] + t.sin()).abs() < 5e-14, "t={t}: {}", sol.v[i][0] + t.sin());
    }
    assert!(sol.stats.accepted_steps > 0 && sol.stats.rhs_evaluations > sol.stats.accepted_steps);
}

#[test]
fn skate_matches_exact_solution_and_keeps_constraint() {
    let sys = skate();
    let times: Vec<f64> = (0..=50).map(|i| 0.2 * i as f64).collect();
    let (q0, v0) = skate_exact(0.0);
    let sol = integrate_at(&sys, 0.0, &q0, &v0, &times, &ReferenceOptions::default()).unwrap();
    let mut worst_state: f64 = 0.0;
    let mut worst_constraint: f64 = 0.0;
    for (i, &t) in times.iter().enumerate() {
        let (q, v) = skate_exact(t);
        worst_state = worst_state.max((sol.q[i] - q).amax()).max((sol.v[i] - v).amax());
        worst_constraint = worst_constraint.max(sys.constraint(t, &sol.q[i], &sol.v[i]).amax());
    }
    assert!(worst_state < 1e-13, "state error {worst_state:e}");
    assert!(worst_constraint < 1e-14, "constraint residual {worst_constraint:e}");
}

#[test]
fn rheonomic_time_dependent_system_keeps_its_invariants() {
    let sys = polar();
    let (r0, w0) = (2.0, 0.3);
    let q0 = Vector::from([r0, 0.0]);
    let v0 = Vector::from([1.0, w0]);
    let times: Vec<f64> = (0..=30).map(|i| 0.25 * i as f64).collect();
    let sol = integrate_at(&sys, 0.0, &q0, &v0, &times, &ReferenceOptions::default()).unwrap();
    let l0 = mass_of(0.0) * r0 * r0 * w0;
    for (i, &t) in times.iter().enumerate() {
        let (q, v) = (sol.q[i], sol.v[i]);
        assert!((q[0] - (r0 + t.sin())).abs() < 1e-14, "r at t={t}: {}", q[0] - (r0 + t.sin()));
        let l = mass_of(t) * q[0] * q[0] * v[1];
        assert!((l - l0).abs() < 1e-14, "angular momentum at t={t}: {}", l - l0);
        assert!(sys.constraint(t, &q, &v)[0].abs() < 1e-14);
    }
}

#[test]
fn multiplier_is_the_constraint_force() {
    // For the skate the multiplier balances the lateral component of
    // gravity and the centripetal force: ψ = −(ẋ θ̇ cos… ) checked through
    // the momentum balance M v̇ = F − Kᵀψ instead of a formula.
    let sys = skate();
    let (q, v) = skate_exact(0.7);
    let (vdot, psi) = acceleration::<_, 3, 1>(&sys, 0.7, &q, &v).unwrap();
    let residual =
        sys.mass_matrix(0.7, &q, &v) * vdot - sys.force(0.7, &q, &v) + sys.constraint_v(0.7, &q, &v).transpose() * psi;
    assert!(residual.amax() < 1e-15);
    let t: f64 = 0.7;
    let exact_vdot = Vector::from([(2.0 * t).cos(), (2.0 * t).sin(), 0.0]);
    assert!((vdot - exact_vdot).amax() < 1e-15);
}

#[test]
fn forward_then_backward_returns_to_start() {
    let sys = skate();
    let (q0, v0) = skate_exact(0.0);
    let opts = ReferenceOptions::default();
    let fwd = integrate(&sys, 0.0, &q0, &v0, 7.0, &opts).unwrap();
    let back = integrate(&sys, 7.0, &fwd.q[0], &fwd.v[0], 0.0, &opts).unwrap();
    let (qe, ve) = skate_exact(7.0);
    assert!((fwd.q[0] - qe).amax() < 1e-13 && (fwd.v[0] - ve).amax() < 1e-13, "{fwd:?}");
    assert!((back.q[0] - q0).amax() < 2e-13 && (back.v[0] - v0).amax() < 2e-13, "{back:?}");
}

#[test]
fn looser_tolerance_gives_proportionate_error() {
    let opts = ReferenceOptions { rtol: 1e-8, atol: 1e-8, ..ReferenceOptions::default() };
    let sys = oscillator();
    let sol = integrate(&sys, 0.0, &Vector::from([1.0]), &Vector::from([0.0]), 10.0, &opts).unwrap();
    let err = (sol.q[0][0] - 10f64.cos()).abs();
    assert!(err < 1e-6, "error {err:e}");
    let tight = integrate(&sys, 0.0, &Vector::from([1.0]), &Vector::from([0.0]), 10.0, &Default::default());
    assert!(tight.unwrap().stats.rhs_evaluations > sol.stats.rhs_evaluations);
}

#[test]
fn rejects_bad_input() {
    let sys = oscillator();
    let (q, v) = (Vector::from([1.0]), Vector::from([0.0]));
    let bad = ReferenceOptions { rtol: 0.0, atol: 0.0, ..Default::default() };
    assert!(matches!(integrate(&sys, 0.0, &q, &v, 1.0, &bad), Err(ReferenceError::InvalidOptions(_))));
    let bad = ReferenceOptions { max_rows: 2, ..Default::default() };
    assert!(matches!(integrate(&sys, 0.0, &q, &v, 1.0, &bad), Err(ReferenceError::InvalidOptions(_))));
    let r = integrate_at(&sys, 0.0, &q, &v, &[1.0, 0.5], &Default::default());
    assert!(matches!(r, Err(ReferenceError::InvalidTimes { .. })));
    let r = integrate_at(&sys, 0.0, &q, &v, &[f64::NAN], &Default::default());
    assert!(matches!(r, Err(ReferenceError::InvalidTimes { .. })));
    let few = ReferenceOptions { max_steps: 3, ..Default::default() };
    assert!(matches!(integrate(&sys, 0.0, &q, &v, 100.0, &few), Err(ReferenceError::TooManySteps { .. })));
}

#[test]
fn rejects_non_finite_initial_values_and_never_returns_a_non_finite_state() {
    let sys = skate();
    let opts = ReferenceOptions::default();
    let (q, v) = skate_exact(0.0);
    let nan_q = Vector::from([f64::NAN, 0.0, 0.0]);
    let r = integrate(&sys, 0.0, &nan_q, &v, 1.0, &opts);
    assert!(matches!(r, Err(ReferenceError::NonFiniteInitialState { which: "q0", index: 0, .. })), "{r:?}");
    let r = integrate_at(&sys, 0.0, &nan_q, &v, &[0.0], &opts);
    assert!(matches!(r, Err(ReferenceError::NonFiniteInitialState { which: "q0", index: 0, .. })), "{r:?}");
    let inf_v = Vector::from([0.0, f64::INFINITY, 1.0]);
    let r = integrate(&sys, 0.0, &q, &inf_v, 1.0, &opts);
    assert!(matches!(r, Err(ReferenceError::NonFiniteInitialState { which: "v0", index: 1, .. })), "{r:?}");
    assert!(matches!(integrate(&sys, f64::NAN, &q, &v, 1.0, &opts), Err(ReferenceError::InvalidTimes { .. })));
    assert!(matches!(integrate(&sys, 0.0, &q, &v, f64::INFINITY, &opts), Err(ReferenceError::InvalidTimes { .. })));
    // A finite start with finite accelerations whose solution overflows:
    // the free particle from q = v = 1e308 reaches q = 2e308 = ∞ at t = 1.
    let free = Analytic::<1, 0> { force: |_, _, _| Vector::zeros(), ..oscillator() };
    let r = integrate(&free, 0.0, &Vector::from([1e308]), &Vector::from([1e308]), 1.0, &opts);
    assert!(matches!(r, Err(ReferenceError::NonFiniteState { .. })), "{r:?}");
}

#[test]
fn singular_saddle_is_reported() {
    let mut sys = skate();
    sys.constraint_v = |_, _, _| Matrix::zeros();
    let (q0, v0) = skate_exact(0.0);
    let r = integrate(&sys, 0.0, &q0, &v0, 1.0, &Default::default());
    assert!(matches!(r, Err(ReferenceError::SingularSaddle { .. })), "{r:?}");
}
