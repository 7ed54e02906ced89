//! The runtime-parameter methods of the trait implementation:
//! `parameter_values` and `set_parameter` (which refuses unknown names and
//! non-finite values with a `SystemError` that lists the known names).

use proc_macro2::{Ident, TokenStream};
use quote::quote;

/// `parameter_values` and `set_parameter` over the fields `params`.
pub(super) fn parameter_methods(rt: &TokenStream, params: &[Ident]) -> TokenStream {
    let param_names: Vec<String> = params.iter().map(Ident::to_string).collect();
    let known = param_names.join(", ");
    let unknown = quote! {
        ::core::result::Result::Err(#rt::SystemError::UnknownParameter {
            name: ::std::string::ToString::to_string(name),
            known: ::std::string::ToString::to_string(#known),
        })
    };
    let set_body = if params.is_empty() {
        quote!(let _ = value; #unknown)
    } else {
        let arms = param_names.iter().zip(params).map(|(s, id)| quote!(#s => &mut self.#id,));
        quote! {
            let slot: &mut f64 = match name {
                #(#arms)*
                _ => return #unknown,
            };
            if !value.is_finite() {
                return ::core::result::Result::Err(#rt::SystemError::NonFiniteParameter {
                    name: ::std::string::ToString::to_string(name),
                    value,
                });
            }
            *slot = value;
            ::core::result::Result::Ok(())
        }
    };
    quote! {
        fn parameter_values(&self) -> ::std::vec::Vec<f64> {
            ::std::vec![#(self.#params),*]
        }

        fn set_parameter(&mut self, name: &str, value: f64) -> ::core::result::Result<(), #rt::SystemError> {
            #set_body
        }
    }
}
