"""One system rebuilt in CasADi from its neutral source text.

Owns the derivative set: every quantity of the Rust trait
``NonholonomicSystem`` recomputed with CasADi's own ``jacobian``/``gradient``
from the S-expressions of ``L`` and ``k`` (never from anything Rust derived).
"""

from __future__ import annotations

from typing import Dict, List

import casadi as ca

from . import sexpr


class SourceError(ValueError):
    """The exported source of a system is malformed."""


class CasadiSystem:
    """``L(t,q,v)`` and ``k(t,q,v)`` of one system as CasADi SX, with derivatives.

    Parameters are symbolic inputs ``p`` (their values are supplied at
    evaluation), so the operation counts compare like with like: the generated
    Rust code also reads its parameters at run time.
    """

    def __init__(self, source: Dict):
        try:
            self.name: str = source["name"]
            self.coordinates: List[str] = list(source["coordinates"])
            self.parameters: List[str] = list(source["parameters"])
            lagrangian_text: str = source["lagrangian"]
            constraint_texts: List[str] = list(source["constraints"])
        except KeyError as err:
            raise SourceError(f"source is missing field {err}") from None
        n, m, n_p = len(self.coordinates), len(constraint_texts), len(self.parameters)
        if len(set(self.coordinates)) != n:
            raise SourceError(f"{self.name}: duplicate coordinate names {self.coordinates}")
        self.n, self.m = n, m
        self.t = ca.SX.sym("t")
        self.q = ca.SX.sym("q", n)
        self.v = ca.SX.sym("v", n)
        self.p = ca.SX.sym("p", n_p)
        self.psi = ca.SX.sym("psi", m)
        env = sexpr.Env(
            self.t,
            {name: self.q[i] for i, name in enumerate(self.coordinates)},
            {name: self.v[i] for i, name in enumerate(self.coordinates)},
            {name: self.p[i] for i, name in enumerate(self.parameters)},
        )
        try:
            self.L = sexpr.translate(lagrangian_text, env)
            ks = [sexpr.translate(text, env) for text in constraint_texts]
        except sexpr.SexprError as err:
            raise SourceError(f"{self.name}: {err}") from None
        self.k = ca.vertcat(*ks) if ks else ca.SX(0, 1)

        q, v, t, psi = self.q, self.v, self.t, self.psi
        self.grad_q = ca.gradient(self.L, q)
        self.grad_v = ca.gradient(self.L, v)
        self.k_q = ca.jacobian(self.k, q)
        self.k_v = ca.jacobian(self.k, v)
        self.R = -ca.mtimes(self.k_v.T, psi)
        self.sym = {
            "lagrangian": self.L,
            "energy": ca.dot(self.grad_v, v) - self.L,
            "momentum": self.grad_v,
            "force": self.grad_q,
            # The Hessian of L in v, taken by CasADi's own hessian().
            "mass_matrix": ca.hessian(self.L, v)[0],
            "momentum_q": ca.jacobian(self.grad_v, q),
            "force_q": ca.jacobian(self.grad_q, q),
            "force_v": ca.jacobian(self.grad_q, v),
            "constraint": self.k,
            "constraint_q": self.k_q,
            "constraint_v": self.k_v,
            "constraint_force": self.R,
            "constraint_force_q": ca.jacobian(self.R, q),
            "constraint_force_v": ca.jacobian(self.R, v),
            "lagrangian_t": ca.jacobian(self.L, t),
            "momentum_t": ca.jacobian(self.grad_v, t),
            "force_t": ca.jacobian(self.grad_q, t),
            "constraint_t": ca.jacobian(self.k, t),
        }
        # Kᵀψ itself (not R = −Kᵀψ) is what `OperationCounts::bundle` counts.
        kt_psi = ca.mtimes(self.k_v.T, psi)
        self.sym["kt_psi"] = kt_psi
        self.sym["kt_psi_q"] = ca.jacobian(kt_psi, q)
        self.sym["kt_psi_v"] = ca.jacobian(kt_psi, v)
        # Quantities the structure-fact check needs.
        mass = self.sym["mass_matrix"]
        self.sym["mass_matrix_dtqv"] = ca.jacobian(ca.vec(mass), ca.vertcat(t, q, v))
        self.sym["constraint_v_v"] = ca.jacobian(ca.vec(self.k_v), v)
        self.sym["constraint_at_zero_velocity"] = ca.substitute(self.k, v, ca.SX.zeros(n))
        names = list(self.sym)
        self._eval = ca.Function(
            f"{self.name}_all", [t, q, v, self.p, psi], [self.sym[k] for k in names], ["t", "q", "v", "p", "psi"], names
        )

    def evaluate(self, t: float, q, v, p, psi) -> Dict[str, "ca.DM"]:
        """Every derivative at one point, as CasADi DM matrices."""
        out = self._eval(t=t, q=q, v=v, p=p, psi=psi)
        return {k: out[k] for k in self.sym}

    # Outputs of the bundle `OperationCounts::bundle` counts (system.rs):
    # L, ∇_q L, ∇_v L, ∇²_vv L, ∂(∇_v L)/∂q, k, k_q, k_v, Kᵀψ and its Jacobians in q, v.
    BUNDLE = (
        "lagrangian",
        "force",
        "momentum",
        "mass_matrix",
        "momentum_q",
        "constraint",
        "constraint_q",
        "constraint_v",
        "kt_psi",
        "kt_psi_q",
        "kt_psi_v",
    )
    STAGE_VALUES = ("momentum", "force", "constraint", "constraint_force")
    STAGE_JACOBIANS = STAGE_VALUES + (
        "momentum_q",
        "mass_matrix",
        "force_q",
        "force_v",
        "constraint_q",
        "constraint_v",
        "constraint_force_q",
        "constraint_force_v",
    )

    def op_counts(self, outputs) -> Dict[str, int]:
        """CasADi's cost of computing ``outputs`` together in one cse=True SX Function.

        ``n_instructions`` is CasADi's own figure (it includes input, output
        and constant instructions); ``arithmetic`` counts only the operations
        (additions, multiplications, divisions, negations, powers and
        elementary functions), which is what the Rust ``OperationCounts`` count.
        """
        f = ca.Function(
            "bundle",
            [self.t, self.q, self.v, self.p, self.psi],
            [self.sym[k] for k in outputs],
            {"cse": True},
        )
        skip = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_PARAMETER, ca.OP_ASSIGN}
        arithmetic = sum(1 for i in range(f.n_instructions()) if f.instruction_id(i) not in skip)
        return {"n_instructions": int(f.n_instructions()), "arithmetic": arithmetic}
