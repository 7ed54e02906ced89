"""Ensembles that locate events (`ensemble(..., events=True)`): every member
runs alone, and its events and samples are those of `integrate(...,
events=True)` for it alone, bit for bit; a terminal event ends its member
only, which is NaN at the later sample times and carries its end in
`t_stop`. Registered systems (whose events are not terminal) and a compiled
sleigh whose turn is terminal."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import spark
from test_compile import declaration

pytestmark = pytest.mark.usefixtures("compiles_without_optimization")

EVENT_FIELDS = ("name", "index", "rising", "terminal", "t", "step")


def assert_same_events(a: list[spark.Event], b: list[spark.Event]) -> None:
    assert [[getattr(e, f) for f in EVENT_FIELDS] for e in a] == [[getattr(e, f) for f in EVENT_FIELDS] for e in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.q, y.q)
        np.testing.assert_array_equal(x.v, y.v)


def assert_member_is_its_run(e: spark.Ensemble, j: int, run: spark.Trajectory) -> None:
    """Member `j` of `e` against its solo run: the same events; the same
    samples at the ensemble's times up to the run's end and NaN after;
    `t_stop` the run's last time."""
    assert_same_events(e.events[j], run.events)
    assert e.t_stop[j] == run.t[-1]
    ended = bool(run.events) and run.events[-1].terminal
    # The solo run's samples are a prefix of the ensemble's times, then (when
    # a terminal event ended it off those times) the event's state.
    kept = len(run.t) - 1 if ended and run.t[-1] not in e.t else len(run.t)
    assert kept <= len(e.t)
    np.testing.assert_array_equal(e.t[:kept], run.t[:kept])
    for column in ("q", "v", "energy", "constraint"):
        ours, alone = getattr(e, column)[j], getattr(run, column)
        np.testing.assert_array_equal(ours[:kept], alone[:kept], err_msg=column)
        assert np.isnan(ours[kept:]).all(), column
    if ended:
        assert e.t_stop[j] == run.events[-1].t < e.t[-1]
        assert kept < len(e.t)
        np.testing.assert_array_equal(run.q[-1], run.events[-1].q)
    else:
        assert kept == len(e.t) and e.t_stop[j] == e.t[-1]


def check_members(system: spark.System, e: spark.Ensemble, q0s, v0s, plan: dict) -> None:
    """Every member of `e` against `system.integrate(..., events=True)` for
    it alone with the same arguments. A tolerance-driven ensemble without
    `t_eval` records `t_end` alone, as the run with `t_eval=[t_end]` does;
    its events are also those of the run without `t_eval`, which records
    every accepted step."""
    for j in range(len(q0s)):
        run = system.integrate("gauss", 2, q0=q0s[j], v0=v0s[j], events=True, **plan)
        if "rtol" in plan and "t_eval" not in plan:
            assert_same_events(e.events[j], run.events)
            run = system.integrate("gauss", 2, q0=q0s[j], v0=v0s[j], events=True, t_eval=[plan["t_end"]], **plan)
        assert_member_is_its_run(e, j, run)


# --- registered systems ------------------------------------------------------


def sleigh_members() -> tuple[np.ndarray, np.ndarray]:
    """Sleighs with headings θ0 and rates θ̇0, each moving along its blade
    (the constraint −sin θ ẋ + cos θ ẏ = 0 holds)."""
    headings = np.array([0.0, 0.3, -0.2, 1.0, 0.1])
    rates = np.array([0.5, 1.5, -0.4, 0.2, 3.0])
    speed = np.array([1.0, 0.5, 2.0, 1.0, 0.3])
    q0s = np.stack([np.zeros(5), np.zeros(5), headings], axis=1)
    v0s = np.stack([speed * np.cos(headings), speed * np.sin(headings), rates], axis=1)
    return q0s, v0s


REGISTERED_PLANS = (
    dict(h=0.05, steps=300, every=3),
    dict(h=-0.05, steps=200, t0=1.0, t_eval=np.linspace(0.9, -9.0, 34)),
    dict(rtol=1e-8, t_end=15.0, t_eval=np.linspace(0.25, 15.0, 60)),
    dict(rtol=1e-7, atol=1e-9, t_end=15.0, max_step=0.5),
)


@pytest.mark.parametrize("plan", REGISTERED_PLANS, ids=["fixed-every-3", "fixed-backward-t_eval", "rtol-t_eval",
                                                        "rtol-t_end"])
def test_each_members_events_are_its_integrate_events_bit_for_bit(plan):
    sleigh = spark.system("sleigh")
    q0s, v0s = sleigh_members()
    e = sleigh.ensemble("gauss", 2, q0s=q0s, v0s=v0s, events=True, **plan)
    assert len(e.events) == 5 and e.t_stop.shape == (5,)
    assert sum(len(x) for x in e.events) >= 3
    check_members(sleigh, e, q0s, v0s, plan)
    assert all(x.name == "turn" and not x.terminal for m in e.events for x in m)
    # The same on one thread.
    one = sleigh.ensemble("gauss", 2, q0s=q0s, v0s=v0s, events=True, threads=1, **plan)
    for j in range(5):
        assert_same_events(one.events[j], e.events[j])
        np.testing.assert_array_equal(one.q[j], e.q[j])


