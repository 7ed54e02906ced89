//! The `spark` binary's output folder: results appear all at once or not at
//! all (an interrupted run leaves the previous ones intact), one run at a
//! time per folder, an unusable `--out` or argument is refused before any
//! computation, and output sizes stay bounded.

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The test-only pause (`problems::report::files::TEST_PAUSE_ENV`), spelled out so
/// that this file also builds against code without the hook.
const PAUSE_ENV: &str = "SPARK_TEST_PAUSE_AFTER_FIRST_FILE_MS";

fn spark() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_spark"));
    c.env_remove(PAUSE_ENV);
    c
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spark-cli-files-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn run_ok(args: &[&str], out: &Path) -> Output {
    let o = spark().args(args).arg("--out").arg(out).output().unwrap();
    assert!(o.status.success(), "spark {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    o
}

fn run_err(args: &[&str]) -> String {
    let o = spark().args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "spark {args:?} should fail; stdout:\n{}", String::from_utf8_lossy(&o.stdout));
    stderr
}

/// Contents of the files in `dir`: hidden ones (temporary files) included
/// or not; the lock file never.
fn snapshot(dir: &Path, hidden: bool) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name == ".spark-lock" || (!hidden && name.starts_with('.')) {
            continue;
        }
        // A file may be renamed away between listing and reading.
        if let Ok(bytes) = std::fs::read(entry.path()) {
            files.insert(name, bytes);
        }
    }
    files
}

