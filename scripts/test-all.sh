#!/usr/bin/env bash
# Runs every test of spark: the Rust workspace (unit, property, compile-fail,
# integration tests), the independent CasADi cross-check and the Python
# package (wheel build, clean install, pytest).
# On a fresh machine it installs what it needs itself (local Python venvs
# with the pinned CasADi, see casadi/requirements.txt, and the Python test
# requirements, see python/requirements-test.txt).
set -euo pipefail
cd "$(dirname "$0")/.."

# The Python environments of the last two stages install (from PyPI, when
# they are missing or stale) while cargo compiles; their logs are printed
# when the stages start.
mkdir -p out/logs
bash casadi/run.sh --prepare >out/logs/casadi-venv.log 2>&1 &
casadi_venv=$!
bash python/run.sh --prepare >out/logs/python-venv.log 2>&1 &
python_venv=$!

echo "==> cargo test --workspace"
cargo test --workspace --release

# The README's main-job command builds `problems` without its default
# features; the workspace tests above build it with them.
echo "==> the main job's build (problems --no-default-features)"
cargo check --release -p problems --no-default-features --lib --bin spark

# The environment set up alongside the build, or why it failed.
prepared() {
    local status=0
    wait "$1" || status=$?
    cat "$2"
    return "$status"
}

echo "==> CasADi cross-check (casadi/run.sh)"
prepared "$casadi_venv" out/logs/casadi-venv.log
bash casadi/run.sh

echo "==> Python package (python/run.sh)"
prepared "$python_venv" out/logs/python-venv.log
bash python/run.sh
