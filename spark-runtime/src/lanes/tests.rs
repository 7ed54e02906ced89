//! Every lane against its member stepped alone, bit for bit; failures that
//! stay in their lane; the requests a lane group refuses.

use super::*;
use crate::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use crate::{
    Jacobian, Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, StepError, Stepper, Tableau, Vector,
};

/// The settings of the paper's Fig. 8.4: simplified Newton, the matrix
/// chosen by the structure facts (stage-decoupled for these systems).
fn fig84() -> NewtonOptions {
    NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Auto, ..NewtonOptions::default() }
}

/// The member `start` stepped alone by its own stepper as `integrate`
/// steps it (a failed step retried cold and halved), with `t` pinned to
/// `t₀ + k·h` after every step and sampled as [`integrate_ensemble`]
/// samples.
fn solo<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: &Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    start: State<N>,
    h: f64,
    steps: usize,
    every: usize,
) -> EnsembleRun<N>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(system.clone(), tableau).with_options(options);
    let mut run =
        EnsembleRun { samples: vec![start], steps: 0, iterations: 0, recovery: LaneRecovery::default(), failure: None };
    let mut s = start;
    for k in 0..steps {
        let t_target = start.t + (k + 1) as f64 * h;
        match st.scheduled_step(&s, h, t_target, crate::DEFAULT_MAX_HALVINGS) {
            Ok(counts) => {
                s = State { t: t_target, ..counts.state };
                st.retarget_warm_start(&s);
                run.steps = k + 1;
                run.iterations += counts.iterations;
                run.recovery.count(&counts);
                if k + 1 == steps || (every != 0 && (k + 1) % every == 0) {
                    run.samples.push(s);
                }
            }
            Err(error) => {
                run.failure = Some(LaneFailure { step: k, t: s.t, error });
                break;
            }
        }
    }
    run
}

/// Whether two runs agree bit for bit (failures compared by their debug
/// text, which holds every number of the Newton history, NaN included).
fn assert_same<const N: usize>(lane: &EnsembleRun<N>, alone: &EnsembleRun<N>, what: &str) {
    let bits = |s: &State<N>| (s.t.to_bits(), s.q.map(f64::to_bits), s.v.map(f64::to_bits));
    assert_eq!(lane.steps, alone.steps, "{what}: steps");
    assert_eq!(lane.iterations, alone.iterations, "{what}: Newton iterations");
    assert_eq!(lane.recovery, alone.recovery, "{what}: recovery");
    assert_eq!(lane.samples.len(), alone.samples.len(), "{what}: samples");
    for (k, (a, b)) in lane.samples.iter().zip(&alone.samples).enumerate() {
        assert!(bits(a) == bits(b), "{what}: sample {k}: {a:?} in the lane, {b:?} alone");
    }
    assert_eq!(format!("{:?}", lane.failure), format!("{:?}", alone.failure), "{what}: failure");
}

/// Runs `starts` as one ensemble and every member alone; all must agree.
#[allow(clippy::too_many_arguments)]
fn compare<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: Sys,
    method: Method,
    options: NewtonOptions,
    starts: &[State<N>],
    h: f64,
    steps: usize,
    every: usize,
) -> Vec<EnsembleRun<N>>
where
    Sys: NonholonomicSystem<N, M> + Clone + Send + Sync,
{
    let tab = Tableau::<S>::new(method).unwrap();
    let runs = integrate_ensemble::<Sys, N, M, S, D>(&system, tab, options, starts, h, steps, every).unwrap();
    assert_eq!(runs.len(), starts.len());
    for (j, (run, start)) in runs.iter().zip(starts).enumerate() {
        let alone = solo::<Sys, N, M, S, D>(&system, tab, options, *start, h, steps, every);
        assert_same(run, &alone, &format!("{} {method} s={S} member {j}", Sys::SOURCE.name));
    }
    runs
}

