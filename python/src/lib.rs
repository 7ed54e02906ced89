//! `spark._native`: the extension module behind the `spark` Python package.
//!
//! It exposes the registry of the `problems` crate (every system `spark list`
//! shows, by name), one integration run and ensembles of runs for those
//! systems, and the DSL check that `spark.compile` runs before it calls
//! cargo.
//!
//! Runs go through `problems::run::run` and `problems::run::run_ensemble_with`,
//! the non-generic entry points `spark run` uses: every (system, s) stepper
//! is compiled once, in `problems`, and this crate holds no generic
//! instantiation per system. It shares the request parsing and the result
//! conversion with the modules `spark.compile` builds (`spark-python-core`),
//! so registered and compiled systems take the same requests and return the
//! same dicts.

use problems::catalog::{entries, lookup, SystemEntry, MAX_DISPATCH_STAGES};
use problems::run::{check_parameters, run, run_ensemble_with, EnsembleError, RunError, RunResult, RunSpec};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use spark_python_core::{
    argument_error, check_initial_state, check_members, check_stages, columns_to_py, ensemble_to_py, facts_to_py,
    interruptible, python_words, read_ensemble, read_request, spark_error, text, Columns, Failure, IntegrateRequest,
    SystemFacts, ENSEMBLE_PROJECT_HINT, PROJECTION_TOLERANCE,
};
use spark_runtime::{ConsistencyPolicy, Method};
use std::sync::atomic::Ordering;
use std::time::Instant;

pyo3::create_exception!(
    _native,
    SparkError,
    pyo3::exceptions::PyException,
    "An error of spark: a bad argument, an inconsistent initial state, a failed step, a bad declaration. \
     The message is the Rust library's and says what to change."
);

/// The registered system `name`; an unknown name is a bad argument.
fn entry(py: Python<'_>, name: &str) -> PyResult<&'static SystemEntry> {
    lookup(name).map_err(|e| argument_error(py, e.to_string()))
}

/// Where a registered system's steppers are compiled, for the message of a
/// stage count beyond them.
const PROGRAM: &str = "this program";

/// The run `r` asks for, of the registered system `e`.
fn run_spec(e: &'static SystemEntry, r: &IntegrateRequest) -> RunSpec {
    RunSpec {
        system: e.kind,
        parameters: r.parameters.clone(),
        method: r.method,
        stages: r.stages,
        h: r.h,
        steps: r.steps,
        t0: r.t0,
        q0: r.q0.clone(),
        v0: r.v0.clone(),
        record_every: r.every,
        newton: r.newton,
        consistency: if r.project_v0 {
            ConsistencyPolicy::Project { tolerance: PROJECTION_TOLERANCE }
        } else {
            ConsistencyPolicy::default()
        },
        multipliers: r.multipliers,
        max_halvings: r.max_halvings,
        tolerance: r.tolerance,
        times: r.times.clone(),
        events: r.events,
    }
}

/// A run's error in the words of the Python API: the keyword arguments
/// where `spark run`'s message names command-line flags.
fn message(e: &RunError) -> Failure {
    match e {
        RunError::InconsistentVelocities { system, residual, tolerance, default } => format!(
            "v0 violates the constraints of `{system}`: max |k(t0, q0, v0)| = {residual:.3e} > {tolerance:.1e}; give \
             a v0 with k = 0 or pass project_v0=True to use the nearest consistent one (default v0 = {default:?})"
        ),
        RunError::UnknownParameter { system, name, suggestion, known } => format!(
            "system `{system}` has no parameter `{name}`{}; its parameters: {known} \
             (see `spark.system(\"{system}\").parameters`)",
            problems::catalog::did_you_mean(suggestion)
        ),
        e => python_words(&e.to_string()),
    }
}

/// An ensemble's error in the words of the Python API; an inconsistent
/// member is told what `spark.ensemble` takes (it has no `project_v0`).
fn ensemble_message(e: &EnsembleError) -> Failure {
    match e {
        EnsembleError::Member {
            member,
            source: RunError::InconsistentVelocities { system, residual, tolerance, .. },
        } => {
            format!(
                "member {member}: v0 violates the constraints of `{system}`: max |k(t0, q0, v0)| = {residual:.3e} > \
                 {tolerance:.1e}; {ENSEMBLE_PROJECT_HINT}"
            )
        }
        EnsembleError::Member { member, source } => format!("member {member}: {}", message(source)),
        e => e.to_string(),
    }
}

/// A run's columns as the row-major samples the Python side returns.
fn columns(r: RunResult, m: usize, seconds: f64) -> Columns {
    let samples = r.t.len();
    let rows = |cols: &[Vec<f64>]| -> Vec<f64> {
        let mut out = Vec::with_capacity(samples * cols.len());
        for k in 0..samples {
            out.extend(cols.iter().map(|c| c[k]));
        }
        out
    };
    Columns {
        n: r.q.len(),
        m,
        q: rows(&r.q),
        v: rows(&r.v),
        psi: rows(&r.psi),
        t: r.t,
        energy: r.energy,
        constraint: r.constraint,
        holonomic: r.holonomic,
        e0: r.stats.e0,
        steps: r.stats.steps,
        newton_iterations_mean: r.stats.newton_iterations_mean,
        rejected_steps: r.stats.rejected_steps,
        steps_with_rejections: r.stats.steps_with_rejections,
        substeps: r.stats.substeps,
        smallest_step: r.stats.smallest_step,
        seconds,
        events: r.events,
        controller: r.controller,
    }
}

/// Every registered system name, in registry order (the paper's first).
#[pyfunction]
fn names() -> Vec<&'static str> {
    problems::catalog::names()
}

