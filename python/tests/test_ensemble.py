"""The ensemble stepper (SIMD lane groups): members equal their single runs,
the same whatever the thread count; shapes and errors."""

from __future__ import annotations

import numpy as np
import pytest

import spark


def _members(k: int):
    qs, vs = zip(*(spark._native.mp7_initial_values(j, k - 1) for j in range(k)))
    return np.array(qs), np.array(vs)


def test_members_equal_single_runs_for_any_thread_count():
    q0s, v0s = _members(6)
    runs = [
        spark.ensemble("mp7-nh", "lobatto-iiia-b", 2, 0.05, 400, q0s, v0s, every=10, newton="simplified", threads=t)
        for t in (1, 2)
    ]
    for e in runs:
        assert e.q.shape == (6, 41, 7) and e.energy.shape == (6, 41) and e.t.shape == (41,)
    for field in ("q", "v", "energy", "constraint", "e0"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field))
    # A lane repeats the solo stepper's operations in the same order (the
    # lane kernel, with the stage values in lane form): each member is bit
    # for bit its single run.
    for j in (0, 3, 5):
        one = spark.integrate("mp7-nh", "lobatto-iiia-b", 2, 0.05, 400, q0=q0s[j], v0=v0s[j], every=10,
                              newton="simplified")
        np.testing.assert_array_equal(runs[0].t, one.t)
        np.testing.assert_array_equal(runs[0].q[j], one.q)
        np.testing.assert_array_equal(runs[0].energy[j], one.energy)
        assert runs[0].e0[j] == one.e0


def test_parameters_apply_to_every_member():
    q0s = np.zeros((2, 3))
    v0s = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    a = spark.ensemble("skate", "gauss", 2, 0.1, 50, q0s, v0s, {"g": 1.0})
    b = spark.ensemble("skate", "gauss", 2, 0.1, 50, q0s, v0s, {"g": 9.81})
    assert not np.array_equal(a.q, b.q)
    one = spark.integrate("skate", "gauss", 2, 0.1, 50, q0=q0s[1], v0=v0s[1], params={"g": 9.81})
    np.testing.assert_array_equal(b.q[1], one.q)


def test_ensemble_errors_name_the_member_and_the_shape():
    with pytest.raises(spark.SparkError, match=r"shape \(members, 3\)"):
        spark.ensemble("skate", "gauss", 2, 0.1, 5, np.zeros((2, 2)), np.zeros((2, 2)))
    # An ensemble takes no project_v0: its message does not offer it.
    for system, kw in (("skate", {}), ("skate", dict(t_eval=[0.2])), ("mp7", {})):
        n = spark.system(system).n
        q0s, v0s = np.array([spark.system(system).q0] * 2), np.zeros((2, n))
        v0s[1] = 1.0
        with pytest.raises(spark.SparkError, match="member 1: v0 violates") as e:
            spark.ensemble(system, "gauss", 2, 0.1, 5, q0s, v0s, **kw)
        assert "give the member a row of v0s with k = 0" in str(e.value)
        assert "pass project_v0" not in str(e.value)
    with pytest.raises(spark.SparkError, match="threads"):
        spark.ensemble("skate", "gauss", 2, 0.1, 5, np.zeros((1, 3)), np.array([[0, 0, 1.0]]), threads=0)


