//! Checks of a whole [`SystemSpec`] that its parts cannot make alone, run
//! before the model is built, on parsed specs and on specs built by hand
//! (tests, tools) alike: code generation itself does not fail.

use crate::spec::{SpecError, SystemSpec};

/// Rejects a user `#[derive(Default)]` (the `Default` is generated from the
/// parameter defaults) and non-finite parameter defaults.
pub fn validate(spec: &SystemSpec) -> Result<(), SpecError> {
    if let Some(d) = spec.user_derives().iter().find(|d| *d == "Default") {
        return Err(SpecError {
            span: d.span(),
            message: "`Default` is generated from the parameter defaults; remove it from `#[derive(...)]`".into(),
        });
    }
    for p in &spec.parameters {
        if !p.default.is_finite() {
            return Err(SpecError {
                span: p.name.span,
                message: format!("parameter `{}` needs a finite default value", p.name.name),
            });
        }
    }
    Ok(())
}
