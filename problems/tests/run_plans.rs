//! Runs that are not fixed steps recorded at the steps: tolerance-driven
//! steps, output times from the continuous extension and located events,
//! through `problems::run` (what `spark run` and the Python package call)
//! and through `spark run --rtol/--atol/--sample-every/--events`.

use problems::catalog::SystemKind;
use problems::run::{run, RunError, RunSpec};
use spark_runtime::{Method, Tolerance};
use std::path::PathBuf;
use std::process::Command;

fn tolerance(rtol: f64, t_end: f64) -> Tolerance {
    Tolerance { rtol, atol: rtol, first_step: None, max_step: None, max_steps: 100_000, t_end }
}

fn sleigh(stages: usize) -> RunSpec {
    RunSpec::defaults(SystemKind::Sleigh, Method::Gauss, stages)
}

#[test]
fn a_tolerance_driven_run_lands_on_t_end_and_follows_its_tolerance() {
    // The reference: Gauss s = 4 at a hundredth of the registered step.
    let base = sleigh(4);
    let fine = RunSpec { h: base.h / 100.0, steps: base.steps * 100, record_every: base.steps * 100, ..base.clone() };
    let reference = run(&fine, &|_| true).unwrap();
    let t_end = base.t0 + base.steps as f64 * base.h;
    let end = |r: &problems::run::RunResult, i: usize| *r.q[i].last().unwrap();
    let mut errors = Vec::new();
    for rtol in [1e-6, 1e-10] {
        let spec = RunSpec { tolerance: Some(tolerance(rtol, t_end)), ..sleigh(2) };
        let r = run(&spec, &|_| true).unwrap();
        let c = r.controller.expect("a tolerance-driven run reports its controller");
        assert_eq!(*r.t.last().unwrap(), t_end, "the last step lands on t_end");
        assert_eq!(r.t.len(), c.accepted + 1, "every accepted step is recorded");
        assert_eq!(r.stats.steps, c.accepted);
        assert!(c.smallest_step < c.largest_step, "the steps vary: {c:?}");
        let steps: Vec<f64> = r.t.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&h| h > 0.0 && h <= c.largest_step * (1.0 + 1e-12)));
        let error = (0..3).map(|i| (end(&r, i) - end(&reference, i)).abs()).fold(0.0f64, f64::max);
        errors.push(error);
        assert!(error < 100.0 * rtol, "rtol = {rtol:e}: error at t_end {error:e}");
    }
    // Gauss s = 2 (order 4) at 1e4 times the tolerance: 2.4e-7 against 6.3e-10.
    assert!(errors[1] < 1e-2 * errors[0], "{errors:?}");
}

#[test]
fn output_times_on_step_ends_are_the_steps_bit_for_bit() {
    let plain = run(&sleigh(3), &|_| true).unwrap();
    // Every third step end, as the plain run's samples spell them.
    let times: Vec<f64> = plain.t.iter().skip(3).step_by(3).copied().collect();
    let sampled = run(&RunSpec { times: Some(times.clone()), ..sleigh(3) }, &|_| true).unwrap();
    assert_eq!(sampled.t.len(), times.len() + 1);
    assert_eq!(sampled.t[1..], times[..]);
    for (k, &t) in times.iter().enumerate() {
        let j = plain.t.iter().position(|&u| u == t).unwrap();
        for i in 0..3 {
            assert_eq!(sampled.q[i][k + 1].to_bits(), plain.q[i][j].to_bits(), "q{i} at t = {t}");
            assert_eq!(sampled.v[i][k + 1].to_bits(), plain.v[i][j].to_bits(), "v{i} at t = {t}");
        }
    }
    // A time outside the run's interval is refused, naming it.
    let t_end = plain.t.last().copied().unwrap();
    let err = run(&RunSpec { times: Some(vec![1.0, t_end + 1.0]), ..sleigh(3) }, &|_| true).unwrap_err();
    assert!(matches!(err, RunError::Plan { .. }), "{err:?}");
    assert!(err.to_string().contains("outside the interval"), "{err}");
}

