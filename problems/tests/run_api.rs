//! The non-generic run API that `spark run` and the Python extension call:
//! multipliers recorded on request, records that cannot fit refused, runs
//! stopped by their progress callback (ensembles: `ensemble_lanes.rs`).

use problems::catalog::SystemKind;
use problems::run::{run, RunError, RunResult, RunSpec};
use spark_runtime::{IntegrationError, Method, NoObserver, Observe, RunOptions, Schedule, Stepper, Tableau, Vector};

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
    let plain = run(&spec, &|_| true).unwrap();
    assert!(plain.psi.is_empty());
    let json = serde_json::to_value(&plain).unwrap();
    assert!(json.get("psi").is_none(), "spark run's JSON has no psi unless asked for");
    let with = run(&RunSpec { multipliers: true, ..spec.clone() }, &|_| true).unwrap();
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

/// Every row of `report.md`'s table has two cells: the `|` of `max |E − E0|`,
/// `max |k|` and `max |g|` is escaped, not a cell boundary.
#[test]
fn the_run_report_table_has_two_cells_in_every_row() {
    let spec = RunSpec::paper(SystemKind::RodPendulumHand, Method::Gauss, 2, 0.05, 20);
    let report = problems::run::run_report(&run(&spec, &|_| true).unwrap(), &spec);
    let rows: Vec<&str> = report.lines().filter(|l| l.starts_with('|')).collect();
    assert!(rows.len() > 8 && report.contains("max \\|g\\|"), "{report}");
    for row in rows {
        let boundaries = row.char_indices().filter(|&(i, c)| c == '|' && !row[..i].ends_with('\\')).count();
        assert_eq!(boundaries, 3, "{row}");
    }
}

/// Numbers far from 1 print in scientific notation in `report.md`, as its
/// other numbers do: an E0 of 5e299 is `5e299`, not 300 digits.
#[test]
fn the_run_report_prints_huge_and_tiny_numbers_in_scientific_notation() {
    let mut spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 1e-300, 2);
    spec.parameters = vec![("inertia".into(), 1e300)];
    let result = run(&spec, &|_| true).unwrap();
    assert_eq!(result.stats.e0, 5e299);
    let report = problems::run::run_report(&result, &spec);
    assert!(report.contains("| E0 | 5e299 |"), "{report}");
    assert!(report.contains("inertia = 1e300") && report.contains("2 × 1e-300 (t = 0 … 2e-300)"), "{report}");
    assert!(report.lines().all(|l| l.len() < 200), "{report}");
    // Numbers near 1 keep their positional form.
    let spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 2);
    let report = problems::run::run_report(&run(&spec, &|_| true).unwrap(), &spec);
    assert!(report.contains("| E0 | 0.5 |") && report.contains("2 × 0.1 (t = 0 … 0.2)"), "{report}");
}

/// A run spec that cannot work is refused before any step, saying what to
/// change: a subnormal step (1/h overflows in the step's equations), a
/// step that does not move t0, a parameter given twice.
#[test]
fn unusable_steps_and_repeated_parameters_are_refused_up_front() {
    let spec = |h: f64, t0: f64| RunSpec { t0, ..RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, h, 3) };
    for (h, t0, what) in [(1e-311, 0.0, "subnormal"), (-5e-324, 0.0, "subnormal"), (1.0, 1e20, "resolution of t")] {
        match run(&spec(h, t0), &|_| true) {
            Err(RunError::Invalid(e)) => assert!(e.contains(what) && e.contains("use"), "h = {h:e}: {e}"),
            other => panic!("h = {h:e}, t0 = {t0:e}: expected a refusal, got {other:?}"),
        }
    }
    assert_eq!(run(&spec(f64::MIN_POSITIVE, 0.0), &|_| true).unwrap().t.len(), 4);
    let twice = RunSpec { parameters: vec![("m".into(), 1.0), ("g".into(), 2.0), ("m".into(), 2.0)], ..spec(0.1, 0.0) };
    let err = run(&twice, &|_| true).unwrap_err().to_string();
    assert!(err.contains("`m` is given twice"), "{err}");
}

