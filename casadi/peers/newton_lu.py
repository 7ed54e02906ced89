"""The Newton-LU peer: the SPARK step equations (paper eq. 6.1) as CasADi
generated C, solved by a hand-written dense Newton in C.

CasADi SX builds the residual ``F(x, par)`` of (6.1) from the neutral source
text and the exported tableau (``spark_check.step.spark_residual``, the same
equations the cross-check solves) and its dense exact Jacobian ``∂F/∂x``;
``CodeGenerator`` writes both as C with common-subexpression elimination
(``cse``). The C driver below does the rest by hand:

- Newton with a dense partial-pivoting LU of ``∂F/∂x`` (no CasADi solver);
- the unknowns ``x = [V_1..V_s, Ψ_1..Ψ_s, v1]`` of step ``k+1`` start from the
  converged unknowns of step ``k`` (the first step from ``V_j = v0``,
  ``Ψ_j = 0``, ``v1 = v0``);
- the stop rule: after every residual evaluation, before the Jacobian is
  evaluated or factorized, ``|F|∞ ≤ 1e-14`` ends the step; after every
  Newton update, ``|Δx|∞ ≤ 1e-14`` ends it; at most 50 iterations;
- ``gcc -O3 -march=native``; timed by ``CLOCK_THREAD_CPUTIME_ID`` (median of
  repeats, the same clock the Rust measurements use).

The residual and the Jacobian are separate generated functions, so the final
residual check of a step costs no Jacobian.

The executable has two modes:

``driver step t0 h q0[n] v0[n] p[np] x0[dim]``
    one step from the guess ``x0``; prints ``status evaluations
    factorizations``, the converged unknowns, then one line ``|F|∞ |Δx|∞``
    per residual evaluation (``|Δx|∞`` is ``nan`` when no factorization
    followed it).
``driver run steps repeats min_seconds T q0[n] v0[n] p[np]``
    ``steps`` steps of size ``T/steps``, repeated at least ``repeats`` times
    and until ``min_seconds`` of CPU time are spent; prints ``q(T) v(T)``,
    the median wall and CPU time of one run, the residual evaluations and
    factorizations per step, a failure flag and the number of repeats.
"""

from __future__ import annotations

import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import List, Sequence

import casadi as ca
import numpy as np

import c_driver
from spark_check.step import spark_residual
from spark_check.system import CasadiSystem

SOLVER = "CasADi C (Newton-LU)"
TOLERANCE = 1e-14
MAX_ITERATIONS = 50

