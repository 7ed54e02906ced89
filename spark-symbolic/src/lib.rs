//! Symbolic engine of spark: a hash-consed expression graph, exact
//! differentiation, simplification, common-subexpression elimination,
//! structure analysis and Rust code emission.
//!
//! It is an ordinary library (no proc-macro context needed) so that it can be
//! tested, fuzzed and benchmarked on its own; `spark-macros` is a thin parser
//! in front of it.
#![warn(missing_docs)]

pub mod spec;

pub use spec::{BinOp, Constant, ConstraintSpec, Func, Named, Parameter, SpecError, SrcExpr, SystemSpec};

/// Generates the struct, its `Default`, inherent items and the
/// `NonholonomicSystem` implementation for a parsed declaration.
pub fn generate(spec: &SystemSpec) -> Result<proc_macro2::TokenStream, SpecError> {
    Err(SpecError { span: spec.name.span(), message: "spark-symbolic: code generation not implemented yet".into() })
}
