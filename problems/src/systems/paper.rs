//! The systems of the paper's §8, and more that exercise what the DSL and the
//! engine can do (explicit time, affine and nonlinear constraints, a
//! configuration-dependent mass matrix, no constraints), all declared with
//! `nonholonomic_system!`.
//!
//! Notation in the docs: `q` are the coordinates, `v = q̇` their velocities,
//! `L = T − U`, and `k(t, q, v) = 0` the ideal nonholonomic constraints with
//! `K = ∂k/∂v`. Parameter defaults are the values the paper uses.
//!
//! To see what the macro generates for one of them (and its operation count):
//! `cargo run -p spark-symbolic --example expand -- problems/src/systems/paper.rs Skate`.

use spark_runtime::{nonholonomic_system, Vector};

nonholonomic_system! {
    /// The nonholonomic particle (paper §8.1; Cortés, Bloch; `n = 3`, `m = 1`).
    ///
    /// `L = ½(v₁² + v₂² + v₃²) − (q₁² + q₂²)`, constraint `v₃ − q₂ v₁ = 0`
    /// (linear in `v`, scleronomic). Energy `E = T + U` is conserved. The
    /// paper starts from `q₀ = (1, 0, 0)`, `v₀ = (0, 1, 0)`.
    pub struct NonholonomicParticle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

nonholonomic_system! {
    /// The skate on an inclined plane (paper §8.2; Arnold–Kozlov–Neishtadt,
    /// Neimark–Fufaev; `n = 3`, `m = 1`).
    ///
    /// `L = ½m(v₁² + v₂²) + ½I v₃² + m g q₁ sin β` (the plane is inclined by
    /// `β` along `q₁`), constraint `cos(q₃) v₂ − sin(q₃) v₁ = 0`: the blade,
    /// at angle `q₃`, does not slide sideways. Parameters `m = I = g = 1`,
    /// `β = π/2` as in the paper; `q₀ = 0`, `v₀ = (0, 0, 1)`.
    pub struct Skate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
}

nonholonomic_system! {
    /// A mobile robot with fixed orientation and a potential (paper §8.3;
    /// Cortés; `n = 4`, `m = 2`).
    ///
    /// `L = ½m(v₁² + v₂²) + ½I v₃² + (3/2) I_ω v₄² − 10 sin q₄`, constraints
    /// `v₁ − ℓ cos(q₃) v₄ = 0`, `v₂ − ℓ sin(q₃) v₄ = 0` (the wheels roll
    /// without slipping). Parameters `m = I = I_ω = ℓ = 1`;
    /// `q₀ = 0`, `v₀ = (1, 0, 0, 1)`.
    pub struct MobileRobot {
        coordinates: [x, y, theta, phi],
        parameters: { m = 1.0, inertia = 1.0, inertia_wheel = 1.0, ell = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + 3/2*inertia_wheel*dot(phi)^2
            - 10*sin(phi),
        constraints: [
            dot(x) - ell*cos(theta)*dot(phi),
            dot(y) - ell*sin(theta)*dot(phi),
        ],
    }
}

nonholonomic_system! {
    /// McLachlan and Perlmutter's particles for `n = 2m + 1 = 7` (paper §8.4;
    /// McLachlan–Perlmutter 2004, 2006; `m = 3`, one constraint).
    ///
    /// `L = ½|v|² − U`, `U = ½(|q|² + q₅²q₆² + Σ_{i=1..3} q_{1+i}² q_{4+i}²)`,
    /// constraint `v₁ + q₅v₅ + q₆v₆ + q₇v₇ = 0`. The paper's initial states are
    /// `q₀ = (cos(jπ/18), 0.6, 0.4, 0.2, 1, 1, 1)`, `v₀ = (0, sin(jπ/18), 0, …, 0)`,
    /// all with energy 3.06.
    ///
    /// This is the constraint exactly as the paper prints it
    /// (`v₁ + Σ_{i=m+2}^{n} q_i v_i = 0`). It is **holonomic**: it is
    /// `d/dt [q₁ + ½(q₅² + q₆² + q₇²)] = 0`, so the motion is that of a
    /// Hamiltonian system on a level set of `φ(q) = q₁ + ½(q₅² + q₆² + q₇²)`.
    /// See [`McLachlanPerlmutter7Nonholonomic`] for the nonholonomic reading
    /// and `docs/stress/chaos.md` for what this changes in Fig. 8.4.
    ///
    /// Event `section`: `q₂` rising through 0, the Poincaré section of
    /// `spark section mp7 --event section`.
    pub struct McLachlanPerlmutter7 {
        coordinates: [q1, q2, q3, q4, q5, q6, q7],
        lagrangian: (dot(q1)^2 + dot(q2)^2 + dot(q3)^2 + dot(q4)^2 + dot(q5)^2 + dot(q6)^2 + dot(q7)^2)/2
            - (q1^2 + q2^2 + q3^2 + q4^2 + q5^2 + q6^2 + q7^2
               + q5^2*q6^2 + q2^2*q5^2 + q3^2*q6^2 + q4^2*q7^2)/2,
        constraints: [ dot(q1) + q5*dot(q5) + q6*dot(q6) + q7*dot(q7) ],
        events: { section: rising(q2) },
    }
}

nonholonomic_system! {
    /// McLachlan and Perlmutter's particles (`n = 7`, `m = 3`) with the
    /// constraint read as `v₁ + Σ_{i=m+2}^{n} q_{i−m} v_i = 0`, i.e.
    /// `v₁ + q₂v₅ + q₃v₆ + q₄v₇ = 0` (paper §8.4 with the index `i − m`).
    ///
    /// Same `L` as [`McLachlanPerlmutter7`]. Unlike the printed constraint this
    /// one is not integrable (`dq₁ + q₂dq₅ + q₃dq₆ + q₄dq₇` is a contact
    /// form), so the system is genuinely nonholonomic, as §8.4 says, and the
    /// paper's initial states `v₀ = (0, sin(jπ/18), 0, …, 0)` satisfy it with
    /// energy 3.06. With it the three methods of Fig. 8.4 show the random
    /// walk of the energy error that the paper reports (`docs/stress/chaos.md`).
    ///
    /// Event `section`: `q₂` rising through 0, as for [`McLachlanPerlmutter7`].
    pub struct McLachlanPerlmutter7Nonholonomic {
        coordinates: [q1, q2, q3, q4, q5, q6, q7],
        lagrangian: (dot(q1)^2 + dot(q2)^2 + dot(q3)^2 + dot(q4)^2 + dot(q5)^2 + dot(q6)^2 + dot(q7)^2)/2
            - (q1^2 + q2^2 + q3^2 + q4^2 + q5^2 + q6^2 + q7^2
               + q5^2*q6^2 + q2^2*q5^2 + q3^2*q6^2 + q4^2*q7^2)/2,
        constraints: [ dot(q1) + q2*dot(q5) + q3*dot(q6) + q4*dot(q7) ],
        events: { section: rising(q2) },
    }
}

nonholonomic_system! {
    /// A skate on a turntable whose angular velocity varies in time: a
    /// rheonomic, affine constraint (`n = 3`, `m = 1`).
    ///
    /// A rheonomic variant of §8.2 built for this project (moving supports
    /// as in Neimark–Fufaev, *Dynamics of Nonholonomic Systems*). In the inertial frame `L = ½m(v₁² + v₂²) + ½I v₃²`; the table
    /// turns about the origin with `ω(t) = ω₀(1 + ε sin(νt))`, so the surface
    /// under the blade moves with `(−ω q₂, ω q₁)`. The blade cannot slide
    /// sideways relative to the surface:
    /// `k = cos(q₃)(v₂ − ω q₁) − sin(q₃)(v₁ + ω q₂) = 0`, i.e.
    /// `K = (−sin q₃, cos q₃, 0)`, `b(t, q) = −ω(t)(q₁ cos q₃ + q₂ sin q₃)`.
    /// Energy is not conserved (the table does work).
    ///
    /// Event `relative_speed`: the blade's speed relative to the table,
    /// `|v − ω(t)(−q₂, q₁)|`, crossing 1 (an event function that depends on
    /// `t`, on parameters and nonlinearly on `q` and `v`).
    pub struct TurntableSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, omega0 = 1.0, eps = 0.5, nu = 2.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2,
        constraints: [
            cos(theta)*(dot(y) - omega0*(1 + eps*sin(nu*t))*x)
                - sin(theta)*(dot(x) + omega0*(1 + eps*sin(nu*t))*y),
        ],
        events: {
            relative_speed: (dot(x) + omega0*(1 + eps*sin(nu*t))*y)^2
                + (dot(y) - omega0*(1 + eps*sin(nu*t))*x)^2 - 1,
        },
    }
}

nonholonomic_system! {
    /// The Appell–Hamel particle: a constraint nonlinear in the velocities
    /// (Appell 1911, Hamel; see Neimark–Fufaev, *Dynamics of Nonholonomic
    /// Systems*; `n = 3`, `m = 1`).
    ///
    /// A particle of mass `m` under gravity, `L = ½m(v₁² + v₂² + v₃²) − m g q₃`,
    /// whose vertical speed is tied to its horizontal speed (the original
    /// mechanism: a cord wound on a weightless wheel):
    /// `k = v₃² − a²(v₁² + v₂²) = 0`, squared so that it is polynomial.
    /// `K = (−2a²v₁, −2a²v₂, 2v₃)` is nonzero, and
    /// `[[M, Kᵀ], [K, 0]]` regular, wherever `v ≠ 0` (e.g. at
    /// `v = (1, 0, a)`); Chetaev's rule applies. `E = T + U` is conserved
    /// since `K v = 2k = 0`.
    pub struct AppellHamel {
        coordinates: [x, y, z],
        parameters: { m = 1.0, g = 1.0, a = 0.5 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2 + dot(z)^2) - m*g*z,
        constraints: [ dot(z)^2 - a^2*(dot(x)^2 + dot(y)^2) ],
    }
}

nonholonomic_system! {
    /// The Chaplygin sleigh on an inclined plane: a configuration-dependent
    /// mass matrix and a Lagrangian that is not `T(v) − U(q)` (Chaplygin 1911;
    /// Bloch, *Nonholonomic Mechanics and Control*, ch. 1; `n = 3`, `m = 1`).
    ///
    /// `(x, y)` is the contact point of the knife edge, `θ` its direction, the
    /// centre of mass sits at distance `a` ahead of it:
    /// `L = ½m(v₁² + v₂² + a²v₃² + 2a v₃(−v₁ sin θ + v₂ cos θ)) + ½I v₃²
    ///      + m g sin α (x + a cos θ)`,
    /// constraint `−sin(θ) v₁ + cos(θ) v₂ = 0` (no sideways slip). The mass
    /// matrix depends on `θ`; `∂(∇_v L)/∂q` and `∂(∇_q L)/∂v` are nonzero.
    ///
    /// Event `turn`: `θ̇` falling through 0, the turning points of the
    /// heading (`spark section sleigh --event turn`).
    pub struct ChaplyginSleigh {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.5, a = 0.5, g = 1.0, alpha = pi/6 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2 + a^2*dot(theta)^2
                         + 2*a*dot(theta)*(-dot(x)*sin(theta) + dot(y)*cos(theta)))
            + inertia/2*dot(theta)^2 + m*g*sin(alpha)*(x + a*cos(theta)),
        constraints: [ -sin(theta)*dot(x) + cos(theta)*dot(y) ],
        events: { turn: falling(dot(theta)) },
    }
}

