//! The DSL parser: `nonholonomic_system!` tokens → [`SystemSpec`].
use crate::spec::{SpecError, SystemSpec};
use proc_macro2::TokenStream;

/// Parses the body of a `nonholonomic_system!` invocation.
pub fn parse(input: TokenStream) -> Result<SystemSpec, SpecError> {
    let _ = input;
    Err(SpecError { span: proc_macro2::Span::call_site(), message: "DSL parser not implemented yet".into() })
}