/// Facts about the registered system `name`: description, `N`, `M`,
/// coordinates, parameters with defaults, structure facts, effects, events,
/// operation counts, default initial state, step and final time.
#[pyfunction]
fn system_info_of<'py>(py: Python<'py>, name: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, &text(name, "name")?)?;
    let facts = SystemFacts {
        source: e.source,
        n: e.n,
        m: e.m,
        parameter_values: e.default_parameters().into_iter().map(|(_, value)| value).collect(),
        structure: e.structure,
        constant_stiffness: e.constant_stiffness,
        diagonal_stiffness: e.diagonal_stiffness,
        forcing: e.effects.forcing,
        nonideal: e.effects.nonideal,
        holonomic: e.effects.holonomic,
        events: problems::catalog::declared_events(e.kind),
    };
    let d = facts_to_py(py, &facts)?;
    d.set_item("name", e.name)?;
    d.set_item("description", e.description)?;
    d.set_item("path", e.path)?;
    d.set_item("paper", e.paper)?;
    d.set_item("t0", e.t0)?;
    d.set_item("q0", e.q0.to_vec())?;
    d.set_item("v0", e.v0.to_vec())?;
    d.set_item("h", e.h)?;
    d.set_item("t_end", e.t_end)?;
    d.set_item("operations_stage_jacobians", e.operations.stage_jacobians)?;
    Ok(d)
}

/// One run of the registered system `name` (see `spark.System.integrate`).
/// `rust_seconds` is the wall time of `problems::run::run` (checks, stepper
/// set-up, the steps and the columns): what a Rust caller pays.
#[pyfunction]
fn integrate<'py>(py: Python<'py>, name: &str, request: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, name)?;
    let r = read_request(py, request)?;
    check_stages(py, &r, MAX_DISPATCH_STAGES, PROGRAM)?;
    // A parameter name the system does not have is the caller's bad
    // argument: refused here, as the others, not as the run's failure.
    check_parameters(e, &r.parameters).map_err(|err| argument_error(py, message(&err)))?;
    check_initial_state(py, &r, e.n)?;
    let spec = run_spec(e, &r);
    let c = interruptible(py, |stop| {
        let start = Instant::now();
        let result = run(&spec, &|_| !stop.load(Ordering::Relaxed)).map_err(|err| message(&err))?;
        Ok(columns(result, e.m, start.elapsed().as_secs_f64()))
    })?;
    columns_to_py(py, c)
}

