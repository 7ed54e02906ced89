"""What `spark.compile(optimize=False)` saves and costs: a declaration new
to the cache (three coordinates, one constraint) built in the release
profile and at opt-level 0, each build timed, then 10⁵ steps of Gauss
s = 2 on each (best of three `integrate` calls), and the two runs compared.

    python python/bench/compile_optimize.py [--steps 100000] [--cache-dir DIR]

The cache is a fresh temporary folder unless --cache-dir names one, so the
first build also compiles pyo3 and spark-runtime; give a warm cache to time
the declaration's crate alone.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

import spark

TEXT = """
pub struct CompileProbe {
    coordinates: [x, y, th],
    parameters: { c = 0.3 },
    lagrangian: (dot(x)^2 + dot(y)^2 + dot(th)^2)/2 - c*x^2,
    constraints: [ dot(y) - sin(th)*dot(x) ],
}
// %s
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--cache-dir", default=None)
    args = ap.parse_args()
    cache = args.cache_dir or tempfile.mkdtemp(prefix="spark-compile-")
    # A text of its own each run, so that neither build comes from the cache.
    text = TEXT % time.time_ns()
    runs = {}
    for optimize in (True, False):
        t = time.perf_counter()
        system = spark.compile(text, cache_dir=cache, optimize=optimize)
        built = time.perf_counter() - t
        best, run = float("inf"), None
        for _ in range(3):
            t = time.perf_counter()
            run = system.integrate("gauss", 2, 0.01, args.steps, q0=[0.1, 0, 0], v0=[1, 0, 0.5], every=1000)
            best = min(best, time.perf_counter() - t)
        runs[optimize] = run
        print(f"optimize={optimize}: build {built:.1f} s, {args.steps} steps {best:.3f} s")
    same = all(np.array_equal(getattr(runs[True], c), getattr(runs[False], c)) for c in ("q", "v"))
    print(f"same samples bit for bit: {same}")


if __name__ == "__main__":
    main()
