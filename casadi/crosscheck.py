#!/usr/bin/env python3
"""Independent CasADi cross-check of spark's generated derivatives and SPARK steps.

Reads the JSON written by ``cargo run -p problems --bin spark-casadi-export``,
rebuilds every system from its neutral S-expression source with CasADi,
differentiates it with CasADi, compares every trait output at every sample
point, solves one SPARK step per (system, method) with CasADi's rootfinder and
compares (q1, v1, Ψ); compares the hard cold steps (every Newton mode) with
the root on the branch from h → 0 (spark_check.cold). Writes a Markdown report.

Exit status: 0 all agree, 1 some comparison failed, 2 bad input or setup.

    python casadi/crosscheck.py --input out/casadi/export.json --report docs/casadi-report.md
    python casadi/crosscheck.py --input ... --perturb derivative   # must exit 1
    python casadi/crosscheck.py --input ... --perturb cold         # must exit 1
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from spark_check import cold, compare, tableaux  # noqa: E402
from spark_check.step import StepSetupError, lda_applicable, solve_lda, solve_step  # noqa: E402
from spark_check.system import CasadiSystem, SourceError  # noqa: E402
from spark_check.sexpr import SexprError  # noqa: E402

FORMAT = "spark-casadi/1"
PERTURBATION = 1e-10  # relative (and absolute) size of the deliberate error, 100x the tolerance
TABLEAU_TOLERANCE = 1e-14


class InputError(Exception):
    """Bad input: exit status 2."""


# ---------------------------------------------------------------- derivatives


def perturb_value(outputs: Dict, path: str) -> str:
    """Add a small error to the first entry of ``outputs[path]``; returns a description."""
    parent = outputs
    parts = path.split(".")
    for part in parts[:-1]:
        parent = parent[part]
    key = parts[-1]
    value = parent[key]
    if isinstance(value, list):
        holder, index = value, 0
        while isinstance(holder[index], list):
            if not holder[index]:
                raise InputError(f"cannot perturb `{path}`: it is empty")
            holder, index = holder[index], 0
        old = holder[index]
        holder[index] = old * (1 + PERTURBATION) + PERTURBATION
    else:
        old = value
        parent[key] = old * (1 + PERTURBATION) + PERTURBATION
    return f"{path}[0…] {old!r} -> perturbed by {PERTURBATION:g} (relative and absolute)"


def check_system(entry: Dict, perturb_path: Optional[str], corrupt: Optional[str] = None) -> compare.SystemResult:
    try:
        system = CasadiSystem(entry["source"], corrupt, PERTURBATION)
        n, m = int(entry["n"]), int(entry["m"])
        params = [float(x) for x in entry["parameter_values"]]
        points = entry["points"]
    except (KeyError, TypeError, ValueError, SourceError, SexprError) as err:
        raise InputError(f"system {entry.get('name', '?')}: {err}") from None
    if (system.n, system.m) != (n, m):
        raise InputError(f"system {entry['name']}: source has n={system.n}, m={system.m}, export says n={n}, m={m}")
    if len(params) != len(system.parameters):
        raise InputError(f"system {entry['name']}: {len(params)} parameter values for {len(system.parameters)} parameters")
    result = compare.SystemResult(entry["name"], n, m, len(points), int(entry.get("skipped_points", 0)))
    if perturb_path is not None and points:
        result.structure_notes.append("PERTURBED: " + perturb_value(points[0]["outputs"], perturb_path))
    if corrupt is not None:
        result.structure_notes.append(f"CORRUPTED: CasADi's {corrupt} is x(1+{PERTURBATION:g})+{PERTURBATION:g}")
    comparisons = compare.output_map(system)
    result.effects = [
        e for e, on in (("f", system.f), ("N", system.N), ("g", system.g), ("events", system.events)) if on is not None
    ]
    casadi_values = []
    for index, point in enumerate(points):
        val = system.evaluate(point["t"], point["q"], point["v"], params, point["psi"])
        casadi_values.append({k: np.array(x) for k, x in val.items()})
        where = f"point {index} ({point['class']})"
        for path, key in comparisons:
            scaled, normwise = compare.errors(compare.lookup(point["outputs"], path), casadi_values[-1][key])
            result.worst.setdefault(path, compare.Worst()).update(scaled, normwise, where)
        if system.g is not None and system.holonomic_rows:
            # CasADi against itself on the source: the velocity-level constraint
            # of a holonomic row is the total time derivative of its g.
            scaled, normwise = compare.errors(casadi_values[-1]["holonomic_g_dot"], casadi_values[-1]["holonomic_k"])
            result.worst.setdefault(compare.HOLONOMIC_IDENTITY, compare.Worst()).update(scaled, normwise, where)
    if system.g is not None:
        symbolic = system.holonomic_identity_is_symbolic()
        rows = ", ".join(
            f"k_{i} = ġ_{i} {'symbolically' if sym else 'numerically'}"
            for i, sym in zip(system.holonomic_rows, symbolic)
        )
        result.structure_notes.append(f"holonomic rows {system.holonomic_rows}: {rows or 'none (all rows are 0)'}")
    claims = dict(
        entry["structure"],
        constant_stiffness=entry.get("constant_stiffness", False),
        diagonal_stiffness=entry.get("diagonal_stiffness", False),
    )
    compare.check_structure(system, claims, casadi_values, result)
    compare.check_effect_flags(system, entry.get("effects", {}), result)
    result.rust_ops = {k: int(v) for k, v in entry.get("operations", {}).items()}
    result.casadi_ops = {
        "stage_values": system.op_counts(CasadiSystem.STAGE_VALUES),
        "stage_jacobians": system.op_counts(CasadiSystem.STAGE_JACOBIANS),
        "bundle": system.op_counts(CasadiSystem.BUNDLE),
    }
    effect_outputs = system.effect_outputs()
    if effect_outputs:
        result.casadi_ops["effects"] = system.op_counts(effect_outputs)
    return result


# ---------------------------------------------------------------------- steps


@dataclass
class StepResult:
    """One whole-step comparison."""

    system: str
    method: str
    stages: int
    errors: Dict[str, float] = field(default_factory=dict)
    residual: float = math.nan
    last_newton_step: float = math.nan
    tableau_error: Optional[float] = None
    note: str = ""

    @property
    def ok(self) -> bool:
        fine = all(e <= compare.TOLERANCE for e in self.errors.values()) and bool(self.errors)
        if self.tableau_error is not None:
            fine = fine and self.tableau_error <= TABLEAU_TOLERANCE
        return fine


def tableau_error(method: Dict) -> Optional[float]:
    """Largest difference between the exported coefficients and Python's own construction."""
    s = int(method["stages"])
    exp = tableaux.expected(method["key"], s)
    if exp is None:
        return None
    c, a, a_hat, a_tilde, b = exp
    worst = 0.0
    pairs = [
        (method["c"], c),
        (method["a"], a),
        (method["a_hat"], a_hat),
        (method["a_tilde"], a_tilde),
        (method["b"], b),
        (method["b_hat"], b),
        (method["b_tilde"], b),
    ]
    for row_index, row in enumerate(method["conditions"]):
        if row.get("kind") == "weights":
            pairs.append((row["omega"], b * c**row_index))
    for got, want in pairs:
        got = np.asarray(got, dtype=float).reshape(np.shape(want))
        worst = max(worst, float(np.max(np.abs(got - want))))
    return worst


