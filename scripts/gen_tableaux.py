#!/usr/bin/env python3
"""Generate spark-runtime/src/tableau/tables.rs: Gauss and Lobatto coefficients for s <= 10.

Every coefficient is computed with mpmath at 50 significant digits and then rounded
once to the nearest f64 (mpmath's float conversion rounds to nearest), so each entry
is within 0.5 ulp of the exact value. `repr` prints the shortest decimal that
round-trips, and Rust parses float literals with correct rounding.

Families (c = nodes, b = weights, matrices row-major, a[i][j]):
  * Gauss:   c = roots of the shifted Legendre polynomial P_s(2c-1); A = collocation
             (sum_j a_ij c_j^(k-1) = c_i^k / k, k = 1..s).
  * Lobatto: c = 0, 1 and the roots of P'_{s-1}(2c-1);
      IIIA   collocation (as Gauss);
      IIIB   symplectic conjugate of IIIA: b_i a^B_ij + b_j a^A_ji = b_i b_j;
      IIIC   a_i1 = b_1 and C(s-1);
      IIIC*  a_is = 0 and C(s-1);
      IIID   (IIIC + IIIC*) / 2.

Usage:  python3 scripts/gen_tableaux.py > spark-runtime/src/tableau/tables.rs
"""
import mpmath as mp

mp.mp.dps = 50
SMAX = 10


def bracketed_roots(f, count):
    """All simple roots of f in (-1, 1): bracket sign changes on a fine grid, then refine
    each bracket with the Illinois method (guaranteed to stay inside its bracket)."""
    grid = [mp.mpf(-1) + mp.mpf(2) * (k + mp.mpf(1) / 2) / 4000 for k in range(4000)]
    vals = [f(x) for x in grid]
    roots = []
    for x0, x1, f0, f1 in zip(grid, grid[1:], vals, vals[1:]):
        if f0 == 0:
            roots.append(x0)
        elif f0 * f1 < 0:
            roots.append(mp.findroot(f, (x0, x1), solver="illinois", tol=mp.mpf(10) ** -90))
    assert len(roots) == count, (len(roots), count)
    return sorted(roots)


def legendre_roots(n):
    """Roots of P_n on (-1, 1), ascending."""
    return bracketed_roots(lambda x: mp.legendre(n, x), n)


def dlegendre(n, x):
    """P_n'(x) for |x| < 1 via n (x P_n - P_{n-1}) / (x^2 - 1)."""
    return n * (x * mp.legendre(n, x) - mp.legendre(n - 1, x)) / (x * x - 1)


def lobatto_interior(n):
    """Roots of P_n' on (-1, 1), ascending (n - 1 of them)."""
    if n < 2:
        return []
    return bracketed_roots(lambda x: dlegendre(n, x), n - 1)


def solve(V, rhs):
    """Gaussian elimination with partial pivoting (mpmath's lu_solve fails on 1x1 systems)."""
    n = V.rows
    A = [[V[i, j] for j in range(n)] + [rhs[i]] for i in range(n)]
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(A[i][k]))
        A[k], A[p] = A[p], A[k]
        for i in range(k + 1, n):
            f = A[i][k] / A[k][k]
            for j in range(k, n + 1):
                A[i][j] -= f * A[k][j]
    x = [mp.mpf(0)] * n
    for i in reversed(range(n)):
        x[i] = (A[i][n] - sum(A[i][j] * x[j] for j in range(i + 1, n))) / A[i][i]
    return x


def weights(c):
    s = len(c)
    V = mp.matrix(s, s)
    rhs = mp.matrix(s, 1)
    for k in range(s):
        for j in range(s):
            V[k, j] = c[j] ** k
        rhs[k] = mp.mpf(1) / (k + 1)
    x = solve(V, rhs)
    return [x[j] for j in range(s)]


def collocation(c):
    """a_ij with sum_j a_ij c_j^(k-1) = c_i^k / k for k = 1..s."""
    s = len(c)
    V = mp.matrix(s, s)
    for k in range(s):
        for j in range(s):
            V[k, j] = c[j] ** k
    A = []
    for i in range(s):
        rhs = mp.matrix(s, 1)
        for k in range(s):
            rhs[k] = c[i] ** (k + 1) / (k + 1)
        x = solve(V, rhs)
        A.append([x[j] for j in range(s)])
    return A


