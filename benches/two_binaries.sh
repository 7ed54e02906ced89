#!/usr/bin/env bash
# Step time of `integrate` at two commits, side by side: builds
# `examples/driver_cost.rs` (this checkout's copy, which uses only API that
# predates dense output and events) at commits OLD and NEW in temporary
# worktrees, runs the two binaries alternately for ROUNDS rounds (the first
# of each round swapped every round, so load on the machine hits both
# alike) and prints, per paper system, the median ns per step of
# `integrate` in each, the median and quartiles of the per-round ratio
# NEW / OLD, and each binary's own median ratio of `integrate` to a bare
# loop of `Stepper::step` over the same steps (the driver's cost at that
# commit, independent of how fast its step is).
#
#   bash benches/two_binaries.sh [OLD [NEW [ROUNDS [SECONDS]]]]
#
# The defaults compare the stepper without dense output and events
# (cb791eb, the first parent of the merge cdc06d2 that added them) with the
# stepper that has them (660ac37: the merge and the one-line fix that makes
# its adaptive module build). SECONDS is the time per system per run.
set -euo pipefail
cd "$(dirname "$0")/.."
old=${1:-cb791eb}
new=${2:-660ac37}
rounds=${3:-15}
seconds=${4:-0.4}
example=$PWD/spark-runtime/examples/driver_cost.rs
work=$(mktemp -d)
cleanup() {
    git worktree remove --force "$work/old" 2>/dev/null || true
    git worktree remove --force "$work/new" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT

for side in old new; do
    commit=$old
    [ "$side" = new ] && commit=$new
    git worktree add --detach --quiet "$work/$side" "$commit"
    cp "$example" "$work/$side/spark-runtime/examples/driver_cost.rs"
    echo "==> building driver_cost at $commit ($side)" >&2
    (cd "$work/$side" && CARGO_TARGET_DIR="$work/target-$side" \
        cargo build --quiet --release -p spark-runtime --example driver_cost)
done

for round in $(seq 1 "$rounds"); do
    if [ $((round % 2)) -eq 1 ]; then order="old new"; else order="new old"; fi
    for side in $order; do
        "$work/target-$side/release/examples/driver_cost" "$seconds" | sed "s/^/$round $side /"
    done
done >"$work/times.txt"

python3 - "$work/times.txt" "$old" "$new" <<'EOF'
import statistics, sys
path, old, new = sys.argv[1:4]
runs = {}
for line in open(path):
    round_, side, system, driven, bare, ratio, updates = line.split()
    runs.setdefault(system, {}).setdefault(side, {})[int(round_)] = (float(driven), float(ratio), float(updates))
def quartiles(x):
    x = sorted(x)
    pick = lambda p: x[round((len(x) - 1) * p)]
    return pick(0.25), pick(0.5), pick(0.75)
print(f"| system | integrate at {old} (ns/step) | integrate at {new} (ns/step) | paired ratio {new} / {old}, median [quartiles] | integrate / step loop at {old} | at {new} | Newton updates/step |")
print("|---|---:|---:|---:|---:|---:|---:|")
for system, sides in runs.items():
    rounds = sorted(set(sides["old"]) & set(sides["new"]))
    a = [sides["old"][r][0] for r in rounds]
    b = [sides["new"][r][0] for r in rounds]
    q1, q2, q3 = quartiles([y / x for x, y in zip(a, b)])
    la = statistics.median(sides["old"][r][1] for r in rounds)
    lb = statistics.median(sides["new"][r][1] for r in rounds)
    ua, ub = sides["old"][rounds[0]][2], sides["new"][rounds[0]][2]
    print(f"| {system} | {statistics.median(a):.1f} | {statistics.median(b):.1f} | {q2:.3f} [{q1:.3f}, {q3:.3f}] "
          f"| {la:.3f} | {lb:.3f} | {ua:.3f} / {ub:.3f} |")
EOF
