//! Systems a new user declares beyond the quadratic kinetic energies of
//! `newcomer_systems`: a magnetic (gyroscopic) term with explicit `t`, a
//! position-dependent non-diagonal mass with a constraint quadratic in `v`
//! and a `t`-dependent drift, a relativistic Lagrangian (not polynomial in
//! `v`), quartic and exponential kinetic terms with `M = 0`, one coordinate
//! with a force, a Chaplygin sleigh with forces and a non-ideal force in
//! `ψ`, two mixed constraints with fractional and negative powers, a
//! breathing bowl (rheonomic holonomic effect, force and non-ideal force in
//! scenes), as many constraints as coordinates, and legal but odd names
//! (`None`, `q`, `v`, `psi`, `h`, a variable exponent).
//!
//! Each is checked for exact derivatives (finite differences, the effect
//! Jacobians included) and for steps that equal the tightly converged
//! solution of their equations in every Newton mode: Gauss s = 1..3,
//! Lobatto IIIA-B and IIIA-B-D s = 2, 3, full Newton and simplified Newton
//! on the exact, the stage-decoupled and the automatically chosen matrix.
//! The same systems exported through the CasADi checker's JSON format
//! (a scratch exporter built from `problems/src/crosscheck`) gave derivative
//! differences of at most 5.3e-15 and steps within 5.2e-14 of CasADi's
//! Newton solve of (6.1) (1232 steps, four steps per method and mode, h = 0.1).

use super::newcomer_systems::{against_tight, derivative_error, step_distance, tally_against_tight, EVERY_MODE};

use spark_runtime::{
    consistent_velocity, nonholonomic_system, ConsistencyPolicy, ConstraintForm, Jacobian, Method, NewtonMode,
    NewtonOptions, NoObserver, NonholonomicSystem, RunOptions, Schedule, State, Stepper, Tableau, Vector,
    HISTORY_CAPACITY,
};

nonholonomic_system! {
    /// A skate in a pulsating magnetic field (terms linear in v with t) and a breathing well.
    pub struct MagneticSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.3, b0 = 0.8, eps = 0.3, w = 1.7, kap = 1.2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2
            + b0*(1 + eps*sin(w*t))/2*(x*dot(y) - y*dot(x)) - kap/2*(x^2 + y^2)*(1 + 0.2*cos(t)),
        constraints: [ sin(theta)*dot(x) - cos(theta)*dot(y) ],
    }
}

nonholonomic_system! {
    /// Position-dependent non-diagonal mass; a constraint quadratic in v with a cross term and a t drift.
    pub struct QuadCross {
        coordinates: [x, y, z],
        parameters: { c = 0.4, a = 0.5 },
        lagrangian: ((1 + y^2)*dot(x)^2 + 2*c*sin(x)*dot(x)*dot(y) + (2 + cos(x))*dot(y)^2 + dot(z)^2)/2
            - (x^2 + y^2 + z^2)/2 - x*y*z/3,
        constraints: [ dot(x)*dot(y) + dot(z)^2 - a^2*(1 + t^2/4) ],
    }
}

nonholonomic_system! {
    /// A relativistic particle (L not polynomial in v, undefined at |v| ≥ c) on an affine rheonomic guide.
    pub struct Relativistic {
        coordinates: [x, y],
        parameters: { c = 3.0, w = 0.2 },
        lagrangian: -c^2*sqrt(1 - (dot(x)^2 + dot(y)^2)/c^2) - (x^2 + 2*y^2)/2,
        constraints: [ dot(y) - tanh(x)*dot(x) - w*sin(t) ],
    }
}

nonholonomic_system! {
    /// Quartic and exponential kinetic terms, a q-dependent cross term, t in the potential, M = 0.
    pub struct QuarticKinetic {
        coordinates: [x, y],
        lagrangian: dot(x)^2/2 + dot(x)^4/12 + exp(-y^2)*dot(y)^2/2 + x*dot(x)*dot(y)/4 + exp(dot(y)/5)
            + t*x/3 - cosh(y/2) - x^2/2,
    }
}

nonholonomic_system! {
    /// One coordinate: a driven, damped Duffing oscillator with a position-dependent mass.
    pub struct DrivenDuffing {
        coordinates: [x],
        parameters: { c = 0.1, amp = 0.5, w = 1.3 },
        lagrangian: (1 + x^2/4)*dot(x)^2/2 - x^4/4 + x^2/2*cos(t)/5,
        forces: { x: -c*dot(x) + amp*cos(w*t) },
    }
}

