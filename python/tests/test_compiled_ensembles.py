"""Ensembles of a system declared from Python: every member, those whose
steps are halved included, is bit for bit its own `integrate`, for a system
forced in `t` whose parameters the call changes and for one whose constraint
is nonlinear in `v`, forward and backward."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import spark

pytestmark = pytest.mark.usefixtures("compiles_without_optimization")

FORCED = """
    pub struct ForcedBladeEnsemble {
        coordinates: [x, y, th],
        parameters: { m = 1.3, inertia = 0.7, k = 0.8, a = 0.9, w = 2.3, b = 0.4 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(th)^2 - k/2*(x^2 + y^2),
        constraints: [ cos(th)*dot(y) - sin(th)*dot(x) ],
        forces: { th: a*sin(w*t), x: b*cos(t) },
    }
"""

NONLINEAR = """
    pub struct QuadConstraintEnsemble {
        coordinates: [x, y, z],
        parameters: { c = 0.5, g = 1.0 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + 2*y^2)/2 - g*z,
        constraints: [ dot(z) - c*(dot(x)*dot(y) + sin(t)*dot(x)^2) ],
    }
"""


def members(which: str, scale: float):
    rng = np.random.default_rng(3)
    count = 11  # a full lane group and a partial one
    if which == "forced":
        th = rng.uniform(-1, 1, count)
        u = rng.uniform(0.1, 1.0, count) * scale
        q0s = np.c_[rng.uniform(-0.5, 0.5, count), rng.uniform(-0.5, 0.5, count), th]
        v0s = np.c_[u * np.cos(th), u * np.sin(th), rng.uniform(-1, 1, count) * scale]
        return q0s, v0s, {"w": 3.1, "b": 0.7}
    q0s = rng.uniform(-1, 1, (count, 3))
    vx, vy = rng.uniform(-1, 1, count) * scale, rng.uniform(-1, 1, count) * scale
    # At t0 = 0 the constraint is ż = c ẋẏ, with c = 0.8 as passed.
    return q0s, np.c_[vx, vy, 0.8 * vx * vy], {"c": 0.8}


@pytest.mark.parametrize(
    "which, h, steps, scale, newton",
    [
        ("forced", 0.05, 60, 1.0, "full"),
        ("forced", 3.0, 10, 10.0, "full"),
        ("forced", -1.5, 20, 6.0, "simplified"),
        ("nonlinear", 0.05, 60, 1.0, "full"),
        ("nonlinear", 1.0, 20, 3.0, "simplified"),
    ],
)
def test_members_of_a_compiled_ensemble_are_their_single_runs(tmp_path_factory, which, h, steps, scale, newton):
    cache = tmp_path_factory.getbasetemp() / "compiled-ensembles"
    system = spark.compile(FORCED if which == "forced" else NONLINEAR, cache_dir=str(cache))
    q0s, v0s, params = members(which, scale)
    halvings = 0
    for method, s in (("gauss", 2), ("gauss", 3), ("lobatto-iiia-b", 3)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", spark.StepHalvingWarning)
            ens = spark.ensemble(system, method, s, h, steps, q0s, v0s, params=params, newton=newton, threads=2)
            for j in range(len(q0s)):
                one = system.integrate(method, s, h, steps, q0=q0s[j], v0=v0s[j], params=params, newton=newton)
                np.testing.assert_array_equal(ens.t, one.t)
                np.testing.assert_array_equal(ens.q[j], one.q, err_msg=f"{method} s = {s}, member {j}")
                np.testing.assert_array_equal(ens.v[j], one.v, err_msg=f"{method} s = {s}, member {j}")
                assert ens.rejected_steps[j] == one.rejected_steps, f"{method} s = {s}, member {j}"
                assert ens.smallest_step[j] == one.smallest_step, f"{method} s = {s}, member {j}"
        halvings += int(np.sum(ens.rejected_steps))
    # The large steps do halve some members' steps: their lanes retry and
    # halve them as `integrate` does, and count the halvings alike.
    assert (halvings > 0) == (abs(h) >= 1.0), halvings
