//! Newcomers' systems in lane groups: every member of a [`LaneStepper`] and
//! of [`integrate_ensemble`] against the same member run alone by
//! [`Stepper::integrate`] on the same fixed steps, bit for bit at every
//! step (`t`, `q`, `v`, Newton iterations, the failed step and its error).
//! The systems cover what the kernel takes (constant diagonal and full
//! mass matrices, explicit time, affine drift terms, trig at the end point,
//! several constraints, as many constraints as coordinates) and what it
//! hands back to the members' steppers (forces, position-dependent mass,
//! constraints nonlinear in `v`), with members that diverge, turn NaN or
//! are refused by the energy guard next to members that step on.

use super::newcomer_systems::{
    BeltSleigh, ConstantSpeed, CoupledSleigh, DiffDrive, KnifeOnTurntable, PolarParticle, RheonomicSleigh,
    RollingDiskIncline, TrigChain8,
};
use super::newcomer_unusual_systems::{start, DrivenDuffing, FrictionSleigh, FullyConstrained, MagneticSkate};
use spark_runtime::{
    integrate_ensemble, nonholonomic_system, IntegrationError, LaneStatus, LaneStepper, Method, NewtonMode,
    NewtonOptions, NoObserver, NonholonomicSystem, RunOptions, Schedule, State, StepError, Stepper, Tableau,
};

/// Simplified Newton with the matrix the structure facts choose: the path
/// the kernel repeats wherever the mass matrix is constant.
fn simplified() -> NewtonOptions {
    NewtonOptions { mode: NewtonMode::Simplified, ..NewtonOptions::default() }
}

/// One member alone: its state after every step (its start first), the
/// Newton iterations of every step, and the failed step with its error.
struct Alone<const N: usize> {
    states: Vec<State<N>>,
    iterations: Vec<usize>,
    failure: Option<(usize, StepError)>,
}

/// `start` run alone by `Stepper::integrate` on `steps` fixed steps of
/// size `h` with the default run options (a failed step retried from the
/// cold guess and halved, as a lane retries and halves it), stopping at the
/// first step that fails even so, with the driver's error for it.
fn alone<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    tab: Tableau<S>,
    opts: NewtonOptions,
    start: &State<N>,
    h: f64,
    steps: usize,
) -> Alone<N>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let name = Sys::SOURCE.name;
    let record = RunOptions { record_every: 1, ..Default::default() };
    let run = |steps: usize| {
        let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tab).with_options(opts);
        st.integrate(start.t, &start.q, &start.v, Schedule::Fixed { h, steps }, &record, &mut NoObserver)
    };
    let samples = |traj: &spark_runtime::Trajectory<N, M>| {
        let states: Vec<_> = traj.samples.iter().map(|p| State::new(p.t, p.q, p.v)).collect();
        let iterations: Vec<usize> = traj.samples.iter().skip(1).map(|p| p.newton_iterations).collect();
        (states, iterations)
    };
    let (index, error) = match run(steps) {
        Err(IntegrationError::Step { index, source, .. }) => (index, source),
        Err(e) => panic!("{name}: {e}"),
        Ok(traj) => {
            let (states, iterations) = samples(&traj);
            assert_eq!(states.len(), steps + 1, "{name}: one sample a step");
            return Alone { states, iterations, failure: None };
        }
    };
    // The steps before the failed one.
    let (states, iterations) = if index == 0 {
        (vec![*start], Vec::new())
    } else {
        samples(&run(index).unwrap_or_else(|e| panic!("{name}: the steps before step {index}: {e}")))
    };
    assert_eq!(states.len(), index + 1, "{name}: one sample a step");
    Alone { states, iterations, failure: Some((index, error)) }
}

fn bits<const N: usize>(s: &State<N>) -> (u64, [u64; N], [u64; N]) {
    (s.t.to_bits(), s.q.map(f64::to_bits).into(), s.v.map(f64::to_bits).into())
}

