//! Hand-written implementations of the paper's systems (§8.1–8.4) and of one
//! deliberately general system (time-dependent, non-separable Lagrangian with
//! a configuration-dependent mass matrix and a constraint nonlinear in `v`).
//!
//! They are independent checks of the code `nonholonomic_system!`
//! generates, and test systems for the runtime. Every derivative is written
//! out by hand; [`Derivatives`] collects the primitive pieces and a macro
//! derives the trait's fused functions from them.

use crate::system::{
    ConstraintForm, Matrix, NonholonomicSystem, OperationCounts, StageJacobians, StageValues, Structure, SystemSource,
    TimeDerivatives, Vector,
};
use crate::SystemError;

/// The primitive derivatives of a hand-written system, from which the
/// [`NonholonomicSystem`] implementation is assembled.
pub trait Derivatives<const N: usize, const M: usize> {
    /// `L`.
    fn l(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64;
    /// `∇_v L`.
    fn p(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N>;
    /// `∇_q L`.
    fn f(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<N>;
    /// `∇²_vv L`.
    fn mass(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N>;
    /// `∂(∇_v L)/∂q`.
    fn p_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N>;
    /// `∂(∇_q L)/∂q`.
    fn f_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N>;
    /// `∂(∇_q L)/∂v`.
    fn f_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<N, N>;
    /// `k`.
    fn k(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<M>;
    /// `k_q`.
    fn k_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N>;
    /// `k_v`.
    fn k_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> Matrix<M, N>;
    /// `∂(−k_vᵀψ)/∂q`.
    fn r_q(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> Matrix<N, N>;
    /// `∂(−k_vᵀψ)/∂v`.
    fn r_v(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>) -> Matrix<N, N>;
    /// Explicit time derivatives.
    fn td(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> TimeDerivatives<N, M>;
}

fn autonomous_td<const N: usize, const M: usize>() -> TimeDerivatives<N, M> {
    TimeDerivatives {
        lagrangian_t: 0.0,
        momentum_t: Vector::zeros(),
        force_t: Vector::zeros(),
        constraint_t: Vector::zeros(),
    }
}

macro_rules! impl_system {
    ($ty:ident, $n:literal, $m:literal, $structure:expr, $source:expr) => {
        impl $ty {
            /// Number of coordinates.
            pub const N: usize = $n;
            /// Number of constraints.
            pub const M: usize = $m;
        }
        impl NonholonomicSystem<$n, $m> for $ty {
            const STRUCTURE: Structure = $structure;
            const SOURCE: SystemSource = $source;
            const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };
            fn parameter_values(&self) -> Vec<f64> {
                self.params().to_vec()
            }
            fn set_parameter(&mut self, name: &str, value: f64) -> Result<(), SystemError> {
                if !value.is_finite() {
                    return Err(SystemError::NonFiniteParameter { name: name.to_string(), value });
                }
                match Self::SOURCE.parameters.iter().position(|p| *p == name) {
                    Some(i) => {
                        self.set_param(i, value);
                        Ok(())
                    }
                    None => Err(SystemError::UnknownParameter {
                        name: name.to_string(),
                        known: Self::SOURCE.parameters.join(", "),
                    }),
                }
            }
            fn lagrangian(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> f64 {
                self.l(t, q, v)
            }
            fn energy(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> f64 {
                self.p(t, q, v).dot(v) - self.l(t, q, v)
            }
            fn momentum(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Vector<$n> {
                self.p(t, q, v)
            }
            fn force(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Vector<$n> {
                self.f(t, q, v)
            }
            fn mass_matrix(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Matrix<$n, $n> {
                self.mass(t, q, v)
            }
            fn constraint(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Vector<$m> {
                self.k(t, q, v)
            }
            fn constraint_q(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Matrix<$m, $n> {
                self.k_q(t, q, v)
            }
            fn constraint_v(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> Matrix<$m, $n> {
                self.k_v(t, q, v)
            }
            fn time_derivatives(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>) -> TimeDerivatives<$n, $m> {
                self.td(t, q, v)
            }
            fn stage_values(&self, t: f64, q: &Vector<$n>, v: &Vector<$n>, psi: &Vector<$m>) -> StageValues<$n, $m> {
                StageValues {
                    momentum: self.p(t, q, v),
                    force: self.f(t, q, v),
                    constraint: self.k(t, q, v),
                    constraint_force: -(self.k_v(t, q, v).transpose() * psi),
                }
            }
            fn stage_jacobians(
                &self,
                t: f64,
                q: &Vector<$n>,
                v: &Vector<$n>,
                psi: &Vector<$m>,
            ) -> (StageValues<$n, $m>, StageJacobians<$n, $m>) {
                let jac = StageJacobians {
                    momentum_q: self.p_q(t, q, v),
                    mass: self.mass(t, q, v),
                    force_q: self.f_q(t, q, v),
                    force_v: self.f_v(t, q, v),
                    constraint_q: self.k_q(t, q, v),
                    constraint_v: self.k_v(t, q, v),
                    constraint_force_q: self.r_q(t, q, v, psi),
                    constraint_force_v: self.r_v(t, q, v, psi),
                };
                (self.stage_values(t, q, v, psi), jac)
            }
        }
    };
}

const CONSERVATIVE_LINEAR: Structure = Structure {
    lagrangian_autonomous: true,
    constraints_autonomous: true,
    constant_mass_matrix: true,
    separable: true,
    constraint_form: ConstraintForm::Linear,
};

/// The nonholonomic particle (§8.1): `L = ½|v|² − q₁² − q₂²`, `v₃ − q₂v₁ = 0`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Particle;

impl Particle {
    fn params(&self) -> [f64; 0] {
        []
    }
    fn set_param(&mut self, _: usize, _: f64) {}
}

impl Derivatives<3, 1> for Particle {
    fn l(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> f64 {
        0.5 * v.norm_squared() - q[0] * q[0] - q[1] * q[1]
    }
    fn p(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Vector<3> {
        *v
    }
    fn f(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Vector<3> {
        Vector::<3>::new(-2.0 * q[0], -2.0 * q[1], 0.0)
    }
    fn mass(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::identity()
    }
    fn p_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn f_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::from_diagonal(&Vector::<3>::new(-2.0, -2.0, 0.0))
    }
    fn f_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn k(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<1> {
        Vector::<1>::new(v[2] - q[1] * v[0])
    }
    fn k_q(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(0.0, -v[0], 0.0)
    }
    fn k_v(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(-q[1], 0.0, 1.0)
    }
    fn r_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>, psi: &Vector<1>) -> Matrix<3, 3> {
        // R = (q₂ψ, 0, −ψ).
        let mut m = Matrix::zeros();
        m[(0, 1)] = psi[0];
        m
    }
    fn r_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>, _: &Vector<1>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn td(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> TimeDerivatives<3, 1> {
        autonomous_td()
    }
}

impl_system!(
    Particle,
    3,
    1,
    CONSERVATIVE_LINEAR,
    SystemSource {
        name: "Particle",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y", "z"],
        parameters: &[],
        lagrangian: "(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2) (^ (v z) 2))) (+ (^ (q x) 2) (^ (q y) 2)))",
        constraints: &["(- (v z) (* (q y) (v x)))"],
    }
);

/// The skate on an inclined plane (§8.2): `L = ½m(v₁²+v₂²) + ½Iv₃² + mgq₁ sin β`,
/// `cos(q₃)v₂ − sin(q₃)v₁ = 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Skate {
    /// Mass.
    pub m: f64,
    /// Moment of inertia.
    pub inertia: f64,
    /// Gravity.
    pub g: f64,
    /// Inclination.
    pub beta: f64,
}

impl Default for Skate {
    fn default() -> Self {
        Skate { m: 1.0, inertia: 1.0, g: 1.0, beta: std::f64::consts::FRAC_PI_2 }
    }
}

impl Skate {
    fn params(&self) -> [f64; 4] {
        [self.m, self.inertia, self.g, self.beta]
    }
    fn set_param(&mut self, i: usize, x: f64) {
        match i {
            0 => self.m = x,
            1 => self.inertia = x,
            2 => self.g = x,
            _ => self.beta = x,
        }
    }
}

impl Derivatives<3, 1> for Skate {
    fn l(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> f64 {
        0.5 * self.m * (v[0] * v[0] + v[1] * v[1])
            + 0.5 * self.inertia * v[2] * v[2]
            + self.m * self.g * q[0] * self.beta.sin()
    }
    fn p(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Vector<3> {
        Vector::<3>::new(self.m * v[0], self.m * v[1], self.inertia * v[2])
    }
    fn f(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Vector<3> {
        Vector::<3>::new(self.m * self.g * self.beta.sin(), 0.0, 0.0)
    }
    fn mass(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::from_diagonal(&Vector::<3>::new(self.m, self.m, self.inertia))
    }
    fn p_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn f_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn f_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn k(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<1> {
        Vector::<1>::new(q[2].cos() * v[1] - q[2].sin() * v[0])
    }
    fn k_q(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(0.0, 0.0, -q[2].sin() * v[1] - q[2].cos() * v[0])
    }
    fn k_v(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(-q[2].sin(), q[2].cos(), 0.0)
    }
    fn r_q(&self, _: f64, q: &Vector<3>, _: &Vector<3>, psi: &Vector<1>) -> Matrix<3, 3> {
        // R = (sin(q₃)ψ, −cos(q₃)ψ, 0).
        let mut m = Matrix::zeros();
        m[(0, 2)] = q[2].cos() * psi[0];
        m[(1, 2)] = q[2].sin() * psi[0];
        m
    }
    fn r_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>, _: &Vector<1>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn td(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> TimeDerivatives<3, 1> {
        autonomous_td()
    }
}

impl_system!(
    Skate,
    3,
    1,
    CONSERVATIVE_LINEAR,
    SystemSource {
        name: "Skate",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y", "theta"],
        parameters: &["m", "inertia", "g", "beta"],
        lagrangian: "(+ (* (/ (p m) 2) (+ (^ (v x) 2) (^ (v y) 2))) (* (/ (p inertia) 2) (^ (v theta) 2)) \
                     (* (p m) (p g) (q x) (sin (p beta))))",
        constraints: &["(- (* (cos (q theta)) (v y)) (* (sin (q theta)) (v x)))"],
    }
);

/// The mobile robot with fixed orientation and a potential (§8.3):
/// `L = ½m(v₁²+v₂²) + ½Iv₃² + (3/2)I_ω v₄² − 10 sin q₄`,
/// `v₁ − ℓ cos(q₃)v₄ = 0`, `v₂ − ℓ sin(q₃)v₄ = 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MobileRobot {
    /// Mass.
    pub m: f64,
    /// Moment of inertia of the body.
    pub inertia: f64,
    /// Moment of inertia of the wheels.
    pub inertia_w: f64,
    /// Wheel radius.
    pub l: f64,
}

impl Default for MobileRobot {
    fn default() -> Self {
        MobileRobot { m: 1.0, inertia: 1.0, inertia_w: 1.0, l: 1.0 }
    }
}

impl MobileRobot {
    fn params(&self) -> [f64; 4] {
        [self.m, self.inertia, self.inertia_w, self.l]
    }
    fn set_param(&mut self, i: usize, x: f64) {
        match i {
            0 => self.m = x,
            1 => self.inertia = x,
            2 => self.inertia_w = x,
            _ => self.l = x,
        }
    }
}

impl Derivatives<4, 2> for MobileRobot {
    fn l(&self, _: f64, q: &Vector<4>, v: &Vector<4>) -> f64 {
        0.5 * self.m * (v[0] * v[0] + v[1] * v[1])
            + 0.5 * self.inertia * v[2] * v[2]
            + 1.5 * self.inertia_w * v[3] * v[3]
            - 10.0 * q[3].sin()
    }
    fn p(&self, _: f64, _: &Vector<4>, v: &Vector<4>) -> Vector<4> {
        Vector::<4>::new(self.m * v[0], self.m * v[1], self.inertia * v[2], 3.0 * self.inertia_w * v[3])
    }
    fn f(&self, _: f64, q: &Vector<4>, _: &Vector<4>) -> Vector<4> {
        Vector::<4>::new(0.0, 0.0, 0.0, -10.0 * q[3].cos())
    }
    fn mass(&self, _: f64, _: &Vector<4>, _: &Vector<4>) -> Matrix<4, 4> {
        Matrix::from_diagonal(&Vector::<4>::new(self.m, self.m, self.inertia, 3.0 * self.inertia_w))
    }
    fn p_q(&self, _: f64, _: &Vector<4>, _: &Vector<4>) -> Matrix<4, 4> {
        Matrix::zeros()
    }
    fn f_q(&self, _: f64, q: &Vector<4>, _: &Vector<4>) -> Matrix<4, 4> {
        let mut m = Matrix::zeros();
        m[(3, 3)] = 10.0 * q[3].sin();
        m
    }
    fn f_v(&self, _: f64, _: &Vector<4>, _: &Vector<4>) -> Matrix<4, 4> {
        Matrix::zeros()
    }
    fn k(&self, _: f64, q: &Vector<4>, v: &Vector<4>) -> Vector<2> {
        Vector::<2>::new(v[0] - self.l * q[2].cos() * v[3], v[1] - self.l * q[2].sin() * v[3])
    }
    fn k_q(&self, _: f64, q: &Vector<4>, v: &Vector<4>) -> Matrix<2, 4> {
        Matrix::<2, 4>::new(0.0, 0.0, self.l * q[2].sin() * v[3], 0.0, 0.0, 0.0, -self.l * q[2].cos() * v[3], 0.0)
    }
    fn k_v(&self, _: f64, q: &Vector<4>, _: &Vector<4>) -> Matrix<2, 4> {
        Matrix::<2, 4>::new(1.0, 0.0, 0.0, -self.l * q[2].cos(), 0.0, 1.0, 0.0, -self.l * q[2].sin())
    }
    fn r_q(&self, _: f64, q: &Vector<4>, _: &Vector<4>, psi: &Vector<2>) -> Matrix<4, 4> {
        // R = (−ψ₁, −ψ₂, 0, ℓ cos(q₃)ψ₁ + ℓ sin(q₃)ψ₂).
        let mut m = Matrix::zeros();
        m[(3, 2)] = -self.l * q[2].sin() * psi[0] + self.l * q[2].cos() * psi[1];
        m
    }
    fn r_v(&self, _: f64, _: &Vector<4>, _: &Vector<4>, _: &Vector<2>) -> Matrix<4, 4> {
        Matrix::zeros()
    }
    fn td(&self, _: f64, _: &Vector<4>, _: &Vector<4>) -> TimeDerivatives<4, 2> {
        autonomous_td()
    }
}

impl_system!(
    MobileRobot,
    4,
    2,
    CONSERVATIVE_LINEAR,
    SystemSource {
        name: "MobileRobot",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y", "theta", "phi"],
        parameters: &["m", "inertia", "inertia_w", "l"],
        lagrangian: "(- (+ (* (/ (p m) 2) (+ (^ (v x) 2) (^ (v y) 2))) (* (/ (p inertia) 2) (^ (v theta) 2)) \
                     (* 1.5 (p inertia_w) (^ (v phi) 2))) (* 10 (sin (q phi))))",
        constraints: &["(- (v x) (* (p l) (cos (q theta)) (v phi)))", "(- (v y) (* (p l) (sin (q theta)) (v phi)))",],
    }
);

/// McLachlan and Perlmutter's particles (§8.4) with `m = 3`, `n = 7`:
/// `L = ½|v|² − ½(|q|² + q₅²q₆² + q₂²q₅² + q₃²q₆² + q₄²q₇²)`,
/// `v₁ + q₅v₅ + q₆v₆ + q₇v₇ = 0`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MpParticles;

/// The quartic couplings `q_a² q_b²` of [`MpParticles`] (0-based).
const MP_PAIRS: [(usize, usize); 4] = [(4, 5), (1, 4), (2, 5), (3, 6)];

impl MpParticles {
    fn params(&self) -> [f64; 0] {
        []
    }
    fn set_param(&mut self, _: usize, _: f64) {}
}

impl Derivatives<7, 1> for MpParticles {
    fn l(&self, _: f64, q: &Vector<7>, v: &Vector<7>) -> f64 {
        let quartic: f64 = MP_PAIRS.iter().map(|&(a, b)| q[a] * q[a] * q[b] * q[b]).sum();
        0.5 * v.norm_squared() - 0.5 * (q.norm_squared() + quartic)
    }
    fn p(&self, _: f64, _: &Vector<7>, v: &Vector<7>) -> Vector<7> {
        *v
    }
    fn f(&self, _: f64, q: &Vector<7>, _: &Vector<7>) -> Vector<7> {
        let mut f = -q;
        for &(a, b) in &MP_PAIRS {
            f[a] -= q[a] * q[b] * q[b];
            f[b] -= q[a] * q[a] * q[b];
        }
        f
    }
    fn mass(&self, _: f64, _: &Vector<7>, _: &Vector<7>) -> Matrix<7, 7> {
        Matrix::identity()
    }
    fn p_q(&self, _: f64, _: &Vector<7>, _: &Vector<7>) -> Matrix<7, 7> {
        Matrix::zeros()
    }
    fn f_q(&self, _: f64, q: &Vector<7>, _: &Vector<7>) -> Matrix<7, 7> {
        let mut m = -Matrix::<7, 7>::identity();
        for &(a, b) in &MP_PAIRS {
            m[(a, a)] -= q[b] * q[b];
            m[(b, b)] -= q[a] * q[a];
            m[(a, b)] -= 2.0 * q[a] * q[b];
            m[(b, a)] -= 2.0 * q[a] * q[b];
        }
        m
    }
    fn f_v(&self, _: f64, _: &Vector<7>, _: &Vector<7>) -> Matrix<7, 7> {
        Matrix::zeros()
    }
    fn k(&self, _: f64, q: &Vector<7>, v: &Vector<7>) -> Vector<1> {
        Vector::<1>::new(v[0] + q[4] * v[4] + q[5] * v[5] + q[6] * v[6])
    }
    fn k_q(&self, _: f64, _: &Vector<7>, v: &Vector<7>) -> Matrix<1, 7> {
        Matrix::<1, 7>::from_row_slice(&[0.0, 0.0, 0.0, 0.0, v[4], v[5], v[6]])
    }
    fn k_v(&self, _: f64, q: &Vector<7>, _: &Vector<7>) -> Matrix<1, 7> {
        Matrix::<1, 7>::from_row_slice(&[1.0, 0.0, 0.0, 0.0, q[4], q[5], q[6]])
    }
    fn r_q(&self, _: f64, _: &Vector<7>, _: &Vector<7>, psi: &Vector<1>) -> Matrix<7, 7> {
        let mut m = Matrix::zeros();
        for i in 4..7 {
            m[(i, i)] = -psi[0];
        }
        m
    }
    fn r_v(&self, _: f64, _: &Vector<7>, _: &Vector<7>, _: &Vector<1>) -> Matrix<7, 7> {
        Matrix::zeros()
    }
    fn td(&self, _: f64, _: &Vector<7>, _: &Vector<7>) -> TimeDerivatives<7, 1> {
        autonomous_td()
    }
}

impl_system!(
    MpParticles,
    7,
    1,
    CONSERVATIVE_LINEAR,
    SystemSource {
        name: "MpParticles",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["q1", "q2", "q3", "q4", "q5", "q6", "q7"],
        parameters: &[],
        lagrangian: "(- (* 0.5 (+ (^ (v q1) 2) (^ (v q2) 2) (^ (v q3) 2) (^ (v q4) 2) (^ (v q5) 2) (^ (v q6) 2) \
                     (^ (v q7) 2))) (* 0.5 (+ (^ (q q1) 2) (^ (q q2) 2) (^ (q q3) 2) (^ (q q4) 2) (^ (q q5) 2) \
                     (^ (q q6) 2) (^ (q q7) 2) (* (^ (q q5) 2) (^ (q q6) 2)) (* (^ (q q2) 2) (^ (q q5) 2)) \
                     (* (^ (q q3) 2) (^ (q q6) 2)) (* (^ (q q4) 2) (^ (q q7) 2)))))",
        constraints: &["(+ (v q1) (* (q q5) (v q5)) (* (q q6) (v q6)) (* (q q7) (v q7)))"],
    }
);

/// A deliberately general test system exercising every Jacobian block:
/// `L = ½(1+q₁²)v₁² + ½v₂² + c sin(t) q₂v₁ − ½(q₁² + q₂²)` (time-dependent,
/// non-separable, configuration-dependent mass) with the constraint
/// `v₂ − q₁v₁ − a v₁² + e sin t = 0` (nonlinear in `v`, rheonomic).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct General {
    /// Coupling `c`.
    pub c: f64,
    /// Constraint nonlinearity `a`.
    pub a: f64,
    /// Constraint forcing `e`.
    pub e: f64,
}

impl Default for General {
    fn default() -> Self {
        General { c: 0.3, a: 0.1, e: 0.05 }
    }
}

impl General {
    fn params(&self) -> [f64; 3] {
        [self.c, self.a, self.e]
    }
    fn set_param(&mut self, i: usize, x: f64) {
        match i {
            0 => self.c = x,
            1 => self.a = x,
            _ => self.e = x,
        }
    }
}

impl Derivatives<2, 1> for General {
    fn l(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> f64 {
        0.5 * (1.0 + q[0] * q[0]) * v[0] * v[0] + 0.5 * v[1] * v[1] + self.c * t.sin() * q[1] * v[0]
            - 0.5 * (q[0] * q[0] + q[1] * q[1])
    }
    fn p(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<2> {
        Vector::<2>::new((1.0 + q[0] * q[0]) * v[0] + self.c * t.sin() * q[1], v[1])
    }
    fn f(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<2> {
        Vector::<2>::new(q[0] * v[0] * v[0] - q[0], self.c * t.sin() * v[0] - q[1])
    }
    fn mass(&self, _: f64, q: &Vector<2>, _: &Vector<2>) -> Matrix<2, 2> {
        Matrix::<2, 2>::new(1.0 + q[0] * q[0], 0.0, 0.0, 1.0)
    }
    fn p_q(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Matrix<2, 2> {
        Matrix::<2, 2>::new(2.0 * q[0] * v[0], self.c * t.sin(), 0.0, 0.0)
    }
    fn f_q(&self, _: f64, _: &Vector<2>, v: &Vector<2>) -> Matrix<2, 2> {
        Matrix::<2, 2>::new(v[0] * v[0] - 1.0, 0.0, 0.0, -1.0)
    }
    fn f_v(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Matrix<2, 2> {
        Matrix::<2, 2>::new(2.0 * q[0] * v[0], 0.0, self.c * t.sin(), 0.0)
    }
    fn k(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> Vector<1> {
        Vector::<1>::new(v[1] - q[0] * v[0] - self.a * v[0] * v[0] + self.e * t.sin())
    }
    fn k_q(&self, _: f64, _: &Vector<2>, v: &Vector<2>) -> Matrix<1, 2> {
        Matrix::<1, 2>::new(-v[0], 0.0)
    }
    fn k_v(&self, _: f64, q: &Vector<2>, v: &Vector<2>) -> Matrix<1, 2> {
        Matrix::<1, 2>::new(-q[0] - 2.0 * self.a * v[0], 1.0)
    }
    fn r_q(&self, _: f64, _: &Vector<2>, _: &Vector<2>, psi: &Vector<1>) -> Matrix<2, 2> {
        // R = ((q₁ + 2a v₁)ψ, −ψ).
        Matrix::<2, 2>::new(psi[0], 0.0, 0.0, 0.0)
    }
    fn r_v(&self, _: f64, _: &Vector<2>, _: &Vector<2>, psi: &Vector<1>) -> Matrix<2, 2> {
        Matrix::<2, 2>::new(2.0 * self.a * psi[0], 0.0, 0.0, 0.0)
    }
    fn td(&self, t: f64, q: &Vector<2>, v: &Vector<2>) -> TimeDerivatives<2, 1> {
        TimeDerivatives {
            lagrangian_t: self.c * t.cos() * q[1] * v[0],
            momentum_t: Vector::<2>::new(self.c * t.cos() * q[1], 0.0),
            force_t: Vector::<2>::new(0.0, self.c * t.cos() * v[0]),
            constraint_t: Vector::<1>::new(self.e * t.cos()),
        }
    }
}

impl_system!(
    General,
    2,
    1,
    Structure {
        lagrangian_autonomous: false,
        constraints_autonomous: false,
        constant_mass_matrix: false,
        separable: false,
        constraint_form: ConstraintForm::Nonlinear,
    },
    SystemSource {
        name: "General",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y"],
        parameters: &["c", "a", "e"],
        lagrangian: "(- (+ (* 0.5 (+ 1 (^ (q x) 2)) (^ (v x) 2)) (* 0.5 (^ (v y) 2)) (* (p c) (sin t) (q y) (v x))) \
                     (* 0.5 (+ (^ (q x) 2) (^ (q y) 2))))",
        constraints: &["(+ (- (v y) (* (q x) (v x)) (* (p a) (^ (v x) 2))) (* (p e) (sin t)))"],
    }
);

/// The nonholonomic particle of §8.1 in a softened Kepler potential instead
/// of the harmonic one: `L = ½|v|² + μ/√(q₁² + q₂² + ε²)`, `v₃ − q₂v₁ = 0`.
///
/// A conservative system (energy is a first integral) whose time scale
/// varies along the solution: from `q = (1, 0, 0)`, `v = (0, 0.3, 0)` the
/// `(q₁, q₂)` motion is close to a Kepler ellipse of eccentricity ≈ 0.9, so
/// the local time scale `r^{3/2}` changes by a factor ≈ 100 between the
/// closest and farthest points. The softening `ε` keeps the potential
/// smooth where the constraint force lets the orbit pass near `r = 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitParticle {
    /// Gravitational parameter `μ`.
    pub mu: f64,
    /// Softening length `ε`.
    pub softening: f64,
}

impl Default for OrbitParticle {
    fn default() -> Self {
        OrbitParticle { mu: 1.0, softening: 0.01 }
    }
}

impl OrbitParticle {
    fn params(&self) -> [f64; 2] {
        [self.mu, self.softening]
    }
    fn set_param(&mut self, i: usize, x: f64) {
        match i {
            0 => self.mu = x,
            _ => self.softening = x,
        }
    }
    /// `√(q₁² + q₂² + ε²)`.
    pub fn radius(&self, q: &Vector<3>) -> f64 {
        (q[0] * q[0] + q[1] * q[1] + self.softening * self.softening).sqrt()
    }
}

impl Derivatives<3, 1> for OrbitParticle {
    fn l(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> f64 {
        0.5 * v.norm_squared() + self.mu / self.radius(q)
    }
    fn p(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Vector<3> {
        *v
    }
    fn f(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Vector<3> {
        let r3 = self.radius(q).powi(3);
        Vector::<3>::new(-self.mu * q[0] / r3, -self.mu * q[1] / r3, 0.0)
    }
    fn mass(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::identity()
    }
    fn p_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn f_q(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        // ∂(−μ qᵢ/r³)/∂q_j = −μ(δᵢⱼ/r³ − 3qᵢq_j/r⁵), i, j ∈ {1, 2}.
        let r = self.radius(q);
        let (r3, r5) = (r.powi(3), r.powi(5));
        let mut m = Matrix::zeros();
        for i in 0..2 {
            for j in 0..2 {
                let delta = if i == j { 1.0 } else { 0.0 };
                m[(i, j)] = -self.mu * (delta / r3 - 3.0 * q[i] * q[j] / r5);
            }
        }
        m
    }
    fn f_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn k(&self, _: f64, q: &Vector<3>, v: &Vector<3>) -> Vector<1> {
        Vector::<1>::new(v[2] - q[1] * v[0])
    }
    fn k_q(&self, _: f64, _: &Vector<3>, v: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(0.0, -v[0], 0.0)
    }
    fn k_v(&self, _: f64, q: &Vector<3>, _: &Vector<3>) -> Matrix<1, 3> {
        Matrix::<1, 3>::new(-q[1], 0.0, 1.0)
    }
    fn r_q(&self, _: f64, _: &Vector<3>, _: &Vector<3>, psi: &Vector<1>) -> Matrix<3, 3> {
        let mut m = Matrix::zeros();
        m[(0, 1)] = psi[0];
        m
    }
    fn r_v(&self, _: f64, _: &Vector<3>, _: &Vector<3>, _: &Vector<1>) -> Matrix<3, 3> {
        Matrix::zeros()
    }
    fn td(&self, _: f64, _: &Vector<3>, _: &Vector<3>) -> TimeDerivatives<3, 1> {
        autonomous_td()
    }
}

impl_system!(
    OrbitParticle,
    3,
    1,
    CONSERVATIVE_LINEAR,
    SystemSource {
        name: "OrbitParticle",
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
        coordinates: &["x", "y", "z"],
        parameters: &["mu", "softening"],
        lagrangian: "(+ (* 0.5 (+ (^ (v x) 2) (^ (v y) 2) (^ (v z) 2))) \
                     (/ (p mu) (sqrt (+ (^ (q x) 2) (^ (q y) 2) (^ (p softening) 2)))))",
        constraints: &["(- (v z) (* (q y) (v x)))"],
    }
);
