//! What the experiments and the command line turn runs into: figures
//! ([`plot`], with the dots of a scatter plot's SVG as paths,
//! [`svg_dots`]), output folders and their files ([`files`]), statistics
//! ([`stats`]), number formats ([`format`](mod@format)), the thread-CPU clock
//! ([`clock`]) and progress bars ([`progress`]). Nothing here imports
//! another wing of the crate: runs, experiments and the command line use it.

pub mod clock;
pub mod files;
pub mod format;
pub mod plot;
pub mod progress;
pub mod stats;
pub mod svg_dots;