nonholonomic_system! {
    /// The planar double pendulum: no constraints, a non-separable Lagrangian
    /// (`n = 2`, `m = 0`; a standard textbook example, e.g. Goldstein,
    /// *Classical Mechanics*, ch. 1).
    ///
    /// Angles `θ₁, θ₂` from the downward vertical:
    /// `L = ½(m₁ + m₂)ℓ₁²v₁² + ½m₂ℓ₂²v₂² + m₂ℓ₁ℓ₂ cos(θ₁ − θ₂) v₁v₂
    ///      + (m₁ + m₂) g ℓ₁ cos θ₁ + m₂ g ℓ₂ cos θ₂`.
    pub struct DoublePendulum {
        coordinates: [theta1, theta2],
        parameters: { m1 = 1.0, m2 = 1.0, l1 = 1.0, l2 = 1.0, g = 9.81 },
        lagrangian: (m1 + m2)/2*l1^2*dot(theta1)^2 + m2/2*l2^2*dot(theta2)^2
            + m2*l1*l2*cos(theta1 - theta2)*dot(theta1)*dot(theta2)
            + (m1 + m2)*g*l1*cos(theta1) + m2*g*l2*cos(theta2),
    }
}

nonholonomic_system! {
    /// The nonholonomic particle of §8.1 in a softened Kepler potential:
    /// `L = ½|v|² + μ/√(x² + y² + ε²)`, `v₃ − y v₁ = 0`. Conservative, with a
    /// time scale that varies along the solution: from `(1, 0, 0)` with
    /// `v = (0, 0.3, 0)` the `(x, y)` motion is close to a Kepler ellipse of
    /// eccentricity ≈ 0.9, so the local time scale `r^{3/2}` changes by a
    /// factor ≈ 100 between the farthest and closest points (the system on
    /// which tolerance-driven stepping pays; see `docs/adaptive.md`).
    pub struct OrbitParticle {
        coordinates: [x, y, z],
        parameters: { mu = 1.0, softening = 0.01 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 + mu/sqrt(x^2 + y^2 + softening^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

/// Initial values `j` of the §8.4 ensemble with `J + 1` members:
/// `q = (α_j, 0.6, 0.4, 0.2, 1, 1, 1)`, `v = (0, β_j, 0, 0, 0, 0, 0)` with
/// `α_j = cos(jπ/(2J))`, `β_j = sin(jπ/(2J))`.
///
/// The paper prints six velocity entries `(0, β_j, 0, 0, 0, 0)` for `n = 7`.
/// Reading them as `v = (0, β_j, 0, 0, 0, 0, 0)` is the consistent choice:
/// the constraint `v1 + q5 v5 + q6 v6 + q7 v7 = 0` holds, and
/// `E = β_j²/2 + (α_j² + 3.56 + 1 + 0.56)/2 = 3.06` for every `j`, as the
/// paper states.
pub fn mp7_initial_values(j: usize, big_j: usize) -> (Vec<f64>, Vec<f64>) {
    let theta = if big_j == 0 { 0.0 } else { j as f64 * std::f64::consts::PI / (2.0 * big_j as f64) };
    let (alpha, beta) = (theta.cos(), theta.sin());
    (vec![alpha, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0], vec![0.0, beta, 0.0, 0.0, 0.0, 0.0, 0.0])
}

/// `φ(q) = q1 + ½(q5² + q6² + q7²)`: the constraint of §8.4 as printed,
/// `v1 + q5 v5 + q6 v6 + q7 v7 = 0`, is `dφ/dt = 0`.
pub fn mp7_phi(q: &[f64]) -> f64 {
    q[0] + 0.5 * (q[4] * q[4] + q[5] * q[5] + q[6] * q[6])
}

/// One RATTLE step for the holonomic constraint `φ(q) = φ(q0)` of
/// [`McLachlanPerlmutter7`], written independently of the SPARK stepper:
/// `v½ = v0 − (h/2)(∇U(q0) + λ∇φ(q0))`, `q1 = q0 + h v½` with `φ(q1) = φ(q0)`
/// (a quadratic in `λ`, solved by Newton), then
/// `v1 = v½ − (h/2)(∇U(q1) + μ∇φ(q1))` with `∇φ(q1)·v1 = 0`.
pub fn mp7_rattle(q0: &Vector<7>, v0: &Vector<7>, h: f64) -> (Vector<7>, Vector<7>) {
    let grad_u = |q: &Vector<7>| {
        let mut g = *q;
        g[1] += q[1] * q[4] * q[4];
        g[2] += q[2] * q[5] * q[5];
        g[3] += q[3] * q[6] * q[6];
        g[4] += q[4] * (q[5] * q[5] + q[1] * q[1]);
        g[5] += q[5] * (q[4] * q[4] + q[2] * q[2]);
        g[6] += q[6] * q[3] * q[3];
        g
    };
    let grad_phi = |q: &Vector<7>| Vector::<7>::from_column_slice(&[1.0, 0.0, 0.0, 0.0, q[4], q[5], q[6]]);
    let phi = |q: &Vector<7>| mp7_phi(q.as_slice());
    let a = v0 - 0.5 * h * grad_u(q0);
    let g0 = grad_phi(q0);
    let mut lambda = 0.0;
    for _ in 0..50 {
        let q1 = q0 + h * (a - 0.5 * h * lambda * g0);
        let slope = grad_phi(&q1).dot(&(-0.5 * h * h * g0));
        let d = (phi(&q1) - phi(q0)) / slope;
        lambda -= d;
        if d.abs() <= 1e-16 * (1.0 + lambda.abs()) {
            break;
        }
    }
    let half = a - 0.5 * h * lambda * g0;
    let q1 = q0 + h * half;
    let g1 = grad_phi(&q1);
    let w = half - 0.5 * h * grad_u(&q1);
    let mu = g1.dot(&w) / g1.dot(&g1);
    (q1, w - mu * g1)
}
