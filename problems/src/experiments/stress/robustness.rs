//! Robustness cases: steps too large for Newton (with and without the
//! rejection policy), a stiff spring on the skate, nearly parallel
//! constraint rows, a non-reversible oscillator, and bad input.

use super::{run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::{log_points, sci, thin};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::report::stats::drift_test;
use crate::systems::stress::{
    contact_oscillator_initial, near_parallel_exact, ContactOscillator, NearParallel, NonReversibleContactOscillator,
    NonReversibleOscillator, StiffSkate,
};
use crate::systems::{McLachlanPerlmutter7, Skate};
use spark_runtime::{
    integrate_with_rejection, IntegrationError, Method, NonholonomicSystem, RejectionError, RejectionPolicy,
    RejectionReport, RejectionRunError, RunOptions, Schedule, State, StepError, Stepper, Tableau, Vector,
};

/// A short name of a step failure's kind.
pub fn step_error_kind(e: &StepError) -> &'static str {
    match e {
        StepError::InvalidStep { .. } => "InvalidStep",
        StepError::Diverged { .. } => "Diverged",
        StepError::MaxIterations { .. } => "MaxIterations",
        StepError::SingularMatrix { .. } => "SingularMatrix",
        StepError::NonFinite { .. } => "NonFinite",
        StepError::EnergyDrift { .. } => "EnergyDrift",
        StepError::InconsistentInitialState { .. } => "InconsistentInitialState",
        StepError::InvalidOption(_) => "InvalidOption",
        StepError::InconsistentStart { .. } => "InconsistentStart",
        StepError::DependentConstraints { .. } => "DependentConstraints",
    }
}

/// The kind of a driver failure (`Step/<kind>`, `Initial/<kind>`, `InvalidSchedule`, `InvalidOption`).
pub fn integration_error_kind(e: &IntegrationError) -> String {
    match e {
        IntegrationError::InvalidSchedule(_) => "InvalidSchedule".into(),
        IntegrationError::InvalidOption(_) => "InvalidOption".into(),
        IntegrationError::Initial(s) => format!("Initial/{}", step_error_kind(s)),
        IntegrationError::Step { source, .. } => format!("Step/{}", step_error_kind(source)),
    }
}

/// The kind of a protected-run failure.
pub fn rejection_error_kind(e: &RejectionRunError) -> String {
    match &e.source {
        RejectionError::InvalidPolicy(_) => "InvalidPolicy".into(),
        RejectionError::InvalidInterval { .. } => "InvalidInterval".into(),
        RejectionError::Input(s) => format!("Input/{}", step_error_kind(s)),
        RejectionError::Floor { last, .. } => format!("Floor/{}", step_error_kind(last)),
    }
}

/// Newton failures a smaller step may cure.
fn is_newton_failure(e: &IntegrationError) -> bool {
    matches!(
        e,
        IntegrationError::Step {
            source: StepError::Diverged { .. }
                | StepError::MaxIterations { .. }
                | StepError::SingularMatrix { .. }
                | StepError::NonFinite { .. },
            ..
        }
    )
}

/// One plain and one protected run of the same problem.
struct Pair {
    plain: Result<RunData, IntegrationError>,
    protected: Result<(State<7>, RejectionReport), RejectionRunError>,
}

