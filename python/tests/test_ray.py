"""The Ray sweep on a local Ray instance: the 1000-member Fig. 8.4 statistic
equals, bit for bit, the one computed from the Rust CLI's runs of the same
members.

The sweep's shards run the native ensemble (SIMD lane groups), the CLI one
stepper per run; a member in a lane computes bit for bit its run alone. The
CLI's CSV and report.json carry every number with round-trip precision, and
both statistics sum the squared energy errors member by member in member
order, then divide by J + 1 and by h⁴ = (h·h)·(h·h) as `problems::report::
stats::ensemble_quantity` does (LLVM expands its `h.powi(4)` by repeated
squaring into those two products), so the two are compared exactly."""

from __future__ import annotations

import concurrent.futures
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import ray

import spark
import spark.ray as sray
from conftest import run_cli

H, STEPS, EVERY, MEMBERS = 0.05, 100, 10, 1000
METHOD = "lobatto-iiia-b"


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_sweep_of_1000_members_equals_the_cli(local_ray, spark_cli, tmp_path):
    q0s, v0s = sray.fig84_members(MEMBERS)
    out = tmp_path / "fig84.parquet"
    report = sray.sweep("mp7-nh", METHOD, 2, H, STEPS, q0s, v0s, out=str(out), every=EVERY, newton="simplified",
                        shards=8)
    assert report.members == MEMBERS and report.shards == 8
    assert report.rejected_steps.shape == (MEMBERS,) and not report.rejected_steps.any()
    table = pq.read_table(out)
    samples = STEPS // EVERY + 1
    assert table.num_rows == MEMBERS * samples
    assert table.column_names[:3] == ["member", "t", "q_q1"]
    assert table.column_names[-3:] == ["energy", "energy_error", "constraint"]
    t, stat = sray.ensemble_statistic(str(out), H)

    def cli(j: int):
        args = ["--method", METHOD, "--stages", "2", "--h", repr(H), "--t-end", repr(STEPS * H), "--every",
                str(EVERY), "--newton", "simplified", "--q0", ",".join(repr(float(x)) for x in q0s[j]), "--v0",
                ",".join(repr(float(x)) for x in v0s[j])]
        c = run_cli(spark_cli, tmp_path / f"cli{j}", "mp7-nh", *args)
        return c["energy"] - c["e0"], c["t"]

    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(cli, range(MEMBERS)))
    errors = np.array([r[0] for r in results])
    np.testing.assert_array_equal(t, results[0][1])
    acc = np.zeros(samples)
    for row in errors:
        acc += row * row
    expected = acc / MEMBERS / (H * H * (H * H))
    np.testing.assert_array_equal(stat, expected)
    # and every member's energy error, row by row
    err = table.column("energy_error").to_numpy().reshape(MEMBERS, samples)
    np.testing.assert_array_equal(err, errors)
    assert stat[-1] > 0


def test_a_sweep_that_halves_steps_warns_once_and_counts_them(local_ray, tmp_path):
    # The robot at h = 3 (its paper step is 0.2) halves three of its first
    # four steps; the workers' warnings would not reach the user, so the
    # driver warns for the sweep, and the report counts each member's.
    robot = spark.system("robot")
    q0s, v0s = np.array([robot.q0] * 3), np.array([robot.v0] * 3)
    out = tmp_path / "robot.parquet"
    with pytest.warns(spark.StepHalvingWarning, match=r"3 of 3 members halved steps .*9 halvings") as caught:
        report = sray.sweep("robot", "gauss", 2, 3.0, 4, q0s, v0s, out=str(out), shards=2)
    assert len(caught) == 1
    np.testing.assert_array_equal(report.rejected_steps, [3, 3, 3])
    with pytest.raises(spark.SparkError, match=r"before any shard runs: .*Newton diverged"):
        sray.sweep("robot", "gauss", 2, 3.0, 4, q0s, v0s, out=str(tmp_path / "none.parquet"), max_halvings=0)


