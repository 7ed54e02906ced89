//! Holds no code: the package exists for its compile-fail tests
//! (`tests/ui.rs`), which trybuild checks with this package's dependencies,
//! the macro alone.
