//! Long runs: 10⁶ steps on the particle and the skate (bounded energy error,
//! no drift, constraints to 1e-12), and the chaotic McLachlan–Perlmutter
//! particles, whose energy error grows like a random walk with the
//! nonholonomic reading of the constraint and stays bounded with the
//! constraint as printed (holonomic; Lobatto IIIA-B is RATTLE there).

use super::{newton, run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::{log_points, sci, thin};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::report::stats::{
    drift_test, energy_structure_function, fit_line, fit_power, structure_plateau, structure_slope, window_mean,
    LineFit, PowerFit,
};
use crate::systems::{mp7_initial_values, mp7_phi, mp7_rattle};
use crate::systems::{McLachlanPerlmutter7, McLachlanPerlmutter7Nonholonomic, NonholonomicParticle, Skate};
use rayon::prelude::*;
use spark_runtime::{Method, State, Stepper, Tableau, Vector};

/// The runs of the long-time case: system, method, stage count.
const LONG_TIME_JOBS: [(&str, Method, usize); 4] = [
    ("particle", Method::Gauss, 2),
    ("particle", Method::LobattoIIIAB, 3),
    ("skate", Method::Gauss, 2),
    ("skate", Method::LobattoIIIAB, 3),
];

/// 10⁶ steps (quick: 2·10⁴) of Gauss s = 2 and Lobatto IIIA-B s = 3 with
/// `h = 0.1` on the particle and the skate (paper initial values).
pub fn long_time(scale: Scale) -> Result<CaseReport, StressError> {
    let steps = match scale {
        Scale::Quick => 20_000,
        Scale::Full => 1_000_000,
    };
    let h = 0.1;
    let every = (steps / 20_000).max(1);
    let mut c = CaseReport::new(
        "long_time",
        "Long time: 10⁶ steps, particle and skate",
        format!(
            "{steps} steps of h = {h} (t ∈ [0, {}]) with Gauss SPARK s = 2 and Lobatto IIIA-B SPARK s = 3 on the \
             nonholonomic particle (q0 = (1,0,0), v0 = (0,1,0)) and the skate (q0 = 0, v0 = (0,0,1)); energy and \
             residual observed at every step, recorded every {every}. Drift is judged by the slope of |E − E0| \
             against t through 20 block means (its standard error accounts for the correlated samples) and by the \
             share of the error band a linear drift would explain.",
            steps as f64 * h
        ),
    );
    let results = LONG_TIME_JOBS
        .par_iter()
        .map(|&(sys, method, s)| long_time_measure(sys, method, s, h, steps, every))
        .collect::<Result<Vec<_>, _>>()?;
    let labels: Vec<String> =
        LONG_TIME_JOBS.iter().map(|&(sys, method, s)| format!("{sys}, {}", method.label(s))).collect();
    for (label, r) in labels.iter().zip(&results) {
        long_time_judge(&mut c, label, r);
    }
    c.energy = format!(
        "max |E − E0| over the four runs {}; see the drift checks",
        sci(results.iter().filter_map(|r| r.as_ref().ok()).map(|d| d.max_energy_error).fold(0.0, f64::max))
    );
    c.figure = Some(long_time_figure(&c.title, &labels, &results));
    Ok(c)
}

/// One run of the long-time case (paper initial values), or the typed
/// error's text.
fn long_time_measure(
    sys: &str,
    method: Method,
    s: usize,
    h: f64,
    steps: usize,
    every: usize,
) -> Result<Result<RunData, String>, StressError> {
    let (pq, pv) = (Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let (sq, sv) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let particle = NonholonomicParticle::default;
    let r = match (sys, s) {
        ("particle", 2) => run_fixed(
            &mut <Stepper![NonholonomicParticle, 2]>::new(particle(), Tableau::new(method)?),
            &pq,
            &pv,
            h,
            steps,
            every,
            0,
        ),
        ("particle", _) => run_fixed(
            &mut <Stepper![NonholonomicParticle, 3]>::new(particle(), Tableau::new(method)?),
            &pq,
            &pv,
            h,
            steps,
            every,
            0,
        ),
        (_, 2) => run_fixed(
            &mut <Stepper![Skate, 2]>::new(Skate::default(), Tableau::new(method)?),
            &sq,
            &sv,
            h,
            steps,
            every,
            0,
        ),
        _ => run_fixed(
            &mut <Stepper![Skate, 3]>::new(Skate::default(), Tableau::new(method)?),
            &sq,
            &sv,
            h,
            steps,
            every,
            0,
        ),
    };
    Ok(r.map_err(|e| e.to_string()))
}

/// The checks and metrics of one long run: residual at every step, no drift.
fn long_time_judge(c: &mut CaseReport, label: &str, r: &Result<RunData, String>) {
    let d = match r {
        Err(e) => {
            c.errors.push(format!("{label}: {e}"));
            c.check(format!("{label}: completes"), false, e.clone());
            return;
        }
        Ok(d) => d,
    };
    c.absorb(d);
    let dt = drift_test(&d.t, &d.energy_error, 20);
    c.check(
        format!("{label}: constraint residual ≤ 1e-12 at every step"),
        d.max_residual <= 1e-12,
        format!("max |k| = {}", sci(d.max_residual)),
    );
    match dt {
        Some(dt) => {
            c.check(
                format!("{label}: no energy drift"),
                dt.no_drift(),
                format!(
                    "block slope {} ± {} (|slope|/se = {:.2}); OLS slope {} ± {}; drift fraction {:.3}; \
                     max |E − E0| = {}",
                    sci(dt.block_slope),
                    sci(dt.block_std_error),
                    dt.block_slope.abs() / dt.block_std_error,
                    sci(dt.slope),
                    sci(dt.slope_std_error),
                    dt.drift_fraction,
                    sci(d.max_energy_error)
                ),
            );
            c.metric(
                format!("{label}: slope of |E−E0|"),
                format!("{} ± {}", sci(dt.block_slope), sci(dt.block_std_error)),
            );
            c.metric(format!("{label}: drift fraction"), format!("{:.4}", dt.drift_fraction));
        }
        None => c.check(format!("{label}: no energy drift"), false, "too few samples to fit"),
    }
    c.metric(format!("{label}: max |E−E0|"), sci(d.max_energy_error));
    c.metric(format!("{label}: max |k|"), sci(d.max_residual));
    c.metric(format!("{label}: mean Newton iterations"), format!("{:.2}", d.report.newton_iterations_mean));
}

/// `|E − E0|` with its fitted line for each completed run, and the
/// constraint residuals of all of them.
fn long_time_figure(title: &str, labels: &[String], results: &[Result<RunData, String>]) -> Figure {
    let mut panels = Vec::new();
    let mut residual_series = Vec::new();
    for (label, d) in labels.iter().zip(results).filter_map(|(l, r)| Some((l, r.as_ref().ok()?))) {
        let pts: Vec<(f64, f64)> = d.t.iter().zip(&d.energy_error).map(|(&t, &e)| (t, e.abs())).collect();
        let mut series = vec![Series::new("|E − E0|", thin(pts, 4000))];
        if let Some(f) = fit_line(&d.t, &d.energy_error.iter().map(|e| e.abs()).collect::<Vec<_>>()) {
            let (t0, t1) = (d.t[0], *d.t.last().unwrap_or(&0.0));
            series.push(Series {
                label: format!("fit: slope {}", sci(f.slope)),
                points: vec![(t0, f.intercept + f.slope * t0), (t1, f.intercept + f.slope * t1)],
                dashed: true,
            });
        }
        panels.push(Panel {
            title: label.clone(),
            x_label: "t".into(),
            y_label: "|E − E0|".into(),
            x_scale: Axis::Linear,
            y_scale: Axis::Linear,
            series,
        });
        residual_series.push(Series::new(label.clone(), thin(log_points(&d.t, &d.residual, 1e-18), 2000)));
    }
    if !residual_series.is_empty() {
        panels.push(Panel {
            title: "constraint residual (zeros at 1e-18)".into(),
            x_label: "t".into(),
            y_label: "max |k|".into(),
            x_scale: Axis::Linear,
            y_scale: Axis::Log,
            series: residual_series,
        });
    }
    Figure { title: title.to_string(), panels, columns: 2, panel_size: (620, 380) }
}

/// Lags up to this (time units) measure the plateau of the structure function.
const PLATEAU_UNTIL: f64 = 50.0;

/// Which constraint of §8.4 a chaos ensemble uses.
#[derive(Clone, Copy, PartialEq)]
enum Mp7Reading {
    /// `v1 + q2 v5 + q3 v6 + q4 v7 = 0`.
    Nonholonomic,
    /// `v1 + q5 v5 + q6 v6 + q7 v7 = 0` as printed (holonomic).
    Printed,
}

/// One chaos ensemble: the statistic and the largest `|φ(q_k) − φ(q_0)|`.
struct Ensemble {
    t: Vec<f64>,
    measure: Vec<f64>,
    max_phi: f64,
}

impl Ensemble {
    /// The statistic `(1/h⁴)·mean_j (E_jk − E_j0)²` over the common samples
    /// of the completed members, and the largest drift of `φ`.
    fn of(ok: &[&RunData], h: f64) -> Self {
        let n = ok.iter().map(|d| d.t.len()).min().unwrap_or(0);
        let h4 = h.powi(4);
        Ensemble {
            t: ok[0].t[..n].to_vec(),
            measure: (0..n)
                .map(|k| ok.iter().map(|d| d.energy_error[k].powi(2)).sum::<f64>() / ok.len() as f64 / h4)
                .collect(),
            max_phi: ok
                .iter()
                .map(|d| {
                    let p0 = mp7_phi(&d.q[0]);
                    d.q.iter().map(|q| (mp7_phi(q) - p0).abs()).fold(0.0, f64::max)
                })
                .fold(0.0, f64::max),
        }
    }
}

/// What the chaos case judges one ensemble by.
struct ChaosStatistics {
    /// Power-law fit from `fit_from`, and over the last decade.
    fit: Option<PowerFit>,
    late: Option<PowerFit>,
    /// Mean statistic over `[0.05, 0.15]·T` and `[0.9, 1]·T`, and their ratio.
    early_mean: f64,
    late_mean: f64,
    growth: f64,
    /// Structure function: plateau, last lag and value, slope above the plateau.
    plateau: f64,
    sf_last: (f64, f64),
    sf_slope: Option<LineFit>,
    /// Largest `|E − E0|` over the ensemble.
    max_energy_error: f64,
}

/// One row of the chaos case: reading, method, label, final time.
type ChaosRun = (Mp7Reading, Method, &'static str, f64);

/// `(1/h⁴)·mean_j (E_jk − E_j0)²` over the paper's 10 initial values of the
/// McLachlan–Perlmutter particles, `h = 0.05`, for both readings of the
/// constraint: the nonholonomic one over t ∈ [0, 50000] (quick: [0, 4000]),
/// the printed, holonomic one over a tenth of that (quick: a quarter); plus a
/// check that on the printed one Lobatto IIIA-B SPARK is RATTLE.
pub fn chaos(scale: Scale) -> Result<CaseReport, StressError> {
    let (t_nonholonomic, t_printed, fit_from) = match scale {
        Scale::Quick => (4000.0, 1000.0, 20.0),
        Scale::Full => (50_000.0, 5000.0, 50.0),
    };
    let (h, every, members) = (0.05, 100, 10);
    let mut c = CaseReport::new(
        "chaos",
        "Chaos: McLachlan–Perlmutter particles",
        format!(
            "The paper's §8.4 ensemble: {members} initial values q0 = (cos θ_j, 0.6, 0.4, 0.2, 1, 1, 1), \
             v0 = (0, sin θ_j, 0, …), E = 3.06, h = {h}, Gauss s = 2 and Lobatto IIIA-B s = 2 (full Newton), \
             for two readings of the constraint. As printed, v1 + q5 v5 + q6 v6 + q7 v7 = 0 is \
             d/dt[q1 + ½(q5² + q6² + q7²)] = 0, a holonomic constraint (t ∈ [0, {t_printed}]); read as \
             v1 + q2 v5 + q3 v6 + q4 v7 = 0 (index i − m) it is nonholonomic (t ∈ [0, {t_nonholonomic}]). \
             The measure (1/h⁴)·mean_j (E_jk − E_j0)² is fitted by C·t^p (log-spaced samples) on t ≥ {fit_from} \
             and on the last decade: p ≈ 1 is a random walk of the energy error, p ≈ 2 a drift, p ≈ 0 bounded. \
             Investigation behind it: docs/stress/chaos.md and `cargo run --release -p problems --example mp_chaos`."
        ),
    );
    let rattle = rattle_difference(h, members, &mut c.errors)?;
    c.check(
        "printed constraint: a Lobatto IIIA-B SPARK step equals an independent RATTLE step (≤ 1e-13)",
        rattle <= 1e-13,
        format!("max difference over 400 steps from the same state: {}", sci(rattle)),
    );
    let runs: [ChaosRun; 4] = [
        (Mp7Reading::Nonholonomic, Method::LobattoIIIAB, "nonholonomic reading, Lobatto IIIA-B s=2", t_nonholonomic),
        (Mp7Reading::Nonholonomic, Method::Gauss, "nonholonomic reading, Gauss s=2", t_nonholonomic),
        (Mp7Reading::Printed, Method::LobattoIIIAB, "printed (holonomic), Lobatto IIIA-B s=2", t_printed),
        (Mp7Reading::Printed, Method::Gauss, "printed (holonomic), Gauss s=2", t_printed),
    ];
    let mut panels: Vec<(Mp7Reading, Vec<Series>)> =
        vec![(Mp7Reading::Nonholonomic, Vec::new()), (Mp7Reading::Printed, Vec::new())];
    let mut all_ok = true;
    for run in runs {
        let (reading, _, label, _) = run;
        let data = chaos_measure(run, h, every, members)?;
        let ok: Vec<&RunData> = data.iter().filter_map(|r| r.as_ref().ok()).collect();
        for e in data.iter().filter_map(|r| r.as_ref().err()) {
            c.errors.push(format!("{label}: {e}"));
            all_ok = false;
        }
        if ok.is_empty() {
            c.check(format!("{label}: ensemble completes"), false, "every member failed (see errors)");
            continue;
        }
        for d in &ok {
            c.absorb(d);
        }
        let e = Ensemble::of(&ok, h);
        let stats = chaos_statistics(&e, &ok, run.3, fit_from, every as f64 * h, h);
        chaos_judge(&mut c, run, &e, &stats, fit_from);
        let target = if reading == Mp7Reading::Nonholonomic { 0 } else { 1 };
        panels[target].1.push(Series::new(label, thin(log_points(&e.t[1..], &e.measure[1..], 1e-30), 3000)));
    }
    c.check("every member completes", all_ok, if all_ok { "all runs completed".into() } else { c.errors.join("; ") });
    c.energy = "nonholonomic reading: random walk (fitted exponents in the metrics); constraint as printed: \
                holonomic, Lobatto IIIA-B = RATTLE, bounded as a symplectic method should be"
        .into();
    c.figure = Some(chaos_figure(&c.title, panels));
    Ok(c)
}

/// The printed constraint is holonomic, and Lobatto IIIA-B SPARK on it is
/// RATTLE: the largest difference between a SPARK step and an independent
/// RATTLE step from the same state, over 400 states along a trajectory
/// (infinite, with the error in `errors`, when a step fails).
fn rattle_difference(h: f64, members: usize, errors: &mut Vec<String>) -> Result<f64, StressError> {
    let (q, v) = mp7_initial_values(3, members - 1);
    let mut s = State::new(0.0, Vector::<7>::from_column_slice(&q), Vector::<7>::from_column_slice(&v));
    let mut st =
        <Stepper![McLachlanPerlmutter7, 2]>::new(McLachlanPerlmutter7::default(), Tableau::new(Method::LobattoIIIAB)?)
            .with_options(newton());
    let mut worst: f64 = 0.0;
    for _ in 0..400 {
        match st.step(&s, h) {
            Ok(r) => {
                let (q1, v1) = mp7_rattle(&s.q, &s.v, h);
                worst = worst.max((r.state.q - q1).amax().max((r.state.v - v1).amax()));
                s = r.state;
            }
            Err(e) => {
                errors.push(format!("RATTLE comparison: {e}"));
                return Ok(f64::INFINITY);
            }
        }
    }
    Ok(worst)
}

/// The ensemble of one chaos row, in parallel: each member's run or the
/// typed error's text.
fn chaos_measure(
    (reading, method, _, t_end): ChaosRun,
    h: f64,
    every: usize,
    members: usize,
) -> Result<Vec<Result<RunData, String>>, StressError> {
    let steps = (t_end / h).round() as usize;
    (0..members)
        .into_par_iter()
        .map(|j| -> Result<Result<RunData, String>, StressError> {
            let (q, v) = mp7_initial_values(j, members - 1);
            let (q, v) = (Vector::<7>::from_column_slice(&q), Vector::<7>::from_column_slice(&v));
            Ok(match reading {
                Mp7Reading::Nonholonomic => {
                    let system = McLachlanPerlmutter7Nonholonomic::default();
                    let mut st = <Stepper![McLachlanPerlmutter7Nonholonomic, 2]>::new(system, Tableau::new(method)?)
                        .with_options(newton());
                    run_fixed(&mut st, &q, &v, h, steps, every, 0)
                }
                Mp7Reading::Printed => {
                    let system = McLachlanPerlmutter7::default();
                    let mut st =
                        <Stepper![McLachlanPerlmutter7, 2]>::new(system, Tableau::new(method)?).with_options(newton());
                    run_fixed(&mut st, &q, &v, h, steps, every, 0)
                }
            }
            .map_err(|e| e.to_string()))
        })
        .collect()
}

/// Fits, window means and the structure function of one ensemble sampled
/// every `dt`.
fn chaos_statistics(e: &Ensemble, ok: &[&RunData], t_end: f64, fit_from: f64, dt: f64, h: f64) -> ChaosStatistics {
    let early_mean = window_mean(&e.t, &e.measure, 0.05 * t_end, 0.15 * t_end);
    let late_mean = window_mean(&e.t, &e.measure, 0.9 * t_end, t_end);
    // The structure function averages over every start time, so it
    // separates a random walk (S − plateau ∝ Δ) from a bounded error
    // (S flat) far more sharply than the ensemble mean at one time.
    let n = e.t.len();
    let series: Vec<&[f64]> = ok.iter().map(|d| &d.energy_error[..n]).collect();
    let sf = energy_structure_function(&series, dt, h);
    ChaosStatistics {
        fit: fit_power(&e.t, &e.measure, fit_from, 200),
        late: fit_power(&e.t, &e.measure, t_end / 10.0, 200),
        early_mean,
        late_mean,
        growth: late_mean / early_mean,
        plateau: structure_plateau(&sf, PLATEAU_UNTIL),
        sf_last: sf.last().copied().unwrap_or((0.0, 0.0)),
        sf_slope: structure_slope(&sf, PLATEAU_UNTIL, 5),
        max_energy_error: ok.iter().map(|d| d.max_energy_error).fold(0.0, f64::max),
    }
}

/// The metrics and checks of one chaos row.
fn chaos_judge(
    c: &mut CaseReport,
    (reading, method, label, t_end): ChaosRun,
    e: &Ensemble,
    st: &ChaosStatistics,
    fit_from: f64,
) {
    let show = |f: Option<PowerFit>| {
        f.map_or("—".to_string(), |f| format!("{:.3} ± {:.3}", f.exponent, f.exponent_std_error))
    };
    let (growth, plateau, sf_last) = (st.growth, st.plateau, st.sf_last);
    c.metric(format!("{label}: exponent p on t ≥ {fit_from}"), show(st.fit));
    c.metric(format!("{label}: exponent p on t ≥ {}", t_end / 10.0), show(st.late));
    c.metric(format!("{label}: coefficient C (t ≥ {fit_from})"), st.fit.map_or("—".into(), |f| sci(f.coefficient)));
    c.metric(
        format!("{label}: mean measure over t ∈ [0.05, 0.15]·T and [0.9, 1]·T"),
        format!("{} → {} (×{:.2})", sci(st.early_mean), sci(st.late_mean), growth),
    );
    c.metric(format!("{label}: max |φ(q) − φ(q0)|, φ = q1 + ½(q5² + q6² + q7²)"), sci(e.max_phi));
    c.metric(format!("{label}: max |E−E0| over the ensemble"), sci(st.max_energy_error));
    let show_slope = st.sf_slope.map_or("— (nothing above the plateau)".to_string(), |f| {
        format!("{:.2} ± {:.2}", f.slope, f.slope_std_error)
    });
    c.metric(
        format!("{label}: structure function S(Δ), plateau (Δ ≤ {PLATEAU_UNTIL}) → S at Δ = {}", sf_last.0),
        format!(
            "{} → {} (×{:.2}); log–log slope of S − plateau on the 5 largest lags: {show_slope}",
            sci(plateau),
            sci(sf_last.1),
            sf_last.1 / plateau
        ),
    );
    match reading {
        // One criterion for every method, at both scales: the claim itself,
        // S(Δ) − plateau ∝ Δ (slope 1), told apart from a bounded error (S
        // flat: nothing above the plateau) and from a steady drift (slope 2).
        // The band is wide because a 10-member chaotic ensemble is one
        // realization: initial values moved by 1e-15 … 1e-12 give slopes
        // 1.05–1.33 (Gauss s=2) and 1.13–1.33 (Lobatto IIIA-B s=2), and
        // Gauss's ensemble-mean exponent p 0.76–1.36. The bounded O(h²)
        // oscillation dominates the ensemble mean for the first decades, so
        // p is reported, not judged.
        Mp7Reading::Nonholonomic => {
            let detail = format!(
                "S ×{:.2} above its plateau at Δ = {}, slope {show_slope}; ensemble mean ×{growth:.2} from \
                 [0.05, 0.15]·T to [0.9, 1]·T; p on t ≥ {fit_from} = {}",
                sf_last.1 / plateau,
                sf_last.0,
                show(st.fit)
            );
            c.check(
                format!(
                    "{label}: energy error is a random walk: S(Δ) − plateau ∝ Δ (slope within 1 ± 0.5: bounded \
                     would be flat, a drift slope 2)"
                ),
                st.sf_slope.is_some_and(|f| (f.slope - 1.0).abs() <= 0.5),
                detail,
            );
        }
        Mp7Reading::Printed if method == Method::LobattoIIIAB => {
            c.check(
                format!("{label}: φ(q) is conserved to round-off (≤ 1e-11): the constraint is holonomic"),
                e.max_phi <= 1e-11,
                format!("max |φ − φ0| = {}", sci(e.max_phi)),
            );
            c.check(
                format!("{label}: energy error stays bounded, as for the symplectic RATTLE (S(Δ_max) ≤ 1.3 × plateau)"),
                sf_last.1 <= 1.3 * plateau,
                format!(
                    "S ×{:.2}; ensemble mean ×{growth:.2} from [0.05, 0.15]·T to [0.9, 1]·T; p on t ≥ {fit_from} = {}",
                    sf_last.1 / plateau,
                    show(st.fit)
                ),
            );
        }
        Mp7Reading::Printed => {}
    }
}

/// The ensemble statistic of each reading, log–log.
fn chaos_figure(title: &str, panels: Vec<(Mp7Reading, Vec<Series>)>) -> Figure {
    Figure {
        title: title.to_string(),
        panels: panels
            .into_iter()
            .map(|(reading, series)| Panel {
                title: match reading {
                    Mp7Reading::Nonholonomic => "v1 + q2 v5 + q3 v6 + q4 v7 = 0 (nonholonomic reading)".into(),
                    Mp7Reading::Printed => "v1 + q5 v5 + q6 v6 + q7 v7 = 0 (as printed: holonomic)".into(),
                },
                x_label: "t".into(),
                y_label: "(1/h⁴)·mean_j (E_jk − E_j0)²".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series,
            })
            .collect(),
        columns: 2,
        panel_size: (700, 500),
    }
}
