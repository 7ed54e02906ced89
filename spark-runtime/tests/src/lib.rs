//! The runtime's integration tests, a package of their own so that they
//! compile without optimization (the workspace's `Cargo.toml`,
//! `[profile.release.package.spark-runtime-tests]`): the tests themselves are
//! in `integration/`, one binary; this library holds nothing.
