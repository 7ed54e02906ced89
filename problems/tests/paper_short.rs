//! A shortened `spark paper` run (same code path as the full one, intervals
//! scaled down): every file is written, and the numbers behind the figures
//! agree with a direct computation that drives the stepper by hand.

use problems::experiments::paper::{run_paper, PaperConfig, PaperReport};
use problems::report::files::read_columns;
use problems::report::progress::Progress;
use problems::systems::mp7_initial_values;
use problems::systems::{McLachlanPerlmutter7, McLachlanPerlmutter7Nonholonomic, NonholonomicParticle, Skate};
use spark_runtime::{Method, NonholonomicSystem, State, Stepper, Tableau, Vector};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

const FRACTION: f64 = 0.004;

struct Shared {
    dir: PathBuf,
    cfg: PaperConfig,
    report: PaperReport,
}

/// One shortened run shared by all tests of this file.
fn shared() -> &'static Shared {
    static RUN: OnceLock<Shared> = OnceLock::new();
    RUN.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("spark-paper-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cfg = PaperConfig::shortened(&dir, FRACTION);
        let report = run_paper(&cfg, &Progress::hidden()).expect("shortened paper run");
        Shared { dir, cfg, report }
    })
}

fn column<'a>(header: &[String], cols: &'a [Vec<f64>], name: &str) -> &'a [f64] {
    let i = header.iter().position(|h| h == name).unwrap_or_else(|| panic!("column {name} missing in {header:?}"));
    &cols[i]
}

/// Energy errors `E_k − E_0` of `steps` steps driven directly by `Stepper::step`.
fn direct_energy_errors<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    cfg: &PaperConfig,
    q0: &[f64],
    v0: &[f64],
    h: f64,
    steps: usize,
) -> Vec<f64>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let probe = sys.clone();
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap()).with_options(cfg.newton);
    let mut state = State::new(0.0, Vector::<N>::from_column_slice(q0), Vector::<N>::from_column_slice(v0));
    let e0 = probe.energy(0.0, &state.q, &state.v);
    let mut out = vec![0.0];
    for _ in 0..steps {
        state = stepper.step(&state, h).unwrap().state;
        out.push(probe.energy(state.t, &state.q, &state.v) - e0);
    }
    out
}

#[test]
fn every_file_is_written() {
    let s = shared();
    let mut expected: Vec<String> = Vec::new();
    for f in 1..=4 {
        for ext in ["png", "svg", "csv"] {
            expected.push(format!("fig8_{f}.{ext}"));
        }
    }
    expected.extend(
        [
            "fig8_4_energy_errors.csv",
            "fig8_4_printed.csv",
            "fig8_4_printed_energy_errors.csv",
            "summary.md",
            "summary.json",
        ]
        .map(String::from),
    );
    for name in &expected {
        let p = s.dir.join(name);
        let len = std::fs::metadata(&p).unwrap_or_else(|_| panic!("{} not written", p.display())).len();
        assert!(len > 100, "{} is only {len} bytes", p.display());
        assert!(s.report.files.iter().any(|f| f == &p), "{name} missing from the report's file list");
    }
    for f in &s.report.files {
        assert!(f.exists(), "{} listed but absent", f.display());
    }
    let png = std::fs::read(s.dir.join("fig8_1.png")).unwrap();
    assert_eq!(&png[..4], b"\x89PNG");
    let svg = std::fs::read_to_string(s.dir.join("fig8_4.svg")).unwrap();
    assert!(svg.contains("McLachlan"), "figure title missing from the SVG");
    let md = std::fs::read_to_string(s.dir.join("summary.md")).unwrap();
    for fig in ["Fig. 8.1", "Fig. 8.2", "Fig. 8.3", "Fig. 8.4", "exponent"] {
        assert!(md.contains(fig), "summary.md lacks {fig}");
    }
}

#[test]
fn summary_rows_cover_every_run_and_constraints_hold() {
    let s = shared();
    // 3 + 3 + (3 + 6) single runs and 3 ensemble rows per reading of the §8.4 constraint.
    assert_eq!(s.report.rows.len(), 21);
    for r in &s.report.rows {
        assert!(
            r.max_constraint_residual <= 1e-12,
            "{} {}: residual {:e}",
            r.figure,
            r.method,
            r.max_constraint_residual
        );
        assert!(r.max_energy_error.is_finite() && r.steps > 0);
    }
    let ens: Vec<_> = s.report.rows.iter().filter(|r| r.figure == "Fig. 8.4").collect();
    assert_eq!(ens.len(), 6);
    let per_run = (s.cfg.fig84_t_end / 0.05).round() as usize;
    let per_run_printed = (s.cfg.fig84_printed_t_end / 0.05).round() as usize;
    assert_eq!(ens.iter().filter(|r| r.system == "mp7-nh").count(), 3);
    for r in &ens {
        let n = if r.system == "mp7" { per_run_printed } else { per_run };
        assert!(r.runs == s.cfg.fig84_members && r.steps == n * s.cfg.fig84_members, "{r:?}");
    }
    assert_eq!(s.report.growth.len(), 6);
    assert!(s.report.growth.iter().all(|g| g.fit.is_some_and(|f| f.exponent.is_finite())));
}

