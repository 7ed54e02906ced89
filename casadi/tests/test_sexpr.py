"""Unit tests of the S-expression translator and the CasADi rebuild."""

import math
import sys
import unittest
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from spark_check import sexpr  # noqa: E402
from spark_check.system import CasadiSystem, SourceError  # noqa: E402
from spark_check import tableaux  # noqa: E402


def value(text, **kw):
    env = sexpr.Env(ca.SX(kw.get("t", 0.0)), {"x": ca.SX(kw.get("x", 0.0))}, {"x": ca.SX(kw.get("vx", 0.0))},
                    {"m": ca.SX(kw.get("m", 0.0))})
    return float(ca.evalf(sexpr.translate(text, env)))


class Translate(unittest.TestCase):
    def test_every_operator(self):
        x, vx, m, t = 0.7, -1.3, 2.5, 0.4
        cases = {
            "(+ (q x) (v x) (p m) t)": x + vx + m + t,
            "(* (q x) (v x) (p m))": x * vx * m,
            "(- (q x) (v x))": x - vx,
            "(/ (q x) (v x))": x / vx,
            "(^ (p m) (q x))": m**x,
            "(^ (v x) 3)": vx**3,
            "(atan2 (q x) (v x))": math.atan2(x, vx),
            "(neg (q x))": -x,
            "(sqrt (p m))": math.sqrt(m),
            "(exp (q x))": math.exp(x),
            "(ln (p m))": math.log(m),
            "(sin (q x))": math.sin(x),
            "(cos (q x))": math.cos(x),
            "(tan (q x))": math.tan(x),
            "(sinh (q x))": math.sinh(x),
            "(cosh (q x))": math.cosh(x),
            "(tanh (q x))": math.tanh(x),
            "pi": math.pi,
            "-2.5e-3": -2.5e-3,
            "t": t,
        }
        for text, want in cases.items():
            with self.subTest(text=text):
                self.assertAlmostEqual(value(text, x=x, vx=vx, m=m, t=t), want, places=14)

    def test_literals_round_trip(self):
        for lit in ["0.1", "1.7976931348623157e308", "5e-324", "0.30000000000000004"]:
            self.assertEqual(value(lit), float(lit))

    def test_errors_name_the_problem(self):
        bad = {
            "(+ (q x)": "unclosed",
            "(foo (q x))": "unknown operator",
            "(sin (q x) (q x))": "takes 1 argument",
            "(- (q x))": "takes 2 arguments",
            "(q y)": "unknown q name 'y'",
            "(q x) (q x)": "trailing input",
            "abc": "unknown atom",
            "": "empty",
            ")": "unexpected ')'",
            "inf": "non-finite",
        }
        for text, fragment in bad.items():
            with self.subTest(text=text):
                with self.assertRaises(sexpr.SexprError) as ctx:
                    value(text)
                self.assertIn(fragment, str(ctx.exception))


class Rebuild(unittest.TestCase):
    SOURCE = {
        "name": "Pendulum",
        "coordinates": ["th"],
        "parameters": ["g"],
        "lagrangian": "(+ (* 0.5 (^ (v th) 2)) (* (p g) (cos (q th))))",
        "constraints": [],
    }

    def test_derivatives_of_a_pendulum(self):
        s = CasadiSystem(self.SOURCE)
        out = s.evaluate(0.0, [0.3], [2.0], [9.81], [])
        self.assertAlmostEqual(float(out["force"]), -9.81 * math.sin(0.3), places=14)
        self.assertAlmostEqual(float(out["force_q"]), -9.81 * math.cos(0.3), places=14)
        self.assertEqual(float(out["mass_matrix"]), 1.0)
        self.assertAlmostEqual(float(out["energy"]), 2.0 - 9.81 * math.cos(0.3), places=14)
        self.assertEqual(out["constraint_v"].shape, (0, 1))

    def test_bad_source_is_reported(self):
        src = dict(self.SOURCE, lagrangian="(* (q nope) 2)")
        with self.assertRaises(SourceError) as ctx:
            CasadiSystem(src)
        self.assertIn("nope", str(ctx.exception))


class Tableaux(unittest.TestCase):
    def test_gauss2_and_lobatto2_match_the_paper(self):
        r3 = math.sqrt(3.0)
        g = tableaux.gauss(2)
        np.testing.assert_allclose(g["a"], [[0.25, 0.25 - r3 / 6], [0.25 + r3 / 6, 0.25]], atol=1e-15)
        lo = tableaux.lobatto(2)
        np.testing.assert_allclose(lo["iiid"], [[0.25, -0.25], [0.75, 0.25]], atol=1e-15)
        np.testing.assert_allclose(lo["iiib"], [[0.5, 0.0], [0.5, 0.0]], atol=1e-15)

    def test_lobatto3_nodes(self):
        np.testing.assert_allclose(tableaux.lobatto(3)["c"], [0.0, 0.5, 1.0], atol=1e-16)
        np.testing.assert_allclose(tableaux.lobatto(3)["b"], [1 / 6, 2 / 3, 1 / 6], atol=1e-15)


