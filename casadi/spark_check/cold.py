"""Hard cold steps: spark's step against the root on the branch from ``h → 0``.

Where a velocity-dependent force changes the velocity by much more than
itself within one step (``h`` times the force's rate between 2 and 10), the
SPARK equations can have several roots, and which one a Newton iteration
finds depends on where it starts. The step a method defines is the root on
the branch of solutions that starts at ``V_i = v0`` for ``h → 0``. This
module finds that root by continuation in the step size: the equations are
solved at ``θh`` for ``θ`` rising from ``THETA_START`` to 1, each solve
starting from the previous solutions' extrapolation, and the last one
polished to the limit of double precision (:meth:`StepSolver.solve`).

Independently, CasADi's Newton from the constant guess ``V_i = v0, Ψ = 0,
v1 = v0`` (what :func:`spark_check.step.solve_step` does) gives a root too.
When the two are farther apart than ``SAME_ROOT`` the case is *ambiguous*:
the constant guess found another root (or none), and only the branch root
is the reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict

import casadi as ca
import numpy as np

from . import compare
from .step import StepSolution, StepSolver

# spark's step must equal the branch root to this, in compare.errors' scaled measure.
TOLERANCE = 1e-13
# Two roots this close (scaled) are the same root.
SAME_ROOT = 1e-10
# The continuation starts at θ = THETA_START from the constant guess.
THETA_START = 1e-3
# Largest and smallest increments of θ.
MAX_DTHETA = 0.05
MIN_DTHETA = 1e-7
# A continuation step is accepted when its Newton converges in at most this
# many iterations from the extrapolated guess ...
TRACK_ITERATIONS = 6
# ... and moves the unknowns by at most this fraction of their size.
TRACK_MOVE = 0.05


class ContinuationError(RuntimeError):
    """The branch from h → 0 could not be followed up to h."""


@dataclass
class Reference:
    """The branch root and the constant-guess root of one cold step."""

    branch: StepSolution
    constant: StepSolution
    distance: float  # scaled distance from the constant-guess root to the branch root
    continuation_steps: int

    @property
    def ambiguous(self) -> bool:
        return not self.distance <= SAME_ROOT


def solution_distance(a: StepSolution, b: StepSolution) -> float:
    """Largest scaled error (``compare.errors``) of ``a`` against ``b`` over
    ``q1, v1, Ψ, V``."""
    return max(
        compare.errors(getattr(a, key), getattr(b, key))[0] for key in ("q1", "v1", "psi", "stage_velocities")
    )


class BranchSolver:
    """The branch root by continuation in ``h``, and the constant-guess root."""

    def __init__(self, system, parameter_values, method: Dict):
        self.exact = StepSolver(system, parameter_values, method)
        # Tracking solves: a few Newton iterations to a loose tolerance; how
        # many it took decides whether the increment of θ was small enough.
        self.track = ca.rootfinder(
            "track",
            "newton",
            self.exact.g,
            {"abstol": 1e-11, "abstolStep": 1e-12, "max_iter": TRACK_ITERATIONS, "error_on_fail": False},
        )

    def _track(self, t0: float, h: float, q0, v0, guess: np.ndarray):
        par = self.exact.par(t0, h, q0, v0)
        x = np.array(self.track(guess, par)).ravel()
        stats = self.track.stats()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(x)))
        return ok, x

    def branch(self, t0: float, h: float, q0, v0):
        """The root on the branch from ``h → 0`` and the number of
        continuation steps it took."""
        theta = THETA_START
        ok, x = self._track(t0, theta * h, q0, v0, self.exact.constant_guess(v0))
        if not ok:
            raise ContinuationError(f"no root at θ = {theta:g} from the constant guess")
        previous = None  # (θ, x) of the solution before
        dtheta, steps = THETA_START, 0
        while theta < 1.0:
            target = min(1.0, theta + dtheta)
            if previous is None:
                guess = x
            else:
                guess = x + (target - theta) / (theta - previous[0]) * (x - previous[1])
            ok, y = self._track(t0, target * h, q0, v0, guess)
            move = float(np.max(np.abs(y - x))) if ok else np.inf
            if ok and move <= TRACK_MOVE * (1.0 + float(np.max(np.abs(x)))):
                previous, theta, x = (theta, x), target, y
                steps += 1
                dtheta = min(MAX_DTHETA, 1.5 * dtheta)
            else:
                dtheta /= 2.0
                if dtheta < MIN_DTHETA:
                    raise ContinuationError(f"the branch turns or ends near θ = {theta:.6g}")
        return self.exact.solve(t0, h, q0, v0, x0=x), steps

    def reference(self, t0: float, h: float, q0, v0) -> Reference:
        branch, steps = self.branch(t0, h, q0, v0)
        constant = self.exact.solve(t0, h, q0, v0)
        return Reference(branch, constant, solution_distance(constant, branch), steps)
