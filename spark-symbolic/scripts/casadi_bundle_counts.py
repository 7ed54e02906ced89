"""Operation counts of CasADi SX (cse=True) for the bundle spark compares with.

The bundle is L, ∇_q L, ∇_v L, ∇²_vv L, ∂(∇_v L)/∂q, k, k_q, k_v, Kᵀψ,
∂(Kᵀψ)/∂q, ∂(Kᵀψ)/∂v (see `OperationCounts::bundle` in spark-runtime), for
the paper's four §8 systems with symbolic parameters. An operation is every
instruction of the CasADi Function other than inputs, outputs, constants and
parameters (so +, −, ×, ÷, neg, sq, twice, sin, cos, … each count 1).

Run (any Python with casadi; casadi/.venv after `bash casadi/run.sh`):

    casadi/.venv/bin/python spark-symbolic/scripts/casadi_bundle_counts.py

and compare with spark's counts from
`cargo test --release -p spark-symbolic --test systems -- --nocapture bundle`.
"""
from collections import Counter

import casadi as ca

SKIP = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_PARAMETER}


def bundle_ops(L, k, q, v, p):
    psi = ca.SX.sym("psi", k.shape[0])
    F, P = ca.gradient(L, q), ca.gradient(L, v)
    kv = ca.jacobian(k, v)
    kt_psi = ca.mtimes(kv.T, psi)
    outs = [L, F, P, ca.jacobian(P, v), ca.jacobian(P, q), k, ca.jacobian(k, q), kv, kt_psi,
            ca.jacobian(kt_psi, q), ca.jacobian(kt_psi, v)]
    f = ca.Function("bundle", [q, v, p, psi], outs, {"cse": True})
    ops = Counter(f.instruction_id(i) for i in range(f.n_instructions()))
    return sum(n for op, n in ops.items() if op not in SKIP)


def main():
    S = ca.SX.sym
    q, v, p = S("q", 3), S("v", 3), S("p", 0)
    particle = (0.5 * ca.sumsqr(v) - (q[0] ** 2 + q[1] ** 2), v[2] - q[1] * v[0], q, v, p)

    q, v, p = S("q", 3), S("v", 3), S("p", 4)
    m, inertia, g, beta = p[0], p[1], p[2], p[3]
    skate = (m / 2 * (v[0] ** 2 + v[1] ** 2) + inertia / 2 * v[2] ** 2 + m * g * q[0] * ca.sin(beta),
             ca.cos(q[2]) * v[1] - ca.sin(q[2]) * v[0], q, v, p)

    q, v, p = S("q", 4), S("v", 4), S("p", 4)
    m, inertia, iw, ell = p[0], p[1], p[2], p[3]
    robot = (m / 2 * (v[0] ** 2 + v[1] ** 2) + inertia / 2 * v[2] ** 2 + 3 / 2 * iw * v[3] ** 2 - 10 * ca.sin(q[3]),
             ca.vertcat(v[0] - ell * ca.cos(q[2]) * v[3], v[1] - ell * ca.sin(q[2]) * v[3]), q, v, p)

    n, mm = 7, 3
    q, v, p = S("q", n), S("v", n), S("p", 0)
    qi = lambda i: q[i - 1]  # 1-based, as in the paper
    U = 0.5 * (ca.sumsqr(q) + qi(mm + 2) ** 2 * qi(mm + 3) ** 2
               + sum(qi(1 + i) ** 2 * qi(mm + 1 + i) ** 2 for i in range(1, mm + 1)))
    k = v[0] + sum(qi(i) * v[i - 1] for i in range(mm + 2, n + 1))
    mp = (0.5 * ca.sumsqr(v) - U, k, q, v, p)

    for name, system in [("skate", skate), ("particle", particle), ("robot", robot), ("mclachlan_perlmutter_7", mp)]:
        print(f"{name}: {bundle_ops(*system)}")


if __name__ == "__main__":
    main()
