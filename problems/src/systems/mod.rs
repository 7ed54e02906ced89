//! Every system declaration: the inputs of the pipeline. Nothing here
//! imports the rest of `problems`; the catalogue, the runs, the peers and
//! the experiments read these types.
//!
//! - [`paper`]: the paper's §8 systems and more that exercise the DSL, with
//!   the §8.4 ensemble's initial values and the constraint `φ` of its printed
//!   reading (re-exported here: `problems::systems::Skate`);
//! - [`scenes`]: declarations with effects and scenes;
//! - [`stress`]: systems built for `spark stress`;
//! - [`scaling`]: McLachlan–Perlmutter particles of growing size (generated).

pub mod paper;
pub mod scaling;
pub mod scenes;
pub mod stress;

pub use paper::*;
