//! The acceptance of an update along which the step's equations are affine
//! (`convergence::affine_along`): the pairs `nonholonomic_system!` declares
//! are sound — the residual is affine along any update that moves no pair
//! — and steps that end on such an update agree with steps that confirm it.

use super::convergence::AffinePlan;
use crate::fixtures::paper::Particle as HandWrittenParticle;
use crate::{
    nonholonomic_system, Jacobian, Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, StepResult, Stepper,
    Tableau, Vector,
};

nonholonomic_system! {
    /// The skate of §8.2: every curved pair has the heading in it.
    struct AffineSkate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
    }
}

nonholonomic_system! {
    /// A disk rolling on an inclined plane: curved in its heading only.
    struct AffineDisk {
        coordinates: [x, y, theta, phi],
        parameters: { m = 1.0, r = 0.5, g = 9.81, alpha = 0.3 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + m*r^2/4*dot(theta)^2 + m*r^2/2*dot(phi)^2 + m*g*x*sin(alpha),
        constraints: [
            dot(x) - r*cos(theta)*dot(phi),
            dot(y) - r*sin(theta)*dot(phi),
        ],
    }
}

nonholonomic_system! {
    /// Coupled oscillators under a constant linear constraint: affine
    /// everywhere (no pairs).
    struct LinearOscillators {
        coordinates: [x, y, z],
        parameters: { k = 2.0, c = 0.3 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + k*y^2 + z^2)/2 - c*x*y,
        constraints: [ dot(z) - dot(x) + 0.5*dot(y) ],
    }
}

nonholonomic_system! {
    /// The particle of §8.1: `k = ż − y ẋ` curves the pairs (x, y) and
    /// (y, ψ).
    struct AffineParticle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

nonholonomic_system! {
    /// Time-dependent, forced, with a non-ideal force and a constraint
    /// nonlinear in `v`: the pairs must cover all of it.
    struct CurvedEverywhere {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 0.5, mu = 0.2 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + cos(t)*x - y*dot(x)*0.1,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) + 0.05*dot(y)^2 ],
        forces: { theta: 0.3*sin(t)*dot(theta), x: -0.1*dot(x)*x },
        nonideal_forces: { y: -mu*psi[0]*dot(y) },
    }
}

/// The groups of a step's unknown `i` (`z = [V | μ | v₁]`): coordinate `c`
/// or constraint `N + j`.
fn group_of<const N: usize, const M: usize, const S: usize>(i: usize) -> usize {
    if i < S * N {
        i % N
    } else if i < S * (N + M) {
        N + (i - S * N) % M
    } else {
        i - S * (N + M)
    }
}

/// `|G(z + Δ) − G(z) − J(z)Δ|∞` for `Δ` nonzero only on the unknowns of
/// `groups`.
fn remainder<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    st: &mut Stepper<Sys, N, M, S, D>,
    state: &State<N>,
    h: f64,
    groups: &[usize],
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let z = crate::tests::probe::<D>();
    let (g, jac) = st.residual_and_jacobian(state, h, &z);
    let delta = Vector::<D>::from_fn(|i, _| {
        if groups.contains(&group_of::<N, M, S>(i)) {
            0.2 - 0.07 * ((i * 5 + 1) % 7) as f64
        } else {
            0.0
        }
    });
    (st.residual_at(state, h, &(z + delta)) - g - jac * delta).amax()
}

/// For every group that the pairs do not curve by itself, the largest set
/// of groups around it with no pair inside (greedy): the residual must be
/// affine along updates on it. And the residual must be curved along some
/// pair, so that the check above can see a missing one.
fn check_soundness<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    state: State<N>,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M>,
{
    let pairs = Sys::NONLINEARITY.expect("the macro declares the nonlinearity").pairs;
    let paired = |a: usize, b: usize| pairs.contains(&(a.min(b) as u32, a.max(b) as u32));
    let name = Sys::SOURCE.name;
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    for start in (0..N + M).filter(|&a| !paired(a, a)) {
        let mut set = vec![start];
        for b in 0..N + M {
            if !set.contains(&b) && !paired(b, b) && set.iter().all(|&a| !paired(a, b)) {
                set.push(b);
            }
        }
        let r = remainder(&mut st, &state, h, &set);
        assert!(r <= 1e-13, "{name} {method} s = {S}: curved along {set:?} ({r:e}) though no pair says so");
    }
    if let Some(&(a, b)) = pairs.first() {
        let r = remainder(&mut st, &state, h, &[a as usize, b as usize]);
        assert!(r > 1e-8, "{name} {method} s = {S}: pair ({a}, {b}) is declared but not curved ({r:e})");
    }
}

