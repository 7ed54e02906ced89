//! Time per step at the paper's step sizes, SPARK against the two CasADi C
//! peers (Newton-LU and Newton-QR), measured side by side in one run
//! (`spark work-precision --per-step`).
//!
//! For each of the paper's systems at its step size (particle `h = 0.2`,
//! skate `h = 0.1`, robot `h = 0.2`, McLachlan–Perlmutter particles `n = 7`
//! `h = 0.05`) and each of Gauss `s = 1..4` and Lobatto IIIA-B `s = 2..4`,
//! the SPARK stepper (generated code, default options) integrates from the
//! paper's initial values over `[0, 10]` with full Newton, with simplified
//! Newton on the exact Jacobian, and with simplified Newton on the
//! stage-decoupled matrix (`Jacobian::Auto`, the default of simplified
//! Newton: stage-decoupled where the structure facts allow it, exact
//! otherwise), timed by the thread's CPU time (median of repeats); then
//! `casadi/peers/peers.py --per-step` runs the Newton-LU peer
//! ([`super::external::CASADI_NEWTON_LU`]) and the Newton-QR peer
//! ([`super::external::CASADI_NEWTON_QR`]) on the same steps, timed by the
//! same clock. The table gives nanoseconds per step, the Newton iterations of
//! each, the Newton-LU peer's residual evaluations and factorizations per
//! step, and how far its end state is from SPARK's (both solve the same
//! equations, so this is round-off accumulated over the run); a summary
//! under it gives the geometric means of the ratios and how many cases
//! reach the targets.

use super::external::{self, MethodInput, PeerStepRun};
use super::flops::{flops_per_step, newton_work, NewtonPath};
use super::{Problem, WorkPrecisionConfig};
use crate::catalog::{Dispatch, StageVisitor, SystemEntry, SystemKind};
use crate::peers::dual::{visit_twin, DualTwin, TwinVisitor};
use crate::report::clock::median_time;
use spark_runtime::TableauTable;
use spark_runtime::{
    Jacobian, Method, NewtonMode, NewtonOptions, NoObserver, Observe, RunOptions, Schedule, State, Stepper, Tableau,
    Vector,
};
use std::fmt::Write as _;
use std::marker::PhantomData;

/// The final time of every per-step run.
pub const FINAL_TIME: f64 = 10.0;

/// The paper's systems with the step sizes of its §8 experiments.
pub const PAPER_STEP_SIZES: [(SystemKind, f64); 4] = [
    (SystemKind::Particle, 0.2),
    (SystemKind::Skate, 0.1),
    (SystemKind::Robot, 0.2),
    (SystemKind::McLachlanPerlmutter7, 0.05),
];

/// The methods of the table: Gauss `s = 1..4`, Lobatto IIIA-B `s = 2..4`.
pub fn per_step_methods() -> Vec<(Method, usize)> {
    let mut v: Vec<(Method, usize)> = (1..=4).map(|s| (Method::Gauss, s)).collect();
    v.extend((2..=4).map(|s| (Method::LobattoIIIAB, s)));
    v
}

/// One SPARK run of the table.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SparkRun {
    /// Median thread CPU time per step, seconds.
    pub time_per_step: f64,
    /// Mean Newton iterations per step.
    pub iterations: f64,
    /// Mean factorizations per step (counted over the same steps by
    /// `Stepper::step`).
    pub factorizations: f64,
    /// Floating-point operations per step by [`flops_per_step`].
    pub flops_per_step: f64,
    /// Timed repeats.
    pub repeats: usize,
    /// End coordinates.
    pub q: Vec<f64>,
    /// End velocities.
    pub v: Vec<f64>,
}

/// One row of the table: a system, a method, SPARK in both Newton modes and
/// the Newton-LU peer.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PerStepRow {
    /// System key.
    pub system: &'static str,
    /// Method label.
    pub method: String,
    /// Step size.
    pub h: f64,
    /// Steps over `[0, T]`.
    pub steps: usize,
    /// SPARK, full Newton.
    pub full: SparkRun,
    /// SPARK, simplified Newton on the exact Jacobian.
    pub simplified: SparkRun,
    /// SPARK, simplified Newton with `Jacobian::Auto` (the stage-decoupled
    /// matrix where the structure facts allow it).
    pub decoupled: SparkRun,
    /// The Newton-LU peer (`Err` with the reason when it did not run).
    pub peer: Result<PeerStepRun, String>,
    /// The Newton-QR peer (`Err` with the reason when it did not run).
    pub qr_peer: Result<PeerStepRun, String>,
}