/// McLachlan–Perlmutter particles (quartic coupling) with Gauss s = 2 and
/// `h` doubled from 0.1 to 12.8 over t ∈ [0, 51.2].
pub fn large_steps(_scale: Scale) -> Result<CaseReport, StressError> {
    let t_end = 51.2;
    let hs: Vec<f64> = (0..8).map(|k| 0.1 * f64::from(1u32 << k)).collect();
    let policy = RejectionPolicy::default();
    let mut c = CaseReport::new(
        "large_steps",
        "Large steps: where Newton stops converging",
        format!(
            "McLachlan–Perlmutter particles (j = 0 of the paper's ensemble: q0 = (1, 0.6, 0.4, 0.2, 1, 1, 1), \
             v0 = 0, E = 3.06), Gauss SPARK s = 2, full Newton, t ∈ [0, {t_end}], h = {hs:?}. Each h is run plainly \
             (the driver, no retries) and under the rejection policy (halve on failure down to |h|·2^-{} or {:e}, \
             double back after {} successes, then restore h).",
            policy.max_halvings, policy.min_step, policy.regrow_after
        ),
    );
    let sys = McLachlanPerlmutter7::default();
    let (q0v, v0v) = crate::systems::mp7_initial_values(0, 9);
    let (q0, v0) = (Vector::<7>::from_column_slice(&q0v), Vector::<7>::from_column_slice(&v0v));
    let e0 = sys.energy(0.0, &q0, &v0);
    let mut pairs = Vec::new();
    for &h in &hs {
        let mut st = crate::stress_stepper!(McLachlanPerlmutter7, 2, Method::Gauss, sys);
        let n = (t_end / h).round() as usize;
        let plain = run_fixed(&mut st, &q0, &v0, h, n, 1, 0);
        let protected = integrate_with_rejection(&mut st, 0.0, &q0, &v0, t_end, h, &policy, &mut |_| {});
        pairs.push(Pair { plain, protected });
    }
    let mut plain_fail = Vec::new();
    let mut rescued = Vec::new();
    let mut all_typed = true;
    let (mut ok_pts, mut prot_pts, mut rej_pts) = (Vec::new(), Vec::new(), Vec::new());
    for (&h, p) in hs.iter().zip(&pairs) {
        let plain_desc = match &p.plain {
            Ok(d) => {
                c.absorb(d);
                let finite = d.max_energy_error.is_finite() && d.max_residual <= 1e-10;
                if !finite {
                    all_typed = false;
                }
                ok_pts.push((h, d.max_energy_error.max(1e-17)));
                format!("completes: max |E−E0| {}, max |k| {}", sci(d.max_energy_error), sci(d.max_residual))
            }
            Err(e) => {
                plain_fail.push(h);
                if !is_newton_failure(e) {
                    all_typed = false;
                }
                c.errors.push(format!("plain, h = {h}: {e}"));
                format!("fails: {} at step {}", integration_error_kind(e), failed_index(e))
            }
        };
        let prot_desc = match &p.protected {
            Ok((s, r)) => {
                c.rejections += r.rejections;
                let de = (sys.energy(s.t, &s.q, &s.v) - e0).abs();
                let k = sys.constraint(s.t, &s.q, &s.v).amax();
                c.worst_residual = c.worst_residual.max(k);
                if p.plain.is_err() {
                    rescued.push(h);
                }
                prot_pts.push((h, de.max(1e-17)));
                rej_pts.push((h, r.rejections as f64));
                format!(
                    "completes: {} rejections in {} nominal steps, smallest sub-step {}, final |E−E0| {}, |k| {}",
                    r.rejections,
                    r.steps,
                    sci(r.smallest_step),
                    sci(de),
                    sci(k)
                )
            }
            Err(e) => {
                if !matches!(e.source, RejectionError::Floor { .. }) {
                    all_typed = false;
                }
                c.errors.push(format!("protected, h = {h}: {e}"));
                format!(
                    "fails: {} in nominal step {} ({} rejections before)",
                    rejection_error_kind(e),
                    e.index,
                    e.partial.rejections
                )
            }
        };
        c.metric(format!("h = {h}: plain"), plain_desc);
        c.metric(format!("h = {h}: with rejection"), prot_desc);
    }
    c.check(
        "every plain failure is a typed Newton failure (Diverged/MaxIterations/SingularMatrix/NonFinite) with its reason",
        all_typed,
        format!("plain runs failed at h = {plain_fail:?}; messages listed below"),
    );
    c.check(
        "Newton stops converging somewhere in the sweep (the sweep reaches the limit)",
        !plain_fail.is_empty(),
        match plain_fail.first() {
            Some(h) => format!("first plain failure at h = {h}"),
            None => "no plain run failed".into(),
        },
    );
    c.check(
        "the rejection policy carries at least one failing run through",
        !rescued.is_empty(),
        format!("rescued at h = {rescued:?}"),
    );
    // A policy allowed a single halving cannot rescue the largest step: the
    // protected run must then stop with a typed Floor error naming the floor
    // and the last Newton failure.
    let tight = RejectionPolicy { max_halvings: 1, ..policy };
    let h_max = *hs.last().unwrap_or(&12.8);
    let mut st = crate::stress_stepper!(McLachlanPerlmutter7, 2, Method::Gauss, sys);
    match integrate_with_rejection(&mut st, 0.0, &q0, &v0, t_end, h_max, &tight, &mut |_| {}) {
        Ok(_) => c.check(
            format!("h = {h_max} with a policy of one halving stops with a typed Floor error"),
            false,
            "the run completed",
        ),
        Err(e) => {
            c.errors.push(format!("protected, h = {h_max}, max_halvings = 1: {e}"));
            c.check(
                format!("h = {h_max} with a policy of one halving stops with a typed Floor error"),
                matches!(e.source, RejectionError::Floor { .. }),
                format!("{}: {e}", rejection_error_kind(&e)),
            );
        }
    }
    c.energy = match plain_fail.first() {
        Some(h) => format!("plain runs fail from h = {h}; per-h energy errors in the metrics"),
        None => "no plain run failed; per-h energy errors in the metrics".into(),
    };
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![
            Panel {
                title: "energy error (plain: max over run; protected: at t_end)".into(),
                x_label: "h".into(),
                y_label: "|E − E0|".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new("plain (completed runs)", ok_pts), Series::new("with rejection", prot_pts)],
            },
            Panel {
                title: "rejections of the protected run (0 drawn at 0.5)".into(),
                x_label: "h".into(),
                y_label: "rejections".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new(
                    "rejections",
                    rej_pts.into_iter().map(|(h, r)| (h, if r > 0.0 { r } else { 0.5 })).collect(),
                )],
            },
        ],
        columns: 2,
        panel_size: (600, 420),
    });
    Ok(c)
}

