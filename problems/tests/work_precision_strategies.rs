//! Work-precision with every step-size strategy: fixed, error-controlled
//! and reversible steps of the generated stepper measured in one run, and
//! the Python peers handed the system that is measured.

use problems::catalog::{entries, SystemKind};
use problems::experiments::work_precision::external::source_of;
use problems::experiments::work_precision::report::{strategy_table, SPARK};
use problems::experiments::work_precision::{
    method_variants, run_work_precision, step_density, Point, WorkPrecisionConfig, SPARK_ADAPTIVE, SPARK_REVERSIBLE,
};
use spark_runtime::adaptive::is_symmetric;

fn temp_dir(tag: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("spark-wp-strategies-{tag}-{}", std::process::id()))
}

/// The points of one `(solver, method)` curve, in sweep order (tolerances
/// from loose to tight).
fn curve<'a>(points: &'a [Point], solver: &str, method: &str) -> Vec<&'a Point> {
    points.iter().filter(|p| p.solver == solver && p.method == method).collect()
}

/// Errors must fall as the tolerance tightens (100× per tolerance here).
fn assert_error_falls(c: &[&Point], what: &str) {
    assert!(c.len() >= 2, "{what}: fewer than two points: {c:?}");
    for w in c.windows(2) {
        assert!(w[1].setting < w[0].setting, "{what}: tolerances not tightening: {c:?}");
        assert!(w[1].error() < w[0].error(), "{what}: error does not fall as rtol falls: {c:?}");
    }
}

/// The reversible rule takes its scale from the tolerance once, and loose
/// tolerances may all be capped at the sweep's largest step (the same run):
/// errors must not grow as the tolerance tightens, and must fall overall.
fn assert_error_does_not_grow(c: &[&Point], what: &str) {
    assert!(c.len() >= 2, "{what}: fewer than two points: {c:?}");
    for w in c.windows(2) {
        assert!(w[1].setting < w[0].setting, "{what}: tolerances not tightening: {c:?}");
        assert!(w[1].error() <= w[0].error(), "{what}: error grows as rtol falls: {c:?}");
    }
    assert!(c[c.len() - 1].error() < c[0].error() / 10.0, "{what}: error does not fall: {c:?}");
}

/// On the orbit (time scale varying by ≈ 100 around the orbit), the sweep
/// measures error-controlled steps for every method of order ≥ 2 and the
/// reversible rule only for symmetric ones, both with errors falling as the
/// tolerance falls, and reports them against the best fixed step.
#[test]
fn orbit_sweep_measures_adaptive_and_reversible_steps_next_to_fixed_steps() {
    let dir = temp_dir("orbit");
    let mut cfg = WorkPrecisionConfig::quick(&dir);
    cfg.systems = vec![SystemKind::Orbit];
    cfg.final_time = 3.0;
    cfg.max_steps = 4096;
    cfg.tolerances = vec![1e-5, 1e-7, 1e-9];
    let all = run_work_precision(&cfg, &|_| {}).unwrap();
    let m = &all[0];
    for (method, s) in method_variants() {
        let label = method.label(s);
        assert!(!curve(&m.points, SPARK, &label).is_empty(), "no fixed-step point for {label}");
        // First-order methods may not meet even 1e-3 within the step budget.
        if method.order(s) >= 2 {
            assert!(!curve(&m.points, SPARK_ADAPTIVE, &label).is_empty(), "no adaptive point for {label}");
        }
        if !is_symmetric(method) {
            assert!(curve(&m.points, SPARK_REVERSIBLE, &label).is_empty(), "reversible points for {label}");
        }
    }
    for label in ["Gauss s=2", "Gauss s=4", "Lobatto IIIA-B s=3"] {
        assert_error_falls(&curve(&m.points, SPARK_ADAPTIVE, label), &format!("adaptive {label}"));
    }
    for label in ["Gauss s=2", "Lobatto IIIA-B s=3"] {
        assert_error_does_not_grow(&curve(&m.points, SPARK_REVERSIBLE, label), &format!("reversible {label}"));
    }
    let table = strategy_table(m, &cfg.targets);
    for row in ["SPARK fixed steps", "SPARK adaptive (rtol = atol)", "SPARK reversible adaptive", "ode_solvers"] {
        assert!(table.contains(row), "no row `{row}` in\n{table}");
    }
    let md = std::fs::read_to_string(dir.join("orbit.md")).unwrap();
    assert!(md.contains("Fixed against adaptive steps"), "{md}");
    assert!(dir.join("orbit-adaptive.png").exists() && dir.join("orbit-adaptive.svg").exists());
    // SciPy runs on the orbit when a Python interpreter is configured.
    assert!(m.missing.iter().any(|s| s.starts_with("SciPy: not run (no Python")), "{:?}", m.missing);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The paper's systems have no step density: error-controlled steps only.
#[test]
fn skate_sweep_measures_adaptive_steps_with_errors_falling_with_the_tolerance() {
    let dir = temp_dir("skate");
    let mut cfg = WorkPrecisionConfig::quick(&dir);
    cfg.systems = vec![SystemKind::Skate];
    cfg.max_steps = 1024;
    cfg.tolerances = vec![1e-4, 1e-6, 1e-8];
    let all = run_work_precision(&cfg, &|_| {}).unwrap();
    let m = &all[0];
    assert!(step_density(SystemKind::Skate).is_none());
    assert!(!m.points.iter().any(|p| p.solver == SPARK_REVERSIBLE));
    for label in ["Gauss s=2", "Lobatto IIIA-B s=3"] {
        assert_error_falls(&curve(&m.points, SPARK_ADAPTIVE, label), &format!("adaptive {label}"));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The SciPy peers rebuild the measured system from its source: every
/// registered system hands over its own coordinates and Lagrangian.
#[test]
fn peers_get_the_source_of_the_measured_system() {
    for e in entries() {
        let src = source_of(e.kind);
        assert_eq!(src.coordinates, e.coordinates, "{}", e.name);
        assert_eq!(src.parameters.len(), e.parameter_names.len(), "{}", e.name);
    }
    assert!(source_of(SystemKind::Orbit).lagrangian.contains("softening"));
}
