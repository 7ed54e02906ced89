//! The paper's systems and the `spark` command-line program.
pub mod casadi_export;
pub mod plot;
pub mod analysis;
pub mod progress;
pub mod systems;
pub mod simulate;
pub mod output;
pub mod paper;
pub mod peers;
pub mod workprecision;