fn failed_index(e: &IntegrationError) -> String {
    match e {
        IntegrationError::Step { index, t, .. } => format!("{index} (t = {t})"),
        _ => "—".into(),
    }
}

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
    let options = spark_runtime::NewtonOptions { energy_drift_limit: None, ..super::newton() };
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
    let defaults = super::newton();
    let mut energy_series = Vec::new();
    let mut radius_series = Vec::new();
    let mut typed = true;
    let mut bounded = true;
    let mut gauss2_low_ok = true;
    let mut gauss2_top: Option<String> = None;
    let mut handles = Vec::new();
    let mut refuses = Vec::new();
    for (label, run, radius, method) in STIFF_METHODS {
        let mut e_pts = Vec::new();
        let mut r_pts = Vec::new();
        for &w in &omegas {
            let wh = w * h;
            let rho = radius(method, wh, h, 1.0);
            if let Some(r) = rho {
                r_pts.push((wh, (r - 1.0).abs().max(1e-16)));
            }
            let (outcome, data) = run(method, w, &v0, defaults)?;
            if let Some(d) = &data {
                c.absorb(d);
            }
            let rho_s = rho.map_or("step failed".into(), |r| format!("{r:.6}"));
            let desc = match &outcome {
                StiffOutcome::Completed { rel, residual, newton } => {
                    bounded &= *rel <= 3.0;
                    e_pts.push((wh, rel.max(1e-17)));
                    if wh == 1000.0 {
                        handles.push(format!("{label} (max |E−E0|/E0 {})", sci(*rel)));
                    }
                    if label == "Gauss s=2" && wh <= 100.0 {
                        gauss2_low_ok &= *residual <= 1e-12 && *rel <= 1.0;
                    }
                    format!(
                        "completes: max |E−E0|/E0 {}, max |k| {}, mean Newton {newton:.2}; step-map ρ = {rho_s}",
                        sci(*rel),
                        sci(*residual)
                    )
                }
                StiffOutcome::Refused { kind, at, message, typed: t } => {
                    typed &= *t;
                    c.errors.push(format!("{label}, ω·h = {wh}: {message}"));
                    if wh == 1000.0 {
                        refuses.push(format!("{label} ({kind})"));
                    }
                    if label == "Gauss s=2" && wh == 1000.0 {
                        gauss2_top = Some(format!("{kind} at step {at}"));
                    }
                    if label == "Gauss s=2" && wh <= 100.0 {
                        gauss2_low_ok = false;
                    }
                    format!("refuses: {kind} at step {at}; step-map ρ = {rho_s}")
                }
            };
            c.metric(format!("{label}, ω·h = {wh}"), desc);
        }
        energy_series.push(Series::new(label, e_pts));
        radius_series.push(Series::new(label, r_pts));
    }
    c.check(
        "Gauss s=2, ω·h ≤ 100: completes, constraint residual ≤ 1e-12, |E − E0|/E0 ≤ 1",
        gauss2_low_ok,
        "see metrics",
    );
    c.check(
        "every run either completes within the guard's bound (|E − E0| ≤ 3·E0) or refuses with a typed error",
        typed && bounded,
        format!("{} typed refusals", c.errors.len()),
    );
    // The diagnosis of the failure the last session reported.
    let rho2 = stiff_step_radius::<2, 11>(Method::Gauss, 1000.0, h, 1.0).unwrap_or(f64::NAN);
    let rho2_still = stiff_step_radius::<2, 11>(Method::Gauss, 1000.0, h, 0.0).unwrap_or(f64::NAN);
    let rho2_100 = stiff_step_radius::<2, 11>(Method::Gauss, 100.0, h, 1.0).unwrap_or(f64::NAN);
    c.metric(
        "Gauss s=2 step-map ρ at ω·h = 10³, θ̇ = 1 / θ̇ = 0 / ω·h = 100",
        format!("{rho2:.6} / {rho2_still:.6} / {rho2_100:.6}"),
    );
    let off = spark_runtime::NewtonOptions { energy_drift_limit: None, ..defaults };
    let (unguarded, data) = stiff_run::<2, 11>(Method::Gauss, 1000.0 / h, &v0, off)?;
    let mut growth = f64::NAN;
    let mut newton_max = 0;
    let mut extra = None;
    if let (StiffOutcome::Completed { rel, residual, .. }, Some(d)) = (&unguarded, &data) {
        // Energy growth per step over the second half (the dominant mode has
        // taken over): E ∝ ρ^{2n}.
        let e0 = 1.0;
        let n = d.energy_error.len();
        let (a, b) = (n / 2, n - 1);
        let (ea, eb) = (d.energy_error[a] + e0, d.energy_error[b] + e0);
        growth = (eb / ea).powf(1.0 / (b - a) as f64);
        newton_max = d.report.newton_iterations_max;
        c.metric(
            "Gauss s=2, ω·h = 10³, guard off",
            format!(
                "completes without the guard: max |E−E0|/E0 {}, max |k| {}, Newton ≤ {} iterations per step, energy \
                 growth per step {growth:.4} = ρ^{:.3}",
                sci(*rel),
                sci(*residual),
                newton_max,
                growth.ln() / rho2.ln()
            ),
        );
        let pts: Vec<(f64, f64)> =
            d.t.iter().zip(&d.energy_error).map(|(&t, &e)| (t, (e + e0).abs().max(1e-17))).collect();
        let model: Vec<(f64, f64)> = d.t.iter().map(|&t| (t, rho2.powf(2.0 * t / h))).collect();
        extra = Some((pts, model));
    }
    c.check(
        "Gauss s=2, ω·h = 10³: not returned as success (typed error)",
        gauss2_top.is_some(),
        match &gauss2_top {
            Some(s) => format!(
                "refused: {s}. Diagnosis: Newton converges (≤ {newton_max} iterations, residual at round-off; the step \
                 equations are linear in (V, Ψ, v1) once θ̇ = V₃ is fixed, so the root is unique: no spurious root, no \
                 wrong basin); the SPARK map itself is unstable: ρ = {rho2:.4} per step (→ e^(θ̇h) = {:.4} as ω·h → ∞), \
                 energy ×{growth:.3} per step with the guard off (= ρ²). With θ̇ = 0 (fixed constraint direction, \
                 energy a quadratic invariant of a linear problem) ρ = {rho2_still:.6}; at ω·h = 100, ρ = {rho2_100:.6}",
                (h * 1.0f64).exp()
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
    c.metric("methods that handle ω·h = 10³", if handles.is_empty() { "none".into() } else { handles.join(", ") });
    c.metric("methods that refuse ω·h = 10³", if refuses.is_empty() { "none".into() } else { refuses.join(", ") });
    c.check("every failure is typed", typed, format!("{} failures", c.errors.len()));
    c.energy = "completed runs per ω·h in the metrics; unstable maps refused by the energy guard".into();
    let mut panels = vec![
        Panel {
            title: "completed runs: max relative energy error over t ∈ [0, 20] (refused runs absent)".into(),
            x_label: "ω·h".into(),
            y_label: "|E − E0| / E0".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series: energy_series,
        },
        Panel {
            title: "one-step map in the turning frame: |ρ − 1| (exact flow: 0; floor 1e-16)".into(),
            x_label: "ω·h".into(),
            y_label: "|ρ − 1|".into(),
            x_scale: Axis::Log,
            y_scale: Axis::Log,
            series: radius_series,
        },
    ];
    if let Some((pts, model)) = extra {
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
    c.figure = Some(Figure { title: c.title.clone(), panels, columns: 3, panel_size: (560, 440) });
    Ok(c)
}

/// 2-norm condition number of `[[∇²_vv L, Kᵀ],[K, 0]]` at `(t, q, v)` (from
/// the singular values; infinite when the smallest is zero).
pub fn saddle_condition<Sys, const N: usize, const M: usize>(sys: &Sys, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let w = sys.mass_matrix(t, q, v);
    let k = sys.constraint_v(t, q, v);
    let a = nalgebra::DMatrix::<f64>::from_fn(N + M, N + M, |i, j| match (i < N, j < N) {
        (true, true) => w[(i, j)],
        (true, false) => k[(j - N, i)],
        (false, true) => k[(i - N, j)],
        (false, false) => 0.0,
    });
    let sv = a.singular_values();
    let (max, min) = sv.iter().fold((0.0f64, f64::INFINITY), |(a, b), &s| (a.max(s), b.min(s)));
    if min > 0.0 {
        max / min
    } else {
        f64::INFINITY
    }
}

/// Condition numbers above this are reported as a warning.
pub const CONDITION_WARNING: f64 = 1e10;

/// Two nearly parallel constraint rows (`ε → 0`), Gauss s = 2.
pub fn near_singular(_scale: Scale) -> Result<CaseReport, StressError> {
    let epss = [1.0, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-14, 0.0];
    let (h, t_end): (f64, f64) = (0.05, 10.0);
    let mut c = CaseReport::new(
        "near_singular",
        "Near-singular constraints: two nearly parallel rows",
        format!(
            "Nonholonomic particle with k = (v₃ − q₂v₁, v₃ − q₂v₁ + ε v₂), ε = {epss:?}; q0 = (1, 0.5, 0), \
             v0 = (0.3, 0, 0.15); Gauss s = 2, h = {h}, t ∈ [0, {t_end}]. The motion is known exactly for ε ≠ 0 \
             (q₂ stays 0.5); the multiplier of the second row grows like 1/ε. The condition number of \
             [[∇²_vv L, Kᵀ],[K, 0]] (2-norm, from its singular values) is estimated at the start of each run \
             and reported as a warning above {CONDITION_WARNING:e}."
        ),
    );
    let q0 = Vector::<3>::new(1.0, 0.5, 0.0);
    let v0 = Vector::<3>::new(0.3, 0.0, 0.15);
    let n = (t_end / h).round() as usize;
    let (mut cond_pts, mut err_pts) = (Vec::new(), Vec::new());
    let mut conds = Vec::new();
    let mut zero_outcome = String::new();
    let mut zero_typed = false;
    for &eps in &epss {
        let sys = NearParallel { eps };
        let cond = saddle_condition(&sys, 0.0, &q0, &v0);
        conds.push(cond);
        if cond > CONDITION_WARNING {
            c.warnings.push(format!(
                "ε = {eps:e}: [[∇²_vv L, Kᵀ],[K, 0]] nearly singular, condition ≈ {} (multipliers and the Newton \
                 matrix lose about log10(cond) digits)",
                sci(cond)
            ));
        }
        if eps > 0.0 {
            cond_pts.push((eps, cond.min(1e300)));
        }
        let mut st = crate::stress_stepper!(NearParallel, 2, Method::Gauss, sys);
        let desc = match run_fixed(&mut st, &q0, &v0, h, n, 1, 0) {
            Ok(d) => {
                c.absorb(&d);
                let t = *d.t.last().unwrap_or(&0.0);
                let (qe, ve) = near_parallel_exact([1.0, 0.5, 0.0], [0.3, 0.0, 0.15], t);
                let q = d.q.last().cloned().unwrap_or_default();
                let v = d.v.last().cloned().unwrap_or_default();
                let err = (0..3).map(|i| (q[i] - qe[i]).abs().max((v[i] - ve[i]).abs())).fold(0.0, f64::max);
                if eps > 0.0 {
                    err_pts.push((eps, err.max(1e-17)));
                } else {
                    zero_outcome = format!("ε = 0 completed (error {}), no singularity detected", sci(err));
                }
                format!(
                    "cond {}; completes: error vs exact {}, max |k| {}, max |E−E0| {}, mean Newton {:.2}",
                    sci(cond),
                    sci(err),
                    sci(d.max_residual),
                    sci(d.max_energy_error),
                    d.report.newton_iterations_mean
                )
            }
            Err(e) => {
                c.errors.push(format!("ε = {eps:e}: {e}"));
                if eps == 0.0 {
                    zero_typed = matches!(
                        e,
                        IntegrationError::Step {
                            source: StepError::SingularMatrix { .. } | StepError::DependentConstraints { .. },
                            ..
                        } | IntegrationError::Initial(StepError::SingularMatrix { .. })
                    );
                    zero_outcome = format!("ε = 0: {} ({e})", integration_error_kind(&e));
                }
                format!("cond {}; fails: {}", sci(cond), integration_error_kind(&e))
            }
        };
        c.metric(format!("ε = {eps:e}"), desc);
    }
    // Condition ~ ε⁻² when the rows are close: check the ratio over two decades of ε.
    let ratio = conds[3] / conds[2];
    c.check(
        "condition number detected and growing like ε⁻² (cond(1e-6)/cond(1e-4) within 10^(4±0.5))",
        (ratio.log10() - 4.0).abs() <= 0.5,
        format!("cond(1e-4) = {}, cond(1e-6) = {}, ratio {}", sci(conds[2]), sci(conds[3]), sci(ratio)),
    );
    c.check("ill-conditioning reported as a warning", !c.warnings.is_empty(), format!("{} warnings", c.warnings.len()));
    c.check("ε = 0 (parallel rows) is a typed SingularMatrix or DependentConstraints error", zero_typed, zero_outcome);
    c.energy = "see per-ε max |E−E0|".into();
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![
            Panel {
                title: "condition of [[W, Kᵀ],[K, 0]]".into(),
                x_label: "ε".into(),
                y_label: "cond₂".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new("cond", cond_pts)],
            },
            Panel {
                title: "error at t = 10 against the exact solution".into(),
                x_label: "ε".into(),
                y_label: "max-norm error".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new("Gauss s=2, h=0.05", err_pts)],
            },
        ],
        columns: 2,
        panel_size: (600, 420),
    });
    Ok(c)
}