def check_step(
    step: Dict, systems: Dict[str, Dict], built: Dict[str, CasadiSystem], perturb: bool, corrupt: Optional[str] = None
) -> StepResult:
    name = step["system"]
    if name not in systems:
        raise InputError(f"step refers to unknown system {name!r}")
    if name not in built:
        built[name] = CasadiSystem(systems[name]["source"], corrupt, PERTURBATION)
    system = built[name]
    method = step["method"]
    result = StepResult(name, method["key"], int(method["stages"]))
    try:
        sol = solve_step(
            system, systems[name]["parameter_values"], method, float(step["t0"]), float(step["h"]), step["q0"], step["v0"]
        )
    except StepSetupError as err:
        raise InputError(f"step {name} / {method['key']}: {err}") from None
    rust = {k: np.asarray(step[k], dtype=float) for k in ("q1", "v1", "psi")}
    if perturb:
        rust["v1"] = rust["v1"].copy()
        rust["v1"][0] = rust["v1"][0] * (1 + PERTURBATION) + PERTURBATION
        result.note = "PERTURBED v1[0]"
    ours = {"q1": sol.q1, "v1": sol.v1, "psi": sol.psi}
    if step.get("stage_velocities"):
        rust["V"] = np.asarray(step["stage_velocities"], dtype=float)
        ours["V"] = sol.stage_velocities
    if sol.holonomic_residual is not None:
        # g(t1, q1): drift of the holonomic constraints after the step, Rust's
        # `holonomic_residual` at its q1 against CasADi's g at CasADi's q1.
        if step.get("holonomic_residual") is None:
            raise InputError(f"step {name} / {method['key']}: the source declares g but no residual was exported")
        rust["g1"] = np.asarray(step["holonomic_residual"], dtype=float)
        ours["g1"] = sol.holonomic_residual
    if corrupt is not None:
        result.note = f"CORRUPTED {corrupt}"
    for key in rust:
        result.errors[key] = compare.errors(rust[key], ours[key])[0]
    if method["key"] == "lobatto-iiib-a-lda" and lda_applicable(system):
        # Also against the paper's own statement of the method (7.3), not its SPARK rewriting.
        q1, v1, psi = solve_lda(
            system, systems[name]["parameter_values"], float(step["t0"]), float(step["h"]), step["q0"], step["v0"]
        )
        for key, ours_73 in (("q1", q1), ("v1", v1), ("psi", np.tile(psi, (int(method["stages"]), 1)))):
            result.errors[key + "(7.3)"] = compare.errors(rust[key], ours_73)[0]
    result.residual = sol.residual
    result.last_newton_step = sol.last_newton_step
    result.tableau_error = tableau_error(method)
    return result


