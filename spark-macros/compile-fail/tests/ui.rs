//! Compile-fail tests of `nonholonomic_system!`: every malformed declaration is
//! a `compile_error!` at the offending token with a message that says what to
//! write instead (checked-in `.stderr` files). The cases name the macro as
//! `spark_macros::nonholonomic_system` (users reach it through
//! `spark_runtime`, which re-exports it): trybuild checks them with every
//! dependency of this package, and it depends on the macro alone. Well-formed
//! declarations are compiled and run by `spark-macros/tests/declarations/`.
//!
//! After an intended message change, regenerate the `.stderr` files with
//! `TRYBUILD=overwrite cargo test -p spark-macros-compile-fail --test ui` and review the diff.

#[test]
fn ui() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/fail/*.rs");
}
