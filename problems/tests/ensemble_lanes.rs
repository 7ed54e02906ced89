//! Ensembles on the lane stepper (`run_ensemble`): every member agrees with
//! its run alone, whatever the thread count; a lane group's members share
//! its time; an inconsistent member is reported with its index; the runs
//! the lanes cannot take go through `run` per member.

use problems::catalog::SystemKind;
use problems::run::{run, run_ensemble, run_ensemble_with, EnsembleError, RunError, RunResult, RunSpec};
use spark_runtime::{ConsistencyPolicy, IntegrationError, Method, NewtonMode, LANES};
use std::sync::atomic::{AtomicU64, Ordering};

/// `a` and `b` equal bit for bit, entry by entry.
///
/// Why they are: a lane takes the member's steps with the member's own
/// tableau, options and warm start, and the lane kernel repeats the solo
/// stepper's operations in the same order (`spark_runtime::lanes`), with
/// the system's stage values in lane form equal to its scalar ones
/// (`lane_values.rs`); the observations are computed from the same states
/// by the same functions.
fn same_bits(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert_eq!(x.to_bits(), y.to_bits(), "{what}[{k}]: {x:e} (ensemble) vs {y:e} (alone)");
    }
}

/// The samples and statistics of an ensemble member and of its run alone
/// are the same (see [`same_bits`]).
fn agrees(a: &RunResult, b: &RunResult, what: &str) {
    // Sample times are pinned to t0 + k·h in both: equal.
    assert_eq!(a.t, b.t, "{what}: t");
    assert_eq!(a.q.len(), b.q.len(), "{what}: coordinates");
    for i in 0..a.q.len() {
        same_bits(&a.q[i], &b.q[i], &format!("{what}: q{i}"));
        same_bits(&a.v[i], &b.v[i], &format!("{what}: v{i}"));
    }
    same_bits(&a.energy, &b.energy, &format!("{what}: energy"));
    same_bits(&a.constraint, &b.constraint, &format!("{what}: |k|"));
    same_bits(&a.holonomic, &b.holonomic, &format!("{what}: |g|"));
    assert_eq!(a.psi, b.psi, "{what}: psi");
    let (s, t) = (&a.stats, &b.stats);
    assert_eq!(s.steps, t.steps, "{what}: steps");
    assert_eq!(s.e0, t.e0, "{what}: e0 (same checked start)");
    // The extremes over every step, not only over the samples.
    same_bits(&[s.max_energy_error], &[t.max_energy_error], &format!("{what}: max |E − E0|"));
    same_bits(&[s.max_constraint_residual], &[t.max_constraint_residual], &format!("{what}: max |k|"));
    assert_eq!(s.max_holonomic_drift.is_some(), t.max_holonomic_drift.is_some(), "{what}: holonomic drift");
    same_bits(
        &[s.max_holonomic_drift.unwrap_or(0.0)],
        &[t.max_holonomic_drift.unwrap_or(0.0)],
        &format!("{what}: max |g|"),
    );
    assert!(s.newton_iterations_mean >= 1.0, "{what}: Newton iterations {}", s.newton_iterations_mean);
    same_bits(&[s.newton_iterations_mean], &[t.newton_iterations_mean], &format!("{what}: Newton iterations"));
    // Failed steps retried and halved as the driver does, and counted alike.
    assert_eq!(
        (s.rejected_steps, s.steps_with_rejections, s.substeps),
        (t.rejected_steps, t.steps_with_rejections, t.substeps),
        "{what}: rejections and sub-steps"
    );
    same_bits(&[s.smallest_step], &[t.smallest_step], &format!("{what}: smallest step"));
}

/// Runs `members` as an ensemble on 1 and 2 threads and on the global pool,
/// checks each member against its run alone and the thread counts against
/// each other (bit for bit: the lane groups do not depend on the threads).
fn check_against_solo_runs(spec: &RunSpec, members: &[(Vec<f64>, Vec<f64>)], samples: usize) -> Vec<RunResult> {
    let one = run_ensemble(spec, members, Some(1)).unwrap();
    let two = run_ensemble(spec, members, Some(2)).unwrap();
    let pool = run_ensemble(spec, members, None).unwrap();
    assert_eq!(one.len(), members.len());
    for (j, (q0, v0)) in members.iter().enumerate() {
        let alone = run(&RunSpec { q0: q0.clone(), v0: v0.clone(), ..spec.clone() }, &|_| true).unwrap();
        assert_eq!(alone.t.len(), samples, "member {j}: samples");
        agrees(&one[j], &alone, &format!("member {j}"));
        for other in [&two[j], &pool[j]] {
            assert_eq!((&other.t, &other.q, &other.v), (&one[j].t, &one[j].q, &one[j].v), "member {j}: threads");
            assert_eq!(other.energy, one[j].energy, "member {j}: threads");
        }
    }
    one
}