class Structure(unittest.TestCase):
    SOURCE = {
        "name": "Rheonomic",
        "coordinates": ["x", "y"],
        "parameters": ["m"],
        "lagrangian": "(+ (* 0.5 (p m) (+ 1 t) (^ (v x) 2)) (* (q x) (v y)))",
        "constraints": ["(- (^ (v x) 2) (* (sin t) (q y)))"],
    }

    def run_check(self, claims):
        from spark_check import compare

        system = CasadiSystem(self.SOURCE)
        values = [{k: np.array(v) for k, v in system.evaluate(0.3, [0.1, 0.2], [0.3, -0.4], [1.2], [0.5]).items()}]
        result = compare.SystemResult("t", 2, 1, 1, 0)
        compare.check_structure(system, claims, values, result)
        return result

    def test_false_claims_fail_and_missed_facts_are_noted(self):
        honest = {"lagrangian_autonomous": False, "constraints_autonomous": False, "constant_mass_matrix": False,
                  "separable": False, "constraint_form": "Nonlinear"}
        self.assertEqual(self.run_check(honest).structure_failures, [])
        for key in ("lagrangian_autonomous", "constraints_autonomous", "constant_mass_matrix", "separable",
                    "constant_stiffness"):
            with self.subTest(key=key):
                self.assertEqual(len(self.run_check(dict(honest, **{key: True})).structure_failures), 1)
        for form in ("None", "Linear", "Affine"):
            with self.subTest(form=form):
                self.assertEqual(len(self.run_check(dict(honest, constraint_form=form)).structure_failures), 1)

    @staticmethod
    def potential_check(potential, claims):
        """Failures and notes of `claims` for `L = |v|²/2 − U(q)` in the plane
        with the constraint `v_y = x v_x`."""
        from spark_check import compare

        source = {
            "name": "Potential",
            "coordinates": ["x", "y"],
            "parameters": [],
            "lagrangian": f"(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2))) {potential})",
            "constraints": ["(- (v y) (* (q x) (v x)))"],
        }
        system = CasadiSystem(source)
        values = [{k: np.array(v) for k, v in system.evaluate(0.3, [0.1, 0.2], [0.3, -0.4], [], [0.5]).items()}]
        honest = {"lagrangian_autonomous": True, "constraints_autonomous": True, "constant_mass_matrix": True,
                  "separable": True, "constraint_form": "Linear"}
        result = compare.SystemResult("t", 2, 1, 1, 0)
        compare.check_structure(system, dict(honest, **claims), values, result)
        return result.structure_failures, result.structure_notes

    def assert_fact_holds(self, potential, fact):
        """The claimed `fact` of `potential` holds; not claimed, it is noted as missed."""
        self.assertEqual(self.potential_check(potential, {fact: True}), ([], []))
        failures, notes = self.potential_check(potential, {fact: False})
        self.assertEqual((len(failures), len(notes)), (0, 1))
        self.assertIn(fact, notes[0])

    def test_a_quadratic_potential_has_a_constant_stiffness(self):
        self.assert_fact_holds("(+ (^ (q x) 2) (* (q x) (q y)))", "constant_stiffness")

    def test_a_sum_of_one_coordinate_potentials_has_a_diagonal_stiffness(self):
        self.assert_fact_holds("(+ (cos (q x)) (^ (q y) 4))", "diagonal_stiffness")
        failures, _ = self.potential_check("(* (cos (q x)) (^ (q y) 2))", {"diagonal_stiffness": True})
        self.assertEqual(len(failures), 1)
        self.assertIn("diagonal_stiffness", failures[0])