/// An ensemble of runs of the registered system `name` (see `spark.ensemble`).
#[pyfunction]
fn ensemble<'py>(py: Python<'py>, name: &str, request: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, name)?;
    let r = read_ensemble(py, request)?;
    check_stages(py, &r.run, MAX_DISPATCH_STAGES, PROGRAM)?;
    // As in `integrate`: before the members run, not as member 0's failure.
    check_parameters(e, &r.run.parameters).map_err(|err| argument_error(py, message(&err)))?;
    check_members(py, &r, e.n)?;
    let row = |x: &[f64], j: usize| x[j * e.n..(j + 1) * e.n].to_vec();
    let members: Vec<(Vec<f64>, Vec<f64>)> = (0..r.members).map(|j| (row(&r.q0s, j), row(&r.v0s, j))).collect();
    let spec = run_spec(e, &r.run);
    let runs = interruptible(py, |stop| {
        let go_on = |_| !stop.load(Ordering::Relaxed);
        let results = run_ensemble_with(&spec, &members, r.threads, &go_on).map_err(|err| ensemble_message(&err))?;
        Ok(results
            .into_iter()
            .map(|result| {
                let seconds = result.stats.wall_time.as_secs_f64();
                columns(result, e.m, seconds)
            })
            .collect::<Vec<_>>())
    })?;
    ensemble_to_py(py, &r.run, runs)
}

/// The methods: `(key, name, smallest s, largest compiled s)`.
#[pyfunction]
fn methods() -> Vec<(String, String, usize, usize)> {
    Method::ALL
        .into_iter()
        .map(|m| {
            let (lo, hi) = m.stage_range();
            (m.key().to_string(), m.name().to_string(), lo, hi.min(MAX_DISPATCH_STAGES))
        })
        .collect()
}

/// Initial values of member `j` of the §8.4 ensemble with `big_j + 1`
/// members (`problems::systems::mp7_initial_values`).
#[pyfunction]
fn mp7_initial_values(j: usize, big_j: usize) -> (Vec<f64>, Vec<f64>) {
    problems::systems::mp7_initial_values(j, big_j)
}

/// Where a span starts, 1-based line and column.
fn position(span: proc_macro2::Span) -> (usize, usize) {
    let start = span.start();
    (start.line, start.column + 1)
}

/// The traits a struct in a module `spark.compile` builds may derive: those
/// of `std` that a struct of `f64` fields supports. (`Default` is generated;
/// the declaration check refuses it with its own message.)
const MODULE_DERIVES: [&str; 5] = ["Clone", "Copy", "Debug", "PartialEq", "PartialOrd"];

/// The attributes such a struct may carry: doc comments and attributes that
/// build in any module. Python sees none of them; they are accepted so that
/// a declaration copied from Rust compiles.
const MODULE_ATTRIBUTES: [&str; 8] =
    ["doc", "derive", "allow", "warn", "expect", "must_use", "deprecated", "non_exhaustive"];

