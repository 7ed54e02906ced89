"""The branch root of spark_check.cold on a one-dimensional step with several roots.

Gauss s = 1 on ``ẍ = c sin ẋ`` is ``V − (hc/2) sin V = v0``: for ``hc/2 > 1``
it has several roots. The branch from ``h → 0`` starts at ``V = v0``;
Newton from the constant guess ``V = v0`` may find another one.
"""

import math
import sys
import unittest
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spark_check import cold  # noqa: E402
from spark_check.system import CasadiSystem  # noqa: E402

SOURCE = {
    "name": "SineDrive",
    "coordinates": ["x"],
    "parameters": ["c"],
    "lagrangian": "(* 0.5 (^ (v x) 2))",
    "constraints": [],
    "external_force": ["(* (p c) (sin (v x)))"],
}
# Gauss s = 1, the implicit midpoint rule.
MIDPOINT = {
    "key": "gauss",
    "stages": 1,
    "c": [0.5],
    "a": [[0.5]],
    "a_hat": [[0.5]],
    "a_tilde": [[0.5]],
    "b": [1.0],
    "b_hat": [1.0],
    "b_tilde": [1.0],
    "conditions": [],
}


def reference(c: float, v0: float) -> cold.Reference:
    return cold.BranchSolver(CasadiSystem(SOURCE), [c], MIDPOINT).reference(0.0, 1.0, [0.0], [v0])


class BranchRoot(unittest.TestCase):
    def test_the_constant_guess_finds_another_root_and_the_case_is_ambiguous(self):
        r = reference(4.0, 0.5)
        (v_branch,), (v_constant,) = r.branch.stage_velocities.ravel(), r.constant.stage_velocities.ravel()
        for v in (v_branch, v_constant):
            self.assertAlmostEqual(v - 2.0 * math.sin(v), 0.5, places=14)
        # Along the branch V grows from 0.5 with h (dV/dh > 0 while 1 − (hc/2) cos V > 0).
        self.assertGreater(v_branch, 2.0)
        self.assertLess(v_constant, 0.0)
        self.assertTrue(r.ambiguous)

    def test_a_single_root_is_the_branch_root(self):
        r = reference(2.0, 0.5)
        self.assertFalse(r.ambiguous)
        self.assertLessEqual(r.distance, 1e-15)
        (v,) = r.branch.stage_velocities.ravel()
        self.assertAlmostEqual(v - math.sin(v), 0.5, places=15)


if __name__ == "__main__":
    unittest.main()
