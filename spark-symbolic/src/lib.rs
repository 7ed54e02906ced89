//! Symbolic engine of spark: the DSL parser, a hash-consed expression graph,
//! exact differentiation, simplification, common-subexpression elimination,
//! structure analysis and Rust code emission.
//!
//! It is an ordinary library (no proc-macro context needed) so that it can be
//! tested, fuzzed and benchmarked on its own; `spark-macros` only calls
//! [`expand`].
#![warn(missing_docs)]

pub mod dsl;
pub mod spec;

pub use spec::{BinOp, Constant, ConstraintSpec, Func, Named, Parameter, SpecError, SrcExpr, SystemSpec};

use proc_macro2::TokenStream;

/// Generates the struct, its `Default`, inherent items and the
/// `NonholonomicSystem` implementation for a parsed declaration.
pub fn generate(spec: &SystemSpec) -> Result<TokenStream, SpecError> {
    Err(SpecError { span: spec.name.span(), message: "spark-symbolic: code generation not implemented yet".into() })
}

/// The whole macro: DSL tokens in, generated items (or a `compile_error!`
/// pointing at the offending token) out. Never panics.
pub fn expand(input: TokenStream) -> TokenStream {
    match dsl::parse(input).and_then(|spec| generate(&spec)) {
        Ok(tokens) => tokens,
        Err(error) => error.to_compile_error(),
    }
}