def test_sweep_of_a_compiled_system(local_ray, tmp_path, monkeypatch):
    from test_compile import declaration

    from spark._compile import cache_key

    cache = tmp_path / "cache"
    monkeypatch.setenv("SPARK_CACHE_DIR", str(cache))
    # A text of its own, so that this process has not loaded it from
    # another cache; unoptimized (seconds to build), and the workers load
    # the same module.
    text = declaration("Skate") + "\n// swept on Ray"
    skate = spark.compile(text, optimize=False)
    q0s = np.zeros((4, 3))
    v0s = np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 0.5], [0, 0, 1.5]])
    out = tmp_path / "skate.parquet"
    sray.sweep(skate, "gauss", 2, 0.1, 20, q0s, v0s, out=str(out), shards=2)
    x = pq.read_table(out).column("q_x").to_numpy().reshape(4, 21)
    ref = spark.ensemble("skate", "gauss", 2, 0.1, 20, q0s, v0s)
    # Two shards of two members against one ensemble of four.
    np.testing.assert_array_equal(x, ref.q[:, :, 0])
    # The workers compiled nothing of their own (an optimized build would
    # have a folder of its own).
    built = sorted(p.name for p in cache.iterdir() if p.name != "target")
    assert built == [cache_key(text, optimize=False)], built


def test_a_sweep_with_params_as_an_iterator_of_pairs_uses_them(local_ray, tmp_path):
    # The check before Ray starts read the iterator, and the shards were
    # handed what was left of it: nothing, so they ran with the default
    # parameters and wrote the wrong trajectories without a word.
    q0s = np.zeros((2, 3))
    v0s = np.array([[0, 0, 1.0], [0, 0, 2.0]])
    args = ("skate", "gauss", 2, 0.1, 20, q0s, v0s)
    out = tmp_path / "pairs.parquet"
    sray.sweep(*args, params=iter([("g", 3.0)]), out=str(out), shards=2)
    x = pq.read_table(out).column("q_x").to_numpy().reshape(2, 21)
    ref = spark.ensemble(*args, params={"g": 3.0})
    np.testing.assert_array_equal(x, ref.q[:, :, 0])
    default = spark.ensemble(*args)
    assert not np.array_equal(ref.q, default.q)


def test_a_sweep_refuses_what_cannot_work_before_ray_starts(tmp_path):
    # An output path it cannot write and a shard count below 1 are refused
    # up front: found only when the file is written, they would cost a run of
    # every member, and a shard count below 1 would run as 1.
    q0s, v0s = sray.fig84_members(2)
    args = ("mp7-nh", METHOD, 2, H, 10, q0s, v0s)
    cases = {
        "is a folder": dict(out=str(tmp_path)),
        "does not exist": dict(out=str(tmp_path / "missing" / "sweep.parquet")),
        "shards = 0 is less than 1": dict(out=str(tmp_path / "a.parquet"), shards=0),
    }
    for words, kwargs in cases.items():
        with pytest.raises(spark.SparkError, match=words):
            sray.sweep(*args, **kwargs)
    # An empty path, a bytes path and a folder that cannot be written are
    # refused up front too, not when the file is written after every member.
    with pytest.raises(spark.SparkError, match="names no file"):
        sray.sweep(*args, out="")
    with pytest.raises(spark.SparkError, match="holds a NUL character"):
        sray.sweep(*args, out=str(tmp_path / "a\0b.parquet"))
    with pytest.raises(spark.SparkError, match="is no file name: .*surrogates not allowed"):
        sray.sweep(*args, out=str(tmp_path / "a\ud800.parquet"))
    with pytest.raises(spark.SparkError, match="is a folder"):
        sray.sweep(*args, out=str(tmp_path) + "/")
    with pytest.raises(spark.SparkError, match="cannot write into the folder of out = '/proc/sweep.parquet'"):
        sray.sweep(*args, out="/proc/sweep.parquet")
    with pytest.raises(spark.SparkError, match="does not exist"):
        sray.sweep(*args, out=bytes(tmp_path / "missing" / "sweep.parquet"))
    with pytest.raises(spark.SparkError, match=r"shape \(members, N\)"):
        sray.sweep("mp7-nh", METHOD, 2, H, 10, q0s[0], v0s[0], out=str(tmp_path / "a.parquet"))
    assert not list(tmp_path.iterdir())


