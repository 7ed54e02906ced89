//! The workspace's integration tests, in one test binary: `problems` and its
//! monomorphized systems are linked once instead of once per file, and
//! generic code the files share is compiled once. `runtime_alloc` is its own
//! binary because it installs a counting global allocator.

mod large_systems;
mod parameter_terms;
mod runtime_generated;
mod scenes_systems;
mod stress_cases;
mod stress_fuzz;
