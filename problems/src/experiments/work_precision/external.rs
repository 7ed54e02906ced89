//! The peers that live outside Rust: the SPARK step written in CasADi and
//! generated to C in two variants — CasADi's own Newton iteration with its QR
//! solve (`CasADi C (Newton-QR)`), and the residual with its dense Jacobian
//! solved by a hand-written partial-pivoting LU Newton (`CasADi C
//! (Newton-LU)`) — both `gcc -O3 -march=native` and timed by a C driver, and
//! SciPy `solve_ivp` (DOP853, Radau) on the ψ-eliminated ODE. All run in
//! `casadi/peers/peers.py`; this module hands it the problem (source text,
//! parameters, initial values, the Rust reference end state, tableaux and
//! step counts) as JSON and reads its measured points back as CSV, so every
//! peer's error is measured against the same reference in the same run.

use super::{Point, Problem, SystemMeasurement, WorkPrecisionConfig};
use crate::catalog::{visit_system, Dispatch, SystemEntry, SystemKind, SystemVisitor};
use crate::children;
use crate::report::files::replace_file;
use spark_runtime::TableauTable;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};

/// Most bytes read from each of the peer script's standard output and
/// standard error. The peer script writes nothing on standard output (its
/// results go to a file) and a few lines on standard error (one per
/// compiled peer, one per failed method; a Python traceback is a few
/// kilobytes): a `--python` program that writes more is no peer script,
/// and is stopped rather than read into memory without bound.
pub const MAX_PEER_OUTPUT: usize = 4 << 20;

/// Solver label of the CasADi-generated Newton iteration with CasADi's QR solve.
pub const CASADI_NEWTON_QR: &str = "CasADi C (Newton-QR)";
/// Solver label of the CasADi-generated residual and dense Jacobian with a
/// hand-written LU Newton.
pub const CASADI_NEWTON_LU: &str = "CasADi C (Newton-LU)";

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
    /// Smallest total CPU time of the timed repeats of one point, seconds.
    min_timing: f64,
    max_run_time: f64,
}

/// One peer method: its label, tableau and the step counts to run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MethodInput {
    /// Label ([`Method::label`](spark_runtime::Method::label)).
    pub label: String,
    /// The coefficients.
    pub tableau: TableauTable,
    /// Step counts over `[0, T]`.
    pub steps: Vec<usize>,
}

/// What `peers.py --per-step` measured for one method with the Newton-LU peer.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PeerStepRun {
    /// The peer: [`CASADI_NEWTON_LU`] or [`CASADI_NEWTON_QR`].
    pub solver: String,
    /// Method label.
    pub method: String,
    /// Steps over `[0, T]`.
    pub steps: usize,
    /// Whether some step's Newton did not meet the stop rule.
    pub failed: bool,
    /// Timed repeats.
    pub repeats: usize,
    /// Median wall time of one run, seconds.
    pub wall_time: f64,
    /// Median thread CPU time of one run, seconds.
    pub cpu_time: f64,
    /// Residual evaluations per step.
    pub evaluations_per_step: f64,
    /// Jacobian evaluations and LU factorizations per step (Newton iterations).
    pub factorizations_per_step: f64,
    /// End coordinates.
    pub q: Vec<f64>,
    /// End velocities.
    pub v: Vec<f64>,
}

