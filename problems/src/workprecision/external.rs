//! The peers that live outside Rust: the SPARK step written in CasADi and
//! generated to C (`Function.generate`, `gcc -O3`, timed by a C driver), and
//! SciPy `solve_ivp` (DOP853, Radau) on the ψ-eliminated ODE. Both run in
//! `casadi/peers/peers.py`; this module hands it the problem (source text,
//! parameters, initial values, the Rust reference end state, tableaux and
//! step counts) as JSON and reads its measured points back as CSV, so every
//! peer's error is measured against the same reference in the same run.

use super::{Point, SystemMeasurement, WorkPrecisionConfig};
use crate::casadi_export::TableauExport;
use crate::simulate::SystemKind;
use std::path::Path;
use std::process::Command;

#[derive(serde::Serialize)]
struct Input<'a> {
    system: &'a str,
    name: &'a str,
    coordinates: Vec<String>,
    parameters: Vec<String>,
    parameter_values: Vec<f64>,
    lagrangian: &'a str,
    constraints: Vec<String>,
    q0: &'a [f64],
    v0: &'a [f64],
    final_time: f64,
    q_ref: &'a [f64],
    v_ref: &'a [f64],
    /// One entry per peer method: its tableau and the step counts SPARK used.
    methods: Vec<MethodInput>,
    tolerances: &'a [f64],
    repeats: usize,
    max_run_time: f64,
}

#[derive(serde::Serialize)]
struct MethodInput {
    label: String,
    tableau: TableauExport,
    steps: Vec<usize>,
}

/// Runs the external peers for one measured system and returns their points.
pub fn run(
    python: &Path,
    script: &Path,
    out: &Path,
    kind: SystemKind,
    m: &SystemMeasurement,
    tableaux: &[TableauExport],
    cfg: &WorkPrecisionConfig,
) -> Result<Vec<Point>, String> {
    if !python.exists() {
        return Err(format!(
            "Python interpreter {} not found; create it with `bash casadi/peers/setup.sh`",
            python.display()
        ));
    }
    if !script.exists() {
        return Err(format!("peer script {} not found (run from the repository root)", script.display()));
    }
    let info = kind.info();
    let source = source_of(kind);
    let methods = tableaux
        .iter()
        .zip(&cfg.peer_methods)
        .map(|(t, &(method, s))| {
            let label = super::method_label(method, s);
            let mut steps: Vec<usize> = m
                .points
                .iter()
                .filter(|p| p.solver == super::report::SPARK && p.method == label)
                .map(|p| p.steps)
                .collect();
            steps.sort_unstable();
            MethodInput { label, tableau: t.clone(), steps }
        })
        .collect();
    let input = Input {
        system: kind.key(),
        name: source.name,
        coordinates: source.coordinates.iter().map(|s| s.to_string()).collect(),
        parameters: source.parameters.iter().map(|s| s.to_string()).collect(),
        parameter_values: info.parameters.iter().map(|p| p.1).collect(),
        lagrangian: source.lagrangian,
        constraints: source.constraints.iter().map(|s| s.to_string()).collect(),
        q0: &m.problem.q0,
        v0: &m.problem.v0,
        final_time: m.problem.final_time,
        q_ref: &m.problem.q_ref,
        v_ref: &m.problem.v_ref,
        methods,
        tolerances: &cfg.tolerances,
        repeats: cfg.repeats,
        max_run_time: cfg.max_run_time.as_secs_f64(),
    };
    let dir = out.join("external");
    std::fs::create_dir_all(&dir).map_err(|e| format!("could not create {}: {e}", dir.display()))?;
    let input_path = dir.join(format!("{}-input.json", kind.key()));
    let output_path = dir.join(format!("{}-points.csv", kind.key()));
    let text = serde_json::to_string_pretty(&input).map_err(|e| e.to_string())?;
    std::fs::write(&input_path, text).map_err(|e| format!("could not write {}: {e}", input_path.display()))?;
    let result = Command::new(python)
        .arg(script)
        .arg("--input")
        .arg(&input_path)
        .arg("--output")
        .arg(&output_path)
        .arg("--build")
        .arg(dir.join(format!("{}-build", kind.key())))
        .output()
        .map_err(|e| format!("could not start {}: {e}", python.display()))?;
    if !result.status.success() {
        let stderr = String::from_utf8_lossy(&result.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(12).collect();
        return Err(format!(
            "{} exited with {}: {}",
            script.display(),
            result.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        ));
    }
    let mut reader = csv::Reader::from_path(&output_path).map_err(|e| format!("{}: {e}", output_path.display()))?;
    reader.deserialize::<Point>().collect::<Result<Vec<_>, _>>().map_err(|e| format!("{}: {e}", output_path.display()))
}

fn source_of(kind: SystemKind) -> spark_runtime::SystemSource {
    use crate::systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};
    use spark_runtime::NonholonomicSystem;
    match kind {
        SystemKind::Skate => <Skate as NonholonomicSystem<3, 1>>::SOURCE,
        SystemKind::Robot => <MobileRobot as NonholonomicSystem<4, 2>>::SOURCE,
        SystemKind::McLachlanPerlmutter7 => <McLachlanPerlmutter7 as NonholonomicSystem<7, 1>>::SOURCE,
        _ => <NonholonomicParticle as NonholonomicSystem<3, 1>>::SOURCE,
    }
}