# ----------------------------------------------------------------- cold steps


@dataclass
class ColdResult:
    """One hard cold step of one Newton mode against the branch root."""

    system: str
    method: str
    stages: int
    newton: str
    h: float
    errors: Dict[str, float] = field(default_factory=dict)
    reference: Optional[cold.Reference] = None
    to_constant: float = math.nan  # spark's distance to the constant-guess root
    refusal: Optional[str] = None  # the stepper's error
    problem: Optional[str] = None  # why there is no branch reference
    note: str = ""

    @property
    def ok(self) -> bool:
        return (
            self.refusal is None
            and self.problem is None
            and bool(self.errors)
            and all(e <= cold.TOLERANCE for e in self.errors.values())
        )

    def constant_guess(self) -> str:
        """What CasADi's Newton from the constant guess found, against the branch root."""
        r = self.reference
        if r is None:
            return "-"
        if not (math.isfinite(r.constant.last_newton_step) and r.constant.last_newton_step <= 1e-8):
            return f"no root (last update {r.constant.last_newton_step:.1e})"
        if r.ambiguous:
            return f"another root ({r.distance:.1e} away)"
        return f"the branch root ({r.distance:.1e})"


def check_cold_steps(cold_steps: List[Dict], systems: Dict[str, Dict], perturb: bool) -> List[ColdResult]:
    """Every exported cold step against the branch root of its (system, method), which is
    computed once per (system, method); with ``perturb`` the first solved step's ``v1[0]``
    is corrupted."""
    references: Dict[tuple, object] = {}
    results = []
    perturbed = False
    for step in cold_steps:
        name, method = step["system"], step["method"]
        if name not in systems:
            raise InputError(f"cold step refers to unknown system {name!r}")
        key = (name, method["key"], int(method["stages"]))
        r = ColdResult(name, method["key"], int(method["stages"]), step["newton"], float(step["h"]))
        if key not in references:
            entry = systems[name]
            try:
                solver = cold.BranchSolver(CasadiSystem(entry["source"]), entry["parameter_values"], method)
                references[key] = solver.reference(float(step["t0"]), float(step["h"]), step["q0"], step["v0"])
            except StepSetupError as err:
                raise InputError(f"cold step {name} / {method['key']}: {err}") from None
            except cold.ContinuationError as err:
                references[key] = str(err)
        ref = references[key]
        if isinstance(ref, str):
            r.problem = f"no branch reference: {ref}"
        else:
            r.reference = ref
        solved = step.get("solved")
        if solved is None:
            r.refusal = str(step.get("error") or "no step and no error exported")
        elif r.reference is not None:
            rust = {k: np.asarray(solved[k], dtype=float) for k in ("q1", "v1", "psi", "stage_velocities")}
            if perturb and not perturbed:
                rust["v1"] = rust["v1"].copy()
                rust["v1"][0] = rust["v1"][0] * (1 + PERTURBATION) + PERTURBATION
                r.note, perturbed = "PERTURBED v1[0]", True
            branch, constant = r.reference.branch, r.reference.constant
            for k, label in (("q1", "q1"), ("v1", "v1"), ("psi", "psi"), ("stage_velocities", "V")):
                r.errors[label] = compare.errors(rust[k], getattr(branch, k))[0]
            r.to_constant = max(compare.errors(rust[k], getattr(constant, k))[0] for k in rust)
        results.append(r)
    return results


