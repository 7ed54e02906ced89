"""Shared fixtures: the Rust CLI (`spark`) the Python results are compared with."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def _target_dir() -> Path:
    return Path(os.environ.get("CARGO_TARGET_DIR") or REPO / "target")


@pytest.fixture(scope="module")
def compiles_without_optimization():
    """Every compile of a module that uses this (`pytestmark =
    pytest.mark.usefixtures("compiles_without_optimization")`), and of the
    interpreters its tests start, builds without optimization
    (`SPARK_COMPILE_OPTIMIZE=0`, which they inherit and which `spark.compile`
    takes as `optimize=False`, the same cache key included): the
    declaration's crate and the spark crates at opt-level 0, about 3 s a
    declaration instead of 25 s, the crates from crates.io those the
    wheel's build compiled in the shared target directory; the same
    results bit for bit, as a floating-point result in Rust does not
    depend on the optimization level (test_compile.py's first test compares
    such a module with the optimized registry)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SPARK_COMPILE_OPTIMIZE", "0")
        yield


@pytest.fixture(scope="session")
def spark_cli() -> Path:
    """The release `spark` binary, built by cargo if it is missing (never skipped)."""
    exe = Path(os.environ.get("SPARK_CLI") or _target_dir() / "release" / "spark")
    if not exe.exists():
        subprocess.run(
            ["cargo", "build", "--release", "-p", "problems", "--bin", "spark"], cwd=REPO, check=True
        )
    assert exe.exists(), f"{exe} missing after cargo build"
    return exe


def run_cli(exe: Path, out: Path, system: str, *args: str) -> dict[str, np.ndarray]:
    """Runs `spark run SYSTEM ARGS --out OUT --no-plot` and reads its CSV and report.json."""
    subprocess.run(
        [str(exe), "run", system, *args, "--out", str(out), "--no-plot"],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    (csv_path,) = [p for p in out.iterdir() if p.suffix == ".csv"]
    with open(csv_path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    cols = {name: np.array([float(r[i]) for r in body]) for i, name in enumerate(header)}
    cols["e0"] = json.loads((out / "report.json").read_text())["stats"]["e0"]
    return cols


def interrupt_after_start(script: str, delay: float = 1.0, timeout: float = 60.0) -> tuple[float, str]:
    """Runs `script` in a fresh interpreter; once it prints `running` (just
    before its long call) and `delay` seconds have passed, sends it SIGINT
    (Ctrl-C). Returns the seconds from the signal to its exit and its
    stderr; fails if it exits successfully or before the signal."""
    import signal
    import time

    # The child starts with SIGINT at its default, so that Python installs
    # its KeyboardInterrupt handler even where this test runs with SIGINT
    # ignored (a job started with `&` by a non-interactive shell inherits
    # that, and Python keeps an ignored SIGINT ignored).
    proc = subprocess.Popen(
        [sys.executable, "-u", "-c", script],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        line = proc.stdout.readline()
        assert line.strip() == "running", f"no start line: {line!r}; stderr: {proc.stderr.read()}"
        time.sleep(delay)
        assert proc.poll() is None, f"the run ended before the signal: {proc.stderr.read()}"
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=timeout)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode != 0, f"exited with 0 after SIGINT; stderr: {err}"
    return took, err
