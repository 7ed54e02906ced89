//! Systems built for the stress suite, declared with `nonholonomic_system!`:
//! a skate with a stiff spring, a particle with two nearly parallel
//! constraint rows, the Modin–Verdier non-reversible contact oscillator with
//! its reversible twin, a gyroscopic reconstruction kept beside them, and the
//! vertical rolling disk (exact solution in [`rolling_disk_exact`]).

use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    /// The skate of the paper's §8.2 tied to the origin by a spring of
    /// stiffness `k` (`ω = √(k/m)`; `n = 3`, `m = 1`).
    ///
    /// `L = ½m(v₁² + v₂²) + ½I v₃² + m g q₁ sin β − ½k(q₁² + q₂²)`,
    /// constraint `cos(q₃) v₂ − sin(q₃) v₁ = 0`. Energy is conserved.
    pub struct StiffSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2, k = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta) - k/2*(x^2 + y^2),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
}

nonholonomic_system! {
    /// The nonholonomic particle with a second constraint row that is the
    /// first one plus `ε v₂` (`n = 3`, `m = 2`): as `ε → 0` the rows become
    /// parallel and `[[∇²_vv L, Kᵀ],[K, 0]]` singular (condition `~ ε⁻²`).
    ///
    /// `L = ½|v|² − (q₁² + q₂²)`, `k = (v₃ − q₂v₁, v₃ − q₂v₁ + ε v₂)`.
    /// For `ε ≠ 0` the motion is exact: `q₂ = q₂(0)`, and with
    /// `μ = 1 + q₂²`, `q₁ = A cos(ωt) + B sin(ωt)`, `ω = √(2/μ)`,
    /// `q₃ = q₃(0) + q₂(q₁ − q₁(0))` (see [`near_parallel_exact`]).
    pub struct NearParallel {
        coordinates: [x, y, z],
        parameters: { eps = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x), dot(z) - y*dot(x) + eps*dot(y) ],
    }
}

nonholonomic_system! {
    /// A contact oscillator with a gyroscopic perturbation that breaks
    /// reversibility (`n = 3`, `m = 1`). A *reconstruction* in the spirit of
    /// Modin & Verdier, "What makes nonholonomic integrators work?" (Numer.
    /// Math. 145, 2020): their exact test problems were not available to us.
    ///
    /// Base: the McLachlan–Perlmutter family for one oscillator pair,
    /// `L₀ = ½|v|² − ½(q₁² + q₂² + q₃² + q₂²q₃²)`, constraint
    /// `v₁ + q₃v₃ = 0`, reversible under `(q, v, t) ↦ (q, −v, −t)`. The
    /// term `ε·(q₁v₂ − q₂v₁)/2` (a uniform magnetic field normal to the
    /// `(q₁, q₂)` plane) is odd in `v`, so the equations are no longer
    /// reversible under that map, while `E = ½|v|² + U` stays a first
    /// integral (the term does no work).
    pub struct NonReversibleOscillator {
        coordinates: [x, y, z],
        parameters: { eps = 0.5 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2 + z^2 + y^2*z^2)/2
            + eps*(x*dot(y) - y*dot(x))/2,
        constraints: [ dot(x) + z*dot(z) ],
    }
}

nonholonomic_system! {
    /// The contact oscillator of McLachlan & Perlmutter (J. Nonlinear Sci.
    /// 16, 2006, §5.2; `n = 3`, `m = 1`): `L = ½|v|² − U`,
    /// `U = ½(x² + y² + z² + ε x²z²)`, constraint `ẋ + y ż = 0`. Reversible
    /// under `(q, v, t) ↦ (q, −v, −t)`; the reversible twin of
    /// [`NonReversibleContactOscillator`].
    pub struct ContactOscillator {
        coordinates: [x, y, z],
        parameters: { eps = 0.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2 + z^2 + eps*x^2*z^2)/2,
        constraints: [ dot(x) + y*dot(z) ],
    }
}