nonholonomic_system! {
    /// Chaplygin sleigh (non-constant, non-diagonal mass) with a periodic push, damping and a
    /// smoothed friction on the blade that depends on its multiplier.
    pub struct FrictionSleigh {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.4, a = 0.3, f0 = 0.5, w = 0.9, c = 0.2, mu = 0.1, delta = 0.05 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2
            + m*a*dot(theta)*(cos(theta)*dot(y) - sin(theta)*dot(x)),
        constraints: [ -sin(theta)*dot(x) + cos(theta)*dot(y) ],
        forces: { x: f0*cos(w*t) - c*dot(x), theta: -c*dot(theta)*tanh(dot(theta)) },
        nonideal_forces: {
            x: -mu*sqrt(psi[0]^2 + delta^2)*cos(theta)*tanh(cos(theta)*dot(x) + sin(theta)*dot(y)),
            y: -mu*sqrt(psi[0]^2 + delta^2)*sin(theta)*tanh(cos(theta)*dot(x) + sin(theta)*dot(y)),
        },
    }
}

nonholonomic_system! {
    /// Two constraints, one quadratic and rheonomic, one affine with a t drift; fractional and
    /// negative powers; a constant cross term.
    pub struct MixedTwo {
        coordinates: [q1, q2, q3, q4],
        parameters: { k1 = 1.0, k2 = 0.5, s0 = 1.0, p = 0.3 },
        lagrangian: ((1 + q1^2)^(1/3)*dot(q1)^2 + dot(q2)^2 + (2 + sin(q2))*dot(q3)^2 + dot(q4)^2)/2
            + p*dot(q1)*dot(q3) - k1/2*(q1^2 + q2^2) - k2*(1 + q3^2)^-1 - q4^4/4,
        constraints: [
            dot(q1)^2 + dot(q2)^2 - s0^2*(1 + 0.2*sin(t)),
            dot(q4) - q1*dot(q3) - 0.1*cos(2*t)*exp(-q2^2),
        ],
    }
}

nonholonomic_system! {
    /// A charged bead in a breathing bowl (rheonomic holonomic effect), with drag and a
    /// non-ideal force proportional to the bowl's multiplier.
    pub struct Bowl {
        coordinates: [x, y, z],
        parameters: { g = 9.81, om = 0.5, c = 0.1, bz = 0.7 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - g*z + bz/2*(x*dot(y) - y*dot(x)),
        effects: {
            bowl: holonomic(z - (x^2 + y^2)/2*(1 + 0.3*sin(om*t))),
            drag: force { x: -c*dot(x), y: -c*dot(y), z: -c*dot(z) },
            slide: nonideal { x: -c*bowl*x, y: -c*bowl*y },
        },
        scenes: { BowlFree = [bowl], BowlDragged = [bowl, drag, slide] },
    }
}

nonholonomic_system! {
    /// As many constraints as coordinates: the motion is prescribed, the multipliers are not.
    pub struct FullyConstrained {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - x^2/2,
        constraints: [ dot(x) - cos(t), dot(y) - x*dot(x) ],
    }
}

nonholonomic_system! {
    /// Legal but odd names: `None`, `q`, `v` as coordinates, `psi` and `h` as parameters, and a
    /// variable exponent in L and in a constraint nonlinear in v.
    pub struct OddNames {
        coordinates: [None, q, v],
        parameters: { psi = 1.5, h = 0.3 },
        lagrangian: psi*(dot(None)^2 + dot(q)^2 + dot(v)^2)/2 - h*(1 + None^2)^q - v^2/2,
        constraints: [ dot(q) - (2 + v)^dot(None) + 1 ],
    }
}

/// The systems with their starting times and states (the velocities are
/// projected onto the constraints before use), each passed to
/// `$each!(system, N, M, t0, q0, v0)`.
macro_rules! unusual {
    ($each:ident) => {
        $each!(MagneticSkate::default(), 3, 1, 0.3, [0.4, -0.2, 0.5], [0.8, 0.3, 0.7]);
        $each!(QuadCross::default(), 3, 1, 0.2, [0.3, 0.1, -0.2], [0.4, 0.3, 0.4]);
        $each!(Relativistic::default(), 2, 1, 0.5, [0.2, 0.1], [1.2, 0.5]);
        $each!(QuarticKinetic::default(), 2, 0, 0.7, [0.3, -0.4], [0.9, -0.5]);
        $each!(DrivenDuffing::default(), 1, 0, 0.25, [0.6], [-0.4]);
        $each!(FrictionSleigh::default(), 3, 1, 0.1, [0.1, 0.2, 0.4], [0.9, 0.2, 0.6]);
        $each!(MixedTwo::default(), 4, 2, 0.3, [0.2, -0.1, 0.3, 0.1], [0.6, 0.7, 0.2, 0.1]);
        $each!(BowlFree::default(), 3, 1, 0.4, [0.5, -0.3, 0.2], [0.2, 0.6, 0.1]);
        $each!(BowlDragged::default(), 3, 1, 0.4, [0.5, -0.3, 0.2], [0.2, 0.6, 0.1]);
        $each!(FullyConstrained::default(), 2, 2, 0.2, [0.3, 0.1], [1.0, 0.3]);
        $each!(OddNames::default(), 3, 1, 0.1, [0.3, 0.2, 0.4], [0.5, 0.6, 0.1]);
    };
}

/// A consistent start: `v0` projected onto `k(t0, q0, ·) = 0`.
pub fn start<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(
    sys: &Sys,
    t0: f64,
    q0: [f64; N],
    v0: [f64; N],
) -> State<N> {
    let q0 = Vector::<N>::from(q0);
    let v0 = consistent_velocity(sys, t0, &q0, &Vector::<N>::from(v0), ConsistencyPolicy::Project { tolerance: 0.0 })
        .unwrap_or_else(|e| panic!("{}: projecting v0: {e}", Sys::SOURCE.name));
    State::new(t0, q0, v0)
}

/// The declared name of a system's type.
fn name_of<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(_: &Sys) -> &'static str {
    Sys::SOURCE.name
}

