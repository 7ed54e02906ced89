//! Energy over a long run with fixed, error-controlled and reversible
//! steps (`spark work-precision --adaptive-energy`): the orbit system
//! ([`crate::systems::OrbitParticle`]) with Gauss s = 2, a fixed run of 10⁶
//! steps and the two tolerance-driven runs over the same time span.

use crate::report::files::OutputDir;
use crate::report::plot::{Figure, Panel, Scale, Series};
use crate::systems::OrbitParticle;
use spark_runtime::{
    integrate_adaptive, integrate_reversible, AdaptiveOptions, Method, NonholonomicSystem, Observe, RunOptions,
    Schedule, State, Stepper, Tableau, Vector,
};
use std::fmt::Write as _;
use std::time::Instant;

/// Fixed steps of the long run.
pub const FIXED_STEPS: usize = 1_000_000;
/// Fixed step size (the catalogue's default for `orbit`).
pub const FIXED_H: f64 = 0.002;
/// `rtol = atol` of the tolerance-driven runs.
pub const TOLERANCE: f64 = 1e-8;
/// Time bins of the figure (largest `|E − E₀|` per bin).
const BINS: usize = 400;

/// One run of the study.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct EnergyRun {
    /// `fixed`, `adaptive` or `reversible`.
    pub label: String,
    /// Accepted steps.
    pub steps: usize,
    /// Step solves (three per attempt for the error-controlled run).
    pub solves: usize,
    /// Largest `|E − E₀|` over the first tenth of the run.
    pub energy_error_early: f64,
    /// Largest `|E − E₀|` over the whole run.
    pub energy_error: f64,
    /// Wall time in seconds.
    pub wall_time: f64,
    /// `(t, max |E − E₀| in the bin ending at t)`.
    pub curve: Vec<(f64, f64)>,
}

struct Bins {
    t_end: f64,
    e0: f64,
    max: Vec<f64>,
}

impl Bins {
    fn add(&mut self, sys: &OrbitParticle, s: &State<3>) {
        let e = (sys.energy(s.t, &s.q, &s.v) - self.e0).abs();
        let k = ((s.t / self.t_end * BINS as f64) as usize).min(BINS - 1);
        self.max[k] = self.max[k].max(e);
    }
    fn finish(self, label: &str, steps: usize, solves: usize, wall_time: f64) -> EnergyRun {
        let early = self.max[..BINS / 10].iter().copied().fold(0.0, f64::max);
        let all = self.max.iter().copied().fold(0.0, f64::max);
        let curve = self.max.iter().enumerate().map(|(k, &e)| ((k + 1) as f64 * self.t_end / BINS as f64, e)).collect();
        EnergyRun { label: label.into(), steps, solves, energy_error_early: early, energy_error: all, wall_time, curve }
    }
}

