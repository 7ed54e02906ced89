//! Well-formed declarations compile and their generated types work: the
//! counterpart of the compile-fail cases of `tests/ui.rs`, as an ordinary test
//! binary (so that trybuild, left with compile-fail cases only, checks them
//! with `cargo check` and never builds the runtime's dependencies in full).

mod newcomer;
mod skate;