DRIVER = c_driver.HEAD + r"""
#define TOL %(tol)r
#define MAXIT %(maxit)d

static const casadi_real* arg_f[8];
static casadi_real* res_f[8];
static casadi_int* iw_f;
static casadi_real* w_f;
static const casadi_real* arg_j[8];
static casadi_real* res_j[8];
static casadi_int* iw_j;
static casadi_real* w_j;
static double F[DIM], J[DIM * DIM], dx[DIM];
static int piv[DIM];

static double median(double* v, int n) {
    qsort(v, n, sizeof(double), cmp);
    return n %% 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static double norm_inf(const double* v) {
    double r = 0.0;
    for (int i = 0; i < DIM; ++i) {
        double a = fabs(v[i]);
        if (!(a <= r)) r = a; /* a NaN propagates */
    }
    return r;
}

/* Dense LU with partial pivoting of the column-major DIM x DIM matrix A,
   in place; returns 1 on a zero or non-finite pivot. */
static int lu_factor(double* A) {
    for (int k = 0; k < DIM; ++k) {
        int p = k;
        double big = fabs(A[k + k * DIM]);
        for (int i = k + 1; i < DIM; ++i) {
            double a = fabs(A[i + k * DIM]);
            if (a > big) { big = a; p = i; }
        }
        if (!(big > 0.0) || !isfinite(big)) return 1;
        piv[k] = p;
        if (p != k)
            for (int j = 0; j < DIM; ++j) {
                double t = A[k + j * DIM];
                A[k + j * DIM] = A[p + j * DIM];
                A[p + j * DIM] = t;
            }
        double inv = 1.0 / A[k + k * DIM];
        for (int i = k + 1; i < DIM; ++i) A[i + k * DIM] *= inv;
        for (int j = k + 1; j < DIM; ++j) {
            double akj = A[k + j * DIM];
            if (akj == 0.0) continue;
            for (int i = k + 1; i < DIM; ++i) A[i + j * DIM] -= A[i + k * DIM] * akj;
        }
    }
    return 0;
}

/* Solves A x = b in place with the factors and row swaps of lu_factor
   (the swaps first, then the unit lower and the upper triangle). */
static void lu_solve(const double* A, double* b) {
    for (int k = 0; k < DIM; ++k) {
        int p = piv[k];
        if (p != k) { double t = b[k]; b[k] = b[p]; b[p] = t; }
    }
    for (int k = 0; k < DIM; ++k)
        for (int i = k + 1; i < DIM; ++i) b[i] -= A[i + k * DIM] * b[k];
    for (int k = DIM - 1; k >= 0; --k) {
        b[k] /= A[k + k * DIM];
        for (int i = 0; i < k; ++i) b[i] -= A[i + k * DIM] * b[k];
    }
}

/* Newton on F(x, par) = 0 from the guess in x (overwritten by the solution).
   Returns 0 when the stop rule holds, 1 after MAXIT iterations, 2 on a
   singular or non-finite Jacobian or residual, 3 if the generated code fails.
   hist (2 per evaluation, may be NULL) receives |F| and |dx|. */
static int newton(double* x, const double* par, long* evals, long* facts, double* hist, int* nhist) {
    for (int it = 0; it <= MAXIT; ++it) {
        arg_f[0] = x; arg_f[1] = par; res_f[0] = F;
        if (spark_f(arg_f, res_f, iw_f, w_f, 0)) return 3;
        ++*evals;
        double fn = norm_inf(F);
        if (hist) { hist[2 * *nhist] = fn; hist[2 * *nhist + 1] = NAN; ++*nhist; }
        if (!(fn == fn) || isinf(fn)) return 2;
        if (fn <= TOL) return 0;
        if (it == MAXIT) return 1;
        arg_j[0] = x; arg_j[1] = par; res_j[0] = J;
        if (spark_j(arg_j, res_j, iw_j, w_j, 0)) return 3;
        if (lu_factor(J)) return 2;
        ++*facts;
        for (int i = 0; i < DIM; ++i) dx[i] = -F[i];
        lu_solve(J, dx);
        double dn = norm_inf(dx);
        if (hist) hist[2 * *nhist - 1] = dn;
        if (!(dn == dn) || isinf(dn)) return 2;
        for (int i = 0; i < DIM; ++i) x[i] += dx[i];
        if (dn <= TOL) return 0;
    }
    return 1;
}

static void work(void) {
    casadi_int a, r, i, w;
    spark_f_work(&a, &r, &i, &w);
    if (a > 8 || r > 8) { fprintf(stderr, "too many arguments\n"); exit(2); }
    iw_f = malloc(sizeof(casadi_int) * (i + 1));
    w_f = malloc(sizeof(casadi_real) * (w + 1));
    spark_j_work(&a, &r, &i, &w);
    if (a > 8 || r > 8) { fprintf(stderr, "too many arguments\n"); exit(2); }
    iw_j = malloc(sizeof(casadi_int) * (i + 1));
    w_j = malloc(sizeof(casadi_real) * (w + 1));
}

static void read_vec(char** argv, int* k, double* out, int n) {
    for (int i = 0; i < n; ++i) out[i] = strtod(argv[(*k)++], NULL);
}

static int step_mode(int argc, char** argv) {
    if (argc != 4 + 2 * N + NP + DIM) { fprintf(stderr, "step: bad arguments\n"); return 2; }
    int k = 2;
    double par[NPAR], x[DIM];
    par[0] = strtod(argv[k++], NULL);
    par[1] = strtod(argv[k++], NULL);
    read_vec(argv, &k, par + 2, 2 * N + NP);
    read_vec(argv, &k, x, DIM);
    long evals = 0, facts = 0;
    static double hist[2 * (MAXIT + 2)];
    int nhist = 0;
    int status = newton(x, par, &evals, &facts, hist, &nhist);
    printf("%%d %%ld %%ld\n", status, evals, facts);
    for (int i = 0; i < DIM; ++i) printf("%%.17g ", x[i]);
    printf("\n");
    for (int i = 0; i < nhist; ++i) printf("%%.17g %%.17g\n", hist[2 * i], hist[2 * i + 1]);
    return 0;
}

static int run_mode(int argc, char** argv) {
    if (argc != 6 + 2 * N + NP) { fprintf(stderr, "run: bad arguments\n"); return 2; }
    long steps = atol(argv[2]);
    int repeats = atoi(argv[3]);
    double min_seconds = strtod(argv[4], NULL);
    double T = strtod(argv[5], NULL);
    int k = 6;
    double q0[N], v0[N], p[NP > 0 ? NP : 1];
    read_vec(argv, &k, q0, N);
    read_vec(argv, &k, v0, N);
    read_vec(argv, &k, p, NP);
    if (steps < 1 || repeats < 1) { fprintf(stderr, "run: need steps, repeats >= 1\n"); return 2; }
    int cap = repeats > 1000 ? repeats : 1000;
    double* times = malloc(sizeof(double) * cap);
    double* cpus = malloc(sizeof(double) * cap);
    double q[N], v[N], x[DIM], par[NPAR];
    double h = T / steps;
    long evals = 0, facts = 0;
    int failed = 0, r = 0;
    double spent = 0.0;
    while (r < cap && (r < repeats || spent < min_seconds)) {
        double start = now(), cpu_start = cpu_now();
        cold_start(q, v, x, q0, v0);
        evals = facts = 0;
        failed = 0;
        for (long st = 0; st < steps && !failed; ++st) {
            step_parameters(par, st * h, h, q, v, p);
            if (newton(x, par, &evals, &facts, NULL, NULL)) failed = 1;
            advance(q, v, x, h);
        }
        times[r] = now() - start;
        cpus[r] = cpu_now() - cpu_start;
        spent += cpus[r];
        ++r;
        if (failed) break;
    }
    for (int i = 0; i < N; ++i) printf("%%.17g ", q[i]);
    for (int i = 0; i < N; ++i) printf("%%.17g ", v[i]);
    printf("%%.9g %%.9g %%.9g %%.9g %%d %%d\n", median(times, r), median(cpus, r), (double)evals / steps,
           (double)facts / steps, failed, r);
    return 0;
}

int main(int argc, char** argv) {
    work();
    if (argc > 1 && strcmp(argv[1], "step") == 0) return step_mode(argc, argv);
    if (argc > 1 && strcmp(argv[1], "run") == 0) return run_mode(argc, argv);
    fprintf(stderr, "usage: driver step ... | driver run ...\n");
    return 2;
}
"""


