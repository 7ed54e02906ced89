"""Registered systems from Python: facts, errors, and bit-for-bit agreement
with the Rust CLI (`spark run`) on the paper's four experiments."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import spark
from conftest import interrupt_after_start, run_cli


def test_every_registered_system_is_listed_with_its_facts():
    names = spark.systems()
    assert names[:4] == ["particle", "skate", "robot", "mp7"]
    assert len(names) >= 34
    skate = spark.system("Skate")
    assert (skate.name, skate.n, skate.m) == ("skate", 3, 1)
    assert skate.coordinates == ["x", "y", "theta"]
    assert set(skate.parameters) == {"m", "inertia", "g", "beta"}
    assert skate.structure["constraint_form"] == "linear"
    # The particle's potential q₁² + q₂² is quadratic; the skate's is linear.
    assert spark.system("particle").structure["constant_stiffness"]
    assert not skate.structure["constant_stiffness"]
    assert spark.system("robot").structure["diagonal_stiffness"]
    assert not skate.structure["diagonal_stiffness"]
    assert not spark.system("particle").structure["diagonal_stiffness"]
    assert skate.effects == {"forcing": False, "nonideal": False, "holonomic": False}
    assert spark.system("rod-pendulum").effects["holonomic"]
    keys = [m[0] for m in spark.methods()]
    assert "lobatto-iiib-a-lda" in keys and "gauss" in keys


def _same(py_run: spark.Trajectory, cli: dict[str, np.ndarray], coordinates: list[str]) -> None:
    np.testing.assert_array_equal(py_run.t, cli["t"])
    for i, c in enumerate(coordinates):
        np.testing.assert_array_equal(py_run.q[:, i], cli[f"q_{c}"], err_msg=f"q_{c}")
        np.testing.assert_array_equal(py_run.v[:, i], cli[f"v_{c}"], err_msg=f"v_{c}")
    np.testing.assert_array_equal(py_run.energy, cli["energy"])
    np.testing.assert_array_equal(py_run.constraint, cli["constraint_residual"])
    assert py_run.e0 == cli["e0"]


# The paper's experiments (Figs. 8.1–8.3 over the paper's intervals; Fig. 8.4
# two members of its ensemble over a fiftieth of its interval, both readings
# of the constraint, all three methods, simplified Newton as `spark paper`).
PAPER = (
    [("particle", "gauss", s, 0.2, 1250, None, "full") for s in (1, 2, 3)]
    + [("skate", "lobatto-iiia-b", s, 0.1, 1000, None, "full") for s in (2, 3, 4)]
    + [("robot", "lobatto-iiia-b-d", s, 0.2, 750, None, "full") for s in (2, 3, 4)]
    + [
        (sys, method, 2, 0.05, 20_000, j, "simplified")
        for sys in ("mp7-nh", "mp7")
        for method in ("lobatto-iiia-b", "modified-lobatto-iiia-b", "lobatto-iiib-a-lda")
        for j in (0, 9)
    ]
)


@pytest.mark.parametrize("system,method,s,h,steps,member,newton", PAPER)
def test_paper_experiments_match_the_cli_bit_for_bit(spark_cli, tmp_path, system, method, s, h, steps, member, newton):
    sys = spark.system(system)
    every = 1 if member is None else 100
    q0, v0 = (sys.q0, sys.v0) if member is None else spark._native.mp7_initial_values(member, 9)
    args = ["--method", method, "--stages", str(s), "--h", str(h), "--t-end", str(steps * h), "--every", str(every),
            "--newton", newton, "--q0", ",".join(map(repr, q0)), "--v0", ",".join(map(repr, v0))]
    cli = run_cli(spark_cli, tmp_path / "out", system, *args)
    run = sys.integrate(method, s, h, steps, q0=q0, v0=v0, every=every, newton=newton)
    assert run.steps == steps
    _same(run, cli, sys.coordinates)


def test_multipliers_and_holonomic_drift_on_request():
    run = spark.integrate("skate", "gauss", 2, 0.1, 20, multipliers=True)
    assert run.psi.shape == (21, 1) and np.all(np.isfinite(run.psi))
    assert run.holonomic is None
    assert spark.integrate("skate", "gauss", 2, 0.1, 20).psi is None
    pend = spark.integrate("rod-pendulum", "gauss", 2, 0.05, 40)
    assert pend.holonomic.shape == (41,) and pend.holonomic.max() < 1e-6


def test_errors_are_python_exceptions_with_the_rust_message():
    with pytest.raises(spark.SparkError, match="unknown system `skat`.*did you mean `skate`"):
        spark.system("skat")
    with pytest.raises(spark.SparkError, match="v0 violates the constraints"):
        spark.integrate("skate", "gauss", 2, 0.1, 10, v0=[0.0, 1.0, 0.0])
    with pytest.raises(spark.SparkError, match="has no parameter|bta"):
        spark.integrate("skate", "gauss", 2, 0.1, 10, params={"bta": 1.0})
    with pytest.raises(spark.SparkError, match="unknown method|gaus"):
        spark.integrate("skate", "gaus", 2, 0.1, 10)
    with pytest.raises(spark.SparkError, match="s = 9"):
        spark.integrate("skate", "gauss", 9, 0.1, 10)
    with pytest.raises(spark.SparkError, match="q0 has 2 entries"):
        spark.integrate("skate", "gauss", 2, 0.1, 10, q0=[0.0, 0.0])
    with pytest.raises(spark.SparkError, match="step size"):
        spark.integrate("skate", "gauss", 2, float("nan"), 10)
    # a projected v0 is accepted
    run = spark.integrate("skate", "gauss", 2, 0.1, 10, v0=[0.0, 1.0, 0.0], project_v0=True)
    assert run.constraint.max() < 1e-12


def test_a_record_that_would_not_fit_in_memory_is_refused_before_any_step():
    # 2^62 recorded steps would grow the record until an allocation failure
    # aborts the interpreter; the request is refused at once with the
    # `every` that would fit.
    with pytest.raises(spark.SparkError, match=r"samples .* more than the limit .* record every \d+-th step"):
        spark.integrate("skate", "gauss", 2, 0.1, 2**62)
    q0s = np.zeros((200_000, 3))
    v0s = np.tile([0.0, 0.0, 1.0], (200_000, 1))
    with pytest.raises(spark.SparkError, match=r"samples .* more than the limit"):
        spark.ensemble("skate", "gauss", 2, 0.1, 200_000, q0s, v0s)
    with pytest.raises(spark.SparkError, match="must be a whole number"):
        spark.integrate("skate", "gauss", 2, 0.1, 10.5)
    with pytest.raises(spark.SparkError, match="not a finite number of steps"):
        spark.system("skate").integrate(h=0.1, t0=-1e308, t_end=1e308)
    # An infinite end is no time at all: a bad argument, named as such.
    with pytest.raises(spark.ArgumentError, match="t_end = inf is not a finite time"):
        spark.system("skate").integrate(h=0.1, t_end=float("inf"))


LONG_RUNS = {
    "run": 'spark.integrate("skate", "gauss", 2, 0.1, 2**40, every=2**30)',
    # Lanes: eight McLachlan-Perlmutter members.
    "lane ensemble": (
        "q0s = np.array([[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]] * 8)\n"
        "v0s = np.zeros((8, 7)); v0s[:, 1] = np.linspace(0.0, 0.5, 8)\n"
        'spark.ensemble("mp7", "lobatto-iiia-b", 2, 0.05, 2**40, q0s, v0s, every=2**30, newton="simplified")'
    ),
    # Each member alone (the skate has no lane kernel).
    "member runs": (
        "q0s = np.zeros((3, 3)); v0s = np.array([[0, 0, 1.0]] * 3)\n"
        'spark.ensemble("skate", "gauss", 2, 0.1, 2**40, q0s, v0s, every=2**30)'
    ),
}


@pytest.mark.parametrize("kind", sorted(LONG_RUNS))
def test_ctrl_c_stops_a_long_run(kind):
    script = "import numpy as np, spark\nprint('running')\n" + LONG_RUNS[kind] + "\n"
    took, err = interrupt_after_start(script)
    assert "KeyboardInterrupt" in err, err
    assert took < 10.0, f"{kind}: {took:.1f} s from Ctrl-C to exit"


def test_arguments_that_cannot_work_are_refused_up_front():
    # A subnormal step (1/h overflows inside the step) and one that does not
    # move t0 are refused before any step, saying what to use.
    with pytest.raises(spark.SparkError, match=r"subnormal.*use \|h\| ≥ 2.2e-308"):
        spark.integrate("skate", "gauss", 2, 1e-311, 3)
    with pytest.raises(spark.SparkError, match="resolution of t"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, t0=1e20)
    # The default end that rounds back to t0 names t0, not a t_end never given.
    with pytest.raises(spark.SparkError, match=r"t0 = 1e20 leaves no interval.*default end"):
        spark.integrate("skate", "gauss", 2, t0=1e20)
    with pytest.raises(spark.SparkError, match="needs exactly 1 stage, got s = 2"):
        spark.integrate("skate", "euler-1", 2, 0.1, 3)
    # Fractional counts are refused, not truncated.
    for kw in ({"s": 2.5}, {"every": 1.5}):
        with pytest.raises(spark.SparkError, match="must be a whole number"):
            spark.integrate("skate", **{"method": "gauss", "h": 0.1, "steps": 3, "s": 2, **kw})


@pytest.mark.parametrize("system", ["skate", "mp7"])
def test_an_ensemble_refuses_more_threads_than_it_starts(system):
    # 2**40 threads would make rayon start thousands of threads and stall the
    # interpreter; the request is refused at once.
    entry = spark.system(system)
    q0s, v0s = np.tile(entry.q0, (2, 1)), np.tile(entry.v0, (2, 1))
    for threads in (1025, 2**40):
        with pytest.raises(spark.SparkError, match="more than 1024"):
            spark.ensemble(system, "gauss", 2, 0.1, 3, q0s, v0s, threads=threads)
    assert spark.ensemble(system, "gauss", 2, 0.1, 3, q0s, v0s, threads=4).q.shape[0] == 2


def test_a_bool_where_a_number_is_meant_is_a_type_error_naming_the_argument():
    # A bool is not a number here, though Python reads h=True as 1.0 and
    # s=True as 1.
    skate = spark.system("skate")
    q0s, v0s = np.tile(skate.q0, (2, 1)), np.tile(skate.v0, (2, 1))
    calls = {
        "h": lambda: spark.integrate("skate", "gauss", 2, True, 3),
        "s": lambda: spark.integrate("skate", "gauss", True, 0.1, 3),
        "steps": lambda: spark.integrate("skate", "gauss", 2, 0.1, True),
        "t0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, t0=False),
        "t_end": lambda: skate.integrate("gauss", 2, 0.1, t_end=True),
        "every": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, every=True),
        "newton_tol": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, newton_tol=True),
        "params['g']": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": True}),
        "q0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, q0=[False, 0, 0]),
        "v0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, v0=np.array([0, 0, 1], dtype=bool)),
        "threads": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, threads=True),
        "q0s": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, [[0, 0, True]] * 2, v0s),
        "h ": lambda: spark.ensemble("skate", "gauss", 2, np.True_, 3, q0s, v0s),
    }
    for name, call in calls.items():
        with pytest.raises(TypeError, match=rf"^{re.escape(name.strip())} .*(bool|a number)"):
            call()
    with pytest.raises(TypeError, match="h = '0.1' is a string"):
        spark.integrate("skate", "gauss", 2, "0.1", 3)
    # Numbers of any numeric type still work.
    assert spark.integrate("skate", "gauss", np.int64(2), np.float32(0.1), 3, t0=0).t.shape == (4,)


def test_a_newton_tolerance_of_one_or_more_is_refused():
    # It bounds the last update relative to 1 + |z|: 1 or more would accept
    # an update with no correct digit as a converged step.
    for tol in (1.0, 1e300, float("inf"), 0.0, -1e-9):
        with pytest.raises(spark.SparkError, match=r"newton_tol = .* must lie in \(0, 1\)"):
            spark.integrate("skate", "gauss", 2, 0.1, 3, newton_tol=tol)
    assert spark.integrate("skate", "gauss", 2, 0.1, 3, newton_tol=1e-6).t.shape == (4,)


def test_halved_steps_warn_and_are_counted_or_refused_with_max_halvings_0(spark_cli, tmp_path):
    # The robot at h = 3 (its paper step is 0.2): Newton fails on three of
    # the first four steps, each is covered by two half steps. The run
    # succeeds, but it is not one of fixed steps h, so it warns and says how
    # far it departed, with the same steps as `spark run`.
    with pytest.warns(spark.StepHalvingWarning, match=r"3 of 4 steps failed in Newton .* 7 sub-steps .*smallest 1.5"):
        run = spark.integrate("robot", "gauss", 2, 3.0, 4)
    assert (run.steps, run.rejected_steps, run.steps_with_rejections, run.substeps) == (4, 3, 3, 7)
    assert run.smallest_step == 1.5
    robot = spark.system("robot")
    cli = run_cli(spark_cli, tmp_path / "out", "robot", "--h", "3", "--t-end", "12")
    _same(run, cli, robot.coordinates)
    # max_halvings=0: the first failing step is an error.
    with pytest.raises(spark.SparkError, match=r"step 0 .* failed: Newton diverged"):
        spark.integrate("robot", "gauss", 2, 3.0, 4, max_halvings=0)
    # Out of range or of the wrong kind: refused, naming it.
    with pytest.raises(spark.ArgumentError, match=r"max_halvings = 61 is more than 60; give 0 ≤ max_halvings ≤ 60"):
        spark.integrate("robot", "gauss", 2, 3.0, 4, max_halvings=61)
    with pytest.raises(spark.ArgumentError, match=r"max_halvings = -1 is less than 0"):
        spark.integrate("robot", "gauss", 2, 3.0, 4, max_halvings=-1)
    with pytest.raises(TypeError, match="max_halvings"):
        spark.integrate("robot", "gauss", 2, 3.0, 4, max_halvings=True)
    # A run at the paper's step halves nothing and does not warn.
    with warnings.catch_warnings():
        warnings.simplefilter("error", spark.StepHalvingWarning)
        fixed = spark.integrate("robot", "gauss", 2, 0.2, 10)
    halvings = (fixed.rejected_steps, fixed.steps_with_rejections, fixed.substeps, fixed.smallest_step)
    assert halvings == (0, 0, 10, 0.2)
    # An ensemble counts each member's halvings and warns once.
    q0s = np.array([robot.q0, robot.q0])
    v0s = np.array([robot.v0, robot.v0])
    with pytest.warns(spark.StepHalvingWarning, match=r"2 of 2 members halved steps .*6 halvings"):
        ens = spark.ensemble("robot", "gauss", 2, 3.0, 4, q0s, v0s)
    np.testing.assert_array_equal(ens.rejected_steps, [3, 3])
    np.testing.assert_array_equal(ens.smallest_step, [1.5, 1.5])
    np.testing.assert_array_equal(ens.q[0], run.q)


def test_a_start_where_no_step_can_succeed_is_refused_with_the_cause():
    # |v0|² overflows: named at the initial state (the first step would end
    # in an energy drift against E0 = inf).
    with pytest.raises(spark.SparkError, match=r"initial state: the energy .* is (inf|NaN).*overflows f64"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, q0=[0, 0, 0], v0=[0, 0, 1e155])
    # A zero mass: the mass matrix is singular at the start, with the
    # coordinate and the parameter (the first step would fail with a singular
    # Newton matrix).
    with pytest.raises(spark.SparkError, match=r"mass matrix W = d²L/dv².*coordinate `x`.*Parameters that are 0 here: m"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params={"m": 0.0})
    # A negative mass: the kinetic energy is negative along the skate's
    # heading; refused, naming the parameter, for a run and an ensemble
    # (the equations are regular, so it would run to a motion no
    # mechanical system has).
    negative = r"kinetic energy is not positive.*1 direction .*Parameters that are negative here: m = -1\.000e0"
    with pytest.raises(spark.SparkError, match=negative):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params={"m": -1.0})
    with pytest.raises(spark.SparkError, match=negative):
        spark.ensemble("skate", "gauss", 2, 0.1, 3, [[0, 0, 0]], [[0, 0, 1]], params={"m": -1.0})
    spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": -9.81, "beta": -0.5})
    # h² overflows in the Newton matrix: refused up front, saying so (the run
    # would fail after four halvings with a non-finite Jacobian).
    with pytest.raises(spark.SparkError, match=r"h = 1.000e300.*h² overflows f64.*smaller \|h\|"):
        spark.integrate("skate", "gauss", 2, 1e300, 1)


def test_a_final_time_is_reached_in_whole_steps_in_its_direction_or_refused():
    skate = spark.system("skate")
    # 10⁷ steps of 0.1 and half a hundredth of a step more: within the
    # relative tolerance alone (10⁻⁹ of the steps), the run would end at 10⁶,
    # 5e-4 short of t_end. As `spark run`, the tolerance is capped at a
    # thousandth of a step.
    with pytest.raises(spark.SparkError, match="not a whole number"):
        skate.integrate("gauss", 2, 0.1, t_end=1e6 + 5e-4, every=10**7)
    # An end behind t0, or at it, names the cause, not "not a whole number".
    with pytest.raises(spark.SparkError, match=r"t_end = -1\.0 lies behind t0 .* negative h"):
        skate.integrate("gauss", 2, 0.1, t_end=-1.0)
    with pytest.raises(spark.SparkError, match="shorter than one step"):
        skate.integrate("gauss", 2, 0.1, t_end=0.0)
    # Backward with a negative h, and round-off in the ratio, still run.
    assert skate.integrate("gauss", 2, -0.1, t_end=-1.0).t[-1] == pytest.approx(-1.0)
    assert skate.integrate("gauss", 2, 0.1, t_end=0.3).t.shape == (4,)


def test_steps_and_t_end_given_together_must_agree():
    # 10 steps of 0.1 end at 1, not at the t_end also given: one of the two
    # would be dropped, and the run returned for another interval than asked.
    skate = spark.system("skate")
    q0s, v0s = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    message = r"steps = 10 and t_end = 5.0 disagree: 10 steps of h = 0.1 from t0 = 0.0 end at t = 1.0"
    with pytest.raises(spark.ArgumentError, match=message):
        skate.integrate("gauss", 2, 0.1, 10, t_end=5.0)
    with pytest.raises(spark.ArgumentError, match=message):
        spark.ensemble("skate", "gauss", 2, 0.1, 10, q0s, v0s, t_end=5.0)
    with pytest.raises(spark.ArgumentError, match="steps = 10 and t_end = -1.0 disagree"):
        skate.integrate("gauss", 2, 0.1, 10, t_end=-1.0)
    # Both given and agreeing (up to the round-off of t_end / h) run as either alone.
    run = skate.integrate("gauss", 2, 0.1, 10, t_end=1.0)
    np.testing.assert_array_equal(run.q, skate.integrate("gauss", 2, 0.1, 10).q)
    assert spark.ensemble("skate", "gauss", 2, -0.1, 3, q0s, v0s, t_end=-0.3).t.shape == (4,)


def test_complex_numbers_and_strings_where_real_numbers_are_meant_are_type_errors():
    # NumPy's cast to float64 drops the imaginary part with a warning and
    # parses strings: unchecked, q0 = [1+2j, 0, 0] would run from x = 1,
    # h = 0.1+1j as h = 0.1, q0 = ["0", "0", "1"] from theta = 1.
    skate = spark.system("skate")
    q0s, v0s = np.tile(skate.q0, (2, 1)), np.tile(skate.v0, (2, 1))
    calls = {
        "h": lambda: spark.integrate("skate", "gauss", 2, np.complex128(0.1 + 1j), 3),
        "t0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, t0=1j),
        "params['g']": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": 9.81 + 0j}),
        "q0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, q0=np.array([1 + 2j, 0, 0])),
        "v0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, v0=["0", "0", "1"]),
        "q0 ": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, q0=np.array([0, 0, "1"], dtype=object)),
        "q0s": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s + 1j, v0s),
        "v0s": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s.astype(str)),
    }
    for name, call in calls.items():
        with pytest.raises(TypeError, match=rf"^{re.escape(name.strip())} .*(complex|string)"):
            call()
    # A parameter named by something else than a string is named as such
    # (PyO3's own message is "'int' object cannot be cast as 'str'").
    with pytest.raises(TypeError, match="params key 1 is not a string"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params={1: 9.81})


def test_integers_beyond_the_native_range_are_value_errors_naming_the_argument():
    # PyO3's own error for steps=2**70, "Python int too large to convert to
    # C long", names no argument, nor does Python's "int too large to convert
    # to float" for an int beyond the largest float.
    skate = spark.system("skate")
    q0s, v0s = np.tile(skate.q0, (2, 1)), np.tile(skate.v0, (2, 1))
    calls = {
        "steps": lambda: spark.integrate("skate", "gauss", 2, 0.1, 2**70),
        "s": lambda: spark.integrate("skate", "gauss", 2**64, 0.1, 3),
        "every": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, every=2**63),
        "threads": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, threads=2**70),
        "ensemble steps": lambda: spark.ensemble("skate", "gauss", 2, 0.1, -(2**70), q0s, v0s),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError, match=rf"^{name.split()[-1]} = -?\d+ is (more|less) than -?\d+; give 1 ≤ "):
            call()
    with pytest.raises(spark.ArgumentError, match=r"more than 9223372036854775807, the most a run can count"):
        skate.integrate(h=1e-300, t_end=1e-200)
    floats = {
        "h": lambda: spark.integrate("skate", "gauss", 2, 10**400, 3),
        "params['g']": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": -(10**400)}),
        "q0": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, q0=[10**400, 0, 0]),
        "v0s": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, [[0, 0, 10**400]] * 2),
    }
    for name, call in floats.items():
        with pytest.raises(ValueError, match=rf"^{re.escape(name)} .*too large for a float"):
            call()
    # Each is also a SparkError, as the other refusals of an argument.
    with pytest.raises(spark.SparkError):
        spark.integrate("skate", "gauss", 2, 0.1, 2**70)


def test_a_flag_that_is_not_a_bool_is_a_type_error_naming_it():
    # `project_v0="no"` is truthy: read as a bool, it would replace an
    # inconsistent v0 by its projection instead of refusing it, and
    # `multipliers="no"` would record ψ.
    for name in ("multipliers", "project_v0"):
        for value in ("no", 0, None, [False]):
            with pytest.raises(TypeError, match=rf"^{name} = .* is not a bool; pass True or False"):
                spark.integrate("skate", "gauss", 2, 0.1, 3, **{name: value})
    run = spark.integrate("skate", "gauss", 2, 0.1, 3, multipliers=np.bool_(True), project_v0=False)
    assert run.psi.shape == (4, 1)


def test_arguments_of_the_wrong_kind_are_type_errors_naming_them():
    # Unchecked, `params="g"` would raise dict()'s "dictionary update
    # sequence element #0 has length 1", `q0={}` float()'s "argument must be
    # a string or a real number, not 'dict'", ragged rows NumPy's
    # "inhomogeneous shape", and a None in q0 would run into "q0 has a
    # non-finite entry NaN": none names the argument.
    with pytest.raises(TypeError, match=r"^params = 'g' is not a mapping of parameter names to numbers"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params="g")
    with pytest.raises(TypeError, match=r"^params = 5 is not a mapping"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params=5)
    with pytest.raises(TypeError, match=r"^q0 = \{\} is not an array of real numbers"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, q0={})
    with pytest.raises(TypeError, match=r"^q0 holds None; pass real numbers"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, q0=[None, 0, 0])
    with pytest.raises(TypeError, match=r"^q0s = .* is not an array of real numbers"):
        spark.ensemble("skate", "gauss", 2, 0.1, 3, [[0, 0, 0], [0, 0]], [[0, 0, 1], [0, 0, 1]])
    # An empty mapping and a list of pairs are accepted as parameters.
    assert spark.integrate("skate", "gauss", 2, 0.1, 3, params={}).q.shape == (4, 3)
    run = spark.integrate("skate", "gauss", 2, 0.1, 3, params=[("g", 2.0)])
    assert np.array_equal(run.q, spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": 2.0}).q)


def test_the_native_request_names_an_integer_beyond_64_bits():
    # The native functions behind `spark.integrate` name the argument too,
    # where PyO3 alone raises "Python int too large to convert to C long".
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 2**70, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    with pytest.raises(ValueError, match=r"^`steps` = 1180591620717411303424 is outside the 64-bit integers"):
        spark._native.integrate("skate", request)
    with pytest.raises(ValueError, match=r"^`every` = 10+…0+ \(401 characters\) is outside"):
        spark._native.integrate("skate", {**request, "steps": 3, "every": 10**400})
    with pytest.raises(ValueError, match=r"^`h` = 10+…0+ \(401 characters\) is outside the floats"):
        spark._native.integrate("skate", {**request, "steps": 3, "h": 10**400})


def test_a_lone_surrogate_in_a_name_is_an_argument_error():
    # A str holding a lone surrogate ("\ud800", left by decoding bytes with
    # errors="surrogateescape") cannot cross into Rust as UTF-8: each name
    # that carries one is refused, naming the argument, instead of the raw
    # UnicodeEncodeError of the conversion.
    cases = {
        "name": lambda: spark.system("sk\ud800ate"),
        "method": lambda: spark.integrate("skate", "gauss\ud800", 2, 0.1, 3),
        "newton": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, newton="full\udcff"),
        "params key": lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g\ud800": 1.0}),
        "params key ": lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, [[0, 0, 0]], [[0, 0, 1]],
                                              params={"\udcff": 1.0}),
    }
    for what, call in cases.items():
        with pytest.raises(spark.ArgumentError, match=rf"^{what.strip()} .*lone surrogate U\+D[8C][0F][0F]"):
            call()
    # The native functions refuse it as well, naming the key.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    with pytest.raises(spark.ArgumentError, match=r"`method` .*lone surrogate"):
        spark._native.integrate("skate", {**request, "method": "\ud800"})
    with pytest.raises(spark.ArgumentError, match=r"params key .*lone surrogate"):
        spark._native.integrate("skate", {**request, "params": {"\ud800": 1.0}})
    with pytest.raises(spark.ArgumentError, match=r"lone surrogate"):
        spark._native.system_info_of("\ud800")


def test_options_out_of_range_are_argument_errors_naming_the_range():
    # Each is a bad argument, refused as spark.ArgumentError (a SparkError
    # and a ValueError) naming it and the range it takes.
    q0s, v0s = [[0, 0, 0]], [[0, 0, 1]]
    cases = [
        (r"max_halvings = 61 is more than 60; give 0 ≤ max_halvings ≤ 60",
         lambda: spark.integrate("robot", "gauss", 2, 3.0, 4, max_halvings=61)),
        (r"max_halvings = 61 is more than 60; give 0 ≤ max_halvings ≤ 60",
         lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, max_halvings=61)),
        (r"Gauss with s = 100 is not compiled into this program; supported: s = 1\.\.=5",
         lambda: spark.integrate("skate", "gauss", 100, 0.1, 3)),
        (r"Gauss with s = 100 is not compiled into this program",
         lambda: spark.ensemble("skate", "gauss", 100, 0.1, 3, q0s, v0s)),
        (r"symplectic Euler I needs exactly 1 stage, got s = 2",
         lambda: spark.integrate("skate", "euler-1", 2, 0.1, 3)),
        (r"Gauss with s = 6 is not compiled into this program; supported: s = 1\.\.=5",
         lambda: spark.integrate("skate", "gauss", 6, 0.1, 3)),
        (r"threads = 1025 is more than 1024; give 1 ≤ threads ≤ 1024",
         lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, threads=1025)),
        (r"newton_tol = 2\.000e0 must lie in \(0, 1\)",
         lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, newton_tol=2.0)),
        (r"newton_tol = NaN must lie in \(0, 1\)",
         lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, newton_tol=float("nan"))),
        (r"newton = `fast`: write \"full\" or \"simplified\"",
         lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, newton="fast")),
        (r"unknown method `nope`", lambda: spark.integrate("skate", "nope", 2, 0.1, 3)),
    ]
    for words, call in cases:
        with pytest.raises(spark.ArgumentError, match=words):
            call()
    # The native functions refuse them as ArgumentError too.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    native = [
        (r"max_halvings = 61 must lie in 0\.\.=60", {"max_halvings": 61}),
        (r"Gauss with s = 100 is not compiled into this program", {"s": 100}),
        (r"Lobatto IIIA-B needs between 2 and \d+ stages, got s = 1", {"method": "lobatto-iiia-b", "s": 1}),
        (r"s = 0 must be at least 1", {"s": 0}),
        (r"steps = 0 must be at least 1", {"steps": 0}),
        (r"every = -2 must be at least 1", {"every": -2}),
        (r"max_steps = 0 must be at least 1", {"rtol": 1e-6, "t_end": 1.0, "steps": None, "h": None, "max_steps": 0}),
    ]
    for words, change in native:
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.integrate("skate", {**request, **change})
    members = {**request, "q0s": q0s, "v0s": v0s}
    for threads, words in ((1025, "threads = 1025 is more than 1024"), (0, "threads = 0 must be at least 1")):
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.ensemble("skate", {**members, "threads": threads})
    with pytest.raises(spark.ArgumentError, match="an ensemble needs at least one member"):
        spark.ensemble("skate", "gauss", 2, 0.1, 3, np.zeros((0, 3)), np.zeros((0, 3)))
    # An unknown system is an ArgumentError with the closest name.
    with pytest.raises(spark.ArgumentError, match="unknown system `skat`.*did you mean `skate`"):
        spark.system("skat")


def test_a_time_that_is_not_finite_is_an_argument_error_naming_it():
    # A NaN or infinite t0 or t_end is the caller's bad argument: refused as
    # ArgumentError naming it, before any step, instead of a SparkError
    # about "the interval ... is not a finite number of steps", a member's
    # "invalid run", or (t_end with steps) a claim that the two disagree.
    skate = spark.system("skate")
    q0s, v0s = [skate.q0], [skate.v0]
    nan, inf = float("nan"), float("inf")
    for bad in (nan, inf, -inf):
        calls = {
            "t0": [
                lambda: skate.integrate("gauss", 2, 0.1, 10, t0=bad),
                lambda: skate.integrate("gauss", 2, 0.1, t0=bad),
                lambda: skate.integrate("gauss", 2, rtol=1e-6, t_end=1.0, t0=bad),
                lambda: spark.ensemble("skate", "gauss", 2, 0.1, 10, q0s, v0s, t0=bad),
                lambda: spark.ensemble("skate", "gauss", 2, None, None, q0s, v0s, t_end=1.0, t0=bad, rtol=1e-6),
            ],
            "t_end": [
                lambda: skate.integrate("gauss", 2, 0.1, t_end=bad),
                lambda: skate.integrate("gauss", 2, 0.1, 10, t_end=bad),
                lambda: skate.integrate("gauss", 2, rtol=1e-6, t_end=bad),
                lambda: spark.ensemble("skate", "gauss", 2, 0.1, None, q0s, v0s, t_end=bad),
                lambda: spark.ensemble("skate", "gauss", 2, None, None, q0s, v0s, t_end=bad, rtol=1e-6),
            ],
        }
        for name, cases in calls.items():
            for call in cases:
                with pytest.raises(spark.ArgumentError, match=rf"^{name} = {bad!r} is not a finite time; give a "
                                                              rf"finite {name}"):
                    call()
    # The native functions refuse them as ArgumentError too.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    tolerance = {**request, "h": None, "steps": None, "rtol": 1e-6, "t_end": 1.0}
    for bad in (nan, inf):
        with pytest.raises(spark.ArgumentError, match=r"`t0` = (NaN|inf) is not a finite time"):
            spark._native.integrate("skate", {**request, "t0": bad})
        with pytest.raises(spark.ArgumentError, match=r"`t_end` = (NaN|inf) is not a finite time"):
            spark._native.integrate("skate", {**tolerance, "t_end": bad})
        with pytest.raises(spark.ArgumentError, match=r"`t0` = (NaN|inf) is not a finite time"):
            spark._native.ensemble("skate", {**request, "t0": bad, "q0s": q0s, "v0s": v0s})


def test_unknown_and_repeated_parameter_names_are_argument_errors():
    # A name the system does not have is the caller's bad argument, named
    # with the names it has, before the run (it was a SparkError of the
    # run, "member 0: ..." in an ensemble).
    q0s, v0s = [[0, 0, 0]], [[0, 0, 1]]
    words = (r"^params key 'bta': system `skate` has no parameter `bta` \(did you mean `beta`\?\); its parameters: "
             r"m, inertia, g, beta")
    for call in (
        lambda: spark.integrate("skate", "gauss", 2, 0.1, 3, params={"bta": 1.0}),
        lambda: spark.integrate("skate", "gauss", 2, rtol=1e-6, t_end=1.0, params={"bta": 1.0}),
        lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, params={"bta": 1.0}),
        lambda: spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, params=[("g", 2.0), ("bta", 1.0)]),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            call()
    with pytest.raises(spark.ArgumentError, match=r"system `particle` has no parameter `m`; it has no parameters"):
        spark.integrate("particle", "gauss", 2, 0.1, 3, params={"m": 1.0})
    # A list of pairs that names a parameter twice is refused: dict() kept
    # the last value silently.
    with pytest.raises(spark.ArgumentError, match=r"^params names 'g' more than once \(1.0, 2.0\); give each "
                                                  r"parameter once"):
        spark.integrate("skate", "gauss", 2, 0.1, 3, params=[("g", 1.0), ("m", 1.0), ("g", 2.0)])
    with pytest.raises(spark.ArgumentError, match=r"^params names 'g' more than once"):
        spark.ensemble("skate", "gauss", 2, 0.1, 3, q0s, v0s, params=[("g", 1.0), ("g", 1.0)])
    # An iterator of pairs is read once, and its values are the run's (it
    # was read twice, and the second, empty reading ran the defaults).
    given = spark.integrate("skate", "gauss", 2, 0.1, 3, params=iter([("g", 2.0)]))
    np.testing.assert_array_equal(given.q, spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": 2.0}).q)
    # The native functions refuse an unknown name, and a value that is not
    # finite, as ArgumentError too.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    with pytest.raises(spark.ArgumentError, match=r"system `skate` has no parameter `bta` \(did you mean `beta`"):
        spark._native.integrate("skate", {**request, "params": {"bta": 1.0}})
    with pytest.raises(spark.ArgumentError, match=r"^system `skate` has no parameter `bta`"):
        spark._native.ensemble("skate", {**request, "params": {"bta": 1.0}, "q0s": q0s, "v0s": v0s})
    for bad in (float("nan"), float("inf")):
        with pytest.raises(spark.ArgumentError, match=r"parameter `g` = (NaN|inf) must be finite"):
            spark.integrate("skate", "gauss", 2, 0.1, 3, params={"g": bad})


def test_bad_steps_and_intervals_are_argument_errors_before_the_run():
    # The step size, the step count and the interval are the caller's
    # arguments: an end behind t0 or within one step, a step size that is
    # zero or not finite (h = 0 with t_end divided by zero), no h, no steps
    # and no t_end are refused as ArgumentError naming them, before the
    # run, not as a generic SparkError of the run ("invalid run: ...",
    # "member 0: ...").
    skate = spark.system("skate")
    q0s, v0s = [skate.q0], [skate.v0]
    nan, inf = float("nan"), float("inf")
    cases = [
        (r"^t_end = -1\.0 lies behind t0", lambda: skate.integrate("gauss", 2, 0.1, t_end=-1.0)),
        (r"^t_end = -1\.0 lies behind t0",
         lambda: spark.ensemble("skate", "gauss", 2, 0.1, None, q0s, v0s, t_end=-1.0)),
        (r"^the interval .* is shorter than one step", lambda: skate.integrate("gauss", 2, 0.1, t_end=0.04)),
        (r"^the interval .* is shorter than one step", lambda: skate.integrate("gauss", 2, 0.1, t_end=0.0)),
        (r"^the interval .* 3\.4999\d* steps .* not a whole number",
         lambda: skate.integrate("gauss", 2, 0.1, t_end=0.35)),
        (r"^the interval .* is not a finite number of steps",
         lambda: skate.integrate("gauss", 2, 0.1, t0=-1e308, t_end=1e308)),
        # Ends far from t = 0 print with every digit, so a reader tells
        # them apart (six decimals print both as 1.000000e+17).
        (r"^the interval from t0 = 1e17 to t_end = 1\.0000000000000002e17 is shorter than one step of h = 100\.0;",
         lambda: skate.integrate("gauss", 2, 100.0, t0=1e17, t_end=1e17 + 16)),
        (r"^steps = 2.5 must be a whole number", lambda: skate.integrate("gauss", 2, 0.1, 2.5)),
        (r"^steps = 0 is less than 1", lambda: spark.ensemble("skate", "gauss", 2, 0.1, 0, q0s, v0s)),
        (r"^give the step size h=", lambda: spark.ensemble("skate", "gauss", 2, None, 3, q0s, v0s)),
        (r"^give steps= .* or t_end=", lambda: spark.ensemble("skate", "gauss", 2, 0.1, None, q0s, v0s)),
        (r"needs t_end=", lambda: skate.integrate("gauss", 2, rtol=1e-6)),
        (r"^t_end = 0.0 is t0: a tolerance-driven run needs an interval",
         lambda: skate.integrate("gauss", 2, rtol=1e-6, t_end=0.0)),
        (r"^t_end = 0.0 is t0", lambda: spark.ensemble("skate", "gauss", 2, None, None, q0s, v0s, rtol=1e-6,
                                                        t_end=0.0)),
    ]
    for h in (0.0, -0.0, nan, inf, -inf):
        shown = "NaN" if h != h else repr(h)
        words = rf"^step size h = {re.escape(shown)} must be finite and nonzero"
        cases += [
            (words, lambda h=h: skate.integrate("gauss", 2, h, 3)),
            (words, lambda h=h: skate.integrate("gauss", 2, h, t_end=1.0)),
            (words, lambda h=h: spark.ensemble("skate", "gauss", 2, h, 3, q0s, v0s)),
        ]
    for words, call in cases:
        with pytest.raises(spark.ArgumentError, match=words):
            call()
    # The native functions refuse them as ArgumentError too: a step size
    # the runtime cannot step with, a missing h or steps, a count that is
    # not a whole number, a t_end beside fixed steps (which it would
    # ignore), a tolerance-driven request without an interval.
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    tolerance = {**request, "h": None, "steps": None, "rtol": 1e-6, "t_end": 1.0}
    native = [
        (r"^step size h = 0.000e0 must be finite and nonzero", {**request, "h": 0.0}),
        (r"^step size h = NaN must be finite and nonzero", {**request, "h": nan}),
        (r"^step size h = 1.000e300 from t0 = 0.000e0: step size is above 1.34e154", {**request, "h": 1e300}),
        (r"^the request has no `h`", {**request, "h": None}),
        (r"^the request has no `steps`", {**request, "steps": None}),
        (r"^`steps` = 2.5 must be a whole number", {**request, "steps": 2.5}),
        (r"^`t_end` applies to a tolerance-driven request", {**request, "t_end": 5.0}),
        (r"needs a finite t_end other than t0", {**tolerance, "t_end": 0.0}),
        (r"needs t_end", {**tolerance, "t_end": None}),
        (r"^`h` does not apply to a tolerance-driven run", {**tolerance, "h": 0.1}),
    ]
    for words, req in native:
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.integrate("skate", req)
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.ensemble("skate", {**req, "q0s": q0s, "v0s": v0s})


def test_a_missing_or_bad_initial_state_is_an_argument_error_before_the_run():
    # q0 and v0 of another length, of another shape or with an entry that
    # is not finite are refused as ArgumentError naming the entry, not as
    # the run's "invalid run: q0 has a non-finite entry".
    skate = spark.system("skate")
    for words, kw in (
        (r"^q0\[1\] = nan is not finite", dict(q0=[0, float("nan"), 0])),
        (r"^v0\[2\] = inf is not finite", dict(v0=[0, 0, float("inf")])),
        (r"^q0 has 2 entries but skate has 3 coordinates \(x, y, theta\)", dict(q0=[0, 0])),
        (r"^v0 must be a vector of 3 numbers; got shape \(1, 3\)", dict(v0=[[0, 0, 1]])),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            skate.integrate("gauss", 2, 0.1, 3, **kw)
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    for words, kw in (
        (r"^q0\[1\] = NaN is not finite", dict(q0=[0, float("nan"), 0])),
        (r"^q0 has 2 entries but the system has 3 coordinates", dict(q0=[0, 0])),
        (r"^v0 has 0 entries", dict(v0=None)),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            spark._native.integrate("skate", {**request, **kw})