/// Runs the three integrations.
pub fn measure(progress: &dyn Fn(&str)) -> Result<Vec<EnergyRun>, String> {
    let sys = OrbitParticle::default();
    let softening = sys.parameter_values()[1];
    let (q0, v0) = (Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 0.3, 0.0));
    let t_end = FIXED_H * FIXED_STEPS as f64;
    let e0 = sys.energy(0.0, &q0, &v0);
    let bins = || Bins { t_end, e0, max: vec![0.0; BINS] };
    let tableau = Tableau::<2>::new(Method::Gauss).map_err(|e| e.to_string())?;
    let mut stepper: Stepper<OrbitParticle, 3, 1, 2, 11> = Stepper::new(sys, tableau);
    let mut out = Vec::new();

    progress(&format!("orbit: {FIXED_STEPS} fixed steps, h = {FIXED_H}"));
    let mut b = bins();
    let quiet = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let start = Instant::now();
    let traj = stepper
        .integrate(
            0.0,
            &q0,
            &v0,
            Schedule::Fixed { h: FIXED_H, steps: FIXED_STEPS },
            &quiet,
            &mut |s: &State<3>, _: usize| b.add(&sys, s),
        )
        .map_err(|e| e.to_string())?;
    out.push(b.finish("fixed", traj.report.steps, traj.report.steps, start.elapsed().as_secs_f64()));

    let options = AdaptiveOptions {
        rtol: TOLERANCE,
        atol: TOLERANCE,
        record_every: 0,
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        max_steps: 100 * FIXED_STEPS,
        ..AdaptiveOptions::default()
    };
    progress(&format!("orbit: error-controlled steps, rtol = atol = {TOLERANCE:.0e}"));
    let mut b = bins();
    let start = Instant::now();
    let run =
        integrate_adaptive(&mut stepper, 0.0, &q0, &v0, t_end, &options, &mut |s: &State<3>, _: usize| b.add(&sys, s))
            .map_err(|e| e.to_string())?;
    out.push(b.finish("adaptive", run.report.accepted, run.report.solves, start.elapsed().as_secs_f64()));

    progress(&format!("orbit: reversible steps, σ = r^(-3/2), ε from rtol = atol = {TOLERANCE:.0e}"));
    let mut b = bins();
    let density =
        |_: f64, q: &Vector<3>, _: &Vector<3>| (q[0] * q[0] + q[1] * q[1] + softening * softening).powf(-0.75);
    let start = Instant::now();
    let run =
        integrate_reversible(&mut stepper, 0.0, &q0, &v0, t_end, density, &options, &mut |s: &State<3>, _: usize| {
            b.add(&sys, s)
        })
        .map_err(|e| e.to_string())?;
    out.push(b.finish("reversible", run.report.accepted, run.report.solves, start.elapsed().as_secs_f64()));
    Ok(out)
}

/// The table of the study.
pub fn markdown(runs: &[EnergyRun]) -> String {
    let mut s = String::new();
    let t_end = FIXED_H * FIXED_STEPS as f64;
    let _ = writeln!(
        s,
        "Orbit (`orbit`), Gauss s = 2, T = {t_end}: {FIXED_STEPS} fixed steps of h = {FIXED_H}; \
         error-controlled and reversible steps at rtol = atol = {TOLERANCE:.0e}.\n"
    );
    let _ = writeln!(
        s,
        "| steps | accepted | step solves | max abs(E − E₀), first T/10 | max abs(E − E₀), whole run | wall time |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
    for r in runs {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.2e} | {:.2e} | {:.1} s |",
            r.label, r.steps, r.solves, r.energy_error_early, r.energy_error, r.wall_time
        );
    }
    let _ = writeln!(s, "\n![energy over the long run](adaptive-energy.png)");
    s
}

/// The figure of the study.
pub fn figure(runs: &[EnergyRun]) -> Figure {
    let series = runs.iter().map(|r| Series::new(r.label.clone(), r.curve.clone())).collect();
    Figure {
        title: "orbit, Gauss s = 2: energy error over a 10⁶-step run".into(),
        panels: vec![Panel {
            title: format!("max |E − E₀| per 1/{BINS} of the run"),
            x_label: "t".into(),
            y_label: "|E − E₀|".into(),
            x_scale: Scale::Linear,
            y_scale: Scale::Log,
            series,
        }],
        columns: 1,
        panel_size: (900, 500),
    }
}

/// Measures and writes `adaptive-energy.{md,json,png,svg}` into `out`.
pub fn run(out: &mut OutputDir, progress: &dyn Fn(&str)) -> Result<String, String> {
    let runs = measure(progress)?;
    let md = markdown(&runs);
    out.render(&figure(&runs), "adaptive-energy").map_err(|e| e.to_string())?;
    out.write_json("adaptive-energy.json", &runs).map_err(|e| e.to_string())?;
    out.write_bytes("adaptive-energy.md", md.as_bytes()).map_err(|e| e.to_string())?;
    Ok(md)
}