/// One energy record of the non-reversible case.
struct EnergyRun {
    label: String,
    data: Result<RunData, String>,
}

/// Runs `steps` steps of an `s = 2` method (D = 11 for `n = 3`, `m = 1`).
fn nr_run<Sys>(
    sys: Sys,
    method: Method,
    q0: &Vector<3>,
    v0: &Vector<3>,
    h: f64,
    steps: usize,
) -> Result<Result<RunData, String>, StressError>
where
    Sys: NonholonomicSystem<3, 1> + Clone,
{
    // The case shows how far the energy of a non-reversible system drifts,
    // so the energy guard (which would refuse a drift beyond 100 %) is off.
    let options = spark_runtime::NewtonOptions { energy_drift_limit: None, ..super::newton() };
    let mut st = Stepper::<Sys, 3, 1, 2, 11>::new(sys, Tableau::<2>::new(method)?).with_options(options);
    let every = (steps / 10_000).max(1);
    Ok(run_fixed(&mut st, q0, v0, h, steps, every, 0).map_err(|e| e.to_string()))
}

/// `max |E − E0|` over the first and the last tenth of the samples.
fn first_last_tenth(d: &RunData) -> (f64, f64) {
    let n = d.energy_error.len();
    let k = (n / 10).max(1);
    let m = |s: &[f64]| s.iter().fold(0.0f64, |a, e| a.max(e.abs()));
    (m(&d.energy_error[..k]), m(&d.energy_error[n - k..]))
}

