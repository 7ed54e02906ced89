#!/usr/bin/env bash
# Compile cost of `nonholonomic_system!` : McLachlan and
# Perlmutter's particles for n = 7, 51, 201 are declared in a scratch crate
# outside the repository that depends on spark-runtime like any user crate
# (default cargo profiles), which is built with and without the declaration.
#
#   scripts/compile-cost.sh                 # writes docs/compile-cost.md
#   SIZES="7 51" REPS=2 scripts/compile-cost.sh
#
# Environment: SIZES (default "7 51 201"), REPS (repetitions, the minimum is
# kept; default 3), SCRATCH (scratch crate, default /tmp/spark-compile-cost),
# OUT (report, default docs/compile-cost.md), CARGO_TARGET_DIR (for the repo's
# helper example only; the scratch crate has its own target dir).
#
# Measured per n (each the minimum over REPS runs, wall clock):
#   expand    parse + generate in-process (examples/compile_cost.rs): the
#             macro's own work, in an optimized build and at opt-level 0 (how
#             cargo builds proc macros by default)
#   check     `cargo check` of the scratch crate with the system minus without:
#             macro expansion as rustc runs it (proc macros are built with
#             cargo's default build-override opt-level 0) + type checking
#   dev       `cargo build` (debug) with minus without: expansion + all of rustc
#   release   `cargo build --release` with minus without
# plus the operation counts of the generated code and of the source expressions.
set -euo pipefail

REPO=$(cd "$(dirname "$0")/.." && pwd)
SIZES=${SIZES:-"7 51 201"}
REPS=${REPS:-3}
SCRATCH=${SCRATCH:-/tmp/spark-compile-cost}
OUT=${OUT:-$REPO/docs/compile-cost.md}

log() { printf '%s\n' "$*" >&2; }

# "wall cpu" seconds of one command (cpu = user + sys of it and its children,
# which is far less sensitive than wall clock to other jobs on a shared
# machine), its output discarded unless it fails.
seconds() {
    local TIMEFORMAT="%R %U %S" t
    if ! t=$( { time "$@" >"$SCRATCH/last.log" 2>&1; } 2>&1 ); then
        log "command failed: $*"
        cat "$SCRATCH/last.log" >&2
        exit 1
    fi
    awk '{ printf "%.2f %.2f", $1, $2 + $3 }' <<<"$t"
}

# Minimum over REPS rebuilds of the scratch crate (only it is rebuilt), as
# "wall cpu" (each minimized separately).
min_time() {
    local bw="" bc="" t
    for _ in $(seq "$REPS"); do
        touch "$SCRATCH/src/lib.rs"
        t=$(seconds "$@")
        bw=$(awk -v a="$bw" -v b="${t% *}" 'BEGIN { print (a == "" || b < a) ? b : a }')
        bc=$(awk -v a="$bc" -v b="${t#* }" 'BEGIN { print (a == "" || b < a) ? b : a }')
    done
    printf '%s %s' "$bw" "$bc"
}

log "building the helper example (release, and opt-level 0)"
(cd "$REPO" && cargo build -q --release -p spark-symbolic --example compile_cost)
(cd "$REPO" && cargo build -q -p spark-symbolic --example compile_cost --profile expand0 \
    --config 'profile.expand0.inherits="dev"' --config 'profile.expand0.opt-level=0' \
    --config 'profile.expand0.package."*".opt-level=0')
HELPER="${CARGO_TARGET_DIR:-$REPO/target}/release/examples/compile_cost"
HELPER0="${CARGO_TARGET_DIR:-$REPO/target}/expand0/examples/compile_cost"

mkdir -p "$SCRATCH/src"
cat >"$SCRATCH/Cargo.toml" <<TOML
[package]
name = "spark-compile-cost"
version = "0.0.0"
edition = "2021"
publish = false

[dependencies]
spark-runtime = { path = "$REPO/spark-runtime" }

[workspace]
TOML
cp "$REPO/Cargo.lock" "$SCRATCH/Cargo.lock"