/// A thread count beyond what an ensemble starts is refused at once (rayon
/// would start up to 65535 threads for `usize::MAX`, which stalls the
/// process); the largest allowed count runs.
#[test]
fn an_ensemble_refuses_more_threads_than_it_starts() {
    let spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 3);
    let members = vec![(spec.q0.clone(), spec.v0.clone()); 2];
    let start = std::time::Instant::now();
    for threads in [problems::run::MAX_ENSEMBLE_THREADS + 1, 1 << 40, usize::MAX] {
        let err = problems::run::run_ensemble(&spec, &members, Some(threads)).unwrap_err().to_string();
        assert!(err.contains("more than 1024") && err.contains("cores"), "{err}");
    }
    assert!(start.elapsed().as_secs() < 5, "refused up front");
    assert_eq!(problems::run::run_ensemble(&spec, &members, Some(8)).unwrap().len(), 2);
}

/// An interval that is not a whole number of steps is refused however
/// many steps it holds (half a step off at 5·10⁸ steps too), with
/// suggestions that can be told apart; round-off of the division is not,
/// up to the largest run (10¹⁰ steps), beyond which the count is refused.
#[test]
fn an_interval_that_is_not_a_whole_number_of_steps_is_refused_at_any_length() {
    use problems::cli::step_count;
    assert_eq!(step_count(0.0, 150.0, 0.2), Ok(750));
    assert_eq!(step_count(0.0, 50_000_000.0, 0.1), Ok(500_000_000));
    assert_eq!(step_count(0.0, 1e9, 0.1), Ok(10_000_000_000));
    let err = step_count(0.0, 1e12, 0.1).unwrap_err();
    assert!(err.contains("more than 1e10"), "{err}");
    let err = step_count(0.0, 50_000_000.05, 0.1).unwrap_err();
    assert!(err.contains("not a whole number") && err.contains("--t-end 50000000 or 50000000.1"), "{err}");
    assert!(step_count(0.0, 5_000_000.05, 0.1).unwrap_err().contains("--t-end 5000000 or 5000000.1"));
    // Half a step rounds to one: the one end that is a whole number of
    // steps is named once, and its count in the singular.
    let err = step_count(0.0, 0.05, 0.1).unwrap_err();
    assert!(err.contains("use --t-end 0.1, or --h 0.05 (1 step)"), "{err}");
}

/// Far from t = 0 the given ends of an interval differ beyond fifteen
/// digits (at 1e17 by 16, one unit in the last place): the refusals print
/// them with every digit, as the suggested ends when fifteen would print
/// one of them as the given end.
#[test]
fn a_refused_interval_far_from_zero_prints_its_ends_apart() {
    use problems::cli::step_count;
    let (t0, t_end) = (1e17, 1e17 + 16.0);
    let err = step_count(t0, t_end, 1000.0).unwrap_err();
    assert!(
        err.contains("from t0 = 1e17 to --t-end 1.0000000000000002e17 is shorter than one step of --h 1000;"),
        "{err}"
    );
    let t_end = 1e17 + 1024.0;
    let err = step_count(t0, t_end, 1000.0).unwrap_err();
    assert!(err.contains("from t0 = 1e17 to --t-end 1.0000000000000102e17 is 1.024 steps of --h 1000,"), "{err}");
    assert!(err.contains("use --t-end 1.00000000000001e17 or 1.00000000000002e17, or --h 512 (2 steps)"), "{err}");
}

/// A run or an ensemble whose record would not fit in memory is refused
/// before any step (it would otherwise step until an allocation failure
/// aborts the process), with the record interval that fits; the run at
/// that interval passes the check.
#[test]
fn a_record_that_would_not_fit_is_refused_before_any_step() {
    let huge = RunSpec { steps: 1 << 62, ..RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 20) };
    let start = std::time::Instant::now();
    let err = run(&huge, &|_| true).unwrap_err().to_string();
    assert!(err.contains("more than the limit") && err.contains("-th step or fewer"), "{err}");
    let spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 1 << 24);
    let members = vec![(spec.q0.clone(), spec.v0.clone()); 4096];
    let err = problems::run::run_ensemble(&spec, &members, Some(1)).unwrap_err().to_string();
    assert!(err.contains("more than the limit"), "{err}");
    assert!(start.elapsed().as_secs() < 5, "refused up front, not after stepping");
}