/// The members `starts` of one lane group of eight, Gauss s = 2, stepped
/// 20 times in every build of the kernel (the baseline, AVX2 and AVX-512
/// where the CPU has them): each member's end state must be bit for bit
/// its solo run's. Returns, per build, the steps the kernel took of each
/// member.
fn every_build_bit_for_bit<Sys>(sys: Sys, starts: &[State<3>], h: f64) -> Vec<(super::kernel::Simd, Vec<usize>)>
where
    Sys: NonholonomicSystem<3, 1> + Clone,
{
    use super::kernel::Simd;
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let alone: Vec<_> = starts.iter().map(|s| solo::<_, 3, 1, 2, 11>(&sys, tab, fig84(), *s, h, 20, 0)).collect();
    let mut kernel_steps = Vec::new();
    for simd in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
        let mut lanes = LaneStepper::<_, 3, 1, 2, 11, 8>::new(sys.clone(), tab, fig84()).with_simd(simd);
        lanes.start(starts, h).unwrap();
        lanes.advance_by(20);
        for (j, run) in alone.iter().enumerate() {
            let (lane, solo) = (lanes.state(j).unwrap(), run.samples.last().unwrap());
            let bits = |s: &State<3>| (s.t.to_bits(), s.q.map(f64::to_bits), s.v.map(f64::to_bits));
            assert!(bits(lane) == bits(solo), "{simd:?}, member {j}: {lane:?} in the lane, {solo:?} alone");
        }
        kernel_steps.push((simd, (0..starts.len()).map(|j| lanes.kernel_steps(j).unwrap()).collect()));
    }
    kernel_steps
}

/// A constant stiffness (the particle's `U = q₁² + q₂²`) couples the
/// stages of the stage-decoupled matrix coordinate by coordinate: the
/// kernel keeps the couplings as the steppers do, takes every step after
/// the two that start the extrapolation, and each member is bit for bit its
/// solo run.
#[test]
fn constant_stiffness_members_in_lanes_match_each_member_alone() {
    let starts: Vec<_> = (0..5)
        .map(|j| State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0 + 0.1 * j as f64, 0.0)))
        .collect();
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        let runs = compare::<_, 3, 1, 2, 11>(Particle, method, fig84(), &starts, 0.2, 200, 50);
        assert!(runs.iter().all(|r| r.failure.is_none() && r.samples.len() == 5), "{method}");
    }
    let runs = compare::<_, 3, 1, 4, 19>(Particle, Method::Gauss, fig84(), &starts, 0.2, 200, 0);
    assert!(runs.iter().all(|r| r.failure.is_none()));
    // Every build of the kernel (the solve of the stage blocks runs in it).
    for (simd, kernel_steps) in every_build_bit_for_bit(Particle, &starts, 0.2) {
        assert!(kernel_steps.iter().all(|&k| k == 18), "{simd:?}: {kernel_steps:?} steps in the kernel");
    }
}