baseline() {
    cat >"$SCRATCH/src/lib.rs" <<'RS'
//! Scratch crate for compile-cost measurements.
#![allow(dead_code, unused_imports)]
use spark_runtime::nonholonomic_system;

pub fn marker() -> usize {
    0
}
RS
}

with_system() {
    baseline
    "$HELPER" dsl "$1" >>"$SCRATCH/src/lib.rs"
}

field() { tr ' ' '\n' <<<"$1" | awk -F= -v k="$2" '$1 == k { print $2 }'; }

declare -A RESULT
cd "$SCRATCH"
log "warming up dependencies (dev and release)"
baseline
cargo build -q && cargo build -q --release && cargo check -q
pair() { tr ' ' ',' <<<"$1"; }
base_check=$(pair "$(min_time cargo check -q)")
base_dev=$(pair "$(min_time cargo build -q)")
base_rel=$(pair "$(min_time cargo build -q --release)")
log "baseline (wall,cpu s): check $base_check, dev $base_dev, release $base_rel"

for n in $SIZES; do
    line=$("$HELPER" expand "$n" 5)
    line0=$("$HELPER0" expand "$n" 3)
    with_system "$n"
    chk=$(pair "$(min_time cargo check -q)")
    dev=$(pair "$(min_time cargo build -q)")
    rel=$(pair "$(min_time cargo build -q --release)")
    RESULT[$n]="$line expand0_ms=$(field "$line0" expand_ms) expand0_cpu_ms=$(field "$line0" expand_cpu_ms) check=$chk dev=$dev release=$rel"
    log "${RESULT[$n]}"
done
baseline

# "a,b" minus "c,d" -> "a-c (b-d)"
delta() {
    awk -v x="$1" -v y="$2" 'BEGIN { split(x, a, ","); split(y, b, ","); printf "%.2f (%.2f)", a[1] - b[1], a[2] - b[2] }'
}
show() { awk -v x="$1" 'BEGIN { split(x, a, ","); printf "%s s (%s s)", a[1], a[2] }'; }

