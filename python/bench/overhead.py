"""Overhead of calling spark from Python: a 10⁶-step run through
`spark.integrate` against the Rust call inside it (`problems::run::run`,
what `spark run` and a Rust program call: checks, stepper set-up, the steps
and the recorded columns), timed inside Rust.

    python python/bench/overhead.py [--steps 1000000] [--repeat 5]

Prints, per recording setting, the median over --repeat runs of the Python
wall time, the Rust time and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time

import spark


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--system", default="skate")
    a = p.parse_args()
    sys_ = spark.system(a.system)
    for label, every in (("endpoints only", a.steps), ("every step", 1)):
        ratios, py, rust = [], [], []
        for _ in range(a.repeat):
            start = time.perf_counter()
            run = sys_.integrate("gauss", 2, 0.01, a.steps, every=every)
            wall = time.perf_counter() - start
            py.append(wall)
            rust.append(run.rust_seconds)
            ratios.append(wall / run.rust_seconds)
        print(
            f"{a.system} gauss s=2, {a.steps} steps, {label:<14}: Python {statistics.median(py):.3f} s, "
            f"Rust {statistics.median(rust):.3f} s, ratio {statistics.median(ratios):.4f} "
            f"(min {min(ratios):.4f}, max {max(ratios):.4f})"
        )


if __name__ == "__main__":
    main()