/// Steps the members `starts` (at most eight) in one [`LaneStepper`], in
/// advances of 1, 2, 3, … steps, and in [`integrate_ensemble`], sampled at
/// every step, and compares every member with its run alone at every step.
/// Returns the steps the kernel took of each member.
fn lanes_match_alone<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    opts: NewtonOptions,
    starts: &[State<N>],
    h: f64,
    steps: usize,
) -> Vec<usize>
where
    Sys: NonholonomicSystem<N, M> + Clone + Send + Sync,
{
    let tab = Tableau::<S>::new(method).unwrap();
    let what = |j: usize| format!("{} {method} s = {S}, h = {h}, member {j}", Sys::SOURCE.name);
    let solo: Vec<_> = starts.iter().map(|s| alone::<Sys, N, M, S, D>(sys, tab, opts, s, h, steps)).collect();

    let mut lanes = LaneStepper::<Sys, N, M, S, D, 8>::new(sys.clone(), tab, opts);
    lanes.start(starts, h).unwrap();
    let (mut done, mut chunk) = (0, 1);
    while done < steps {
        let k = chunk.min(steps - done);
        lanes.advance_by(k);
        done += k;
        chunk += 1;
        for (j, a) in solo.iter().enumerate() {
            let lane = lanes.state(j).unwrap();
            match &a.failure {
                Some((index, error)) if *index < done => {
                    let Some(LaneStatus::Failed(f)) = lanes.status(j) else {
                        panic!("{}: runs in lanes after step {done}, fails alone at step {index}", what(j))
                    };
                    assert_eq!((f.step, format!("{:?}", f.error)), (*index, format!("{error:?}")), "{}", what(j));
                    let at = &a.states[*index];
                    assert!(bits(lane) == bits(at), "{}: failed at {lane:?} in lanes, at {at:?} alone", what(j));
                }
                _ => {
                    assert_eq!(lanes.status(j), Some(&LaneStatus::Running), "{}: step {done}", what(j));
                    let at = &a.states[done];
                    assert!(bits(lane) == bits(at), "{}: step {done}: {lane:?} in lanes, {at:?} alone", what(j));
                    let total: usize = a.iterations[..done].iter().sum();
                    assert_eq!(lanes.total_iterations(j), Some(total), "{}: iterations up to step {done}", what(j));
                }
            }
        }
    }

    let runs = integrate_ensemble::<Sys, N, M, S, D>(sys, tab, opts, starts, h, steps, 1).unwrap();
    for (j, (run, a)) in runs.iter().zip(&solo).enumerate() {
        let completed = a.failure.as_ref().map_or(steps, |f| f.0);
        assert_eq!(run.steps, completed, "{}: ensemble steps", what(j));
        assert_eq!(run.samples.len(), completed + 1, "{}: ensemble samples", what(j));
        for (k, (x, y)) in run.samples.iter().zip(&a.states).enumerate() {
            assert!(bits(x) == bits(y), "{}: ensemble sample {k}: {x:?}, alone {y:?}", what(j));
        }
        assert_eq!(run.iterations, a.iterations.iter().sum::<usize>(), "{}: ensemble iterations", what(j));
        let failure = run.failure.as_ref().map(|f| (f.step, format!("{:?}", f.error)));
        let expected = a.failure.as_ref().map(|(i, e)| (*i, format!("{e:?}")));
        assert_eq!(failure, expected, "{}: ensemble failure", what(j));
    }
    (0..starts.len()).map(|j| lanes.kernel_steps(j).unwrap()).collect()
}

/// Every method family and stage count the kernel takes: Gauss s = 1..4,
/// Lobatto IIIA-B s = 2..4, Lobatto IIIA-B-D s = 2..4 (its constraint at
/// the midpoint). `D = (S + 1)·N + S·M`.
macro_rules! every_method {
    ($sys:expr, $n:literal, $m:literal, $opts:expr, $starts:expr, $h:expr, $steps:expr) => {{
        let (sys, opts, starts) = (&$sys, $opts, &$starts);
        let mut kernel = Vec::new();
        kernel.push(lanes_match_alone::<_, $n, $m, 1, { 2 * $n + $m }>(sys, Method::Gauss, opts, starts, $h, $steps));
        for method in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
            kernel.push(lanes_match_alone::<_, $n, $m, 2, { 3 * $n + 2 * $m }>(sys, method, opts, starts, $h, $steps));
            kernel.push(lanes_match_alone::<_, $n, $m, 3, { 4 * $n + 3 * $m }>(sys, method, opts, starts, $h, $steps));
            kernel.push(lanes_match_alone::<_, $n, $m, 4, { 5 * $n + 4 * $m }>(sys, method, opts, starts, $h, $steps));
        }
        kernel
    }};
}