nonholonomic_system! {
    /// The non-reversible contact oscillator of Modin & Verdier ("What makes
    /// nonholonomic integrators work?", Numer. Math. 145, 2020), as defined
    /// in Verdier's `odelab` (`odelab/system/nonholonomic/contactoscillator.py`,
    /// class `NonReversibleContactOscillator`): the Hamiltonian of the
    /// [`ContactOscillator`] with `p` replaced by `p + ∇S`, `S(q) = cos z`,
    /// i.e. `H = ½(|q|² + ε x²z² + |p + ∇S|²)` (`n = 3`, `m = 1`).
    ///
    /// As a Lagrangian (`v = ∂H/∂p = p + ∇S`): `L = ½|v|² − ∇S·v − U =
    /// ½|v|² + sin(z) ż − U`, same constraint `ẋ + y ż = 0`. The added term is
    /// the total derivative `−dS/dt`, so the motion `(q(t), v(t))` and the
    /// energy `E = ½|v|² + U` are exactly those of the reversible oscillator;
    /// what changes is the momentum `p = v − ∇S` the integrators discretize,
    /// and with it the standard reversibility map `(q, p) ↦ (q, −p)`, under
    /// which this system is not reversible.
    pub struct NonReversibleContactOscillator {
        coordinates: [x, y, z],
        parameters: { eps = 0.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 + sin(z)*dot(z) - (x^2 + y^2 + z^2 + eps*x^2*z^2)/2,
        constraints: [ dot(x) + y*dot(z) ],
    }
}

/// The initial state `odelab` uses for the contact oscillators
/// (`initial_sin`, `H₀ = 1.5`, `H_y = ½`, `ż₀` momentum 0): `q0 = (x₀, 0, z₀)`
/// with `x₀ = √((2(H₀ − H_y) − z₀²)/(1 + ε z₀²))`, momentum `p0 = (0, 1, 0)`,
/// hence `v0 = p0 + ∇S = (0, 1, −sin z₀)` for the non-reversible system.
/// Both systems are started from this same `(q0, v0)`, so their exact
/// motions coincide.
pub fn contact_oscillator_initial(z0: f64, eps: f64) -> ([f64; 3], [f64; 3]) {
    let (h0, hy) = (1.5, 0.5);
    let x0 = ((2.0 * (h0 - hy) - z0 * z0) / (1.0 + eps * z0 * z0)).sqrt();
    ([x0, 0.0, z0], [0.0, (2.0 * hy).sqrt(), -z0.sin()])
}

nonholonomic_system! {
    /// The vertical rolling disk (Bloch, *Nonholonomic Mechanics and
    /// Control*, §1.4; `n = 4`, `m = 2`): contact point `(x, y)`, heading
    /// `θ`, rolling angle `φ`, radius `R`.
    ///
    /// `L = ½m(ẋ² + ẏ²) + ½I θ̇² + ½J φ̇²`, constraints
    /// `ẋ = R cos θ φ̇`, `ẏ = R sin θ φ̇`. `θ̇` and `φ̇` are constant and
    /// `x, y` follow in closed form ([`rolling_disk_exact`]).
    pub struct RollingDisk {
        coordinates: [x, y, theta, phi],
        parameters: { m = 1.0, inertia = 0.5, inertia_roll = 0.25, radius = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + inertia_roll/2*dot(phi)^2,
        constraints: [
            dot(x) - radius*cos(theta)*dot(phi),
            dot(y) - radius*sin(theta)*dot(phi),
        ],
    }
}

/// Exact `(q, v)` of [`RollingDisk`] at time `t` from `q0 = (x₀, y₀, θ₀, φ₀)`
/// with heading rate `ω ≠ 0` and rolling rate `Ω`, radius `r`.
pub fn rolling_disk_exact(q0: [f64; 4], omega: f64, big_omega: f64, r: f64, t: f64) -> ([f64; 4], [f64; 4]) {
    let [x0, y0, th0, ph0] = q0;
    let th = th0 + omega * t;
    let c = r * big_omega / omega;
    // Integrate ẋ = RΩ cos(θ₀ + ωt) and ẏ = RΩ sin(θ₀ + ωt); the differences
    // of sines/cosines are written as products to keep relative accuracy
    // when ωt is small.
    let half = 0.5 * omega * t;
    let mid = th0 + half;
    let x = x0 + c * 2.0 * mid.cos() * half.sin();
    let y = y0 + c * 2.0 * mid.sin() * half.sin();
    let q = [x, y, th, ph0 + big_omega * t];
    let v = [r * big_omega * th.cos(), r * big_omega * th.sin(), omega, big_omega];
    (q, v)
}

/// Exact `(q, v)` of [`NearParallel`] (any `ε ≠ 0`) at time `t` from a
/// consistent `(q0, v0)` (`v0₂ = 0`, `v0₃ = q0₂ v0₁`).
pub fn near_parallel_exact(q0: [f64; 3], v0: [f64; 3], t: f64) -> ([f64; 3], [f64; 3]) {
    let y = q0[1];
    let mu = 1.0 + y * y;
    let w = (2.0 / mu).sqrt();
    let (a, b) = (q0[0], v0[0] / w);
    let x = a * (w * t).cos() + b * (w * t).sin();
    let vx = -a * w * (w * t).sin() + b * w * (w * t).cos();
    ([x, y, q0[2] + y * (x - q0[0])], [vx, 0.0, y * vx])
}