/// Runs the external peers for one measured system and returns their points:
/// the CasADi C steps of `tableaux` (when `casadi`) and SciPy's DOP853 and
/// Radau (always).
#[allow(clippy::too_many_arguments)]
pub fn run(
    python: &Path,
    script: &Path,
    out: &Path,
    kind: SystemKind,
    m: &SystemMeasurement,
    tableaux: &[TableauTable],
    cfg: &WorkPrecisionConfig,
    casadi: bool,
) -> Result<Vec<Point>, String> {
    let methods = tableaux
        .iter()
        .zip(&cfg.peer_methods)
        .map(|(t, &(method, s))| {
            let label = method.label(s);
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
    let dir = out.join("external");
    let output_path = dir.join(format!("{}-points.csv", kind.key()));
    let extra: &[&str] = if casadi { &[] } else { &["--skip-casadi"] };
    run_script(python, script, &dir, kind, &m.problem, methods, cfg, &output_path, extra)?;
    let mut reader = csv::Reader::from_path(&output_path).map_err(|e| format!("{}: {e}", output_path.display()))?;
    reader.deserialize::<Point>().collect::<Result<Vec<_>, _>>().map_err(|e| format!("{}: {e}", output_path.display()))
}

/// Runs only the two CasADi C peers, Newton-LU and Newton-QR (`peers.py
/// --per-step`), on `problem`, each method at its step counts, and returns
/// what they measured. `problem`'s reference end state is not used.
pub fn run_per_step(
    python: &Path,
    script: &Path,
    out: &Path,
    kind: SystemKind,
    problem: &Problem,
    methods: Vec<MethodInput>,
    cfg: &WorkPrecisionConfig,
) -> Result<Vec<PeerStepRun>, String> {
    let dir = out.join("per-step");
    let output_path = dir.join(format!("{}-casadi-peers.json", kind.key()));
    run_script(python, script, &dir, kind, problem, methods, cfg, &output_path, &["--per-step"])?;
    let text = std::fs::read_to_string(&output_path).map_err(|e| format!("{}: {e}", output_path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", output_path.display()))
}

/// Writes the problem as JSON into `dir` and runs the peer script on it;
/// the script writes `output`. An `output` left by an earlier run is
/// removed first, and a script that ends successfully without writing it is
/// an error: the earlier run's numbers are never read back as this run's.
#[allow(clippy::too_many_arguments)]
fn run_script(
    python: &Path,
    script: &Path,
    dir: &Path,
    kind: SystemKind,
    problem: &Problem,
    methods: Vec<MethodInput>,
    cfg: &WorkPrecisionConfig,
    output: &Path,
    extra: &[&str],
) -> Result<(), String> {
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
    let input = Input {
        system: kind.key(),
        name: source.name,
        coordinates: source.coordinates.iter().map(|s| s.to_string()).collect(),
        parameters: source.parameters.iter().map(|s| s.to_string()).collect(),
        parameter_values: info.parameters.iter().map(|p| p.1).collect(),
        lagrangian: source.lagrangian,
        constraints: source.constraints.iter().map(|s| s.to_string()).collect(),
        q0: &problem.q0,
        v0: &problem.v0,
        final_time: problem.final_time,
        q_ref: &problem.q_ref,
        v_ref: &problem.v_ref,
        methods,
        tolerances: &cfg.tolerances,
        repeats: cfg.repeats,
        min_timing: cfg.min_timing.as_secs_f64(),
        max_run_time: cfg.max_run_time.as_secs_f64(),
    };
    std::fs::create_dir_all(dir).map_err(|e| format!("could not create {}: {e}", dir.display()))?;
    let input_path = dir.join(format!("{}-input.json", kind.key()));
    // Replaced whole, like every output: an interrupted run leaves the
    // earlier input or the new one, never a part that a later run's peer
    // script or a reader would take for a problem.
    replace_file(&input_path, |w| serde_json::to_writer_pretty(w, &input)).map_err(|e| e.to_string())?;
    let build: PathBuf = dir.join(format!("{}-build", kind.key()));
    match std::fs::remove_file(output) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(format!("could not remove the earlier peer results {}: {e}", output.display()));
        }
        _ => {}
    }
    let mut command = Command::new(python);
    command
        .arg(script)
        .arg("--input")
        .arg(&input_path)
        .arg("--output")
        .arg(output)
        .arg("--build")
        .arg(build)
        .args(extra);
    let program = format!("{} {}", python.display(), script.display());
    let (status, stderr) = output_bounded(&mut command, &program)?;
    if !status.success() {
        let stderr = String::from_utf8_lossy(&stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(12).collect();
        return Err(format!(
            "{} exited with {}: {}",
            script.display(),
            status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        ));
    }
    if !output.is_file() {
        return Err(format!(
            "{} {} exited successfully but wrote no {}; --python must name a Python interpreter with casadi and \
             scipy (set up by `bash casadi/peers/setup.sh`)",
            python.display(),
            script.display(),
            output.display()
        ));
    }
    Ok(())
}

/// Runs `command` (the program `program`) to its end with standard input
/// closed and returns its exit status and standard error. Each of its
/// standard output (read and discarded) and standard error is read up to
/// [`MAX_PEER_OUTPUT`] bytes; a program that writes more is killed and is
/// an error naming it and the stream. The program runs as a
/// [`children::spawn`] child: it and what it starts (the compiler, the
/// timing driver) end with this program, also on a signal.
fn output_bounded(command: &mut Command, program: &str) -> Result<(ExitStatus, Vec<u8>), String> {
    let mut child = children::spawn(command.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()))
        .map_err(|e| format!("could not start {program}: {e}"))?;
    // Both streams are read at once, each on its own thread: a program
    // blocked writing one stream while the other is read would never end.
    let (sender, received) = std::sync::mpsc::channel();
    let streams: [(&'static str, Option<Box<dyn Read + Send>>); 2] = [
        ("standard output", child.child().stdout.take().map(|s| Box::new(s) as Box<dyn Read + Send>)),
        ("standard error", child.child().stderr.take().map(|s| Box::new(s) as Box<dyn Read + Send>)),
    ];
    let mut readers = 0;
    for (stream, reader) in streams {
        let Some(reader) = reader else { continue };
        let sender = sender.clone();
        let read = move || {
            let mut bytes = Vec::new();
            let read = reader.take(MAX_PEER_OUTPUT as u64 + 1).read_to_end(&mut bytes).map(|_| bytes);
            let _ = sender.send((stream, read));
        };
        if let Err(e) = std::thread::Builder::new().name("peer output".into()).spawn(read) {
            child.kill();
            let _ = child.wait();
            return Err(format!("could not read the output of {program}: {e}"));
        }
        readers += 1;
    }
    drop(sender);
    let mut stderr = Vec::new();
    for _ in 0..readers {
        // A reader that stops early is not waited for: a process the
        // program started may still hold the other stream open.
        let failure = match received.recv() {
            Ok((stream, Ok(bytes))) if bytes.len() > MAX_PEER_OUTPUT => Some(format!(
                "{program} wrote more than {} MiB to its {stream}, which no peer script does, and was stopped; \
                 --python must name a Python interpreter with casadi and scipy (set up by `bash \
                 casadi/peers/setup.sh`)",
                MAX_PEER_OUTPUT >> 20,
            )),
            Ok(("standard error", Ok(bytes))) => {
                stderr = bytes;
                None
            }
            Ok((_, Ok(_))) => None,
            Ok((stream, Err(e))) => Some(format!("could not read the {stream} of {program}: {e}")),
            Err(_) => Some(format!("could not read the output of {program}")),
        };
        if let Some(failure) = failure {
            child.kill();
            let _ = child.wait();
            return Err(failure);
        }
    }
    let status = child.wait().map_err(|e| format!("could not wait for {program}: {e}"))?;
    Ok((status, stderr))
}

/// The neutral source (coordinates, parameters, Lagrangian, constraints) of
/// the registered system `kind`, which the Python peers rebuild in CasADi.
pub fn source_of(kind: SystemKind) -> spark_runtime::SystemSource {
    struct Source;
    impl SystemVisitor for Source {
        type Output = spark_runtime::SystemSource;
        fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
            self,
            _: &'static SystemEntry,
        ) -> Self::Output {
            Sys::SOURCE
        }
    }
    visit_system(kind, Source)
}
