//! Compile-fail tests of `nonholonomic_system!`: every malformed declaration is
//! a `compile_error!` at the offending token with a message that says what to
//! write instead (checked-in `.stderr` files). Well-formed declarations are
//! compiled and run by `tests/declarations/`.
//!
//! After an intended message change, regenerate the `.stderr` files with
//! `TRYBUILD=overwrite cargo test -p spark-macros --test ui` and review the diff.

#[test]
fn ui() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/fail/*.rs");
}