#[test]
fn events_are_located_when_asked_for_with_either_stepping() {
    // The sleigh declares `turn: falling(dot(theta))`.
    let t_end = sleigh(2).t_end();
    for spec in [
        RunSpec { events: true, ..sleigh(2) },
        RunSpec { events: true, tolerance: Some(tolerance(1e-9, t_end)), ..sleigh(2) },
    ] {
        let r = run(&spec, &|_| true).unwrap();
        assert!(!r.events.is_empty(), "the sleigh turns by t = {t_end}");
        for e in &r.events {
            assert_eq!((e.name.as_str(), e.rising, e.terminal), ("turn", false, false));
            assert!(e.v[2].abs() < 1e-9, "dot(theta) = {:e} at the located turn", e.v[2]);
            assert!(e.t > spec.t0 && e.t < t_end);
        }
        let quiet = run(&RunSpec { events: false, ..spec.clone() }, &|_| true).unwrap();
        assert!(quiet.events.is_empty());
        assert_eq!(quiet.t, r.t, "locating events does not change the steps");
    }
    let err = run(&RunSpec { events: true, ..RunSpec::defaults(SystemKind::Skate, Method::Gauss, 2) }, &|_| true)
        .unwrap_err();
    assert!(err.to_string().contains("declares no events"), "{err}");
}

fn out_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spark-run-plans-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn spark(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_spark")).args(args).output().unwrap()
}