def test_the_lane_system_locates_events_member_by_member():
    """The McLachlan–Perlmutter particles step in SIMD lane groups without
    events; with them each member runs alone and equals its solo run."""
    qs, vs = zip(*(spark._native.mp7_initial_values(j, 3) for j in range(4)))
    q0s, v0s = np.array(qs), np.array(vs)
    plan = dict(h=0.05, steps=200, every=10)
    e = spark.ensemble("mp7-nh", "gauss", 2, q0s=q0s, v0s=v0s, events=True, **plan)
    assert all(e.events) and all(x.name == "section" for m in e.events for x in m)
    check_members(spark.system("mp7-nh"), e, q0s, v0s, plan)
    plain = spark.ensemble("mp7-nh", "gauss", 2, q0s=q0s, v0s=v0s, **plan)
    assert plain.events == [[], [], [], []]
    np.testing.assert_array_equal(plain.t_stop, np.full(4, plain.t[-1]))
    np.testing.assert_array_equal(plain.q, e.q)


def test_events_of_an_ensemble_of_a_system_that_declares_none_are_an_error():
    with pytest.raises(spark.SparkError, match="member 0: .*declares no events"):
        spark.ensemble("skate", "gauss", 2, 0.1, 10, np.zeros((2, 3)), [[0, 0, 1.0], [0, 0, 2.0]], events=True)
    with pytest.raises(TypeError, match="events"):
        spark.ensemble("sleigh", "gauss", 2, 0.1, 10, *sleigh_members(), events="yes")


def test_a_sweep_refuses_events_before_ray_starts(tmp_path):
    import spark.ray

    q0s, v0s = sleigh_members()
    with pytest.raises(spark.ArgumentError, match=r"events=True is not taken by spark.ray.sweep.*spark.ensemble"):
        spark.ray.sweep("sleigh", "gauss", 2, 0.05, 10, q0s, v0s, out=str(tmp_path / "s.parquet"), events=True)
    assert not (tmp_path / "s.parquet").exists()


def test_a_module_that_predates_ensemble_events_is_refused_for_them():
    """A module cached by an older spark.compile returns neither `events`
    nor `t_stop` from its ensemble: asked for events it is an error, not an
    ensemble without any; a plain ensemble still works."""
    info = spark._native.system_info_of("sleigh")

    def old_ensemble(request):
        kept = {k: v for k, v in request.items() if k != "events"}
        d = spark._native.ensemble("sleigh", kept)
        del d["events"], d["t_stop"]
        return d

    old = spark.System(info, None, old_ensemble)
    q0s, v0s = sleigh_members()
    e = old.ensemble("gauss", 2, 0.05, 20, q0s, v0s)
    assert e.events == [[]] * 5 and (e.t_stop == e.t[-1]).all()
    with pytest.raises(spark.SparkError, match="predates events in ensembles"):
        old.ensemble("gauss", 2, 0.05, 20, q0s, v0s, events=True)


# --- a compiled system with a terminal event -----------------------------------


@pytest.fixture(scope="module")
def terminal(tmp_path_factory) -> spark.System:
    """The sleigh with its turn terminal."""
    text = declaration("ChaplyginSleigh")
    turn = "events: { turn: falling(dot(theta)) }"
    assert turn in text
    cache: Path = tmp_path_factory.mktemp("spark-cache")
    return spark.compile(text.replace(turn, "events: { turn: falling(dot(theta)) terminal }"), cache_dir=str(cache))


TERMINAL_PLANS = (
    dict(h=0.05, steps=120, every=3),
    dict(h=0.05, steps=120, t_eval=np.linspace(0.1, 6.0, 40)),
    dict(rtol=1e-8, t_end=6.0, t_eval=np.linspace(0.1, 6.0, 40)),
    dict(rtol=1e-8, t_end=6.0),
)


@pytest.mark.parametrize("plan", TERMINAL_PLANS, ids=["fixed-every-3", "fixed-t_eval", "rtol-t_eval", "rtol-t_end"])
def test_a_terminal_event_ends_its_member_alone(terminal, plan):
    q0s, v0s = sleigh_members()
    e = terminal.ensemble("gauss", 2, q0s=q0s, v0s=v0s, events=True, **plan)
    ended = [bool(m) and m[-1].terminal for m in e.events]
    # Some members turn before the end and stop there, the others run on.
    assert any(ended) and not all(ended), [m and m[-1].t for m in e.events]
    check_members(terminal, e, q0s, v0s, plan)
    assert ended == [bool(t < e.t[-1]) for t in e.t_stop]
    assert np.isnan(e.q[ended, -1]).all() and not np.isnan(e.q[[not x for x in ended]]).any()
