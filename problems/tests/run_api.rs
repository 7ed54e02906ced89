//! The non-generic run API that `spark run` and the Python extension call:
//! multipliers recorded on request, and ensembles whose members equal
//! single runs bit for bit whatever the thread count, with errors that name
//! the member.

use problems::catalog::SystemKind;
use problems::run::{run, run_ensemble, EnsembleError, RunError, RunResult, RunSpec};
use spark_runtime::{Method, NewtonMode, NoObserver, Observe, RunOptions, Schedule, Stepper, Tableau, Vector};

/// The recorded samples of two runs are the same, bit for bit.
fn same_samples(a: &RunResult, b: &RunResult, what: &str) {
    assert_eq!(a.t, b.t, "{what}: t");
    assert_eq!(a.q, b.q, "{what}: q");
    assert_eq!(a.v, b.v, "{what}: v");
    assert_eq!(a.energy, b.energy, "{what}: energy");
    assert_eq!(a.constraint, b.constraint, "{what}: constraint");
    assert_eq!(a.stats.e0, b.stats.e0, "{what}: e0");
    assert_eq!(a.stats.steps, b.stats.steps, "{what}: steps");
}

#[test]
fn multipliers_are_recorded_on_request_without_changing_the_run() {
    let spec = RunSpec { steps: 20, ..RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 20) };
    let plain = run(&spec, &|_| {}).unwrap();
    assert!(plain.psi.is_empty());
    let json = serde_json::to_value(&plain).unwrap();
    assert!(json.get("psi").is_none(), "spark run's JSON has no psi unless asked for");
    let with = run(&RunSpec { multipliers: true, ..spec.clone() }, &|_| {}).unwrap();
    same_samples(&plain, &with, "multipliers recorded");
    assert_eq!(with.psi.len(), 1);
    assert_eq!(with.psi[0].len(), with.t.len());
    // The same ψ as the stepper's own observation.
    let mut stepper = Stepper::<problems::systems::Skate, 3, 1, 2, 11>::new(
        problems::systems::Skate::default(),
        Tableau::<2>::new(Method::Gauss).unwrap(),
    );
    let options = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: true },
        ..RunOptions::default()
    };
    let traj = stepper
        .integrate(
            0.0,
            &Vector::<3>::from_column_slice(&spec.q0),
            &Vector::<3>::from_column_slice(&spec.v0),
            Schedule::Fixed { h: 0.1, steps: 20 },
            &options,
            &mut NoObserver,
        )
        .unwrap();
    let psi: Vec<f64> = traj.samples.iter().map(|s| s.multipliers.map_or(f64::NAN, |p| p[0])).collect();
    assert!(psi.iter().skip(1).all(|x| x.is_finite()), "{psi:?}");
    let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    assert_eq!(bits(&with.psi[0]), bits(&psi));
}

/// Members `j` of the §8.4 ensemble with 6 members.
fn mp7_members() -> Vec<(Vec<f64>, Vec<f64>)> {
    (0..6).map(|j| problems::systems::mp7_initial_values(j, 5)).collect()
}

#[test]
fn ensemble_members_equal_single_runs_for_any_thread_count() {
    let kind = SystemKind::parse("mp7-nh").unwrap();
    let mut spec = RunSpec::paper(kind, Method::LobattoIIIAB, 2, 0.05, 200);
    spec.record_every = 10;
    spec.newton.mode = NewtonMode::Simplified;
    let members = mp7_members();
    let one = run_ensemble(&spec, &members, Some(1)).unwrap();
    let two = run_ensemble(&spec, &members, Some(2)).unwrap();
    let pool = run_ensemble(&spec, &members, None).unwrap();
    assert_eq!(one.len(), members.len());
    for (j, (q0, v0)) in members.iter().enumerate() {
        let alone = run(&RunSpec { q0: q0.clone(), v0: v0.clone(), ..spec.clone() }, &|_| {}).unwrap();
        assert_eq!(alone.t.len(), 21);
        same_samples(&one[j], &alone, &format!("member {j}, 1 thread"));
        same_samples(&two[j], &alone, &format!("member {j}, 2 threads"));
        same_samples(&pool[j], &alone, &format!("member {j}, global pool"));
    }
    // The members differ: each starts from its own state.
    assert_ne!(one[0].q, one[5].q);
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
    let err = run_ensemble(&spec, &[short], None).unwrap_err();
    assert!(err.to_string().contains("member 0: q0 has 2 entries"), "{err}");
    assert!(matches!(run_ensemble(&spec, &[], None), Err(EnsembleError::NoMembers)));
    assert!(matches!(run_ensemble(&spec, &[good], Some(0)), Err(EnsembleError::NoThreads)));
}