{
    echo "# Compile cost of \`nonholonomic_system!\`"
    echo
    echo "McLachlan and Perlmutter's particles (paper §8.4) for \`n = 2m + 1\`, one linear constraint,"
    echo "declared in a scratch crate outside the repository that depends on \`spark-runtime\` with"
    echo "cargo's default profiles. Generated and measured by \`scripts/compile-cost.sh\`; rerun it"
    echo "to refresh this file."
    echo
    echo "Seconds added by the declaration: wall clock, and in parentheses CPU (user + sys of cargo,"
    echo "rustc and the macro)."
    echo
    echo "| n | \`cargo check\` | \`cargo build\` (debug) | \`cargo build --release\` |"
    echo "|---|---|---|---|"
    for n in $SIZES; do
        r=${RESULT[$n]}
        printf '| %s | %s | %s | %s |\n' "$n" "$(delta "$(field "$r" check)" "$base_check")" \
            "$(delta "$(field "$r" dev)" "$base_dev")" "$(delta "$(field "$r" release)" "$base_rel")"
    done
    echo
    echo "The macro's own work (\`dsl::parse\` + \`generate\`, in-process, milliseconds wall (mean CPU)) and the"
    echo "size of what it reads and writes:"
    echo
    echo "| n | expand, optimized | expand, opt-level 0 | source ops | ops stage_values | ops stage_jacobians | ops CasADi bundle | generated tokens |"
    echo "|---|---|---|---|---|---|---|---|"
    for n in $SIZES; do
        r=${RESULT[$n]}
        printf '| %s | %s (%s) | %s (%s) | %s | %s | %s | %s | %s kB |\n' "$n" \
            "$(field "$r" expand_ms)" "$(field "$r" expand_cpu_ms)" "$(field "$r" expand0_ms)" "$(field "$r" expand0_cpu_ms)" \
            "$(field "$r" source_ops)" "$(field "$r" stage_values)" "$(field "$r" stage_jacobians)" "$(field "$r" bundle)" \
            "$(awk -v b="$(field "$r" code_bytes)" 'BEGIN { printf "%.0f", b / 1000 }')"
    done
    echo
    first=${SIZES%% *}; last=${SIZES##* }
    verdict() { awk -v x="$1" -v y="$2" -v lim="$3" 'BEGIN { split(x, a, ","); split(y, b, ",");
        w = a[1] - b[1]; c = a[2] - b[2];
        printf "%.2f s wall (%.2f s CPU): %s", w, c, (w < lim) ? "met" : ((c < lim) ? "met in CPU time, not in wall time on this loaded machine" : "NOT met") }'; }
    echo "Aims: under 1 s added per paper system — n = $first adds to a release build"
    echo "$(verdict "$(field "${RESULT[$first]}" release)" "$base_rel" 1). Under 10 s at n = $last — it adds"
    echo "$(verdict "$(field "${RESULT[$last]}" release)" "$base_rel" 10). Generated operations per source"
    echo "operation (stage_values / stage_jacobians / bundle), flat if counts grow no faster than the expressions:"
    for n in $SIZES; do
        r=${RESULT[$n]}
        awk -v n="$n" -v s="$(field "$r" source_ops)" -v a="$(field "$r" stage_values)" -v b="$(field "$r" stage_jacobians)" \
            -v c="$(field "$r" bundle)" 'BEGIN { printf "n = %s: %.2f / %.2f / %.2f; ", n, a / s, b / s, c / s }'
    done
    echo
    echo
    prev=$(awk '{ print $(NF-1) }' <<<"$SIZES")
    if [ "$prev" != "$last" ]; then
        awk -v a="$prev" -v b="$last" -v ta="$(field "${RESULT[$prev]}" expand_cpu_ms)" -v tb="$(field "${RESULT[$last]}" expand_cpu_ms)" \
            'BEGIN { if (ta > 0 && tb > 0) printf "The macro'"'"'s own work (optimized, CPU) grows like n^%.1f from n = %s to %s, faster than the\noperation counts; it stays a minor part of the build at n = %s.\n", log(tb / ta) / log(b / a), a, b, b }'
    fi
    echo
    echo "- *added seconds*: minimum over $REPS rebuilds of the crate with the declaration, minus the"
    echo "  same for the crate without it (baseline: check $(show "$base_check"), debug $(show "$base_dev"),"
    echo "  release $(show "$base_rel")). They include running the macro inside rustc."
    echo "- *expand*: the macro's work alone, optimized and at opt-level 0. Cargo builds proc macros"
    echo "  and their dependencies with \`build-override\` opt-level 0 unless a profile says"
    echo "  otherwise, so a default build pays the opt-level 0 kind of cost; a user can set"
    echo "  \`[profile.dev.build-override] opt-level = 3\` (and the same for release) to pay the"
    echo "  optimized figure instead. The in-process opt-level 0 figure overstates what rustc pays"
    echo "  (it uses proc-macro2's fallback token implementation with span locations, which the"
    echo "  parser's tests enable); the *check* column is the real cost inside rustc."
    echo "- *source ops*: operators and calls in the declared \`L\` and \`k\`; *ops*: arithmetic"
    echo "  operations of the generated code after simplification and CSE (\`OPERATIONS\` of the"
    echo "  generated impl); *generated tokens*: size of the emitted token stream as text."
    echo
    echo "Machine: $(nproc) cores shared with other jobs (load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)),"
    echo "$(rustc --version), repository at $(git -C "$REPO" rev-parse --short HEAD), $(date -u +%Y-%m-%dT%H:%MZ)."
    echo "Wall-clock figures on a loaded machine are inflated and noisy; CPU figures are steadier."
} >"$OUT.new"
# A hand-written section from `## Against another build` on (comparisons of
# builds run back to back) is kept below the regenerated tables.
if [ -f "$OUT" ] && grep -q '^## Against another build' "$OUT"; then
    { echo; sed -n '/^## Against another build/,$p' "$OUT"; } >>"$OUT.new"
fi
mv "$OUT.new" "$OUT"
log "wrote $OUT"