/// Why an attribute of `spec` would not build in the module `spark.compile`
/// makes, with the attribute's span: that module depends on spark alone,
/// finds the runtime at `::spark_runtime` and has no configuration to
/// select, so `#[spark(crate = …)]` with another path, `#[cfg]`, derives
/// beyond [`MODULE_DERIVES`] and attributes of other crates fail in cargo,
/// after the check.
fn module_attribute_error(spec: &spark_symbolic::SystemSpec) -> Option<(String, proc_macro2::Span)> {
    use proc_macro2::TokenTree;
    let runtime: String = spec.runtime_path.to_string().split_whitespace().collect();
    if runtime.trim_start_matches("::") != "spark_runtime" {
        let span = spec.runtime_path.clone().into_iter().next().map_or_else(|| spec.name.span(), |t| t.span());
        let message = "spark.compile builds the module against spark's runtime at `::spark_runtime`; remove \
                       `#[spark(crate = …)]`";
        return Some((message.into(), span));
    }
    let attrs: Vec<TokenTree> = spec.attrs.clone().into_iter().collect();
    for pair in attrs.chunks(2) {
        let [TokenTree::Punct(pound), TokenTree::Group(group)] = pair else { continue };
        let inner: Vec<TokenTree> = group.stream().into_iter().collect();
        let name = match inner.first() {
            Some(TokenTree::Ident(id)) => id.to_string(),
            _ => String::new(),
        };
        if name == "cfg" || name == "cfg_attr" {
            return Some((
                format!(
                    "`#[{name}(…)]`: spark.compile builds the declaration as written, with no configuration to \
                     select (a false condition removes the struct and breaks the build); remove it"
                ),
                pound.span(),
            ));
        }
        if !MODULE_ATTRIBUTES.contains(&name.as_str()) {
            return Some((
                format!(
                    "spark.compile does not take `#[{name}…]` on the struct: its module depends on spark alone and \
                     Python sees no attribute. It takes doc comments, `#[derive(…)]` of {} and lint attributes \
                     (`allow`, `warn`, `expect`); remove it",
                    MODULE_DERIVES.join(", ")
                ),
                pound.span(),
            ));
        }
        if name != "derive" {
            continue;
        }
        let Some(TokenTree::Group(traits)) = inner.get(1) else { continue };
        let traits: Vec<TokenTree> = traits.stream().into_iter().collect();
        let is_comma = |t: &TokenTree| matches!(t, TokenTree::Punct(p) if p.as_char() == ',');
        // The trait of each item is its path's last segment (`std::fmt::Debug`).
        let last_idents = traits.split(is_comma).filter_map(|item| {
            item.iter().rev().find_map(|t| if let TokenTree::Ident(id) = t { Some(id.clone()) } else { None })
        });
        for id in last_idents {
            let t = id.to_string();
            if t != "Default" && !MODULE_DERIVES.contains(&t.as_str()) {
                let message = format!(
                    "spark.compile's module cannot derive `{t}` (the struct's fields are f64 and the module \
                     depends on spark alone); it may derive {}",
                    MODULE_DERIVES.join(", ")
                );
                return Some((message, id.span()));
            }
        }
    }
    None
}

/// What [`check_dsl`] found, as plain data: the token types of proc-macro2
/// stay on the thread that made them.
enum Checked {
    Good { name: String, n: usize, m: usize, coordinates: Vec<String>, parameters: Vec<String> },
    Bad { message: String, line: usize, column: usize },
}

/// The check of [`check_dsl`]: the macro's parser and engine on `text`.
fn check_text(text: &str) -> Checked {
    let fail = |message: String, span: proc_macro2::Span| {
        let (line, column) = position(span);
        // A name of millions of characters is quoted as an excerpt, as in
        // the macro's errors.
        let message = spark_symbolic::spec::bound_long_words(&message).into_owned();
        Checked::Bad { message, line, column }
    };
    let tokens: proc_macro2::TokenStream = match text.parse() {
        Ok(t) => t,
        Err(e) => {
            let e: proc_macro2::LexError = e;
            return fail(format!("the text is not valid Rust tokens: {e}"), e.span());
        }
    };
    match spark_symbolic::scenes::parse_with_scenes(&tokens) {
        Err(e) => return fail(e.message, e.span),
        Ok(Some((base, _))) => {
            return fail(
                "spark.compile takes one system without `effects`/`scenes`; declare each scene as its own system \
                 (its effects written in the base sections)"
                    .into(),
                base.name.span(),
            )
        }
        Ok(None) => {}
    }
    let spec = match spark_symbolic::dsl::parse(tokens) {
        Ok(s) => s,
        Err(e) => return fail(e.message, e.span),
    };
    if let Some((message, span)) = module_attribute_error(&spec) {
        return fail(message, span);
    }
    if let Err(e) = spark_symbolic::generate(&spec) {
        return fail(e.message, e.span);
    }
    let analysis = match spark_symbolic::analyze(&spec) {
        Ok(a) => a,
        Err(e) => return fail(e.message, e.span),
    };
    Checked::Good {
        name: spec.name.to_string(),
        n: analysis.n,
        m: analysis.m,
        coordinates: spec.coordinates.iter().map(|c| c.name.clone()).collect(),
        parameters: spec.parameters.iter().map(|p| p.name.name.clone()).collect(),
    }
}

/// How often [`check_dsl`]'s waiting thread checks for signals (Ctrl-C).
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Stack of the thread the check works on: the size of a main thread's, as
/// if the check ran on the calling thread (the parser recurses into nested
/// expressions).
const CHECK_STACK: usize = 8 << 20;