impl PerStepRow {
    /// Largest difference between the peer's and SPARK full Newton's end
    /// state (`q` and `v`).
    pub fn end_state_difference(&self) -> Option<f64> {
        let p = self.peer.as_ref().ok()?;
        let d = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        Some(d(&p.q, &self.full.q).max(d(&p.v, &self.full.v)))
    }
}

/// Times `steps` SPARK steps of `(method, S)` with the Newton `mode` and
/// `jacobian` from the entry's initial values.
fn spark_run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    entry: &SystemEntry,
    method: Method,
    h: f64,
    steps: usize,
    (mode, jacobian, path): (NewtonMode, Jacobian, NewtonPath),
    cfg: &WorkPrecisionConfig,
) -> Result<SparkRun, String>
where
    Sys: Dispatch<N, M>,
{
    let tableau = Tableau::<S>::new(method).map_err(|e| e.to_string())?;
    let opts = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(Sys::default(), tableau).with_options(opts);
    let (q0, v0) = (Vector::<N>::from_column_slice(entry.q0), Vector::<N>::from_column_slice(entry.v0));
    let quiet = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let schedule = Schedule::Fixed { h, steps };
    let label = method.label(S);
    // Timed without event location, like the peers: declared events are
    // for `spark section`.
    let traj = stepper
        .integrate_with_events(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents)
        .map_err(|e| format!("{} {label}: {e}", entry.name))?;
    let end = traj.last().ok_or_else(|| format!("{} {label}: the run recorded no end state", entry.name))?;
    let (_, cpu, repeats) = median_time(cfg.repeats, cfg.min_timing, || {
        stepper
            .integrate_with_events(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver, &spark_runtime::NoEvents)
            .is_ok()
    })
    .ok_or_else(|| format!("{} {label}: a timed repeat failed", entry.name))?;
    // The same steps once more, one by one, to count the factorizations the
    // driver's report does not keep.
    let mut counting = Stepper::<Sys, N, M, S, D>::new(Sys::default(), tableau).with_options(opts);
    let (iterations, factorizations) = newton_work(&mut counting, State::new(0.0, q0, v0), h, steps)
        .map_err(|e| format!("{} {label}: {e}", entry.name))?;
    let flops = flops_per_step::<Sys, N, M, S>(path, iterations, factorizations);
    Ok(SparkRun {
        time_per_step: cpu / steps as f64,
        iterations: traj.report.newton_iterations_mean,
        factorizations,
        flops_per_step: flops,
        repeats,
        q: end.q.iter().copied().collect(),
        v: end.v.iter().copied().collect(),
    })
}

/// Both Newton modes of one `(method, S)`, and its tableau for the peer.
struct MethodRuns<'a, Sys> {
    entry: &'a SystemEntry,
    method: Method,
    h: f64,
    steps: usize,
    cfg: &'a WorkPrecisionConfig,
    system: PhantomData<Sys>,
}

type Runs = Result<([SparkRun; 3], TableauTable), String>;

/// The three SPARK variants of a row: full Newton, simplified Newton on the
/// exact Jacobian, simplified Newton with the default `Jacobian::Auto`.
/// The third is counted as the structured path: every paper system meets
/// the structure facts that make `Auto` stage-decoupled.
const VARIANTS: [(NewtonMode, Jacobian, NewtonPath); 3] = [
    (NewtonMode::Full, Jacobian::Exact, NewtonPath::Dense),
    (NewtonMode::Simplified, Jacobian::Exact, NewtonPath::DenseSimplified),
    (NewtonMode::Simplified, Jacobian::Auto, NewtonPath::Structured),
];

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for MethodRuns<'_, Sys> {
    type Output = Runs;
    fn visit<const S: usize, const D: usize>(self) -> Runs {
        let Self { entry, method, h, steps, cfg, .. } = self;
        let [full, simplified, decoupled] = VARIANTS;
        let runs = [
            spark_run::<Sys, N, M, S, D>(entry, method, h, steps, full, cfg)?,
            spark_run::<Sys, N, M, S, D>(entry, method, h, steps, simplified, cfg)?,
            spark_run::<Sys, N, M, S, D>(entry, method, h, steps, decoupled, cfg)?,
        ];
        let tableau = TableauTable::of(&Tableau::<S>::new(method).map_err(|e| e.to_string())?);
        Ok((runs, tableau))
    }
}

