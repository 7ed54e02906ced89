//! The `nonholonomic_system!` macro (thin: parse, hand to spark-symbolic, report errors).
use proc_macro::TokenStream;

/// Declares a nonholonomic Lagrangian system (see the crate docs of `spark-runtime`).
#[proc_macro]
pub fn nonholonomic_system(input: TokenStream) -> TokenStream {
    let _ = input;
    quote::quote!(compile_error!("nonholonomic_system! is not implemented yet");).into()
}