fn wait_until(child: &mut Child, what: &str, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the run ended ({status}) before {what}");
        }
        assert!(start.elapsed() < Duration::from_secs(60), "timed out waiting until {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// A run interrupted in its write phase (SIGINT, SIGTERM, SIGHUP) leaves
/// the previous results intact and no temporary file, and ends by the
/// signal (status 128 + signal to a shell).
#[test]
fn an_interrupted_run_leaves_the_previous_results_intact() {
    use std::os::unix::process::ExitStatusExt;
    let dir = temp_dir("sigint");
    let base = ["run", "skate", "--t-end", "10", "--format", "both"];
    run_ok(&[&base[..], &["--h", "0.01"]].concat(), &dir);
    let before = snapshot(&dir, false);
    assert!(before.len() >= 6, "{:?}", before.keys());

    for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // A second run with another step size, interrupted in its write
        // phase (as soon as anything in the folder changes).
        let all_before = snapshot(&dir, true);
        let mut child = spark();
        child
            .args(base)
            .args(["--h", "0.02", "--out"])
            .arg(&dir)
            .env(PAUSE_ENV, "60000")
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        // A shell that starts this test in the background ignores SIGINT,
        // and the child would inherit that; give the run the disposition
        // an interactive Ctrl-C meets.
        // SAFETY: `signal` is async-signal-safe, the only call between fork and exec.
        unsafe {
            child.pre_exec(move || {
                libc::signal(signal, libc::SIG_DFL);
                Ok(())
            });
        }
        let mut child = child.spawn().unwrap();
        wait_until(&mut child, "writing", || snapshot(&dir, true) != all_before);
        // SAFETY: `kill` takes plain integers; the child is not yet waited for.
        assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
        let status = child.wait().unwrap();
        assert_eq!(status.signal(), Some(signal), "the interrupted run ends by its signal: {status}");

        let names: Vec<String> = snapshot(&dir, true).into_keys().collect();
        assert!(names.iter().all(|n| !n.starts_with(".spark-tmp-")), "signal {signal} left {names:?}");
        let after = snapshot(&dir, false);
        assert_eq!(after.keys().collect::<Vec<_>>(), before.keys().collect::<Vec<_>>());
        for (name, bytes) in &before {
            assert!(
                after[name] == *bytes,
                "{name} changed by the interrupted run ({} → {} bytes)",
                bytes.len(),
                after[name].len()
            );
        }
    }

    // A run that ignores SIGHUP (`nohup`) keeps ignoring it and finishes.
    let mut child = spark();
    child.args(base).args(["--h", "0.02", "--out"]).arg(&dir).env(PAUSE_ENV, "300");
    child.stdout(Stdio::null()).stderr(Stdio::null());
    // SAFETY: as above.
    unsafe {
        child.pre_exec(|| {
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            Ok(())
        });
    }
    let mut child = child.spawn().unwrap();
    let all_before = snapshot(&dir, true);
    wait_until(&mut child, "writing", || snapshot(&dir, true) != all_before);
    // SAFETY: as above.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGHUP) }, 0);
    assert!(child.wait().unwrap().success(), "a run under nohup ends on its own");
    let names: Vec<String> = snapshot(&dir, true).into_keys().collect();
    assert!(names.iter().all(|n| !n.starts_with(".spark-tmp-")), "{names:?}");
    assert_ne!(snapshot(&dir, false)["skate_gauss_s2.csv"], before["skate_gauss_s2.csv"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Whether the process `pid` is gone: no such process, or one that has
/// ended and is not yet reaped (an orphan's new parent may never reap it).
fn gone(pid: libc::pid_t) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the command name, which is in parentheses.
        Ok(stat) => stat.rsplit_once(')').is_some_and(|(_, rest)| rest.trim_start().starts_with(['Z', 'X'])),
        Err(_) => true,
    }
}

/// A run ended by a signal, or killed outright, while a peer runs leaves
/// no child behind. The fake peer (`--python`, a shell script) starts a
/// long `sleep` of its own, as the Python peer starts the compiler and the
/// timing driver, and waits: on SIGINT, SIGTERM or SIGHUP the run ends the
/// peer and what it started (the background `sleep` of a shell ignores
/// SIGINT, and is killed after the grace time) and ends by the signal; on
/// SIGKILL the kernel ends the peer with the run.
#[test]
#[cfg(target_os = "linux")]
fn a_run_ended_while_a_peer_runs_leaves_no_child_behind() {
    use std::os::unix::fs::PermissionsExt;
    use std::os::unix::process::ExitStatusExt;
    let root = temp_dir("children");
    std::fs::create_dir_all(root.join("casadi/peers")).unwrap();
    std::fs::write(root.join("casadi/peers/peers.py"), "").unwrap();
    let python = root.join("fake-python");
    let script = format!(
        "#!/bin/sh\nsleep 1000 &\necho $! > '{0}/grandchild'\necho $$ > '{0}/child.tmp'\nmv '{0}/child.tmp' \
         '{0}/child'\nwait\n",
        root.display()
    );
    std::fs::write(&python, script).unwrap();
    std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
    let read_pid =
        |name: &str| -> libc::pid_t { std::fs::read_to_string(root.join(name)).unwrap().trim().parse().unwrap() };

    for signal in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP, libc::SIGKILL] {
        let _ = std::fs::remove_file(root.join("child"));
        let mut child = spark();
        child
            .current_dir(&root)
            .args(["work-precision", "--quick", "--system", "skate", "--max-steps", "16", "--python"])
            .arg(&python)
            .arg("--out")
            .arg(root.join("out"))
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        // As in `an_interrupted_run_leaves_the_previous_results_intact`.
        // SAFETY: `signal` is async-signal-safe, the only call between fork and exec.
        unsafe {
            child.pre_exec(move || {
                if signal != libc::SIGKILL {
                    libc::signal(signal, libc::SIG_DFL);
                }
                Ok(())
            });
        }
        let mut child = child.spawn().unwrap();
        wait_until(&mut child, "the peer runs", || root.join("child").exists());
        let (peer, grandchild) = (read_pid("child"), read_pid("grandchild"));
        // SAFETY: `kill` takes plain integers; the child is not yet waited for.
        assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
        let status = child.wait().unwrap();
        assert_eq!(status.signal(), Some(signal), "the run ends by its signal: {status}");
        // A process ends a moment after a signal is sent to it, and the
        // kernel sends the peer its SIGKILL as the run ends.
        let start = Instant::now();
        let ended = || gone(peer) && (gone(grandchild) || signal == libc::SIGKILL);
        while !ended() && start.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(10));
        }
        let (peer_gone, grandchild_gone) = (gone(peer), gone(grandchild));
        // What the peer started is left to the peer when the run is killed outright.
        for pid in [peer, grandchild] {
            if !gone(pid) {
                // SAFETY: as above; the process is this test's, started by the run.
                unsafe { libc::kill(pid, libc::SIGKILL) };
            }
        }
        assert!(peer_gone, "signal {signal} left the peer {peer} running");
        assert!(
            grandchild_gone || signal == libc::SIGKILL,
            "signal {signal} left the peer's child {grandchild} running"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_second_run_on_a_busy_folder_is_refused_and_rows_never_interleave() {
    let dir = temp_dir("lock");
    let mut first = spark()
        .args(["run", "skate", "--h", "0.01", "--t-end", "20", "--out"])
        .arg(&dir)
        .env(PAUSE_ENV, "3000")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = format!("pid {}", first.id());
    let lock = dir.join(".spark-lock");
    wait_until(&mut first, "it took the folder lock", || {
        std::fs::read_to_string(&lock).is_ok_and(|s| s.contains(&pid))
    });
    let second = spark().args(["run", "skate", "--h", "0.02", "--t-end", "20", "--out"]).arg(&dir).output().unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "the second run must be refused");
    assert!(err.contains("in use by another spark run") && err.contains(&pid), "{err}");
    assert!(err.contains(&lock.display().to_string()), "the message names the lock file: {err}");
    let status = first.wait().unwrap();
    assert!(status.success());

    // The first run's trajectory is whole: every row complete, t increasing.
    let csv = std::fs::read_to_string(dir.join("skate_gauss_s2.csv")).unwrap();
    let mut lines = csv.lines();
    let width = lines.next().unwrap().split(',').count();
    let mut last = f64::NEG_INFINITY;
    let mut rows = 0;
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        assert_eq!(fields.len(), width, "torn row {line}");
        let t: f64 = fields[0].parse().unwrap();
        assert!(t > last, "t goes backwards at {t}");
        last = t;
        rows += 1;
    }
    assert_eq!(rows, 2001);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_unwritable_out_is_reported_before_any_computation() {
    // The velocity violates the skate's constraint, which the run itself
    // reports: the folder error must come first.
    let err = run_err(&["run", "skate", "--v0", "0,1,0", "--out", "/proc/spark-no-such-dir/out"]);
    assert!(err.contains("/proc/spark-no-such-dir/out"), "{err}");
    assert!(!err.contains("violates the constraints"), "the run started before the folder was checked: {err}");
    let err = run_err(&["stress", "--only", "bad_input", "--out", "/proc/spark-no-such-dir/out"]);
    assert!(err.contains("/proc/spark-no-such-dir/out"), "{err}");
    // A path that is a file, not a folder, is named as such.
    let err = run_err(&["paper", "--out", "/dev/null"]);
    assert!(err.contains("/dev/null") && err.contains("not a folder"), "{err}");
    // A symbolic link to nowhere is named with where it points.
    let dir = temp_dir("dangling");
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("out");
    std::os::unix::fs::symlink(dir.join("missing"), &link).unwrap();
    let err = run_err(&["run", "skate", "--out", link.to_str().unwrap()]);
    assert!(err.contains("symbolic link") && err.contains("missing") && err.contains("does not exist"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Far from t = 0 the ends of an interval differ beyond the digits of a
/// fixed precision: the messages that compare them print every digit, so
/// that `t0 = 1e17` and `t_end = 1e17 + 16` do not read alike.
#[test]
fn interval_messages_tell_nearby_ends_apart() {
    let dir = temp_dir("far-interval");
    let out = dir.to_str().unwrap();
    let far = ["run", "sleigh", "--t0", "1e17", "--t-end", "1.0000000000000002e17"];
    let err = run_err(&[&far[..], &["--h", "1000", "--out", out]].concat());
    assert!(
        err.contains("from t0 = 1e17 to --t-end 1.0000000000000002e17 is shorter than one step of --h 1000;"),
        "{err}"
    );
    let err = run_err(&[&far[..], &["--rtol", "1e-6", "--sample-every", "2000", "--out", out]].concat());
    assert!(
        err.contains("--sample-every 2000 is longer than the interval from t0 = 1e17 to t_end = 1.0000000000000002e17"),
        "{err}"
    );
    let err = run_err(&["run", "sleigh", "--t0", "1e17", "--t-end", "9.999999999999998e16", "--out", out]);
    assert!(err.contains("greater than t0 = 1e17, got 9.999999999999998e16"), "{err}");
    let err = run_err(&["run", "sleigh", "--t0", "1e300", "--out", out]);
    assert!(err.contains("--t0 1e300 leaves no interval") && err.contains("is 1e300, not after t0"), "{err}");
    assert!(!dir.exists() || std::fs::read_dir(&dir).unwrap().next().is_none(), "refused before any file");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_interval_that_is_not_a_whole_number_of_steps_is_refused() {
    let dir = temp_dir("interval");
    let out = dir.to_str().unwrap();
    let err = run_err(&["run", "skate", "--t-end", "1e-9", "--h", "0.1", "--out", out]);
    assert!(err.contains("shorter than one step") && err.contains("--t-end") && err.contains("--h"), "{err}");
    let err = run_err(&["run", "skate", "--t-end", "0.25", "--h", "0.1", "--out", out]);
    assert!(err.contains("not a whole") && err.contains("--t-end 0.2 or 0.3"), "{err}");
    assert!(!dir.join("skate_gauss_s2.csv").exists());
    // 0.3/0.1 = 2.9999999999999996 is three steps.
    run_ok(&["run", "skate", "--t-end", "0.3", "--h", "0.1", "--no-plot"], &dir);
    let csv = std::fs::read_to_string(dir.join("skate_gauss_s2.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_numeric_argument_is_checked_and_named() {
    let dir = temp_dir("numbers");
    let out = dir.to_str().unwrap();
    let cases: [(&[&str], &str); 12] = [
        (&["run", "skate", "--h", "nan"], "--h"),
        (&["run", "skate", "--h", "-0.1"], "--h"),
        (&["run", "skate", "--t-end", "nan"], "--t-end"),
        (&["run", "skate", "--t0", "inf"], "--t0"),
        (&["run", "skate", "--every", "0"], "--every"),
        (&["run", "skate", "--stages", "0"], "--stages"),
        (&["run", "skate", "--q0", "0,nan,0"], "--q0"),
        (&["run", "skate", "--v0", "inf,0,0"], "--v0"),
        (&["run", "skate", "--param", "m=nan"], "--param"),
        (&["work-precision", "--quick", "--no-python", "--t-end", "nan"], "--t-end"),
        (&["work-precision", "--quick", "--no-python", "--repeats", "0"], "--repeats"),
        (&["work-precision", "--quick", "--no-python", "--max-steps", "0"], "--max-steps"),
    ];
    for (args, flag) in cases {
        let err = run_err(&[args, &["--out", out]].concat());
        assert!(err.contains(flag), "spark {args:?}: the message must name {flag}: {err}");
    }
    assert!(!dir.join("summary.md").exists() && !dir.join("report.md").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Arguments refused before the run, with what to change, named as the
/// user gave them: a subnormal `--h` (its 1/h overflows inside the step),
/// an `--h` that does not move `--t0`, a `--t0` whose default end rounds
/// back to it, a stage count outside a single-valued range, a parameter
/// given twice, an `--h` whose h² overflows in the Newton matrix (the run
/// would fail after halving with a non-finite Jacobian), a `--v0` whose
/// energy overflows (it would fail with an energy drift against E0 = inf)
/// and a zero mass (it would fail with a singular Newton matrix in the first
/// step), and a `spark paper --fraction` that leaves a figure less than one
/// step (its final time would be printed with 300 digits), and a `--newton-tol` of 1 or
/// more, which would accept updates with no correct digit.
#[test]
fn unusable_arguments_are_refused_naming_what_was_given() {
    let dir = temp_dir("given");
    let out = dir.to_str().unwrap();
    let cases: [(&[&str], &[&str]); 13] = [
        (&["run", "skate", "--h", "1e300", "--t-end", "1e300"], &["--h", "h² overflows", "smaller |h|"]),
        (
            &["run", "skate", "--v0", "0,0,1e155", "--t-end", "1"],
            &["initial state: the energy", "overflows f64", "|v0|²"],
        ),
        (
            &["run", "skate", "--param", "m=0", "--t-end", "1"],
            &["initial state", "mass matrix W = d²L/dv²", "coordinate `x`", "Parameters that are 0 here: m"],
        ),
        (&["run", "skate", "--h", "1e-311", "--t-end", "3e-311"], &["--h", "subnormal", "use |h| ≥ 2.2e-308"]),
        (&["run", "skate", "--t0", "1e20", "--h", "1", "--t-end", "1.0000001e20"], &["--h", "resolution of t", "use"]),
        (&["section", "mp7-nh", "--event", "section", "--members", "2", "--h", "1e-311"], &["--h", "subnormal"]),
        (&["run", "skate", "--t0", "-1e300"], &["--t0 -1e300", "default end", "give a --t-end greater"]),
        (
            &["run", "skate", "--t0", "1e20", "--t-end", "2e20"],
            &["default step h = 1.000e-1", "--h", "resolution of t"],
        ),
        (&["run", "skate", "--method", "euler-1", "--stages", "2"], &["needs exactly 1 stage, got s = 2"]),
        (&["run", "skate", "--param", "m=1", "--param", "m = 2"], &["`m` is given twice", "`m=1`", "`m = 2`"]),
        (&["run", "skate", "--param", "=1"], &["--param `=1`", "no parameter name", "NAME=VALUE"]),
        (&["paper", "--fraction", "1e-300"], &["final time 2.500e-298", "shorter than one step", "--fraction"]),
        (&["paper", "--newton-tol", "1e300"], &["--newton-tol 1e300", "in (0, 1)"]),
    ];
    for (args, words) in cases {
        let err = run_err(&[args, &["--out", out]].concat());
        for w in words {
            assert!(err.contains(w), "spark {args:?}: the message must contain {w:?}: {err}");
        }
        assert!(!err.contains("non-finite") && !err.contains("--t-end must"), "spark {args:?}: {err}");
    }
    assert!(!dir.join("report.md").exists() && !dir.join("section.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn runs_whose_output_would_not_fit_are_refused_up_front() {
    let dir = temp_dir("size");
    let out = dir.to_str().unwrap();
    // 10⁹ samples do not fit in memory: thin with --every.
    let err = run_err(&["run", "skate", "--t-end", "1e6", "--h", "0.001", "--out", out]);
    assert!(err.contains("--every") && err.contains("samples"), "{err}");
    // 10³⁰⁰ steps cannot be counted.
    let err = run_err(&["run", "skate", "--h", "1e-300", "--out", out]);
    assert!(err.contains("1e10") && err.contains("--h"), "{err}");
    // A 3·10⁵-sample JSON trajectory is too large: use CSV or --every.
    let err = run_err(&["run", "skate", "--t-end", "3000", "--h", "0.01", "--format", "json", "--out", out]);
    assert!(err.contains("--format csv") && err.contains("--every"), "{err}");
    assert!(!dir.join("skate_gauss_s2.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_figure_of_a_long_run_stays_small() {
    // 10⁵ samples of eight curves: decimated to a few thousand points each.
    let dir = temp_dir("svg");
    run_ok(&["run", "skate", "--t-end", "100", "--h", "0.001"], &dir);
    let svg = std::fs::metadata(dir.join("skate_gauss_s2.svg")).unwrap().len();
    let csv = std::fs::metadata(dir.join("skate_gauss_s2.csv")).unwrap().len();
    assert!(csv > 10_000_000, "the CSV keeps every sample ({csv} bytes)");
    assert!(svg < 1_000_000, "SVG of {svg} bytes");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run into a folder that holds an earlier run of the same system,
/// method and stage count leaves no file of that run that it does not
/// write itself: a `--no-plot` or `--format csv` run removes the earlier
/// figure and JSON trajectory, which would describe another run than its
/// report.md (a figure of h = 0.1 to t = 2 beside the report and CSV of
/// h = 0.05 to t = 1). Files of other runs stay.
#[test]
fn a_run_leaves_no_file_of_an_earlier_run_beside_its_own() {
    let dir = temp_dir("stale");
    run_ok(&["run", "skate", "--h", "0.1", "--t-end", "2", "--format", "both"], &dir);
    run_ok(&["run", "particle", "--h", "0.1", "--t-end", "1", "--no-plot"], &dir);
    for name in ["skate_gauss_s2.csv", "skate_gauss_s2.json", "skate_gauss_s2.png", "skate_gauss_s2.svg"] {
        assert!(dir.join(name).exists(), "{name} missing after the first run");
    }
    run_ok(&["run", "skate", "--h", "0.05", "--t-end", "1", "--no-plot"], &dir);
    for name in ["skate_gauss_s2.json", "skate_gauss_s2.png", "skate_gauss_s2.svg"] {
        assert!(!dir.join(name).exists(), "{name} of the earlier run is still there");
    }
    let csv = std::fs::read_to_string(dir.join("skate_gauss_s2.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 21);
    assert!(dir.join("particle_gauss_s2.csv").exists(), "another run's file was removed");
    run_ok(&["run", "skate", "--h", "0.1", "--t-end", "1", "--format", "json", "--no-plot"], &dir);
    assert!(!dir.join("skate_gauss_s2.csv").exists(), "the CSV of the earlier run is still there");
    assert!(dir.join("skate_gauss_s2.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A folder under the name of one of a run's files cannot be replaced by
/// the file: the run fails naming it, before anything is renamed, and the
/// earlier results stay as they were (every final name is checked first, so
/// the CSV and PNG of the new run are not renamed beside the old run's
/// reports before the SVG fails).
#[test]
fn a_folder_in_the_way_of_a_file_leaves_the_earlier_results_whole() {
    let dir = temp_dir("folder-in-the-way");
    run_ok(&["run", "skate", "--h", "0.1", "--t-end", "2"], &dir);
    std::fs::remove_file(dir.join("skate_gauss_s2.svg")).unwrap();
    std::fs::create_dir(dir.join("skate_gauss_s2.svg")).unwrap();
    let before = snapshot(&dir, true);
    let e = run_err(&["run", "skate", "--h", "0.05", "--t-end", "2", "--out", dir.to_str().unwrap()]);
    assert!(e.contains("skate_gauss_s2.svg") && e.contains("a folder of that name is in the way"), "{e}");
    assert_eq!(snapshot(&dir, true), before, "the folder changed");
    // The same for a stale file of the run's own name that it would remove.
    std::fs::remove_dir(dir.join("skate_gauss_s2.svg")).unwrap();
    std::fs::create_dir(dir.join("skate_gauss_s2.json")).unwrap();
    let before = snapshot(&dir, true);
    let e = run_err(&["run", "skate", "--h", "0.05", "--t-end", "2", "--no-plot", "--out", dir.to_str().unwrap()]);
    assert!(e.contains("skate_gauss_s2.json") && e.contains("in the way"), "{e}");
    assert_eq!(snapshot(&dir, true), before, "the folder changed");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Standard output that cannot be written (a full disk) ends the program
/// with an error, never a panic: `print!` would panic with "failed printing
/// to stdout" and exit status 101. A pipe whose reader has gone
/// (`spark list | head -1`) ends it quietly with status 0: the reader took
/// what it wanted, and `set -o pipefail` must not fail the pipeline.
#[test]
fn an_unwritable_standard_output_is_an_error_not_a_panic() {
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let o = spark().arg("list").stdout(full).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && o.status.code() == Some(1), "{:?}: {stderr}", o.status);
    assert!(stderr.contains("standard output") && !stderr.contains("panicked"), "{stderr}");
    // A reader that reads nothing and exits: the write fails with a broken
    // pipe (or lands in the pipe's buffer first); either way, no panic.
    let o = Command::new("sh")
        .arg("-c")
        .arg(format!("'{}' list --json | true", env!("CARGO_BIN_EXE_spark")))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!stderr.contains("panicked") && !stderr.contains("Broken pipe"), "{stderr}");
    // The read end closed before the program writes (or, should it write
    // first, while the listing, larger than a pipe's buffer, is still
    // being written): the write fails with a broken pipe.
    for args in [&["list", "--json"][..], &["list"][..]] {
        let mut child = spark().args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success() && stderr.is_empty(), "{args:?}: {:?}: {stderr}", o.status);
    }
}

/// Help and version text go to standard output like a listing does: one
/// that cannot take them (a full disk) is exit status 1 with a message on
/// standard error, not status 0 with the text lost; a reader that has gone
/// ends the program quietly with the status the command has. The CasADi
/// export's help is written alike.
#[test]
fn help_and_version_that_cannot_be_written_are_an_error() {
    let export = env!("CARGO_BIN_EXE_spark-casadi-export");
    let cases: [(&str, &[&str]); 7] = [
        ("spark", &["--help"]),
        ("spark", &["-h"]),
        ("spark", &["--version"]),
        ("spark", &["help", "run"]),
        ("spark", &["run", "--help"]),
        ("spark", &["list", "--json"]),
        (export, &["--help"]),
    ];
    for (program, args) in cases {
        let program = if program == "spark" { env!("CARGO_BIN_EXE_spark") } else { program };
        let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
        let o = Command::new(program).args(args).stdout(full).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?} > /dev/full: {stderr}");
        assert!(stderr.contains("cannot write to standard output") && !stderr.contains("panicked"), "{stderr}");
        // Written in full to a pipe, it succeeds.
        let o = Command::new(program).args(args).output().unwrap();
        assert!(o.status.success() && !o.stdout.is_empty(), "{args:?}: {:?}", o.status);
        let mut child = Command::new(program).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success() && stderr.is_empty(), "{args:?} | closed: {:?}: {stderr}", o.status);
    }
    // A usage error keeps its status 2 and its message on standard error.
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let o = spark().arg("--no-such-flag").stdout(full).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--no-such-flag"));
}

/// A tolerance that is not a finite number ≥ 0 is refused naming the flag
/// that was given: a lone `--atol` also stands for the relative tolerance,
/// and the message names `--atol`, not `--rtol`.
#[test]
fn an_unusable_tolerance_is_refused_naming_the_flag_given() {
    let dir = temp_dir("tolerance-flags");
    let out = dir.to_str().unwrap();
    for (args, flag) in [
        (&["--atol", "-1"][..], "--atol must be"),
        (&["--rtol", "nan"][..], "--rtol must be"),
        (&["--rtol", "1e-6", "--atol", "inf"][..], "--atol must be"),
        (&["--atol", "1e-6", "--rtol", "-1e-3"][..], "--rtol must be"),
    ] {
        let err = run_err(&[&["run", "skate", "--out", out][..], args].concat());
        assert!(err.contains(flag), "{args:?}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `spark ARGS` must fail within `seconds`: an argument that is accepted
/// would start a run that does not end, so the child is killed and the
/// test fails rather than hanging.
fn run_err_within(args: &[&str], seconds: u64) -> String {
    let mut child = spark().args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(seconds) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("spark {args:?} was accepted and still ran after {seconds} s; it must be refused at once");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success(), "spark {args:?} should fail");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Counts and intervals that cannot finish in any sensible time, or over
/// which nothing can be measured, are refused before any computation,
/// naming the flag and the range that works. Unchecked, `--t-end 1e-300`
/// would say "loosen rtol/atol" about a tolerance the user cannot set,
/// `--t-end 1e300` would run the reference solution for 10⁶ step attempts,
/// `--repeats` near `u64::MAX` would time each point forever, and runs and
/// sections of up to 2⁵³ steps (decades) would start.
#[test]
fn counts_and_intervals_beyond_their_limits_are_refused_naming_the_range() {
    let dir = temp_dir("limits");
    let out = dir.to_str().unwrap();
    let wp = ["work-precision", "--quick", "--no-python", "--system", "skate", "--out", out];
    let range = "1e-15 ≤ --t-end ≤ 1e4";
    let cases: [(&[&str], &[&str]); 9] = [
        (&["--t-end", "1e-300"], &["--t-end 1.000e-300", "shorter than the smallest step", range]),
        (&["--t-end", "9e-16"], &["--t-end 9.000e-16", "shorter than the smallest step", range]),
        (&["--t-end", "1e300"], &["--t-end 1.000e300", "longer than a sweep can measure", range]),
        (&["--t-end", "2e4"], &["--t-end 2.000e4", "longer than a sweep can measure", range]),
        (&["--t-end", "-1"], &["--t-end must be a positive number", range]),
        (&["--repeats", "18446744073709551615"], &["--repeats 18446744073709551615", "1 ≤ --repeats ≤ 1000"]),
        (&["--repeats", "1001"], &["--repeats 1001", "1 ≤ --repeats ≤ 1000"]),
        (&["--per-step", "--t-end", "5"], &["--t-end", "--per-step", "cannot be used with"]),
        (&["--adaptive-energy", "--repeats", "3"], &["--repeats", "--adaptive-energy", "cannot be used with"]),
    ];
    for (args, words) in cases {
        let err = run_err_within(&[&wp[..], args].concat(), 30);
        for w in words {
            assert!(err.contains(w), "spark work-precision {args:?}: the message must contain {w:?}: {err}");
        }
        assert!(!err.contains("loosen") && !err.contains("panicked"), "{args:?}: {err}");
    }
    let others: [(&[&str], &[&str]); 3] = [
        // 10¹¹ steps, recorded sparsely enough to fit in memory.
        (
            &["run", "skate", "--h", "1e-9", "--t-end", "100", "--every", "100000000"],
            &["1.000e11 steps", "1e10", "--h"],
        ),
        (&["run", "skate", "--h", "1e-300"], &["1e10", "--h"]),
        // 2·10⁶ steps for each of 10⁴ members.
        (
            &["section", "mp7-nh", "--event", "section", "--members", "10000", "--t-end", "1e5", "--h", "0.05"],
            &["--members 10000 × 2000000 steps", "1e10", "fewer --members"],
        ),
    ];
    for (args, words) in others {
        let err = run_err_within(&[args, &["--out", out]].concat(), 30);
        for w in words {
            assert!(err.contains(w), "spark {args:?}: the message must contain {w:?}: {err}");
        }
    }
    assert!(!dir.join("summary.md").exists() && !dir.join("report.md").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// An `--out` whose name is not UTF-8 is a folder like any other: the
/// command line recorded in the lock file is read with `std::env::args_os`
/// (`std::env::args` would panic on it, after the lock file is created).
#[test]
fn an_out_folder_whose_name_is_not_utf8_is_written() {
    use std::os::unix::ffi::OsStrExt;
    let dir = temp_dir("non-utf8");
    let out = dir.join(std::ffi::OsStr::from_bytes(b"run-\xff"));
    let o = spark().args(["run", "skate", "--t-end", "1", "--no-plot", "--out"]).arg(&out).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && !stderr.contains("panicked"), "{:?}: {stderr}", o.status);
    assert!(out.join("skate_gauss_s2.csv").exists() && out.join("report.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `spark-casadi-export` replaces its document whole: the file an earlier
/// export wrote is renamed over, never truncated and rewritten in place (a
/// link to it keeps the earlier document, as a reader that has it open
/// does), and a standard error that cannot take its closing line (a full
/// disk) loses the line, not the export (exit status 0, not a panic).
#[test]
fn the_casadi_export_replaces_its_document_whole() {
    let dir = temp_dir("casadi-export");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("export.json");
    let earlier = dir.join("earlier.json");
    std::fs::write(&out, b"{\"earlier\": true}").unwrap();
    std::fs::hard_link(&out, &earlier).unwrap();
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_spark-casadi-export"))
        .arg("--out")
        .arg(&out)
        .stderr(Stdio::from(full))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{:?}", o.status);
    assert_eq!(std::fs::read(&earlier).unwrap(), b"{\"earlier\": true}", "the earlier file was rewritten in place");
    let document: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert!(document["systems"].as_array().is_some_and(|s| !s.is_empty()), "no systems in the export");
    // A folder in the way is an error naming it, and leaves no temporary file.
    let folder = dir.join("folder.json");
    std::fs::create_dir(&folder).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_spark-casadi-export")).arg("--out").arg(&folder).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains(&folder.display().to_string()), "{stderr}");
    let left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".spark-tmp-"))
        .collect();
    assert!(left.is_empty(), "temporary files left: {left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Output times too many to record are refused from their count, before
/// their list is made: `--sample-every 1e-7` over the skate's 10 time units
/// is 10⁸ times, and the 800 MB list of them made first took seconds and,
/// under a 600 MB memory limit, aborted the process (allocation failure,
/// SIGABRT) instead of the refusal.
#[test]
fn too_many_output_times_are_refused_before_they_take_memory() {
    let dir = temp_dir("sample-count");
    let mut cmd = spark();
    cmd.args(["run", "skate", "--sample-every", "1.0000001e-7", "--no-plot", "--out"]).arg(&dir);
    // SAFETY: `setrlimit` is async-signal-safe; the closure touches nothing else.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit { rlim_cur: 600 << 20, rlim_max: 600 << 20 };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) == 0 {
                Ok(())
            } else {
                Err(std::io::Error::last_os_error())
            }
        });
    }
    let o = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{:?}: {stderr}", o.status);
    assert!(stderr.contains("records 1.000e8 samples") && stderr.contains("give a --sample-every of"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}
