//! The paper's four systems as the catalogue declares them, and the initial
//! values the examples start them from, shared by the profiling examples
//! (`step_profile`, `driver_cost`, `lanes_profile`, `extrapolation_degree`)
//! and the integration test `end_point_values`. Each uses some of them.
//!
//! The declarations are `problems/src/systems/paper.rs`, included by path:
//! the runtime cannot depend on `problems` (which depends on the runtime),
//! that file imports nothing of `problems`, and so the examples time the
//! code generated from the very text the `spark` binary and its catalogue
//! compile.
#![allow(dead_code, unused_imports)]

use spark_runtime::{State, Vector};

#[path = "../../../problems/src/systems/paper.rs"]
mod catalogue;
pub use catalogue::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};

/// The particle's initial values (§8.1).
pub fn particle_start() -> State<3> {
    State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0))
}

/// The skate's initial values (§8.2).
pub fn skate_start() -> State<3> {
    State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0))
}

/// The mobile robot's initial values (§8.3).
pub fn robot_start() -> State<4> {
    State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0))
}

/// The McLachlan–Perlmutter particles' state `j = 5` of Fig. 8.4.
pub fn mp7_start() -> State<7> {
    let (q, v) = catalogue::mp7_initial_values(5, 9);
    State::new(0.0, Vector::<7>::from_column_slice(&q), Vector::<7>::from_column_slice(&v))
}
