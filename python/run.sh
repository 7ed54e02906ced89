#!/usr/bin/env bash
# The Python package's tests, alone: sets up python/.venv (pinned
# requirements), builds the wheel with maturin (reusing the workspace's
# target directory, so the workspace's compiled crates are not built again),
# installs it into a clean venv and imports it there, installs it into
# python/.venv and runs pytest (registry against the Rust CLI, ensembles,
# spark.compile, the Ray sweep on a local Ray instance).
#
#   bash python/run.sh             # the whole test
#   bash python/run.sh --prepare   # only set up python/.venv, then exit
#
# Prints the time of each stage. Exit status is non-zero on any failure.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=python/.venv
REQ=python/requirements-test.txt
PY=$VENV/bin/python
OUT=${SPARK_PYTHON_OUT:-out/python}

fail() {
    echo "python tests: ERROR: $*" >&2
    exit 1
}
stamp() { date +%s.%N; }
took() { awk -v a="$1" -v b="$(stamp)" 'BEGIN { printf "%.1f s", b - a }'; }

command -v python3 >/dev/null 2>&1 ||
    fail "python3 not found. Install Python >= 3.11 with its venv module (Debian/Ubuntu: apt-get install python3 python3-venv)."
python3 -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' ||
    fail "python3 is $(python3 --version 2>&1); the package needs Python >= 3.11."

# --- test environment --------------------------------------------------------
t=$(stamp)
want=$(sha256sum "$REQ" | cut -d' ' -f1)
have=$(cat "$VENV/.requirements.sha256" 2>/dev/null || true)
if [[ "$want" != "$have" ]] || ! "$PY" -c 'import numpy, pytest, ray, pyarrow' >/dev/null 2>&1; then
    echo "==> creating $VENV with $(python3 --version) and installing $REQ"
    python3 -m venv --clear "$VENV" || fail "could not create $VENV (Debian/Ubuntu: apt-get install python3-venv)."
    "$PY" -m pip install --disable-pip-version-check --quiet -r "$REQ" ||
        fail "pip could not install $REQ into $VENV (is PyPI reachable?)."
    echo "$want" >"$VENV/.requirements.sha256"
else
    echo "==> reusing $VENV"
fi
echo "    test environment: $(took "$t")"
[[ "${1:-}" == --prepare ]] && exit 0

# --- wheel -------------------------------------------------------------------
target_dir=$(cargo metadata --format-version 1 --no-deps |
    "$PY" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
rm -rf "$OUT/wheels"
mkdir -p "$OUT/wheels"
echo "==> building the wheel (maturin, release, CARGO_TARGET_DIR=$target_dir)"
t=$(stamp)
# `-i "$PY"`: PyO3's build then sees the interpreter pytest runs, the one
# `spark.compile` names to its cargo builds in the same target directory, so
# neither build invalidates PyO3 for the other.
CARGO_TARGET_DIR="$target_dir" "$VENV/bin/maturin" build --release --quiet --compatibility linux \
    -i "$PY" -m python/Cargo.toml -o "$OUT/wheels" || fail "maturin could not build the wheel."
wheel=$(ls "$OUT"/wheels/*.whl)
echo "    wheel build: $(took "$t") -> $wheel"

# --- install into a clean venv -------------------------------------------------
echo "==> installing the wheel into a clean venv"
t=$(stamp)
python3 -m venv --clear "$OUT/clean-venv"
"$OUT/clean-venv/bin/pip" install --disable-pip-version-check --quiet "$wheel" ||
    fail "pip could not install $wheel into a clean venv."
"$OUT/clean-venv/bin/python" -c '
import spark
r = spark.integrate("skate", "lobatto-iiia-b", 3, 0.1, 100)
assert r.q.shape == (101, 3) and r.constraint.max() < 1e-12, r
print("    clean venv: import spark and a skate run work;", len(spark.systems()), "systems")
' || fail "the wheel does not work in a clean venv."
echo "    clean install and import: $(took "$t")"

# --- pytest ------------------------------------------------------------------
"$PY" -m pip install --disable-pip-version-check --quiet --force-reinstall --no-deps "$wheel"
echo "==> pytest python/tests"
t=$(stamp)
# --durations: the ten slowest tests close the log, so that a run that got
# slower says where (the spark.compile builds are most of the stage).
CARGO_TARGET_DIR="$target_dir" SPARK_CARGO_TARGET_DIR="$target_dir" \
    "$PY" -m pytest python/tests -q -p no:cacheprovider --durations=10 || fail "pytest failed."
echo "    pytest: $(took "$t")"