/// Every method of one system through the dispatch of the paper's systems
/// ([`visit_twin`]): the table measures only those, so the timed runs are
/// compiled for them alone.
struct SystemRuns<'a> {
    h: f64,
    steps: usize,
    cfg: &'a WorkPrecisionConfig,
}

impl TwinVisitor for SystemRuns<'_> {
    type Output = Result<Vec<(Method, usize, Runs)>, String>;
    fn visit<Sys: Dispatch<N, M> + DualTwin<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        entry: &'static SystemEntry,
    ) -> Self::Output {
        per_step_methods()
            .into_iter()
            .map(|(method, s)| {
                let runs = MethodRuns::<Sys> {
                    entry,
                    method,
                    h: self.h,
                    steps: self.steps,
                    cfg: self.cfg,
                    system: PhantomData,
                };
                let out = Sys::with_stages(s, runs).map_err(|e| e.to_string())?;
                Ok((method, s, out))
            })
            .collect()
    }
}

/// Measures the table: every system of [`PAPER_STEP_SIZES`] that `cfg`
/// selects, SPARK first, then the peer (when `cfg.python` is set).
pub fn measure_per_step(cfg: &WorkPrecisionConfig, progress: &dyn Fn(&str)) -> Result<Vec<PerStepRow>, String> {
    let mut rows = Vec::new();
    for &(kind, h) in PAPER_STEP_SIZES.iter().filter(|(k, _)| cfg.systems.contains(k)) {
        let entry = kind.entry();
        let steps = (FINAL_TIME / h).round() as usize;
        progress(&format!("{}: SPARK, h = {h}", entry.name));
        let runs = visit_twin(kind, SystemRuns { h, steps, cfg })
            .map_err(|_| format!("--per-step measures the paper's systems only, not `{}`", entry.name))??;
        let mut spark = Vec::new();
        let mut methods = Vec::new();
        for (method, s, r) in runs {
            let (runs, tableau) = r?;
            let label = method.label(s);
            methods.push(MethodInput { label: label.clone(), tableau, steps: vec![steps] });
            spark.push((label, runs));
        }
        let peers: Result<Vec<PeerStepRun>, String> = match &cfg.python {
            None => Err("not run (no Python interpreter configured)".into()),
            Some(python) => {
                progress(&format!("{}: {}, {}", entry.name, external::CASADI_NEWTON_LU, external::CASADI_NEWTON_QR));
                let problem = Problem {
                    system: entry.name,
                    q0: entry.q0.to_vec(),
                    v0: entry.v0.to_vec(),
                    final_time: FINAL_TIME,
                    q_ref: spark.first().map(|s| s.1[0].q.clone()).unwrap_or_default(),
                    v_ref: spark.first().map(|s| s.1[0].v.clone()).unwrap_or_default(),
                };
                external::run_per_step(python, &cfg.peers_script, &cfg.out, kind, &problem, methods, cfg)
            }
        };
        for (label, [full, simplified, decoupled]) in spark {
            let peer = |solver: &str| match &peers {
                Err(e) => Err(e.clone()),
                Ok(list) => match list.iter().find(|p| p.solver == solver && p.method == label && p.steps == steps) {
                    None => Err(format!("{solver} returned no run of {label}")),
                    Some(p) if p.failed => Err(format!("{solver}'s Newton did not meet its stop rule on {label}")),
                    Some(p) => Ok(p.clone()),
                },
            };
            let (peer, qr_peer) = (peer(external::CASADI_NEWTON_LU), peer(external::CASADI_NEWTON_QR));
            rows.push(PerStepRow {
                system: entry.name,
                method: label,
                h,
                steps,
                full,
                simplified,
                decoupled,
                peer,
                qr_peer,
            });
        }
    }
    if rows.is_empty() {
        return Err("--per-step measures the paper's systems (particle, skate, robot, mp7); none selected".into());
    }
    Ok(rows)
}

/// The geometric mean of positive ratios.
fn geometric_mean(ratios: &[f64]) -> f64 {
    (ratios.iter().map(|x| x.ln()).sum::<f64>() / ratios.len() as f64).exp()
}

