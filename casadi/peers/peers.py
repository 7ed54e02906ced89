"""Performance peers of the SPARK stepper, measured on the problem the Rust
`spark work-precision` command hands over (JSON) and written back as CSV:

1. CasADi C (Newton-QR): the SPARK equations (paper eq. 6.1) written in
   CasADi from the neutral S-expression source, one Newton iteration
   (residual, Jacobian, CasADi's dense QR solve) generated to C with
   ``CodeGenerator`` and compiled with ``gcc -O3``; a small C driver loops
   the iterations (stop when ``|Δx|∞ ≤ 16ε(1+|x|∞)``, at most 20) and the
   steps, with the previous step's solution as starting guess, and times the
   whole run with ``clock_gettime`` (median of repeats). Same method, same
   step counts as the Rust run, so per-step times compare at equal accuracy.
2. CasADi C (Newton-LU) (``newton_lu.py``): the same equations, the residual
   and its dense exact Jacobian generated to C (``cse``), solved by a
   hand-written Newton with a dense partial-pivoting LU, warm-started from
   the previous step's converged unknowns, stopping at ``|F|∞ ≤ 1e-14`` or
   ``|Δx|∞ ≤ 1e-14``; same step counts, same clock.
3. SciPy ``solve_ivp`` (DOP853 and Radau) on the ψ-eliminated ODE
   ``q̇ = v``, ``[[M, Kᵀ], [K, 0]] [v̇; ψ] = [F − P_q v − P_t; −k_t − k_q v]``,
   with the right-hand side and its Jacobian as CasADi functions (compiled
   expression graphs called from Python), over a tolerance sweep.

With ``--per-step`` only the two CasADi C peers run, once per method at the
one step count given, and the output is JSON (times, residual evaluations
and factorizations per step, end state; each row names its ``solver``) for
`spark work-precision --per-step`.

Usage: peers.py --input problem.json --output points.csv --build DIR [--per-step]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import c_driver  # noqa: E402
import newton_lu  # noqa: E402
from spark_check.step import spark_residual  # noqa: E402
from spark_check.system import CasadiSystem  # noqa: E402

QR_SOLVER = "CasADi C (Newton-QR)"

FIELDS = [
    "system", "solver", "method", "stages", "setting", "steps", "error_q", "error_v",
    "energy_error", "wall_time", "cpu_time", "time_per_step", "newton_iterations", "repeats",
]

DRIVER = c_driver.HEAD + r"""
/* argv: steps repeats T q0[N] v0[N] p[NP]; prints q(T) v(T) median_wall median_cpu mean_iterations failed */
int main(int argc, char** argv) {
    if (argc != 4 + 2 * N + NP) { fprintf(stderr, "bad arguments\n"); return 2; }
    long steps = atol(argv[1]);
    int repeats = atoi(argv[2]);
    double T = atof(argv[3]);
    double q0[N], v0[N], p[NP > 0 ? NP : 1];
    for (int i = 0; i < N; ++i) q0[i] = atof(argv[4 + i]);
    for (int i = 0; i < N; ++i) v0[i] = atof(argv[4 + N + i]);
    for (int i = 0; i < NP; ++i) p[i] = atof(argv[4 + 2 * N + i]);
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    spark_newton_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    const casadi_real** arg = malloc(sizeof(casadi_real*) * (sz_arg + 1));
    casadi_real** res = malloc(sizeof(casadi_real*) * (sz_res + 1));
    casadi_int* iw = malloc(sizeof(casadi_int) * (sz_iw + 1));
    casadi_real* w = malloc(sizeof(casadi_real) * (sz_w + 1));
    double* times = malloc(sizeof(double) * repeats);
    double* cpus = malloc(sizeof(double) * repeats);
    double q[N], v[N], x[DIM], xn[DIM], par[NPAR], dxn;
    double h = T / steps;
    long iterations = 0;
    int failed = 0;
    for (int r = 0; r < repeats; ++r) {
        double start = now(), cpu_start = cpu_now();
        cold_start(q, v, x, q0, v0);
        iterations = 0;
        for (long k = 0; k < steps; ++k) {
            step_parameters(par, k * h, h, q, v, p);
            int it = 0;
            for (; it < 20; ++it) {
                arg[0] = x; arg[1] = par; res[0] = xn; res[1] = &dxn;
                if (spark_newton(arg, res, iw, w, 0)) { failed = 1; break; }
                double xmax = 0.0;
                for (int i = 0; i < DIM; ++i) xmax = fmax(xmax, fabs(xn[i]));
                memcpy(x, xn, sizeof x);
                if (!(dxn == dxn)) { failed = 1; break; }
                if (dxn <= 16 * 2.220446049250313e-16 * (1.0 + xmax)) { ++it; break; }
            }
            iterations += it;
            advance(q, v, x, h);
        }
        times[r] = now() - start;
        cpus[r] = cpu_now() - cpu_start;
    }
    qsort(times, repeats, sizeof(double), cmp);
    qsort(cpus, repeats, sizeof(double), cmp);
    double median = repeats %% 2 ? times[repeats / 2] : 0.5 * (times[repeats / 2 - 1] + times[repeats / 2]);
    double cpu_median = repeats %% 2 ? cpus[repeats / 2] : 0.5 * (cpus[repeats / 2 - 1] + cpus[repeats / 2]);
    for (int i = 0; i < N; ++i) printf("%%.17g ", q[i]);
    for (int i = 0; i < N; ++i) printf("%%.17g ", v[i]);
    printf("%%.9g %%.9g %%.6g %%d\n", median, cpu_median, (double)iterations / steps, failed);
    return 0;
}
"""


def point(inp, solver, method, stages, setting, steps, q, v, wall, cpu, iters, repeats):
    q_ref, v_ref = np.array(inp["q_ref"]), np.array(inp["v_ref"])
    return {
        "system": inp["system"], "solver": solver, "method": method, "stages": stages,
        "setting": setting, "steps": steps,
        "error_q": float(np.max(np.abs(np.asarray(q) - q_ref))),
        "error_v": float(np.max(np.abs(np.asarray(v) - v_ref))),
        "energy_error": float("nan"), "wall_time": wall, "cpu_time": cpu, "time_per_step": cpu / max(steps, 1),
        "newton_iterations": iters, "repeats": repeats,
    }


def build_newton(system: CasadiSystem, tableau, build: Path, label: str) -> Path:
    """Generate one Newton iteration of the SPARK step as C and compile it with its driver."""
    g = spark_residual(system, tableau)
    x = ca.MX.sym("x", g.size1_in(0))
    par = ca.MX.sym("par", g.size1_in(1))
    xs, ps = ca.SX.sym("x", g.size1_in(0)), ca.SX.sym("p", g.size1_in(1))
    gx = g(xs, ps)
    jac = ca.Function("spark_jac", [xs, ps], [gx, ca.jacobian(gx, xs)], {"cse": True})
    r, J = jac(x, par)
    dx = ca.solve(J, -r, "qr")
    newton = ca.Function("spark_newton", [x, par], [x + dx, ca.norm_inf(dx)])
    d = build / label.replace(" ", "_").replace("=", "")
    d.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator("spark_newton.c", {"with_header": True})
    cg.add(newton)
    c_driver.generate(cg, d)
    (d / "driver.c").write_text(DRIVER % c_driver.fields(system, tableau, "spark_newton.h"))
    exe = d / "driver"
    t0 = time.perf_counter()
    subprocess.run(["gcc", "-O3", "-march=native", "-o", str(exe), str(d / "spark_newton.c"), str(d / "driver.c"),
                    "-lm"], check=True, capture_output=True)
    print(f"compiled {label} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return exe


def run_qr_driver(exe: Path, steps: int, repeats: int, inp):
    """One call of the Newton-QR driver: ``(q, v, wall, cpu, iterations per step, failed)``, the
    times the medians of ``repeats`` runs."""
    args = [str(exe), str(steps), str(repeats), repr(inp["final_time"])]
    args += [repr(x) for x in inp["q0"]] + [repr(x) for x in inp["v0"]]
    args += [repr(x) for x in inp["parameter_values"]]
    res = subprocess.run(args, check=True, capture_output=True, text=True).stdout.split()
    n = len(inp["q0"])
    q, v = [float(x) for x in res[:n]], [float(x) for x in res[n:2 * n]]
    failed = bool(int(res[2 * n + 3])) or not all(math.isfinite(x) for x in q + v)
    return q, v, float(res[2 * n]), float(res[2 * n + 1]), float(res[2 * n + 2]), failed


def casadi_points(inp, system, build):
    out = []
    T = inp["final_time"]
    for m in inp["methods"]:
        exe = build_newton(system, m["tableau"], build, m["label"])
        for steps in m["steps"]:
            q, v, wall, cpu, iters, failed = run_qr_driver(exe, steps, max(1, inp["repeats"]), inp)
            if failed:
                continue
            out.append(point(inp, QR_SOLVER, m["label"], int(m["tableau"]["stages"]), T / steps, steps,
                             q, v, wall, cpu, iters, inp["repeats"]))
    return out


def newton_lu_runs(inp, system, build):
    """Every method at every step count with the Newton-LU peer: ``(method, steps, RunOutcome)``."""
    out = []
    for m in inp["methods"]:
        exe = newton_lu.build(system, m["tableau"], build, m["label"])
        for steps in m["steps"]:
            r = newton_lu.run(exe, steps, inp["repeats"], inp.get("min_timing", 0.0), inp["final_time"],
                              inp["q0"], inp["v0"], inp["parameter_values"])
            out.append((m, steps, r))
    return out


def newton_lu_points(inp, system, build):
    """The Newton-LU peer's work-precision points (``newton_iterations``: factorizations per step)."""
    out = []
    T = inp["final_time"]
    for m, steps, r in newton_lu_runs(inp, system, build):
        if r.failed or not all(math.isfinite(x) for x in r.q + r.v):
            continue
        out.append(point(inp, newton_lu.SOLVER, m["label"], int(m["tableau"]["stages"]), T / steps, steps,
                         r.q, r.v, r.wall, r.cpu, r.factorizations_per_step, r.repeats))
    return out


