//! A hand-written [`NonholonomicSystem`] that exercises every branch of the
//! trait the paper's systems leave at zero: explicit time dependence of `L`
//! and `k`, a non-separable `L` (gyroscopic term), a time-varying mass matrix
//! and a constraint nonlinear in `v` with an affine part.
//!
//! Its derivatives were worked out by hand; the CasADi cross-check verifies
//! them together with its neutral source, so the checker is itself checked
//! against an implementation that owes nothing to the macro.
//!
//! ```text
//! L = ½ m (1 + a t)(ẋ² + ẏ²) + m g sin(x) y + x ẏ
//! k = ẋ² + x ẏ − sin(t) y
//! ```

use spark_runtime::{
    ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemError,
    SystemSource, TimeDerivatives, Vector,
};

/// The hand-written rheonomic test system (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rheonomic {
    /// Mass `m`.
    pub m: f64,
    /// Gravity `g`.
    pub g: f64,
    /// Mass growth rate `a`.
    pub a: f64,
}

impl Default for Rheonomic {
    fn default() -> Self {
        Self { m: 1.5, g: 9.81, a: 0.25 }
    }
}

impl Rheonomic {
    /// Number of coordinates (for `Stepper!`).
    pub const N: usize = 2;
    /// Number of constraints.
    pub const M: usize = 1;

    fn scale(&self, t: f64) -> f64 {
        self.m * (1.0 + self.a * t)
    }
}

impl NonholonomicSystem<2, 1> for Rheonomic {
    const STRUCTURE: Structure = Structure {
        lagrangian_autonomous: false,
        constraints_autonomous: false,
        constant_mass_matrix: false,
        separable: false,
        constraint_form: ConstraintForm::Nonlinear,
    };
    const SOURCE: SystemSource = SystemSource {
        name: "Rheonomic",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y"],
        parameters: &["m", "g", "a"],
        lagrangian: "(+ (* 0.5 (p m) (+ 1 (* (p a) t)) (+ (^ (v x) 2) (^ (v y) 2))) \
                     (* (p m) (p g) (sin (q x)) (q y)) (* (q x) (v y)))",
        constraints: &["(- (+ (^ (v x) 2) (* (q x) (v y))) (* (sin t) (q y)))"],
    };
    const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };

    fn parameter_values(&self) -> Vec<f64> {
        vec![self.m, self.g, self.a]
    }

    fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
        if !value.is_finite() {
            return Err(SystemError::NonFiniteParameter { name: name.to_owned(), value });
        }
        match name {
            "m" => self.m = value,
            "g" => self.g = value,
            "a" => self.a = value,
            _ => return Err(SystemError::UnknownParameter { name: name.to_owned(), known: "m, g, a".to_owned() }),
        }
        Ok(())
    }

    fn lagrangian(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> f64 {
        0.5 * self.scale(t) * (v[0] * v[0] + v[1] * v[1]) + self.m * self.g * q[0].sin() * q[1] + q[0] * v[1]
    }

    fn energy(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> f64 {
        0.5 * self.scale(t) * (v[0] * v[0] + v[1] * v[1]) - self.m * self.g * q[0].sin() * q[1]
    }

    fn momentum(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<2> {
        let s = self.scale(t);
        Vector::<2>::new(s * v[0], s * v[1] + q[0])
    }

    fn force(&self, _t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<2> {
        let mg = self.m * self.g;
        Vector::<2>::new(mg * q[0].cos() * q[1] + v[1], mg * q[0].sin())
    }

    fn mass_matrix(&self, t: f64, _q: &Vector<2>, _v: &Vector<2>) -> Matrix<2, 2> {
        Matrix::<2, 2>::identity() * self.scale(t)
    }

    fn constraint(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<1> {
        Vector::<1>::new(v[0] * v[0] + q[0] * v[1] - t.sin() * q[1])
    }

    fn constraint_q(&self, t: f64, _q: &Vector<2>, v: &Vector<2>) -> Matrix<1, 2> {
        Matrix::<1, 2>::new(v[1], -t.sin())
    }

    fn constraint_v(&self, _t: f64, q: &Vector<2>, v: &Vector<2>) -> Matrix<1, 2> {
        Matrix::<1, 2>::new(2.0 * v[0], q[0])
    }

    fn time_derivatives(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> TimeDerivatives<2, 1> {
        let ma = self.m * self.a;
        TimeDerivatives {
            lagrangian_t: 0.5 * ma * (v[0] * v[0] + v[1] * v[1]),
            momentum_t: Vector::<2>::new(ma * v[0], ma * v[1]),
            force_t: Vector::<2>::zeros(),
            constraint_t: Vector::<1>::new(-t.cos() * q[1]),
        }
    }

    fn stage_values(&self, t: f64, q: &Vector<2>, v: &Vector<2>, psi: &Vector<1>) -> StageValues<2, 1> {
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
        q: &Vector<2>,
        v: &Vector<2>,
        psi: &Vector<1>,
    ) -> (StageValues<2, 1>, StageJacobians<2, 1>) {
        let mg = self.m * self.g;
        let (sx, cx) = q[0].sin_cos();
        let p = psi[0];
        let jac = StageJacobians {
            momentum_q: Matrix::<2, 2>::new(0.0, 0.0, 1.0, 0.0),
            mass: self.mass_matrix(t, q, v),
            force_q: Matrix::<2, 2>::new(-mg * sx * q[1], mg * cx, mg * cx, 0.0),
            force_v: Matrix::<2, 2>::new(0.0, 1.0, 0.0, 0.0),
            constraint_q: self.constraint_q(t, q, v),
            constraint_v: self.constraint_v(t, q, v),
            constraint_force_q: Matrix::<2, 2>::new(0.0, 0.0, -p, 0.0),
            constraint_force_v: Matrix::<2, 2>::new(-2.0 * p, 0.0, 0.0, 0.0),
        };
        (self.stage_values(t, q, v, psi), jac)
    }
}