class PeerError(RuntimeError):
    """The generated peer could not be built or did not answer as expected."""


@dataclass
class StepOutcome:
    """What one Newton-LU step returned."""

    status: int  # 0 converged, 1 iteration limit, 2 singular or non-finite, 3 generated code failed
    evaluations: int
    factorizations: int
    x: np.ndarray
    residual_norms: List[float]  # |F|∞ at every evaluation
    update_norms: List[float]  # |Δx|∞ after it (nan if none followed)


@dataclass
class RunOutcome:
    """What one timed Newton-LU trajectory returned."""

    q: List[float]
    v: List[float]
    wall: float
    cpu: float
    evaluations_per_step: float
    factorizations_per_step: float
    failed: bool
    repeats: int


def _flat(label: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in label)


def build(system: CasadiSystem, tableau, build_dir: Path, label: str) -> Path:
    """Generate ``F`` and ``∂F/∂x`` of the SPARK step as C and compile them with the Newton driver."""
    g = spark_residual(system, tableau)
    xs = ca.SX.sym("x", g.size1_in(0))
    ps = ca.SX.sym("par", g.size1_in(1))
    residual = g(xs, ps)
    jacobian = ca.densify(ca.jacobian(residual, xs))
    f = ca.Function("spark_f", [xs, ps], [residual], {"cse": True})
    j = ca.Function("spark_j", [xs, ps], [jacobian], {"cse": True})
    d = build_dir / f"newton-lu-{_flat(label)}"
    d.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator("spark_fj.c", {"with_header": True})
    cg.add(f)
    cg.add(j)
    c_driver.generate(cg, d)
    (d / "driver.c").write_text(DRIVER % {
        **c_driver.fields(system, tableau, "spark_fj.h"), "tol": TOLERANCE, "maxit": MAX_ITERATIONS,
    })
    exe = d / "driver"
    cmd = ["gcc", "-O3", "-march=native", "-o", str(exe), str(d / "spark_fj.c"), str(d / "driver.c"), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise PeerError(f"gcc failed on {d}: {done.stderr[-2000:]}")
    return exe


def initial_guess(v0: Sequence[float], stages: int, m: int) -> np.ndarray:
    """The cold start of the first step: ``V_j = v0``, ``Ψ_j = 0``, ``v1 = v0``."""
    v0 = np.asarray(v0, dtype=float)
    return np.concatenate([np.tile(v0, stages), np.zeros(stages * m), v0])


def step(exe: Path, t0: float, h: float, q0, v0, parameters, x0) -> StepOutcome:
    """One step of the compiled peer from the guess ``x0``."""
    args = [str(exe), "step", repr(float(t0)), repr(float(h))]
    args += [repr(float(x)) for x in (*q0, *v0, *parameters, *x0)]
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode != 0:
        raise PeerError(f"{exe} step exited with {done.returncode}: {done.stderr.strip()}")
    lines = done.stdout.strip().splitlines()
    status, evaluations, factorizations = (int(w) for w in lines[0].split())
    x = np.array([float(w) for w in lines[1].split()])
    hist = [tuple(float(w) for w in line.split()) for line in lines[2:]]
    return StepOutcome(status, evaluations, factorizations, x, [a for a, _ in hist], [b for _, b in hist])


def run(exe: Path, steps: int, repeats: int, min_seconds: float, final_time: float, q0, v0, parameters) -> RunOutcome:
    """``steps`` timed steps of the compiled peer from ``(q0, v0)`` to ``final_time``."""
    args = [str(exe), "run", str(int(steps)), str(max(1, int(repeats))), repr(float(min_seconds)), repr(final_time)]
    args += [repr(float(x)) for x in (*q0, *v0, *parameters)]
    t0 = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode != 0:
        raise PeerError(f"{exe} run exited with {done.returncode} after {time.perf_counter() - t0:.1f} s: "
                        f"{done.stderr.strip()}")
    words = done.stdout.split()
    n = len(q0)
    return RunOutcome(
        q=[float(w) for w in words[:n]],
        v=[float(w) for w in words[n:2 * n]],
        wall=float(words[2 * n]),
        cpu=float(words[2 * n + 1]),
        evaluations_per_step=float(words[2 * n + 2]),
        factorizations_per_step=float(words[2 * n + 3]),
        failed=bool(int(words[2 * n + 4])),
        repeats=int(words[2 * n + 5]),
    )