/// Members `j` of the §8.4 ensemble with `k` members.
fn mp7_members(k: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
    (0..k).map(|j| problems::systems::mp7_initial_values(j, k - 1)).collect()
}

fn mp7_spec(kind: &str, steps: usize, every: usize) -> RunSpec {
    let mut spec = RunSpec::paper(SystemKind::parse(kind).unwrap(), Method::LobattoIIIAB, 2, 0.05, steps);
    spec.record_every = every;
    spec.newton.mode = NewtonMode::Simplified;
    spec
}

#[test]
fn mp7_members_agree_with_their_runs_alone() {
    // Six members: one full lane group and one partial one. The sampling
    // interval does not divide the step count: the last step is a sample.
    let members = mp7_members(6);
    let out = check_against_solo_runs(&mp7_spec("mp7-nh", 200, 7), &members, 1 + 200 / 7 + 1);
    assert_ne!(out[0].q, out[5].q, "each member starts from its own state");
    // The constraint as printed, every step recorded.
    check_against_solo_runs(&mp7_spec("mp7", 200, 1), &members[..3], 201);
}

/// At h = 1.2 some members' steps fail and are halved: in their lanes as
/// in their runs alone, counted alike (see [`agrees`]), the members staying
/// in the lane group.
#[test]
fn members_whose_steps_are_halved_agree_with_their_runs_alone() {
    let members = mp7_members(8);
    let mut spec = mp7_spec("mp7-nh", 60, 10);
    spec.h = 1.2;
    let out = check_against_solo_runs(&spec, &members, 7);
    let halved = out.iter().filter(|r| r.stats.rejected_steps > 0).count();
    assert!(halved > 0, "no member halved a step at h = 1.2");
}

#[test]
fn skate_members_agree_with_their_runs_alone() {
    // Headings and speeds along the blade, some of them with a sideways
    // velocity that the projection of v0 removes.
    let members: Vec<(Vec<f64>, Vec<f64>)> = (0..5)
        .map(|j| {
            let (theta, c) = (0.3 * j as f64, 1.0 + 0.25 * j as f64);
            let side = if j % 2 == 1 { 0.1 } else { 0.0 };
            (vec![0.0, 0.0, theta], vec![c * theta.cos() - side * theta.sin(), c * theta.sin(), 0.5 - 0.2 * j as f64])
        })
        .collect();
    for (method, s) in [(Method::LobattoIIIAB, 2), (Method::Gauss, 3)] {
        let mut spec = RunSpec::paper(SystemKind::Skate, method, s, 0.1, 150);
        spec.consistency = ConsistencyPolicy::Project { tolerance: 1e-12 };
        spec.record_every = 5;
        check_against_solo_runs(&spec, &members, 31);
    }
}

#[test]
fn lane_group_members_share_the_group_time() {
    // Members run in lane groups of LANES; each member of a group reports
    // an equal share of the group's time (see `run_ensemble_with`).
    let members = mp7_members(LANES + 2);
    let out = run_ensemble(&mp7_spec("mp7-nh", 100, 10), &members, Some(1)).unwrap();
    for (g, group) in out.chunks(LANES).enumerate() {
        for r in group {
            assert_eq!(r.stats.wall_time, group[0].stats.wall_time, "group {g}: wall time");
            assert_eq!(r.stats.cpu_time, group[0].stats.cpu_time, "group {g}: CPU time");
        }
    }
}

#[test]
fn ensemble_ticks_count_every_member_step() {
    let members = mp7_members(5);
    let done = AtomicU64::new(0);
    let tick = |n: u64| {
        done.fetch_add(n, Ordering::Relaxed);
        true
    };
    run_ensemble_with(&mp7_spec("mp7-nh", 300, 100), &members, Some(2), &tick).unwrap();
    assert_eq!(done.load(Ordering::Relaxed), 5 * 300);
}

/// The step at which a stopped member's error says it stopped (whichever
/// member the error names: every member stops).
fn stopped_at(e: &EnsembleError) -> Option<usize> {
    match e {
        EnsembleError::Member {
            source: RunError::Integration { source: IntegrationError::Stopped { steps, .. }, .. },
            ..
        } => Some(*steps),
        _ => None,
    }
}

