//! Accuracy cases: high-order methods down to round-off (Gauss and Lobatto
//! IIIA-B with s = 6..8), the vertical rolling disk against its exact
//! solution over long times, and rheonomic affine / velocity-nonlinear
//! constraints against the independent Gragg–Bulirsch–Stoer reference.

use super::{run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::{log_points, sci, thin};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::report::stats::fit_power;
use crate::systems::stress::{rolling_disk_exact, RollingDisk};
use crate::systems::{AppellHamel, NonholonomicParticle, TurntableSkate};
use spark_runtime::reference::{integrate as reference, ReferenceOptions};
use spark_runtime::{IntegrationError, Method, NonholonomicSystem, Stepper, Tableau, Vector};

/// `(h, error or the typed error's text)` for each step size.
type Sweep = Vec<(f64, Result<f64, String>)>;

/// `(h, error, max |k|)` for each step size, or why the sweep stopped.
type RefSweep = Result<Vec<(f64, f64, f64)>, String>;

/// Final time of the high-order sweep.
const HIGH_ORDER_T: f64 = 5.0;

/// Error `max(|q − q_ref|∞, |v − v_ref|∞)` at `t = HIGH_ORDER_T` of the
/// particle, integrated by `st`, for each number of steps, or the typed
/// error's text.
fn particle_sweep<const S: usize, const D: usize>(
    mut st: Stepper<NonholonomicParticle, 3, 1, S, D>,
    (counts, q_ref, v_ref): (&[usize], &Vector<3>, &Vector<3>),
) -> Result<Sweep, StressError> {
    let (q0, v0) = (Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    Ok(counts
        .iter()
        .map(|&n| {
            let h = HIGH_ORDER_T / n as f64;
            let r = run_fixed(&mut st, &q0, &v0, h, n, 0, 0)
                .map_err(|e| e.to_string())
                .map(|d| end_error(&d, q_ref, v_ref));
            (h, r)
        })
        .collect())
}

/// `max(|q − q_ref|∞, |v − v_ref|∞)` at the last recorded sample of `d`
/// (the end of the run).
fn end_error<const N: usize>(d: &RunData, q_ref: &Vector<N>, v_ref: &Vector<N>) -> f64 {
    let (q, v) = (d.q.last().cloned().unwrap_or_default(), d.v.last().cloned().unwrap_or_default());
    (0..N).map(|i| (q[i] - q_ref[i]).abs().max((v[i] - v_ref[i]).abs())).fold(0.0, f64::max)
}

/// Gauss s = 6..8 and Lobatto IIIA-B s = 6..8 on the particle, `h` from
/// `T/2` down to `T/1024`: convergence to round-off, then a plateau.
pub fn high_order(_scale: Scale) -> Result<CaseReport, StressError> {
    let mut c = CaseReport::new(
        "high_order",
        "High order near round-off: s = 6..8",
        format!(
            "Nonholonomic particle from q0 = (1,0,0), v0 = (0,1,0) to t = {HIGH_ORDER_T} with Gauss SPARK and \
             Lobatto IIIA-B SPARK, s = 6, 7, 8 (orders 12–16 and 10–14), n = 8…2048 steps (larger steps make Newton diverge for these s: a typed error, shown by the large-step case); error \
             max(|q − q_ref|∞, |v − v_ref|∞) against the Gragg–Bulirsch–Stoer reference (rtol = atol = 1e-14). \
             The runtime's tableaux go up to s = {}; the stepper type is monomorphized per s.",
            spark_runtime::MAX_STAGES
        ),
    );
    let sys = NonholonomicParticle::default();
    let (q0, v0) = (Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let refsol = match reference::<_, 3, 1>(&sys, 0.0, &q0, &v0, HIGH_ORDER_T, &ReferenceOptions::default()) {
        Ok(r) => r,
        Err(e) => {
            c.check("reference solution", false, e.to_string());
            return Ok(c);
        }
    };
    let (qr, vr) = (refsol.q[0], refsol.v[0]);
    let counts: Vec<usize> = (3..=11).map(|k| 1usize << k).collect();
    let target = (counts.as_slice(), &qr, &vr);
    let (particle, gauss, lobatto) = (NonholonomicParticle::default, Method::Gauss, Method::LobattoIIIAB);
    // One row per method and stage count, the stepper type monomorphized per s.
    macro_rules! sweep {
        ($method:expr, $s:literal) => {
            (
                $method.label($s),
                $method.order($s),
                particle_sweep(<Stepper![NonholonomicParticle, $s]>::new(particle(), Tableau::new($method)?), target)?,
            )
        };
    }
    let sweeps = [
        sweep!(gauss, 6),
        sweep!(gauss, 7),
        sweep!(gauss, 8),
        sweep!(lobatto, 6),
        sweep!(lobatto, 7),
        sweep!(lobatto, 8),
    ];
    let mut series = Vec::new();
    for (label, order, sweep) in &sweeps {
        let mut pts = Vec::new();
        for (h, r) in sweep {
            match r {
                Ok(e) => pts.push((*h, *e)),
                Err(msg) => c.errors.push(format!("{label}, h = {h}: {msg}")),
            }
            c.steps += (HIGH_ORDER_T / h).round() as usize;
        }
        let best = pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        // Steepest observed slope between successive halvings while the
        // error is well above round-off.
        let mut max_order: f64 = 0.0;
        for w in pts.windows(2) {
            if w[1].1 > 1e-12 && w[0].1 > w[1].1 {
                max_order = max_order.max((w[0].1 / w[1].1).log2());
            }
        }
        let finest = pts.last().map_or(f64::NAN, |p| p.1);
        let all_finite = pts.len() == sweep.len() && pts.iter().all(|p| p.1.is_finite());
        c.check(
            format!("{label}: reaches round-off (best error ≤ 1e-12)"),
            best <= 1e-12,
            format!("best error {}", sci(best)),
        );
        c.check(
            format!("{label}: plateau, no blow-up (error at h = T/2048 ≤ max(100·best, 1e-12), every run finite)"),
            all_finite && finite_le(finest, (100.0 * best).max(1e-12)),
            format!("error at the finest h {}; {} of {} runs completed", sci(finest), pts.len(), sweep.len()),
        );
        c.metric(format!("{label}: steepest observed order (nominal {order})"), format!("{max_order:.1}"));
        c.metric(format!("{label}: best / finest-h error"), format!("{} / {}", sci(best), sci(finest)));
        series.push(error_series(label.as_str(), pts.iter().copied()));
    }
    c.energy = "not the subject (accuracy against the reference)".into();
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![Panel {
            title: "error at t = 5 against the reference (zeros at 1e-17)".into(),
            x_label: "h".into(),
            y_label: "max-norm error".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series,
        }],
        columns: 1,
        panel_size: (820, 560),
    });
    Ok(c)
}

/// The series of errors `(h, error)` on log axes (zeros drawn at 1e-17).
fn error_series(label: &str, points: impl Iterator<Item = (f64, f64)>) -> Series {
    let (h, error): (Vec<f64>, Vec<f64>) = points.unzip();
    Series::new(label, log_points(&h, &error, 1e-17))
}

fn finite_le(x: f64, bound: f64) -> bool {
    x.is_finite() && x <= bound
}

/// Errors against the exact rolling-disk solution at the recorded points.
fn disk_errors(d: &RunData, omega: f64, big_omega: f64, r: f64) -> Vec<f64> {
    d.t.iter()
        .zip(&d.q)
        .map(|(&t, q)| {
            let (qe, _) = rolling_disk_exact([0.0; 4], omega, big_omega, r, t);
            (0..4).map(|i| (q[i] - qe[i]).abs()).fold(0.0, f64::max)
        })
        .collect()
}

/// `steps` steps of `h` and `2·steps` of `h/2` over the same interval
/// (recording every `every` and `2·every` steps), each by a fresh stepper.
fn with_half_step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: impl Fn() -> Stepper<Sys, N, M, S, D>,
    q0: &Vector<N>,
    v0: &Vector<N>,
    h: f64,
    steps: usize,
    every: usize,
) -> (Result<RunData, IntegrationError>, Result<RunData, IntegrationError>)
where
    Sys: NonholonomicSystem<N, M>,
{
    (
        run_fixed(&mut stepper(), q0, v0, h, steps, every, 0),
        run_fixed(&mut stepper(), q0, v0, h / 2.0, 2 * steps, 2 * every, 0),
    )
}

