//! `spark._native`: the extension module behind the `spark` Python package.
//!
//! It exposes the registry of the `problems` crate (every system `spark list`
//! shows, by name), one integration run and ensembles of runs for those
//! systems through the same generic code as the modules `spark.compile`
//! builds (`spark-python-core`), and the DSL check that `spark.compile` runs
//! before it calls cargo.

use problems::catalog::{
    entries, lookup, visit_system, Dispatch, StageVisitor, SystemEntry, SystemVisitor, MAX_DISPATCH_STAGES,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use spark_python_core::{
    columns_to_py, detached, ensemble_to_py, read_ensemble, read_request, spark_error, system_info, Columns,
    EnsembleRequest, Failure, IntegrateRequest,
};
use spark_runtime::Method;
use std::marker::PhantomData;

pyo3::create_exception!(
    _native,
    SparkError,
    pyo3::exceptions::PyException,
    "An error of spark: a bad argument, an inconsistent initial state, a failed step, a bad declaration. \
     The message is the Rust library's and says what to change."
);

fn entry(py: Python<'_>, name: &str) -> PyResult<&'static SystemEntry> {
    lookup(name).map_err(|e| spark_error(py, e.to_string()))
}

/// What one registry visit does: integrate, or integrate an ensemble.
enum Work<'a> {
    Integrate(&'a IntegrateRequest),
    Ensemble(&'a EnsembleRequest),
}

enum Done {
    One(Columns),
    Many(Vec<Columns>),
}

struct ForSystem<'a>(Work<'a>);

impl SystemVisitor for ForSystem<'_> {
    type Output = Result<Done, Failure>;
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        _: &'static SystemEntry,
    ) -> Self::Output {
        let stages = match &self.0 {
            Work::Integrate(r) => r.stages,
            Work::Ensemble(r) => r.run.stages,
        };
        Sys::with_stages(stages, ForStages::<Sys>(self.0, PhantomData)).map_err(|e| e.to_string())?
    }
}

struct ForStages<'a, Sys>(Work<'a>, PhantomData<Sys>);

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for ForStages<'_, Sys> {
    type Output = Result<Done, Failure>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        match self.0 {
            Work::Integrate(r) => spark_python_core::integrate::<Sys, N, M, S, D>(r).map(Done::One),
            Work::Ensemble(r) => spark_python_core::ensemble::<Sys, N, M, S, D>(r).map(Done::Many),
        }
    }
}

/// Every registered system name, in registry order (the paper's first).
#[pyfunction]
fn names() -> Vec<&'static str> {
    problems::catalog::names()
}

/// Facts about the registered system `name`: description, `N`, `M`,
/// coordinates, parameters with defaults, structure facts, effects,
/// operation counts, default initial state, step and final time.
#[pyfunction]
fn system_info_of<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, name)?;
    struct Info<'py>(Python<'py>);
    impl<'py> SystemVisitor for Info<'py> {
        type Output = PyResult<Bound<'py, PyDict>>;
        fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
            self,
            _: &'static SystemEntry,
        ) -> Self::Output {
            system_info::<Sys, N, M>(self.0)
        }
    }
    let d = visit_system(e.kind, Info(py))?;
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
#[pyfunction]
fn integrate<'py>(py: Python<'py>, name: &str, request: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, name)?;
    let r = read_request(py, request)?;
    let done = detached(py, || visit_system(e.kind, ForSystem(Work::Integrate(&r))))?;
    match done {
        Done::One(c) => columns_to_py(py, c),
        Done::Many(_) => Err(spark_error(py, "internal: integrate returned an ensemble")),
    }
}

/// An ensemble of runs of the registered system `name` (see `spark.ensemble`).
#[pyfunction]
fn ensemble<'py>(py: Python<'py>, name: &str, request: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let e = entry(py, name)?;
    let r = read_ensemble(py, request)?;
    let done = detached(py, || visit_system(e.kind, ForSystem(Work::Ensemble(&r))))?;
    match done {
        Done::Many(c) => ensemble_to_py(py, c),
        Done::One(_) => Err(spark_error(py, "internal: ensemble returned one run")),
    }
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

/// Checks DSL text with the macro's own parser and engine. Returns
/// `{"name", "n", "m", "coordinates", "parameters"}` for a good declaration
/// and `{"error", "line", "column"}` for a bad one (the message is the one
/// `nonholonomic_system!` would give as a compile error).
#[pyfunction]
fn check_dsl<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let fail = |message: String, span: proc_macro2::Span| -> PyResult<Bound<'py, PyDict>> {
        let (line, column) = position(span);
        d.set_item("error", message)?;
        d.set_item("line", line)?;
        d.set_item("column", column)?;
        Ok(d.clone())
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
    if let Err(e) = spark_symbolic::generate(&spec) {
        return fail(e.message, e.span);
    }
    let analysis = match spark_symbolic::analyze(&spec) {
        Ok(a) => a,
        Err(e) => return fail(e.message, e.span),
    };
    d.set_item("name", spec.name.to_string())?;
    d.set_item("n", analysis.n)?;
    d.set_item("m", analysis.m)?;
    d.set_item("coordinates", PyList::new(py, spec.coordinates.iter().map(|c| c.name.clone()))?)?;
    d.set_item("parameters", PyList::new(py, spec.parameters.iter().map(|p| p.name.name.clone()))?)?;
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
    Ok(())
}
