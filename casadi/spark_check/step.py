"""One SPARK step (paper eq. 6.1) built and solved by CasADi.

Owns the whole-step cross-check: from the tableau the Rust side exports and
the system rebuilt from its source text, it writes the SPARK equations in
CasADi SX, solves them with CasADi's Newton ``rootfinder`` and returns
``(q1, v1, V, Ψ)``. Nothing of the Rust stepper is used but its inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional

import casadi as ca
import numpy as np

from .system import CasadiSystem


class StepSetupError(ValueError):
    """The exported method or state is malformed."""


@dataclass
class StepSolution:
    """What CasADi found for one step."""

    q1: np.ndarray
    v1: np.ndarray
    stage_velocities: np.ndarray  # s × n
    psi: np.ndarray  # s × m
    residual: float  # ‖G(x)‖_∞ at the solution
    last_newton_step: float  # ‖Δx‖_∞ of one more Newton step from the solution
    holonomic_residual: Optional[np.ndarray] = None  # g(t1, q1) when the source declares g


def _mat(rows, s: int, name: str) -> np.ndarray:
    a = np.array(rows, dtype=float).reshape(-1, s) if s else np.zeros((0, 0))
    if a.shape != (s, s):
        raise StepSetupError(f"{name} must be {s}x{s}, got {a.shape}")
    return a


def spark_residual(system: CasadiSystem, method: Dict) -> ca.Function:
    """The SPARK equations as ``G(x, [t0, h, q0, v0, p]) = 0``.

    Unknowns ``x = [V_1..V_s, Ψ_1..Ψ_s, v1]`` (``s(n+m)+n`` of them). Rows:
    (6.1b) ``P_i − p0 − h Σ â_ij F_j − h Σ ã_ij R_j``, (6.1d) for ``p1``, the
    ``s−1`` condition rows (6.1e or its replacements) and (6.1f). With
    effects, ``F_j`` includes ``f`` and ``R_j`` includes ``N`` (module docs).
    """
    s = int(method["stages"])
    n, m = system.n, system.m
    c = np.array(method["c"], dtype=float)
    b = np.array(method["b"], dtype=float)
    b_hat = np.array(method["b_hat"], dtype=float)
    b_tilde = np.array(method["b_tilde"], dtype=float)
    a = _mat(method["a"], s, "a")
    a_hat = _mat(method["a_hat"], s, "a_hat")
    a_tilde = _mat(method["a_tilde"], s, "a_tilde")
    for name, vec in (("c", c), ("b", b), ("b_hat", b_hat), ("b_tilde", b_tilde)):
        if vec.shape != (s,):
            raise StepSetupError(f"{name} must have {s} entries, got {vec.shape}")
    conditions: List[Dict] = method["conditions"]
    if len(conditions) != s - 1:
        raise StepSetupError(f"expected {s - 1} condition rows, got {len(conditions)}")

    # The system's pieces as functions of (t, q, v, p[, ψ]) so they can be
    # called at every stage point.
    tt, qq, vv, pp, psi = system.t, system.q, system.v, system.p, system.psi
    grad_v = ca.Function("gv", [tt, qq, vv, pp], [system.grad_v])
    kfun = ca.Function("k", [tt, qq, vv, pp], [system.k])
    # Total stage forces: F = ∇_qL + f, R = −Kᵀψ + N (each effect only if declared).
    total_f = system.grad_q + system.f if system.f is not None else system.grad_q
    total_r = system.R + system.N if system.N is not None else system.R
    ffun = ca.Function("f_total", [tt, qq, vv, pp], [total_f])
    rfun = ca.Function("r_total", [tt, qq, vv, pp, psi], [total_r])

    x = ca.SX.sym("x", s * (n + m) + n)
    par = ca.SX.sym("par", 2 + 2 * n + len(system.parameters))
    t0, h = par[0], par[1]
    q0 = par[2 : 2 + n]
    v0 = par[2 + n : 2 + 2 * n]
    p = par[2 + 2 * n :]
    V = [x[j * n : (j + 1) * n] for j in range(s)]
    Psi = [x[s * n + j * m : s * n + (j + 1) * m] for j in range(s)]
    v1 = x[s * (n + m) :]

    T = [t0 + c[i] * h for i in range(s)]
    Q = [q0 + h * sum(a[i, j] * V[j] for j in range(s)) for i in range(s)]
    F = [ffun(T[i], Q[i], V[i], p) for i in range(s)]
    R = [rfun(T[i], Q[i], V[i], p, Psi[i]) for i in range(s)]
    K = [kfun(T[i], Q[i], V[i], p) for i in range(s)]
    p0 = grad_v(t0, q0, v0, p)
    t1 = t0 + h
    q1 = q0 + h * sum(b[j] * V[j] for j in range(s))

    rows = []
    for i in range(s):
        P_i = grad_v(T[i], Q[i], V[i], p)
        rows.append(P_i - p0 - h * sum(a_hat[i, j] * F[j] for j in range(s)) - h * sum(a_tilde[i, j] * R[j] for j in range(s)))
    p1 = grad_v(t1, q1, v1, p)
    rows.append(p1 - p0 - h * sum(b_hat[j] * F[j] for j in range(s)) - h * sum(b_tilde[j] * R[j] for j in range(s)))
    for row in conditions:
        kind = row.get("kind")
        if kind == "weights":
            omega = np.array(row["omega"], dtype=float)
            if omega.shape != (s,):
                raise StepSetupError(f"omega row must have {s} entries")
            rows.append(sum(omega[j] * K[j] for j in range(s)))
        elif kind == "point":
            alpha = np.array(row["alpha"], dtype=float)
            beta = np.array(row["beta"], dtype=float)
            tc = t0 + float(row["c"]) * h
            qc = q0 + h * sum(alpha[j] * V[j] for j in range(s))
            vc = sum(beta[j] * V[j] for j in range(s))
            rows.append(kfun(tc, qc, vc, p))
        elif kind == "multiplier_difference":
            i, j = int(row["i"]), int(row["j"])
            rows.append(Psi[i] - Psi[j])
        else:
            raise StepSetupError(f"unknown condition kind {kind!r}")
    rows.append(kfun(t1, q1, v1, p))
    g = ca.vertcat(*rows)
    if g.shape[0] != x.shape[0]:
        raise StepSetupError(f"{g.shape[0]} equations for {x.shape[0]} unknowns")
    return ca.Function("spark", [x, par], [g])


class StepSolver:
    """The SPARK equations of one (system, method) with CasADi's Newton
    ``rootfinder`` on them, built once and solved from any state and guess."""

    def __init__(self, system: CasadiSystem, parameter_values, method: Dict):
        self.system, self.method = system, method
        self.s, self.n, self.m = int(method["stages"]), system.n, system.m
        self.parameter_values = np.asarray(parameter_values, float)
        self.g = spark_residual(system, method)
        # abstol is below what double precision reaches on purpose: Newton then
        # stops on the step criterion, i.e. one iteration after the residual
        # stopped shrinking, which is the most accurate solution available.
        self.rf = ca.rootfinder(
            "rf",
            "newton",
            self.g,
            {"abstol": 1e-300, "abstolStep": 1e-15, "max_iter": 60, "error_on_fail": False},
        )
        xs, ps = self.g.mx_in(0), self.g.mx_in(1)
        self.jac = ca.Function("j", [xs, ps], [ca.jacobian(self.g(xs, ps), xs)])
        self.gfun = None
        if system.g is not None:
            self.gfun = ca.Function("g", [system.t, system.q, system.p], [system.g])

    def par(self, t0: float, h: float, q0, v0) -> np.ndarray:
        """The parameter vector ``[t0, h, q0, v0, p]`` of the equations."""
        return np.concatenate(([t0, h], np.asarray(q0, float), np.asarray(v0, float), self.parameter_values))

    def constant_guess(self, v0) -> np.ndarray:
        """``V_i = v0``, ``Ψ_i = 0``, ``v1 = v0``."""
        v0 = np.asarray(v0, float)
        return np.concatenate([np.tile(v0, self.s), np.zeros(self.s * self.m), v0])

    def solve(self, t0: float, h: float, q0, v0, x0=None) -> StepSolution:
        """Solve one step to the limit of double precision from ``x0``
        (default the constant guess)."""
        par = self.par(t0, h, q0, v0)
        x0 = self.constant_guess(v0) if x0 is None else np.asarray(x0, float)
        x = np.array(self.rf(x0, par)).ravel()
        return self.solution(x, t0, h, q0, par)

    def solution(self, x: np.ndarray, t0: float, h: float, q0, par: np.ndarray) -> StepSolution:
        """``(q1, v1, V, Ψ)`` of the unknowns ``x``, with the residual there."""
        s, n, m = self.s, self.n, self.m
        res = np.array(self.g(x, par)).ravel()
        J = np.array(self.jac(x, par))
        if J.size and np.all(np.isfinite(J)) and np.all(np.isfinite(res)):
            try:
                dx = np.linalg.solve(J, -res)
            except np.linalg.LinAlgError:
                dx = np.full(x.shape, np.inf)
        else:
            dx = np.zeros(0) if not J.size else np.full(x.shape, np.inf)
        q1 = np.asarray(q0, float) + h * sum(np.array(self.method["b"])[j] * x[j * n : (j + 1) * n] for j in range(s))
        g1 = None
        if self.gfun is not None:
            g1 = np.array(self.gfun(t0 + h, q1, self.parameter_values)).ravel()
        return StepSolution(
            q1=q1,
            v1=x[s * (n + m) :],
            stage_velocities=x[: s * n].reshape(s, n),
            psi=x[s * n : s * (n + m)].reshape(s, m),
            residual=float(np.max(np.abs(res))) if res.size else 0.0,
            last_newton_step=float(np.max(np.abs(dx))) if dx.size else 0.0,
            holonomic_residual=g1,
        )


def solve_step(system: CasadiSystem, parameter_values, method: Dict, t0: float, h: float, q0, v0) -> StepSolution:
    """Solve one step with CasADi's Newton rootfinder to the limit of double
    precision, from the constant guess ``V_i = v0, Ψ_i = 0, v1 = v0``."""
    return StepSolver(system, parameter_values, method).solve(t0, h, q0, v0)


def lda_applicable(system: CasadiSystem) -> bool:
    """Eq. (7.3) is stated for ``L = ½vᵀMv − U(q)``, ``k = K(q)v + b(q)`` without forcing or
    non-ideal forces: check that form with CasADi."""
    if system.f is not None or system.N is not None:
        return False
    t, q, v = system.t, system.q, system.v
    mass = ca.hessian(system.L, v)[0]
    return (
        not ca.depends_on(system.L, t)
        and not ca.depends_on(system.k, t)
        and not ca.depends_on(mass, ca.vertcat(q, v))
        and ca.jacobian(system.grad_v, q).is_zero()
        and ca.jacobian(system.grad_q, v).is_zero()
        and ca.jacobian(ca.vec(system.k_v), v).is_zero()
    )


def solve_lda(system: CasadiSystem, parameter_values, t0: float, h: float, q0, v0):
    """McLachlan–Perlmutter's Lobatto IIIB-A LDA step written as the paper's eq. (7.3):

    ``Q1 = q0 + (h/2) v0``, ``M v1 = M v0 − h(∇U(Q1) + K(Q1)ᵀΨ)``,
    ``q1 = q0 + (h/2)(v0 + v1)``, ``0 = K(q1) v1 + b(q1)``; returns ``(q1, v1, Ψ)``.
    """
    n, m = system.n, system.m
    tt, qq, vv, pp, psi = system.t, system.q, system.v, system.p, system.psi
    grad_v = ca.Function("gv", [tt, qq, vv, pp], [system.grad_v])
    grad_q = ca.Function("gq", [tt, qq, vv, pp], [system.grad_q])
    kfun = ca.Function("k", [tt, qq, vv, pp], [system.k])
    rfun = ca.Function("r", [tt, qq, vv, pp, psi], [system.R])
    x = ca.SX.sym("x", n + m)
    v1, Psi = x[:n], x[n:]
    q0s, v0s = ca.DM(q0), ca.DM(v0)
    p = ca.DM(parameter_values)
    Q1 = q0s + h / 2 * v0s
    q1 = q0s + h / 2 * (v0s + v1)
    # ∇_q L = −∇U and R = −KᵀΨ; ∇_v L = M v (the force terms do not depend on v here).
    g = ca.vertcat(
        grad_v(t0, Q1, v1, p) - grad_v(t0, Q1, v0s, p) - h * (grad_q(t0, Q1, v0s, p) + rfun(t0, Q1, v0s, p, Psi)),
        kfun(t0 + h, q1, v1, p),
    )
    rf = ca.rootfinder("lda", "newton", ca.Function("g", [x], [g]), {"abstol": 1e-300, "abstolStep": 1e-15,
                                                                     "max_iter": 60, "error_on_fail": False})
    sol = np.array(rf(np.concatenate([np.asarray(v0, float), np.zeros(m)]))).ravel()
    v1n = sol[:n]
    return np.asarray(q0, float) + h / 2 * (np.asarray(v0, float) + v1n), v1n, sol[n:]
