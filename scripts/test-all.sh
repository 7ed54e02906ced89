#!/usr/bin/env bash
# Runs every test of spark: the Rust workspace (unit, property, compile-fail,
# integration tests), the independent CasADi cross-check and the Python
# package (wheel build, clean install, pytest).
# On a fresh machine it installs what it needs itself (local Python venvs
# with the pinned CasADi, see casadi/requirements.txt, and the Python test
# requirements, see python/requirements-test.txt).
set -euo pipefail
cd "$(dirname "$0")/.."

echo "==> cargo test --workspace"
cargo test --workspace --release

# The README's main-job command builds `problems` without its default
# features; the workspace tests above build it with them.
echo "==> the main job's build (problems --no-default-features)"
cargo check --release -p problems --no-default-features --lib --bin spark

echo "==> CasADi cross-check (casadi/run.sh)"
bash casadi/run.sh

echo "==> Python package (python/run.sh)"
bash python/run.sh
