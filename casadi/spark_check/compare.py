"""Comparison of the Rust export with CasADi: errors, verdicts, report.

Owns the error measure and the mapping from the exported trait outputs onto
the CasADi quantities of :mod:`spark_check.system`.

Error measure (the pass criterion, 1e-12): for every entry,
``|rust − casadi| / max(|casadi|, 1)``, i.e. relative error for values of
magnitude ≥ 1 and absolute error near zero. Beside it the *normwise relative*
error ``‖rust − casadi‖_∞ / ‖casadi‖_∞`` of each output at each point is
reported, which stays meaningful at points of tiny magnitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Tuple

import numpy as np

from .system import CasadiSystem

TOLERANCE = 1e-12

# (path in the exported `outputs`, CasADi quantity)
OUTPUT_MAP: List[Tuple[str, str]] = [
    ("lagrangian", "lagrangian"),
    ("energy", "energy"),
    ("momentum", "momentum"),
    ("force", "force"),
    ("mass_matrix", "mass_matrix"),
    ("constraint", "constraint"),
    ("constraint_q", "constraint_q"),
    ("constraint_v", "constraint_v"),
    ("time_derivatives.lagrangian_t", "lagrangian_t"),
    ("time_derivatives.momentum_t", "momentum_t"),
    ("time_derivatives.force_t", "force_t"),
    ("time_derivatives.constraint_t", "constraint_t"),
    ("stage_values.momentum", "momentum"),
    ("stage_values.force", "force"),
    ("stage_values.constraint", "constraint"),
    ("stage_values.constraint_force", "constraint_force"),
    ("stage_jacobians.values.momentum", "momentum"),
    ("stage_jacobians.values.force", "force"),
    ("stage_jacobians.values.constraint", "constraint"),
    ("stage_jacobians.values.constraint_force", "constraint_force"),
    ("stage_jacobians.momentum_q", "momentum_q"),
    ("stage_jacobians.mass", "mass_matrix"),
    ("stage_jacobians.force_q", "force_q"),
    ("stage_jacobians.force_v", "force_v"),
    ("stage_jacobians.constraint_q", "constraint_q"),
    ("stage_jacobians.constraint_v", "constraint_v"),
    ("stage_jacobians.constraint_force_q", "constraint_force_q"),
    ("stage_jacobians.constraint_force_v", "constraint_force_v"),
]


# Effects (present only for systems whose source declares them).
FORCE_MAP: List[Tuple[str, str]] = [
    ("external_force.value", "external_force"),
    ("external_force.jacobians.value", "external_force"),
    ("external_force.jacobians.q", "external_force_q"),
    ("external_force.jacobians.v", "external_force_v"),
]
NONIDEAL_MAP: List[Tuple[str, str]] = [
    ("nonideal_force.value", "nonideal_force"),
    ("nonideal_force.jacobians.value", "nonideal_force"),
    ("nonideal_force.jacobians.q", "nonideal_force_q"),
    ("nonideal_force.jacobians.v", "nonideal_force_v"),
    ("nonideal_force.jacobians.psi", "nonideal_force_psi"),
]
HOLONOMIC_MAP: List[Tuple[str, str]] = [("holonomic_residual", "holonomic_residual")]
EVENT_MAP: List[Tuple[str, str]] = [
    ("events.value", "event_value"),
    ("events.gradient.value", "event_value"),
    ("events.gradient.t", "event_t"),
    ("events.gradient.q", "event_q"),
    ("events.gradient.v", "event_v"),
]
# Not a Rust output: CasADi's k_i against ∂g_i/∂t + ∂g_i/∂q·v from the source's g.
HOLONOMIC_IDENTITY = "holonomic k = ġ"
# Every comparison any system may have (the report's per-function table).
ALL_PATHS: List[str] = [p for p, _ in OUTPUT_MAP + FORCE_MAP + NONIDEAL_MAP + HOLONOMIC_MAP + EVENT_MAP] + [
    HOLONOMIC_IDENTITY
]


def output_map(system: CasadiSystem) -> List[Tuple[str, str]]:
    """The comparisons that apply to ``system``: the trait's outputs plus its effects."""
    out = list(OUTPUT_MAP)
    if system.f is not None:
        out += FORCE_MAP
    if system.N is not None:
        out += NONIDEAL_MAP
    if system.g is not None:
        out += HOLONOMIC_MAP
    if system.events is not None:
        out += EVENT_MAP
    return out


def check_effect_flags(system: CasadiSystem, effects: Dict, result: "SystemResult") -> None:
    """The trait's ``HAS_FORCING``/``HAS_NONIDEAL_FORCE``/``HAS_HOLONOMIC`` must match the source:
    a flag off with an effect in the source means the stepper silently drops it; a flag on with
    no source means CasADi cannot check what the stepper adds."""
    for flag, const, present, what in (
        ("forcing", "HAS_FORCING", system.f is not None, "external_force"),
        ("nonideal", "HAS_NONIDEAL_FORCE", system.N is not None, "nonideal_force"),
        ("holonomic", "HAS_HOLONOMIC", system.g is not None, "holonomic"),
        ("events", "HAS_EVENTS", system.events is not None, "events"),
    ):
        claimed = bool(effects.get(flag, False))
        if claimed != present:
            result.structure_failures.append(
                f"{const} is {claimed} but the source {'has' if present else 'has no'} `{what}`"
            )