#[test]
fn spark_run_writes_tolerance_driven_sampled_runs_and_their_events() {
    let dir = out_dir("sleigh");
    let out = dir.to_str().unwrap();
    let args = ["run", "sleigh", "--rtol", "1e-8", "--sample-every", "0.5", "--events", "--no-plot", "--out", out];
    let o = spark(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(dir.join("sleigh_gauss_s2.csv")).unwrap();
    let times: Vec<f64> = csv.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect();
    let expected: Vec<f64> = (0..=20).map(|k| 0.5 * k as f64).collect();
    assert_eq!(times, expected);
    let events = std::fs::read_to_string(dir.join("events.csv")).unwrap();
    let mut lines = events.lines();
    assert_eq!(lines.next().unwrap(), "event,index,direction,terminal,t,q_x,q_y,q_theta,v_x,v_y,v_theta,step");
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(!rows.is_empty());
    for row in &rows {
        assert_eq!(&row[..4], &["turn", "0", "falling", "false"]);
        let v_theta: f64 = row[10].parse().unwrap();
        assert!(v_theta.abs() < 1e-9, "{row:?}");
    }
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    for row in ["steps (tolerance-driven)", "steps rejected", "samples", "events located"] {
        assert!(report.contains(row), "report.md lacks `{row}`:\n{report}");
    }
    assert!(!report.contains("steps halved"), "halving does not apply to a tolerance-driven run");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert!(json["controller"]["accepted"].as_u64().unwrap() > 10);
    assert_eq!(json["tolerance"]["rtol"].as_f64(), Some(1e-8));
    assert_eq!(json["events"].as_array().unwrap().len(), rows.len());
    // The next run without --events leaves no events.csv of this one behind.
    let o = spark(&["run", "sleigh", "--no-plot", "--out", out]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!dir.join("events.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn spark_run_refuses_what_does_not_apply_naming_the_flag() {
    let dir = out_dir("refused");
    let out = dir.to_str().unwrap();
    for (args, expected) in [
        (&["run", "skate", "--events"][..], "declares no events"),
        (&["run", "skate", "--max-step", "0.1"][..], "--max-step applies to tolerance-driven runs"),
        (&["run", "skate", "--rtol", "-1"][..], "--rtol must be a finite number"),
        (&["run", "skate", "--rtol", "0", "--atol", "0"][..], "both 0"),
        // Tolerances that control nothing: a relative error as large as
        // the state, an absolute one above any state.
        (&["run", "skate", "--rtol", "1e300"][..], "--rtol 1.000e300: a relative tolerance must lie below 1"),
        (&["run", "skate", "--rtol", "1"][..], "--rtol 1.000e0: a relative tolerance must lie below 1"),
        (&["run", "skate", "--atol", "2"][..], "--atol (without --rtol, the relative tolerance too) 2.000e0"),
        (&["run", "skate", "--rtol", "1e-6", "--atol", "1e300"][..], "--atol 1.000e300 is above 1.34e154"),
        (&["run", "skate", "--rtol", "1e-6", "--h", "0.1"][..], "cannot be used with"),
        (&["run", "skate", "--sample-every", "0"][..], "--sample-every must be a positive number"),
        (&["run", "skate", "--sample-every", "1", "--every", "2"][..], "cannot be used with"),
        (&["run", "skate", "--rtol", "1e-12", "--max-steps", "3"][..], "--max-steps"),
        // A fixed-step run would ignore a step limit.
        (&["run", "skate", "--max-steps", "10"][..], "--max-steps applies to tolerance-driven runs"),
        (&["run", "skate", "--rtol", "1e-6", "--max-steps", "-1"][..], "invalid value '-1' for '--max-steps"),
        (&["run", "skate", "--every", "-2"][..], "invalid value '-2' for '--every"),
        (&["run", "skate", "--rtol", "1e-6", "--first-step", "1e-320"][..], "--first-step 1.000e-320 is subnormal"),
        // The advice names flags that apply to the run: a larger DT for
        // output times, a lower step limit for a tolerance-driven run.
        (&["run", "skate", "--sample-every", "1e-7"][..], "give a --sample-every of 8.000e-7 or more"),
        (&["run", "skate", "--rtol", "1e-6", "--max-steps", "1000000000000"][..], "or lower --max-steps"),
    ] {
        let o =
            Command::new(env!("CARGO_BIN_EXE_spark")).args(args).args(["--no-plot", "--out", out]).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "spark {args:?} should fail");
        assert!(stderr.contains(expected), "spark {args:?}: expected `{expected}` in\n{stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Far from t = 0 time itself is coarse (1.2e-4 apart at 1e12): a fixed
/// step below 16 units in the last place there is refused, where the
/// rounded times t0 + k·h would repeat (1e-4: steps 2 and 3 both ended at
/// 1e12 + 2.44e-4) or space unevenly; a step above it runs, to the --t-end
/// given (the interval, itself rounded, is not a whole number of steps,
/// but the last step's time rounds to it), with strictly increasing times.
/// A tolerance-driven run starts there from the resolution of t when its
/// estimated first step lies below it.
#[test]
fn runs_far_from_t_zero_have_times_that_advance_by_their_steps() {
    let dir = out_dir("far");
    let out = dir.to_str().unwrap();
    for h in ["1e-4", "1e-3"] {
        let o = spark(&["run", "skate", "--t0", "1e12", "--h", h, "--t-end", "1000000000000.003", "--out", out]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains("resolution of t at t0"), "--h {h}: {stderr}");
    }
    let times = |args: &[&str]| -> Vec<f64> {
        let o = spark(&[args, &["--no-plot", "--out", out]].concat());
        assert!(o.status.success(), "spark {args:?}: {}", String::from_utf8_lossy(&o.stderr));
        let csv = std::fs::read_to_string(dir.join("skate_gauss_s2.csv")).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect()
    };
    let fixed = times(&["run", "skate", "--t0", "1e12", "--h", "4e-3", "--t-end", "1000000000000.04"]);
    assert_eq!(fixed.len(), 11);
    assert_eq!((fixed[0], fixed[10]), (1e12, 1000000000000.04));
    assert!(fixed.windows(2).all(|w| w[1] > w[0]), "{fixed:?}");
    let adaptive = times(&["run", "skate", "--t0", "1e12", "--rtol", "1e-6", "--t-end", "1000000000001"]);
    assert_eq!((adaptive[0], *adaptive.last().unwrap()), (1e12, 1000000000001.0));
    assert!(adaptive.windows(2).all(|w| w[1] > w[0]), "{adaptive:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A parameter that makes the kinetic energy negative on the motions the
/// constraints allow (a negative mass or inertia) is refused before the
/// run, naming it, rather than integrated into a motion no mechanical
/// system has; negative values of other parameters (an inclination, a
/// gravity pointing the other way) run.
#[test]
fn a_negative_mass_is_refused_and_other_negative_parameters_run() {
    let dir = out_dir("mass");
    let out = dir.to_str().unwrap();
    for (param, name) in [("m=-1", "m = -1.000e0"), ("inertia=-2", "inertia = -2.000e0")] {
        let o = spark(&["run", "skate", "--param", param, "--t-end", "1", "--no-plot", "--out", out]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "--param {param} should fail");
        for w in ["kinetic energy is not positive", "Parameters that are negative here", name] {
            assert!(stderr.contains(w), "--param {param}: expected `{w}` in\n{stderr}");
        }
        assert!(!dir.join("report.md").exists());
    }
    // Both negative: the kinetic energy is negative definite, still refused.
    let mut spec = RunSpec::defaults(SystemKind::Skate, Method::Gauss, 2);
    spec.parameters = vec![("m".into(), -1.0), ("inertia".into(), -1.0)];
    let err = run(&spec, &|_| true).unwrap_err();
    assert!(matches!(err, RunError::KineticEnergy { .. }), "{err}");
    assert!(err.to_string().contains("2 directions"), "{err}");
    spec.parameters = vec![("g".into(), -9.81), ("beta".into(), -0.5)];
    run(&spec, &|_| true).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