/// Largest error of the external and non-ideal force Jacobians against
/// fourth-order central differences of the generated forces at random
/// points, relative to `1 + |derivative|` (0 for a system without them).
fn effect_derivative_error<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(sys: &Sys) -> f64 {
    let mut seed = 11u64;
    let mut next = move || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let mut worst = 0.0f64;
    let mut track = |exact: f64, approx: f64| worst = worst.max((exact - approx).abs() / (1.0 + exact.abs()));
    let e = 1e-3;
    let diff4 = |f: &dyn Fn(f64) -> Vector<N>| {
        (f(-2.0 * e) * (1.0 / 12.0) - f(-e) * (8.0 / 12.0) + f(e) * (8.0 / 12.0) - f(2.0 * e) * (1.0 / 12.0)) / e
    };
    for _ in 0..20 {
        let t = next();
        let q = Vector::<N>::from_fn(|_, _| 0.8 * next());
        let v = Vector::<N>::from_fn(|_, _| next() + 0.3);
        let psi = Vector::<M>::from_fn(|_, _| next());
        if Sys::HAS_FORCING {
            let (f, fq, fv) = sys.external_force_jacobians(t, &q, &v);
            (0..N).for_each(|i| track(f[i], sys.external_force(t, &q, &v)[i]));
            for j in 0..N {
                let along_q = diff4(&|d| {
                    sys.external_force(t, &(q + Vector::<N>::from_fn(|i, _| d * f64::from(u8::from(i == j)))), &v)
                });
                let along_v = diff4(&|d| {
                    sys.external_force(t, &q, &(v + Vector::<N>::from_fn(|i, _| d * f64::from(u8::from(i == j)))))
                });
                (0..N).for_each(|i| {
                    track(fq[(i, j)], along_q[i]);
                    track(fv[(i, j)], along_v[i]);
                });
            }
        }
        if Sys::HAS_NONIDEAL_FORCE {
            let jac = sys.nonideal_force_jacobians(t, &q, &v, &psi);
            (0..N).for_each(|i| track(jac.value[i], sys.nonideal_force(t, &q, &v, &psi)[i]));
            let unit = |j: usize, d: f64| Vector::<N>::from_fn(|i, _| d * f64::from(u8::from(i == j)));
            for j in 0..N {
                let along_q = diff4(&|d| sys.nonideal_force(t, &(q + unit(j, d)), &v, &psi));
                let along_v = diff4(&|d| sys.nonideal_force(t, &q, &(v + unit(j, d)), &psi));
                (0..N).for_each(|i| {
                    track(jac.q[(i, j)], along_q[i]);
                    track(jac.v[(i, j)], along_v[i]);
                });
            }
            for j in 0..M {
                let along_psi = diff4(&|d| {
                    sys.nonideal_force(t, &q, &v, &(psi + Vector::<M>::from_fn(|i, _| d * f64::from(u8::from(i == j)))))
                });
                (0..N).for_each(|i| track(jac.psi[(i, j)], along_psi[i]));
            }
        }
    }
    worst
}