def test_a_sweep_refuses_bad_arguments_as_argument_errors_before_ray_starts(tmp_path):
    # An output path no file can have, and initial states that are missing,
    # of another width than the system's or not finite, are the caller's
    # bad arguments whatever the file system holds: ArgumentError, as
    # spark.ensemble and cache_dir of spark.compile refuse them.
    q0s, v0s = sray.fig84_members(2)
    args = ("mp7-nh", METHOD, 2, H, 10, q0s, v0s)
    for words, out in (
        ("names no file", ""),
        ("holds a NUL character", str(tmp_path / "a\0b.parquet")),
        ("is no file name: .*surrogates not allowed", str(tmp_path / "a\ud800.parquet")),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            sray.sweep(*args, out=out)
    out = str(tmp_path / "a.parquet")
    bad = v0s.copy()
    bad[1, 3] = np.nan
    for words, h, qs, vs in (
        (r"\(v0s is missing\)", H, q0s, None),
        (r"^q0s and v0s must have shape \(members, 7\) for mp7-nh", H, q0s[:, :3], v0s[:, :3]),
        (r"^v0s\[1, 3\] = nan is not finite \(member 1\)", H, q0s, bad),
        (r"^step size h = 0.0 must be finite and nonzero", 0.0, q0s, v0s),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            sray.sweep("mp7-nh", METHOD, 2, h, 10, qs, vs, out=out)
    assert not list(tmp_path.iterdir())


def test_a_sweep_checks_its_settings_and_the_size_of_its_table_before_ray_starts(tmp_path):
    # An unknown system, method or parameter, an unusable h, a width of q0s
    # other than the system's and an inconsistent first member are refused
    # before Ray starts, not in every shard; so is a table of more rows than
    # the driver's memory holds (each shard checks only its own members, so
    # the driver would gather rows until it ran out of memory).
    q0s, v0s = sray.fig84_members(3)
    out = str(tmp_path / "a.parquet")
    bad_v0 = v0s.copy()
    bad_v0[0, 0] = 3.0
    cases = [
        ("unknown system `nope`", ("nope", METHOD, 2, H, 10, q0s, v0s), {}),
        ("unknown method `nope`", ("mp7-nh", "nope", 2, H, 10, q0s, v0s), {}),
        ("not compiled into this program", ("mp7-nh", METHOD, 9, H, 10, q0s, v0s), {}),
        ("step size h = NaN", ("mp7-nh", METHOD, 2, float("nan"), 10, q0s, v0s), {}),
        (r"shape \(members, 7\) for mp7-nh", ("mp7-nh", METHOD, 2, H, 10, q0s[:, :3], v0s[:, :3]), {}),
        ("has no parameter `g`", ("mp7-nh", METHOD, 2, H, 10, q0s, v0s, {"g": 1.0}), {}),
        ("member 0 .*v0 violates the constraints.*a row of v0s", ("mp7-nh", METHOD, 2, H, 10, q0s, bad_v0), {}),
        (r"the sweep's table has 3\.000e\+12 rows", ("mp7-nh", METHOD, 2, H, 10**12, q0s, v0s), {}),
    ]
    for words, args, kwargs in cases:
        with pytest.raises(spark.SparkError, match=words):
            sray.sweep(*args, out=out, **kwargs)
    with pytest.raises(TypeError, match="neither a system name nor a spark.System"):
        sray.sweep(7, METHOD, 2, H, 10, q0s, v0s, out=out)
    # The table's limit names the record interval that fits.
    with pytest.raises(spark.ArgumentError, match="every = ") as info:
        sray.sweep("mp7-nh", METHOD, 2, H, 10**12, q0s, v0s, out=out)
    every = int(str(info.value).split("every = ")[1].split()[0])
    samples = 10**12 // every + 2
    assert 3 * samples * 8 * 19 * 2 <= spark._native.record_memory_limit(), every
    assert not list(tmp_path.iterdir())


def test_fig84_members_and_the_statistic_refuse_what_they_cannot_compute():
    # Unchecked, fig84_members(0) would raise "not enough values to unpack"
    # from its zip and a count of 10**12 would run until memory ran out;
    # ensemble_statistic with h = 0 would return inf/NaN as a statistic, and
    # an empty table would raise ZeroDivisionError.
    for count in (0, -1, sray.MAX_FIG84_MEMBERS + 1, 2**70):
        with pytest.raises(ValueError, match=rf"count = {count} is .* give 1 ≤ count ≤ {sray.MAX_FIG84_MEMBERS}"):
            sray.fig84_members(count)
    with pytest.raises(TypeError, match="count = True is a bool"):
        sray.fig84_members(True)
    q, v = sray.fig84_members(1)
    assert q.shape == v.shape == (1, 7)
    import pyarrow as pa

    table = pa.table({"member": [0, 0, 1, 1], "t": [0.0, 0.1] * 2, "energy_error": [0.0, 1e-3, 0.0, 2e-3]})
    t, stat = sray.ensemble_statistic(table, 0.1)
    np.testing.assert_allclose(stat, [0.0, (1e-6 + 4e-6) / 2 / 1e-4])
    for h in (0.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="must be a finite, nonzero step size"):
            sray.ensemble_statistic(table, h)
    with pytest.raises(ValueError, match="no rows"):
        sray.ensemble_statistic(table.slice(0, 0), 0.1)
    with pytest.raises(ValueError, match="member 1 has 1 samples and others 2"):
        sray.ensemble_statistic(table.slice(0, 3), 0.1)
    # As many samples, at other times: the mean would mix t = 0.1 with t = 0.2.
    other = pa.table({"member": [0, 0, 1, 1], "t": [0.0, 0.1, 0.0, 0.2], "energy_error": [0.0, 1e-3, 0.0, 2e-3]})
    with pytest.raises(ValueError, match="member 1 has samples at other times than member 0"):
        sray.ensemble_statistic(other, 0.1)


def test_the_fig84_example_refuses_an_interval_that_is_not_a_whole_number_of_steps(local_ray, tmp_path,
                                                                                   monkeypatch):
    # 10.03 / 0.05 = 200.6 steps: a count rounded from it ran to t = 10.05.
    import runpy
    import sys

    monkeypatch.setattr(ray, "init", lambda *args, **kwargs: None)
    monkeypatch.setattr(sys, "argv", ["fig84_ray.py", "--members", "2", "--t-end", "10.03", "--every", "1",
                                      "--out", str(tmp_path)])
    with pytest.raises(spark.SparkError, match=r"t_end = 10\.03 is 200\.5999\d* steps .* not a whole number"):
        runpy.run_path(str(Path(__file__).parents[1] / "examples" / "fig84_ray.py"), run_name="__main__")


def test_a_sweep_writes_to_bytes_and_non_utf8_paths(local_ray, tmp_path):
    # pyarrow fails on a bytes `out` ("Can't mix strings and bytes") and
    # refuses a folder whose name is not UTF-8, both only when the file is
    # written after every member has run; the sweep hands it a file Python opens.
    q0s, v0s = sray.fig84_members(2)
    folder = os.fsdecode(bytes(tmp_path) + b"/\xff")
    os.mkdir(folder)
    for out in (bytes(tmp_path / "sweep.parquet"), os.path.join(folder, "sweep.parquet")):
        report = sray.sweep("mp7-nh", METHOD, 2, H, 10, q0s, v0s, out=out, shards=1)
        assert pq.read_table(open(report.path, "rb")).num_rows == 2 * 11
    assert sorted(os.listdir(folder)) == ["sweep.parquet"]


def test_an_interrupted_write_leaves_the_previous_file_intact(local_ray, tmp_path, monkeypatch):
    # The Parquet file is written under a temporary name and renamed: written
    # in place, a write that failed or was interrupted half-way would leave a
    # truncated file under the final name.
    q0s, v0s = sray.fig84_members(2)
    out = tmp_path / "sweep.parquet"
    sray.sweep("mp7-nh", METHOD, 2, H, 10, q0s, v0s, out=str(out), shards=1)
    before = out.read_bytes()

    def interrupted(table, where, *args, **kwargs):
        where.write(b"PAR1 half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(pq, "write_table", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sray.sweep("mp7-nh", METHOD, 2, H, 20, q0s, v0s, out=str(out), shards=1)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["sweep.parquet"]


def test_more_threads_per_task_than_a_node_has_cpus_is_refused(local_ray, tmp_path):
    # Ray keeps a task that asks for more CPUs than any node has waiting
    # for such a node: the sweep would hang (threads_per_task=4 on this
    # two-CPU instance).
    q0s, v0s = sray.fig84_members(2)
    with pytest.raises(spark.ArgumentError, match=r"threads_per_task = 4 .* 2 CPUs"):
        sray.sweep("mp7-nh", METHOD, 2, H, 10, q0s, v0s, out=str(tmp_path / "a.parquet"), threads_per_task=4)
    assert not list(tmp_path.iterdir())


# --- tolerance-driven steps, t_end and output times ----------------------------

SKATE_Q0S = np.zeros((5, 3))
SKATE_V0S = np.array([[0, 0, 1.0], [0, 0, 2.0], [0.3, 0, -0.5], [-1.0, 0, 1.5], [0.2, 0, 0.7]])


@pytest.mark.parametrize(
    "method, kwargs",
    [
        ("gauss", dict(rtol=1e-8, t_end=5.0, t_eval=[1.0, 2.5, 5.0])),
        # atol alone, t_eval by default (t_end alone), backward in time.
        ("lobatto-iiia-b", dict(atol=1e-7, t_end=-3.0)),
        ("gauss", dict(rtol=1e-7, atol=1e-9, t0=1.0, t_end=4.0, first_step=1e-3, max_step=0.5, max_steps=10_000,
                       newton="simplified", t_eval=np.linspace(1.5, 4.0, 6))),
        # Fixed steps up to t_end, recorded at output times off the grid.
        ("gauss", dict(h=0.1, t_end=2.0, t_eval=[0.55, 1.0, 1.234, 2.0])),
        ("gauss", dict(h=0.1, t_end=2.0, every=3)),
    ],
)
def test_a_sweep_over_shards_equals_the_ensemble_with_the_same_arguments(local_ray, tmp_path, method, kwargs):
    # Each of the three shards calls `spark.ensemble` with the sweep's
    # arguments; every member's samples, times and step counts are those of
    # one ensemble of all five, bit for bit.
    out = tmp_path / "sweep.parquet"
    report = sray.sweep("skate", method, 2, q0s=SKATE_Q0S, v0s=SKATE_V0S, out=str(out), shards=3, **kwargs)
    ref = spark.ensemble("skate", method, 2, q0s=SKATE_Q0S, v0s=SKATE_V0S, **kwargs)
    assert report.shards == 3 and report.members == 5
    table = pq.read_table(out)
    members, samples = ref.energy.shape
    assert table.num_rows == members * samples
    column = {name: table.column(name).to_numpy().reshape(members, samples) for name in table.column_names}
    np.testing.assert_array_equal(column["member"], np.repeat(np.arange(members), samples).reshape(members, samples))
    # The samples are the initial point and t_eval (tolerance-driven: t_end
    # alone by default), or every `every` steps and the end.
    if "t_eval" in kwargs or "h" not in kwargs:
        np.testing.assert_array_equal(ref.t, [kwargs.get("t0", 0.0), *kwargs.get("t_eval", [kwargs["t_end"]])])
    else:
        assert len(ref.t) == 20 // 3 + 2 and abs(ref.t[-1] - 2.0) < 1e-12
    for j in range(members):
        np.testing.assert_array_equal(column["t"][j], ref.t)
    for i, c in enumerate(("x", "y", "theta")):
        np.testing.assert_array_equal(column[f"q_{c}"], ref.q[:, :, i])
        np.testing.assert_array_equal(column[f"v_{c}"], ref.v[:, :, i])
    np.testing.assert_array_equal(column["energy"], ref.energy)
    np.testing.assert_array_equal(column["energy_error"], ref.energy_error)
    np.testing.assert_array_equal(column["constraint"], ref.constraint)
    np.testing.assert_array_equal(report.steps, ref.steps)
    np.testing.assert_array_equal(report.rejected_steps, ref.rejected_steps)
    if ref.controller is None:
        assert report.controller is None
        assert report.steps.tolist() == [20] * members
        # Fig. 8.4's statistic reads a fixed-step sweep's table as before.
        t, stat = sray.ensemble_statistic(str(out), 0.1)
        np.testing.assert_array_equal(t, ref.t)
        acc = np.zeros(samples)
        for row in ref.energy_error:
            acc += row * row
        np.testing.assert_array_equal(stat, acc / members / (0.1 * 0.1 * (0.1 * 0.1)))
    else:
        assert set(report.controller) == set(ref.controller)
        for name, values in ref.controller.items():
            np.testing.assert_array_equal(report.controller[name], values, err_msg=name)
        # Each member's controller chose its own steps.
        assert len(set(report.steps.tolist())) > 1
        np.testing.assert_array_equal(report.steps, report.controller["accepted"])


def _refusal(call):
    with pytest.raises(Exception) as raised:
        call()
    return raised.value


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(rtol=1e-6, t_end=1.0, every=2),
        dict(h=0.1, rtol=1e-6, t_end=1.0),
        dict(steps=10, rtol=1e-6, t_end=1.0),
        dict(rtol=1e-6, t_end=1.0, max_halvings=2),
        dict(rtol=1e-6),
        dict(rtol=-1.0, t_end=1.0),
        dict(rtol=0.0, atol=0.0, t_end=1.0),
        dict(rtol="tight", t_end=1.0),
        dict(rtol=1e-6, t_end=1.0, first_step=0.0),
        dict(rtol=1e-6, t_end=1.0, max_step=-1.0),
        dict(rtol=1e-6, t_end=1.0, max_steps=0),
        dict(rtol=1e-6, t_end=1.0, t_eval=[0.5, 2.0]),
        dict(rtol=1e-6, t_end=1.0, t_eval=[0.5, 0.25]),
        dict(h=0.1, steps=10, every=2, t_eval=[0.5]),
        dict(h=0.1, steps=10, max_step=0.1),
        dict(h=0.1, steps=10, first_step=0.1),
        dict(h=0.1, steps=10, max_steps=5),
        dict(h=0.1, steps=10, t_eval=[0.5, True]),
        dict(h=0.1, t_end=1.05),
        dict(steps=10),
    ],
    ids=lambda kwargs: ",".join(kwargs),
)
def test_a_sweep_refuses_what_the_ensemble_refuses_with_its_message(tmp_path, kwargs):
    # The same checks (one code, `System._ensemble_request`), before Ray
    # starts: the same exception and the same words.
    q0s, v0s = SKATE_Q0S[:2], SKATE_V0S[:2]
    mine = _refusal(lambda: sray.sweep("skate", "gauss", 2, q0s=q0s, v0s=v0s, out=str(tmp_path / "a.parquet"),
                                       **kwargs))
    theirs = _refusal(lambda: spark.ensemble("skate", "gauss", 2, q0s=q0s, v0s=v0s, **kwargs))
    assert type(mine) is type(theirs)
    assert str(mine) == str(theirs)
    assert not list(tmp_path.iterdir())


def test_a_tolerance_driven_sweep_checks_the_runtimes_options_before_ray_starts(tmp_path, monkeypatch):
    # The controller's own checks (the tolerance's range, max_step against
    # max_steps, the first step against the resolution of t) run in the
    # runtime: the sweep runs the first member through before Ray starts,
    # so they fail there, with the ensemble's words, not in every shard.
    q0s, v0s = SKATE_Q0S[:2], SKATE_V0S[:2]
    out = str(tmp_path / "a.parquet")
    for kwargs in (dict(rtol=1e-17, t_end=1.0), dict(rtol=1e-6, t_end=1.0, max_step=1e-6, max_steps=5),
                   dict(rtol=1e-6, t0=1e6, t_end=1e6 + 1.0, first_step=1e-12)):
        theirs = _refusal(lambda: spark.ensemble("skate", "gauss", 2, q0s=q0s, v0s=v0s, **kwargs))
        with pytest.raises(spark.SparkError, match="the sweep's settings fail on member 0 before any shard runs: ") as e:
            sray.sweep("skate", "gauss", 2, q0s=q0s, v0s=v0s, out=out, **kwargs)
        # (The ensemble names the member that failed first of those running.)
        assert re.sub(r"^member \d+: ", "", str(theirs)) in str(e.value)
    # The table of a sweep at output times is counted at one sample per time.
    monkeypatch.setattr(spark._native, "record_memory_limit", lambda: 2 * 5 * 8 * 11 * 2)
    with pytest.raises(spark.ArgumentError, match=r"record at 4 output times of t_eval or fewer"):
        sray.sweep("skate", "gauss", 2, q0s=q0s, v0s=v0s, out=out, rtol=1e-6, t_end=1.0,
                   t_eval=np.linspace(0.1, 1.0, 10))
    assert not list(tmp_path.iterdir())


def _closed_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on (bound, then released)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_address_is_refused_before_ray_starts(tmp_path):
    # ray.init(address=…) at an address where no Ray listens waits inside
    # Ray's connect, well beyond any patience. The sweep tries a TCP
    # connection first (5 s at most) and refuses the address, naming it,
    # without starting Ray. Run in a fresh interpreter, so that no Ray
    # instance of the other tests is running, with a time limit.
    port = _closed_port()
    script = f"""
import time, numpy as np, ray, spark, spark.ray as sray
q0s, v0s = sray.fig84_members(2)
for address in ("127.0.0.1:{port}", "ray://127.0.0.1:{port}"):
    start = time.monotonic()
    try:
        sray.sweep("mp7-nh", "lobatto-iiia-b", 2, 0.05, 10, q0s, v0s, out={str(tmp_path / "a.parquet")!r},
                   address=address)
    except spark.SparkError as e:
        print(type(e).__name__, "|", e)
    else:
        print("no error")
    assert time.monotonic() - start < 10, time.monotonic() - start
assert not ray.is_initialized()
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 2, done.stdout
    for line, address in zip(lines, (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}")):
        assert line.startswith("SparkError | "), line
        assert f"address = '{address}'" in line and "cannot be reached" in line, line
    assert not list(tmp_path.iterdir())


def test_an_address_that_names_no_port_is_an_argument_error(tmp_path):
    q0s, v0s = sray.fig84_members(2)
    args = ("mp7-nh", METHOD, 2, H, 10, q0s, v0s)
    out = str(tmp_path / "a.parquet")
    for address, words in (("", "address = '' names no Ray instance"),
                           ("127.0.0.1", "address = '127.0.0.1' names no port"),
                           ("127.0.0.1:99999", "port 99999 is outside 1..=65535"),
                           ("ray://:10001", "names no host")):
        with pytest.raises(spark.ArgumentError, match=words):
            sray.sweep(*args, out=out, address=address)
    with pytest.raises(TypeError, match="^address = 6379 is not a string"):
        sray.sweep(*args, out=out, address=6379)
    with pytest.raises(TypeError, match="^out = 5 is not a path"):
        sray.sweep(*args, out=5)
    assert not list(tmp_path.iterdir())


def test_out_of_range_sweep_options_are_argument_errors(tmp_path):
    q0s, v0s = sray.fig84_members(2)
    args = ("mp7-nh", METHOD, 2, H, 10, q0s, v0s)
    out = str(tmp_path / "a.parquet")
    cases = [
        (dict(shards=0), r"shards = 0 is less than 1; give 1 ≤ shards"),
        (dict(threads_per_task=1025),
         r"threads_per_task = 1025 is more than 1024; give 1 ≤ threads_per_task ≤ 1024"),
        (dict(max_halvings=61), r"max_halvings = 61 is more than 60"),
        (dict(newton_tol=1.5), r"newton_tol = 1\.500e0 must lie in \(0, 1\)"),
    ]
    for kwargs, words in cases:
        with pytest.raises(spark.ArgumentError, match=words):
            sray.sweep(*args, out=out, **kwargs)
    with pytest.raises(spark.ArgumentError, match=r"Lobatto IIIA-B with s = 100 is not compiled into this program"):
        sray.sweep("mp7-nh", METHOD, 100, H, 10, q0s, v0s, out=out)
    assert not list(tmp_path.iterdir())


def test_the_statistic_refuses_what_is_no_sweeps_table_naming_it(tmp_path):
    # Unchecked, a number raised AttributeError ("'int' object has no
    # attribute 'column'"), a table without energy_error pyarrow's KeyError,
    # and a path with a NUL pyarrow's ArrowInvalid.
    import pyarrow as pa

    with pytest.raises(TypeError, match=r"^table = 5 is neither a pyarrow Table nor the path"):
        sray.ensemble_statistic(5, 0.1)
    with pytest.raises(spark.ArgumentError, match=r"the table has no column energy_error"):
        sray.ensemble_statistic(pa.table({"member": [0], "t": [0.0]}), 0.1)
    with pytest.raises(spark.ArgumentError, match=r"names no file"):
        sray.ensemble_statistic(str(tmp_path / "a\0b.parquet"), 0.1)
    pq.write_table(pa.table({"member": [0], "t": [0.0]}), tmp_path / "other.parquet")
    with pytest.raises(spark.ArgumentError, match=r"other\.parquet' is not the Parquet file of a sweep"):
        sray.ensemble_statistic(tmp_path / "other.parquet", 0.1)