/// A peer's time per step over SPARK's, for a run that measured it.
fn ratio(peer: &Result<PeerStepRun, String>, steps: usize, spark: &SparkRun) -> Option<f64> {
    peer.as_ref().ok().map(|p| p.cpu_time / steps as f64 / spark.time_per_step)
}

/// The summary under the table: for each peer and SPARK mode, the geometric
/// mean of the ratios (peer time over SPARK's), their range, and how many
/// cases reach the target (1.5× the Newton-LU peer, 5× the Newton-QR peer).
pub fn per_step_summary(rows: &[PerStepRow]) -> String {
    let mut s = String::from(
        "\nPeer time over SPARK's per step (> 1: SPARK is faster), over the cases each peer measured:\n\n\
         | peer | SPARK | cases | geometric mean | range | cases at the target |\n|---|---|---|---|---|---|\n",
    );
    type Mode = fn(&PerStepRow) -> &SparkRun;
    type Peer = fn(&PerStepRow) -> &Result<PeerStepRun, String>;
    let modes: [(&str, Mode); 3] =
        [("full", |r| &r.full), ("simplified", |r| &r.simplified), ("stage-decoupled", |r| &r.decoupled)];
    let peers: [(&str, Peer, f64); 2] =
        [(external::CASADI_NEWTON_LU, |r| &r.peer, 1.5), (external::CASADI_NEWTON_QR, |r| &r.qr_peer, 5.0)];
    for (peer_name, peer, target) in peers {
        for (mode, run) in modes {
            let ratios: Vec<f64> = rows.iter().filter_map(|r| ratio(peer(r), r.steps, run(r))).collect();
            if ratios.is_empty() {
                continue;
            }
            let geometric = geometric_mean(&ratios);
            let (lo, hi) = ratios.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| (lo.min(x), hi.max(x)));
            let reached = ratios.iter().filter(|&&x| x >= target).count();
            let _ = writeln!(
                s,
                "| {peer_name} | {mode} | {} | {geometric:.2} | {lo:.2}–{hi:.2} | {reached} at {target}× or more |",
                ratios.len()
            );
        }
    }
    s
}

/// The table measured `rounds` times (`spark work-precision --per-step
/// --rounds R`): SPARK and the peers in every round, so that a change of the
/// machine's load reaches both. Returns the rows of the minima over the
/// rounds ([`minimum_over_rounds`]) and every round's rows.
pub fn measure_rounds(
    cfg: &WorkPrecisionConfig,
    rounds: usize,
    progress: &dyn Fn(&str),
) -> Result<(Vec<PerStepRow>, Vec<Vec<PerStepRow>>), String> {
    let mut all = Vec::with_capacity(rounds);
    for round in 1..=rounds.max(1) {
        let label = |msg: &str| {
            if rounds > 1 {
                progress(&format!("round {round} of {rounds}: {msg}"))
            } else {
                progress(msg)
            }
        };
        all.push(measure_per_step(cfg, &label)?);
    }
    Ok((minimum_over_rounds(&all), all))
}

/// Each entry's minimum over the rounds: per SPARK variant the run of the
/// round that took least time per step, per peer the measured run of least
/// time (a peer measured in no round keeps the first round's reason).
/// Rounds are [`measure_per_step`]'s rows, in its order.
pub fn minimum_over_rounds(rounds: &[Vec<PerStepRow>]) -> Vec<PerStepRow> {
    let Some((first, rest)) = rounds.split_first() else { return Vec::new() };
    let faster = |a: &mut SparkRun, b: &SparkRun| {
        if b.time_per_step < a.time_per_step {
            *a = b.clone();
        }
    };
    let faster_peer = |a: &mut Result<PeerStepRun, String>, b: &Result<PeerStepRun, String>| match (&*a, b) {
        (Ok(x), Ok(y)) if y.cpu_time < x.cpu_time => *a = b.clone(),
        (Err(_), Ok(_)) => *a = b.clone(),
        _ => {}
    };
    let mut out = first.clone();
    for round in rest {
        for (o, r) in out.iter_mut().zip(round).filter(|(o, r)| o.system == r.system && o.method == r.method) {
            faster(&mut o.full, &r.full);
            faster(&mut o.simplified, &r.simplified);
            faster(&mut o.decoupled, &r.decoupled);
            faster_peer(&mut o.peer, &r.peer);
            faster_peer(&mut o.qr_peer, &r.qr_peer);
        }
    }
    out
}

