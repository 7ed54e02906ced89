//! Finding a `nonholonomic_system!` invocation in a Rust source file, so that
//! tools (the `expand` example, snapshot tests, compile-cost measurements)
//! work on the declaration as checked in instead of a copy of its text.

use proc_macro2::{TokenStream, TokenTree};
use std::fmt;

/// Why [`find_declaration`] found nothing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LocateError {
    /// The file is not valid Rust.
    Syntax(String),
    /// No invocation declares the requested struct.
    NotFound {
        /// The struct asked for.
        name: String,
        /// The structs the file's invocations do declare.
        available: Vec<String>,
    },
}

impl fmt::Display for LocateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LocateError::Syntax(e) => write!(f, "the file is not valid Rust: {e}"),
            LocateError::NotFound { name, available } if available.is_empty() => {
                write!(f, "no `nonholonomic_system!` invocation declares `{name}`; the file has none")
            }
            LocateError::NotFound { name, available } => write!(
                f,
                "no `nonholonomic_system!` invocation declares `{name}`; the file declares: {}",
                available.join(", ")
            ),
        }
    }
}

impl std::error::Error for LocateError {}

/// The name a declaration's tokens give after `struct`, if any.
fn declared_name(tokens: &TokenStream) -> Option<String> {
    let mut after_struct = false;
    for tt in tokens.clone() {
        match tt {
            TokenTree::Ident(id) if after_struct => return Some(id.to_string()),
            TokenTree::Ident(id) if id == "struct" => after_struct = true,
            _ => after_struct = false,
        }
    }
    None
}

fn collect(items: &[syn::Item], out: &mut Vec<(String, TokenStream)>) {
    for item in items {
        match item {
            syn::Item::Macro(m) => {
                let is_ours = m.mac.path.segments.last().is_some_and(|s| s.ident == "nonholonomic_system");
                if is_ours {
                    if let Some(name) = declared_name(&m.mac.tokens) {
                        out.push((name, m.mac.tokens.clone()));
                    }
                }
            }
            syn::Item::Mod(m) => {
                if let Some((_, items)) = &m.content {
                    collect(items, out);
                }
            }
            _ => {}
        }
    }
}

/// The tokens inside the `nonholonomic_system! { … }` invocation of `source`
/// (a whole Rust file, searched including inline modules) that declares
/// `struct name`.
pub fn find_declaration(source: &str, name: &str) -> Result<TokenStream, LocateError> {
    let file = syn::parse_file(source).map_err(|e| LocateError::Syntax(e.to_string()))?;
    let mut found = Vec::new();
    collect(&file.items, &mut found);
    match found.iter().position(|(n, _)| n == name) {
        Some(i) => Ok(found.swap_remove(i).1),
        None => {
            Err(LocateError::NotFound { name: name.into(), available: found.into_iter().map(|(n, _)| n).collect() })
        }
    }
}
