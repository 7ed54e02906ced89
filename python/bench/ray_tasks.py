"""Where a Ray sweep's time goes, task by task: is a second worker slower
because of Ray or because of the machine?

    python python/bench/ray_tasks.py [--workers 1 2] [--members 1000] [--steps 10000] [--repeat 2]

The §8.4 ensemble (mp7-nh, Lobatto IIIA-B s = 2, h = 0.05, simplified
Newton, every 100 steps) in 4 shards per worker on a local Ray instance with
--workers CPUs, each shard one task calling `spark.ensemble` on one thread.
Each task reports its worker's pid, its start and end (wall clock) and its
process CPU time; printed per sweep: the wall time, the number of worker
processes, the sums of the tasks' wall and CPU times, when the first task
started and the last ended (after submission), the Python threads in a
worker and the cores it may run on. Equal CPU sums with a doubled wall sum
mean the workers shared the cores with something else.
"""

from __future__ import annotations

import argparse
import os
import threading
import time

import numpy as np
import ray

import spark
import spark.ray as sray


def _shard(q0s, v0s, steps):
    t0, c0 = time.time(), time.process_time()
    spark.ensemble("mp7-nh", "lobatto-iiia-b", 2, 0.05, steps, q0s, v0s, every=100, newton="simplified", threads=1)
    cores = len(os.sched_getaffinity(0))
    return os.getpid(), t0, time.time(), time.process_time() - c0, threading.active_count(), cores


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    p.add_argument("--members", type=int, default=1000)
    p.add_argument("--steps", type=int, default=10_000)
    p.add_argument("--repeat", type=int, default=2)
    a = p.parse_args()
    q0s, v0s = sray.fig84_members(a.members)
    for w in a.workers:
        ray.init(num_cpus=w, include_dashboard=False, log_to_driver=False)
        shard = ray.remote(num_cpus=1)(_shard)
        ray.get([shard.remote(q0s[:1], v0s[:1], 10) for _ in range(w)])  # starts the workers
        for _ in range(a.repeat):
            bounds = np.linspace(0, a.members, 4 * w + 1).round().astype(int)
            start = time.time()
            res = ray.get([shard.remote(q0s[i:j], v0s[i:j], a.steps) for i, j in zip(bounds[:-1], bounds[1:])])
            wall = time.time() - start
            print(
                f"{w} worker(s), {a.members} members x {a.steps} steps: wall {wall:.2f} s, "
                f"{len({r[0] for r in res})} worker pid(s), task wall sum {sum(r[2] - r[1] for r in res):.2f} s, "
                f"task CPU sum {sum(r[3] for r in res):.2f} s, first start +{min(r[1] for r in res) - start:.3f} s, "
                f"last end +{max(r[2] for r in res) - start:.3f} s, {res[0][4]} Python threads per worker, "
                f"{res[0][5]} cores allowed"
            )
        ray.shutdown()


if __name__ == "__main__":
    main()
