#!/usr/bin/env bash
# The CasADi cross-check, alone: sets up casadi/.venv (pinned requirements),
# exports every system's derivatives, SPARK steps and hard cold steps from
# Rust, compares them with CasADi, writes docs/casadi-report.md, and proves
# the check can fail.
#
#   bash casadi/run.sh             # the whole cross-check
#   bash casadi/run.sh --prepare   # only set up casadi/.venv, then exit
#
# Exit status is non-zero on any disagreement or setup problem; nothing is
# ever skipped silently.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=casadi/.venv
REQ=casadi/requirements.txt
OUT=${SPARK_CASADI_OUT:-out/casadi}
PY=$VENV/bin/python

fail() {
    echo "casadi cross-check: ERROR: $*" >&2
    exit 1
}

# --- Python environment ------------------------------------------------------
command -v python3 >/dev/null 2>&1 ||
    fail "python3 not found. Install Python >= 3.11 with its venv module (Debian/Ubuntu: apt-get install python3 python3-venv)."
python3 -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' ||
    fail "python3 is $(python3 --version 2>&1); the pinned numpy needs Python >= 3.11."

want=$(sha256sum "$REQ" | cut -d' ' -f1)
have=$(cat "$VENV/.requirements.sha256" 2>/dev/null || true)
if [[ "$want" != "$have" ]] || ! "$PY" -c 'import casadi, numpy' >/dev/null 2>&1; then
    echo "==> creating $VENV with $(python3 --version) and installing $REQ"
    python3 -m venv --clear "$VENV" ||
        fail "could not create the virtual environment $VENV (Debian/Ubuntu: apt-get install python3-venv)."
    "$PY" -m pip install --disable-pip-version-check --quiet -r "$REQ" ||
        fail "pip could not install $REQ into $VENV (is PyPI reachable?)."
    "$PY" -c 'import casadi, numpy' ||
        fail "casadi/numpy installed but cannot be imported from $VENV."
    echo "$want" >"$VENV/.requirements.sha256"
else
    echo "==> reusing $VENV ($("$PY" -c 'import casadi; print("casadi", casadi.__version__)'))"
fi
[[ "${1:-}" == --prepare ]] && exit 0

# --- translator unit tests ---------------------------------------------------
echo "==> CasADi translator unit tests"
"$PY" -m unittest discover -s casadi/tests -q

# --- export from Rust --------------------------------------------------------
echo "==> exporting derivatives and SPARK steps from Rust"
# Built exactly as `cargo test --workspace --release` builds it (same profile
# and feature set), so after the README's test command this is a no-op rather
# than a second compilation of the workspace. scripts/test-all.sh, which has
# just built it, names it in SPARK_CASADI_EXPORTER instead: this stage then
# never waits for another stage's cargo.
if [[ -n "${SPARK_CASADI_EXPORTER:-}" ]]; then
    exporter=$SPARK_CASADI_EXPORTER
else
    cargo test --workspace --release --no-run --quiet
    target_dir=$(cargo metadata --format-version 1 --no-deps |
        "$PY" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
    exporter="$target_dir/release/spark-casadi-export"
fi
[[ -x "$exporter" ]] || fail "cargo did not produce $exporter."
"$exporter" --out "$OUT/export.json"

# --- the cross-check ---------------------------------------------------------
echo "==> CasADi cross-check"
"$PY" casadi/crosscheck.py --input "$OUT/export.json" --report docs/casadi-report.md --require-steps |
    tee "$OUT/crosscheck.log"
passed=$(sed -n -E 's/^casadi: ([0-9]+) passed, 0 failed$/\1/p' "$OUT/crosscheck.log" | tail -n 1)
[[ -n "$passed" ]] || fail "the cross-check printed no summary line."

# --- the Newton-LU performance peer against spark's steps --------------------
# casadi/peers/newton_lu.py: spark's exported steps taken again by the peer's
# generated C and hand-written LU Newton (agreement to 1e-13, its stop rule).
echo "==> Newton-LU peer against spark's exported steps"
SPARK_CASADI_EXPORT="$OUT/export.json" "$PY" -m unittest discover -s casadi/peers -p 'test_*.py' -q

# --- negative tests: a corrupted value must be caught ------------------------
# A hard cold step (v1 of the first one solved) corrupted the same way must
# fail its comparison with the branch root.
for what in derivative step cold; do
    echo "==> negative test: --perturb $what must fail"
    set +e
    "$PY" casadi/crosscheck.py --input "$OUT/export.json" --perturb "$what" >"$OUT/perturb-$what.log" 2>&1
    rc=$?
    set -e
    if [[ $rc -eq 1 ]]; then
        echo "    caught (exit 1): $(grep -m1 -E '^\[FAIL\]' "$OUT/perturb-$what.log")"
    else
        cat "$OUT/perturb-$what.log" >&2
        fail "the deliberately perturbed $what was NOT caught (exit $rc, expected 1)."
    fi
done
# A corrupted effect (CasADi's f or N changed by 1e-10 on every system that
# declares it) must be caught by the value comparisons of every such system
# and by every one of their steps (v1 moves by about h·1e-10/mass, ~10x the
# tolerance, so a step that does not notice means f or N is not in its equations).
for what in force nonideal; do
    echo "==> negative test: --perturb $what must fail in derivatives and in steps"
    set +e
    "$PY" casadi/crosscheck.py --input "$OUT/export.json" --perturb "$what" >"$OUT/perturb-$what.log" 2>&1
    rc=$?
    set -e
    d=$(grep -c -E '^\[FAIL\] derivatives' "$OUT/perturb-$what.log" || true)
    s=$(grep -c -E '^\[FAIL\] step' "$OUT/perturb-$what.log" || true)
    total_s=$(grep -c -E '^\[(FAIL|ok  )\] step' "$OUT/perturb-$what.log" || true)
    k=$(sed -n -E 's/^corrupted: ([0-9]+) systems declare .*/\1/p' "$OUT/perturb-$what.log")
    if [[ $rc -eq 1 && -n "$k" && $d -eq $k && $s -gt 0 && $s -eq $total_s ]]; then
        echo "    caught (exit 1): all $d system(s) in derivatives, all $s step(s)"
    else
        cat "$OUT/perturb-$what.log" >&2
        fail "the corrupted $what was NOT caught (exit $rc, derivative failures $d of ${k:-?} systems, step failures $s of $total_s)."
    fi
done
# A corrupted event function (CasADi's g_i changed by 1e-10 on every system
# that declares events) must be caught by the value and derivative
# comparisons of every such system.
echo "==> negative test: --perturb event must fail in the derivatives of every system with events"
set +e
"$PY" casadi/crosscheck.py --input "$OUT/export.json" --perturb event >"$OUT/perturb-event.log" 2>&1
rc=$?
set -e
d=$(grep -c -E '^\[FAIL\] derivatives' "$OUT/perturb-event.log" || true)
k=$(sed -n -E 's/^corrupted: ([0-9]+) systems declare .*/\1/p' "$OUT/perturb-event.log")
if [[ $rc -eq 1 && -n "$k" && $d -eq $k ]]; then
    echo "    caught (exit 1): all $d system(s) with events"
else
    cat "$OUT/perturb-event.log" >&2
    fail "the corrupted event function was NOT caught (exit $rc, derivative failures $d of ${k:-?} systems)."
fi
echo "casadi cross-check: every comparison agrees; all six corrupted values were caught"
echo "casadi: $((passed + 6)) passed, 0 failed"
