//! The struct item: the parameter struct with its derives, its `Default`
//! from the parameter defaults, and the inherent `N`, `M`, `new` and the
//! helper functions that split-off method bodies call.

use proc_macro2::{Ident, Literal, TokenStream};
use quote::quote;

use crate::spec::SystemSpec;

/// The struct, its `Default` and its inherent items. `params` are the
/// field names, `helpers` the split-off body functions.
pub(super) fn struct_items(
    spec: &SystemSpec,
    params: &[Ident],
    n: &Literal,
    m: &Literal,
    helpers: &[TokenStream],
) -> TokenStream {
    let (attrs, vis, name) = (&spec.attrs, &spec.vis, &spec.name);
    let derived = spec.user_derives();
    let derives: Vec<Ident> = ["Clone", "Copy", "Debug", "PartialEq"]
        .iter()
        .filter(|t| !derived.iter().any(|d| d == *t))
        .map(|t| Ident::new(t, proc_macro2::Span::call_site()))
        .collect();
    let fields = spec.parameters.iter().zip(params).map(|(p, id)| {
        let doc = format!("Runtime parameter `{}` (default `{:?}`).", p.name.name, p.default);
        quote!(#[doc = #doc] pub #id: f64,)
    });
    let defaults = spec.parameters.iter().zip(params).map(|(p, id)| {
        let d = Literal::f64_unsuffixed(p.default.abs());
        if p.default < 0.0 {
            quote!(#id: -#d,)
        } else {
            quote!(#id: #d,)
        }
    });
    let doc_n = "Number of generalized coordinates.";
    let doc_m = "Number of constraints.";
    quote! {
        #attrs
        #[derive(#(#derives),*)]
        #vis struct #name {
            #(#fields)*
        }

        #[allow(clippy::all)]
        impl ::core::default::Default for #name {
            fn default() -> Self {
                Self { #(#defaults)* }
            }
        }

        #[allow(dead_code, unused_variables, unused_mut, clippy::all)]
        impl #name {
            #[doc = #doc_n]
            pub const N: usize = #n;
            #[doc = #doc_m]
            pub const M: usize = #m;
            /// The system with its default parameters.
            pub fn new() -> Self {
                <Self as ::core::default::Default>::default()
            }
            #(#helpers)*
        }
    }
}
