//! Work-precision output: the points as CSV, the "cheapest method per target
//! error" and peer-ratio tables as Markdown, and the figures.

use super::{
    Point, Provider, SystemMeasurement, WorkPrecisionConfig, WorkPrecisionError, SPARK_ADAPTIVE, SPARK_REVERSIBLE,
};
use crate::report::files::OutputDir;
use crate::report::format::duration;
use crate::report::plot::{Figure, Panel, Scale, Series};
use crate::report::stats::positive_median;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Solver label of the generated-code SPARK runs.
pub const SPARK: &str = Provider::Generated.label();
/// Solver labels of the CasADi-generated C steps (CasADi's Newton-QR
/// iteration, and the hand-written LU Newton on CasADi's residual and
/// Jacobian).
pub const CASADI_C: [&str; 2] = [super::external::CASADI_NEWTON_QR, super::external::CASADI_NEWTON_LU];
/// The peers compared per step, at the same method and step count.
const PER_STEP_PEERS: [&str; 4] =
    [Provider::NumDual.label(), Provider::FiniteDifference.label(), CASADI_C[0], CASADI_C[1]];
/// The SPARK step-size strategies of the adaptive figure and table: fixed
/// steps, error-controlled steps, the reversible rule.
pub const SPARK_STRATEGIES: [&str; 3] = [SPARK, SPARK_ADAPTIVE, SPARK_REVERSIBLE];
/// Solver label of SciPy `solve_ivp`.
pub const SCIPY: &str = "SciPy solve_ivp";
/// Solver label of `ode_solvers`.
pub const ODE_SOLVERS: &str = "ode_solvers (Rust)";

/// Points of one curve, keyed by `(solver, method)`, in sweep order.
pub fn curves(points: &[Point]) -> BTreeMap<(String, String), Vec<&Point>> {
    let mut map: BTreeMap<(String, String), Vec<&Point>> = BTreeMap::new();
    for p in points {
        map.entry((p.solver.clone(), p.method.clone())).or_default().push(p);
    }
    map
}

/// Wall time one curve needs to reach error `target`: log–log interpolation
/// between the cheapest point that reaches it and the most expensive cheaper
/// point that does not; `None` if no point reaches it.
pub fn time_to_reach(curve: &[&Point], target: f64) -> Option<f64> {
    let mut pts: Vec<(f64, f64)> =
        curve.iter().filter(|p| p.error() > 0.0 && p.time() > 0.0).map(|p| (p.time(), p.error())).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let first = pts.iter().position(|&(_, e)| e <= target)?;
    let (tb, eb) = pts[first];
    if first == 0 {
        return Some(tb);
    }
    let (ta, ea) = pts[first - 1];
    if ea <= eb {
        return Some(tb);
    }
    let f = (ea.ln() - target.ln()) / (ea.ln() - eb.ln());
    Some((ta.ln() + f * (tb.ln() - ta.ln())).exp())
}