/// The vertical rolling disk against its exact solution: Gauss s = 2 and
/// Lobatto IIIA-B s = 3, `h = 0.1` and `h = 0.05`, t ∈ [0, 1000] (full: 10⁶
/// steps of `h = 0.1`, t ∈ [0, 10⁵]).
pub fn rolling_disk(scale: Scale) -> Result<CaseReport, StressError> {
    let steps = match scale {
        Scale::Quick => 10_000,
        Scale::Full => 1_000_000,
    };
    let h = 0.1;
    let (omega, big_omega, r) = (0.7, 1.3, 1.0);
    let every = (steps / 5000).max(1);
    let mut c = CaseReport::new(
        "rolling_disk",
        "Exact solution: the vertical rolling disk",
        format!(
            "Rolling disk (m = 1, I = 0.5, J = 0.25, R = {r}) from q0 = 0 with θ̇ = {omega}, φ̇ = {big_omega}; \
             {steps} steps of h = {h}, and the same interval with h/2. Exact: θ, φ linear in t, \
             x = (RΦ/ω)(sin θ − sin θ0), y = −(RΦ/ω)(cos θ − cos θ0). Error = max-norm of q − q_exact at the \
             recorded points. A phase error of the method makes the error grow linearly in t (exponent 1); \
             faster growth would be an instability, and the error constant must scale like h^order."
        ),
    );
    let q0 = Vector::<4>::zeros();
    let v0 = Vector::<4>::new(r * big_omega, 0.0, omega, big_omega);
    let mut series = Vec::new();
    let disk = RollingDisk::default;
    let gauss = Tableau::new(Method::Gauss)?;
    let lobatto = Tableau::new(Method::LobattoIIIAB)?;
    let runs = [
        (
            "Gauss s=2",
            4.0,
            with_half_step(|| <Stepper![RollingDisk, 2]>::new(disk(), gauss), &q0, &v0, h, steps, every),
        ),
        (
            "Lobatto IIIA-B s=3",
            4.0,
            with_half_step(|| <Stepper![RollingDisk, 3]>::new(disk(), lobatto), &q0, &v0, h, steps, every),
        ),
    ];
    for (label, order, (run, half)) in runs {
        match (run, half) {
            (Ok(d), Ok(d2)) => {
                c.absorb(&d);
                c.absorb(&d2);
                let err = disk_errors(&d, omega, big_omega, r);
                let err2 = disk_errors(&d2, omega, big_omega, r);
                let (e_end, e2_end) = (*err.last().unwrap_or(&f64::NAN), *err2.last().unwrap_or(&f64::NAN));
                let max = err.iter().copied().fold(0.0, f64::max);
                let t_end = *d.t.last().unwrap_or(&0.0);
                match fit_power(&d.t, &err, 10.0, 100) {
                    Some(f) => {
                        c.check(
                            format!("{label}: error grows at most linearly in t (exponent ≤ 1.2)"),
                            f.exponent <= 1.2,
                            format!("fitted exponent {:.3} ± {:.3}", f.exponent, f.exponent_std_error),
                        );
                        c.metric(
                            format!("{label}: error growth exponent"),
                            format!("{:.3} ± {:.3}", f.exponent, f.exponent_std_error),
                        );
                    }
                    None => c.check(format!("{label}: error growth fitted"), false, "no positive errors"),
                }
                let observed = (e_end / e2_end).log2();
                c.check(
                    format!("{label}: error at t = {t_end} scales like h^{order} (observed order within ±0.5)"),
                    (observed - order).abs() <= 0.5,
                    format!("error {} (h = {h}) vs {} (h = {}): order {observed:.2}", sci(e_end), sci(e2_end), h / 2.0),
                );
                c.check(
                    format!("{label}: constraint residual ≤ 1e-12"),
                    d.max_residual.max(d2.max_residual) <= 1e-12,
                    format!("max |k| = {}", sci(d.max_residual.max(d2.max_residual))),
                );
                c.metric(format!("{label}: max error (h = {h})"), sci(max));
                c.metric(format!("{label}: max |E−E0|"), sci(d.max_energy_error));
                series.push(Series::new(format!("{label}, h = {h}"), thin(log_points(&d.t, &err, 1e-17), 3000)));
                series.push(Series::new(
                    format!("{label}, h = {}", h / 2.0),
                    thin(log_points(&d2.t, &err2, 1e-17), 3000),
                ));
            }
            (a, b) => {
                for e in [a.err(), b.err()].into_iter().flatten() {
                    c.errors.push(format!("{label}: {e}"));
                    c.check(format!("{label}: completes"), false, e.to_string());
                }
            }
        }
    }
    c.energy = "kinetic energy conserved to round-off; see max |E−E0|".into();
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![Panel {
            title: "max-norm error of q against the exact solution".into(),
            x_label: "t".into(),
            y_label: "error".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series,
        }],
        columns: 1,
        panel_size: (820, 520),
    });
    Ok(c)
}

