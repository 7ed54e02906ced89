//! The files of one run (`spark run`): the trajectory as CSV or JSON and
//! the figure of coordinates, velocities, energy error and residuals.

use super::RunResult;
use crate::report::files::{OutputDir, OutputError};
use crate::report::plot::{Figure, Panel, Scale, Series};
use std::path::PathBuf;

/// The trajectory as CSV: `t, q_<name>…, v_<name>…, energy, energy_error,
/// constraint_residual` and, for systems with holonomic constraints,
/// `holonomic_drift` (`max_i |g_i(t, q)|`). Staged in `out` as `name`.
pub fn write_run_csv(run: &RunResult, out: &mut OutputDir, name: &str) -> Result<PathBuf, OutputError> {
    let qn: Vec<String> = run.coordinates.iter().map(|c| format!("q_{c}")).collect();
    let vn: Vec<String> = run.coordinates.iter().map(|c| format!("v_{c}")).collect();
    let err: Vec<f64> = run.energy.iter().map(|e| e - run.stats.e0).collect();
    let mut cols: Vec<(&str, &[f64])> = vec![("t", &run.t)];
    cols.extend(qn.iter().map(String::as_str).zip(run.q.iter().map(Vec::as_slice)));
    cols.extend(vn.iter().map(String::as_str).zip(run.v.iter().map(Vec::as_slice)));
    cols.push(("energy", &run.energy));
    cols.push(("energy_error", &err));
    cols.push(("constraint_residual", &run.constraint));
    if !run.holonomic.is_empty() {
        cols.push(("holonomic_drift", &run.holonomic));
    }
    out.write_columns(name, &cols)
}

/// The located events as CSV: `event, index, direction, terminal, t,
/// q_<name>…, v_<name>…, step` (direction `rising` or `falling`; `step` the
/// 0-based accepted step that holds the event). Staged in `out` as `name`.
pub fn write_events_csv(run: &RunResult, out: &mut OutputDir, name: &str) -> Result<PathBuf, OutputError> {
    let mut header = vec!["event".to_string(), "index".into(), "direction".into(), "terminal".into(), "t".into()];
    header.extend(run.coordinates.iter().map(|c| format!("q_{c}")));
    header.extend(run.coordinates.iter().map(|c| format!("v_{c}")));
    header.push("step".into());
    out.write_with(name, |w| -> Result<(), csv::Error> {
        let mut writer = csv::Writer::from_writer(w);
        writer.write_record(&header)?;
        for e in &run.events {
            let mut fields = vec![
                e.name.clone(),
                e.index.to_string(),
                if e.rising { "rising" } else { "falling" }.to_string(),
                e.terminal.to_string(),
                format!("{:e}", e.t),
            ];
            // Shortest round trip: every digit that tells a value apart.
            fields.extend(e.q.iter().chain(&e.v).map(|x| format!("{x:e}")));
            fields.push(e.step.to_string());
            writer.write_record(&fields)?;
        }
        writer.flush()?;
        Ok(())
    })
}

/// Largest trajectory JSON file (estimated by [`json_trajectory_bytes`])
/// that `spark run --format json` writes: 64 MiB. Larger trajectories belong
/// in CSV (a third of the size, and streamable) or thinned with `--every`.
pub const MAX_JSON_TRAJECTORY_BYTES: u64 = 64 << 20;

/// An upper estimate of the size of the pretty-printed trajectory JSON of a
/// run with `samples` samples of `n` coordinates: one number per line
/// (indentation, up to 24 characters, comma, newline) for `t`, `q`, `v`,
/// energy, constraint residual and holonomic drift.
pub fn json_trajectory_bytes(samples: u64, n: usize, holonomic: bool) -> u64 {
    let columns = 1 + 2 * n as u64 + 2 + u64::from(holonomic);
    samples.saturating_mul(columns).saturating_mul(34)
}

/// The whole run (samples and statistics) as pretty JSON, staged in `out`
/// as `name`.
pub fn write_run_json(run: &RunResult, out: &mut OutputDir, name: &str) -> Result<PathBuf, OutputError> {
    out.write_json(name, run)
}

/// Constraint residuals for a log axis: exact zeros are shown at `floor`.
pub fn residual_points(t: &[f64], r: &[f64], floor: f64) -> Vec<(f64, f64)> {
    t.iter().zip(r).map(|(&t, &r)| (t, r.max(floor))).collect()
}

/// Figure of one run: coordinates, velocities, energy error and constraint
/// residual against time.
pub fn run_figure(run: &RunResult) -> Figure {
    let title = format!("{} — {} s = {}, h = {}", run.system, run.method, run.stages, run.h);
    let curves = |vals: &[Vec<f64>], prefix: &str| -> Vec<Series> {
        run.coordinates
            .iter()
            .zip(vals)
            .map(|(name, col)| {
                Series::new(format!("{prefix}{name}"), run.t.iter().copied().zip(col.iter().copied()).collect())
            })
            .collect()
    };
    let err: Vec<(f64, f64)> = run.t.iter().zip(&run.energy).map(|(&t, &e)| (t, e - run.stats.e0)).collect();
    let panel = |title: &str, y: &str, y_scale, series| Panel {
        title: title.into(),
        x_label: "t".into(),
        y_label: y.into(),
        x_scale: Scale::Linear,
        y_scale,
        series,
    };
    let mut panels = vec![
        panel("coordinates", "q", Scale::Linear, curves(&run.q, "")),
        panel("velocities", "v", Scale::Linear, curves(&run.v, "v_")),
        panel("energy error", "E − E0", Scale::Linear, vec![Series::new("E − E0", err)]),
        panel(
            "constraint residual (zeros shown at 1e-17)",
            "max |k|",
            Scale::Log,
            vec![Series::new("max_i |k_i|", residual_points(&run.t, &run.constraint, 1e-17))],
        ),
    ];
    if !run.holonomic.is_empty() {
        panels.push(panel(
            "holonomic drift (zeros shown at 1e-17)",
            "max |g|",
            Scale::Log,
            vec![Series::new("max_i |g_i(t, q)|", residual_points(&run.t, &run.holonomic, 1e-17))],
        ));
    }
    Figure { title, panels, columns: 2, panel_size: (640, 420) }
}
