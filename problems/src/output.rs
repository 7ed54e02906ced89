//! Files written by the command line: trajectory CSV/JSON, column tables
//! behind the figures, and the figure of a single run.

use crate::plot::{Figure, Panel, Scale, Series};
use crate::simulate::RunResult;
use std::path::{Path, PathBuf};

/// Errors while writing output files.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// A file or directory could not be created or written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// CSV encoding failed.
    #[error("cannot write CSV {path}: {source}")]
    Csv {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: csv::Error,
    },
    /// JSON encoding failed.
    #[error("cannot write JSON {path}: {source}")]
    Json {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: serde_json::Error,
    },
    /// Columns of a table differ in length.
    #[error("table {path}: column `{column}` has {got} rows, expected {expected}")]
    Ragged {
        /// The path.
        path: PathBuf,
        /// The offending column.
        column: String,
        /// Its length.
        got: usize,
        /// The first column's length.
        expected: usize,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io { path: path.to_path_buf(), source }
}

/// Creates `dir` and its parents.
pub fn create_dir(dir: &Path) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))
}

/// Writes named columns of equal length as CSV (numbers in shortest
/// round-trip form, so reading them back gives the same `f64`).
pub fn write_columns(path: &Path, columns: &[(&str, &[f64])]) -> Result<(), OutputError> {
    let rows = columns.first().map_or(0, |c| c.1.len());
    for (name, col) in columns {
        if col.len() != rows {
            return Err(OutputError::Ragged {
                path: path.into(),
                column: name.to_string(),
                got: col.len(),
                expected: rows,
            });
        }
    }
    let csv_err = |source| OutputError::Csv { path: path.to_path_buf(), source };
    let mut w = csv::Writer::from_path(path).map_err(csv_err)?;
    w.write_record(columns.iter().map(|c| c.0)).map_err(csv_err)?;
    for r in 0..rows {
        w.write_record(columns.iter().map(|c| format!("{:?}", c.1[r]))).map_err(csv_err)?;
    }
    w.flush().map_err(io(path))?;
    Ok(())
}

/// Reads a CSV written by [`write_columns`] back as `(header, columns)`.
pub fn read_columns(path: &Path) -> Result<(Vec<String>, Vec<Vec<f64>>), OutputError> {
    let csv_err = |source| OutputError::Csv { path: path.to_path_buf(), source };
    let mut r = csv::Reader::from_path(path).map_err(csv_err)?;
    let header: Vec<String> = r.headers().map_err(csv_err)?.iter().map(str::to_string).collect();
    let mut cols = vec![Vec::new(); header.len()];
    for rec in r.records() {
        let rec = rec.map_err(csv_err)?;
        for (c, field) in cols.iter_mut().zip(rec.iter()) {
            c.push(field.trim().parse::<f64>().unwrap_or(f64::NAN));
        }
    }
    Ok((header, cols))
}

/// The trajectory as CSV: `t, q_<name>…, v_<name>…, energy, energy_error,
/// constraint_residual` and, for systems with holonomic constraints,
/// `holonomic_drift` (`max_i |g_i(t, q)|`).
pub fn write_run_csv(run: &RunResult, path: &Path) -> Result<(), OutputError> {
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
    write_columns(path, &cols)
}

/// The whole run (samples and statistics) as pretty JSON.
pub fn write_run_json(run: &RunResult, path: &Path) -> Result<(), OutputError> {
    let text =
        serde_json::to_string_pretty(run).map_err(|source| OutputError::Json { path: path.to_path_buf(), source })?;
    std::fs::write(path, text).map_err(io(path))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_round_trip_exactly() {
        let dir = std::env::temp_dir().join(format!("spark-out-{}", std::process::id()));
        create_dir(&dir).unwrap();
        let p = dir.join("c.csv");
        let a = [0.1, 1.0 / 3.0, -2.5e-17];
        let b = [1.0, f64::MIN_POSITIVE, 7.0];
        write_columns(&p, &[("a", &a), ("b", &b)]).unwrap();
        let (h, cols) = read_columns(&p).unwrap();
        assert_eq!(h, vec!["a", "b"]);
        assert_eq!(cols[0], a.to_vec());
        assert_eq!(cols[1], b.to_vec());
        let bad = write_columns(&p, &[("a", &a), ("b", &b[..2])]);
        assert!(matches!(bad, Err(OutputError::Ragged { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
