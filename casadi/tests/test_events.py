"""Event functions in the CasADi rebuild of a system: translated from the
exported S-expressions, differentiated in t, q, v, absent without events,
corruptible for the negative test, and never allowed to name multipliers."""

import sys
import unittest
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spark_check.system import CasadiSystem, SourceError  # noqa: E402

SOURCE = {
    "name": "Disk",
    "coordinates": ["x", "phi"],
    "parameters": ["r"],
    "lagrangian": "(* 0.5 (+ (^ (v x) 2) (^ (v phi) 2)))",
    "constraints": ["(- (v x) (* (p r) (v phi)))"],
    "events": [
        {"name": "revolution", "direction": "Rising", "terminal": False, "function": "(sin (q phi))"},
        {"name": "mixed", "direction": "Both", "terminal": True, "function": "(* (q x) (v phi) t)"},
    ],
}


class EventTests(unittest.TestCase):
    def evaluate(self, source, corrupt=None):
        s = CasadiSystem(source, corrupt, 1e-10)
        return s, s.evaluate(2.0, [3.0, 0.5], [1.0, 4.0], [1.5], [0.0])

    def test_values_and_derivatives(self):
        _, e = self.evaluate(SOURCE)
        np.testing.assert_allclose(np.asarray(e["event_value"]).ravel(), [np.sin(0.5), 3.0 * 4.0 * 2.0])
        np.testing.assert_allclose(np.asarray(e["event_t"]).ravel(), [0.0, 12.0])
        np.testing.assert_allclose(np.asarray(e["event_q"]), [[0.0, np.cos(0.5)], [8.0, 0.0]])
        np.testing.assert_allclose(np.asarray(e["event_v"]), [[0.0, 0.0], [0.0, 6.0]])

    def test_no_events_no_outputs(self):
        source = {k: v for k, v in SOURCE.items() if k != "events"}
        s, e = self.evaluate(source)
        self.assertIsNone(s.events)
        self.assertNotIn("event_value", e)

    def test_corruption_changes_every_event(self):
        _, clean = self.evaluate(SOURCE)
        _, bad = self.evaluate(SOURCE, "event")
        diff = np.abs(np.asarray(bad["event_value"]) - np.asarray(clean["event_value"])).ravel()
        self.assertTrue(np.all(diff > 1e-11), diff)

    def test_multipliers_are_refused(self):
        source = dict(SOURCE, events=[{"name": "bad", "direction": "Both", "terminal": False, "function": "(psi 0)"}])
        with self.assertRaises(SourceError):
            CasadiSystem(source)


if __name__ == "__main__":
    unittest.main()