/// Checks DSL text with the macro's own parser and engine. Returns
/// `{"name", "n", "m", "coordinates", "parameters"}` for a good declaration
/// and `{"error", "line", "column"}` for a bad one (the message is the one
/// `nonholonomic_system!` would give as a compile error, or says why the
/// module `spark.compile` builds cannot take an attribute or scenes).
///
/// The check runs on a thread of its own while the calling thread, the GIL
/// released, checks Python's signal handlers every 50 ms: Ctrl-C raises
/// `KeyboardInterrupt` at once, even for a large declaration (the engine's
/// work grows like n², seconds at the largest size it accepts,
/// `spark_symbolic::dsl::MAX_COORDINATES`). An interrupted check cannot be
/// stopped inside the engine; it finishes on its thread and its result is
/// dropped.
#[pyfunction]
fn check_dsl<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyDict>> {
    let text = text.to_owned();
    let (tx, mut rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("spark-check".into())
        .stack_size(CHECK_STACK)
        .spawn(move || {
            // The receiver is gone only when the caller was interrupted.
            let _ = tx.send(check_text(&text));
        })
        .map_err(|e| spark_error(py, format!("could not start the declaration check's thread: {e}")))?;
    let checked = loop {
        // The receiver moves into the wait and back: it is `Send`, not `Sync`.
        let got;
        (rx, got) = py.detach(move || {
            let got = rx.recv_timeout(SIGNAL_POLL);
            (rx, got)
        });
        match got {
            Ok(checked) => break checked,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                return Err(spark_error(py, "the declaration check's thread ended without a result (it panicked)"))
            }
        }
    };
    let d = PyDict::new(py);
    match checked {
        Checked::Bad { message, line, column } => {
            d.set_item("error", message)?;
            d.set_item("line", line)?;
            d.set_item("column", column)?;
        }
        Checked::Good { name, n, m, coordinates, parameters } => {
            d.set_item("name", name)?;
            d.set_item("n", n)?;
            d.set_item("m", m)?;
            d.set_item("coordinates", PyList::new(py, coordinates)?)?;
            d.set_item("parameters", PyList::new(py, parameters)?)?;
        }
    }
    Ok(d)
}

/// The spark source tree this module was built from (the root of the
/// workspace): `spark.compile` builds against its `spark-runtime` and
/// `python/core`.
#[pyfunction]
fn source_dir() -> String {
    let python = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    python.parent().unwrap_or(python).display().to_string()
}

/// The most bytes a record may take (`spark_runtime::record_memory_limit`:
/// 4 GiB, or half the available memory when that is less): the limit of
/// `spark.ray.sweep`'s table, as of every run's record.
#[pyfunction]
fn record_memory_limit() -> u64 {
    spark_runtime::record_memory_limit()
}

/// Bytes of one recorded sample of a registered system with `n` coordinates
/// and `m` constraints, as its record's check counts them
/// (`problems::run::bytes_per_sample`): what `spark` checks a count of
/// output times with before it reads them.
#[pyfunction]
fn record_bytes_per_sample(n: usize, m: usize) -> u64 {
    problems::run::bytes_per_sample(n, m)
}

/// The crate version (part of `spark.compile`'s cache key).
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

/// Every registered system as `(name, description)`, in registry order.
#[pyfunction]
fn catalogue() -> Vec<(&'static str, &'static str)> {
    entries().iter().map(|e| (e.name, e.description)).collect()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SparkError", m.py().get_type::<SparkError>())?;
    m.add("MAX_HALVINGS", spark_runtime::MAX_HALVINGS)?;
    m.add("MAX_ENSEMBLE_THREADS", spark_runtime::MAX_ENSEMBLE_THREADS)?;
    m.add_function(wrap_pyfunction!(names, m)?)?;
    m.add_function(wrap_pyfunction!(catalogue, m)?)?;
    m.add_function(wrap_pyfunction!(system_info_of, m)?)?;
    m.add_function(wrap_pyfunction!(integrate, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(mp7_initial_values, m)?)?;
    m.add_function(wrap_pyfunction!(check_dsl, m)?)?;
    m.add_function(wrap_pyfunction!(source_dir, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    m.add_function(wrap_pyfunction!(record_memory_limit, m)?)?;
    m.add_function(wrap_pyfunction!(record_bytes_per_sample, m)?)?;
    Ok(())
}