/// Every block of the stage Jacobians, the time derivatives, the energy and
/// the external and non-ideal force Jacobians against finite differences
/// at 20 random points each. Measured: at most 6.0e-12 (the two mixed
/// constraints) for the stage functions; 1.9e-9 for the friction's `∂N/∂ψ`,
/// the differences' own error on `√(ψ² + δ²)` with `δ = 0.05` (CasADi
/// agrees with the generated derivatives there to 5.3e-15).
#[test]
fn unusual_systems_have_exact_derivatives() {
    let mut failures = Vec::new();
    macro_rules! check {
        ($sys:expr, $n:literal, $m:literal, $t0:expr, $q0:expr, $v0:expr) => {{
            let sys = $sys;
            let name = name_of::<_, $n, $m>(&sys);
            let (stage, effects) = (derivative_error::<_, $n, $m>(&sys), effect_derivative_error::<_, $n, $m>(&sys));
            println!("{name:18} derivative error {stage:.1e}, effects {effects:.1e}");
            // NaN fails too: `!(x <= bound)`.
            if !(stage <= 1e-8 && effects <= 1e-8) {
                failures.push(format!("{name}: stage derivatives {stage:.2e}, effect Jacobians {effects:.2e}"));
            }
        }};
    }
    unusual!(check);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Every Newton mode stops on a step as accurate as the tightly converged
/// one: 11 systems, Gauss s = 1..3, Lobatto IIIA-B and IIIA-B-D s = 2, 3,
/// four modes, 20 steps of h = 0.1 (308 runs) within the 1e-13 a new
/// user's system is promised, in `q₁`, `v₁`, `V` and `μ = hΨ`. Measured:
/// at most 1.10e-14 (the bowl, Gauss s = 1, simplified Newton on the exact
/// matrix); the test prints the largest.
#[test]
fn unusual_steps_equal_the_tight_solve_in_every_newton_mode() {
    let mut results = Vec::new();
    macro_rules! check {
        ($sys:expr, $n:literal, $m:literal, $t0:expr, $q0:expr, $v0:expr) => {{
            let sys = $sys;
            let start = start::<_, $n, $m>(&sys, $t0, $q0, $v0);
            macro_rules! tight {
                ($method:expr, $s:literal) => {
                    results.extend(against_tight::<_, $n, $m, $s, { $s * ($n + $m) + $n }>(
                        &EVERY_MODE,
                        &sys,
                        $method,
                        &start,
                        0.1,
                        20,
                    ))
                };
            }
            tight!(Method::Gauss, 1);
            tight!(Method::Gauss, 2);
            tight!(Method::Gauss, 3);
            tight!(Method::LobattoIIIAB, 2);
            tight!(Method::LobattoIIIAB, 3);
            tight!(Method::LobattoIIIABD, 2);
            tight!(Method::LobattoIIIABD, 3);
        }};
    }
    unusual!(check);
    let mut failures = Vec::new();
    let worst = tally_against_tight(&results, &mut failures);
    println!("{} runs of 20 steps, largest distance {:.2e} ({})", results.len(), worst.0, worst.1);
    assert!(failures.is_empty(), "{} of {} runs:\n{}", failures.len(), results.len(), failures.join("\n"));
}

#[test]
fn structure_facts_of_unusual_systems() {
    use ConstraintForm::*;
    let facts = [
        (<MagneticSkate as NonholonomicSystem<3, 1>>::STRUCTURE, false, true, Linear),
        (<QuadCross as NonholonomicSystem<3, 1>>::STRUCTURE, true, false, Nonlinear),
        (<Relativistic as NonholonomicSystem<2, 1>>::STRUCTURE, true, false, Affine),
        (<QuarticKinetic as NonholonomicSystem<2, 0>>::STRUCTURE, false, true, None),
        (<DrivenDuffing as NonholonomicSystem<1, 0>>::STRUCTURE, false, true, None),
        (<FrictionSleigh as NonholonomicSystem<3, 1>>::STRUCTURE, true, true, Linear),
        (<MixedTwo as NonholonomicSystem<4, 2>>::STRUCTURE, true, false, Nonlinear),
        (<BowlFree as NonholonomicSystem<3, 1>>::STRUCTURE, true, false, Affine),
        (<FullyConstrained as NonholonomicSystem<2, 2>>::STRUCTURE, true, false, Affine),
        (<OddNames as NonholonomicSystem<3, 1>>::STRUCTURE, true, true, Nonlinear),
    ];
    for (i, (s, lagrangian_autonomous, constraints_autonomous, form)) in facts.into_iter().enumerate() {
        assert_eq!(
            (s.lagrangian_autonomous, s.constraints_autonomous, s.constraint_form),
            (lagrangian_autonomous, constraints_autonomous, form),
            "entry {i}"
        );
    }
    const {
        assert!(DrivenDuffing::HAS_FORCING && !DrivenDuffing::HAS_NONIDEAL_FORCE);
        assert!(FrictionSleigh::HAS_FORCING && FrictionSleigh::HAS_NONIDEAL_FORCE);
        assert!(BowlDragged::HAS_FORCING && BowlDragged::HAS_NONIDEAL_FORCE && BowlDragged::HAS_HOLONOMIC);
        assert!(!BowlFree::HAS_FORCING && BowlFree::HAS_HOLONOMIC);
        assert!(!<QuadCross as NonholonomicSystem<3, 1>>::STRUCTURE.constant_mass_matrix);
        assert!(<MagneticSkate as NonholonomicSystem<3, 1>>::STRUCTURE.constant_mass_matrix);
    }
}

/// A step whose equations turn NaN because a function of the declaration
/// left its domain says so, beside the overflow a smaller `h` cures: the
/// relativistic Lagrangian is undefined beyond `|v| = c`, where the
/// starting guess of a step from `|v0| = 0.9997 c` lands, and the friction
/// `√(ψ² + δ²)` with `δ = 0` has no derivative at `ψ = 0`, where a sleigh at
/// rest starts.
#[test]
fn non_finite_steps_name_functions_outside_their_domain() {
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let project = RunOptions { consistency: ConsistencyPolicy::Project { tolerance: 1e-12 }, ..RunOptions::default() };
    let mut st = Stepper::<Relativistic, 2, 1, 2, 8>::new(Relativistic::default(), tab);
    let (q0, v0) = (Vector::<2>::zeros(), Vector::<2>::new(2.999, 0.0));
    let schedule = Schedule::Fixed { h: 0.5, steps: 4 };
    let relativistic = st.integrate(0.0, &q0, &v0, schedule, &project, &mut NoObserver).unwrap_err().to_string();
    let sleigh = FrictionSleigh { delta: 0.0, ..FrictionSleigh::default() };
    let mut st = Stepper::<FrictionSleigh, 3, 1, 2, 11>::new(sleigh, tab);
    let schedule = Schedule::Fixed { h: 0.1, steps: 4 };
    let at_rest = Vector::<3>::zeros();
    let friction = st.integrate(0.0, &at_rest, &at_rest, schedule, &RunOptions::default(), &mut NoObserver);
    let friction = friction.unwrap_err().to_string();
    for message in [relativistic, friction] {
        assert!(message.contains("non-finite value in the"), "{message}");
        assert!(message.contains("outside its domain") && message.contains("derivative is undefined"), "{message}");
        assert!(message.contains("overflowed f64") && message.contains("reduce h"), "{message}");
    }
}

/// Simplified Newton stops on a contraction rate measured on two pairs of
/// updates, which underestimates the contraction of the multipliers here:
/// a cold Lobatto IIIA-B s = 3 step of the odd-names system at h = 0.25
/// stops after three updates (the last 3.9e-11, ratio 3.8e-5) with μ = hΨ
/// still 1.15e-13 from the tight solution (the remaining error contracts
/// at about 3e-3 per update). Above the 1e-13 a new user's system is
/// promised; the stopping rule lives in `step/`.
#[test]
fn simplified_newton_does_not_stop_on_an_underestimated_rate() {
    let sys = OddNames::default();
    let q0 = Vector::<3>::new(-0.08150560334434104, 0.6155296621717985, 0.11617481806176455);
    let v0 = Vector::<3>::new(0.5299970866203481, 0.48778908712804014, -0.37516167340940443);
    let s = State::new(0.1, q0, v0);
    assert!(sys.constraint(s.t, &s.q, &s.v).amax() <= 1e-16);
    let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
    let opts = NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Exact, ..NewtonOptions::default() };
    let mut stepper = Stepper::<OddNames, 3, 1, 3, 15>::new(sys, tab).with_options(opts);
    let tight = NewtonOptions { tolerance: 0.0, max_iterations: HISTORY_CAPACITY, ..NewtonOptions::default() };
    let mut reference = Stepper::<OddNames, 3, 1, 3, 15>::new(sys, tab).with_options(tight);
    let (a, b) = (stepper.step(&s, 0.25).unwrap(), reference.step(&s, 0.25).unwrap());
    let d = step_distance(&a, &b, 0.25);
    assert!(d <= 1e-13, "{d:.3e} from the tight solve after {} updates", a.iterations);
}