def qr_run(exe: Path, steps: int, inp) -> dict:
    """One per-step figure of the Newton-QR peer: its driver's median over
    repeats, as many as make ``min_timing`` seconds of runs (at least
    ``repeats``), after one untimed run that sizes them."""
    once = max(run_qr_driver(exe, steps, 1, inp)[3], 1e-9)
    repeats = int(min(max(inp["repeats"], math.ceil(inp.get("min_timing", 0.0) / once)), 100_000))
    q, v, wall, cpu, iterations, failed = run_qr_driver(exe, steps, repeats, inp)
    return {
        "solver": QR_SOLVER, "steps": steps, "failed": failed, "repeats": repeats, "wall_time": wall,
        "cpu_time": cpu,
        # Each iteration evaluates the residual and its Jacobian and solves by QR.
        "evaluations_per_step": iterations, "factorizations_per_step": iterations, "q": q, "v": v,
    }


def per_step_rows(inp, system, build):
    """Both CasADi peers' per-step figures at each method's step count, for `spark work-precision --per-step`:
    the Newton-LU peer's, then the Newton-QR peer's, each row naming its ``solver``."""
    rows = []
    for m, steps, r in newton_lu_runs(inp, system, build):
        rows.append({
            "solver": newton_lu.SOLVER, "method": m["label"], "steps": steps, "failed": r.failed,
            "repeats": r.repeats, "wall_time": r.wall, "cpu_time": r.cpu,
            "evaluations_per_step": r.evaluations_per_step, "factorizations_per_step": r.factorizations_per_step,
            "q": r.q, "v": r.v,
        })
    for m in inp["methods"]:
        # A Newton-QR method that does not build or run is left out (the
        # table then says the peer returned no run of it), not the rows above.
        try:
            exe = build_newton(system, m["tableau"], build, m["label"])
            for steps in m["steps"]:
                rows.append({"method": m["label"], **qr_run(exe, steps, inp)})
        except (subprocess.CalledProcessError, OSError, ValueError, IndexError) as e:
            print(f"{QR_SOLVER} {m['label']}: {e}", file=sys.stderr)
    return rows


