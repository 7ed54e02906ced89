//! Well-formed declarations compile and their generated types work: the
//! counterpart of the compile-fail cases of `compile-fail/tests/ui.rs`, as an
//! ordinary test binary.

mod newcomer;
mod skate;