/// A warm-started simplified Newton iteration can end on another root of
/// the step's equations: the bead in the breathing bowl, Lobatto IIIA-B-D
/// s = 2 at h = 0.25, whose fifth step starts from a poor extrapolated
/// guess (first update 7.5): an iteration that diverges, refreshes its
/// matrix at the diverged iterate and converges there reaches
/// `v₁ ≈ (2.9, −4.2, 10.2)`; full Newton from the same guess, every cold
/// start and 64 steps of h/64 give `v₁ ≈ (0.38, −0.48, −0.72)`. Returned,
/// that step would be a success on the wrong root: the step must equal the
/// tight solve or be refused. The iteration lives in `step/`.
#[test]
fn simplified_newton_does_not_return_a_spurious_root() {
    let sys = BowlFree::default();
    let q0 = Vector::<3>::new(0.9585428635301182, -0.533472700675945, 0.437202712236974);
    let v0 = Vector::<3>::new(-0.027643798079252612, 0.11523727336165868, -0.004761279502337668);
    let mut s = State::new(0.4, q0, v0);
    assert!(sys.constraint(s.t, &s.q, &s.v).amax() <= 1e-16);
    let tab = Tableau::<2>::new(Method::LobattoIIIABD).unwrap();
    for jacobian in [Jacobian::Exact, Jacobian::StageDecoupled] {
        let opts = NewtonOptions { mode: NewtonMode::Simplified, jacobian, ..NewtonOptions::default() };
        let mut stepper = Stepper::<BowlFree, 3, 1, 2, 11>::new(sys, tab).with_options(opts);
        let h = 0.25;
        for _ in 0..4 {
            s = stepper.step(&s, h).unwrap().state;
        }
        let mut tight = stepper.clone();
        let o = tight.options_mut();
        (o.mode, o.jacobian, o.tolerance, o.max_iterations) = (NewtonMode::Full, Jacobian::Auto, 0.0, HISTORY_CAPACITY);
        let b = tight.step(&s, h).unwrap();
        // Refusing the step (the driver then retries from the cold guess) is fine.
        if let Ok(a) = stepper.step(&s, h) {
            let d = step_distance(&a, &b, h);
            assert!(d <= 1e-13, "{jacobian:?}: v1 = {} against {}, {d:.3e} apart", a.state.v, b.state.v);
        }
        s = State::new(0.4, q0, v0);
    }
}