class Steps(unittest.TestCase):
    PARTICLE = {
        "name": "Particle",
        "coordinates": ["x", "y", "z"],
        "parameters": [],
        "lagrangian": "(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2) (^ (v z) 2))) (+ (^ (q x) 2) (^ (q y) 2)))",
        "constraints": ["(- (v z) (* (q y) (v x)))"],
    }

    @staticmethod
    def method(key, s, c, a, a_hat, a_tilde, b, conditions):
        rows = lambda m: np.asarray(m, float).tolist()  # noqa: E731
        return {"key": key, "stages": s, "c": list(c), "a": rows(a), "a_hat": rows(a_hat), "a_tilde": rows(a_tilde),
                "b": list(b), "b_hat": list(b), "b_tilde": list(b), "conditions": conditions}

    def test_lda_as_spark_equals_eq_7_3(self):
        from spark_check.step import lda_applicable, solve_lda, solve_step

        system = CasadiSystem(self.PARTICLE)
        self.assertTrue(lda_applicable(system))
        lo = tableaux.lobatto(2)
        m = self.method("lobatto-iiib-a-lda", 2, lo["c"], lo["iiib"], lo["iiia"], lo["iiia"], lo["b"],
                        [{"kind": "multiplier_difference", "i": 0, "j": 1}])
        q0, v0 = [1.0, 0.2, 0.0], [0.0, 1.0, 0.2]
        spark = solve_step(system, [], m, 0.0, 0.1, q0, v0)
        q1, v1, psi = solve_lda(system, [], 0.0, 0.1, q0, v0)
        np.testing.assert_allclose(spark.q1, q1, rtol=0, atol=1e-15)
        np.testing.assert_allclose(spark.v1, v1, rtol=0, atol=1e-15)
        np.testing.assert_allclose(spark.psi[0], psi, rtol=0, atol=1e-14)

    def test_gauss_order_on_the_particle(self):
        # Global-order sanity of the CasADi step: one-step error of s-stage Gauss is O(h^(2s+1)).
        from spark_check.step import solve_step

        system = CasadiSystem(self.PARTICLE)
        q0, v0 = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
        for s in (1, 2):
            g = tableaux.gauss(s)
            m = self.method("gauss", s, g["c"], g["a"], g["a"], g["a"], g["b"],
                            [{"kind": "weights", "omega": list(g["b"] * g["c"] ** i)} for i in range(s - 1)])
            ref = tableaux.gauss(3)
            mref = self.method("gauss", 3, ref["c"], ref["a"], ref["a"], ref["a"], ref["b"],
                               [{"kind": "weights", "omega": list(ref["b"] * ref["c"] ** i)} for i in range(2)])
            errs = []
            for h in (0.2, 0.1):
                errs.append(np.max(np.abs(solve_step(system, [], m, 0.0, h, q0, v0).q1
                                          - solve_step(system, [], mref, 0.0, h, q0, v0).q1)))
            rate = math.log2(errs[0] / errs[1])
            self.assertGreater(rate, 2 * s + 1 - 0.5, f"s={s}: local rate {rate}")


