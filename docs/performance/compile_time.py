#!/usr/bin/env python3
"""Compile time of the SPARK stepper against n (McLachlan-Perlmutter particles).

For each n in SIZES a throw-away crate depending on spark-runtime (by path) is
built in release mode three ways:
  decl     the `nonholonomic_system!` declaration only,
  stepper  + one monomorphized `Stepper<_, n, 1, 2, D>` (Gauss s = 2, its `step`
           exported so it is code-generated),
  stepper5 + the same with s = 5.
Dependencies are built once first; each measured build touches only the crate,
so its cost is the macro expansion, type checking and code generation of that
crate. Reported: CPU seconds (user + sys of cargo and rustc, robust to other
jobs on a shared machine) and wall seconds, median of REPEATS builds.

Usage: python3 docs/performance/compile_time.py [--repeats 3] [--out docs/performance/compile-time.csv]
(run from the workspace root; uses CARGO_TARGET_DIR or /work/target-compile-time).
"""

import argparse
import csv
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from gen_mp_systems import system  # noqa: E402

SIZES = [5, 9, 17, 33, 65]


def crate_source(n: int, variant: str) -> str:
    src = "#![allow(missing_docs)]\nuse spark_runtime::nonholonomic_system;\n\n" + system(n)
    for s in ([2] if variant == "stepper" else [2, 5] if variant == "stepper5" else []):
        d = s * (n + 1) + n
        src += f"""
/// One Gauss step, exported so the stepper is code-generated.
#[no_mangle]
pub fn step_s{s}(q: &[f64; {n}], v: &[f64; {n}], h: f64) -> f64 {{
    let tab = spark_runtime::Tableau::<{s}>::new(spark_runtime::Method::Gauss).unwrap();
    let mut st = spark_runtime::Stepper::<McLachlanPerlmutter{n}, {n}, 1, {s}, {d}>::new(Default::default(), tab);
    let x = spark_runtime::State::new(0.0, spark_runtime::Vector::<{n}>::from_column_slice(q),
        spark_runtime::Vector::<{n}>::from_column_slice(v));
    st.step(&x, h).map(|r| r.state.q[0]).unwrap_or(f64::NAN)
}}
"""
    return src


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def build(crate: Path, env) -> tuple[float, float]:
    (crate / "src" / "lib.rs").touch()
    c0, w0 = children_cpu(), time.perf_counter()
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=crate, env=env, check=True)
    return children_cpu() - c0, time.perf_counter() - w0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="docs/performance/compile-time.csv")
    a = ap.parse_args()
    root = Path.cwd()
    runtime = root / "spark-runtime"
    if not runtime.is_dir():
        print("run from the workspace root", file=sys.stderr)
        return 2
    env = dict(os.environ)
    env.setdefault("CARGO_TARGET_DIR", "/work/target-compile-time")
    crate = Path(env["CARGO_TARGET_DIR"]) / "ct-crate"
    (crate / "src").mkdir(parents=True, exist_ok=True)
    (crate / "Cargo.toml").write_text(f"""[package]
name = "ct-crate"
version = "0.0.0"
edition = "2021"
[lib]
path = "src/lib.rs"
[dependencies]
spark-runtime = {{ path = "{runtime}" }}
[workspace]
""")
    rows = []
    for n in SIZES:
        for variant in ["decl", "stepper", "stepper5"]:
            (crate / "src" / "lib.rs").write_text(crate_source(n, variant))
            build(crate, env)  # dependencies, and a warm cache for the crate
            cpu, wall = zip(*(build(crate, env) for _ in range(a.repeats)))
            row = {"n": n, "variant": variant, "cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall)}
            print(row, file=sys.stderr)
            rows.append(row)
    with open(a.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["n", "variant", "cpu_s", "wall_s"])
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