crate::nonholonomic_system! {
    /// The particle of §8.1, declared: curved only in `y`, whose rows
    /// (`ÿ = −2y`) are affine and its own (a closed affine cover).
    struct DeclaredParticle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

/// A declared system whose first update solves a closed affine cover
/// (`y`): a member whose `y` moves needs a second update on factors
/// refreshed after the first, and its stepper starts every next step from
/// those factors (`Stepper::starts_stale`), which the kernel does not
/// hold: it steps alone. A member at rest in `y` ends each step on its
/// first update (`step::affine_along`), in the kernel. Every member is bit
/// for bit its solo run, iteration counts included, in every build of the
/// kernel.
#[test]
fn a_closed_affine_cover_in_lanes_steps_as_alone() {
    assert!(DeclaredParticle::NONLINEARITY.is_some_and(|n| n.closed_affine_cover));
    let at_rest_in_y = |j: usize| j.is_multiple_of(2);
    let starts: Vec<_> = (0..6)
        .map(|j| {
            let (y, u) = if at_rest_in_y(j) { (0.0, 0.0) } else { (0.2 * j as f64, 1.0 - 0.1 * j as f64) };
            State::new(0.0, Vector::<3>::new(1.0, y, 0.0), Vector::<3>::new(0.3, u, 0.3 * y))
        })
        .collect();
    let sys = DeclaredParticle::default();
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        let runs = compare::<_, 3, 1, 2, 11>(sys, method, fig84(), &starts, 0.2, 100, 25);
        for run in &runs {
            let updates = run.iterations as f64 / run.steps as f64;
            assert!(run.failure.is_none() && updates <= 2.2, "{method}: {updates} updates per step");
        }
    }
    compare::<_, 3, 1, 1, 7>(sys, Method::Gauss, fig84(), &starts, 0.2, 100, 0);
    compare::<_, 3, 1, 3, 15>(sys, Method::Gauss, fig84(), &starts, 0.2, 100, 0);
    for (simd, kernel_steps) in every_build_bit_for_bit(sys, &starts, 0.2) {
        for (j, k) in kernel_steps.into_iter().enumerate() {
            assert_eq!(k, if at_rest_in_y(j) { 18 } else { 0 }, "{simd:?}, member {j}");
        }
    }
}

crate::nonholonomic_system! {
    /// [`DeclaredParticle`] with `y` pushed by a force `sin(t/2)⁶⁰`: a member
    /// starting at rest in `y` stays within round-off of it, and its first
    /// updates land, until the push moves `y`.
    struct PushedParticle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2) + y*sin(t/2)^60,
        constraints: [ dot(z) - y*dot(x) ],
    }
}

/// A member in the kernel whose first update stops landing (the push on
/// `y` of [`PushedParticle`]) goes back to its stepper for that step and
/// the next ones, bit for bit as alone, in every build of the kernel.
#[test]
fn a_closed_affine_cover_that_stops_landing_leaves_the_kernel() {
    assert!(PushedParticle::NONLINEARITY.is_some_and(|n| n.closed_affine_cover));
    let starts: Vec<_> = (0..6)
        .map(|j| State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.3 + 0.1 * j as f64, 0.0, 0.0)))
        .collect();
    for (simd, kernel_steps) in every_build_bit_for_bit(PushedParticle::default(), &starts, 0.2) {
        for (j, k) in kernel_steps.into_iter().enumerate() {
            assert!((1..18).contains(&k), "{simd:?}, member {j}: {k} steps in the kernel");
        }
    }
}

/// McLachlan–Perlmutter starts: the fixed `q₀` with `v₀ = (0, β, 0, …)`
/// (consistent: `k = v₁ + q₅v₅ + q₆v₆ + q₇v₇`).
fn mp_starts(members: usize) -> Vec<State<7>> {
    let q0 = Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    (0..members)
        .map(|j| {
            let mut v0 = Vector::<7>::zeros();
            v0[1] = 0.05 * j as f64;
            State::new(0.0, q0, v0)
        })
        .collect()
}

/// Six members (one full group of four and one of two), 600 steps, the
/// methods of Fig. 8.4 and Gauss s = 3, simplified and full Newton.
#[test]
fn mp_particles_in_lanes_match_each_member_alone() {
    let starts = mp_starts(6);
    for method in [Method::LobattoIIIAB, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
        let runs = compare::<_, 7, 1, 2, 23>(MpParticles, method, fig84(), &starts, 0.05, 600, 100);
        assert!(runs.iter().all(|r| r.failure.is_none() && r.samples.len() == 7), "{method}");
    }
    let full = NewtonOptions::default();
    let runs = compare::<_, 7, 1, 3, 31>(MpParticles, Method::Gauss, full, &starts, 0.05, 600, 0);
    assert!(runs.iter().all(|r| r.failure.is_none() && r.samples.len() == 2));
}

