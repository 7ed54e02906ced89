//! The stress suite's cases at the quick scale: each case's
//! criteria must hold. `spark stress --full` runs the lengths the issue asks
//! for (10⁶ steps, t ∈ [0, 50000]); see docs/stress/report.md.

use problems::experiments::stress::{self, markdown, CaseReport, Scale, StressReport};

fn run(f: stress::CaseFn) -> CaseReport {
    f(Scale::Quick).expect("suite infrastructure")
}

/// Fails with the case's own report (criteria, measured figures, errors).
fn assert_passed(c: &CaseReport) {
    if !c.passed() {
        let text = markdown(&StressReport { scale: Scale::Quick, cases: vec![c.clone()], seconds: 0.0 });
        panic!("stress case `{}` failed:\n{text}", c.key);
    }
    assert!(c.figure.is_some(), "every case draws a figure");
}

#[test]
fn long_time_short_version() {
    let c = run(stress::long_runs::long_time);
    assert_passed(&c);
    assert_eq!(c.steps, 4 * 20_000);
    assert!(c.worst_residual <= 1e-12);
}

#[test]
fn chaos_short_version() {
    assert_passed(&run(stress::long_runs::chaos));
}

#[test]
fn high_order_reaches_round_off_and_plateaus() {
    assert_passed(&run(stress::accuracy::high_order));
}

#[test]
fn large_steps_fail_typed_and_rejection_rescues() {
    let c = run(stress::robustness::large_steps);
    assert_passed(&c);
    assert!(c.rejections > 0);
}

#[test]
fn stiff_spring() {
    let c = run(stress::robustness::stiff_spring);
    assert_passed(&c);
    // An unstable step map is refused with a typed error, never returned
    // as a success.
    let g = c.metric_value("Gauss s=2, ω·h = 1000").unwrap();
    assert!(g.starts_with("refuses: Step/EnergyDrift"), "{g}");
    assert!(c.errors.iter().any(|e| e.contains("energy drift") && e.contains("Gauss s=2, ω·h = 1000")));
}

/// The diagnosis behind the stiff case: Gauss s = 2's step map is unstable
/// at ω·h = 10³ only while the constraint direction turns (θ̇ ≠ 0), with a
/// radius tending to e^(θ̇h); Lobatto IIIA-B is unstable beyond ω·h = 2.
#[test]
fn stiff_step_map_radius() {
    use spark_runtime::Method;
    let r = |m, wh, th| stress::robustness::stiff_step_radius::<2, 11>(m, wh, 0.1, th).unwrap();
    let g = r(Method::Gauss, 1000.0, 1.0);
    assert!(g > 1.1 && g < 0.1f64.exp(), "{g}");
    assert!((r(Method::Gauss, 1000.0, 0.0) - 1.0).abs() < 1e-9);
    assert!((r(Method::Gauss, 100.0, 1.0) - 1.0).abs() < 1e-9);
    assert!((r(Method::LobattoIIIAB, 1.0, 1.0) - 1.0).abs() < 1e-9);
    assert!(r(Method::LobattoIIIAB, 10.0, 1.0) > 50.0);
}

#[test]
fn near_singular_constraints_detected() {
    let c = run(stress::robustness::near_singular);
    assert_passed(&c);
    assert!(c.warnings.iter().any(|w| w.contains("nearly singular")));
}

#[test]
fn non_reversible_oscillator_runs() {
    let c = run(stress::robustness::non_reversible);
    assert_passed(&c);
    // What Modin & Verdier report, measured: the reversible twin keeps a
    // bounded energy error, the non-reversible system drifts.
    let m = |k: &str| c.metric_value(k).unwrap().to_string();
    assert!(m("reversible, Gauss s=2: |E−E0|").starts_with("bounded"));
    assert!(m("non-reversible, Lobatto IIIB-A LDA (MP): |E−E0|").starts_with("DRIFTS"));
}

#[test]
fn rolling_disk_against_exact_solution() {
    assert_passed(&run(stress::accuracy::rolling_disk));
}

#[test]
fn rheonomic_affine_and_nonlinear_constraints_against_reference() {
    assert_passed(&run(stress::accuracy::against_reference));
}

#[test]
fn bad_input_is_typed_and_nothing_is_written() {
    let c = run(stress::robustness::bad_input);
    assert_passed(&c);
    assert!(c.checks.len() >= 15);
}

#[test]
fn report_is_written_only_after_every_case() {
    let dir = std::env::temp_dir().join(format!("spark-stress-{}", std::process::id()));
    let report = stress::run_all(Scale::Quick, &["bad_input".to_string()], &|_| {}).unwrap();
    let written = stress::write_report(&report, &dir).unwrap();
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains("Bad input") && md.contains("![Bad input](bad_input.png)"));
    assert!(
        written.iter().any(|p| p.ends_with("bad_input.png")) && written.iter().any(|p| p.ends_with("bad_input.svg"))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
