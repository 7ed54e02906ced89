//! The `nonholonomic_system!` procedural macro. Deliberately thin: all parsing,
//! differentiation and code emission lives in the plain library
//! `spark-symbolic`, where it is testable without a compiler in the loop.
use proc_macro::TokenStream;

/// Declares a nonholonomic Lagrangian system (see the crate docs of `spark-runtime`).
#[proc_macro]
pub fn nonholonomic_system(input: TokenStream) -> TokenStream {
    spark_symbolic::expand(input.into()).into()
}