/// The skate (five members) and the mobile robot (nine: two full groups
/// and one of one), several methods and stage counts.
#[test]
fn skate_and_robot_in_lanes_match_each_member_alone() {
    let skate: Vec<_> = (0..5)
        .map(|j| State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.2 * j as f64, 0.0, 1.0 + 0.1 * j as f64)))
        .collect();
    compare::<_, 3, 1, 2, 11>(Skate::default(), Method::Gauss, fig84(), &skate, 0.1, 500, 7);
    compare::<_, 3, 1, 3, 15>(Skate::default(), Method::LobattoIIIAB, NewtonOptions::default(), &skate, 0.1, 500, 7);
    let robot: Vec<_> = (0..9)
        .map(|j| {
            let w = 0.1 * j as f64;
            State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(w, 0.0, 0.5 - 0.05 * j as f64, w))
        })
        .collect();
    compare::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::LobattoIIIABD, fig84(), &robot, 0.2, 400, 50);
    compare::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::Gauss, fig84(), &robot, 0.2, 400, 50);
}

/// A member with an inconsistent start fails its first step alone with
/// the stepper's own error; the other members of its group run on and
/// match their solo runs.
#[test]
fn an_inconsistent_member_fails_alone() {
    let mut starts = mp_starts(5);
    starts[2].v[0] = 0.5; // k = v₁ + … = 0.5
    let runs = compare::<_, 7, 1, 2, 23>(MpParticles, Method::LobattoIIIAB, fig84(), &starts, 0.05, 200, 50);
    for (j, run) in runs.iter().enumerate() {
        match (&run.failure, j) {
            (Some(f), 2) => {
                assert!(f.step == 0 && matches!(f.error, StepError::InconsistentStart { .. }), "{f}");
                assert_eq!(run.samples.len(), 1);
            }
            (None, 0 | 1 | 3 | 4) => assert_eq!(run.steps, 200),
            _ => panic!("member {j}: {:?}", run.failure),
        }
    }
}

/// A member whose energy overflows at its start (`|v₀|²` beyond f64) is
/// refused before any step with the error `consistent_velocity` (and so
/// `Stepper::integrate`) gives for it; the others run on in the kernel.
#[test]
fn a_member_no_step_can_use_fails_before_its_first_step() {
    let mut starts = mp_starts(6);
    starts[3].v[2] = 1e155;
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let mut lanes = LaneStepper::<_, 7, 1, 2, 23, 8>::new(MpParticles, tab, fig84());
    lanes.start(&starts, 0.05).unwrap();
    lanes.advance_by(50);
    let s = &starts[3];
    let policy = crate::ConsistencyPolicy::Error { tolerance: 1e300 };
    let alone = crate::consistent_velocity::<_, 7, 1>(&MpParticles, s.t, &s.q, &s.v, policy).unwrap_err();
    assert!(matches!(alone, StepError::NonFiniteInitialValue { .. }), "{alone}");
    let Some(LaneStatus::Failed(failure)) = lanes.status(3) else { panic!("{:?}", lanes.status(3)) };
    assert_eq!((failure.step, format!("{:?}", failure.error)), (0, format!("{alone:?}")));
    assert_eq!(lanes.state(3), Some(s));
    for j in [0, 1, 2, 4, 5] {
        assert_eq!(lanes.status(j), Some(&LaneStatus::Running), "member {j}");
        assert_eq!(lanes.kernel_steps(j), Some(48), "member {j}");
    }
}