/// Eight sleigh starts spread in heading and speed.
fn sleigh_starts<Sys: NonholonomicSystem<3, 1>>(sys: &Sys, t0: f64) -> Vec<State<3>> {
    (0..8)
        .map(|j| {
            let (theta, w) = (0.4 * j as f64 - 1.0, 0.3 + 0.25 * j as f64);
            start(sys, t0, [0.1 * j as f64, -0.2, theta], [w * theta.cos(), w * theta.sin(), 0.5 - 0.1 * j as f64])
        })
        .collect()
}

/// Explicit time in a constraint (`ẏ − sin t ẋ`, a lone `sin t` at the end
/// point), an affine drift term that moves with time (the belt), one that
/// depends on the position (the turntable), from a start time away from
/// zero: every member in every method is bit for bit its run alone, and
/// the kernel takes most steps.
#[test]
fn rheonomic_and_affine_sleighs_in_lanes_match_each_member_alone() {
    let t0 = 0.75;
    let rheo = RheonomicSleigh::default();
    let belt = BeltSleigh::default();
    let turn = KnifeOnTurntable::default();
    let kernel = [
        every_method!(rheo, 3, 1, simplified(), sleigh_starts(&rheo, t0), 0.05, 60),
        every_method!(belt, 3, 1, simplified(), sleigh_starts(&belt, t0), 0.05, 60),
        every_method!(turn, 3, 1, simplified(), sleigh_starts(&turn, t0), 0.05, 60),
    ];
    for (i, per_method) in kernel.iter().enumerate() {
        for (k, steps) in per_method.iter().enumerate() {
            let most = steps.iter().filter(|&&s| s >= 40).count();
            assert!(most >= 6, "system {i}, method {k}: kernel steps {steps:?}");
        }
    }
}

/// Constant mass matrices with more structure: a full one (the coupled
/// sleigh), three constraints with trig (the differential drive), a
/// gyroscopic term with time (the magnetic skate), as many constraints as
/// coordinates (prescribed motion with time), two constraints (the disk).
#[test]
fn constant_mass_systems_in_lanes_match_each_member_alone() {
    let sleigh = CoupledSleigh::default();
    every_method!(sleigh, 3, 1, simplified(), sleigh_starts(&sleigh, 0.0), 0.05, 40);
    let skate = MagneticSkate::default();
    every_method!(skate, 3, 1, simplified(), sleigh_starts(&skate, 0.3), 0.05, 40);
    let drive = DiffDrive::default();
    let drives: Vec<_> = (0..8)
        .map(|j| {
            let th = 0.7 * j as f64;
            start(&drive, 0.0, [0.2, -0.1 * j as f64, th, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0 + 0.3 * j as f64, 0.5])
        })
        .collect();
    every_method!(drive, 5, 3, simplified(), drives, 0.05, 40);
    let full = FullyConstrained::default();
    let prescribed: Vec<_> =
        (0..8).map(|j| start(&full, 0.2, [0.3 + 0.1 * j as f64, 0.1 * j as f64], [1.0, 0.3])).collect();
    every_method!(full, 2, 2, simplified(), prescribed, 0.05, 40);
    let disk = RollingDiskIncline::default();
    let disks: Vec<_> = (0..8)
        .map(|j| {
            let (theta, w) = (0.3 * j as f64, 1.0 + 0.1 * j as f64);
            start(&disk, 0.0, [0.0, 0.0, theta, 0.0], [0.0, 0.0, 0.2, w])
        })
        .collect();
    every_method!(disk, 4, 2, simplified(), disks, 0.05, 40);
}