def c_minus_one(c, fixed_col, fixed_val):
    """Rows with a_{i,fixed_col} = fixed_val[i] and C(s-1) for the other s-1 entries."""
    s = len(c)
    free = [j for j in range(s) if j != fixed_col]
    A = []
    for i in range(s):
        V = mp.matrix(s - 1, s - 1)
        rhs = mp.matrix(s - 1, 1)
        for k in range(s - 1):
            for jj, j in enumerate(free):
                V[k, jj] = c[j] ** k
            rhs[k] = c[i] ** (k + 1) / (k + 1) - fixed_val[i] * c[fixed_col] ** k
        x = solve(V, rhs)
        row = [mp.mpf(0)] * s
        row[fixed_col] = fixed_val[i]
        for jj, j in enumerate(free):
            row[j] = x[jj]
        A.append(row)
    return A


def gauss(s):
    c = [(x + 1) / 2 for x in legendre_roots(s)]
    return c, weights(c), collocation(c)


def lobatto(s):
    c = [mp.mpf(0)] + [(x + 1) / 2 for x in lobatto_interior(s - 1)] + [mp.mpf(1)]
    b = weights(c)
    a3a = collocation(c)
    a3b = [[b[j] - b[j] * a3a[j][i] / b[i] for j in range(s)] for i in range(s)]
    a3c = c_minus_one(c, 0, [b[0]] * s)
    a3cs = c_minus_one(c, s - 1, [mp.mpf(0)] * s)
    a3d = [[(a3c[i][j] + a3cs[i][j]) / 2 for j in range(s)] for i in range(s)]
    return c, b, a3a, a3b, a3c, a3cs, a3d


def lit(x):
    # Entries that are exactly zero in theory come out as ~1e-50 from the 50-digit solves.
    if abs(x) < mp.mpf(10) ** -40:
        x = mp.mpf(0)
    f = float(x)
    r = repr(f)
    if r in ("0.0", "-0.0"):
        return "0.0"
    return r


def vec(xs):
    return "&[" + ", ".join(lit(x) for x in xs) + "]"


def mat(A):
    return "&[" + ", ".join(lit(x) for row in A for x in row) + "]"


def main():
    out = []
    out.append("//! GENERATED by `scripts/gen_tableaux.py` (mpmath, 50 digits, each entry rounded once to the")
    out.append("//! nearest f64). Do not edit by hand; rerun the script instead.")
    out.append("//! Matrices are row-major (`a[i * s + j]`). Index `s - 1` holds the `s`-stage method.")
    out.append("#![allow(clippy::excessive_precision, clippy::unreadable_literal)]")
    out.append("")
    out.append("use super::RawGauss;")
    out.append("use super::RawLobatto;")
    out.append("")
    out.append("/// Largest number of stages with checked-in coefficients.")
    out.append("pub const MAX_STAGES: usize = %d;" % SMAX)
    out.append("")
    out.append("/// Gauss–Legendre coefficients, `s = 1..=MAX_STAGES`.")
    out.append("#[rustfmt::skip]")
    out.append("pub static GAUSS: [RawGauss; MAX_STAGES] = [")
    for s in range(1, SMAX + 1):
        c, b, a = gauss(s)
        out.append("    RawGauss {")
        out.append("        c: %s," % vec(c))
        out.append("        b: %s," % vec(b))
        out.append("        a: %s," % mat(a))
        out.append("    },")
    out.append("];")
    out.append("")
    out.append("/// Lobatto coefficients, `s = 2..=MAX_STAGES` (index 0, `s = 1`, is a placeholder).")
    out.append("#[rustfmt::skip]")
    out.append("pub static LOBATTO: [RawLobatto; MAX_STAGES] = [")
    out.append("    RawLobatto { c: &[], b: &[], iiia: &[], iiib: &[], iiic: &[], iiic_star: &[], iiid: &[] },")
    for s in range(2, SMAX + 1):
        c, b, a3a, a3b, a3c, a3cs, a3d = lobatto(s)
        out.append("    RawLobatto {")
        out.append("        c: %s," % vec(c))
        out.append("        b: %s," % vec(b))
        out.append("        iiia: %s," % mat(a3a))
        out.append("        iiib: %s," % mat(a3b))
        out.append("        iiic: %s," % mat(a3c))
        out.append("        iiic_star: %s," % mat(a3cs))
        out.append("        iiid: %s," % mat(a3d))
        out.append("    },")
    out.append("];")
    print("\n".join(out))


if __name__ == "__main__":
    main()