/// Errors at `t_end` of one system for `h, h/2, h/4` against the reference.
fn reference_sweep<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    mut st: Stepper<Sys, N, M, S, D>,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t_end: f64,
    hs: &[f64],
) -> Result<RefSweep, StressError>
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let refsol = match reference::<_, N, M>(st.system(), 0.0, q0, v0, t_end, &ReferenceOptions::default()) {
        Ok(r) => r,
        Err(e) => return Ok(Err(format!("reference: {e}"))),
    };
    let mut out = Vec::new();
    for &h in hs {
        let n = (t_end / h).round() as usize;
        match run_fixed(&mut st, q0, v0, h, n, 0, 0) {
            Ok(d) => out.push((h, end_error(&d, &refsol.q[0], &refsol.v[0]), d.max_residual)),
            Err(e) => return Ok(Err(e.to_string())),
        }
    }
    Ok(Ok(out))
}

/// Time-dependent affine constraints (turntable skate) and a constraint
/// nonlinear in `v` (Appell–Hamel) against the reference, with the observed
/// order between successive halvings of `h`.
pub fn against_reference(_scale: Scale) -> Result<CaseReport, StressError> {
    let t_end = 10.0;
    let hs = [0.2, 0.1, 0.05, 0.025];
    let mut c = CaseReport::new(
        "reference",
        "Rheonomic affine and velocity-nonlinear constraints vs the reference",
        format!(
            "Turntable skate (k = K(q)v + b(t,q), ω(t) = 1 + 0.5 sin 2t) from q0 = (1,0,0), v0 = (0.5, 1, 0.3), and \
             the Appell–Hamel particle (k = v₃² − a²(v₁² + v₂²)) from q0 = 0, v0 = (1, 0, −0.5) (falling; a rising start stops at t ≈ 2.5 where K(v) = 0 and the saddle matrix is singular); Gauss s = 3 \
             (order 6) and Lobatto IIIA-B s = 3 (order 4), h = {hs:?}, error at t = {t_end} against the \
             Gragg–Bulirsch–Stoer solution of the ψ-eliminated ODE."
        ),
    );
    let (tq, tv) = (Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.5, 1.0, 0.3));
    // Falling (v₃ < 0): rising, the particle would stop, K(v) → 0 and the
    // saddle matrix becomes singular (a typed SingularMatrix error).
    let (aq, av) = (Vector::<3>::zeros(), Vector::<3>::new(1.0, 0.0, -0.5));
    let runs = [
        (
            "turntable, Gauss s=3",
            6.0,
            reference_sweep(
                <Stepper![TurntableSkate, 3]>::new(TurntableSkate::default(), Tableau::new(Method::Gauss)?),
                &tq,
                &tv,
                t_end,
                &hs,
            )?,
        ),
        (
            "turntable, Lobatto IIIA-B s=3",
            4.0,
            reference_sweep(
                <Stepper![TurntableSkate, 3]>::new(TurntableSkate::default(), Tableau::new(Method::LobattoIIIAB)?),
                &tq,
                &tv,
                t_end,
                &hs,
            )?,
        ),
        (
            "Appell–Hamel, Gauss s=3",
            6.0,
            reference_sweep(
                <Stepper![AppellHamel, 3]>::new(AppellHamel::default(), Tableau::new(Method::Gauss)?),
                &aq,
                &av,
                t_end,
                &hs,
            )?,
        ),
        (
            "Appell–Hamel, Lobatto IIIA-B s=3",
            4.0,
            reference_sweep(
                <Stepper![AppellHamel, 3]>::new(AppellHamel::default(), Tableau::new(Method::LobattoIIIAB)?),
                &aq,
                &av,
                t_end,
                &hs,
            )?,
        ),
    ];
    let mut series = Vec::new();
    for (label, order, r) in runs {
        match r {
            Err(e) => {
                c.errors.push(format!("{label}: {e}"));
                c.check(format!("{label}: completes"), false, e);
            }
            Ok(pts) => {
                for p in &pts {
                    c.steps += (t_end / p.0).round() as usize;
                    c.worst_residual = c.worst_residual.max(p.2);
                }
                // Order from the finest pair whose errors stay well above the
                // reference's own accuracy (~1e-12).
                let orders: Vec<f64> = pts
                    .windows(2)
                    .filter(|w| w[1].1 > 1e-9)
                    .map(|w| (w[0].1 / w[1].1).ln() / (w[0].0 / w[1].0).ln())
                    .collect();
                let observed = orders.last().copied().unwrap_or(f64::NAN);
                let worst = pts.iter().map(|p| p.1).fold(0.0, f64::max);
                if worst <= 1e-12 {
                    // Falling Appell–Hamel motion is polynomial in t (constant
                    // accelerations), which every method here integrates exactly:
                    // there is no order to measure, only round-off.
                    c.check(
                        format!("{label}: exact up to round-off (solution polynomial in t)"),
                        true,
                        format!("largest error over h = {hs:?}: {}", sci(worst)),
                    );
                } else {
                    c.check(
                        format!("{label}: observed order {order} ± 0.5"),
                        (observed - order).abs() <= 0.5,
                        format!(
                            "orders between halvings {:?}",
                            orders.iter().map(|o| format!("{o:.2}")).collect::<Vec<_>>()
                        ),
                    );
                }
                let maxk = pts.iter().map(|p| p.2).fold(0.0, f64::max);
                c.check(
                    format!("{label}: constraint residual ≤ 1e-11"),
                    maxk <= 1e-11,
                    format!("max |k| = {}", sci(maxk)),
                );
                c.metric(
                    format!("{label}: errors at h = {hs:?}"),
                    pts.iter().map(|p| sci(p.1)).collect::<Vec<_>>().join(", "),
                );
                c.metric(format!("{label}: max |k|"), sci(pts.iter().map(|p| p.2).fold(0.0, f64::max)));
                series.push(error_series(label, pts.iter().map(|p| (p.0, p.1))));
            }
        }
    }
    c.energy = "turntable: not conserved (the table does work); Appell–Hamel: conserved".into();
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![Panel {
            title: format!("error at t = {t_end} against the reference"),
            x_label: "h".into(),
            y_label: "max-norm error".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series,
        }],
        columns: 1,
        panel_size: (820, 520),
    });
    Ok(c)
}