/// Systems the kernel does not take (forces, a position-dependent mass,
/// a constraint quadratic in `v`): every member goes back to its stepper,
/// still bit for bit its run alone.
#[test]
fn systems_the_kernel_leaves_to_the_steppers_match_each_member_alone() {
    let duffing = DrivenDuffing::default();
    let starts: Vec<_> =
        (0..8).map(|j| start(&duffing, 0.25, [0.6 - 0.1 * j as f64], [-0.4 + 0.1 * j as f64])).collect();
    for k in lanes_match_alone::<_, 1, 0, 2, 3>(&duffing, Method::Gauss, simplified(), &starts, 0.05, 40) {
        assert_eq!(k, 0);
    }
    let friction = FrictionSleigh::default();
    let starts = sleigh_starts(&friction, 0.1);
    lanes_match_alone::<_, 3, 1, 2, 11>(&friction, Method::LobattoIIIAB, simplified(), &starts, 0.05, 40);
    let polar = PolarParticle::default();
    let starts: Vec<_> = (0..8)
        .map(|j| start(&polar, 0.0, [1.0 + 0.1 * j as f64, 0.0, 0.0], [0.1, 0.5 + 0.1 * j as f64, 0.0]))
        .collect();
    lanes_match_alone::<_, 3, 1, 3, 15>(&polar, Method::Gauss, simplified(), &starts, 0.05, 40);
    let speed = ConstantSpeed::default();
    let starts: Vec<_> =
        (0..8).map(|j| start(&speed, 0.0, [0.5, 0.1 * j as f64, -0.2], [0.6, 0.8, 0.1 * j as f64])).collect();
    lanes_match_alone::<_, 3, 1, 2, 11>(&speed, Method::LobattoIIIABD, simplified(), &starts, 0.05, 40);
    let chain = TrigChain8::default();
    let starts: Vec<_> = (0..8)
        .map(|j| {
            let x = 0.1 * j as f64;
            start(&chain, 0.0, [x, 0.2, -x, 0.3, 0.5 + x, 0.1, 0.2, -0.3], [0.3, 0.2, 0.1, -0.2, 0.4, 0.1, x, 0.2])
        })
        .collect();
    lanes_match_alone::<_, 8, 2, 2, 28>(&chain, Method::Gauss, simplified(), &starts, 0.05, 30);
}

/// One group whose members need different numbers of updates: disks on
/// the level plane turning at a constant rate, whose first update lands,
/// next to disks whose heading rate is large and whose updates contract
/// slowly; the members at rest take one update a step. Each member is bit
/// for bit its run alone.
#[test]
fn members_converging_at_different_rates_match_each_member_alone() {
    let disk = RollingDiskIncline { alpha: 0.0, ..RollingDiskIncline::default() };
    let starts: Vec<_> = (0..8)
        .map(|j| match j % 3 {
            0 => start(&disk, 0.0, [0.0, 0.0, 0.3 * j as f64, 0.0], [0.0, 0.0, 0.0, 0.0]),
            1 => start(&disk, 0.0, [0.0, 0.0, 0.1, 0.0], [0.0, 0.0, 0.7, 1.3]),
            _ => start(&disk, 0.0, [0.0, 0.0, 0.1, 0.0], [0.0, 0.0, 8.0 + j as f64, 1.0]),
        })
        .collect();
    let tilted = RollingDiskIncline::default();
    for h in [0.05, 0.2] {
        lanes_match_alone::<_, 4, 2, 2, 16>(&disk, Method::Gauss, simplified(), &starts, h, 60);
        lanes_match_alone::<_, 4, 2, 3, 22>(&tilted, Method::LobattoIIIAB, simplified(), &starts, h, 60);
    }
}

/// Sleighs with very different speeds at a step size where the fast ones
/// leave Newton's reach: the fast members fail (diverge, turn non-finite
/// or are refused) at their own steps with their own errors, the others
/// step on, in lanes as alone.
#[test]
fn members_that_diverge_midway_fail_as_alone() {
    let sleigh = CoupledSleigh::default();
    let off = NewtonOptions { energy_drift_limit: None, ..simplified() };
    let starts: Vec<_> = (0..8)
        .map(|j| {
            let w = [0.5, 5.0, 0.5, 50.0, 0.5, 300.0, 0.5, 1500.0][j];
            start(&sleigh, 0.0, [0.3, 0.1, 0.2 * j as f64], [w, 0.0, w])
        })
        .collect();
    for h in [0.05, 0.4] {
        lanes_match_alone::<_, 3, 1, 2, 11>(&sleigh, Method::Gauss, off, &starts, h, 40);
        lanes_match_alone::<_, 3, 1, 3, 15>(&sleigh, Method::LobattoIIIAB, off, &starts, h, 40);
    }
    // The test is about failures next to members that step on.
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let failed: Vec<bool> =
        starts.iter().map(|s| alone::<_, 3, 1, 2, 11>(&sleigh, tab, off, s, 0.4, 40).failure.is_some()).collect();
    assert!(failed.contains(&true) && failed.contains(&false), "failed at h = 0.4: {failed:?}");
}