# --------------------------------------------------------------------- report


def fmt(x: float) -> str:
    if x == 0:
        return "0"
    if math.isinf(x) or math.isnan(x):
        return str(x)
    return f"{x:.1e}"


VARIED = " (varied parameters)"


def base_name(name: str) -> str:
    return name[: -len(VARIED)] if name.endswith(VARIED) else name


def seven_three(errors: Dict[str, float]) -> str:
    """Worst error against the paper's eq. (7.3) form of the LDA step, or ``-``."""
    vals = [v for k, v in errors.items() if k.endswith("(7.3)")]
    return fmt(max(vals)) if vals else "-"


def write_report(
    path: Path, doc: Dict, systems: List[compare.SystemResult], steps: List[StepResult], colds: List[ColdResult]
) -> None:
    lines = [
        "# CasADi cross-check report",
        "",
        "Generated by `casadi/crosscheck.py` (see [casadi.md](casadi.md)); do not edit by hand.",
        f"Sample points drawn with seed {doc['seed']}. Error of an entry: "
        "`|rust − casadi| / max(|casadi|, 1)` (relative, absolute near zero); pass ≤ 1e-12.",
        "",
        "## Derivatives: worst error per system",
        "",
        "Effects: `f` external force, `N` non-ideal constraint force (with `∂N/∂ψ`), `g` holonomic "
        "constraints (residuals compared, and `k_i = ∂g_i/∂t + ∂g_i/∂q·v` checked on each holonomic row), "
        "`events` declared event functions (`event_value`, and `event_gradient`: the value, `∂g/∂t`, `∂g/∂q`, `∂g/∂v`).",
        "",
        "| system | n | m | effects | points (skipped) | worst error | in | normwise rel. | structure | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in systems:
        worst_path = max(r.worst, key=lambda k: r.worst[k].scaled) if r.worst else "-"
        w = r.worst.get(worst_path, compare.Worst())
        normwise = max((x.normwise for x in r.worst.values()), default=0.0)
        structure = "; ".join(r.structure_failures) or "ok"
        verdict = "pass" if r.ok else "**FAIL**"
        lines.append(
            f"| {r.name} | {r.n} | {r.m} | {', '.join(r.effects) or '-'} | {r.points} ({r.skipped}) | "
            f"{fmt(w.scaled)} | `{worst_path}` | "
            f"{fmt(normwise)} | {structure} | {verdict} |"
        )
    lines += [
        "",
        "## Derivatives: worst error per function",
        "",
        "Each column covers the system with its default parameters and with varied parameters.",
        "",
    ]
    groups: Dict[str, List[compare.SystemResult]] = {}
    for r in systems:
        groups.setdefault(base_name(r.name), []).append(r)
    lines.append("| function | " + " | ".join(groups) + " |")
    lines.append("|---|" + "---|" * len(groups))
    for fpath in compare.ALL_PATHS:
        cells = []
        for members in groups.values():
            vals = [r.worst[fpath].scaled for r in members if fpath in r.worst]
            cells.append(fmt(max(vals)) if vals else "-")
        if all(c == "-" for c in cells):
            continue  # an effect no exported system has
        lines.append(f"| `{fpath}` | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Operation counts",
        "",
        "spark: `OperationCounts` of the generated code (0 for hand-written systems). "
        "CasADi: arithmetic operations of one `cse=True` SX Function computing the same outputs "
        "(CasADi's `n_instructions`, which also counts inputs, outputs and constants, in parentheses). "
        "The bundle is `L, ∇_qL, ∇_vL, ∇²_vvL, ∂(∇_vL)/∂q, k, k_q, k_v, Kᵀψ` and its Jacobians in `q`, `v` (as `OperationCounts::bundle`); `stage_values`/`stage_jacobians` are the fused trait functions (with `R = −Kᵀψ`). "
        "Effects: CasADi's cost of `f`, `N` and their Jacobians (`OperationCounts` has no field for them).",
        "",
        "| system | stage_values spark | stage_values CasADi | stage_jacobians spark | stage_jacobians CasADi "
        "| bundle spark | bundle CasADi | effects CasADi |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in systems:
        if base_name(r.name) != r.name:
            continue  # same generated code as the default-parameter entry
        cells = []
        for key in ("stage_values", "stage_jacobians", "bundle"):
            c = r.casadi_ops.get(key, {})
            cells.append(str(r.rust_ops.get(key, "-")))
            cells.append(f"{c.get('arithmetic', '-')} ({c.get('n_instructions', '-')})")
        c = r.casadi_ops.get("effects")
        cells.append(f"{c['arithmetic']} ({c['n_instructions']})" if c else "-")
        lines.append(f"| {r.name} | " + " | ".join(cells) + " |")
    lines += ["", "## Whole SPARK steps", ""]
    if not steps:
        lines.append("No steps were exported.")
    else:
        lines += [
            "CasADi builds equations (6.1) from the exported tableau and the system's source, solves them with "
            "`rootfinder('newton')` from `V = v0, Ψ = 0`, and compares with the Rust stepper. "
            "Tableau: largest difference between the exported coefficients and an independent numpy "
            "construction from the families' defining conditions. With effects, CasADi's stage forces are "
            "`F_i = ∇_qL + f` (weights `â`, `b̂`) and `R_i = −K_iᵀΨ_i + N(T_i,Q_i,V_i,Ψ_i)` (weights `ã`, `b̃`); "
            "`g(t1,q1)` compares the holonomic residual after the step. "
            "(7.3): the LDA step written as the paper's eq. (7.3), for systems of that form without effects.",
            "",
            "| system | method | s | q1 | v1 | Ψ | V | g(t1,q1) | (7.3) | CasADi residual | tableau | verdict |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for st in steps:
            e = st.errors
            lines.append(
                f"| {st.system} | {st.method} | {st.stages} | {fmt(e.get('q1', math.nan))} | "
                f"{fmt(e.get('v1', math.nan))} | {fmt(e.get('psi', math.nan))} | "
                f"{fmt(e['V']) if 'V' in e else '-'} | {fmt(e['g1']) if 'g1' in e else '-'} | "
                f"{seven_three(e)} | {fmt(st.residual)} | "
                f"{fmt(st.tableau_error) if st.tableau_error is not None else 'n/a'} | "
                f"{'pass' if st.ok else '**FAIL**'} |"
            )
    lines += ["", "## Hard cold steps", ""]
    if not colds:
        lines.append("No cold steps were exported.")
    else:
        lines += [
            "Systems with strong velocity-dependent terms (`problems/src/crosscheck/cold.rs`), one step from "
            "their initial state with no earlier step, in every Newton mode. Reference: the root on the branch "
            "that starts at `V = v0` for `h → 0`, followed by CasADi from `θh`, "
            f"θ = {cold.THETA_START:g}, to `h` and polished to round-off; pass: every error of spark's step "
            f"(`q1`, `v1`, `Ψ`, `V`, the measure above) ≤ {cold.TOLERANCE:g}. Beside it, what CasADi's Newton "
            "from the constant guess `V = v0, Ψ = 0, v1 = v0` finds: the branch root, another root (an "
            f"ambiguous case: more than {cold.SAME_ROOT:g} away, never the reference) or none.",
            "",
            "| system | method | s | h | Newton | q1 | v1 | Ψ | V | continuation steps | constant guess | verdict |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for c in colds:
            e = c.errors
            if c.refusal is not None:
                cells = ["refused: " + c.refusal.splitlines()[0].replace("|", "\\|")[:160]] + ["-"] * 3
            else:
                cells = [fmt(e[k]) if k in e else "-" for k in ("q1", "v1", "psi", "V")]
            steps_taken = str(c.reference.continuation_steps) if c.reference is not None else (c.problem or "-")
            lines.append(
                f"| {c.system} | {c.method} | {c.stages} | {c.h:g} | {c.newton} | " + " | ".join(cells) + " | "
                f"{steps_taken} | {c.constant_guess()} | {'pass' if c.ok else '**FAIL**'} |"
            )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


# ----------------------------------------------------------------------- main


def run(args) -> int:
    try:
        doc = json.loads(Path(args.input).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(f"cannot read {args.input}: {err}") from None
    if doc.get("format") != FORMAT:
        raise InputError(f"{args.input}: format {doc.get('format')!r}, expected {FORMAT!r}")
    if not doc.get("systems"):
        raise InputError(f"{args.input}: no systems exported")

    # --perturb force / nonideal: CasADi's f or N is corrupted, and only the
    # systems whose source declares that effect are checked (derivatives and
    # steps); both kinds of comparison must then fail.
    # --perturb event corrupts CasADi's event functions the same way; events
    # do not enter a step, so only the derivatives are compared.
    corrupt = args.perturb if args.perturb in ("force", "nonideal", "event") else None
    effect_field = {"force": "external_force", "nonideal": "nonideal_force", "event": "events"}.get(args.perturb or "")
    selected = [e for e in doc["systems"] if effect_field is None or e["source"].get(effect_field)]
    if effect_field is not None and not selected:
        raise InputError(f"--perturb {args.perturb}: no exported system declares `{effect_field}`")
    if effect_field is not None:
        print(f"corrupted: {len(selected)} systems declare `{effect_field}`")
    do_derivatives = args.perturb in (None, "derivative", "force", "nonideal", "event")
    do_steps = args.perturb in (None, "step", "force", "nonideal")
    do_cold = args.perturb in (None, "cold")
    passed = failed = 0
    system_results: List[compare.SystemResult] = []
    if do_derivatives:
        for index, entry in enumerate(selected):
            perturb_path = args.perturb_path if (args.perturb == "derivative" and index == 0) else None
            r = check_system(entry, perturb_path, corrupt)
            system_results.append(r)
            worst_path = max(r.worst, key=lambda k: r.worst[k].scaled) if r.worst else "-"
            w = r.worst.get(worst_path, compare.Worst())
            status = "ok  " if r.ok else "FAIL"
            print(
                f"[{status}] derivatives {r.name:<34} n={r.n} m={r.m} points={r.points:<3} "
                f"worst {w.scaled:.2e} ({worst_path} at {w.where or '-'})"
            )
            for path, wp in r.worst.items():
                if not wp.ok:
                    print(f"         {path}: {wp.scaled:.3e} at {wp.where}")
            for msg in r.structure_failures:
                print(f"         structure: {msg}")
            for msg in r.structure_notes:
                print(f"         note: {msg}")
            counted = len(r.worst) + 1  # functions + structure facts
            bad = sum(1 for wp in r.worst.values() if not wp.ok) + (1 if r.structure_failures else 0)
            if r.points == 0:
                print("         no sample points: nothing was compared")
                bad += 1
            passed += counted - bad
            failed += bad

    step_results: List[StepResult] = []
    if do_steps:
        systems = {s["name"]: s for s in doc["systems"]}
        built: Dict[str, CasadiSystem] = {}
        names = {e["name"] for e in selected}
        steps = [st for st in doc.get("steps", []) if st.get("system") in names or effect_field is None]
        if effect_field is not None and not steps:
            raise InputError(f"--perturb {args.perturb}: no exported step of a system with `{effect_field}`")
        if args.perturb == "step" and not steps:
            raise InputError("--perturb step: the export has no steps to perturb")
        if args.require_steps and not steps:
            print("[FAIL] steps: the export contains no SPARK steps")
            failed += 1
        for index, step in enumerate(steps):
            st = check_step(step, systems, built, perturb=(args.perturb == "step" and index == 0), corrupt=corrupt)
            step_results.append(st)
            status = "ok  " if st.ok else "FAIL"
            errs = " ".join(f"{k}={v:.1e}" for k, v in st.errors.items())
            tab = f" tableau={st.tableau_error:.1e}" if st.tableau_error is not None else ""
            print(
                f"[{status}] step {st.system:<30} {st.method:<26} s={st.stages} {errs} "
                f"residual={st.residual:.1e}{tab} {st.note}"
            )
            passed += 1 if st.ok else 0
            failed += 0 if st.ok else 1

    cold_results: List[ColdResult] = []
    if do_cold:
        systems = {s["name"]: s for s in doc["systems"]}
        cold_steps = doc.get("cold_steps", [])
        if args.perturb == "cold":
            if not any(st.get("solved") for st in cold_steps):
                raise InputError("--perturb cold: the export has no solved cold step to perturb")
            # Only the (system, method) of the first solved step: its modes.
            first = next(st for st in cold_steps if st.get("solved"))
            group = (first["system"], first["method"]["label"])
            cold_steps = [st for st in cold_steps if (st["system"], st["method"]["label"]) == group]
        if args.require_steps and not cold_steps:
            print("[FAIL] cold steps: the export contains no hard cold steps")
            failed += 1
        for c in check_cold_steps(cold_steps, systems, perturb=(args.perturb == "cold")):
            cold_results.append(c)
            status = "ok  " if c.ok else "FAIL"
            if c.refusal is not None:
                what = "refused: " + c.refusal.splitlines()[0][:200]
            elif c.problem is not None:
                what = c.problem
            else:
                what = " ".join(f"{k}={v:.1e}" for k, v in c.errors.items())
            if c.reference is not None and c.reference.ambiguous and math.isfinite(c.to_constant):
                what += f" (to the constant guess's root: {c.to_constant:.1e})"
            print(
                f"[{status}] cold-step {c.system:<22} {c.method:<17} s={c.stages} {c.newton:<20} {what} "
                f"| constant guess: {c.constant_guess()} {c.note}"
            )
            passed += 1 if c.ok else 0
            failed += 0 if c.ok else 1

    if args.report and args.perturb is None:
        write_report(Path(args.report), doc, system_results, step_results, cold_results)
        print(f"report written to {args.report}")
    print(f"casadi: {passed} passed, {failed} failed")
    return 1 if failed else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", required=True, help="JSON written by spark-casadi-export")
    parser.add_argument("--report", help="Markdown report to write (not written when perturbing)")
    parser.add_argument(
        "--perturb",
        choices=["derivative", "step", "force", "nonideal", "event", "cold"],
        help="deliberately corrupt one exported value (derivative, step, cold: a hard cold step, and only the "
        "cold steps of its system and method are checked) or CasADi's own f, N or event "
        "functions (force, nonideal, event: only systems with that effect are checked) by 1e-10; "
        "the check must then fail (exit 1)",
    )
    parser.add_argument(
        "--perturb-path",
        default="stage_jacobians.force_q",
        help="which output of the first point of the first system --perturb derivative corrupts",
    )
    parser.add_argument(
        "--require-steps", action="store_true", help="fail if the export has no SPARK steps or no hard cold steps"
    )
    args = parser.parse_args()
    try:
        return run(args)
    except (InputError, compare.ExportError, SourceError, SexprError) as err:
        print(f"casadi crosscheck: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
