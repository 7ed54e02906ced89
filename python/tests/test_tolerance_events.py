"""Tolerance-driven runs (`rtol`/`atol`), output times (`t_eval`) and the
events a system declares (`events=True`), for registered systems and for
systems built by `spark.compile`: both go through the runtime's
`integrate_plan`."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import spark
import spark._compile
from test_compile import declaration

pytestmark = pytest.mark.usefixtures("compiles_without_optimization")

T_END = 10.0


@pytest.fixture(scope="module")
def skate() -> spark.System:
    return spark.system("skate")


@pytest.fixture(scope="module")
def reference(skate):
    """The skate from its default state to t = 10, converged far below the
    errors the tests compare (Gauss s = 4, h = 10⁻³: about 10⁻¹³)."""
    return skate.integrate("gauss", 4, 0.001, 10_000)


def test_a_tolerance_driven_run_lands_on_t_end_and_its_error_falls_with_rtol(skate, reference):
    errors = {}
    for rtol in (1e-6, 1e-10):
        run = skate.integrate("gauss", 2, rtol=rtol, t_end=T_END)
        assert run.t[0] == 0.0 and run.t[-1] == T_END
        # every = 1: one sample per accepted step, besides the initial one.
        c = run.controller
        assert isinstance(c, spark.ControllerStats)
        assert c.accepted == len(run.t) - 1 == run.steps
        assert c.solves >= 3 * c.accepted and c.newton_iterations >= c.solves
        h = np.diff(run.t)
        assert np.all(h > 0)
        # The controller's steps vary: small at the start, long later.
        assert h.max() > 5 * h.min(), (h.min(), h.max())
        assert c.smallest_step == pytest.approx(h.min(), rel=1e-12)
        assert c.largest_step == pytest.approx(h.max(), rel=1e-12)
        assert run.events == []
        errors[rtol] = max(np.abs(run.q[-1] - reference.q[-1]).max(), np.abs(run.v[-1] - reference.v[-1]).max())
    assert errors[1e-6] < 1e-3, errors
    assert errors[1e-10] < errors[1e-6] / 100, errors
    # atol alone sets rtol to its value; rtol alone, atol.
    a = skate.integrate("gauss", 2, atol=1e-8, t_end=T_END)
    b = skate.integrate("gauss", 2, rtol=1e-8, atol=1e-8, t_end=T_END)
    c = skate.integrate("gauss", 2, rtol=1e-8, t_end=T_END)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(c.q, b.q)
    # every records every so many accepted steps, and the end.
    sparse = skate.integrate("gauss", 2, rtol=1e-8, t_end=T_END, every=10)
    assert sparse.t[-1] == T_END and len(sparse.t) < len(b.t) // 5
    np.testing.assert_array_equal(sparse.q[1], b.q[10])


def test_a_fixed_step_run_has_no_controller_and_max_step_bounds_the_steps(skate):
    assert skate.integrate("gauss", 2, 0.1, 10).controller is None
    run = skate.integrate("gauss", 2, rtol=1e-6, t_end=T_END, max_step=0.05, first_step=0.01)
    assert np.diff(run.t).max() <= 0.05 * (1 + 1e-12)
    assert run.t[1] == pytest.approx(0.01)


def test_t_eval_at_step_ends_reproduces_the_fixed_run_bit_for_bit(skate):
    plain = skate.integrate("gauss", 2, 0.1, 100)
    picked = [3, 17, 50, 100]
    sampled = skate.integrate("gauss", 2, 0.1, 100, t_eval=plain.t[picked])
    np.testing.assert_array_equal(sampled.t, plain.t[[0, *picked]])
    for column in ("q", "v", "energy", "constraint"):
        np.testing.assert_array_equal(getattr(sampled, column), getattr(plain, column)[[0, *picked]], err_msg=column)
    assert sampled.controller is None and sampled.events == []


def test_t_eval_off_the_grid_is_within_the_methods_accuracy(skate, reference):
    times = [0.05, 1.234, 5.55, 9.99]
    exact = skate.integrate("gauss", 4, 0.001, 10_000, t_eval=times)
    assert list(exact.t) == [0.0, *times]
    # The plain run's error at its steps is about 2e-6 (h = 0.1, order 4).
    fixed = skate.integrate("gauss", 2, 0.1, 100, t_eval=times)
    tolerance = skate.integrate("gauss", 2, rtol=1e-8, t_end=T_END, t_eval=np.array(times))
    for run in (fixed, tolerance):
        assert list(run.t) == [0.0, *times]
        assert np.abs(run.q - exact.q).max() < 1e-4
        assert np.abs(run.v - exact.v).max() < 1e-4
        # Not the state at the step ends around the time.
        assert np.abs(run.q[1] - skate.q0).max() > 1e-3
    # The run ends at the last time, before t_end.
    short = skate.integrate("gauss", 2, rtol=1e-8, t_end=T_END, t_eval=[1.0, 2.0])
    assert short.t[-1] == 2.0 and short.controller.accepted < tolerance.controller.accepted


def test_events_of_registered_systems_are_zeros_of_their_functions():
    sleigh = spark.system("sleigh")
    run = sleigh.integrate("gauss", 2, events=True, t_end=20.0)
    assert run.events, "the sleigh turns at least once"
    for e in run.events:
        assert isinstance(e, spark.Event)
        assert (e.name, e.index, e.rising, e.terminal) == ("turn", 0, False, False)
        assert 0.0 < e.t <= 20.0 and e.q.shape == e.v.shape == (3,)
        # turn: falling(dot(theta)).
        assert abs(e.v[2]) < 1e-9, e
        assert run.t[e.step] <= e.t <= run.t[e.step + 1]
        with pytest.raises(dataclasses.FrozenInstanceError):
            e.t = 0.0
        with pytest.raises(ValueError):
            e.q[0] = 1.0
    # Without events=True none is located, and the run is the same.
    plain = sleigh.integrate("gauss", 2, t_end=20.0)
    assert plain.events == []
    np.testing.assert_array_equal(plain.q, run.q)

    mp7 = spark.system("mp7-nh")
    for kw in (dict(), dict(rtol=1e-8, t_end=30.0)):
        run = mp7.integrate("gauss", 2, events=True, **kw)
        assert len(run.events) > 3
        times = [e.t for e in run.events]
        assert times == sorted(times) and run.t[0] < times[0] and times[-1] <= run.t[-1]
        for e in run.events:
            # section: rising(q2).
            assert (e.name, e.rising, e.terminal) == ("section", True, False)
            assert abs(e.q[1]) < 1e-9 and e.v[1] > 0


def test_systems_name_their_declared_events(skate):
    assert skate.events == [] and skate.info["events"] == []
    (turn,) = spark.system("sleigh").events
    assert (turn["name"], turn["direction"], turn["terminal"]) == ("turn", "falling", False)
    assert "theta" in turn["function"]
    assert [e["name"] for e in spark.system("mp7-nh").events] == ["section"]
    assert spark.system("mp7-nh").events[0]["direction"] == "rising"


def test_events_of_a_system_that_declares_none_are_an_error(skate):
    with pytest.raises(spark.SparkError, match="declares no events"):
        skate.integrate("gauss", 2, 0.1, 10, events=True)
    with pytest.raises(spark.SparkError, match="declares no events"):
        skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, events=True)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(rtol=1e-6, steps=10, t_end=1.0), spark.ArgumentError, "steps = 10 does not apply"),
        (dict(rtol=1e-6, h=0.1, t_end=1.0), spark.ArgumentError, "h = 0.1 does not apply"),
        (dict(atol=1e-6, max_halvings=2, t_end=1.0), spark.ArgumentError, "max_halvings = 2 does not apply"),
        (dict(rtol=1e-6), spark.SparkError, "needs t_end"),
        (dict(rtol=-1e-6, t_end=1.0), spark.ArgumentError, "rtol = -1e-06 must be finite and ≥ 0"),
        (dict(atol=float("nan"), t_end=1.0), spark.ArgumentError, "atol = nan must be finite"),
        (dict(rtol=0.0, atol=0, t_end=1.0), spark.ArgumentError, "both 0"),
        (dict(rtol=True, t_end=1.0), TypeError, "rtol = True is a bool"),
        (dict(rtol="1e-6", t_end=1.0), TypeError, "rtol = '1e-6' is a string"),
        (dict(rtol=1e-6, t_end=1.0, first_step=0.0), spark.ArgumentError, "first_step = 0.0 must be"),
        (dict(rtol=1e-6, t_end=1.0, first_step=1e-320), spark.ArgumentError, "first_step = 1e-320 is subnormal"),
        # Fixed steps below the resolution of t at t0 = 1e12 (1.2e-4):
        # their rounded times would repeat.
        (dict(h=1e-4, steps=3, t0=1e12), spark.SparkError, "resolution of t at t0"),
        (dict(rtol=1e-6, t_end=1.0, max_step=-1.0), spark.ArgumentError, "max_step = -1.0 must be positive"),
        (dict(rtol=1e-6, t_end=1.0, max_steps=0), spark.ArgumentError, "max_steps = 0 is less than 1"),
        (dict(rtol=1e-6, t_end=1.0, max_steps=2.5), spark.SparkError, "max_steps = 2.5 must be a whole number"),
        (dict(h=0.1, steps=10, max_steps=100), spark.ArgumentError, "max_steps = 100 applies to tolerance"),
        (dict(h=0.1, steps=10, t_eval=[0.5, 0.2]), spark.ArgumentError, "strictly increasing"),
        (dict(h=0.1, steps=10, t_eval=[0.5, 0.5]), spark.ArgumentError, "strictly increasing"),
        (dict(h=0.1, steps=10, t_eval=[0.5, 1.5]), spark.ArgumentError, "t = 1.5, outside the run's interval"),
        (dict(rtol=1e-6, t_end=1.0, t_eval=[-0.1, 0.5]), spark.ArgumentError, "outside the run's interval"),
        (dict(h=0.1, steps=10, t_eval=[0.5], every=2), spark.ArgumentError, "every = 2 does not apply with t_eval"),
        (dict(h=0.1, steps=10, t_eval=[0.5], every=1), spark.ArgumentError, "every = 1 does not apply with t_eval"),
        (dict(h=0.1, steps=10, t_eval=[[0.5, 0.6]]), spark.ArgumentError, "1-D array"),
        (dict(h=0.1, steps=10, t_eval=[]), spark.ArgumentError, "non-empty"),
        (dict(h=0.1, steps=10, t_eval=[0.5, float("nan")]), spark.ArgumentError, "non-finite"),
        (dict(h=0.1, steps=10, t_eval=[True, 0.5]), TypeError, "t_eval holds a bool"),
        (dict(h=0.1, steps=10, events="yes"), TypeError, "events = 'yes' is not a bool"),
        (dict(h=0.1, steps=10, events=1), TypeError, "events = 1 is not a bool"),
    ],
)
def test_bad_arguments_raise_the_documented_exceptions(skate, kwargs, error, match):
    with pytest.raises(error, match=match):
        skate.integrate("gauss", 2, **kwargs)


def test_a_tolerance_driven_run_far_from_t_zero_starts_at_the_resolution_of_t(skate):
    # The estimated first step, 3.54e-3, lies below 16 units in the last
    # place of 1e12 (3.55e-3): the run starts from that floor.
    run = skate.integrate("gauss", 2, rtol=1e-6, t0=1e12, t_end=1e12 + 1.0)
    assert run.t[0] == 1e12 and run.t[-1] == 1e12 + 1.0
    assert np.all(np.diff(run.t) > 0)
    near = skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0)
    np.testing.assert_allclose(run.q[-1], near.q[-1], atol=1e-4)


def test_the_runtimes_messages_name_the_keywords(skate):
    with pytest.raises(spark.SparkError, match=r"invalid option rtol = 1\.000e-17") as raised:
        skate.integrate("gauss", 2, rtol=1e-17, t_end=1.0)
    assert "AdaptiveOptions" not in str(raised.value)
    with pytest.raises(spark.SparkError, match=r"3 step attempts \(the limit: max_steps\)") as raised:
        skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, max_steps=3)
    assert "--max-steps" not in str(raised.value)
    with pytest.raises(spark.SparkError, match=r"the largest step, max_step = 1\.000e-6, needs at least 1\.000e6 steps") as raised:
        skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, max_step=1e-6, max_steps=5)
    assert "--max-step" not in str(raised.value) and "AdaptiveOptions" not in str(raised.value)
    assert "(the limit: max_steps); raise max_step or the limit" in str(raised.value)
    with pytest.raises(spark.SparkError, match="t_end other than t0"):
        skate.integrate("gauss", 2, rtol=1e-6, t_end=0.0)
    # A first step below the resolution of t at t0 (3.6e-9 at 1e6) is
    # refused before the first step, naming the keyword.
    with pytest.raises(spark.SparkError, match=r"the first step, first_step = 1\.000e-12, is below 3\.553e-9") as raised:
        skate.integrate("gauss", 2, rtol=1e-6, t0=1e6, t_end=1e6 + 1.0, first_step=1e-12)
    assert "--first-step" not in str(raised.value) and "AdaptiveOptions" not in str(raised.value)


def test_ensembles_keep_their_arguments(skate):
    q0s, v0s = np.zeros((2, 3)), np.array([[0, 0, 1.0], [0, 0, 2.0]])
    e = skate.ensemble("gauss", 2, 0.1, 20, q0s, v0s)
    assert e.q.shape == (2, 21, 3) and e.controller is None
    # A tolerance-driven ensemble refuses the fixed steps, as `integrate`.
    with pytest.raises(spark.ArgumentError, match="h = 0.1 does not apply to a tolerance-driven run"):
        skate.ensemble("gauss", 2, 0.1, 20, q0s, v0s, rtol=1e-6, t_end=1.0)
    # Events are located per member (test_ensemble_events.py); the skate
    # declares none.
    with pytest.raises(spark.SparkError, match="declares no events"):
        skate.ensemble("gauss", 2, 0.1, 20, q0s, v0s, events=True)


# --- compiled systems ---------------------------------------------------------


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("spark-cache")


SLEIGH = declaration("ChaplyginSleigh")
TURN = "events: { turn: falling(dot(theta)) }"
assert TURN in SLEIGH


def assert_same_run(a: spark.Trajectory, b: spark.Trajectory) -> None:
    for column in ("t", "q", "v", "energy", "constraint"):
        np.testing.assert_array_equal(getattr(a, column), getattr(b, column), err_msg=column)
    assert a.controller == b.controller
    assert len(a.events) == len(b.events)
    for x, y in zip(a.events, b.events):
        fields = ("name", "index", "rising", "terminal", "t", "step")
        assert [getattr(x, f) for f in fields] == [getattr(y, f) for f in fields]
        np.testing.assert_array_equal(x.q, y.q)
        np.testing.assert_array_equal(x.v, y.v)


def test_a_compiled_copy_of_a_registered_system_runs_the_same_plans(cache):
    compiled = spark.compile(SLEIGH, cache_dir=str(cache))
    registered = spark.system("sleigh")
    kw = dict(q0=registered.q0, v0=registered.v0)
    for plan in (
        dict(h=0.05, steps=400, events=True),
        dict(rtol=1e-8, t_end=20.0, events=True),
        dict(rtol=1e-7, atol=1e-9, t_end=20.0, t_eval=np.linspace(0.5, 19.5, 39), events=True),
        dict(h=0.05, steps=400, t_eval=[0.01, 1.0, 10.0, 19.99]),
    ):
        a = compiled.integrate("gauss", 2, **kw, **plan)
        b = registered.integrate("gauss", 2, **kw, **plan)
        assert_same_run(a, b)
        if plan.get("events"):
            assert a.events and all(abs(e.v[2]) < 1e-9 for e in a.events)
    with pytest.raises(spark.SparkError, match=r"invalid option rtol = 1\.000e-17") as raised:
        compiled.integrate("gauss", 2, rtol=1e-17, t_end=1.0, **kw)
    assert "AdaptiveOptions" not in str(raised.value)
    with pytest.raises(spark.ArgumentError, match="steps = 10 does not apply"):
        compiled.integrate("gauss", 2, rtol=1e-6, steps=10, t_end=1.0, **kw)
    skate = spark.compile(declaration("Skate"), cache_dir=str(cache))
    with pytest.raises(spark.SparkError, match="declares no events"):
        skate.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1], events=True)
    # A negative mass is refused for compiled systems as for registered ones.
    with pytest.raises(spark.SparkError, match=r"kinetic energy is not positive.*m = -1\.000e0"):
        skate.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1], params={"m": -1.0})


def test_a_terminal_event_of_a_compiled_system_ends_the_run(cache):
    text = SLEIGH.replace(TURN, "events: { turn: falling(dot(theta)) terminal }")
    terminal = spark.compile(text, cache_dir=str(cache))
    counting = spark.compile(SLEIGH, cache_dir=str(cache))
    registered = spark.system("sleigh")
    assert [(e["name"], e["terminal"]) for e in terminal.events] == [("turn", True)]
    assert counting.events == registered.events
    kw = dict(q0=registered.q0, v0=registered.v0, events=True)
    for plan in (
        dict(h=0.05, steps=400),
        dict(rtol=1e-8, t_end=20.0),
        dict(rtol=1e-8, t_end=20.0, t_eval=np.linspace(0.1, 19.9, 199)),
    ):
        run = terminal.integrate("gauss", 2, **kw, **plan)
        (event,) = run.events
        assert event.terminal and event.name == "turn"
        assert run.t[-1] == event.t < 20.0
        np.testing.assert_array_equal(run.q[-1], event.q)
        np.testing.assert_array_equal(run.v[-1], event.v)
        # The same steps as the run that counts the turn and goes on.
        first = counting.integrate("gauss", 2, **kw, **plan).events[0]
        assert (first.t, first.step, first.terminal) == (event.t, event.step, False)
        if "t_eval" in plan:
            before = plan["t_eval"][plan["t_eval"] < event.t]
            np.testing.assert_array_equal(run.t, [0.0, *before, event.t])


def test_a_module_that_predates_the_new_keys_is_refused_for_them_not_run_as_fixed_steps():
    """A module cached by an older spark.compile ignores rtol, t_eval and
    events and returns no `controller`: such a request is an error, not a
    silent run of fixed steps (a plain fixed run still works)."""
    info = spark._native.system_info_of("skate")

    def old_module(request):
        ignored = ("rtol", "atol", "first_step", "max_step", "max_steps", "t_end", "t_eval", "events")
        kept = {k: v for k, v in request.items() if k not in ignored}
        d = spark._native.integrate("skate", {"h": 0.1, "steps": 10} | kept)
        del d["controller"], d["events"]
        return d

    old = spark.System(info, old_module, None)
    assert old.integrate("gauss", 2, 0.1, 10).controller is None
    for kw in (dict(rtol=1e-6, t_end=1.0), dict(h=0.1, steps=10, t_eval=[0.5]), dict(h=0.1, steps=10, events=True)):
        with pytest.raises(spark.SparkError, match="predates rtol, t_eval and events"):
            old.integrate("gauss", 2, **kw)
    assert spark._compile.MODULE_INTERFACE.startswith("3: rtol, t_eval, events; events and controller in the result")


class _Huge:
    """A sequence that says it holds 10⁸ times and fails the test if
    anything reads them."""

    def __len__(self):
        return 10**8

    def __array__(self, *args, **kwargs):
        raise AssertionError("t_eval was materialized")

    def __iter__(self):
        raise AssertionError("t_eval was materialized")

    def __getitem__(self, i):
        raise AssertionError("t_eval was materialized")


def test_more_output_times_than_memory_holds_are_refused_before_they_are_read(skate):
    # 10⁸ times: as a Python list of floats 3.2 GB, before the native check
    # of the record refused the run. The count alone is checked first,
    # against the record's limit, naming the most times that fit.
    words = (r"t_eval holds 1\.000e8 times: the run would record .* more than the limit .*; "
             r"give at most \d+ output times")
    with pytest.raises(spark.ArgumentError, match=words):
        skate.integrate("gauss", 2, 1e-9, 10**9, t_eval=_Huge())
    with pytest.raises(spark.ArgumentError, match=words):
        skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, t_eval=_Huge())
    q0s, v0s = np.zeros((2, 3)), np.array([[0, 0, 1.0]] * 2)
    with pytest.raises(spark.ArgumentError, match=r"t_eval holds 1\.000e8 times"):
        skate.ensemble("gauss", 2, 1e-9, 10**9, q0s, v0s, t_eval=_Huge())
    # An array of 10⁸ times that takes no memory itself (a broadcast view):
    # refused with next to no allocation (no copy, no list).
    import tracemalloc

    times = np.broadcast_to(np.float64(0.5), (10**8,))
    tracemalloc.start()
    try:
        with pytest.raises(spark.ArgumentError, match=r"t_eval holds 1\.000e8 times"):
            skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, t_eval=times)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10**7, peak
    # An ensemble's members are counted together: 1000 members of 10⁶ times.
    many = np.zeros((1000, 3)), np.tile([0, 0, 1.0], (1000, 1))
    with pytest.raises(spark.ArgumentError, match=r"t_eval holds 1\.000e6 times: the 1000 members would record"):
        skate.ensemble("gauss", 2, 1e-6, 10**6, *many, t_eval=np.broadcast_to(np.float64(0.5), (10**6,)))
