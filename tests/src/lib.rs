//! Workspace-level integration tests of spark live in `tests/tests/`.
//!
//! The README is compiled and run here as a doctest, so its example cannot
//! drift from the API:
#![doc = include_str!("../../README.md")]