#[test]
fn declared_pairs_leave_the_residual_affine_elsewhere() {
    let s0 = State::new(0.3, Vector::<3>::new(0.1, 0.2, 0.7), Vector::<3>::new(0.3, 0.1, 1.0));
    let d0 = State::new(0.0, Vector::<4>::new(0.1, 0.2, 0.7, 0.3), Vector::<4>::new(0.5, 0.2, 0.5, 1.0));
    for method in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
        check_soundness::<_, 3, 1, 2, 11>(AffineSkate::default(), method, s0, 0.1);
        check_soundness::<_, 3, 1, 3, 15>(AffineSkate::default(), method, s0, 0.1);
        check_soundness::<_, 4, 2, 2, 16>(AffineDisk::default(), method, d0, 0.1);
        check_soundness::<_, 3, 1, 2, 11>(AffineParticle::default(), method, s0, 0.2);
        check_soundness::<_, 3, 1, 3, 15>(CurvedEverywhere::default(), method, s0, 0.1);
    }
    check_soundness::<_, 3, 1, 1, 7>(AffineSkate::default(), Method::Gauss, s0, 0.1);
    check_soundness::<_, 3, 1, 2, 11>(AffineSkate::default(), Method::ModifiedLobattoIIIAB, s0, 0.1);
    check_soundness::<_, 3, 1, 2, 11>(AffineSkate::default(), Method::LobattoIIIBALda, s0, 0.1);
    // No pairs: the residual is affine in every unknown at once.
    assert!(LinearOscillators::NONLINEARITY.unwrap().pairs.is_empty());
    let mut st = Stepper::<_, 3, 1, 2, 11>::new(LinearOscillators::default(), Tableau::new(Method::Gauss).unwrap());
    let r = remainder(&mut st, &s0, 0.2, &[0, 1, 2, 3]);
    assert!(r <= 1e-13, "{r:e}");
}

/// The pairs the macro reads off the skate's and the particle's Jacobians.
#[test]
fn the_pairs_of_the_paper_systems() {
    let skate = AffineSkate::NONLINEARITY.unwrap();
    assert_eq!(skate.pairs, &[(0, 2), (1, 2), (2, 2), (2, 3)]);
    assert_eq!((skate.stiffness_columns, skate.constraint_force_columns), (&[][..], &[2][..]));
    let particle = AffineParticle::NONLINEARITY.unwrap();
    assert_eq!(particle.pairs, &[(0, 1), (1, 3)]);
    assert_eq!((particle.stiffness_columns, particle.constraint_force_columns), (&[0, 1][..], &[1][..]));
    // The heading's, and `y`'s, rows are affine and their own.
    assert!(skate.closed_affine_cover && particle.closed_affine_cover);
    assert!(AffineDisk::NONLINEARITY.unwrap().closed_affine_cover);
    // `−0.1 ẋ x` curves `x` by itself, and `x`'s rows reach `θ` and `ψ`.
    assert!(!CurvedEverywhere::NONLINEARITY.unwrap().closed_affine_cover);
    // A hand-written system claims nothing.
    assert!(HandWrittenParticle::NONLINEARITY.is_none());
}

/// Largest scaled distance (`|a − b|/(1 + |b|)`) of `q₁`, `v₁` and `μ = hΨ`.
fn distance<const N: usize, const M: usize, const S: usize>(
    a: &StepResult<N, M, S>,
    b: &StepResult<N, M, S>,
    h: f64,
) -> f64 {
    let scaled = |x: f64, y: f64| (x - y).abs() / (1.0 + y.abs());
    let states = a.state.q.iter().zip(b.state.q.iter()).chain(a.state.v.iter().zip(b.state.v.iter()));
    let mu = (0..S).flat_map(|i| a.stage_multipliers[i].iter().zip(b.stage_multipliers[i].iter()));
    states.map(|(x, y)| scaled(*x, *y)).chain(mu.map(|(x, y)| scaled(h * x, h * y))).fold(0.0, f64::max)
}