/// Each round's geometric means of the stage-decoupled mode against each
/// peer, and its cases at the targets: how far the rounds spread.
pub fn per_round_markdown(rounds: &[Vec<PerStepRow>]) -> String {
    let mut s = String::from(
        "\nEach round, stage-decoupled SPARK: geometric mean of the peer's time over SPARK's \
         (cases at the target):\n\n| round | CasADi C (Newton-LU) | CasADi C (Newton-QR) |\n|---|---|---|\n",
    );
    for (k, rows) in rounds.iter().enumerate() {
        let line = |peer: fn(&PerStepRow) -> &Result<PeerStepRun, String>, target: f64| {
            let ratios: Vec<f64> = rows.iter().filter_map(|r| ratio(peer(r), r.steps, &r.decoupled)).collect();
            if ratios.is_empty() {
                return "–".to_string();
            }
            let geometric = geometric_mean(&ratios);
            let reached = ratios.iter().filter(|&&x| x >= target).count();
            format!("{geometric:.2} ({reached} of {} at {target}×)", ratios.len())
        };
        let _ = writeln!(s, "| {} | {} | {} |", k + 1, line(|r| &r.peer, 1.5), line(|r| &r.qr_peer, 5.0));
    }
    s
}

fn ns(seconds: f64) -> String {
    format!("{:.0}", seconds * 1e9)
}

/// The table as Markdown.
pub fn per_step_markdown(rows: &[PerStepRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| system | h | method | Newton-LU peer ns/step | peer evaluations / factorizations per step | \
         SPARK full ns/step (iterations) | SPARK simplified ns/step (iterations) | \
         SPARK simplified, stage-decoupled ns/step (iterations) | peer / full | peer / simplified | \
         peer / stage-decoupled | end state, peer − SPARK | Newton-QR peer ns/step | \
         QR peer / stage-decoupled |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        let full = format!("{} ({:.2})", ns(r.full.time_per_step), r.full.iterations);
        let simplified = format!("{} ({:.2})", ns(r.simplified.time_per_step), r.simplified.iterations);
        let decoupled = format!("{} ({:.2})", ns(r.decoupled.time_per_step), r.decoupled.iterations);
        let (peer, counts, rf, rs, rd, diff) = match &r.peer {
            Ok(p) => {
                let t = p.cpu_time / r.steps as f64;
                (
                    ns(t),
                    format!("{:.2} / {:.2}", p.evaluations_per_step, p.factorizations_per_step),
                    format!("{:.2}", t / r.full.time_per_step),
                    format!("{:.2}", t / r.simplified.time_per_step),
                    format!("{:.2}", t / r.decoupled.time_per_step),
                    r.end_state_difference().map_or("–".into(), |d| format!("{d:.1e}")),
                )
            }
            Err(e) => (format!("not measured: {e}"), "–".into(), "–".into(), "–".into(), "–".into(), "–".into()),
        };
        let (qr, rq) = match &r.qr_peer {
            Ok(p) => {
                let t = p.cpu_time / r.steps as f64;
                (ns(t), format!("{:.2}", t / r.decoupled.time_per_step))
            }
            Err(e) => (format!("not measured: {e}"), "–".into()),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {peer} | {counts} | {full} | {simplified} | {decoupled} | {rf} | {rs} | {rd} | {diff} \
             | {qr} | {rq} |",
            r.system, r.h, r.method
        );
    }
    s.push_str(&per_step_summary(rows));
    let _ = writeln!(
        s,
        "\nSPARK's Newton work per step (updates / factorizations), the flops it implies \
         (counted, `work_precision::flops`) and the rate reached:\n\n\
         | system | method | full: updates / factorizations, flop/step, GFLOP/s | \
         simplified | stage-decoupled |\n|---|---|---|---|---|"
    );
    let work = |run: &SparkRun| {
        format!(
            "{:.2} / {:.2}, {:.2e}, {:.2}",
            run.iterations,
            run.factorizations,
            run.flops_per_step,
            run.flops_per_step / run.time_per_step / 1e9
        )
    };
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} |",
            r.system,
            r.method,
            work(&r.full),
            work(&r.simplified),
            work(&r.decoupled)
        );
    }
    s
}
