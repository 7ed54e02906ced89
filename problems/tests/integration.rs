//! Every integration test of `problems`, in one test binary: the crate's
//! monomorphized code is linked once instead of once per file, and generic
//! code the tests share is compiled once.

mod catalog;
mod cli_files;
mod crosscheck;
mod ensemble_lanes;
mod lane_values;
mod output_files;
mod paper_short;
mod peers;
mod report;
mod run_api;
mod run_plans;
mod scene_effects;
mod section;
mod systems;
mod work_precision;
mod work_precision_strategies;
