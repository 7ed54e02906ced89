#!/usr/bin/env bash
# Runs every test of spark: the Rust workspace (unit, property, compile-fail,
# integration tests), the independent CasADi cross-check and the Python
# package (wheel build, clean install, pytest).
# On a fresh machine it installs what it needs itself (local Python venvs
# with the pinned CasADi, see casadi/requirements.txt, and the Python test
# requirements, see python/requirements-test.txt).
#
# The workspace is compiled once, first; then three independent stages run
# side by side, each into its own log under out/logs, printed whole when the
# stage ends:
#   rust    the workspace's tests;
#   casadi  the CasADi cross-check (casadi/run.sh), then a check that the
#           README main job's target compiles;
#   python  the Python package (python/run.sh).
# Cargo holds its build lock only while it compiles, so a stage's tests
# never wait for another stage's cargo; the stages' cargo calls after the
# first build find the workspace compiled. The exit status is non-zero when
# any stage fails, and every stage runs to its end either way.
set -euo pipefail
cd "$(dirname "$0")/.."

# Every cargo call of the test command (the stages' own, maturin's and the
# builds pytest asks for inherit it) compiles without thin-local LTO (a third
# of the `problems` crate's compile time) and at opt-level 2 (8 % less CPU
# time for that crate than opt-level 3). What the tests check does not
# depend on either: neither inlining nor LLVM's optimization level changes a
# floating-point result in Rust. The main job keeps opt-level 3 and
# thin-local LTO: its steps are 1.2-2.8x faster with the LTO
# (docs/performance/README.md, "Build profile").
# The runtime's integration tests (package spark-runtime-tests) compile at
# opt-level 0 whatever these say: the workspace's Cargo.toml overrides it.
export CARGO_PROFILE_RELEASE_LTO=off
export CARGO_PROFILE_RELEASE_OPT_LEVEL=2
# The property tests (the fuzz harness among them) draw their cases from a
# fixed seed here, so every run of this command meets the same cases and
# takes the same time (docs/stress/README.md, "Fuzz harness"). Set
# PROPTEST_RNG_SEED to draw other cases.
export PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-2}"

stamp() { date +%s.%N; }
took() { awk -v a="$1" -v b="$(stamp)" 'BEGIN { printf "%.0f s", b - a }'; }
cargo_target_dir() {
    cargo metadata --format-version 1 --no-deps | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])'
}
start=$(stamp)

# The Python environments install (from PyPI, when they are missing or
# stale) while cargo compiles.
mkdir -p out/logs
bash casadi/run.sh --prepare >out/logs/casadi-venv.log 2>&1 &
casadi_venv=$!
bash python/run.sh --prepare >out/logs/python-venv.log 2>&1 &
python_venv=$!

echo "==> cargo test --workspace --no-run (the build every stage uses)"
t=$(stamp)
cargo test --workspace --release --no-run
echo "    build: $(took "$t")"

# The environments set up alongside the build, or why they failed.
prepared() {
    local status=0
    wait "$1" || status=$?
    cat "$2"
    return "$status"
}
prepared "$casadi_venv" out/logs/casadi-venv.log
prepared "$python_venv" out/logs/python-venv.log

rust_stage() {
    echo "==> cargo test --workspace"
    cargo test --workspace --release
}

# The CasADi cross-check runs the exporter the build above made (no cargo
# call, so it starts at once); then a check that the README main job's
# target compiles: `problems` without its default features (the
# workspace's tests build it with them). A check, not the main job's
# release build: on a clean checkout (CI) that build is five minutes of
# thin-local LTO on the cores the Python stage needs, a check half of that.
# It checks into a target directory of its own, so that it never
# holds the build lock of the one the Python stage's cargo calls (the
# wheel, `spark.compile`'s builds in its tests) share.
casadi_stage() {
    echo "==> CasADi cross-check (casadi/run.sh)"
    SPARK_CASADI_EXPORTER="$(cargo_target_dir)/release/spark-casadi-export" bash casadi/run.sh
    echo "==> the main job's target compiles (cargo check -p problems --no-default-features --bin spark)"
    cargo check --release -p problems --no-default-features --bin spark --target-dir "$(cargo_target_dir)/main-job-check"
}

python_stage() {
    echo "==> Python package (python/run.sh)"
    bash python/run.sh
}

declare -A pid began
for stage in rust casadi python; do
    began[$stage]=$(stamp)
    "${stage}_stage" >"out/logs/$stage.log" 2>&1 &
    pid[$stage]=$!
done
echo "==> stages rust, casadi and python running side by side (logs in out/logs)"

# Print each stage's log as it ends, in the order they end.
failed=()
remaining=(rust casadi python)
while ((${#remaining[@]} > 0)); do
    running=()
    for stage in "${remaining[@]}"; do running+=("${pid[$stage]}"); done
    wait -n "${running[@]}" || true
    still=()
    for stage in "${remaining[@]}"; do
        if kill -0 "${pid[$stage]}" 2>/dev/null; then
            still+=("$stage")
            continue
        fi
        status=0
        wait "${pid[$stage]}" || status=$?
        echo
        echo "==================== stage $stage: exit $status after $(took "${began[$stage]}") ===================="
        cat "out/logs/$stage.log"
        ((status == 0)) || failed+=("$stage")
    done
    remaining=("${still[@]}")
done

echo
echo "test-all: $(took "$start") in all"
if ((${#failed[@]} > 0)); then
    echo "test-all: FAILED stage(s): ${failed[*]} (logs in out/logs)" >&2
    exit 1
fi
echo "test-all: every stage passed"