#[test]
fn fig81_numbers_match_a_direct_computation() {
    let s = shared();
    let (header, cols) = read_columns(&s.dir.join("fig8_1.csv")).unwrap();
    let t = column(&header, &cols, "t");
    let steps = t.len() - 1;
    assert_eq!(steps, (s.cfg.fig81_t_end / 0.2).round() as usize);
    for (k, tk) in t.iter().enumerate() {
        assert!((tk - 0.2 * k as f64).abs() < 1e-12);
    }
    let (q0, v0) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let sys = NonholonomicParticle::default();
    let direct = [
        direct_energy_errors::<_, 3, 1, 1, 7>(sys, Method::Gauss, &s.cfg, &q0, &v0, 0.2, steps),
        direct_energy_errors::<_, 3, 1, 2, 11>(sys, Method::Gauss, &s.cfg, &q0, &v0, 0.2, steps),
        direct_energy_errors::<_, 3, 1, 3, 15>(sys, Method::Gauss, &s.cfg, &q0, &v0, 0.2, steps),
    ];
    for (s_idx, d) in direct.iter().enumerate() {
        let file = column(&header, &cols, &format!("energy_error_gauss_s{}", s_idx + 1));
        assert_eq!(file.len(), d.len());
        for (a, b) in file.iter().zip(d) {
            assert!((a - b).abs() <= 1e-13 + 1e-9 * b.abs(), "Gauss s={}: file {a:e} vs direct {b:e}", s_idx + 1);
        }
    }
    // The figure is not trivially zero: Gauss s=1 has a visible error.
    assert!(direct[0].iter().any(|e| e.abs() > 1e-8));
}

#[test]
fn fig82_numbers_match_a_direct_computation() {
    let s = shared();
    let (header, cols) = read_columns(&s.dir.join("fig8_2.csv")).unwrap();
    let steps = column(&header, &cols, "t").len() - 1;
    let d = direct_energy_errors::<_, 3, 1, 3, 15>(
        Skate::default(),
        Method::LobattoIIIAB,
        &s.cfg,
        &[0.0; 3],
        &[0.0, 0.0, 1.0],
        0.1,
        steps,
    );
    let file = column(&header, &cols, "energy_error_lobatto_iiia_b_s3");
    for (a, b) in file.iter().zip(&d) {
        assert!((a - b).abs() <= 1e-13 + 1e-9 * b.abs(), "file {a:e} vs direct {b:e}");
    }
}

/// Fig. 8.4's statistic in `file` (LDA column) against a direct computation on `Sys`.
fn check_fig84_statistic<Sys: NonholonomicSystem<7, 1> + Clone + Default>(s: &Shared, file: &str, t_end: f64) {
    let (header, cols) = read_columns(&s.dir.join(file)).unwrap();
    let t = column(&header, &cols, "t");
    let quantity = column(&header, &cols, "scaled_mean_square_energy_error_lobatto_iiib_a_lda_s2");
    let every = s.cfg.fig84_sample_every;
    let steps = (t_end / 0.05).round() as usize;
    assert_eq!(t.len(), steps / every + 1);
    let members = s.cfg.fig84_members;
    let mut sum = vec![0.0; t.len()];
    for j in 0..members {
        let (q0, v0) = mp7_initial_values(j, members - 1);
        let sys = Sys::default();
        let e0 = sys.energy(0.0, &Vector::<7>::from_column_slice(&q0), &Vector::<7>::from_column_slice(&v0));
        assert!((e0 - 3.06).abs() < 1e-14, "member {j}: E0 = {e0}");
        let d = direct_energy_errors::<_, 7, 1, 2, 23>(sys, Method::LobattoIIIBALda, &s.cfg, &q0, &v0, 0.05, steps);
        for (k, acc) in sum.iter_mut().enumerate() {
            *acc += d[k * every].powi(2);
        }
    }
    let h4 = 0.05f64.powi(4);
    for (k, (file, acc)) in quantity.iter().zip(&sum).enumerate() {
        let direct = acc / members as f64 / h4;
        assert!((file - direct).abs() <= 1e-9 * direct.abs() + 1e-12, "sample {k}: file {file:e} vs direct {direct:e}");
    }
    assert!(quantity.iter().skip(1).all(|q| *q > 0.0));
}

#[test]
fn fig84_statistic_matches_a_direct_computation() {
    let s = shared();
    check_fig84_statistic::<McLachlanPerlmutter7Nonholonomic>(s, "fig8_4.csv", s.cfg.fig84_t_end);
    check_fig84_statistic::<McLachlanPerlmutter7>(s, "fig8_4_printed.csv", s.cfg.fig84_printed_t_end);
}

#[test]
fn shortened_config_scales_every_interval() {
    let full = PaperConfig::full(Path::new("x"));
    let short = PaperConfig::shortened(Path::new("x"), 0.5);
    assert_eq!(full.fig84_t_end, 50_000.0);
    assert_eq!(full.fig84_members, 10);
    assert_eq!(full.fig84_sample_every, 100);
    assert_eq!(short.fig81_t_end, 125.0);
    assert_eq!(short.fig84_t_end, 25_000.0);
}