/// Runs `steps` default steps in each Newton mode; before each, solves the
/// same step (same stepper state, so the same starting guess) with every
/// update confirmed, to the round-off floor. Returns, per mode, the largest
/// scaled distance and the steps that ended on their first update and on
/// their first two.
fn against_confirmed<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> Vec<(NewtonMode, Jacobian, f64, [usize; 2])>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let modes = [
        (NewtonMode::Full, Jacobian::Auto),
        (NewtonMode::Simplified, Jacobian::Exact),
        (NewtonMode::Simplified, Jacobian::StageDecoupled),
    ];
    let mut out = Vec::new();
    for (mode, jacobian) in modes {
        let opts = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
        let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap()).with_options(opts);
        let (mut s, mut worst, mut few) = (start, 0.0f64, [0, 0]);
        for _ in 0..steps {
            let mut reference = st.clone();
            reference.always_confirm = true;
            reference.options_mut().tolerance = 0.0;
            reference.options_mut().max_iterations = crate::error::HISTORY_CAPACITY;
            let b = reference.step(&s, h).unwrap();
            let a = st.step(&s, h).unwrap();
            worst = worst.max(distance(&a, &b, h));
            few[0] += usize::from(a.iterations == 1);
            few[1] += usize::from(a.iterations <= 2);
            s = a.state;
        }
        out.push((mode, jacobian, worst, few));
    }
    out
}

/// Steps that end on an update along which the equations are affine agree
/// with the confirmed, tightly converged steps within 1e-14, in every
/// Newton mode, for Gauss s = 1..4 and Lobatto IIIA-B s = 2..4; on the
/// skate and the rolling disk (heading rate constant, so the guess is
/// exact in the only curved group) nearly every step ends on its first
/// update, on the linear oscillators every step does, and on the particle
/// nearly every step ends on its second in full Newton and on the
/// stage-decoupled matrix (which refresh after the first update), where
/// simplified Newton on the exact matrix, which does not, takes three.
#[test]
fn affine_updates_agree_with_confirmed_steps() {
    let mut failures = Vec::new();
    macro_rules! check {
        ($name:literal, $sys:expr, $start:expr, $h:expr, $n:literal, $m:literal, $min_few:expr) => {
            // `(method, s, results)` for one method and stage count.
            macro_rules! run {
                ($method:expr, $s:literal) => {
                    (
                        $method,
                        $s,
                        against_confirmed::<_, $n, $m, $s, { $s * ($n + $m) + $n }>($sys, $method, $start, $h, 20),
                    )
                };
            }
            let runs = [
                run!(Method::Gauss, 1),
                run!(Method::Gauss, 2),
                run!(Method::Gauss, 3),
                run!(Method::Gauss, 4),
                run!(Method::LobattoIIIAB, 2),
                run!(Method::LobattoIIIAB, 3),
                run!(Method::LobattoIIIAB, 4),
            ];
            for (method, s, results) in runs {
                for ((mode, jacobian, worst, few), [min_one, min_two]) in results.into_iter().zip($min_few) {
                    if worst > 1e-14 || worst.is_nan() || few[0] < min_one || few[1] < min_two {
                        failures.push(format!(
                            "{} {method} s = {s} {mode:?}/{jacobian:?}: {worst:.2e}, {} of 20 on one update, {} on two",
                            $name, few[0], few[1]
                        ));
                    }
                }
            }
        };
    }
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    check!("skate", AffineSkate::default(), s0, 0.1, 3, 1, [[15, 20]; 3]);
    let d0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(0.5, 0.0, 0.8, 1.0));
    check!("disk", AffineDisk::default(), d0, 0.1, 4, 2, [[15, 20]; 3]);
    // The stage-decoupled matrix keeps the constant stiffness: it is the
    // exact matrix here.
    let o0 = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(0.2, 0.4, 0.0));
    check!("oscillators", LinearOscillators::default(), o0, 0.2, 3, 1, [[20, 20]; 3]);
    // Curved in `y`, whose rows (`ÿ = −2y`) are affine and its own: the
    // first update solves `y`, the second, on factors evaluated there (full
    // Newton; the stage-decoupled matrix refreshes for it), lands on the
    // solution. Simplified Newton on the exact matrix keeps its factors.
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    check!("particle", AffineParticle::default(), p0, 0.2, 3, 1, [[0, 18], [0, 0], [0, 18]]);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Factorizations and updates of every step after the first of a run
/// `steps` long, on the stage-decoupled matrix.
fn work_per_step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    start: State<N>,
    h: f64,
    steps: usize,
) -> (Vec<usize>, Vec<usize>)
where
    Sys: NonholonomicSystem<N, M>,
{
    let opts = NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::StageDecoupled, ..Default::default() };
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(Method::Gauss).unwrap()).with_options(opts);
    let (mut s, mut factorizations, mut updates) = (start, Vec::new(), Vec::new());
    for i in 0..steps {
        let r = st.step(&s, h).unwrap();
        if i > 0 {
            factorizations.push(r.factorizations);
            updates.push(r.iterations);
        }
        s = r.state;
    }
    (factorizations, updates)
}