/// The cheapest `(solver, method)` and its time at each target error, among
/// the curves whose solver satisfies `filter`.
pub fn cheapest<'a>(
    curves: &BTreeMap<(String, String), Vec<&'a Point>>,
    target: f64,
    filter: impl Fn(&str) -> bool,
) -> Option<(&'a Point, f64)> {
    curves
        .iter()
        .filter(|((solver, _), _)| filter(solver))
        .filter_map(|(_, c)| time_to_reach(c, target).map(|t| (c[0], t)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Steps the cheapest point of `curve` reaching `target` takes.
fn steps_at(curve: &[&Point], target: f64) -> Option<usize> {
    curve.iter().filter(|p| p.error() <= target).min_by(|a, b| a.time().total_cmp(&b.time())).map(|p| p.steps)
}

/// Per-step time ratios `peer / SPARK` at the same method and step count
/// (so at equal accuracy: the same stepper solves the same equations), over
/// the points with error below `1e-2` (out of the pre-asymptotic range).
pub fn per_step_ratios(points: &[Point], peer: &str) -> BTreeMap<String, (f64, usize)> {
    let mut by_method: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for p in points.iter().filter(|p| p.solver == peer) {
        let twin =
            points.iter().find(|g| g.solver == SPARK && g.method == p.method && g.steps == p.steps && g.error() < 1e-2);
        if let Some(g) = twin {
            by_method.entry(p.method.clone()).or_default().push(p.time_per_step / g.time_per_step);
        }
    }
    by_method.into_iter().filter_map(|(m, r)| positive_median(r.clone()).map(|x| (m, (x, r.len())))).collect()
}

/// `time(peer) / time(best SPARK)` to reach each target, for each peer curve.
pub fn equal_error_ratios(points: &[Point], targets: &[f64]) -> Vec<(String, Vec<Option<f64>>)> {
    let all = curves(points);
    let mut out = Vec::new();
    for ((solver, method), curve) in &all {
        if solver == SPARK {
            continue;
        }
        let row = targets
            .iter()
            .map(|&t| {
                let peer = time_to_reach(curve, t)?;
                let (_, best) = cheapest(&all, t, |s| s == SPARK)?;
                Some(peer / best)
            })
            .collect();
        out.push((format!("{solver}: {method}"), row));
    }
    out
}

/// Stages every point as the CSV file `name` in `out`.
pub fn write_points_csv(points: &[Point], out: &mut OutputDir, name: &str) -> Result<(), WorkPrecisionError> {
    out.write_with(name, |w| {
        let mut w = csv::Writer::from_writer(w);
        for p in points {
            w.serialize(p)?;
        }
        w.flush()?;
        Ok::<(), crate::report::files::WriteFailure>(())
    })?;
    Ok(())
}

/// The "which method is cheapest" table of one system (Markdown).
pub fn cheapest_table(m: &SystemMeasurement, targets: &[f64]) -> String {
    let all = curves(&m.points);
    let mut s = String::new();
    let _ = writeln!(s, "| target error | cheapest SPARK method | steps | time per run | time per step | best peer | its time | peer / SPARK |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for &t in targets {
        let spark = cheapest(&all, t, |x| x == SPARK);
        let peer = cheapest(&all, t, |x| !SPARK_STRATEGIES.contains(&x));
        let (sm, st, ss, sps) = match spark {
            Some((p, time)) => {
                let steps = steps_at(&all[&(p.solver.clone(), p.method.clone())], t);
                (p.method.clone(), duration(time), steps.map_or("–".into(), |n| n.to_string()), {
                    steps.map_or("–".into(), |n| duration(time / n as f64))
                })
            }
            None => ("not reached".into(), "–".into(), "–".into(), "–".into()),
        };
        let (pm, pt, ratio) = match (peer, spark) {
            (Some((p, time)), Some((_, best))) => {
                (format!("{}: {}", p.solver, p.method), duration(time), format!("{:.1}×", time / best))
            }
            (Some((p, time)), None) => (format!("{}: {}", p.solver, p.method), duration(time), "–".into()),
            _ => ("not reached".into(), "–".into(), "–".into()),
        };
        let _ = writeln!(s, "| {t:.0e} | {sm} | {ss} | {st} | {sps} | {pm} | {pt} | {ratio} |");
    }
    s
}

/// The "fixed against adaptive steps" table of one system (Markdown): at
/// each target error the cheapest SPARK method of each step-size strategy,
/// its time, and the time of the cheapest fixed-step method divided by it
/// (above 1: the strategy reaches the error at lower cost), next to the ODE
/// solvers.
pub fn strategy_table(m: &SystemMeasurement, targets: &[f64]) -> String {
    let all = curves(&m.points);
    let mut s = String::new();
    let head: Vec<String> = targets.iter().map(|t| format!("{t:.0e}")).collect();
    let _ = writeln!(s, "| step sizes (cheapest method) | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(targets.len()));
    let fixed: Vec<Option<f64>> = targets.iter().map(|&t| cheapest(&all, t, |x| x == SPARK).map(|c| c.1)).collect();
    let mut row = |name: &str, filter: &dyn Fn(&str) -> bool| {
        let cells: Vec<String> = targets
            .iter()
            .zip(&fixed)
            .map(|(&t, best_fixed)| match cheapest(&all, t, filter) {
                None => "not reached".into(),
                Some((p, time)) => {
                    let ratio = best_fixed.map_or("–".into(), |f| times(f / time));
                    format!("{}, {}, fixed / this {ratio}", p.method, duration(time))
                }
            })
            .collect();
        let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
    };
    for solver in SPARK_STRATEGIES {
        if all.keys().any(|(x, _)| x == solver) {
            row(&format!("SPARK {}", strategy(solver)), &|x: &str| x == solver);
        }
    }
    for solver in [ODE_SOLVERS, SCIPY] {
        let methods: Vec<&String> = all.keys().filter(|(x, _)| x == solver).map(|(_, me)| me).collect();
        for method in methods {
            let name = format!("{solver}: {method}");
            let cells: Vec<String> = targets
                .iter()
                .zip(&fixed)
                .map(|(&t, best_fixed)| match time_to_reach(&all[&(solver.to_string(), method.clone())], t) {
                    None => "not reached".into(),
                    Some(time) => {
                        let ratio = best_fixed.map_or("–".into(), |f| times(f / time));
                        format!("{}, fixed / this {ratio}", duration(time))
                    }
                })
                .collect();
            let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
        }
    }
    s
}

/// A time ratio: one decimal, or two significant digits below 0.1.
fn times(x: f64) -> String {
    if x >= 0.1 {
        format!("{x:.1}×")
    } else {
        format!("{x:.1e}×")
    }
}

/// The ratio tables of one system (Markdown).
pub fn ratio_tables(m: &SystemMeasurement, targets: &[f64]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "Per step, same method and step size (equal accuracy), median over the sweep:\n");
    let _ = writeln!(s, "| peer | method | peer / SPARK time per step | points |");
    let _ = writeln!(s, "|---|---|---|---|");
    for peer in PER_STEP_PEERS {
        let ratios = per_step_ratios(&m.points, peer);
        if ratios.is_empty() {
            let _ = writeln!(s, "| {peer} | – | not measured | 0 |");
        }
        for (method, (r, n)) in ratios {
            let _ = writeln!(s, "| {peer} | {method} | {r:.1}× | {n} |");
        }
    }
    let _ = writeln!(s, "\nTime to reach the same error, peer / cheapest SPARK method:\n");
    let head: Vec<String> = targets.iter().map(|t| format!("{t:.0e}")).collect();
    let _ = writeln!(s, "| peer | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(targets.len()));
    for (peer, row) in equal_error_ratios(&m.points, targets) {
        let cells: Vec<String> = row.iter().map(|r| r.map_or("not reached".into(), |x| format!("{x:.1}×"))).collect();
        let _ = writeln!(s, "| {peer} | {} |", cells.join(" | "));
    }
    s
}

fn family(method: &str) -> usize {
    if method.starts_with("Gauss") {
        0
    } else if method.starts_with("Lobatto IIIA-B-D") {
        2
    } else if method.starts_with("Lobatto IIIA-B") {
        1
    } else {
        3
    }
}

const FAMILIES: [&str; 4] = ["Gauss", "Lobatto IIIA-B", "Lobatto IIIA-B-D", "Euler I/II, LDA"];

fn family_figure(m: &SystemMeasurement, title: &str, y_label: &str, y: impl Fn(&Point) -> f64) -> Figure {
    let all = curves(&m.points);
    let panels = FAMILIES
        .iter()
        .enumerate()
        .map(|(k, name)| Panel {
            title: (*name).into(),
            x_label: "time per run [s] (thread CPU)".into(),
            y_label: y_label.into(),
            x_scale: Scale::Log,
            y_scale: Scale::Log,
            series: all
                .iter()
                .filter(|((solver, method), _)| solver == SPARK && family(method) == k)
                .map(|((_, method), c)| Series::new(method.clone(), c.iter().map(|p| (p.time(), y(p))).collect()))
                .collect(),
        })
        .filter(|p| p.series.iter().any(|s| s.points.iter().any(|&(x, y)| x > 0.0 && y > 0.0)))
        .collect();
    Figure { title: title.into(), panels, columns: 2, panel_size: (640, 460) }
}

fn peer_figure(m: &SystemMeasurement, cfg: &WorkPrecisionConfig) -> Figure {
    let all = curves(&m.points);
    let mut panels = Vec::new();
    for &(method, s) in &cfg.peer_methods {
        let label = method.label(s);
        let series: Vec<Series> = all
            .iter()
            .filter(|((_, me), _)| *me == label)
            .map(|((solver, _), c)| Series::new(solver.clone(), c.iter().map(|p| (p.time(), p.error())).collect()))
            .collect();
        // A system whose solution the method reproduces exactly (error 0)
        // has nothing to draw on log axes.
        if series.iter().any(|s| s.points.iter().any(|&(x, y)| x > 0.0 && y > 0.0)) {
            panels.push(Panel {
                title: format!("{label}: same step, other derivative code"),
                x_label: "time per run [s] (thread CPU)".into(),
                y_label: "global error in q, v at T".into(),
                x_scale: Scale::Log,
                y_scale: Scale::Log,
                series,
            });
        }
    }
    // The lower envelope of all SPARK methods against the ODE solvers.
    let series = vec![Series::new("SPARK, best method at each cost", envelope(&m.points, SPARK))];
    push_against_ode_solvers(&mut panels, "SPARK against ODE solvers on the ψ-eliminated ODE", series, &all);
    Figure {
        title: format!("{}: peers, T = {}", m.problem.system, m.problem.final_time),
        panels,
        columns: 2,
        panel_size: (640, 460),
    }
}

/// The lower envelope `(time, error)` of every curve of `solver`: the
/// smallest error reached at each cost, by any method.
pub fn envelope(points: &[Point], solver: &str) -> Vec<(f64, f64)> {
    let mut env: Vec<(f64, f64)> =
        points.iter().filter(|p| p.solver == solver && p.error() > 0.0).map(|p| (p.time(), p.error())).collect();
    env.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best = f64::INFINITY;
    env.retain(|&(_, e)| {
        let keep = e < best;
        best = best.min(e);
        keep
    });
    env
}

/// The series label of a SPARK step-size strategy in the adaptive figure.
fn strategy(solver: &str) -> &'static str {
    if solver == SPARK_ADAPTIVE {
        "adaptive (rtol = atol)"
    } else if solver == SPARK_REVERSIBLE {
        "reversible adaptive"
    } else {
        "fixed steps"
    }
}

/// Adds the ODE solvers' curves (SciPy, ode_solvers) of `all` to `series`
/// and pushes them as one error-against-time panel titled `title`, unless
/// no point can be drawn on its log axes.
fn push_against_ode_solvers(
    panels: &mut Vec<Panel>,
    title: &str,
    mut series: Vec<Series>,
    all: &BTreeMap<(String, String), Vec<&Point>>,
) {
    for ((solver, method), c) in all {
        if *solver == *SCIPY || *solver == *ODE_SOLVERS {
            series.push(Series::new(format!("{solver}: {method}"), c.iter().map(|p| (p.time(), p.error())).collect()));
        }
    }
    if series.iter().any(|s| s.points.iter().any(|&(x, y)| x > 0.0 && y > 0.0)) {
        panels.push(Panel {
            title: title.into(),
            x_label: "time per run [s] (thread CPU)".into(),
            y_label: "global error in q, v at T".into(),
            x_scale: Scale::Log,
            y_scale: Scale::Log,
            series,
        });
    }
}

/// Fixed against tolerance-driven and reversible steps of the same method
/// (the peer methods), next to DOP853 and SciPy's solvers on the
/// ψ-eliminated ODE; the last panel puts the best SPARK method at each cost
/// of each step-size strategy against those solvers.
fn adaptive_figure(m: &SystemMeasurement, cfg: &WorkPrecisionConfig) -> Figure {
    let all = curves(&m.points);
    let mut panels = Vec::new();
    for &(method, s) in &cfg.peer_methods {
        let label = method.label(s);
        let mut series: Vec<Series> = all
            .iter()
            .filter(|((solver, me), _)| *me == label && SPARK_STRATEGIES.contains(&solver.as_str()))
            .map(|((solver, _), c)| Series::new(strategy(solver), c.iter().map(|p| (p.time(), p.error())).collect()))
            .collect();
        for ((solver, me), c) in &all {
            if *solver == *SCIPY || *solver == *ODE_SOLVERS {
                series.push(Series::new(format!("{solver}: {me}"), c.iter().map(|p| (p.time(), p.error())).collect()));
            }
        }
        if series.iter().any(|s| s.points.iter().any(|&(x, y)| x > 0.0 && y > 0.0)) {
            panels.push(Panel {
                title: format!("{label}: fixed and adaptive steps"),
                x_label: "time per run [s] (thread CPU)".into(),
                y_label: "global error in q, v at T".into(),
                x_scale: Scale::Log,
                y_scale: Scale::Log,
                series,
            });
        }
    }
    let series: Vec<Series> = SPARK_STRATEGIES
        .iter()
        .map(|&solver| Series::new(format!("SPARK {}, best method", strategy(solver)), envelope(&m.points, solver)))
        .filter(|s| !s.points.is_empty())
        .collect();
    push_against_ode_solvers(&mut panels, "best method at each cost, per step-size strategy", series, &all);
    Figure {
        title: format!("{}: fixed vs adaptive steps, T = {}", m.problem.system, m.problem.final_time),
        panels,
        columns: 2,
        panel_size: (640, 460),
    }
}

/// Stages one system's CSV, figures and Markdown in `out`.
pub fn write_system(
    m: &SystemMeasurement,
    cfg: &WorkPrecisionConfig,
    out: &mut OutputDir,
) -> Result<(), WorkPrecisionError> {
    let key = m.problem.system;
    write_points_csv(&m.points, out, &format!("{key}.csv"))?;
    let t = m.problem.final_time;
    let fig = family_figure(m, &format!("{key}: global error at T = {t} vs wall time"), "global error in q, v", |p| {
        p.error()
    });
    if !fig.panels.is_empty() {
        out.render(&fig, &format!("{key}-error"))?;
    }
    let fig =
        family_figure(m, &format!("{key}: largest energy error on [0, {t}] vs wall time"), "max |E − E₀|", |p| {
            p.energy_error
        });
    if !fig.panels.is_empty() {
        out.render(&fig, &format!("{key}-energy"))?;
    }
    let fig = peer_figure(m, cfg);
    if !fig.panels.is_empty() {
        out.render(&fig, &format!("{key}-peers"))?;
    }
    let fig = adaptive_figure(m, cfg);
    if !fig.panels.is_empty() {
        out.render(&fig, &format!("{key}-adaptive"))?;
    }
    let md = system_markdown(m, cfg);
    out.write_bytes(&format!("{key}.md"), md.as_bytes())?;
    Ok(())
}

/// One system's section of the report.
pub fn system_markdown(m: &SystemMeasurement, cfg: &WorkPrecisionConfig) -> String {
    let key = m.problem.system;
    let mut s = String::new();
    let (n, mm) = m.dimensions;
    let _ = writeln!(s, "### {key} (n = {n}, m = {mm}, T = {})\n", m.problem.final_time);
    let _ = writeln!(
        s,
        "![error vs time]({key}-error.png)\n![energy error vs time]({key}-energy.png)\n![peers]({key}-peers.png)\n\
         ![fixed vs adaptive steps]({key}-adaptive.png)\n"
    );
    let _ = writeln!(s, "{}", cheapest_table(m, &cfg.targets));
    let _ = writeln!(
        s,
        "Fixed against adaptive steps: time to reach each target error (log–log interpolated along each curve)\n"
    );
    let _ = writeln!(s, "{}", strategy_table(m, &cfg.targets));
    let _ = writeln!(s, "{}", ratio_tables(m, &cfg.targets));
    for miss in &m.missing {
        let _ = writeln!(s, "- not measured: {miss}");
    }
    let _ = writeln!(
        s,
        "\nOperation counts of the generated code: stage values {}, stage values + Jacobians {}.",
        m.operations.stage_values, m.operations.stage_jacobians
    );
    s
}

/// Stages `summary.md` (all systems) and `points.csv` (all points) in `out`.
pub fn write_summary(
    all: &[SystemMeasurement],
    cfg: &WorkPrecisionConfig,
    out: &mut OutputDir,
) -> Result<(), WorkPrecisionError> {
    let points: Vec<Point> = all.iter().flat_map(|m| m.points.iter().cloned()).collect();
    write_points_csv(&points, out, "points.csv")?;
    let mut s = String::new();
    let _ = writeln!(s, "## Peer ratios (one run, medians)\n");
    let _ = writeln!(s, "{}", overall_ratio_table(all, cfg));
    for m in all {
        let _ = writeln!(s, "{}", system_markdown(m, cfg));
    }
    out.write_bytes("summary.md", s.as_bytes())?;
    Ok(())
}

/// One row per system and peer: the per-step ratio (same-stepper peers) or
/// the equal-error time ratio at each target (ODE solvers).
pub fn overall_ratio_table(all: &[SystemMeasurement], cfg: &WorkPrecisionConfig) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| system | peer | basis | ratio (peer / SPARK) |");
    let _ = writeln!(s, "|---|---|---|---|");
    for m in all {
        let key = m.problem.system;
        for peer in PER_STEP_PEERS {
            let r = per_step_ratios(&m.points, peer);
            let cells: Vec<String> = r.iter().map(|(me, (x, _))| format!("{me}: {x:.1}×")).collect();
            let text = if cells.is_empty() { "not measured".to_string() } else { cells.join(", ") };
            let _ = writeln!(s, "| {key} | {peer} | per step, same method and h | {text} |");
        }
        for (peer, row) in equal_error_ratios(&m.points, &cfg.targets) {
            if PER_STEP_PEERS.iter().any(|p| peer.starts_with(p)) {
                continue;
            }
            let cells: Vec<String> = cfg
                .targets
                .iter()
                .zip(&row)
                .map(|(t, r)| format!("{t:.0e}: {}", r.map_or("not reached".into(), |x| format!("{x:.1}×"))))
                .collect();
            let _ = writeln!(s, "| {key} | {peer} | time to equal error vs best SPARK | {} |", cells.join(", "));
        }
    }
    s
}