/// Robots at h = 2 (beyond Newton's reach for a moving one, simplified
/// Newton without the energy guard): the moving member's steps diverge
/// and, as `integrate` does, are retried cold and halved, so every member
/// matches its solo run and the moving one `Stepper::integrate`'s run bit
/// for bit; the robots at rest at `φ = −π/2` (the minimum of the potential
/// `10 sin φ`) step on in the kernel. Allowed one Newton iteration, which
/// no halving gives enough, the moving member fails alone with its own
/// error.
#[test]
fn a_diverging_member_recovers_as_alone_or_fails_alone() {
    let opts = NewtonOptions { energy_drift_limit: None, ..fig84() };
    let phi = -std::f64::consts::FRAC_PI_2;
    let starts = [
        State::new(0.0, Vector::<4>::new(0.0, 0.0, 0.0, phi), Vector::<4>::zeros()),
        State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0)),
        State::new(0.0, Vector::<4>::new(0.5, -0.5, 0.0, phi), Vector::<4>::zeros()),
    ];
    let runs = compare::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, opts, &starts, 2.0, 20, 1);
    assert!(runs.iter().all(|r| r.failure.is_none() && r.steps == 20), "{runs:?}");
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let alone = by_the_driver::<_, 4, 2, 2, 16>(&MobileRobot::default(), tab, opts, &starts[1], 2.0, 20, 1);
    assert_same(&runs[1], &alone, "the moving robot against the driver");
    assert!(runs[1].recovery.rejected_steps > 0, "{:?}", runs[1].recovery);
    let one = NewtonOptions { max_iterations: 1, ..opts };
    let runs = compare::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, one, &starts, 2.0, 5, 1);
    assert!(runs[0].failure.is_none() && runs[2].failure.is_none(), "{:?} {:?}", runs[0].failure, runs[2].failure);
    let failure = runs[1].failure.as_ref().expect("the moving robot with one Newton iteration fails");
    assert!(matches!(failure.error, StepError::MaxIterations { .. }), "{failure}");
}

/// Eight lanes (a partly filled group) stepped directly match their
/// members alone, and report their status and Newton iterations.
#[test]
fn eight_lanes_partly_filled() {
    let starts = mp_starts(5);
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let mut lanes = LaneStepper::<_, 7, 1, 2, 23, 8>::new(MpParticles, tab, fig84());
    lanes.start(&starts, 0.05).unwrap();
    for _ in 0..300 {
        assert_eq!(lanes.advance(), 5);
    }
    assert_eq!(lanes.steps(), 300);
    for (j, start) in starts.iter().enumerate() {
        let alone = solo::<_, 7, 1, 2, 23>(&MpParticles, tab, fig84(), *start, 0.05, 300, 0);
        let iterations = lanes.total_iterations(j).unwrap();
        let lane = EnsembleRun {
            samples: vec![*start, *lanes.state(j).unwrap()],
            steps: 300,
            iterations,
            recovery: LaneRecovery::default(),
            failure: None,
        };
        assert_same(&lane, &alone, &format!("lane {j}"));
        assert_eq!(lanes.status(j), Some(&LaneStatus::Running));
        assert!(lanes.iterations(j).is_some_and(|i| i > 0));
        // Two steps alone build the extrapolation's history; the kernel
        // takes every later step of these members.
        assert_eq!(lanes.kernel_steps(j), Some(298), "lane {j}");
    }
    for j in 5..8 {
        assert_eq!(lanes.status(j), Some(&LaneStatus::Empty));
    }
    assert_eq!(lanes.status(8), None);
    // A second start forgets the first run: the same members again give
    // the same states.
    let first: Vec<_> = (0..5).map(|j| *lanes.state(j).unwrap()).collect();
    lanes.start(&starts, 0.05).unwrap();
    for _ in 0..300 {
        lanes.advance();
    }
    for (j, s) in first.iter().enumerate() {
        assert_eq!(lanes.state(j), Some(s), "lane {j} after a restart");
    }
}