#[test]
fn an_ensemble_stops_at_the_first_tick_that_says_so() {
    // Lanes: five members take 5 member-steps per step, so the first tick
    // comes after the 820th step (4100 ≥ 4096).
    let never_ending = mp7_spec("mp7-nh", 1 << 40, 1 << 30);
    let e = run_ensemble_with(&never_ending, &mp7_members(5), Some(2), &|_| false).unwrap_err();
    assert_eq!(stopped_at(&e), Some(820), "{e}");
    assert!(e.to_string().contains("stopped by its observer"), "{e}");
    // Each member alone (a system without lanes): its run's first tick.
    let mut skate = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 1 << 40);
    skate.record_every = 1 << 30;
    let members = vec![(vec![0.0; 3], vec![0.0, 0.0, 1.0]); 3];
    let e = run_ensemble_with(&skate, &members, Some(2), &|_| false).unwrap_err();
    assert_eq!(stopped_at(&e), Some(4096), "{e}");
}

#[test]
fn an_inconsistent_member_is_reported_with_its_index() {
    let mut members = mp7_members(6);
    // v1 = 0.3 violates v1 + q2 v5 + q3 v6 + q4 v7 = 0 for member 4 only.
    members[4].1[0] = 0.3;
    let err = run_ensemble(&mp7_spec("mp7-nh", 50, 10), &members, None).unwrap_err();
    assert!(
        matches!(err, EnsembleError::Member { member: 4, source: RunError::InconsistentVelocities { .. } }),
        "{err}"
    );
    assert!(err.to_string().starts_with("member 4: v0 violates the constraints"), "{err}");
    // Projected instead, member 4 runs (on its consistent velocity) and the
    // others are unaffected.
    let mut spec = mp7_spec("mp7-nh", 50, 10);
    spec.consistency = ConsistencyPolicy::Project { tolerance: 1e-12 };
    let out = run_ensemble(&spec, &members, None).unwrap();
    let alone =
        run(&RunSpec { q0: members[4].0.clone(), v0: members[4].1.clone(), ..spec.clone() }, &|_| true).unwrap();
    agrees(&out[4], &alone, "projected member 4");
    let clean = run_ensemble(&mp7_spec("mp7-nh", 50, 10), &mp7_members(6), None).unwrap();
    assert_eq!(out[3].q, clean[3].q, "member 3 does not see member 4");
}

#[test]
fn ensemble_errors_name_the_member_and_what_to_change() {
    let spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 5);
    let good = (vec![0.0; 3], vec![0.0, 0.0, 1.0]);
    let bad = (vec![0.0; 3], vec![0.0, 1.0, 0.0]);
    let err = run_ensemble(&spec, &[good.clone(), bad], Some(1)).unwrap_err();
    assert!(
        matches!(err, EnsembleError::Member { member: 1, source: RunError::InconsistentVelocities { .. } }),
        "{err}"
    );
    assert!(err.to_string().starts_with("member 1: v0 violates the constraints"), "{err}");
    let short = (vec![0.0; 2], vec![0.0; 2]);
    let err = run_ensemble(&spec, &[good.clone(), short], None).unwrap_err();
    assert!(err.to_string().contains("member 1: q0 has 2 entries"), "{err}");
    assert!(matches!(run_ensemble(&spec, &[], None), Err(EnsembleError::NoMembers)));
    assert!(matches!(run_ensemble(&spec, std::slice::from_ref(&good), Some(0)), Err(EnsembleError::NoThreads)));
    // A spec `run` rejects: every member reports the same error.
    let err = run_ensemble(&RunSpec { h: f64::NAN, ..spec.clone() }, std::slice::from_ref(&good), None).unwrap_err();
    assert!(err.to_string().contains("step size h = NaN must be finite"), "{err}");
}

#[test]
fn multipliers_go_through_the_per_member_runs() {
    let members = mp7_members(3);
    let mut spec = mp7_spec("mp7-nh", 40, 10);
    spec.multipliers = true;
    let out = run_ensemble(&spec, &members, None).unwrap();
    for (j, (q0, v0)) in members.iter().enumerate() {
        let alone = run(&RunSpec { q0: q0.clone(), v0: v0.clone(), ..spec.clone() }, &|_| true).unwrap();
        assert_eq!(out[j].psi.len(), 1);
        assert_eq!(out[j].psi, alone.psi, "member {j}: psi");
        assert_eq!(out[j].q, alone.q, "member {j}: q");
    }
}
