//! The large-steps case: where Newton stops converging, with and without
//! the rejection policy.

use super::{failed_index, integration_error_kind, is_newton_failure};
use crate::experiments::stress::{run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::sci;
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::systems::McLachlanPerlmutter7;
use spark_runtime::{
    FailurePolicy, IntegrationError, Method, NoEvents, NoObserver, NonholonomicSystem, Observe, RejectionPolicy,
    RunOptions, Schedule, Stepper, Tableau, Trajectory, Vector,
};

/// One plain and one protected run of the same problem.
struct Pair {
    plain: Result<RunData, IntegrationError>,
    protected: Result<Trajectory<7, 1>, IntegrationError>,
}

/// What the sweep over `h` found.
#[derive(Default)]
struct Tally {
    /// Step sizes whose plain run failed, and those the policy carried through.
    plain_fail: Vec<f64>,
    rescued: Vec<f64>,
    /// Every failure is typed (and every completed plain run finite).
    all_typed: bool,
    /// `(h, |E − E0|)` of the completed plain and protected runs, and
    /// `(h, rejections)` of the protected ones.
    plain_points: Vec<(f64, f64)>,
    protected_points: Vec<(f64, f64)>,
    rejection_points: Vec<(f64, f64)>,
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
    let (q0v, v0v) = crate::systems::mp7_initial_values(0, 9);
    let (q0, v0) = (Vector::<7>::from_column_slice(&q0v), Vector::<7>::from_column_slice(&v0v));
    let mut pairs = Vec::new();
    for &h in &hs {
        let mut st = mp7_gauss2()?;
        let n = (t_end / h).round() as usize;
        let plain = run_fixed(&mut st, &q0, &v0, h, n, 1, 0);
        let protected = protected_run(&mut st, &q0, &v0, t_end, h, &policy);
        pairs.push(Pair { plain, protected });
    }
    let e0 = McLachlanPerlmutter7::default().energy(0.0, &q0, &v0);
    let tally = judge_sweep(&mut c, &hs, &pairs, e0);
    let plain_fail = &tally.plain_fail;
    c.check(
        "every plain failure is a typed Newton failure (Diverged/MaxIterations/SingularMatrix/NonFinite) with its reason",
        tally.all_typed,
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
        !tally.rescued.is_empty(),
        format!("rescued at h = {:?}", tally.rescued),
    );
    judge_floor(&mut c, &q0, &v0, t_end, *hs.last().unwrap_or(&12.8), &policy)?;
    c.energy = match plain_fail.first() {
        Some(h) => format!("plain runs fail from h = {h}; per-h energy errors in the metrics"),
        None => "no plain run failed; per-h energy errors in the metrics".into(),
    };
    c.figure = Some(large_steps_figure(&c.title, tally));
    Ok(c)
}

/// Gauss s = 2 on the McLachlan–Perlmutter particles.
fn mp7_gauss2() -> Result<Stepper![McLachlanPerlmutter7, 2], StressError> {
    Ok(<Stepper![McLachlanPerlmutter7, 2]>::new(McLachlanPerlmutter7::default(), Tableau::new(Method::Gauss)?))
}

/// The driver under the rejection policy from `(0, q0, v0)` to `t_end`
/// with nominal step `h`, recording only the endpoints, observing nothing
/// (the energy and the residual are judged at the end) and locating no
/// events.
fn protected_run(
    st: &mut Stepper![McLachlanPerlmutter7, 2],
    q0: &Vector<7>,
    v0: &Vector<7>,
    t_end: f64,
    h: f64,
    policy: &RejectionPolicy,
) -> Result<Trajectory<7, 1>, IntegrationError> {
    let options = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        on_failure: FailurePolicy::Reject(*policy),
        ..RunOptions::default()
    };
    st.integrate_with_events(0.0, q0, v0, Schedule::Until { h, t_end }, &options, &mut NoObserver, &NoEvents)
}

