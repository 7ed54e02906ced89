#!/usr/bin/env bash
# Runs every test of spark: the Rust workspace (unit, property, compile-fail,
# integration tests) and the independent CasADi cross-check.
# On a fresh machine it installs what it needs itself (a local Python venv
# with the pinned CasADi, see casadi/requirements.txt).
set -euo pipefail
cd "$(dirname "$0")/.."

echo "==> cargo test --workspace"
cargo test --workspace --release

echo "==> CasADi cross-check (casadi/run.sh)"
bash casadi/run.sh