def test_missing_or_misshaped_initial_states_are_argument_errors_before_any_member_runs():
    # q0s and v0s are the caller's arguments: a missing one, a 1-D array,
    # rows of another width than the system's N, two shapes and an entry
    # that is not finite are refused as ArgumentError naming them, before
    # any member runs (a NaN failed as "member 0: invalid run: q0 has a
    # non-finite entry" once the members before it had run).
    q0s, v0s = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    bad_q, bad_v = q0s.copy(), v0s.copy()
    bad_q[1, 2] = np.nan
    bad_v[0, 1] = -np.inf
    for words, qs, vs in (
        (r"^give the initial states q0s= and v0s=.*\(q0s and v0s are missing\)", None, None),
        (r"^give the initial states q0s= and v0s=.*\(v0s is missing\)", q0s, None),
        (r"^q0s must be a 2-D array of shape \(members, N\).*got shape \(3,\)", q0s[0], v0s[0]),
        (r"^q0s and v0s must have shape \(members, 3\) for skate \(x, y, theta\); got \(2, 2\)",
         q0s[:, :2], v0s[:, :2]),
        (r"^q0s and v0s must have the same shape .* got \(2, 3\) and \(1, 3\)", q0s, v0s[:1]),
        (r"^q0s\[1, 2\] = nan is not finite \(member 1\)", bad_q, v0s),
        (r"^v0s\[0, 1\] = -inf is not finite \(member 0\)", q0s, bad_v),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            spark.ensemble("skate", "gauss", 2, 0.1, 5, qs, vs)
    # The native function refuses them as ArgumentError too.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 5}
    for words, members in (
        (r"^the request has no `q0s`", dict(v0s=v0s.tolist())),
        (r"^q0s and v0s must have shape \(members, 3\) = \(2, 3\); got rows of 2", dict(
            q0s=q0s[:, :2].tolist(), v0s=v0s[:, :2].tolist())),
        (r"^q0s has 2 rows but v0s has 1", dict(q0s=q0s.tolist(), v0s=v0s[:1].tolist())),
        (r"^row 1 of q0s has 2 numbers but row 0 of q0s has 3", dict(q0s=[[0, 0, 0], [0, 0]], v0s=v0s.tolist())),
        (r"^q0s\[1, 2\] = NaN is not finite \(member 1\)", dict(q0s=bad_q.tolist(), v0s=v0s.tolist())),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.ensemble("skate", {**request, **members})


def test_ensemble_releases_the_gil():
    """The main thread runs Python code while `spark.ensemble` steps in
    another thread. The switch interval is raised far above the call's
    length, so a thread holding the GIL is never made to give it up: had the
    call held the GIL, the worker would read the main thread's counter
    before and after the call with no main-thread bytecode in between, and
    the counter would not move at all."""
    import sys
    import threading
    import time

    q0s, v0s = _members(4)
    counter = [0]
    seen: list[int] = []

    def work():
        before = counter[0]
        e = spark.ensemble("mp7-nh", "lobatto-iiia-b", 2, 0.05, 100_000, q0s, v0s, every=100_000,
                           newton="simplified", threads=1)
        seen.append(counter[0] - before)
        assert e.energy.shape == (4, 2)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(60.0)
    try:
        worker = threading.Thread(target=work)
        worker.start()
        while worker.is_alive():
            counter[0] += 1
            time.sleep(1e-4)  # sleeping releases the GIL, so the worker can take it back on return
        worker.join()
    finally:
        sys.setswitchinterval(interval)
    assert len(seen) == 1, "the ensemble call failed in the worker thread"
    # Thousands of increments during the call when the GIL is released (the
    # main thread sleeps 0.1 ms per increment); none when it is held.
    assert seen[0] >= 100, f"the main thread advanced {seen[0]} times during the call"


def test_tolerance_driven_members_equal_their_single_runs_at_common_times():
    q0s = np.zeros((3, 3))
    v0s = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, -0.5]])
    times = [1.0, 2.5, 5.0]
    e = spark.ensemble("skate", "gauss", 2, q0s=q0s, v0s=v0s, rtol=1e-8, t_end=5.0, t_eval=times, threads=2)
    assert e.q.shape == (3, 4, 3) and e.energy.shape == (3, 4)
    np.testing.assert_array_equal(e.t, [0.0, *times])
    assert set(e.controller) == {"accepted", "rejected", "newton_failures", "solves", "newton_iterations",
                                 "smallest_step", "largest_step"}
    for j in range(3):
        one = spark.integrate("skate", "gauss", 2, q0=q0s[j], v0=v0s[j], rtol=1e-8, t_end=5.0, t_eval=times)
        np.testing.assert_array_equal(e.q[j], one.q)
        np.testing.assert_array_equal(e.v[j], one.v)
        np.testing.assert_array_equal(e.energy[j], one.energy)
        assert e.steps[j] == one.steps
        assert e.controller["accepted"][j] == one.controller.accepted
        assert e.controller["rejected"][j] == one.controller.rejected
        assert e.controller["largest_step"][j] == one.controller.largest_step
    # The faster members take more steps for the same tolerance.
    assert e.steps[1] > e.steps[2]


def test_a_tolerance_driven_ensemble_records_t_end_unless_told_otherwise():
    q0s = np.zeros((2, 3))
    v0s = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    e = spark.ensemble("skate", "lobatto-iiia-b", 2, q0s=q0s, v0s=v0s, atol=1e-7, t_end=-3.0)
    np.testing.assert_array_equal(e.t, [0.0, -3.0])
    one = spark.integrate("skate", "lobatto-iiia-b", 2, q0=q0s[1], v0=v0s[1], atol=1e-7, t_end=-3.0)
    np.testing.assert_array_equal(e.q[1, -1], one.q[-1])


def test_fixed_step_members_at_output_times_equal_their_single_runs():
    q0s, v0s = _members(3)
    times = np.linspace(0.5, 10.0, 7)
    e = spark.ensemble("mp7-nh", "gauss", 2, 0.05, 200, q0s, v0s, t_eval=times)
    assert e.controller is None and e.q.shape == (3, 8, 7)
    np.testing.assert_array_equal(e.t, [0.0, *times])
    for j in range(3):
        one = spark.integrate("mp7-nh", "gauss", 2, 0.05, 200, q0=q0s[j], v0=v0s[j], t_eval=times)
        np.testing.assert_array_equal(e.q[j], one.q)
        assert e.steps[j] == one.steps == 200


def test_ensemble_arguments_that_do_not_apply_are_refused():
    q0s, v0s = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(spark.ArgumentError, match="every = 2 does not apply to a tolerance-driven ensemble"):
        spark.ensemble("skate", "gauss", 2, q0s=q0s, v0s=v0s, rtol=1e-6, t_end=1.0, every=2)
    with pytest.raises(spark.ArgumentError, match="h = 0.1 does not apply to a tolerance-driven run"):
        spark.ensemble("skate", "gauss", 2, 0.1, q0s=q0s, v0s=v0s, rtol=1e-6, t_end=1.0)
    with pytest.raises(spark.ArgumentError, match="every = 2 does not apply with t_eval"):
        spark.ensemble("skate", "gauss", 2, 0.1, 10, q0s, v0s, every=2, t_eval=[0.5])
    with pytest.raises(spark.ArgumentError, match="max_step = 0.1 applies to tolerance-driven runs only"):
        spark.ensemble("skate", "gauss", 2, 0.1, 10, q0s, v0s, max_step=0.1)
    with pytest.raises(spark.SparkError, match="needs t_end"):
        spark.ensemble("skate", "gauss", 2, q0s=q0s, v0s=v0s, rtol=1e-6)
    with pytest.raises(spark.SparkError, match="give the initial states q0s= and v0s="):
        spark.ensemble("skate", "gauss", 2, 0.1, 10)
    with pytest.raises(spark.SparkError, match="member 0: .*declares no events"):
        spark.ensemble("skate", "gauss", 2, 0.1, 10, q0s, v0s, events=True)
