//! The non-reversible case: the Modin–Verdier contact oscillator beside
//! its reversible twin.

use crate::experiments::stress::{run_fixed, CaseReport, RunData, Scale, StressError};
use crate::report::format::{log_points, sci, thin};
use crate::report::plot::{Figure, Panel, Scale as Axis, Series};
use crate::report::stats::drift_test;
use crate::systems::stress::{
    contact_oscillator_initial, ContactOscillator, NonReversibleContactOscillator, NonReversibleOscillator,
};
use spark_runtime::{Method, NonholonomicSystem, Stepper, Tableau, Vector};

/// One energy record of the non-reversible case.
struct EnergyRun {
    label: String,
    data: Result<RunData, String>,
}

/// Runs `steps` steps of `st` with the energy guard off, recording at most
/// about 10⁴ samples.
fn nr_run<Sys, const S: usize, const D: usize>(
    st: Stepper<Sys, 3, 1, S, D>,
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
    let options = spark_runtime::NewtonOptions { energy_drift_limit: None, ..crate::experiments::stress::newton() };
    let mut st = st.with_options(options);
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
/// gyroscopic reconstruction `NonReversibleOscillator`.
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
    let reversible = |method| -> Result<Stepper![ContactOscillator, 2], StressError> {
        Ok(<Stepper![ContactOscillator, 2]>::new(ContactOscillator { eps }, Tableau::new(method)?))
    };
    let gauged = |method| -> Result<Stepper![NonReversibleContactOscillator, 2], StressError> {
        Ok(<Stepper![NonReversibleContactOscillator, 2]>::new(
            NonReversibleContactOscillator { eps },
            Tableau::new(method)?,
        ))
    };
    // The two declarations must describe the same motion (the gauge term is a
    // total derivative): compare them at a small step over t ∈ [0, 10].
    let fine = 0.01;
    let a = nr_run(reversible(Method::Gauss)?, &q0, &v0, fine, 1000)?;
    let b = nr_run(gauged(Method::Gauss)?, &q0, &v0, fine, 1000)?;
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
        let r = nr_run(reversible(method)?, &q0, &v0, h, steps)?;
        runs.push((0, EnergyRun { label: format!("reversible, {name}"), data: r }));
        let r = nr_run(gauged(method)?, &q0, &v0, h, steps)?;
        runs.push((1, EnergyRun { label: format!("non-reversible, {name}"), data: r }));
    }
    let (rq, rv) = (Vector::<3>::new(0.5, 0.6, 0.4), Vector::<3>::new(-0.2, 0.3, 0.5));
    for (method, name) in [(Method::Gauss, "Gauss s=2"), (Method::LobattoIIIAB, "Lobatto IIIA-B s=2")] {
        let r = nr_run(
            <Stepper![NonReversibleOscillator, 2]>::new(NonReversibleOscillator { eps: 0.5 }, Tableau::new(method)?),
            &rq,
            &rv,
            0.05,
            steps,
        )?;
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