/// The Modin–Verdier non-reversible contact oscillator beside its
/// reversible twin (same exact motion), four `s = 2` methods, and the
/// gyroscopic reconstruction of the last session.
pub fn non_reversible(scale: Scale) -> Result<CaseReport, StressError> {
    let h = 2.0 * (std::f64::consts::PI / 40.0).sin();
    let steps = match scale {
        Scale::Quick => 20_000,
        Scale::Full => 1_000_000,
    };
    let z0 = 0.1 * std::f64::consts::SQRT_2;
    let eps = 0.0;
    let (q, v) = contact_oscillator_initial(z0, eps);
    let (q0, v0) = (Vector::<3>::from(q), Vector::<3>::from(v));
    let mut c = CaseReport::new(
        "non_reversible",
        "Non-reversible: the Modin–Verdier contact oscillator",
        format!(
            "Modin & Verdier's non-reversible contact oscillator as defined in Verdier's odelab \
             (`NonReversibleContactOscillator`): L = ½|v|² + sin(z) ż − ½(x² + y² + z² + ε x²z²), constraint \
             ẋ + y ż = 0 (H = ½(|q|² + εx²z² + |p + ∇S|²), S = cos z), beside its reversible twin, the \
             McLachlan–Perlmutter contact oscillator (same L without sin(z) ż). The added term is −dS/dt, so both \
             have the same exact motion from the same state; only the momentum p = v − ∇S the integrators \
             discretize differs. ε = {eps}, odelab's initial state (`initial_sin`, z0 = 0.1·√2, H0 = 1.5, Hy = 0.5): \
             q0 = ({:.6}, 0, {:.6}), v0 = (0, 1, {:.6}); h = 2 sin(π/40) = {h:.6} (odelab's time_step(40)), {steps} \
             steps (t = {:.0}). Methods s = 2: Gauss, Lobatto IIIA-B, Lobatto IIIA-B-D and the McLachlan–Perlmutter \
             Lobatto IIIB-A LDA. Also the gyroscopic reconstruction used before the system was found \
             (`NonReversibleOscillator`, ε = 0.5). No pass/fail on the energy: the point is to show what happens.",
            q0[0],
            q0[2],
            v0[2],
            h * steps as f64
        ),
    );
    // The two declarations must describe the same motion (the gauge term is a
    // total derivative): compare them at a small step over t ∈ [0, 10].
    let fine = 0.01;
    let a = nr_run(ContactOscillator { eps }, Method::Gauss, &q0, &v0, fine, 1000)?;
    let b = nr_run(NonReversibleContactOscillator { eps }, Method::Gauss, &q0, &v0, fine, 1000)?;
    let same = match (&a, &b) {
        (Ok(a), Ok(b)) => {
            let (qa, qb) = (a.q.last().cloned().unwrap_or_default(), b.q.last().cloned().unwrap_or_default());
            let diff = qa.iter().zip(&qb).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
            Some(diff)
        }
        _ => None,
    };
    c.check(
        "reversible and non-reversible declarations have the same exact motion (Gauss s=2, h = 0.01, t = 10: |Δq| ≤ 1e-9)",
        same.is_some_and(|d| d <= 1e-9),
        same.map_or("a run failed".into(), |d| format!("|Δq(10)| = {}", sci(d))),
    );
    let methods = [
        (Method::Gauss, "Gauss s=2"),
        (Method::LobattoIIIAB, "Lobatto IIIA-B s=2"),
        (Method::LobattoIIIABD, "Lobatto IIIA-B-D s=2"),
        (Method::LobattoIIIBALda, "Lobatto IIIB-A LDA (MP)"),
    ];
    let mut panels_series: [Vec<Series>; 3] = [Vec::new(), Vec::new(), Vec::new()];
    let mut runs: Vec<(usize, EnergyRun)> = Vec::new();
    for (method, name) in methods {
        let r = nr_run(ContactOscillator { eps }, method, &q0, &v0, h, steps)?;
        runs.push((0, EnergyRun { label: format!("reversible, {name}"), data: r }));
        let r = nr_run(NonReversibleContactOscillator { eps }, method, &q0, &v0, h, steps)?;
        runs.push((1, EnergyRun { label: format!("non-reversible, {name}"), data: r }));
    }
    let (rq, rv) = (Vector::<3>::new(0.5, 0.6, 0.4), Vector::<3>::new(-0.2, 0.3, 0.5));
    for (method, name) in [(Method::Gauss, "Gauss s=2"), (Method::LobattoIIIAB, "Lobatto IIIA-B s=2")] {
        let r = nr_run(NonReversibleOscillator { eps: 0.5 }, method, &rq, &rv, 0.05, steps)?;
        runs.push((2, EnergyRun { label: format!("reconstruction ε=0.5, {name}"), data: r }));
    }
    let mut all_ok = true;
    let mut words = Vec::new();
    for (panel, run) in runs {
        match run.data {
            Err(e) => {
                all_ok = false;
                c.errors.push(format!("{}: {e}", run.label));
            }
            Ok(d) => {
                c.absorb(&d);
                let (first, last) = first_last_tenth(&d);
                if let Some(dt) = drift_test(&d.t, &d.energy_error, 20) {
                    let verdict = if dt.no_drift() { "bounded, no drift" } else { "DRIFTS" };
                    c.metric(
                        format!("{}: |E−E0|", run.label),
                        format!(
                            "{verdict}: max {} (first tenth {}, last tenth {}), block slope {} ± {}, drift fraction \
                             {:.3}; max |k| {}",
                            sci(d.max_energy_error),
                            sci(first),
                            sci(last),
                            sci(dt.block_slope),
                            sci(dt.block_std_error),
                            dt.drift_fraction,
                            sci(d.max_residual)
                        ),
                    );
                    words.push(format!("{}: {verdict} (max {})", run.label, sci(d.max_energy_error)));
                }
                panels_series[panel].push(Series::new(run.label, thin(log_points(&d.t, &d.energy_error, 1e-17), 3000)));
            }
        }
    }
    c.check("every run completes", all_ok, c.errors.join("; "));
    c.check("constraint residual ≤ 1e-12", c.worst_residual <= 1e-12, format!("max |k| = {}", sci(c.worst_residual)));
    c.energy = words.join("; ");
    let [rev, nonrev, recon] = panels_series;
    let panel = |title: &str, series| Panel {
        title: title.into(),
        x_label: "t".into(),
        y_label: "|E − E0|".into(),
        x_scale: Axis::Log,
        y_scale: Axis::Log,
        series,
    };
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![
            panel("reversible contact oscillator (McLachlan–Perlmutter)", rev),
            panel("non-reversible contact oscillator (Modin–Verdier)", nonrev),
            panel("gyroscopic reconstruction (ε = 0.5), for comparison", recon),
        ],
        columns: 3,
        panel_size: (600, 460),
    });
    Ok(c)
}