/// Requests a lane group or an ensemble cannot run.
#[test]
fn lane_groups_refuse_what_they_cannot_run() {
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let mut lanes = LaneStepper::<_, 7, 1, 2, 23, 4>::new(MpParticles, tab, fig84());
    let starts = mp_starts(5);
    assert_eq!(lanes.start(&starts, 0.05), Err(LaneError::MemberCount { members: 5, lanes: 4 }));
    assert_eq!(lanes.start(&[], 0.05), Err(LaneError::MemberCount { members: 0, lanes: 4 }));
    for h in [0.0, f64::NAN, f64::INFINITY, 1e-310, 1e200, -1e200] {
        assert!(matches!(lanes.start(&starts[..2], h), Err(LaneError::StepSize { .. })), "{h}");
    }
    // A step that does not move t0 (16 units in its last place at least).
    let mut far = starts.clone();
    for s in &mut far {
        s.t = 1e20;
    }
    let err = lanes.start(&far[..2], 0.05).unwrap_err();
    assert!(matches!(err, LaneError::StepSize { .. }) && err.to_string().contains("resolution of t"), "{err}");
    let mut late = starts.clone();
    late[3].t = 1.0;
    let err = lanes.start(&late[..4], 0.05).unwrap_err();
    assert_eq!(err, LaneError::StartTimes { member: 3, t: 1.0, t0: 0.0 });
    assert!(err.to_string().contains("1.000e0"), "{err}");
    let run =
        |starts: &[State<7>], h| integrate_ensemble::<_, 7, 1, 2, 23>(&MpParticles, tab, fig84(), starts, h, 10, 1);
    assert!(matches!(run(&late, 0.05), Err(LaneError::StartTimes { member: 3, .. })));
    assert!(matches!(run(&starts, f64::NAN), Err(LaneError::StepSize { .. })));
    assert!(matches!(run(&starts, -1e-310), Err(LaneError::StepSize { .. })));
    assert!(matches!(run(&starts, 1e200), Err(LaneError::StepSize { .. })));
    assert!(matches!(run(&far, 0.05), Err(LaneError::StepSize { .. })));
    assert_eq!(run(&[], 0.05), Ok(Vec::new()));
}

/// The run of `start` by `Stepper::integrate` with `steps` fixed steps of
/// size `h`, sampled every `every` steps, as an [`EnsembleRun`] (it must
/// succeed).
fn by_the_driver<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: &Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    start: &State<N>,
    h: f64,
    steps: usize,
    every: usize,
) -> EnsembleRun<N>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let opts = crate::RunOptions { record_every: every, ..Default::default() };
    let mut st = Stepper::<Sys, N, M, S, D>::new(system.clone(), tableau).with_options(options);
    let schedule = crate::Schedule::Fixed { h, steps };
    let traj = st.integrate(start.t, &start.q, &start.v, schedule, &opts, &mut crate::NoObserver).unwrap();
    EnsembleRun {
        samples: traj.samples.iter().map(|p| State::new(p.t, p.q, p.v)).collect(),
        steps: traj.report.steps,
        iterations: traj.report.newton_iterations_total,
        recovery: LaneRecovery {
            rejected_steps: traj.report.rejected_steps,
            steps_with_rejections: traj.report.steps_with_rejections,
            extra_substeps: traj.report.substeps - traj.report.steps,
            smallest_substep: if traj.report.rejected_steps > 0 { traj.report.smallest_step } else { 0.0 },
        },
        failure: None,
    }
}

/// The members' samples are those of the integration driver run on each
/// member alone with the same fixed steps.
#[test]
fn mp_particles_in_lanes_match_the_driver() {
    let starts = mp_starts(6);
    let tab = Tableau::<2>::new(Method::ModifiedLobattoIIIAB).unwrap();
    let runs = integrate_ensemble::<_, 7, 1, 2, 23>(&MpParticles, tab, fig84(), &starts, 0.05, 600, 100).unwrap();
    for (j, (run, s)) in runs.iter().zip(&starts).enumerate() {
        let driver = by_the_driver::<_, 7, 1, 2, 23>(&MpParticles, tab, fig84(), s, 0.05, 600, 100);
        assert_same(run, &driver, &format!("member {j} against the driver"));
    }
}