class ExportError(ValueError):
    """The exported JSON does not have the expected shape."""


def lookup(outputs: Dict, path: str):
    node = outputs
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            raise ExportError(f"exported outputs have no `{path}`")
        node = node[part]
    return node


def errors(rust, reference: np.ndarray) -> Tuple[float, float]:
    """``(scaled, normwise)`` errors of ``rust`` against ``reference`` (same shape)."""
    a = np.asarray(rust, dtype=float)
    b = np.asarray(reference, dtype=float)
    if a.size != b.size:
        raise ExportError(f"shape mismatch: exported {a.shape}, CasADi {b.shape}")
    if a.size == 0:
        return 0.0, 0.0
    a = a.reshape(b.shape)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return math.inf, math.inf
    diff = np.abs(a - b)
    scaled = float(np.max(diff / np.maximum(np.abs(b), 1.0)))
    norm_b = float(np.max(np.abs(b)))
    normwise = float(np.max(diff)) / norm_b if norm_b > 0 else float(np.max(diff))
    return scaled, normwise


@dataclass
class Worst:
    """Worst error seen for one function of one system."""

    scaled: float = 0.0
    normwise: float = 0.0
    where: str = ""
    count: int = 0

    def update(self, scaled: float, normwise: float, where: str) -> None:
        self.count += 1
        if scaled > self.scaled or (math.isinf(scaled) and not self.where):
            self.scaled, self.where = scaled, where
        self.normwise = max(self.normwise, normwise)

    @property
    def ok(self) -> bool:
        return self.scaled <= TOLERANCE


@dataclass
class SystemResult:
    """Everything measured for one system."""

    name: str
    n: int
    m: int
    points: int
    skipped: int
    worst: Dict[str, Worst] = field(default_factory=dict)
    structure_failures: List[str] = field(default_factory=list)
    structure_notes: List[str] = field(default_factory=list)
    rust_ops: Dict[str, int] = field(default_factory=dict)
    casadi_ops: Dict[str, Dict[str, int]] = field(default_factory=dict)
    effects: List[str] = field(default_factory=list)  # "f", "N", "g" present in the source

    @property
    def ok(self) -> bool:
        return all(w.ok for w in self.worst.values()) and not self.structure_failures and self.points > 0


def check_structure(system: CasadiSystem, claims: Dict, values: List[Dict[str, np.ndarray]], result: SystemResult):
    """A claimed structure fact that CasADi's derivatives contradict at a sample point is a failure
    (the runtime would skip work it needs); a fact the generator missed is only noted."""

    def all_zero(keys) -> bool:
        # Structural independence (CasADi proves the derivative is zero) or
        # numerically zero at every sample point.
        if all(system.sym[k].is_zero() for k in keys):
            return True
        return all(float(np.max(np.abs(np.asarray(val[k])), initial=0.0)) <= TOLERANCE for k in keys for val in values)

    def off_diagonal_zero(key) -> bool:
        # Structurally, or numerically at every sample point.
        sym = system.sym[key]
        if all(sym[r, c].is_zero() for r in range(sym.size1()) for c in range(sym.size2()) if r != c):
            return True
        for val in values:
            m = np.asarray(val[key])
            if float(np.max(np.abs(m - np.diag(np.diag(m))), initial=0.0)) > TOLERANCE:
                return False
        return True

    separable = all_zero(["momentum_q", "force_v"])
    facts = {
        "lagrangian_autonomous": all_zero(["lagrangian_t", "momentum_t", "force_t"]),
        "constraints_autonomous": all_zero(["constraint_t"]),
        "separable": separable,
        "constant_mass_matrix": all_zero(["mass_matrix_dtqv"]),
        # The stiffness ∂(∇_q L)/∂q: constant and not zero (a quadratic potential).
        "constant_stiffness": separable and all_zero(["force_q_dtqv"]) and not all_zero(["force_q"]),
        # Diagonal, not constant and not zero (a sum of functions of one coordinate each).
        "diagonal_stiffness": separable
        and off_diagonal_zero("force_q")
        and not all_zero(["force_q_dtqv"])
        and not all_zero(["force_q"]),
    }
    for key, holds in facts.items():
        claimed = bool(claims.get(key))
        if claimed and not holds:
            result.structure_failures.append(f"claims {key} but CasADi's derivatives are not zero")
        elif holds and not claimed:
            result.structure_notes.append(f"{key} holds at every sample point but is not claimed")
    form = claims.get("constraint_form")
    if system.m == 0:
        actual = "None"
    elif not all_zero(["constraint_v_v"]):
        actual = "Nonlinear"
    elif all_zero(["constraint_at_zero_velocity"]):
        actual = "Linear"
    else:
        actual = "Affine"
    order = {"None": 0, "Linear": 1, "Affine": 2, "Nonlinear": 3}
    if form not in order:
        result.structure_failures.append(f"unknown constraint_form {form!r}")
    elif order[form] < order[actual]:
        result.structure_failures.append(f"claims constraint_form {form} but CasADi finds {actual}")
    elif order[form] > order[actual]:
        result.structure_notes.append(f"constraint_form {form} claimed, {actual} holds at every sample point")
