//! The experiments: each runs systems through [`crate::run`] or the
//! catalogue's dispatch and turns the results into figures, tables and
//! reports with [`crate::report`].
//!
//! - [`paper`]: the paper's Figs. 8.1–8.4 and summary (`spark paper`);
//! - [`section`]: Poincaré sections of ensembles (`spark section`);
//! - [`stress`]: the stress suite (`spark stress`);
//! - [`work_precision`]: work-precision diagrams against the peers, the
//!   scaling study (`spark work-precision`).

pub mod paper;
#[cfg(feature = "full")]
pub mod section;
#[cfg(feature = "full")]
pub mod stress;
#[cfg(feature = "full")]
pub mod work_precision;
