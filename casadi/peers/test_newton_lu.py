"""The Newton-LU peer against spark's own steps and its stop rule.

Reads the export of ``spark-casadi-export`` (path in ``SPARK_CASADI_EXPORT``;
``casadi/run.sh`` sets it after exporting) and, for the particle, the skate,
the robot and the McLachlan–Perlmutter particles (n = 7) with Gauss
s = 1..3 and Lobatto IIIA-B s = 2..3 (the exported steps, at the paper's
step sizes), builds the peer's C, takes the exported step with it from the
same cold start, and checks:

- the peer's stage velocities, multipliers, ``v1`` and ``q1`` agree with
  spark's to 1e-13;
- its stop rule: every residual evaluation but the last has ``|F|∞ > 1e-14``
  and is followed by a factorization whose update has ``|Δx|∞ > 1e-14``; the
  last either has ``|F|∞ ≤ 1e-14`` (and no factorization follows) or is
  followed by an update with ``|Δx|∞ ≤ 1e-14``;
- a step from converged unknowns (the peer's own, and spark's) takes one
  residual evaluation and no factorization.

Run: ``SPARK_CASADI_EXPORT=out/casadi/export.json casadi/.venv/bin/python -m unittest casadi/peers/test_newton_lu.py``
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import unittest
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import newton_lu  # noqa: E402
from spark_check.system import CasadiSystem  # noqa: E402

SYSTEMS = ("particle", "skate", "robot", "mp7")
METHODS = {("gauss", 1), ("gauss", 2), ("gauss", 3), ("lobatto-iiia-b", 2), ("lobatto-iiia-b", 3)}
AGREEMENT = 1e-13


def load_export():
    path = os.environ.get("SPARK_CASADI_EXPORT")
    if not path:
        raise RuntimeError("set SPARK_CASADI_EXPORT to the JSON written by spark-casadi-export (casadi/run.sh does)")
    return json.loads(Path(path).read_text())


class NewtonLuPeer(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        doc = load_export()
        cls.systems = {s["name"]: s for s in doc["systems"]}
        cls.steps = [
            st for st in doc["steps"]
            if st["system"] in SYSTEMS and (st["method"]["key"], int(st["method"]["stages"])) in METHODS
        ]
        cls.tmp = tempfile.TemporaryDirectory(prefix="newton-lu-test-")
        cls.cases = []
        for st in cls.steps:
            entry = cls.systems[st["system"]]
            system = CasadiSystem(entry["source"])
            label = f'{st["system"]} {st["method"]["key"]} s={st["method"]["stages"]}'
            exe = newton_lu.build(system, st["method"], Path(cls.tmp.name), label)
            cls.cases.append((label, st, entry, system, exe))

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_every_system_and_method_is_covered(self):
        covered = {(st["system"], st["method"]["key"], int(st["method"]["stages"])) for st in self.steps}
        want = {(sy, name, s) for sy in SYSTEMS for name, s in METHODS}
        self.assertEqual(covered, want)

    def test_one_step_agrees_with_spark(self):
        for label, st, entry, system, exe in self.cases:
            with self.subTest(label):
                s, n, m = int(st["method"]["stages"]), system.n, system.m
                x0 = newton_lu.initial_guess(st["v0"], s, m)
                out = newton_lu.step(exe, st["t0"], st["h"], st["q0"], st["v0"], entry["parameter_values"], x0)
                self.assertEqual(out.status, 0, out)
                V = out.x[: s * n].reshape(s, n)
                psi = out.x[s * n : s * (n + m)].reshape(s, m)
                v1 = out.x[s * (n + m) :]
                q1 = np.asarray(st["q0"]) + st["h"] * np.asarray(st["method"]["b"]) @ V
                for name, ours, theirs in (
                    ("V", V, st["stage_velocities"]),
                    ("psi", psi, st["psi"]),
                    ("v1", v1, st["v1"]),
                    ("q1", q1, st["q1"]),
                ):
                    err = float(np.max(np.abs(ours - np.asarray(theirs, dtype=float))))
                    self.assertLessEqual(err, AGREEMENT, f"{label}: {name} differs from spark's by {err:.3e}")

    def test_stop_rule(self):
        for label, st, entry, system, exe in self.cases:
            with self.subTest(label):
                s, m = int(st["method"]["stages"]), system.m
                x0 = newton_lu.initial_guess(st["v0"], s, m)
                out = newton_lu.step(exe, st["t0"], st["h"], st["q0"], st["v0"], entry["parameter_values"], x0)
                self.assertEqual(out.status, 0, out)
                f, dx = out.residual_norms, out.update_norms
                self.assertEqual(len(f), out.evaluations)
                self.assertGreaterEqual(out.evaluations, 2, f"{label}: the cold start is not already converged")
                for k in range(len(f) - 1):
                    self.assertGreater(f[k], newton_lu.TOLERANCE, f"{label}: evaluation {k} should have stopped")
                    self.assertGreater(dx[k], newton_lu.TOLERANCE, f"{label}: update {k} should have stopped")
                if f[-1] <= newton_lu.TOLERANCE:
                    self.assertEqual(out.factorizations, out.evaluations - 1, label)
                    self.assertTrue(np.isnan(dx[-1]), label)
                else:
                    self.assertLessEqual(dx[-1], newton_lu.TOLERANCE, label)
                    self.assertEqual(out.factorizations, out.evaluations, label)

    def test_converged_guess_costs_no_factorization(self):
        for label, st, entry, system, exe in self.cases:
            s, n, m = int(st["method"]["stages"]), system.n, system.m
            args = (exe, st["t0"], st["h"], st["q0"], st["v0"], entry["parameter_values"])
            first = newton_lu.step(*args, newton_lu.initial_guess(st["v0"], s, m))
            spark_x = np.concatenate([
                np.asarray(st["stage_velocities"], dtype=float).ravel(),
                np.asarray(st["psi"], dtype=float).ravel(),
                np.asarray(st["v1"], dtype=float),
            ])
            self.assertEqual(spark_x.size, s * (n + m) + n)
            for whose, guess in (("its own", first.x), ("spark's", spark_x)):
                with self.subTest(f"{label} from {whose} solution"):
                    again = newton_lu.step(*args, guess)
                    self.assertEqual((again.status, again.evaluations, again.factorizations), (0, 1, 0), again)
                    self.assertLessEqual(again.residual_norms[0], newton_lu.TOLERANCE)


if __name__ == "__main__":
    unittest.main()
