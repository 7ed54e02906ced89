//! The runtime's integration tests, in one test binary (the steppers the
//! files share are compiled and linked once): whole runs through the public
//! API on systems declared with `nonholonomic_system!` here or in
//! `spark_runtime::fixtures`. The tests that need the catalogue of
//! `problems` live in the workspace's `tests/` crate.
//!
//! `driver_robustness` installs the binary's global allocator, a thin
//! wrapper over the system allocator that records each thread's largest
//! request; the other tests do not observe it.

mod adaptive_new_systems;
mod client_shapes;
mod dense_output;
mod driver_robustness;
mod end_point_values;
mod events;
mod hand_built_tableaux;
mod initial_domain;
mod landing;
mod lanes_newcomer;
mod newcomer_systems;
mod newcomer_unusual_systems;
mod orders;
mod paper;
mod parameter_edge_systems;
mod plan;
mod small_scales;
mod step_start;
mod stop_requests;
mod strong_velocity_forces;