/// Steps the kernel hands back: at h = 0.6 the McLachlan–Perlmutter
/// particles' stage-decoupled iteration is too slow (the stepper falls back
/// to the exact matrix for a while), and the energy guard is tight enough
/// to refuse some members. Every lane still matches its member alone, bit
/// for bit, and the kernel took some of the steps and not all. Both
/// starting guesses: extrapolation across steps (Gauss s = 2, Lobatto
/// IIIA-B s = 2), where a step handed back right after the stepper's own
/// steps on the exact matrix carries their prior, and Gauss s = 3's step
/// polynomial.
#[test]
fn lanes_the_kernel_hands_back_match_each_member_alone() {
    fn handed_back<const S: usize, const D: usize>(method: Method, starts: &[State<7>], sizes: &[(f64, usize)]) {
        let tab = Tableau::<S>::new(method).unwrap();
        for &(h, steps) in sizes {
            let runs = compare::<_, 7, 1, S, D>(MpParticles, method, fig84(), starts, h, steps, 10);
            let mut lanes = LaneStepper::<_, 7, 1, S, D, 4>::new(MpParticles, tab, fig84());
            lanes.start(&starts[..4], h).unwrap();
            lanes.advance_by(steps);
            let kernel: usize = (0..4).map(|j| lanes.kernel_steps(j).unwrap()).sum();
            let stepped: usize = runs[..4].iter().map(|r| r.steps).sum();
            assert!(
                kernel > 0 && kernel + 8 < stepped,
                "{method:?} s = {S}, h = {h}: kernel took {kernel} of {stepped}"
            );
        }
    }
    let starts = mp_starts(6);
    handed_back::<2, 23>(Method::Gauss, &starts, &[(0.6, 120), (0.45, 200)]);
    handed_back::<2, 23>(Method::LobattoIIIAB, &starts, &[(0.6, 120), (0.45, 200)]);
    handed_back::<3, 31>(Method::Gauss, &starts, &[(0.6, 120), (0.75, 100)]);
    let guard = NewtonOptions { energy_drift_limit: Some(1e-9), ..fig84() };
    let runs = compare::<_, 7, 1, 2, 23>(MpParticles, Method::LobattoIIIAB, guard, &starts, 0.05, 300, 25);
    assert!(runs.iter().any(|r| matches!(r.failure, Some(LaneFailure { error: StepError::EnergyDrift { .. }, .. }))));
}

/// Every build of the kernel (baseline, AVX2, AVX-512, as far as this CPU
/// has them) steps eight McLachlan–Perlmutter members bit for bit as each
/// member alone, with the kernel taking the steps.
#[test]
fn every_build_of_the_kernel_matches_each_member_alone() {
    use super::kernel::Simd;
    let (starts, h, steps) = (mp_starts(8), 0.05, 300);
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let alone: Vec<_> =
        starts.iter().map(|s| solo::<_, 7, 1, 2, 23>(&MpParticles, tab, fig84(), *s, h, steps, 0)).collect();
    for simd in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
        let mut lanes = LaneStepper::<_, 7, 1, 2, 23, 8>::new(MpParticles, tab, fig84()).with_simd(simd);
        lanes.start(&starts, h).unwrap();
        assert_eq!(lanes.advance_by(steps), 8, "{simd:?}: every lane runs");
        for (j, run) in alone.iter().enumerate() {
            let (lane, solo) = (lanes.state(j).unwrap(), run.samples.last().unwrap());
            let bits = |s: &State<7>| (s.t.to_bits(), s.q.map(f64::to_bits), s.v.map(f64::to_bits));
            assert!(bits(lane) == bits(solo), "{simd:?}, member {j}: {lane:?} in the lane, {solo:?} alone");
            assert_eq!(lanes.total_iterations(j), Some(run.iterations), "{simd:?}, member {j}");
            assert!(lanes.kernel_steps(j).unwrap() + 2 >= steps, "{simd:?}, member {j}: the kernel stepped little");
        }
    }
}
