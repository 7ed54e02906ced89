//! The work-precision experiment: medians of repeats, a quick run with
//! every solver and output, the sweep over families and stage counts, the
//! per-step table and the report's interpolation.

mod sweep {
    use problems::catalog::SystemKind;
    use problems::experiments::work_precision::*;
    use problems::report::clock::median_time;
    use std::time::Duration;

    #[test]
    fn median_time_takes_the_middle_of_the_repeats() {
        let mut k = 0;
        let (t, _, n) = median_time(3, Duration::ZERO, || {
            k += 1;
            std::thread::sleep(Duration::from_millis(if k == 2 { 30 } else { 1 }));
            true
        })
        .unwrap();
        assert_eq!(n, 3);
        assert!(t < 0.02, "median {t} should ignore the one slow repeat");
        assert!(median_time(3, Duration::ZERO, || false).is_none());
    }

    /// Smoke test of the whole code path (the measurement itself is a
    /// command, never a test): one system, tiny sweep, no Python.
    #[test]
    fn quick_run_measures_every_solver_and_writes_every_output() {
        let dir = std::env::temp_dir().join(format!("spark-work-precision-smoke-{}", std::process::id()));
        let mut cfg = WorkPrecisionConfig::quick(&dir);
        cfg.systems = vec![SystemKind::Skate];
        cfg.max_steps = 32;
        let all = run_work_precision(&cfg, &|_| {}).unwrap();
        let m = &all[0];
        for (method, s) in method_variants() {
            let label = method.label(s);
            assert!(
                m.points.iter().any(|p| p.solver == Provider::Generated.label() && p.method == label),
                "no point for {label}"
            );
        }
        for solver in [Provider::NumDual.label(), Provider::FiniteDifference.label(), report::ODE_SOLVERS] {
            assert!(m.points.iter().any(|p| p.solver == solver), "no point for {solver}");
        }
        // Gauss s=2 is of order 4: doubling the steps must shrink the error.
        let g: Vec<&Point> =
            m.points.iter().filter(|p| p.solver == Provider::Generated.label() && p.method == "Gauss s=2").collect();
        assert!(g.len() >= 2 && g[1].error() < g[0].error() / 8.0, "Gauss s=2 errors {:?}", g);
        // num-dual solves the same equations: the same errors.
        let ad = m.points.iter().find(|p| p.solver == Provider::NumDual.label() && p.steps == g[0].steps).unwrap();
        assert!((ad.error() - g[0].error()).abs() <= 1e-9 * g[0].error().max(1e-12));
        assert!(m.missing.iter().any(|s| s.contains("CasADi")));
        for f in ["skate.csv", "skate.md", "skate-error.png", "skate-energy.svg", "skate-peers.png", "summary.md"] {
            assert!(dir.join(f).exists(), "{f} not written");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The peers' results are read back from a file in the output folder:
    /// one that an earlier run left there is never taken for this run's.
    /// A `--python` that ends successfully without writing it (here a
    /// script that only exits 0) is a peer not measured, naming the file.
    #[test]
    fn an_earlier_runs_peer_results_are_not_read_as_this_runs() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("spark-work-precision-stale-peers-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("external")).unwrap();
        let stale = dir.join("external").join("skate-points.csv");
        std::fs::write(
            &stale,
            "system,solver,method,stages,setting,steps,error_q,error_v,energy_error,wall_time,cpu_time,\
             time_per_step,newton_iterations,repeats\nskate,SciPy,EARLIER,0,0.001,7,1e-99,1e-99,NaN,1e-9,1e-9,\
             1e-10,NaN,1\n",
        )
        .unwrap();
        let python = dir.join("fake-python");
        std::fs::write(&python, "#!/bin/sh\nexit 0\n").unwrap();
        std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
        let script = dir.join("peers.py");
        std::fs::write(&script, "").unwrap();
        let mut cfg = WorkPrecisionConfig::quick(&dir);
        cfg.systems = vec![SystemKind::Skate];
        cfg.max_steps = 16;
        cfg.python = Some(python);
        cfg.peers_script = script;
        let all = run_work_precision(&cfg, &|_| {}).unwrap();
        let m = &all[0];
        assert!(!m.points.iter().any(|p| p.method == "EARLIER"), "the earlier run's peer point was read back");
        assert!(
            m.missing.iter().any(|s| s.contains("exited successfully but wrote no") && s.contains("skate-points.csv")),
            "{:?}",
            m.missing
        );
        assert!(!stale.exists(), "the earlier results are still there");
        let points = std::fs::read_to_string(dir.join("points.csv")).unwrap();
        assert!(!points.contains("EARLIER"), "{points}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The peer script's output is read up to `MAX_PEER_OUTPUT` bytes a
    /// stream: a `--python` that floods standard output (or standard
    /// error) is stopped and is a peer not measured naming the program and
    /// the stream, in bounded memory, and the rest of the study runs.
    #[test]
    fn a_python_that_floods_its_output_is_stopped_not_read_without_bound() {
        use problems::experiments::work_precision::external::MAX_PEER_OUTPUT;
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("spark-work-precision-flood-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, redirect, stream) in [("out", "", "standard output"), ("err", " >&2", "standard error")] {
            // `yes` writes without end; it is killed, never waited for to
            // finish on its own.
            let python = dir.join(format!("flooding-python-{name}"));
            std::fs::write(&python, format!("#!/bin/sh\nexec yes spark{redirect}\n")).unwrap();
            std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
            let script = dir.join("peers.py");
            std::fs::write(&script, "").unwrap();
            let mut cfg = WorkPrecisionConfig::quick(dir.join(name));
            cfg.systems = vec![SystemKind::Skate];
            cfg.max_steps = 16;
            cfg.python = Some(python.clone());
            cfg.peers_script = script;
            let all = run_work_precision(&cfg, &|_| {}).unwrap();
            let limit = format!("more than {} MiB to its {stream}", MAX_PEER_OUTPUT >> 20);
            assert!(
                all[0].missing.iter().any(|s| s.contains(&limit) && s.contains(&python.display().to_string())),
                "{:?}",
                all[0].missing
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The problem handed to the peer script (`external/<system>-input.json`)
    /// is replaced whole, never rewritten in place: a second name of the
    /// earlier file (a hard link, or a reader that has it open) keeps the
    /// earlier problem whole, the script reads the whole new one, and no
    /// temporary file stays in the folder.
    #[test]
    fn the_peer_input_is_replaced_whole_not_rewritten_in_place() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("spark-work-precision-peer-input-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("external")).unwrap();
        let input = dir.join("external").join("skate-input.json");
        let earlier = b"{\"system\": \"EARLIER\"}";
        std::fs::write(&input, earlier).unwrap();
        let kept = dir.join("kept-input.json");
        std::fs::hard_link(&input, &kept).unwrap();
        // The fake peer script copies the input it is given (`--input
        // PATH` after the script) and writes no results.
        let seen = dir.join("seen-input.json");
        let python = dir.join("fake-python");
        std::fs::write(&python, format!("#!/bin/sh\ncp \"$3\" '{}'\n", seen.display())).unwrap();
        std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
        let script = dir.join("peers.py");
        std::fs::write(&script, "").unwrap();
        let mut cfg = WorkPrecisionConfig::quick(&dir);
        cfg.systems = vec![SystemKind::Skate];
        cfg.max_steps = 16;
        cfg.python = Some(python);
        cfg.peers_script = script;
        run_work_precision(&cfg, &|_| {}).unwrap();
        assert_eq!(std::fs::read(&kept).unwrap(), earlier, "the earlier input file was rewritten in place");
        let new: serde_json::Value = serde_json::from_slice(&std::fs::read(&input).unwrap()).unwrap();
        assert_eq!(new["system"], "skate");
        assert_eq!(std::fs::read(&seen).unwrap(), std::fs::read(&input).unwrap());
        let names: Vec<String> = std::fs::read_dir(dir.join("external"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.starts_with(".spark-tmp-")), "{names:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The reversible sweep runs on the systems with a step density, and
    /// its driver is compiled for the entries marked `steps: reversible`:
    /// the two lists agree.
    /// A largest step count near `usize::MAX` (`--max-steps
    /// 18446744073709551615`) ends the sweep's step counts at the largest
    /// that fits: doubling past it would wrap to 0, and the list of counts
    /// would grow until an allocation fails and aborts the process. The point mass
    /// is solved exactly, so each sweep stops at its first point.
    #[test]
    fn a_sweep_up_to_any_step_count_ends() {
        let dir = std::env::temp_dir().join(format!("spark-work-precision-max-steps-{}", std::process::id()));
        let mut cfg = WorkPrecisionConfig::quick(&dir);
        cfg.systems = vec![SystemKind::PointMass];
        cfg.max_steps = usize::MAX;
        let all = run_work_precision(&cfg, &|_| {}).unwrap();
        assert!(!all[0].points.is_empty());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Settings that cannot be measured, or not in any sensible time, are
    /// refused before the output folder is created: a final time below the
    /// reference solution's smallest step, one beyond the reference's
    /// reach, and a repeat count that never ends.
    #[test]
    fn settings_beyond_the_limits_are_refused_before_any_work() {
        let dir = std::env::temp_dir().join(format!("spark-work-precision-limits-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let base = WorkPrecisionConfig::quick(&dir);
        let cases = [
            WorkPrecisionConfig { final_time: 1e-300, ..base.clone() },
            WorkPrecisionConfig { final_time: MIN_FINAL_TIME * 0.9, ..base.clone() },
            WorkPrecisionConfig { final_time: MAX_FINAL_TIME * 1.1, ..base.clone() },
            WorkPrecisionConfig { repeats: usize::MAX, ..base.clone() },
            WorkPrecisionConfig { repeats: MAX_REPEATS + 1, ..base.clone() },
        ];
        for cfg in cases {
            let err = run_work_precision(&cfg, &|_| {}).unwrap_err().to_string();
            assert!(err.contains("1e-15 ≤ T ≤ 1e4") && err.contains("repeats ≤ 1000"), "{err}");
        }
        assert!(!dir.exists());
    }

    /// A reference solution that fails because of the final time says that
    /// the final time is what to change (not "raise max_steps or loosen the
    /// tolerances", options a sweep does not offer, nor "check the initial
    /// values" of a default state): the turntable's default state
    /// leaves the finite numbers near t = 830.
    #[test]
    fn a_reference_that_cannot_reach_the_final_time_names_it() {
        let dir = std::env::temp_dir().join(format!("spark-work-precision-reach-{}", std::process::id()));
        let mut cfg = WorkPrecisionConfig::quick(&dir);
        cfg.systems = vec![SystemKind::Turntable];
        cfg.final_time = 1e3;
        let err = run_work_precision(&cfg, &|_| {}).unwrap_err().to_string();
        assert!(err.contains("over [0, 1.000e3]") && err.contains("shorter final time, --t-end"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn systems_with_a_step_density_are_marked_reversible_in_the_catalogue() {
        use problems::catalog::{visit_system, Dispatch, SystemEntry, SystemVisitor};
        struct Marked;
        impl SystemVisitor for Marked {
            type Output = bool;
            fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
                self,
                _: &'static SystemEntry,
            ) -> bool {
                Sys::REVERSIBLE_STEPS
            }
        }
        let marked: Vec<SystemKind> = SystemKind::ALL.iter().copied().filter(|&k| visit_system(k, Marked)).collect();
        let with_density: Vec<SystemKind> =
            SystemKind::ALL.iter().copied().filter(|&k| step_density(k).is_some()).collect();
        assert_eq!(marked, with_density);
        assert_eq!(marked, vec![SystemKind::Orbit]);
    }

    #[test]
    fn sweep_covers_every_family_and_stage_count() {
        let v = method_variants();
        assert_eq!(v.len(), 5 + 4 + 4 + 3);
        for (m, s) in v {
            let (lo, hi) = m.stage_range();
            assert!(lo <= s && s <= hi, "{m} s={s}");
        }
    }
}

mod per_step {
    use problems::catalog::SystemKind;
    use problems::experiments::work_precision::external::{self, PeerStepRun};
    use problems::experiments::work_precision::per_step::*;
    use problems::experiments::work_precision::WorkPrecisionConfig;

    #[test]
    fn per_step_table_measures_spark_and_reports_a_missing_peer() {
        let mut cfg = WorkPrecisionConfig::quick(std::env::temp_dir().join("spark-per-step-unused"));
        cfg.systems = vec![SystemKind::Skate];
        let rows = measure_per_step(&cfg, &|_| {}).unwrap();
        assert_eq!(rows.len(), per_step_methods().len());
        for r in &rows {
            assert_eq!((r.steps, r.h), (100, 0.1));
            assert!(r.full.time_per_step > 0.0 && r.simplified.time_per_step > 0.0, "{r:?}");
            assert!(r.decoupled.time_per_step > 0.0, "{r:?}");
            assert!(r.full.iterations >= 1.0, "{r:?}");
            assert!(r.peer.as_ref().is_err_and(|e| e.contains("no Python")), "{r:?}");
            assert!(r.qr_peer.as_ref().is_err_and(|e| e.contains("no Python")), "{r:?}");
        }
        let md = per_step_markdown(&rows);
        assert!(md.contains("| skate | 0.1 | Gauss s=2 |"), "{md}");
        assert!(md.contains("not measured"), "{md}");
        // No peer measured: no summary line.
        assert!(!md.contains("geometric mean |\n|---|---|---|---|---|---|\n|"), "{md}");
        cfg.systems = vec![SystemKind::Sleigh];
        assert!(measure_per_step(&cfg, &|_| {}).is_err());
    }

    /// A SPARK run of `time_per_step` seconds a step.
    fn spark(time_per_step: f64) -> SparkRun {
        SparkRun {
            time_per_step,
            iterations: 2.0,
            factorizations: 1.0,
            flops_per_step: 1.0,
            repeats: 1,
            q: vec![0.0],
            v: vec![0.0],
        }
    }

    fn peer(solver: &str, ns_per_step: f64, steps: usize) -> Result<PeerStepRun, String> {
        Ok(PeerStepRun {
            solver: solver.into(),
            method: "m".into(),
            steps,
            failed: false,
            repeats: 1,
            wall_time: 0.0,
            cpu_time: ns_per_step * 1e-9 * steps as f64,
            evaluations_per_step: 2.0,
            factorizations_per_step: 1.0,
            q: vec![0.0],
            v: vec![0.0],
        })
    }

    /// The summary's geometric means, ranges and counts at the targets, from
    /// rows whose ratios are known: 2× and 1.2× the Newton-LU peer (mean
    /// √2.4, one at 1.5×), 8× and 4× the Newton-QR peer (mean √32, one at
    /// 5×); a row without the QR peer is left out of its line.
    #[test]
    fn the_summary_gives_geometric_means_and_counts_at_the_targets() {
        let row = |lu: f64, qr: Option<f64>| PerStepRow {
            system: "s",
            method: "m".into(),
            h: 0.1,
            steps: 10,
            full: spark(200e-9),
            simplified: spark(200e-9),
            decoupled: spark(100e-9),
            peer: peer(external::CASADI_NEWTON_LU, lu, 10),
            qr_peer: qr.map_or_else(|| Err("not run".into()), |t| peer(external::CASADI_NEWTON_QR, t, 10)),
        };
        let rows = [row(200.0, Some(800.0)), row(120.0, Some(400.0)), row(160.0, None)];
        let s = per_step_summary(&rows[..2]);
        let lu = format!(
            "| CasADi C (Newton-LU) | stage-decoupled | 2 | {:.2} | 1.20–2.00 | 1 at 1.5× or more |",
            2.4f64.sqrt()
        );
        assert!(s.contains(&lu), "{s}");
        let full =
            format!("| CasADi C (Newton-LU) | full | 2 | {:.2} | 0.60–1.00 | 0 at 1.5× or more |", 0.6f64.sqrt());
        assert!(s.contains(&full), "{s}");
        let qr = format!(
            "| CasADi C (Newton-QR) | stage-decoupled | 2 | {:.2} | 4.00–8.00 | 1 at 5× or more |",
            32f64.sqrt()
        );
        assert!(s.contains(&qr), "{s}");
        let with_missing = per_step_summary(&rows);
        assert!(per_round_markdown(&[rows.to_vec()]).contains("| 1 | 1.57 (2 of 3 at 1.5×) | 5.66 (1 of 2 at 5×) |"));
        assert!(with_missing.contains("| CasADi C (Newton-LU) | stage-decoupled | 3 |"), "{with_missing}");
        assert!(with_missing.contains("| CasADi C (Newton-QR) | stage-decoupled | 2 |"), "{with_missing}");
    }

    /// Each entry's minimum over rounds: the faster SPARK run of each
    /// variant and the faster measured peer, a peer measured in one round
    /// only taken from it, rows matched by system and method.
    #[test]
    fn rounds_keep_each_entrys_minimum() {
        let row = |full: f64, decoupled: f64, lu: Result<PeerStepRun, String>| PerStepRow {
            system: "s",
            method: "m".into(),
            h: 0.1,
            steps: 10,
            full: spark(full),
            simplified: spark(5e-7),
            decoupled: spark(decoupled),
            peer: lu,
            qr_peer: Err("not run".into()),
        };
        let a = vec![row(3e-7, 1e-7, peer(external::CASADI_NEWTON_LU, 200.0, 10))];
        let b = vec![row(2e-7, 1.5e-7, Err("the peer failed".into()))];
        let c = vec![row(4e-7, 0.9e-7, peer(external::CASADI_NEWTON_LU, 150.0, 10))];
        let min = minimum_over_rounds(&[a.clone(), b.clone(), c]);
        assert_eq!(min.len(), 1);
        assert_eq!((min[0].full.time_per_step, min[0].decoupled.time_per_step), (2e-7, 0.9e-7));
        assert_eq!(min[0].peer.as_ref().map(|p| p.cpu_time), Ok(150.0 * 1e-9 * 10.0));
        assert!(min[0].qr_peer.is_err());
        let min = minimum_over_rounds(&[b, a]);
        assert_eq!(min[0].peer.as_ref().map(|p| p.cpu_time), Ok(200.0 * 1e-9 * 10.0), "an Err round gives way");
        assert!(minimum_over_rounds(&[]).is_empty());
    }
}

mod report {
    use problems::experiments::work_precision::report::*;
    use problems::experiments::work_precision::{Point, Provider};

    fn point(solver: &str, method: &str, steps: usize, err: f64, time: f64) -> Point {
        Point {
            system: "x".into(),
            solver: solver.into(),
            method: method.into(),
            stages: 2,
            setting: 1.0 / steps as f64,
            steps,
            error_q: err,
            error_v: err / 2.0,
            energy_error: f64::NAN,
            wall_time: time,
            cpu_time: f64::NAN,
            time_per_step: time / steps as f64,
            newton_iterations: 2.0,
            repeats: 3,
        }
    }

    #[test]
    fn time_to_reach_interpolates_in_log_log() {
        let a = point(SPARK, "m", 10, 1e-4, 1e-3);
        let b = point(SPARK, "m", 20, 1e-8, 1e-2);
        let c = [&a, &b];
        let t = time_to_reach(&c, 1e-6).unwrap();
        assert!((t - 10f64.powf(-2.5)).abs() < 1e-12);
        assert_eq!(time_to_reach(&c, 1e-3), Some(1e-3));
        assert_eq!(time_to_reach(&c, 1e-9), None);
    }

    #[test]
    fn per_step_ratio_pairs_equal_steps() {
        let pts = vec![
            point(SPARK, "Gauss s=2", 10, 1e-4, 1e-3),
            point(Provider::NumDual.label(), "Gauss s=2", 10, 1e-4, 4e-3),
            point(Provider::NumDual.label(), "Gauss s=2", 20, 1e-5, 9e-3),
        ];
        let r = per_step_ratios(&pts, Provider::NumDual.label());
        assert_eq!(r["Gauss s=2"], (4.0, 1));
    }
}
