//! The paper's systems and the `spark` command-line program.
pub mod analysis;
pub mod crosscheck;
/// [`crosscheck`] under the path `workprecision` imports it by.
pub use crosscheck as casadi_export;
pub mod output;
pub mod paper;
pub mod peers;
pub mod plot;
pub mod progress;
pub mod registry;
pub mod scenes;
pub mod section;
pub mod simulate;
pub mod stress;
pub mod systems;
pub mod workprecision;