/// The metrics of each `h` (plain and protected outcome), and the tally the
/// checks and the figure read.
fn judge_sweep(c: &mut CaseReport, hs: &[f64], pairs: &[Pair], e0: f64) -> Tally {
    let sys = McLachlanPerlmutter7::default();
    let mut t = Tally { all_typed: true, ..Tally::default() };
    for (&h, p) in hs.iter().zip(pairs) {
        let plain_desc = match &p.plain {
            Ok(d) => {
                c.absorb(d);
                let finite = d.max_energy_error.is_finite() && d.max_residual <= 1e-10;
                if !finite {
                    t.all_typed = false;
                }
                t.plain_points.push((h, d.max_energy_error.max(1e-17)));
                format!("completes: max |E−E0| {}, max |k| {}", sci(d.max_energy_error), sci(d.max_residual))
            }
            Err(e) => {
                t.plain_fail.push(h);
                if !is_newton_failure(e) {
                    t.all_typed = false;
                }
                c.errors.push(format!("plain, h = {h}: {e}"));
                format!("fails: {} at step {}", integration_error_kind(e), failed_index(e))
            }
        };
        let prot_desc = match p.protected.as_ref().map(|run| (run.last(), &run.report)) {
            Ok((Some(s), r)) => {
                c.rejections += r.rejected_steps;
                let de = (sys.energy(s.t, &s.q, &s.v) - e0).abs();
                let k = sys.constraint(s.t, &s.q, &s.v).amax();
                c.worst_residual = c.worst_residual.max(k);
                if p.plain.is_err() {
                    t.rescued.push(h);
                }
                t.protected_points.push((h, de.max(1e-17)));
                t.rejection_points.push((h, r.rejected_steps as f64));
                format!(
                    "completes: {} rejections in {} nominal steps, smallest sub-step {}, final |E−E0| {}, |k| {}",
                    r.rejected_steps,
                    r.steps,
                    sci(r.smallest_step),
                    sci(de),
                    sci(k)
                )
            }
            Ok((None, _)) => {
                t.all_typed = false;
                "completes without recording its end".to_string()
            }
            Err(e) => {
                if !matches!(e, IntegrationError::Floor { .. }) {
                    t.all_typed = false;
                }
                c.errors.push(format!("protected, h = {h}: {e}"));
                let before = match e {
                    IntegrationError::Step { partial, .. }
                    | IntegrationError::Floor { partial, .. }
                    | IntegrationError::SubstepBudget { partial, .. } => partial.rejected_steps,
                    _ => 0,
                };
                format!(
                    "fails: {} in nominal step {} ({before} rejections before)",
                    integration_error_kind(e),
                    failed_index(e)
                )
            }
        };
        c.metric(format!("h = {h}: plain"), plain_desc);
        c.metric(format!("h = {h}: with rejection"), prot_desc);
    }
    t
}

/// A policy allowed a single halving cannot rescue the largest step: the
/// protected run must then stop with a typed Floor error naming the floor
/// and the last Newton failure.
fn judge_floor(
    c: &mut CaseReport,
    q0: &Vector<7>,
    v0: &Vector<7>,
    t_end: f64,
    h_max: f64,
    policy: &RejectionPolicy,
) -> Result<(), StressError> {
    let tight = RejectionPolicy { max_halvings: 1, ..*policy };
    let mut st = mp7_gauss2()?;
    match protected_run(&mut st, q0, v0, t_end, h_max, &tight) {
        Ok(_) => c.check(
            format!("h = {h_max} with a policy of one halving stops with a typed Floor error"),
            false,
            "the run completed",
        ),
        Err(e) => {
            c.errors.push(format!("protected, h = {h_max}, max_halvings = 1: {e}"));
            c.check(
                format!("h = {h_max} with a policy of one halving stops with a typed Floor error"),
                matches!(e, IntegrationError::Floor { .. }),
                format!("{}: {e}", integration_error_kind(&e)),
            );
        }
    }
    Ok(())
}

/// Energy errors against `h`, and the protected runs' rejections.
fn large_steps_figure(title: &str, t: Tally) -> Figure {
    Figure {
        title: title.to_string(),
        panels: vec![
            Panel {
                title: "energy error (plain: max over run; protected: at t_end)".into(),
                x_label: "h".into(),
                y_label: "|E − E0|".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![
                    Series::new("plain (completed runs)", t.plain_points),
                    Series::new("with rejection", t.protected_points),
                ],
            },
            Panel {
                title: "rejections of the protected run (0 drawn at 0.5)".into(),
                x_label: "h".into(),
                y_label: "rejections".into(),
                x_scale: Axis::Log,
                y_scale: Axis::Log,
                series: vec![Series::new(
                    "rejections",
                    t.rejection_points.into_iter().map(|(h, r)| (h, if r > 0.0 { r } else { 0.5 })).collect(),
                )],
            },
        ],
        columns: 2,
        panel_size: (600, 420),
    }
}