/// A guess extrapolated across steps can be too far off for Newton where
/// the solution turns on the scale of `h`: the two mixed constraints at
/// h = 0.25, whose velocity `(q̇₁, q̇₂)` turns by about 0.4 rad a step near
/// t = 3.3. There every Newton mode diverges from the extrapolated guess of
/// Lobatto IIIA-B-D s = 2 and s = 3 (the second update larger than the
/// first, the residual growing from 0.83 to 6.5), and again from the guess
/// of degree 3, where Newton from the consistent acceleration at the step's
/// start converges in five updates (as does Gauss s = 1 at t = 9.55).
/// Every mode's steps, over 40 steps, equal the tight solve's.
#[test]
fn a_step_whose_extrapolated_guess_diverges_is_solved_from_the_cold_one() {
    let sys = MixedTwo::default();
    let start = start::<_, 4, 2>(&sys, 0.3, [0.2, -0.1, 0.3, 0.1], [0.6, 0.7, 0.2, 0.1]);
    let mut results = Vec::new();
    results.extend(against_tight::<_, 4, 2, 1, 10>(&EVERY_MODE, &sys, Method::Gauss, &start, 0.25, 40));
    results.extend(against_tight::<_, 4, 2, 2, 16>(&EVERY_MODE, &sys, Method::LobattoIIIABD, &start, 0.25, 40));
    results.extend(against_tight::<_, 4, 2, 3, 22>(&EVERY_MODE, &sys, Method::LobattoIIIABD, &start, 0.25, 40));
    let failures: Vec<String> = results
        .iter()
        .filter_map(|(label, r)| match r {
            Ok(d) if *d <= 1e-13 => None,
            Ok(d) => Some(format!("{label}: {d:.3e} from the tight solve")),
            Err(e) => Some(format!("{label}: {e}")),
        })
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