/// The particle's first update moves its curved pair `(x, y)` at every
/// step: each step after the first starts from the factors its predecessor
/// refreshed after that update (`Stepper::starts_stale`), and factors once,
/// not twice, still ending on its second update. The skate's first updates
/// land: its steps keep factoring at their guess and end on one update.
#[test]
fn a_closed_affine_cover_starts_from_the_refreshed_factors() {
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let (factorizations, updates) = work_per_step::<_, 3, 1, 2, 11>(AffineParticle::default(), p0, 0.2, 20);
    assert!(factorizations.iter().all(|&f| f == 1), "particle: {factorizations:?} factorizations");
    assert!(updates.iter().all(|&u| u == 2), "particle: {updates:?} updates");
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let (factorizations, updates) = work_per_step::<_, 3, 1, 2, 11>(AffineSkate::default(), s0, 0.1, 20);
    assert!(factorizations.iter().all(|&f| f == 1), "skate: {factorizations:?} factorizations");
    assert!(updates.iter().filter(|&&u| u == 1).count() >= 15, "skate: {updates:?} updates");
}

/// [`AffinePlan`]'s reading of the pairs and columns — each required group
/// once, then the pairs none of them holds — against the pairs and columns
/// read one by one (the plan of a system beyond 64 groups), for every set
/// of moved groups of these systems, on all three matrices.
fn check_plan<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const S: usize, const D: usize>() {
    let nonlinearity = Sys::NONLINEARITY.expect("declared systems carry their pairs");
    let groups = N + M;
    for (decoupled, kept) in [(false, false), (true, false), (true, true)] {
        let plan = AffinePlan::new::<N, M>(&nonlinearity, decoupled, kept);
        let pair_by_pair = AffinePlan::new::<65, 0>(&nonlinearity, decoupled, kept);
        assert_ne!(plan, pair_by_pair);
        for moved in 0u64..1 << groups {
            let moved_at = |i: usize| (moved >> group_of::<N, M, S>(i)) & 1 == 1;
            assert_eq!(
                super::convergence::affine_along_by::<N, M, S>(moved_at, &nonlinearity, &plan),
                super::convergence::affine_along_by::<N, M, S>(moved_at, &nonlinearity, &pair_by_pair),
                "{} moved groups {moved:b}, decoupled {decoupled}, stiffness kept {kept}",
                std::any::type_name::<Sys>(),
            );
        }
        // Eight lanes at once, each with its own set of moved groups (the
        // sets in turn, and the lane kernel's early end when every lane
        // moved a required group).
        let lanes = 1u64 << groups;
        for first in 0..lanes {
            let sets: [u64; 8] = std::array::from_fn(|w| (first + w as u64 * 5) % lanes);
            let moved_at =
                |i: usize| -> [bool; 8] { std::array::from_fn(|w| (sets[w] >> group_of::<N, M, S>(i)) & 1 == 1) };
            let together = super::convergence::affine_along_lanes::<N, M, S, 8>(moved_at, &nonlinearity, &plan);
            for (w, set) in sets.iter().enumerate() {
                let alone = |i: usize| (set >> group_of::<N, M, S>(i)) & 1 == 1;
                assert_eq!(
                    together[w],
                    super::convergence::affine_along_by::<N, M, S>(alone, &nonlinearity, &plan),
                    "{} lane {w}, moved groups {set:b}, decoupled {decoupled}, stiffness kept {kept}",
                    std::any::type_name::<Sys>(),
                );
            }
        }
    }
}

#[test]
fn the_affine_plan_reads_the_pairs_as_they_are() {
    check_plan::<AffineSkate, 3, 1, 2, 11>();
    check_plan::<AffineDisk, 4, 2, 3, 22>();
    check_plan::<LinearOscillators, 3, 1, 1, 7>();
    check_plan::<AffineParticle, 3, 1, 2, 11>();
    check_plan::<CurvedEverywhere, 3, 1, 2, 11>();
}
