//! The catalogue as the command line sees it: every registered system
//! runs through the one stage dispatch with every method family, names are
//! looked up forgivingly with useful errors, `spark run` works end to end,
//! and work-precision measures a system that is not in the paper.

use problems::catalog::{edit_distance, entries, lookup, SystemKind, MAX_DISPATCH_STAGES};
use problems::experiments::work_precision::{
    method_variants, run_work_precision, Provider, WorkPrecisionConfig, SPARK_ADAPTIVE,
};
use problems::run::{run, RunError, RunSpec};
use spark_runtime::{ConstraintForm, Jacobian, Method, NewtonMode, NewtonOptions, HISTORY_CAPACITY};
use std::path::PathBuf;
use std::process::Command;

/// Every method family at every stage count the dispatch compiles.
fn all_method_variants() -> Vec<(Method, usize)> {
    let mut v = Vec::new();
    for m in [
        Method::Gauss,
        Method::LobattoIIIAB,
        Method::LobattoIIIABD,
        Method::SymplecticEulerI,
        Method::SymplecticEulerII,
        Method::ModifiedLobattoIIIAB,
        Method::LobattoIIIBALda,
    ] {
        let (lo, hi) = m.stage_range();
        v.extend((lo..=hi.min(MAX_DISPATCH_STAGES)).map(|s| (m, s)));
    }
    v
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spark-registry-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn every_entry_agrees_with_its_type_and_has_a_consistent_default_state() {
    assert!(entries().len() >= 21, "registry shrank: {}", entries().len());
    for e in entries() {
        assert_eq!(e.coordinates.len(), e.n, "{}", e.name);
        assert_eq!(e.m == 0, e.structure.constraint_form == ConstraintForm::None, "{}", e.name);
        assert_eq!(e.default_parameters().len(), e.parameter_names.len(), "{}", e.name);
        assert!(e.h > 0.0 && e.t_end > 0.0, "{}", e.name);
        // Consistency of (t0, q0, v0) is checked by the run itself (it
        // refuses an inconsistent state); one step of Gauss s=1 suffices.
        let spec = RunSpec { steps: 1, ..RunSpec::defaults(e.kind, Method::Gauss, 1) };
        let r = run(&spec, &|_| true).unwrap_or_else(|err| panic!("{}: {err}", e.name));
        assert!(r.stats.max_constraint_residual < 1e-12, "{}: |k| = {:e}", e.name, r.stats.max_constraint_residual);
        if e.effects.holonomic {
            assert!(r.stats.max_holonomic_drift.is_some(), "{}: no drift reported", e.name);
        }
    }
    let names: Vec<&str> = entries().iter().map(|e| e.name).collect();
    for (i, a) in names.iter().enumerate() {
        assert!(!names[i + 1..].contains(a), "name `{a}` registered twice");
    }
    let paper: Vec<&str> = entries().iter().filter(|e| e.paper).map(|e| e.name).collect();
    assert_eq!(paper, ["particle", "skate", "robot", "mp7"]);
}

/// Three steps of every registered system with every family and stage
/// count, through the shared dispatch. Constraint residuals stay at round-off.
#[test]
fn every_system_steps_with_every_method_family_and_stage_count() {
    let mut failures = Vec::new();
    let mut runs = 0;
    for e in entries() {
        for (method, s) in all_method_variants() {
            let spec = RunSpec { steps: 3, ..RunSpec::defaults(e.kind, method, s) };
            match run(&spec, &|_| true) {
                Ok(r) => {
                    runs += 1;
                    assert_eq!(r.stats.steps, 3);
                    assert_eq!(r.stages, s);
                    assert_eq!(r.t.len(), 4);
                    if r.stats.max_constraint_residual > 1e-11 {
                        failures
                            .push(format!("{} {method} s={s}: |k| = {:e}", e.name, r.stats.max_constraint_residual));
                    }
                }
                Err(err) => failures.push(format!("{} {method} s={s}: {err}", e.name)),
            }
        }
    }
    assert!(failures.is_empty(), "{} of {} runs failed:\n{}", failures.len(), runs, failures.join("\n"));
}

/// Newton's stopping rule costs no accuracy: three steps of every registered
/// system with every family and stage count, at its registered step size
/// (the paper's for the paper's systems), with full Newton and with
/// simplified Newton on the exact and on the stage-decoupled matrix, equal
/// full Newton iterated to the round-off floor (tolerance 0) to 1e-14 in
/// `|Δx| / max(1, |x|)` at every step, cold and warm-started.
#[test]
fn converged_steps_equal_the_tight_solve_in_both_newton_modes() {
    let tight = NewtonOptions { tolerance: 0.0, max_iterations: HISTORY_CAPACITY, ..NewtonOptions::default() };
    let distance = |a: &[Vec<f64>], b: &[Vec<f64>]| {
        a.iter()
            .zip(b)
            .flat_map(|(x, y)| x.iter().zip(y).map(|(x, y)| (x - y).abs() / y.abs().max(1.0)))
            .fold(0.0f64, |m, d| if d.is_nan() { f64::INFINITY } else { m.max(d) })
    };
    let (mut failures, mut runs, mut worst) = (Vec::new(), 0, (0.0f64, String::new()));
    for e in entries() {
        for (method, s) in all_method_variants() {
            let base = RunSpec { steps: 3, ..RunSpec::defaults(e.kind, method, s) };
            let reference = match run(&RunSpec { newton: tight, ..base.clone() }, &|_| true) {
                Ok(r) => r,
                Err(err) => {
                    failures.push(format!("{} {method} s={s} tight: {err}", e.name));
                    continue;
                }
            };
            for (mode, jacobian) in [
                (NewtonMode::Full, Jacobian::Exact),
                (NewtonMode::Simplified, Jacobian::Exact),
                (NewtonMode::Simplified, Jacobian::StageDecoupled),
            ] {
                let newton = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
                let spec = RunSpec { newton, ..base.clone() };
                match run(&spec, &|_| true) {
                    Ok(r) => {
                        runs += 1;
                        let d = distance(&r.q, &reference.q).max(distance(&r.v, &reference.v));
                        let label = format!("{} {method} s={s} {mode:?} {jacobian:?}", e.name);
                        if d > worst.0 {
                            worst = (d, label.clone());
                        }
                        if d > 1e-14 {
                            failures.push(format!("{label}: {d:.3e} from the tight solve"));
                        }
                    }
                    Err(err) => failures.push(format!("{} {method} s={s} {mode:?} {jacobian:?}: {err}", e.name)),
                }
            }
        }
    }
    println!("{runs} runs, largest difference {:.3e} ({})", worst.0, worst.1);
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

/// The drift `max |g|` of a holonomic constraint imposed at velocity level
/// is reported, for the hand-written type and for the generated scene alike.
/// `g = ½(x² + y² − ℓ²)` is quadratic, and `k = ġ` is kept at round-off, so
/// Gauss s = 2 keeps `g` at round-off too (measured 1.3e-15 over t ∈ [0, 10]),
/// while Lobatto IIIA-B-D s = 2 lets it drift (measured 9.8e-8).
#[test]
fn holonomic_drift_is_reported_for_holonomic_systems() {
    for name in ["rod-pendulum-hand", "rod-pendulum"] {
        let kind = SystemKind::parse(name).unwrap();
        let drift = |method, s| {
            let spec = RunSpec { steps: 200, ..RunSpec::defaults(kind, method, s) };
            let r = run(&spec, &|_| true).unwrap();
            assert_eq!(r.holonomic.len(), r.t.len());
            assert!(r.stats.max_constraint_residual < 1e-13, "{name}: |k| {:e}", r.stats.max_constraint_residual);
            r.stats.max_holonomic_drift.expect("holonomic system reports drift")
        };
        let gauss = drift(Method::Gauss, 2);
        let lobatto_d = drift(Method::LobattoIIIABD, 2);
        assert!(gauss < 1e-13, "{name}: Gauss s=2 drift {gauss:e}");
        assert!(lobatto_d > 1e-9 && lobatto_d < 1e-5, "{name}: IIIA-B-D s=2 drift {lobatto_d:e}");
    }
    // Non-holonomic systems report none.
    let skate = RunSpec { steps: 2, ..RunSpec::defaults(SystemKind::Skate, Method::Gauss, 2) };
    let r = run(&skate, &|_| true).unwrap();
    assert!(r.stats.max_holonomic_drift.is_none() && r.holonomic.is_empty());
}

#[test]
fn lookup_ignores_case_and_separators_and_suggests_near_misses() {
    assert_eq!(lookup("Skate").unwrap().name, "skate");
    assert_eq!(lookup("BODY_SKATING").unwrap().name, "body-skating");
    assert_eq!(lookup("BallOnTurntable").unwrap().name, "ball-on-turntable");
    assert_eq!(lookup("McLachlanPerlmutter7").unwrap().name, "mp7");
    // A name beats a type name: the scene is `rod-pendulum`, the
    // hand-written type of the same name `rod-pendulum-hand`.
    assert_eq!(lookup("RodPendulum").unwrap().path, "crate::systems::scenes::RodPendulum");
    let err = lookup("skat").unwrap_err();
    assert_eq!(err.suggestion, Some("skate"));
    let text = err.to_string();
    assert!(text.contains("did you mean `skate`") && text.contains("double-pendulum"), "{text}");
    let err = lookup("vertical-disc").unwrap_err();
    assert_eq!(err.suggestion, Some("vertical-disk"));
    let err = lookup("zzzzzzzz").unwrap_err();
    assert_eq!(err.suggestion, None);
    assert!(lookup("").is_err());
}

#[test]
fn bad_run_inputs_get_actionable_errors() {
    let skate = || RunSpec { steps: 2, ..RunSpec::defaults(SystemKind::Skate, Method::Gauss, 2) };
    // Unknown parameter, with a suggestion and the list.
    let spec = RunSpec { parameters: vec![("bta".into(), 0.5)], ..skate() };
    let text = run(&spec, &|_| true).unwrap_err().to_string();
    assert!(
        text.contains("`bta`") && text.contains("did you mean `beta`") && text.contains("m, inertia, g, beta"),
        "{text}"
    );
    // A known parameter is accepted.
    assert!(run(&RunSpec { parameters: vec![("beta".into(), 0.5)], ..skate() }, &|_| true).is_ok());
    // Wrong vector length names the coordinates.
    let text = run(&RunSpec { q0: vec![0.0; 2], ..skate() }, &|_| true).unwrap_err().to_string();
    assert!(text.contains("q0 has 2 entries") && text.contains("x, y, theta"), "{text}");
    // Inconsistent velocity: says how to fix it.
    let err = run(&RunSpec { v0: vec![0.0, 1.0, 0.0], ..skate() }, &|_| true).unwrap_err();
    assert!(matches!(err, RunError::InconsistentVelocities { .. }), "{err}");
    assert!(err.to_string().contains("--project-v0"));
    // Inconsistent position of a holonomic system.
    let rod = SystemKind::parse("rod-pendulum-hand").unwrap();
    let spec = RunSpec { q0: vec![1.0, 1.0], v0: vec![0.0, 0.0], ..RunSpec::defaults(rod, Method::Gauss, 2) };
    let err = run(&spec, &|_| true).unwrap_err();
    assert!(matches!(err, RunError::InconsistentPositions { .. }), "{err}");
    // Stage counts: beyond the method's range, and beyond what is compiled.
    let err =
        run(&RunSpec { stages: 3, ..RunSpec::defaults(SystemKind::Skate, Method::SymplecticEulerI, 3) }, &|_| true);
    assert!(matches!(err, Err(RunError::Tableau(_))));
    let err = run(&RunSpec { stages: 6, ..RunSpec::defaults(SystemKind::Skate, Method::Gauss, 6) }, &|_| true);
    assert!(matches!(err, Err(RunError::StagesNotCompiled { stages: 6, max: MAX_DISPATCH_STAGES, .. })), "{err:?}");
}

#[test]
fn spark_run_writes_trajectory_report_and_figure() {
    let dir = temp_dir("run");
    let out = Command::new(env!("CARGO_BIN_EXE_spark"))
        .args(["run", "rod-pendulum-hand", "--method", "gauss", "--stages", "2", "--h", "0.05", "--t-end", "1"])
        .args(["--param", "ell=1", "--format", "both", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    // The report's Markdown escapes the `|` inside its cells.
    assert!(stdout.contains(r"max \|g\| (holonomic drift"), "{stdout}");
    for f in [
        "rod-pendulum-hand_gauss_s2.csv",
        "rod-pendulum-hand_gauss_s2.json",
        "rod-pendulum-hand_gauss_s2.png",
        "rod-pendulum-hand_gauss_s2.svg",
        "report.md",
        "report.json",
    ] {
        assert!(dir.join(f).exists(), "{f} not written");
    }
    let csv = std::fs::read_to_string(dir.join("rod-pendulum-hand_gauss_s2.csv")).unwrap();
    assert!(csv.lines().next().unwrap().ends_with("holonomic_drift"), "{}", csv.lines().next().unwrap());
    assert_eq!(csv.lines().count(), 1 + 21);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["stats"]["steps"], 20);
    assert!(report["stats"]["max_holonomic_drift"].as_f64().unwrap() < 1e-6);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn spark_cli_errors_are_actionable_and_list_has_every_system() {
    let spark = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_spark")).args(args).output().unwrap();
    let out = spark(&["run", "sleigth", "--out", "/nonexistent/never-written"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown system `sleigth`") && err.contains("did you mean `sleigh`"), "{err}");
    let out = spark(&["run", "skate", "--method", "gaus", "--out", "/nonexistent/never-written"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("did you mean `gauss`"), "{err}");
    let out = spark(&["run", "skate", "--q0", "1,2", "--out", "/nonexistent/never-written"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("q0 has 2 entries"), "{err}");
    let out = spark(&["list", "--json"]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let systems = v["systems"].as_array().unwrap();
    assert_eq!(systems.len(), entries().len());
    let rod = systems.iter().find(|s| s["name"] == "rod-pendulum-hand").unwrap();
    assert_eq!(rod["effects"]["holonomic"], true);
    assert_eq!(rod["n"], 2);
    let out = spark(&["list"]);
    let table = String::from_utf8_lossy(&out.stdout);
    for e in entries() {
        assert!(table.contains(e.name), "{} missing from `spark list`", e.name);
    }
}

/// Work-precision on a system outside the paper, at a tiny sweep: every
/// SPARK method is measured against the reference, the peers that exist only
/// for the paper's systems are skipped with a reason.
#[test]
fn work_precision_measures_a_system_outside_the_paper() {
    let dir = temp_dir("wp");
    let mut cfg = WorkPrecisionConfig::quick(&dir);
    cfg.systems = vec![SystemKind::parse("driven-skate").unwrap()];
    cfg.max_steps = 32;
    let all = run_work_precision(&cfg, &|_| {}).unwrap();
    let m = &all[0];
    assert_eq!(m.problem.system, "driven-skate");
    for (method, s) in method_variants() {
        let label = method.label(s);
        assert!(
            m.points.iter().any(|p| p.solver == Provider::Generated.label() && p.method == label),
            "no point for {label}"
        );
    }
    // Gauss s=2 has order 4 on a forced system too: the reference (GBS on
    // the ψ-eliminated ODE with f) and the stepper agree as h shrinks.
    let g: Vec<_> =
        m.points.iter().filter(|p| p.solver == Provider::Generated.label() && p.method == "Gauss s=2").collect();
    assert!(g.len() >= 2 && g[1].error() < g[0].error() / 10.0, "Gauss s=2 errors {g:?}");
    // The generated stepper with fixed and with tolerance-driven steps; no peer.
    assert!(
        m.points.iter().all(|p| p.solver == Provider::Generated.label() || p.solver == SPARK_ADAPTIVE),
        "a peer ran on driven-skate"
    );
    assert!(
        m.points.iter().any(|p| p.solver == SPARK_ADAPTIVE && p.method == "Gauss s=2" && p.error() < 1e-3),
        "no adaptive Gauss s=2 point"
    );
    let missing = m.missing.join("\n");
    for peer in ["num-dual", "DOP853", "CasADi C and SciPy"] {
        assert!(missing.contains(peer), "no reason given for skipping {peer}: {missing}");
    }
    assert!(dir.join("driven-skate.csv").exists() && dir.join("summary.md").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn edit_distance_counts_single_edits() {
    assert_eq!(edit_distance("skate", "skate"), 0);
    assert_eq!(edit_distance("skat", "skate"), 1);
    assert_eq!(edit_distance("sakte", "skate"), 2);
    assert_eq!(edit_distance("", "abc"), 3);
}

#[test]
fn kinds_index_their_own_entries() {
    for (i, e) in entries().iter().enumerate() {
        assert_eq!(e.kind as usize, i);
        assert_eq!(e.kind.entry().name, e.name);
        assert_eq!(e.q0.len(), e.n, "{}: q0", e.name);
        assert_eq!(e.v0.len(), e.n, "{}: v0", e.name);
    }
}

/// `spark list` gives the modified Lobatto IIIA-B its order per system, as
/// the drivers take it ([`Method::order_for`]): 2 with a constant mass
/// matrix and separable L, and names the systems where it is 1.
#[test]
fn spark_list_names_the_systems_where_the_modified_lobatto_is_first_order() {
    use problems::cli::list::{list, ListArgs};
    let text = list(ListArgs { json: false }).unwrap();
    let key = Method::ModifiedLobattoIIIAB.key();
    let line = text.lines().find(|l| l.trim_start().starts_with(&format!("{key} "))).unwrap();
    assert!(line.contains("order 2 with a constant mass matrix and separable L; order 1 on "), "{line}");
    let named: Vec<&str> = line.split("order 1 on ").nth(1).unwrap().split(", ").collect();
    let first_order: Vec<&str> = entries()
        .iter()
        .filter(|e| !(e.structure.constant_mass_matrix && e.structure.separable))
        .map(|e| e.name)
        .collect();
    assert!(!first_order.is_empty());
    assert_eq!(named, first_order, "{line}");
    // The other methods' orders hold on every system: no caveat.
    for m in Method::ALL.into_iter().filter(|&m| m != Method::ModifiedLobattoIIIAB) {
        let line = text.lines().find(|l| l.trim_start().starts_with(&format!("{} ", m.key()))).unwrap();
        assert!(!line.contains("separable"), "{line}");
    }
}

/// `spark list --json` carries the orders the text listing prints: per
/// system, each method's order at each stage count as the drivers take it
/// ([`Method::order_for`], so the modified Lobatto IIIA-B is of order 1 on
/// the systems the text names), and per method the order the paper states.
#[test]
fn spark_list_json_gives_each_methods_order_per_system() {
    use problems::cli::list::{list, ListArgs};
    let v: serde_json::Value = serde_json::from_str(&list(ListArgs { json: true }).unwrap()).unwrap();
    let systems = v["systems"].as_array().unwrap();
    assert_eq!(systems.len(), entries().len());
    for (json, e) in systems.iter().zip(entries()) {
        assert_eq!(json["name"], e.name);
        let orders = json["orders"].as_object().unwrap_or_else(|| panic!("{}: no orders in {json}", e.name));
        assert_eq!(orders.len(), Method::ALL.len(), "{}", e.name);
        for m in Method::ALL {
            let (lo, hi) = m.stage_range();
            let per_stage = orders[m.key()].as_object().unwrap();
            assert_eq!(per_stage.len(), hi.min(MAX_DISPATCH_STAGES) - lo + 1, "{} {m}", e.name);
            for s in lo..=hi.min(MAX_DISPATCH_STAGES) {
                assert_eq!(per_stage[&s.to_string()], m.order_for(s, &e.structure), "{} {m} s = {s}", e.name);
            }
        }
    }
    let order = |name: &str, key: &str, s: usize| {
        systems.iter().find(|j| j["name"] == name).unwrap()["orders"][key][s.to_string()].clone()
    };
    assert_eq!(order("skate", "gauss", 3), 6);
    assert_eq!(order("skate", "lobatto-iiia-b", 2), 2);
    // The systems the text names after "order 1 on" are those with order 1 here.
    let text = list(ListArgs { json: false }).unwrap();
    let key = Method::ModifiedLobattoIIIAB.key();
    let line = text.lines().find(|l| l.trim_start().starts_with(&format!("{key} "))).unwrap();
    let named: Vec<&str> = line.split("order 1 on ").nth(1).unwrap().split(", ").collect();
    let first_order: Vec<&str> =
        systems.iter().filter(|j| j["orders"][key]["2"] == 1).map(|j| j["name"].as_str().unwrap()).collect();
    assert_eq!(named, first_order, "{line}");
    assert_eq!(order("skate", key, 2), 2);
    let methods = v["methods"].as_array().unwrap();
    assert_eq!(methods.len(), Method::ALL.len());
    for (json, m) in methods.iter().zip(Method::ALL) {
        assert_eq!((json["key"].as_str(), json["name"].as_str()), (Some(m.key()), Some(m.name())));
        let (lo, hi) = m.stage_range();
        assert_eq!(
            (json["min_stages"].as_u64(), json["max_stages"].as_u64()),
            (Some(lo as u64), Some(hi.min(MAX_DISPATCH_STAGES) as u64))
        );
        assert_eq!(json["orders"][lo.to_string()], m.order(lo), "{m}");
    }
}