/// A tight energy guard refuses some members' steps and not others'
/// (the coupled sleigh's energy is a first integral: autonomous `L`,
/// constraint linear and homogeneous in `v`).
#[test]
fn members_the_energy_guard_refuses_fail_as_alone() {
    let sleigh = CoupledSleigh::default();
    let starts = sleigh_starts(&sleigh, 0.0);
    let (mut refused, mut runs) = (0, 0);
    for limit in [1e-3, 1e-4, 1e-5, 1e-6] {
        let guard = NewtonOptions { energy_drift_limit: Some(limit), ..simplified() };
        let (h, steps) = (0.1, 60);
        let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        lanes_match_alone::<_, 3, 1, 2, 11>(&sleigh, Method::LobattoIIIAB, guard, &starts, h, steps);
        refused += starts
            .iter()
            .map(|s| alone::<_, 3, 1, 2, 11>(&sleigh, tab, guard, s, h, steps))
            .filter(|a| matches!(a.failure, Some((_, StepError::EnergyDrift { .. }))))
            .count();
        runs += starts.len();
    }
    assert!(refused > 0 && refused < runs, "{refused} of {runs} runs refused");
}

/// A new step size for the same members: a second `start` with another
/// `h` from where the first run ended is bit for bit a fresh run alone
/// from there.
#[test]
fn a_new_step_size_restarts_as_alone() {
    let belt = BeltSleigh::default();
    let starts = sleigh_starts(&belt, 0.5);
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let mut lanes = LaneStepper::<_, 3, 1, 2, 11, 8>::new(belt, tab, simplified());
    let mut from = starts.clone();
    for (h, steps) in [(0.05, 30), (0.02, 30), (-0.07, 30), (0.07, 30)] {
        lanes.start(&from, h).unwrap();
        lanes.advance_by(steps);
        for (j, s) in from.iter().enumerate() {
            let a = alone::<_, 3, 1, 2, 11>(&belt, tab, simplified(), s, h, steps);
            let (lane, at) = (lanes.state(j).unwrap(), a.states.last().unwrap());
            assert!(bits(lane) == bits(at), "h = {h}, member {j}: {lane:?} in lanes, {at:?} alone");
            assert!(lanes.kernel_steps(j).unwrap() >= steps - 2, "h = {h}, member {j}");
        }
        // The next run starts where this one ended (one start time for all).
        from = (0..8).map(|j| *lanes.state(j).unwrap()).collect();
    }
}

nonholonomic_system! {
    /// A sleigh on a belt whose speed `√(1.5 − t)` has no value after
    /// `t = 1.5`: the constraint's drift turns NaN at the end point of a
    /// step in the middle of a run, for every member at once.
    pub struct ExpiringBelt {
        coordinates: [x, y, theta],
        parameters: { inertia = 0.4 },
        lagrangian: (dot(x)^2 + dot(y)^2)/2 + inertia/2*dot(theta)^2 - (x^2 + y^2)/2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*(dot(x) - sqrt(1.5 - t)) ],
    }
}

/// An affine drift that turns NaN mid-run (at the end point first for
/// Lobatto, at a stage for Gauss): every member fails at the step each
/// fails alone, with the same error, after the kernel took the steps
/// before.
#[test]
fn a_drift_that_turns_nan_in_lanes_fails_as_alone() {
    let belt = ExpiringBelt::default();
    let starts = sleigh_starts(&belt, 0.0);
    for method in [Method::LobattoIIIAB, Method::LobattoIIIABD, Method::Gauss] {
        let kernel = lanes_match_alone::<_, 3, 1, 2, 11>(&belt, method, simplified(), &starts, 0.05, 40);
        assert!(kernel.iter().all(|&k| k >= 20), "{method}: kernel steps {kernel:?}");
    }
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    for s in &starts {
        let run = alone::<_, 3, 1, 2, 11>(&belt, tab, simplified(), s, 0.05, 40);
        assert!(matches!(run.failure, Some((_, StepError::NonFinite { .. }))), "{:?}", run.failure);
    }
}
