//! `spark section`: the recorded points are crossings of the chosen event
//! (the event function, evaluated independently from the CSV state, is
//! ≈ 0 there, and the crossing direction is the declared one), members run
//! from their documented initial states, and every unusable input is
//! refused with a message that names what to change.

use problems::catalog::SystemKind;
use problems::experiments::section::{member_initial_values, SectionSpec};
use problems::report::files::read_columns;
use spark_runtime::{Method, NewtonOptions, NonholonomicSystem, Vector};
use std::path::{Path, PathBuf};
use std::process::Command;

fn spark() -> Command {
    Command::new(env!("CARGO_BIN_EXE_spark"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spark-section-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn run_ok(args: &[&str], out: &Path) -> String {
    let o = spark().args(args).arg("--out").arg(out).output().unwrap();
    assert!(o.status.success(), "spark {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn run_err(args: &[&str]) -> String {
    let o = spark().args(args).output().unwrap();
    assert!(!o.status.success(), "spark {args:?} should fail; stdout:\n{}", String::from_utf8_lossy(&o.stdout));
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs `spark section` and checks every CSV row against the system's own
/// event function and derivative: `|g| ≤ 1e-12` at the recorded state, the
/// slope `dg/dt` along the motion has the declared sign, members are
/// `0..members` with times in increasing order, and the files exist.
fn check_section<Sys: NonholonomicSystem<N, M> + Default, const N: usize, const M: usize>(
    system: &str,
    event: &str,
    members: usize,
    t_end: &str,
    rising: bool,
) -> usize {
    let out = temp_dir(system);
    let stdout =
        run_ok(&["section", system, "--event", event, "--members", &members.to_string(), "--t-end", t_end], &out);
    assert!(stdout.contains("crossings"), "{stdout}");
    let stem = format!("{system}_{event}");
    for f in [format!("{stem}.png"), format!("{stem}.svg"), "section.json".into()] {
        assert!(out.join(&f).is_file(), "{f} missing");
    }
    let (header, cols) = read_columns(&out.join(format!("{stem}.csv"))).unwrap();
    assert_eq!(header.len(), 2 + 2 * N + 1, "{header:?}");
    assert_eq!(header[0], "member");
    assert_eq!(header[1], "t");
    let index = Sys::EVENTS.iter().position(|e| e.name == event).expect("declared event");
    let sys = Sys::default();
    let rows = cols[0].len();
    assert!(rows > 0, "{system}: no section points");
    let mut seen = vec![0usize; members];
    let mut last_t = vec![f64::NEG_INFINITY; members];
    for (r, &m) in cols[0].iter().enumerate() {
        let member = m as usize;
        assert!(member < members && m == member as f64, "row {r}: member {m}");
        let t = cols[1][r];
        assert!(t > last_t[member], "row {r}: times of member {member} not increasing");
        last_t[member] = t;
        seen[member] += 1;
        let q = Vector::<N>::from_iterator((0..N).map(|i| cols[2 + i][r]));
        let v = Vector::<N>::from_iterator((0..N).map(|i| cols[2 + N + i][r]));
        let g = sys.event_value(index, t, &q, &v);
        assert!(g.abs() <= 1e-12, "{system} row {r}: g = {g:.3e} at the recorded state");
        assert_eq!(cols[2 + 2 * N][r], g, "{system} row {r}: event_value column");
        // For an event function of (t, q) only, the declared direction is
        // the sign of its slope g_t + g_q·v along the motion.
        let grad = sys.event_gradient(index, t, &q, &v);
        if grad.v.amax() == 0.0 {
            let slope = grad.t + grad.q.dot(&v);
            assert!(if rising { slope > 0.0 } else { slope < 0.0 }, "{system} row {r}: slope {slope:.3e}");
        }
    }
    assert!(seen.iter().all(|&c| c > 0), "{system}: a member without crossings: {seen:?}");
    let _ = std::fs::remove_dir_all(&out);
    rows
}

#[test]
fn section_points_of_the_mp_particles_lie_on_the_event_surface() {
    check_section::<problems::systems::McLachlanPerlmutter7, 7, 1>("mp7", "section", 3, "20", true);
    check_section::<problems::systems::McLachlanPerlmutter7Nonholonomic, 7, 1>("mp7-nh", "section", 3, "20", true);
}

#[test]
fn section_points_of_the_sleigh_and_the_rolling_disk_lie_on_the_event_surface() {
    check_section::<problems::systems::ChaplyginSleigh, 3, 1>("sleigh", "turn", 2, "20", false);
    let rows =
        check_section::<problems::systems::scenes::VerticalDisk, 4, 2>("vertical-disk", "revolution", 2, "40", true);
    // The wheel turns at φ̇ = 1 and 1.5 for the two members: sin φ rises
    // through 0 at t = 2πk/φ̇, 6 and 9 times in t ≤ 40.
    assert_eq!(rows, 6 + 9);
}

#[test]
fn members_of_the_mp_particles_are_the_papers_initial_states() {
    // J = 10 members: q1 = cos(jπ/18), v2 = sin(jπ/18), as in §8.4.
    for j in 0..10 {
        let (q, v) = member_initial_values(SystemKind::McLachlanPerlmutter7Nonholonomic, j, 10);
        let theta = j as f64 * std::f64::consts::PI / 18.0;
        assert_eq!(q[0], theta.cos());
        assert_eq!(v[1], theta.sin());
    }
}

#[test]
fn a_section_run_in_the_library_matches_the_cli_contract() {
    let spec = SectionSpec {
        system: SystemKind::McLachlanPerlmutter7,
        event: "nope".into(),
        members: 2,
        method: Method::Gauss,
        stages: 2,
        h: 0.05,
        steps: 10,
        t0: 0.0,
        parameters: Vec::new(),
        newton: NewtonOptions::default(),
        max_halvings: spark_runtime::DEFAULT_MAX_HALVINGS,
    };
    let e = problems::experiments::section::run_section(&spec).unwrap_err().to_string();
    assert!(e.contains("no event `nope`") && e.contains("section"), "{e}");
    let spec = SectionSpec { event: "section".into(), members: 0, ..spec };
    let e = problems::experiments::section::run_section(&spec).unwrap_err().to_string();
    assert!(e.contains("--members"), "{e}");
}

#[test]
fn unusable_section_arguments_are_refused_with_what_to_change() {
    let out = temp_dir("errors");
    let o = out.to_str().unwrap();
    let e = run_err(&["section", "mp7", "--event", "sectoin", "--out", o]);
    assert!(e.contains("no event `sectoin`") && e.contains("did you mean `section`"), "{e}");
    let e = run_err(&["section", "skate", "--event", "section", "--out", o]);
    assert!(e.contains("declares no events") && e.contains("mp7-nh") && e.contains("vertical-disk"), "{e}");
    let e = run_err(&["section", "skait", "--event", "section", "--out", o]);
    assert!(e.contains("unknown system") && e.contains("did you mean"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--members", "0", "--out", o]);
    assert!(e.contains("--members"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--t-end", "-1", "--out", o]);
    assert!(e.contains("--t-end"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--t-end", "1.01", "--h", "0.05", "--out", o]);
    assert!(e.contains("whole"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--h", "nan", "--out", o]);
    assert!(e.contains("--h"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--x", "q9", "--out", o]);
    assert!(e.contains("--x `q9`") && e.contains("q_q1"), "{e}");
    let e = run_err(&["section", "sleigh", "--event", "turn", "--param", "alfa=0.1", "--out", o]);
    assert!(e.contains("did you mean `alpha`"), "{e}");
    // A negative mass, as in `spark run`: refused, not integrated.
    let e = run_err(&["section", "sleigh", "--event", "turn", "--param", "m=-1", "--members", "1", "--out", o]);
    assert!(e.contains("kinetic energy is not positive") && e.contains("m = -1.000e0"), "{e}");
    let e = run_err(&["section", "mp7", "--event", "section", "--stages", "9", "--out", o]);
    assert!(e.contains("s = 9") || e.contains("stages"), "{e}");
    // A run without any crossing says how to get some.
    let e = run_err(&["section", "mp7", "--event", "section", "--t-end", "0.05", "--members", "1", "--out", o]);
    assert!(e.contains("no crossing"), "{e}");
    // Nothing was written by the refused runs.
    let written: Vec<_> = std::fs::read_dir(&out)
        .map(|d| d.flatten().map(|e| e.file_name()).filter(|n| n != ".spark-lock").collect())
        .unwrap_or_default();
    assert!(written.is_empty(), "{written:?}");
    let _ = std::fs::remove_dir_all(&out);
}

/// The crossings a section keeps are bounded: members that find more than
/// the limit stop there (they do not run on, collecting crossings until an
/// allocation failure aborts the process), and the section says how many
/// it keeps and what to change. Here the rolling disk with h = 5 (its
/// `sin φ` crosses zero about every step) over 2000 steps per member.
#[test]
fn a_section_with_more_crossings_than_fit_stops_with_what_to_change() {
    use problems::experiments::section::{max_section_points, run_section_with_limit, SectionError};
    let spec = SectionSpec {
        system: SystemKind::VerticalDisk,
        event: "revolution".into(),
        members: 3,
        method: Method::Gauss,
        stages: 2,
        h: 5.0,
        steps: 2000,
        t0: 0.0,
        parameters: Vec::new(),
        newton: NewtonOptions::default(),
        max_halvings: spark_runtime::DEFAULT_MAX_HALVINGS,
    };
    let all = run_section_with_limit(&spec, usize::MAX).unwrap();
    let found = all.points.len();
    assert!(found > 300, "{found} crossings");
    let started = std::time::Instant::now();
    let e = run_section_with_limit(&spec, 100).unwrap_err();
    assert!(matches!(e, SectionError::TooManyCrossings { limit: 100, .. }), "{e}");
    let text = e.to_string();
    assert!(text.contains("more than 100 times") && text.contains("--members") && text.contains("--t-end"), "{text}");
    // The members stopped near the limit, not at their last step.
    let SectionError::TooManyCrossings { t, .. } = e else { unreachable!() };
    assert!(t < 0.5 * 2000.0 * 5.0, "stopped at t = {t}");
    assert!(started.elapsed().as_secs_f64() < 10.0);
    // A limit the section stays within changes nothing.
    assert_eq!(run_section_with_limit(&spec, found).unwrap(), all);
    // The default limit is what fits in memory: millions of crossings.
    assert!(max_section_points(4) > 1_000_000, "{}", max_section_points(4));
}

/// A section whose members halve failing steps counts each member's
/// halvings (the McLachlan–Perlmutter particles at h = 5, a hundred times
/// their step), and `max_halvings = 0` makes the first failing step an
/// error; at the system's step no member halves.
#[test]
fn a_section_counts_each_members_halved_steps() {
    let spec = SectionSpec {
        system: SystemKind::McLachlanPerlmutter7Nonholonomic,
        event: "section".into(),
        members: 2,
        method: Method::Gauss,
        stages: 2,
        h: 5.0,
        steps: 10,
        t0: 0.0,
        parameters: Vec::new(),
        newton: NewtonOptions::default(),
        max_halvings: spark_runtime::DEFAULT_MAX_HALVINGS,
    };
    let halved = problems::experiments::section::run_section(&spec).unwrap();
    assert_eq!(halved.rejected_steps.len(), 2);
    assert!(halved.rejected_steps.iter().all(|&r| r > 0), "{:?}", halved.rejected_steps);
    let e = problems::experiments::section::run_section(&SectionSpec { max_halvings: 0, ..spec.clone() }).unwrap_err();
    assert!(e.to_string().contains("failed"), "{e}");
    let fixed = problems::experiments::section::run_section(&SectionSpec { h: 0.05, steps: 200, ..spec }).unwrap();
    assert_eq!(fixed.rejected_steps, vec![0, 0]);
}
