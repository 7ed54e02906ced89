//! The static facts of a system that `info()` shows — declaration, sizes,
//! parameters, structure facts and effects — and their Python dict.

use pyo3::prelude::*;
use pyo3::types::PyDict;
use pyo3::types::PyList;
use spark_runtime::{ConstraintForm, Direction, EventSpec, NonholonomicSystem, Structure, SystemSource};

/// The static facts of a system that `info()` shows, without its type.
#[derive(Clone, Debug, PartialEq)]
pub struct SystemFacts {
    /// The declaration: type name, coordinates, parameter names, Lagrangian,
    /// constraints.
    pub source: SystemSource,
    /// Number of coordinates `N`.
    pub n: usize,
    /// Number of constraints `M`.
    pub m: usize,
    /// Default values of `source.parameters`, in the same order.
    pub parameter_values: Vec<f64>,
    /// Structure facts.
    pub structure: Structure,
    /// `CONSTANT_STIFFNESS`: a quadratic potential.
    pub constant_stiffness: bool,
    /// `DIAGONAL_STIFFNESS`: a potential that is a sum of functions of one
    /// coordinate each, not quadratic.
    pub diagonal_stiffness: bool,
    /// External force `f(t, q, v)`.
    pub forcing: bool,
    /// Non-ideal constraint force.
    pub nonideal: bool,
    /// Holonomic constraints imposed at velocity level.
    pub holonomic: bool,
    /// The declared events, in index order.
    pub events: &'static [EventSpec],
}

impl SystemFacts {
    /// The facts of the system type `Sys`.
    pub fn of<Sys, const N: usize, const M: usize>() -> Self
    where
        Sys: NonholonomicSystem<N, M> + Default,
    {
        SystemFacts {
            source: Sys::SOURCE,
            n: N,
            m: M,
            parameter_values: Sys::default().parameter_values(),
            structure: Sys::STRUCTURE,
            constant_stiffness: Sys::CONSTANT_STIFFNESS,
            diagonal_stiffness: Sys::DIAGONAL_STIFFNESS,
            forcing: Sys::HAS_FORCING,
            nonideal: Sys::HAS_NONIDEAL_FORCE,
            holonomic: Sys::HAS_HOLONOMIC,
            events: Sys::EVENTS,
        }
    }
}

/// Static facts of a system type for `info()`: name, `N`, `M`, coordinates,
/// parameters with defaults, structure facts, effects and declared events.
pub fn system_info<'py, Sys, const N: usize, const M: usize>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>>
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    facts_to_py(py, &SystemFacts::of::<Sys, N, M>())
}

/// [`SystemFacts`] as the dict `info()` returns.
pub fn facts_to_py<'py>(py: Python<'py>, facts: &SystemFacts) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let src = &facts.source;
    d.set_item("type_name", src.name)?;
    d.set_item("n", facts.n)?;
    d.set_item("m", facts.m)?;
    d.set_item("coordinates", src.coordinates.to_vec())?;
    let params = PyDict::new(py);
    for (name, value) in src.parameters.iter().zip(&facts.parameter_values) {
        params.set_item(*name, *value)?;
    }
    d.set_item("parameters", params)?;
    let s = facts.structure;
    let st = PyDict::new(py);
    st.set_item("lagrangian_autonomous", s.lagrangian_autonomous)?;
    st.set_item("constraints_autonomous", s.constraints_autonomous)?;
    st.set_item("constant_mass_matrix", s.constant_mass_matrix)?;
    st.set_item("separable", s.separable)?;
    st.set_item("constant_stiffness", facts.constant_stiffness)?;
    st.set_item("diagonal_stiffness", facts.diagonal_stiffness)?;
    st.set_item(
        "constraint_form",
        match s.constraint_form {
            ConstraintForm::None => "none",
            ConstraintForm::Linear => "linear",
            ConstraintForm::Affine => "affine",
            ConstraintForm::Nonlinear => "nonlinear",
        },
    )?;
    d.set_item("structure", st)?;
    let fx = PyDict::new(py);
    fx.set_item("forcing", facts.forcing)?;
    fx.set_item("nonideal", facts.nonideal)?;
    fx.set_item("holonomic", facts.holonomic)?;
    d.set_item("effects", fx)?;
    d.set_item("lagrangian", src.lagrangian)?;
    d.set_item("constraints", src.constraints.to_vec())?;
    let events = PyList::empty(py);
    for e in facts.events {
        let row = PyDict::new(py);
        row.set_item("name", e.name)?;
        row.set_item(
            "direction",
            match e.direction {
                Direction::Rising => "rising",
                Direction::Falling => "falling",
                Direction::Both => "crossing",
            },
        )?;
        row.set_item("terminal", e.terminal)?;
        row.set_item("function", e.source)?;
        events.append(row)?;
    }
    d.set_item("events", events)?;
    Ok(d)
}
