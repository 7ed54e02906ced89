//! The stiffness case: a stiff spring on the skate, diagnosed by the
//! spectral radius of the step map.

use super::{failed_index, integration_error_kind, is_newton_failure};
use crate::experiments::stress::{run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::sci;
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::systems::stress::StiffSkate;
use spark_runtime::{IntegrationError, Method, NonholonomicSystem, State, StepError, Stepper, Tableau, Vector};

/// How one run of the stiff case ended.
enum StiffOutcome {
    /// Every step accepted.
    Completed {
        /// `max |E − E0| / E0`.
        rel: f64,
        /// `max |k|`.
        residual: f64,
        /// Mean Newton iterations per step.
        newton: f64,
    },
    /// A typed error: its kind, the failing step and the message.
    Refused { kind: String, at: String, message: String, typed: bool },
}

/// Steps of the stiff case.
const STIFF_H: f64 = 0.1;
/// End of the stiff case's runs.
const STIFF_T_END: f64 = 20.0;

/// Runs the stiff skate (`k = ω²`) from `q0 = 0`, `v0` with an `S`-stage
/// `method` (energy guard as in `options`).
fn stiff_run<const S: usize, const D: usize>(
    method: Method,
    omega: f64,
    v0: &Vector<3>,
    options: spark_runtime::NewtonOptions,
) -> Result<(StiffOutcome, Option<RunData>), StressError> {
    let sys = StiffSkate { k: omega * omega, ..StiffSkate::default() };
    let mut st = Stepper::<StiffSkate, 3, 1, S, D>::new(sys, Tableau::<S>::new(method)?).with_options(options);
    let q0 = Vector::<3>::zeros();
    let e0 = sys.energy(0.0, &q0, v0);
    let n = (STIFF_T_END / STIFF_H).round() as usize;
    Ok(match run_fixed(&mut st, &q0, v0, STIFF_H, n, 1, 0) {
        Ok(d) => (
            StiffOutcome::Completed {
                rel: d.max_energy_error / e0.abs(),
                residual: d.max_residual,
                newton: d.report.newton_iterations_mean,
            },
            Some(d),
        ),
        Err(e) => {
            let typed = is_newton_failure(&e)
                || matches!(e, IntegrationError::Step { source: StepError::EnergyDrift { .. }, .. });
            (
                StiffOutcome::Refused {
                    kind: integration_error_kind(&e),
                    at: failed_index(&e),
                    message: e.to_string(),
                    typed,
                },
                None,
            )
        }
    })
}

/// Spectral radius of the linear part of one step of the stiff skate
/// (`g = 0`) at `ω·h`, heading rate `θ̇`, in the frame turning with the
/// skate: the map `(s, w, u) ↦ (s₁, w₁, u₁)` of the position along and across
/// the heading and the speed. The exact flow there is `ṡ = u + θ̇w`,
/// `ẇ = −θ̇s`, `u̇ = −ω²s` with eigenvalues `0, ±i√(ω² + θ̇²)`: radius 1.
/// The map does not depend on the heading (the spring is isotropic).
/// `None` when a step fails.
pub fn stiff_step_radius<const S: usize, const D: usize>(
    method: Method,
    omega_h: f64,
    h: f64,
    theta_dot: f64,
) -> Option<f64> {
    let omega = omega_h / h;
    let sys = StiffSkate { k: omega * omega, g: 0.0, ..StiffSkate::default() };
    let options = spark_runtime::NewtonOptions { energy_drift_limit: None, ..crate::experiments::stress::newton() };
    let mut st = Stepper::<StiffSkate, 3, 1, S, D>::new(sys, Tableau::<S>::new(method).ok()?).with_options(options);
    let theta0: f64 = 0.7;
    let (c0, s0) = (theta0.cos(), theta0.sin());
    let mut j = nalgebra::Matrix3::<f64>::zeros();
    for col in 0..3 {
        let mut swu = [0.0; 3];
        swu[col] = 1.0;
        // The map is linear: unit inputs give its columns exactly.
        let q = Vector::<3>::new(c0 * swu[0] - s0 * swu[1], s0 * swu[0] + c0 * swu[1], theta0);
        let v = Vector::<3>::new(swu[2] * c0, swu[2] * s0, theta_dot);
        st.reset_warm_start();
        let r = st.step(&State::new(0.0, q, v), h).ok()?;
        let th1 = r.state.q[2];
        let (c1, s1) = (th1.cos(), th1.sin());
        j[(0, col)] = c1 * r.state.q[0] + s1 * r.state.q[1];
        j[(1, col)] = -s1 * r.state.q[0] + c1 * r.state.q[1];
        j[(2, col)] = c1 * r.state.v[0] + s1 * r.state.v[1];
    }
    Some(j.complex_eigenvalues().iter().map(|c| c.norm()).fold(0.0, f64::max))
}

/// One method of the stiff case: label, runner and step-map radius.
type StiffMethod = (
    &'static str,
    fn(Method, f64, &Vector<3>, spark_runtime::NewtonOptions) -> Result<(StiffOutcome, Option<RunData>), StressError>,
    fn(Method, f64, f64, f64) -> Option<f64>,
    Method,
);

/// The stiff methods compared, with `D = 4S + 3` for the skate.
const STIFF_METHODS: [StiffMethod; 6] = [
    ("Gauss s=1", stiff_run::<1, 7>, stiff_step_radius::<1, 7>, Method::Gauss),
    ("Gauss s=2", stiff_run::<2, 11>, stiff_step_radius::<2, 11>, Method::Gauss),
    ("Gauss s=3", stiff_run::<3, 15>, stiff_step_radius::<3, 15>, Method::Gauss),
    ("Lobatto IIIA-B s=2", stiff_run::<2, 11>, stiff_step_radius::<2, 11>, Method::LobattoIIIAB),
    ("Lobatto IIIA-B s=3", stiff_run::<3, 15>, stiff_step_radius::<3, 15>, Method::LobattoIIIAB),
    ("Lobatto IIIA-B-D s=2", stiff_run::<2, 11>, stiff_step_radius::<2, 11>, Method::LobattoIIIABD),
];

/// What the sweep over methods and `ω·h` found.
struct Sweep {
    /// Per method: `(ω·h, max |E − E0|/E0)` of the completed runs and
    /// `(ω·h, |ρ − 1|)` of the step map.
    energy_series: Vec<Series>,
    radius_series: Vec<Series>,
    /// Every refusal is typed; every completed run stays within the guard.
    typed: bool,
    bounded: bool,
    /// Gauss s=2 completes cleanly up to ω·h = 100, and how it ends at 10³.
    gauss2_low_ok: bool,
    gauss2_top: Option<String>,
    /// The methods that handle and that refuse ω·h = 10³.
    handles: Vec<String>,
    refuses: Vec<String>,
}

/// Two curves `(t, y)`: a run's `E/E0` and a model of it.
type Curves = (Vec<(f64, f64)>, Vec<(f64, f64)>);

/// Gauss s = 2 at ω·h = 10³ looked at closely: the step map's radius in
/// three settings, and the run with the energy guard off.
struct Diagnosis {
    /// ρ at ω·h = 10³ with θ̇ = 1 and θ̇ = 0, and at ω·h = 100.
    rho2: f64,
    rho2_still: f64,
    rho2_100: f64,
    /// Energy growth per step and most Newton iterations of the unguarded run.
    growth: f64,
    newton_max: usize,
    /// `E/E0` of the unguarded run and the model `ρ^(2n)`.
    curves: Option<Curves>,
}

/// The skate with a spring of frequency `ω`, `ω·h` from 0.1 to 10³ (and
/// 10⁴), six methods; the step map's spectral radius explains what each does.
pub fn stiff_spring(_scale: Scale) -> Result<CaseReport, StressError> {
    let h = STIFF_H;
    let omegas = [1.0, 10.0, 100.0, 1000.0, 10000.0];
    let mut c = CaseReport::new(
        "stiff",
        "Stiffness: a stiff spring on the skate",
        format!(
            "Skate with a spring ½k(x² + y²), k = ω², ω = {omegas:?} (ω·h = 0.1 … 10³), h = {h}, t ∈ [0, {STIFF_T_END}], \
             q0 = 0, v0 = (1, 0, 1) (heading rate θ̇ = 1). Six methods with the library defaults, energy guard on \
             (a step may not move E by more than |E0| + |p0·v0| = 3·E0 from the start of the run). Diagnosis: the \
             spectral radius ρ of the linear part of one step in the frame turning with the skate (exact flow: ρ = 1); \
             a control run with θ̇ = 0; Gauss s = 2 at ω·h = 10³ with the guard off."
        ),
    );
    let v0 = Vector::<3>::new(1.0, 0.0, 1.0);
    let defaults = crate::experiments::stress::newton();
    let sweep = stiff_sweep(&mut c, &omegas, &v0, defaults)?;
    c.check(
        "Gauss s=2, ω·h ≤ 100: completes, constraint residual ≤ 1e-12, |E − E0|/E0 ≤ 1",
        sweep.gauss2_low_ok,
        "see metrics",
    );
    c.check(
        "every run either completes within the guard's bound (|E − E0| ≤ 3·E0) or refuses with a typed error",
        sweep.typed && sweep.bounded,
        format!("{} typed refusals", c.errors.len()),
    );
    let d = stiff_diagnosis(&mut c, &v0, defaults)?;
    c.check(
        "Gauss s=2, ω·h = 10³: not returned as success (typed error)",
        sweep.gauss2_top.is_some(),
        match &sweep.gauss2_top {
            Some(s) => format!(
                "refused: {s}. Diagnosis: Newton converges (≤ {} iterations, residual at round-off; the step \
                 equations are linear in (V, Ψ, v1) once θ̇ = V₃ is fixed, so the root is unique: no spurious root, no \
                 wrong basin); the SPARK map itself is unstable: ρ = {:.4} per step (→ e^(θ̇h) = {:.4} as ω·h → ∞), \
                 energy ×{:.3} per step with the guard off (= ρ²). With θ̇ = 0 (fixed constraint direction, \
                 energy a quadratic invariant of a linear problem) ρ = {:.6}; at ω·h = 100, ρ = {:.6}",
                d.newton_max,
                d.rho2,
                (h * 1.0f64).exp(),
                d.growth,
                d.rho2_still,
                d.rho2_100
            ),
            None => "returned success".into(),
        },
    );
    // Control: the same stiffness with a non-turning skate.
    let v_still = Vector::<3>::new(1.0, 0.0, 0.0);
    let control = stiff_run::<2, 11>(Method::Gauss, 1000.0 / h, &v_still, defaults)?.0;
    let (ok, detail) = match control {
        StiffOutcome::Completed { rel, residual, .. } => {
            (rel <= 1e-6, format!("completes: max |E−E0|/E0 {}, max |k| {}", sci(rel), sci(residual)))
        }
        StiffOutcome::Refused { kind, .. } => (false, format!("refused: {kind}")),
    };
    c.check("control: Gauss s=2, ω·h = 10³, θ̇ = 0: energy conserved (|E − E0|/E0 ≤ 1e-6)", ok, detail);
    let list = |v: &[String]| if v.is_empty() { "none".into() } else { v.join(", ") };
    c.metric("methods that handle ω·h = 10³", list(&sweep.handles));
    c.metric("methods that refuse ω·h = 10³", list(&sweep.refuses));
    c.check("every failure is typed", sweep.typed, format!("{} failures", c.errors.len()));
    c.energy = "completed runs per ω·h in the metrics; unstable maps refused by the energy guard".into();
    c.figure = Some(stiff_figure(&c.title, sweep, d.curves));
    Ok(c)
}

/// Runs every method at every `ω` (with its step-map radius) and records a
/// metric per run.
fn stiff_sweep(
    c: &mut CaseReport,
    omegas: &[f64],
    v0: &Vector<3>,
    defaults: spark_runtime::NewtonOptions,
) -> Result<Sweep, StressError> {
    let h = STIFF_H;
    let mut t = Sweep {
        energy_series: Vec::new(),
        radius_series: Vec::new(),
        typed: true,
        bounded: true,
        gauss2_low_ok: true,
        gauss2_top: None,
        handles: Vec::new(),
        refuses: Vec::new(),
    };
    for (label, run, radius, method) in STIFF_METHODS {
        let mut e_pts = Vec::new();
        let mut r_pts = Vec::new();
        for &w in omegas {
            let wh = w * h;
            let rho = radius(method, wh, h, 1.0);
            if let Some(r) = rho {
                r_pts.push((wh, (r - 1.0).abs().max(1e-16)));
            }
            let (outcome, data) = run(method, w, v0, defaults)?;
            if let Some(d) = &data {
                c.absorb(d);
            }
            let rho_s = rho.map_or("step failed".into(), |r| format!("{r:.6}"));
            let desc = match &outcome {
                StiffOutcome::Completed { rel, residual, newton } => {
                    t.bounded &= *rel <= 3.0;
                    e_pts.push((wh, rel.max(1e-17)));
                    if wh == 1000.0 {
                        t.handles.push(format!("{label} (max |E−E0|/E0 {})", sci(*rel)));
                    }
                    if label == "Gauss s=2" && wh <= 100.0 {
                        t.gauss2_low_ok &= *residual <= 1e-12 && *rel <= 1.0;
                    }
                    format!(
                        "completes: max |E−E0|/E0 {}, max |k| {}, mean Newton {newton:.2}; step-map ρ = {rho_s}",
                        sci(*rel),
                        sci(*residual)
                    )
                }
                StiffOutcome::Refused { kind, at, message, typed } => {
                    t.typed &= *typed;
                    c.errors.push(format!("{label}, ω·h = {wh}: {message}"));
                    if wh == 1000.0 {
                        t.refuses.push(format!("{label} ({kind})"));
                    }
                    if label == "Gauss s=2" && wh == 1000.0 {
                        t.gauss2_top = Some(format!("{kind} at step {at}"));
                    }
                    if label == "Gauss s=2" && wh <= 100.0 {
                        t.gauss2_low_ok = false;
                    }
                    format!("refuses: {kind} at step {at}; step-map ρ = {rho_s}")
                }
            };
            c.metric(format!("{label}, ω·h = {wh}"), desc);
        }
        t.energy_series.push(Series::new(label, e_pts));
        t.radius_series.push(Series::new(label, r_pts));
    }
    Ok(t)
}

/// Why Gauss s = 2 refuses ω·h = 10³: the step map's radius there (with and
/// without turning, and at ω·h = 100) and the same run with the energy guard
/// off, whose energy grows like `ρ^(2n)`.
fn stiff_diagnosis(
    c: &mut CaseReport,
    v0: &Vector<3>,
    defaults: spark_runtime::NewtonOptions,
) -> Result<Diagnosis, StressError> {
    let h = STIFF_H;
    let rho2 = stiff_step_radius::<2, 11>(Method::Gauss, 1000.0, h, 1.0).unwrap_or(f64::NAN);
    let rho2_still = stiff_step_radius::<2, 11>(Method::Gauss, 1000.0, h, 0.0).unwrap_or(f64::NAN);
    let rho2_100 = stiff_step_radius::<2, 11>(Method::Gauss, 100.0, h, 1.0).unwrap_or(f64::NAN);
    c.metric(
        "Gauss s=2 step-map ρ at ω·h = 10³, θ̇ = 1 / θ̇ = 0 / ω·h = 100",
        format!("{rho2:.6} / {rho2_still:.6} / {rho2_100:.6}"),
    );
    let off = spark_runtime::NewtonOptions { energy_drift_limit: None, ..defaults };
    let (unguarded, data) = stiff_run::<2, 11>(Method::Gauss, 1000.0 / h, v0, off)?;
    let mut d = Diagnosis { rho2, rho2_still, rho2_100, growth: f64::NAN, newton_max: 0, curves: None };
    if let (StiffOutcome::Completed { rel, residual, .. }, Some(run)) = (&unguarded, &data) {
        // Energy growth per step over the second half (the dominant mode has
        // taken over): E ∝ ρ^{2n}.
        let e0 = 1.0;
        let n = run.energy_error.len();
        let (a, b) = (n / 2, n - 1);
        let (ea, eb) = (run.energy_error[a] + e0, run.energy_error[b] + e0);
        d.growth = (eb / ea).powf(1.0 / (b - a) as f64);
        d.newton_max = run.report.newton_iterations_max;
        c.metric(
            "Gauss s=2, ω·h = 10³, guard off",
            format!(
                "completes without the guard: max |E−E0|/E0 {}, max |k| {}, Newton ≤ {} iterations per step, energy \
                 growth per step {:.4} = ρ^{:.3}",
                sci(*rel),
                sci(*residual),
                d.newton_max,
                d.growth,
                d.growth.ln() / rho2.ln()
            ),
        );
        let pts: Vec<(f64, f64)> =
            run.t.iter().zip(&run.energy_error).map(|(&t, &e)| (t, (e + e0).abs().max(1e-17))).collect();
        let model: Vec<(f64, f64)> = run.t.iter().map(|&t| (t, rho2.powf(2.0 * t / h))).collect();
        d.curves = Some((pts, model));
    }
    Ok(d)
}

/// Energy errors and step-map radii against `ω·h`, and the unguarded run.
fn stiff_figure(title: &str, sweep: Sweep, curves: Option<Curves>) -> Figure {
    let mut panels = vec![
        Panel {
            title: "completed runs: max relative energy error over t ∈ [0, 20] (refused runs absent)".into(),
            x_label: "ω·h".into(),
            y_label: "|E − E0| / E0".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series: sweep.energy_series,
        },
        Panel {
            title: "one-step map in the turning frame: |ρ − 1| (exact flow: 0; floor 1e-16)".into(),
            x_label: "ω·h".into(),
            y_label: "|ρ − 1|".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series: sweep.radius_series,
        },
    ];
    if let Some((pts, model)) = curves {
        let mut model = Series::new("ρ^(2n), ρ from the step map", model);
        model.dashed = true;
        panels.push(Panel {
            title: "Gauss s=2, ω·h = 10³, energy guard off: E/E0".into(),
            x_label: "t".into(),
            y_label: "E / E0".into(),
            x_scale: Axis::Linear,
            y_scale: Axis::Log,
            series: vec![Series::new("E/E0", pts), model],
        });
    }
    Figure { title: title.to_string(), panels, columns: 3, panel_size: (560, 440) }
}