/// One bad-input scenario: what it is, the error kind expected, what came back.
struct Bad {
    what: &'static str,
    expected: &'static str,
    got: Result<String, String>,
    observed_steps: usize,
}

/// NaN/inf state and parameters, `h = 0`, an inconsistent initial state, a
/// final time behind the start: each must come back as the expected typed
/// error before any step is observed.
pub fn bad_input(_scale: Scale) -> Result<CaseReport, StressError> {
    let mut c = CaseReport::new(
        "bad_input",
        "Bad input",
        "Each scenario calls the library as a user would (driver `integrate`, `Stepper::step`, `set_parameter`, \
         `integrate_with_rejection`) on the skate or the near-parallel particle, and must return the expected typed \
         error with no step taken (an observer counts the steps; nothing is returned but the error).",
    );
    let q0 = Vector::<3>::zeros();
    let v0 = Vector::<3>::new(0.0, 0.0, 1.0);
    let opts = RunOptions::default();
    let mut cases: Vec<Bad> = Vec::new();
    let drive = |sys: Skate, q: Vector<3>, v: Vector<3>, schedule: Schedule<'_>| -> (Result<String, String>, usize) {
        let mut st = Stepper::<Skate, 3, 1, 2, 11>::new(sys, spark_runtime::Tableau::new(Method::Gauss).expect("s=2"));
        let mut count = 0usize;
        let mut obs = |_: &State<3>, _: usize| count += 1;
        let r = st.integrate(0.0, &q, &v, schedule, &opts, &mut obs);
        (
            r.map(|t| format!("Ok({} steps)", t.report.steps))
                .map_err(|e| format!("{} — {e}", integration_error_kind(&e))),
            count,
        )
    };
    let fixed = Schedule::Fixed { h: 0.1, steps: 10 };
    let mut push = |what, expected, (got, observed_steps): (Result<String, String>, usize)| {
        cases.push(Bad { what, expected, got, observed_steps })
    };
    push("NaN in q0", "Initial/InvalidStep", drive(Skate::default(), Vector::<3>::new(f64::NAN, 0.0, 0.0), v0, fixed));
    push(
        "+inf in v0",
        "Initial/InvalidStep",
        drive(Skate::default(), q0, Vector::<3>::new(0.0, 0.0, f64::INFINITY), fixed),
    );
    push("h = 0", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: 0.0, steps: 10 }));
    push("h = NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Fixed { h: f64::NAN, steps: 10 }));
    push("output time NaN", "InvalidSchedule", drive(Skate::default(), q0, v0, Schedule::Times(&[0.5, f64::NAN])));
    push(
        "inconsistent initial state (v0 = (1, 1, 0), |k| = 1)",
        "Initial/InconsistentInitialState",
        drive(Skate::default(), q0, Vector::<3>::new(1.0, 1.0, 0.0), fixed),
    );
    let nan_field = Skate { beta: f64::NAN, ..Skate::default() };
    push("parameter field beta = NaN (set directly)", "Step/NonFinite", drive(nan_field, q0, v0, fixed));
    let inf_field = Skate { g: f64::INFINITY, ..Skate::default() };
    push("parameter field g = +inf (set directly)", "Step/NonFinite", drive(inf_field, q0, v0, fixed));
    // Parameters through the API.
    let mut sk = Skate::default();
    let api = |r: Result<(), spark_runtime::SystemError>| match r {
        Ok(()) => (Ok("accepted".to_string()), 0),
        Err(e) => (
            Err(format!(
                "{} — {e}",
                match e {
                    spark_runtime::SystemError::NonFiniteParameter { .. } => "NonFiniteParameter",
                    spark_runtime::SystemError::UnknownParameter { .. } => "UnknownParameter",
                }
            )),
            0,
        ),
    };
    push("set_parameter(\"beta\", NaN)", "NonFiniteParameter", api(sk.set_parameter("beta", f64::NAN)));
    push("set_parameter(\"g\", -inf)", "NonFiniteParameter", api(sk.set_parameter("g", f64::NEG_INFINITY)));
    push("set_parameter(\"gravity\", 1)", "UnknownParameter", api(sk.set_parameter("gravity", 1.0)));
    // A constraint that depends on a non-finite parameter: the initial check must say so.
    {
        let sys = NearParallel { eps: f64::NAN };
        let mut st = crate::stress_stepper!(NearParallel, 2, Method::Gauss, sys);
        let mut count = 0usize;
        let mut obs = |_: &State<3>, _: usize| count += 1;
        let r = st.integrate(
            0.0,
            &Vector::<3>::new(1.0, 0.5, 0.0),
            &Vector::<3>::new(0.3, 0.0, 0.15),
            fixed,
            &opts,
            &mut obs,
        );
        let got = r
            .map(|t| format!("Ok({} steps)", t.report.steps))
            .map_err(|e| format!("{} — {e}", integration_error_kind(&e)));
        push("parameter field eps = NaN in the constraint", "Initial/NonFinite", (got, count));
    }
    // Stepper::step directly.
    {
        let mut st = Stepper::<Skate, 3, 1, 2, 11>::new(Skate::default(), spark_runtime::Tableau::new(Method::Gauss)?);
        let step = |st: &mut Stepper<Skate, 3, 1, 2, 11>, s: State<3>, h: f64| -> (Result<String, String>, usize) {
            (st.step(&s, h).map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", step_error_kind(&e))), 0)
        };
        push("Stepper::step with h = 0", "InvalidStep", step(&mut st, State::new(0.0, q0, v0), 0.0));
        push("Stepper::step with t0 = NaN", "InvalidStep", step(&mut st, State::new(f64::NAN, q0, v0), 0.1));
        push("Stepper::step with h = -inf", "InvalidStep", step(&mut st, State::new(0.0, q0, v0), f64::NEG_INFINITY));
        push(
            "Stepper::step with h below the resolution of t (t0 = 1e20, h = 1)",
            "InvalidStep",
            step(&mut st, State::new(1e20, q0, v0), 1.0),
        );
    }
    // Final time behind the start.
    {
        let mut st = crate::stress_stepper!(Skate, 2, Method::Gauss, Skate::default());
        let mut count = 0usize;
        let r = integrate_with_rejection(&mut st, 5.0, &q0, &v0, 1.0, 0.1, &RejectionPolicy::default(), &mut |_| {
            count += 1
        });
        push(
            "final time 1 behind the start 5 (h = 0.1)",
            "InvalidInterval",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), count),
        );
        let mut count = 0usize;
        let r = integrate_with_rejection(&mut st, 0.0, &q0, &v0, 1.0, 0.0, &RejectionPolicy::default(), &mut |_| {
            count += 1
        });
        push(
            "protected run with h = 0",
            "InvalidInterval",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), count),
        );
        let bad_policy = RejectionPolicy { min_step: f64::NAN, ..RejectionPolicy::default() };
        let r = integrate_with_rejection(&mut st, 0.0, &q0, &v0, 1.0, 0.1, &bad_policy, &mut |_| {});
        push(
            "rejection policy with min_step = NaN",
            "InvalidPolicy",
            (r.map(|_| "Ok".to_string()).map_err(|e| format!("{} — {e}", rejection_error_kind(&e))), 0),
        );
    }
    for b in &cases {
        let (passed, detail) = match &b.got {
            Ok(s) => (false, format!("no error: {s}")),
            Err(msg) => {
                let kind = msg.split(" — ").next().unwrap_or("");
                c.errors.push(format!("{}: {msg}", b.what));
                (kind == b.expected && b.observed_steps == 0, format!("{msg} (steps observed: {})", b.observed_steps))
            }
        };
        c.check(format!("{} → {}", b.what, b.expected), passed, detail);
    }
    c.energy = "—".into();
    let n = cases.len() as f64;
    let passed = c.checks.iter().filter(|k| k.passed).count() as f64;
    c.figure = Some(Figure {
        title: c.title.clone(),
        panels: vec![Panel {
            title: format!("scenarios returning the expected typed error: {passed} of {n}"),
            x_label: "scenario".into(),
            y_label: "1 = expected typed error, 0 = not".into(),
            x_scale: Axis::Linear,
            y_scale: Axis::Linear,
            series: vec![Series::new(
                "outcome",
                c.checks.iter().enumerate().map(|(i, k)| (i as f64 + 1.0, if k.passed { 1.0 } else { 0.0 })).collect(),
            )],
        }],
        columns: 1,
        panel_size: (820, 360),
    });
    Ok(c)
}
