"""One system rebuilt in CasADi from its neutral source text.

Owns the derivative set: every quantity of the Rust trait
``NonholonomicSystem`` recomputed with CasADi's own ``jacobian``/``gradient``
from the S-expressions of ``L`` and ``k`` (never from anything Rust derived),
and of the optional effects in the source: the external force ``f(t,q,v)``,
the non-ideal constraint force ``N(t,q,v,ψ)`` and the position-level
constraints ``g(t,q)`` behind holonomic rows of ``k``.
"""

from __future__ import annotations

from typing import Dict, List, Optional

import casadi as ca

from . import sexpr


class SourceError(ValueError):
    """The exported source of a system is malformed."""


class CasadiSystem:
    """``L(t,q,v)`` and ``k(t,q,v)`` of one system as CasADi SX, with derivatives.

    Parameters are symbolic inputs ``p`` (their values are supplied at
    evaluation), so the operation counts compare like with like: the generated
    Rust code also reads its parameters at run time.

    ``corrupt`` (``"force"`` or ``"nonideal"``) deliberately changes ``f`` or
    ``N`` to ``x(1 + ε) + ε`` with ``ε = corruption`` in every entry: the
    negative tests use it to show that an error of that size in an effect is
    caught by both the derivative and the step comparisons.
    """

    def __init__(self, source: Dict, corrupt: Optional[str] = None, corruption: float = 0.0):
        try:
            self.name: str = source["name"]
            self.coordinates: List[str] = list(source["coordinates"])
            self.parameters: List[str] = list(source["parameters"])
            lagrangian_text: str = source["lagrangian"]
            constraint_texts: List[str] = list(source["constraints"])
            # Effects: absent fields (older exports) mean "no such effect".
            force_texts: List[str] = list(source.get("external_force", []))
            nonideal_texts: List[str] = list(source.get("nonideal_force", []))
            holonomic_texts: List[str] = list(source.get("holonomic", []))
            # Declared events g(t,q,v): name, direction, terminal, function.
            event_texts: List[str] = [str(e["function"]) for e in source.get("events", [])]
            self.event_names: List[str] = [str(e["name"]) for e in source.get("events", [])]
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
        # Only N(t,q,v,ψ) may name multipliers.
        env_psi = sexpr.Env(env.t, env.tables["q"], env.tables["v"], env.tables["p"], [self.psi[j] for j in range(m)])
        for what, texts, want in (
            ("external_force", force_texts, n),
            ("nonideal_force", nonideal_texts, n),
            ("holonomic", holonomic_texts, m),
        ):
            if texts and len(texts) != want:
                raise SourceError(f"{self.name}: {what} has {len(texts)} entries, expected {want} (or none)")
        try:
            self.L = sexpr.translate(lagrangian_text, env)
            ks = [sexpr.translate(text, env) for text in constraint_texts]
            fs = [sexpr.translate(text, env) for text in force_texts]
            ns = [sexpr.translate(text, env_psi) for text in nonideal_texts]
            gs = [sexpr.translate(text, env) for text in holonomic_texts]
            es = [sexpr.translate(text, env) for text in event_texts]
        except sexpr.SexprError as err:
            raise SourceError(f"{self.name}: {err}") from None
        self.k = ca.vertcat(*ks) if ks else ca.SX(0, 1)
        if corrupt not in (None, "force", "nonideal", "event"):
            raise SourceError(f"unknown corruption {corrupt!r}")
        bump = (lambda x: x * (1 + corruption) + corruption)
        #: External force f(t,q,v) (``None`` when the source has none).
        self.f = ca.vertcat(*[bump(x) if corrupt == "force" else x for x in fs]) if fs else None
        #: Non-ideal constraint force N(t,q,v,ψ) (``None`` when absent).
        self.N = ca.vertcat(*[bump(x) if corrupt == "nonideal" else x for x in ns]) if ns else None
        #: Position-level constraints g(t,q) (``None`` when absent); rows whose
        #: source is the literal ``0`` are genuinely nonholonomic.
        self.g = ca.vertcat(*gs) if gs else None
        #: Event functions g_i(t,q,v), one row per declared event (``None`` when none).
        self.events = ca.vertcat(*[bump(x) if corrupt == "event" else x for x in es]) if es else None
        self.holonomic_rows = [i for i, text in enumerate(holonomic_texts) if text.strip() != "0"]
        if self.g is not None and ca.depends_on(self.g, ca.vertcat(self.v, self.psi)):
            raise SourceError(f"{self.name}: a holonomic constraint g(t,q) depends on a velocity")

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
        if self.f is not None:
            self.sym["external_force"] = self.f
            self.sym["external_force_q"] = ca.jacobian(self.f, q)
            self.sym["external_force_v"] = ca.jacobian(self.f, v)
        if self.N is not None:
            self.sym["nonideal_force"] = self.N
            self.sym["nonideal_force_q"] = ca.jacobian(self.N, q)
            self.sym["nonideal_force_v"] = ca.jacobian(self.N, v)
            self.sym["nonideal_force_psi"] = ca.jacobian(self.N, psi)
        if self.g is not None:
            self.sym["holonomic_residual"] = self.g
            # k_i − (∂g_i/∂t + ∂g_i/∂q·v) on the holonomic rows (paper §5.1:
            # the constraint imposed is the time derivative of g).
            g_dot = ca.jacobian(self.g, t) + ca.mtimes(ca.jacobian(self.g, q), v)
            rows = self.holonomic_rows
            self.sym["holonomic_g_dot"] = g_dot[rows] if rows else ca.SX(0, 1)
            self.sym["holonomic_k"] = self.k[rows] if rows else ca.SX(0, 1)
        if self.events is not None:
            # The event functions and their derivatives, as `event_value` and
            # `event_gradient` return them.
            self.sym["event_value"] = self.events
            self.sym["event_t"] = ca.jacobian(self.events, t)
            self.sym["event_q"] = ca.jacobian(self.events, q)
            self.sym["event_v"] = ca.jacobian(self.events, v)
        # Quantities the structure-fact check needs.
        mass = self.sym["mass_matrix"]
        self.sym["mass_matrix_dtqv"] = ca.jacobian(ca.vec(mass), ca.vertcat(t, q, v))
        self.sym["force_q_dtqv"] = ca.jacobian(ca.vec(self.sym["force_q"]), ca.vertcat(t, q, v))
        self.sym["constraint_v_v"] = ca.jacobian(ca.vec(self.k_v), v)
        self.sym["constraint_at_zero_velocity"] = ca.substitute(self.k, v, ca.SX.zeros(n))
        names = list(self.sym)
        self._eval = ca.Function(
            f"{self.name}_all", [t, q, v, self.p, psi], [self.sym[k] for k in names], ["t", "q", "v", "p", "psi"], names
        )

    def holonomic_identity_is_symbolic(self) -> List[bool]:
        """Per holonomic row: whether CasADi proves ``k_i − (∂g_i/∂t + ∂g_i/∂q·v) ≡ 0``
        after its own simplification (otherwise the identity is checked numerically)."""
        if self.g is None:
            return []
        diff = self.sym["holonomic_k"] - self.sym["holonomic_g_dot"]
        return [bool(ca.simplify(diff[i]).is_zero()) for i in range(diff.shape[0])]

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

    def effect_outputs(self) -> tuple:
        """What the optional effect methods of the trait return: ``f`` with its Jacobians
        in ``q``, ``v`` and ``N`` with its Jacobians in ``q``, ``v``, ``ψ`` (empty without effects)."""
        keys = (
            "external_force",
            "external_force_q",
            "external_force_v",
            "nonideal_force",
            "nonideal_force_q",
            "nonideal_force_v",
            "nonideal_force_psi",
        )
        return tuple(k for k in keys if k in self.sym)

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