def ode_rhs(system: CasadiSystem):
    """The ψ-eliminated right-hand side y ↦ (v, v̇) and its Jacobian as CasADi functions."""
    t, q, v, p = system.t, system.q, system.v, system.p
    n, m = system.n, system.m
    mom = ca.gradient(system.L, v)
    force = ca.gradient(system.L, q)
    mass = ca.jacobian(mom, v)
    rhs = force - ca.mtimes(ca.jacobian(mom, q), v) - ca.jacobian(mom, t)
    if m:
        K = ca.jacobian(system.k, v)
        rk = -ca.jacobian(system.k, t) - ca.mtimes(ca.jacobian(system.k, q), v)
        A = ca.vertcat(ca.horzcat(mass, K.T), ca.horzcat(K, ca.SX.zeros(m, m)))
        acc = ca.solve(A, ca.vertcat(rhs, rk))[:n]
    else:
        acc = ca.solve(mass, rhs)
    y = ca.vertcat(q, v)
    f = ca.vertcat(v, acc)
    return ca.Function("f", [t, y, p], [f]), ca.Function("J", [t, y, p], [ca.jacobian(f, y)])


def scipy_points(inp, system):
    f, J = ode_rhs(system)
    pv = np.array(inp["parameter_values"], dtype=float)
    fun = lambda t, y: np.asarray(f(t, y, pv)).ravel()  # noqa: E731
    jac = lambda t, y: np.asarray(J(t, y, pv))  # noqa: E731
    y0 = np.concatenate([inp["q0"], inp["v0"]])
    T, n = inp["final_time"], system.n
    out = []
    for method in ("DOP853", "Radau"):
        for tol in inp["tolerances"]:
            kw = {"jac": jac} if method == "Radau" else {}
            times, cpus = [], []
            sol = None
            for _ in range(max(1, min(inp["repeats"], 3))):
                t0, c0 = time.perf_counter(), time.thread_time()
                sol = solve_ivp(fun, (0.0, T), y0, method=method, rtol=tol, atol=tol, t_eval=[T], **kw)
                cpus.append(time.thread_time() - c0)
                times.append(time.perf_counter() - t0)
                if cpus[-1] > 5 * inp["max_run_time"]:
                    break
            if sol is None or not sol.success:
                continue
            y = sol.y[:, -1]
            wall, cpu = statistics.median(times), statistics.median(cpus)
            out.append(point(inp, "SciPy solve_ivp", method, 0, tol, _steps(sol),
                             y[:n], y[n:], wall, cpu, float("nan"), len(times)))
            if cpu > 5 * inp["max_run_time"]:
                break
    return out


def _steps(sol) -> int:
    # solve_ivp reports evaluations, not steps; DOP853 uses 12 per step, Radau about 1 + 3·(Newton its).
    return int(sol.nfev)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", required=True, type=Path)
    ap.add_argument("--output", required=True, type=Path)
    ap.add_argument("--build", required=True, type=Path)
    ap.add_argument("--skip-casadi", action="store_true")
    ap.add_argument("--per-step", action="store_true", help="only the CasADi C peers' per-step figures, as JSON")
    a = ap.parse_args()
    inp = json.loads(a.input.read_text())
    system = CasadiSystem(inp)
    if a.per_step:
        a.output.write_text(json.dumps(per_step_rows(inp, system, a.build), indent=1))
        return 0
    points = []
    if not a.skip_casadi:
        points += casadi_points(inp, system, a.build)
        points += newton_lu_points(inp, system, a.build)
    points += scipy_points(inp, system)
    with a.output.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        w.writeheader()
        for p in points:
            w.writerow(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
