"""Throughput of `spark.ray.sweep` with 1 and 2 Ray workers on this machine.

    python python/bench/ray_throughput.py [--members 1000] [--steps 1000]

The §8.4 ensemble (mp7-nh, Lobatto IIIA-B s = 2, h = 0.05, simplified
Newton, every 100 steps) on a local Ray instance with --workers CPUs; prints
the wall time of the sweep (tasks, gathering and the Parquet file), members
per second and the time per member, and the same ensemble with
`spark.ensemble` in-process on one thread for comparison.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import ray

import spark
import spark.ray as sray


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--members", type=int, default=1000)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    a = p.parse_args()
    q0s, v0s = sray.fig84_members(a.members)
    start = time.perf_counter()
    spark.ensemble("mp7-nh", "lobatto-iiia-b", 2, 0.05, a.steps, q0s, v0s, every=100, newton="simplified",
                   threads=1)
    wall = time.perf_counter() - start
    print(f"in-process, 1 thread : {wall:7.2f} s, {a.members / wall:8.1f} members/s, "
          f"{wall / a.members * 1e3:.2f} ms per member")
    for w in a.workers:
        ray.init(num_cpus=w, include_dashboard=False, log_to_driver=False)
        with tempfile.TemporaryDirectory() as d:
            # one warm-up sweep starts the workers
            sray.sweep("mp7-nh", "lobatto-iiia-b", 2, 0.05, 10, q0s[:w], v0s[:w], out=f"{d}/warm.parquet",
                       shards=w)
            r = sray.sweep("mp7-nh", "lobatto-iiia-b", 2, 0.05, a.steps, q0s, v0s, out=f"{d}/s.parquet",
                           every=100, newton="simplified", shards=4 * w)
        ray.shutdown()
        print(f"Ray, {w} worker(s)    : {r.wall_seconds:7.2f} s, {a.members / r.wall_seconds:8.1f} members/s, "
              f"{r.seconds_per_member * 1e3:.2f} ms per member ({r.shards} shards)")


if __name__ == "__main__":
    main()