class Effects(unittest.TestCase):
    # A point on a circle g = ½(x² + y² − ℓ²) at velocity level, damped, with a
    # friction-like non-ideal force along the velocity proportional to ψ.
    SOURCE = {
        "name": "Effects",
        "coordinates": ["x", "y"],
        "parameters": ["c", "ell"],
        "lagrangian": "(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2))) (q y))",
        "constraints": ["(+ (* (q x) (v x)) (* (q y) (v y)))"],
        "external_force": ["(neg (* (p c) (v x)))", "(neg (* (p c) (v y)))"],
        "nonideal_force": ["(* -0.1 (psi 0) (v x))", "(* -0.1 (psi 0) (v y))"],
        "holonomic": ["(* 0.5 (- (+ (^ (q x) 2) (^ (q y) 2)) (^ (p ell) 2)))"],
    }

    def test_psi_only_in_the_nonideal_force(self):
        env = sexpr.Env(ca.SX(0.0), {}, {}, {}, [ca.SX(2.5)])
        self.assertEqual(float(ca.evalf(sexpr.translate("(* 2 (psi 0))", env))), 5.0)
        with self.assertRaises(sexpr.SexprError) as ctx:
            sexpr.translate("(psi 1)", env)
        self.assertIn("1 constraints", str(ctx.exception))
        with self.assertRaises(sexpr.SexprError):
            sexpr.parse("(psi x)")
        bad = dict(self.SOURCE, external_force=["(psi 0)", "0"])
        with self.assertRaises(SourceError) as ctx:
            CasadiSystem(bad)
        self.assertIn("non-ideal force", str(ctx.exception))

    def test_effect_values_jacobians_and_holonomic_identity(self):
        s = CasadiSystem(self.SOURCE)
        out = s.evaluate(0.0, [0.6, -0.8], [0.8, 0.6], [0.3, 1.0], [2.0])
        np.testing.assert_allclose(np.array(out["external_force"]).ravel(), [-0.24, -0.18], atol=1e-15)
        np.testing.assert_allclose(np.array(out["external_force_v"]), -0.3 * np.eye(2), atol=1e-15)
        np.testing.assert_allclose(np.array(out["nonideal_force"]).ravel(), [-0.16, -0.12], atol=1e-15)
        np.testing.assert_allclose(np.array(out["nonideal_force_psi"]).ravel(), [-0.08, -0.06], atol=1e-15)
        self.assertAlmostEqual(float(out["holonomic_residual"]), 0.0, places=15)
        self.assertEqual(s.holonomic_rows, [0])
        self.assertEqual(s.holonomic_identity_is_symbolic(), [True])
        # A g that is not the integral of k is told apart.
        wrong = CasadiSystem(dict(self.SOURCE, holonomic=["(* 0.5 (- (+ (^ (q x) 2) (^ (q y) 3)) (^ (p ell) 2)))"]))
        self.assertEqual(wrong.holonomic_identity_is_symbolic(), [False])
        with self.assertRaises(SourceError):
            CasadiSystem(dict(self.SOURCE, holonomic=["(* (q x) (v y))"]))
        with self.assertRaises(SourceError):
            CasadiSystem(dict(self.SOURCE, external_force=["0"]))

    def test_corruption_changes_only_its_effect(self):
        s = CasadiSystem(self.SOURCE, "force", 1e-10)
        out = s.evaluate(0.0, [0.6, -0.8], [0.8, 0.6], [0.3, 1.0], [2.0])
        self.assertAlmostEqual(float(out["external_force"][0]), -0.24 * (1 + 1e-10) + 1e-10, places=16)
        self.assertEqual(float(out["nonideal_force"][0]), -0.1 * 2.0 * 0.8)

    def test_forcing_in_the_step_has_the_gauss_local_order(self):
        # Damped oscillator L = ½v² − ½q², f = −c v: exact solution known.
        from spark_check.step import solve_step

        src = {"name": "Damped", "coordinates": ["x"], "parameters": ["c"],
               "lagrangian": "(- (* 0.5 (^ (v x) 2)) (* 0.5 (^ (q x) 2)))", "constraints": [],
               "external_force": ["(neg (* (p c) (v x)))"]}
        system = CasadiSystem(src)
        c = 0.4
        w = math.sqrt(1 - c * c / 4)

        def exact(t):  # q(0) = 1, v(0) = 0
            e = math.exp(-c * t / 2)
            return e * (math.cos(w * t) + c / (2 * w) * math.sin(w * t))

        g = tableaux.gauss(2)
        m = Steps.method("gauss", 2, g["c"], g["a"], g["a"], g["a"], g["b"],
                         [{"kind": "weights", "omega": list(g["b"])}])
        errs = [abs(solve_step(system, [c], m, 0.0, h, [1.0], [0.0]).q1[0] - exact(h)) for h in (0.4, 0.2)]
        self.assertGreater(math.log2(errs[0] / errs[1]), 4.5)
        # Without the force the step misses the damped solution by O(c h²) (300x more here).
        undamped = solve_step(system, [0.0], m, 0.0, 0.4, [1.0], [0.0]).q1[0]
        self.assertGreater(abs(undamped - exact(0.4)), 100 * errs[0])

    def test_psi_free_nonideal_force_equals_the_same_external_force_when_weights_agree(self):
        from spark_check.step import solve_step

        base = {"name": "P", "coordinates": ["x", "y", "z"], "parameters": [],
                "lagrangian": "(- (* 0.5 (+ (^ (v x) 2) (^ (v y) 2) (^ (v z) 2))) (+ (^ (q x) 2) (^ (q y) 2)))",
                "constraints": ["(- (v z) (* (q y) (v x)))"]}
        push = ["(cos (q x))", "(* 0.3 (v y))", "t"]
        g = tableaux.gauss(2)
        m = Steps.method("gauss", 2, g["c"], g["a"], g["a"], g["a"], g["b"],
                         [{"kind": "weights", "omega": list(g["b"])}])
        a = solve_step(CasadiSystem(dict(base, external_force=push)), [], m, 0.1, 0.1, [1, 0.2, 0], [0, 1, 0.2])
        b = solve_step(CasadiSystem(dict(base, nonideal_force=push)), [], m, 0.1, 0.1, [1, 0.2, 0], [0, 1, 0.2])
        none = solve_step(CasadiSystem(base), [], m, 0.1, 0.1, [1, 0.2, 0], [0, 1, 0.2])
        np.testing.assert_allclose(a.v1, b.v1, rtol=0, atol=1e-15)
        np.testing.assert_allclose(a.psi, b.psi, rtol=0, atol=1e-14)
        self.assertGreater(np.max(np.abs(a.v1 - none.v1)), 1e-3)


if __name__ == "__main__":
    unittest.main()