#[test]
fn a_run_stops_at_the_first_progress_tick_that_says_so() {
    let mut spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 1 << 40);
    spec.record_every = 1 << 30;
    let ticks = std::sync::atomic::AtomicUsize::new(0);
    let tick = |n: u64| {
        assert_eq!(n, 4096);
        ticks.fetch_add(1, std::sync::atomic::Ordering::Relaxed) < 2
    };
    match run(&spec, &tick) {
        Err(RunError::Integration { source: IntegrationError::Stopped { steps, t, .. }, .. }) => {
            // The third tick said stop.
            assert_eq!(steps, 3 * 4096);
            assert!((t - 0.1 * steps as f64).abs() < 1e-9, "t = {t}");
        }
        other => panic!("expected a stopped run, got {other:?}"),
    }
}

/// A run whose steps fail at `h` and are halved says so: the statistics
/// count the halvings and the report names them; `max_halvings = 0` makes
/// the first failure an error, and a run that halves nothing reports
/// `steps` sub-steps of `|h|`. (The robot at h = 3 is far beyond its
/// paper step of 0.2: Newton diverges on three of its first four steps.)
#[test]
fn halved_steps_are_counted_and_reported() {
    let spec = RunSpec::paper(SystemKind::Robot, Method::Gauss, 2, 3.0, 4);
    let halved = run(&spec, &|_| true).unwrap();
    let s = halved.stats;
    assert_eq!((s.steps, s.rejected_steps, s.steps_with_rejections, s.substeps), (4, 3, 3, 7), "{s:?}");
    assert_eq!(s.smallest_step, 1.5);
    let report = problems::run::run_report(&halved, &spec);
    assert!(report.contains("| steps halved (Newton failed at h) | 3 of 4 steps, covered by 7 sub-steps"), "{report}");
    let json = serde_json::to_value(s).unwrap();
    assert_eq!(json["rejected_steps"], 3, "{json}");

    let err = run(&RunSpec { max_halvings: 0, ..spec.clone() }, &|_| true).unwrap_err();
    assert!(
        matches!(err, RunError::Integration { source: IntegrationError::Step { .. }, .. }),
        "max_halvings = 0 ends the run at the failure: {err:?}"
    );

    let fixed = run(&RunSpec::paper(SystemKind::Robot, Method::Gauss, 2, 0.2, 10), &|_| true).unwrap();
    let s = fixed.stats;
    assert_eq!((s.rejected_steps, s.steps_with_rejections, s.substeps, s.smallest_step), (0, 0, 10, 0.2), "{s:?}");
    let report = problems::run::run_report(&fixed, &RunSpec::paper(SystemKind::Robot, Method::Gauss, 2, 0.2, 10));
    assert!(report.contains("| steps halved (Newton failed at h) | none |"), "{report}");
}

/// A projected `v0` is reported beside the given one, so the report shows
/// the velocity the run integrated (its first sample's); a consistent `v0`
/// that is not projected keeps one row.
#[test]
fn the_report_names_the_projected_initial_velocity() {
    let mut spec = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 10);
    spec.v0 = vec![1.0, 1.0, 1.0];
    spec.consistency = spark_runtime::ConsistencyPolicy::Project { tolerance: 1e-12 };
    let result = run(&spec, &|_| true).unwrap();
    // The skate's blade at θ = 0 allows no ẏ: the nearest consistent v0.
    assert_eq!(result.initial_velocity(), Some(vec![1.0, 0.0, 1.0]));
    let report = problems::run::run_report(&result, &spec);
    assert!(report.contains("| v0 (given) | [1.0, 1.0, 1.0] |"), "{report}");
    assert!(report.contains("| v0 (projected onto the constraints, integrated) | [1.0, 0.0, 1.0] |"), "{report}");
    let plain = RunSpec::paper(SystemKind::Skate, Method::Gauss, 2, 0.1, 10);
    let report = problems::run::run_report(&run(&plain, &|_| true).unwrap(), &plain);
    assert!(report.contains(&format!("| v0 | {:?} |", plain.v0)) && !report.contains("v0 (given)"), "{report}");
}
