"""Independent construction of the SPARK coefficient families (DESIGN.md §2).

Owns a second, Python-side derivation of the tableaux the Rust runtime ships
(Gauss, Lobatto IIIA/IIIB/IIIC/IIIC*/IIID, symplectic Euler I and II), built
from their defining conditions with numpy rather than copied from a table, so
that the coefficients the Rust side exports are themselves checked.
"""

from __future__ import annotations

from typing import Dict

import numpy as np
from numpy.polynomial import legendre


def _shifted_legendre_roots(s: int) -> np.ndarray:
    """Roots of P_s(2c − 1) in (0, 1), ascending."""
    coeffs = np.zeros(s + 1)
    coeffs[s] = 1.0
    roots = legendre.legroots(coeffs)
    return np.sort((roots + 1.0) / 2.0)


def _polish_legendre_roots(s: int, c: np.ndarray) -> np.ndarray:
    """A few Newton steps on P_s(2c − 1) to put each node within an ulp or two."""
    coeffs = np.zeros(s + 1)
    coeffs[s] = 1.0
    d = legendre.legder(coeffs)
    x = 2.0 * c - 1.0
    for _ in range(3):
        x = x - legendre.legval(x, coeffs) / legendre.legval(x, d)
    return (x + 1.0) / 2.0


def _weights(c: np.ndarray) -> np.ndarray:
    """Quadrature weights exact for degree < s: Σ_j b_j c_j^(k−1) = 1/k."""
    s = len(c)
    vander = np.array([[c[j] ** k for j in range(s)] for k in range(s)])
    rhs = np.array([1.0 / (k + 1) for k in range(s)])
    return np.linalg.solve(vander, rhs)


def _collocation(c: np.ndarray) -> np.ndarray:
    """a_ij with Σ_j a_ij c_j^(k−1) = c_i^k / k, k = 1..s (condition C(s))."""
    s = len(c)
    vander = np.array([[c[j] ** k for j in range(s)] for k in range(s)])
    a = np.zeros((s, s))
    for i in range(s):
        rhs = np.array([c[i] ** (k + 1) / (k + 1) for k in range(s)])
        a[i] = np.linalg.solve(vander, rhs)
    return a


def gauss(s: int) -> Dict[str, np.ndarray]:
    """Gauss–Legendre collocation: nodes, weights and A."""
    c = _polish_legendre_roots(s, _shifted_legendre_roots(s))
    return {"c": c, "b": _weights(c), "a": _collocation(c)}


def lobatto(s: int) -> Dict[str, np.ndarray]:
    """Lobatto nodes/weights and the IIIA, IIIB, IIIC, IIIC*, IIID matrices (s ≥ 2)."""
    if s < 2:
        raise ValueError("Lobatto needs s >= 2")
    inner = np.array([])
    if s > 2:
        # Roots of P'_{s−1}(2c − 1).
        coeffs = np.zeros(s)
        coeffs[s - 1] = 1.0
        d1 = legendre.legder(coeffs)
        d2 = legendre.legder(d1)
        x = np.sort(legendre.legroots(d1))
        for _ in range(3):
            x = x - legendre.legval(x, d1) / legendre.legval(x, d2)
        inner = (x + 1.0) / 2.0
    c = np.concatenate(([0.0], inner, [1.0]))
    b = _weights(c)
    iiia = _collocation(c)
    # Symplectic conjugate: b_i â_ij + b_j a_ji = b_i b_j.
    iiib = np.array([[b[j] - b[j] * iiia[j, i] / b[i] for j in range(s)] for i in range(s)])
    # IIIC: a_i1 = b_1 and C(s−1); IIIC*: a_is = 0 and C(s−1).
    vander = np.array([[c[j] ** k for j in range(s)] for k in range(s - 1)])
    iiic = np.zeros((s, s))
    iiic_star = np.zeros((s, s))
    for i in range(s):
        rhs = np.array([c[i] ** (k + 1) / (k + 1) for k in range(s - 1)])
        system = np.vstack([vander, np.eye(s)[0]])
        iiic[i] = np.linalg.solve(system, np.concatenate([rhs, [b[0]]]))
        system = np.vstack([vander, np.eye(s)[s - 1]])
        iiic_star[i] = np.linalg.solve(system, np.concatenate([rhs, [0.0]]))
    iiid = 0.5 * (iiic + iiic_star)
    return {"c": c, "b": b, "iiia": iiia, "iiib": iiib, "iiic": iiic, "iiic_star": iiic_star, "iiid": iiid}


def expected(key: str, s: int):
    """``(c, A, Â, Ã, b)`` of a method named by its key, or None if unknown here.

    The keys are those of ``Method::key`` in ``spark-runtime`` (``gauss``,
    ``lobatto-iiia-b``, ``lobatto-iiia-b-d``, ``euler-1``, ``euler-2``,
    ``modified-lobatto-iiia-b``, ``lobatto-iiib-a-lda``).
    """
    one = np.ones(1)
    if key == "gauss":
        g = gauss(s)
        return g["c"], g["a"], g["a"], g["a"], g["b"]
    if key == "euler-2" and s == 1:
        return one, one.reshape(1, 1), np.zeros((1, 1)), np.zeros((1, 1)), one
    if key == "euler-1" and s == 1:
        return np.zeros(1), np.zeros((1, 1)), one.reshape(1, 1), one.reshape(1, 1), one
    if key == "lobatto-iiib-a-lda":
        lo = lobatto(s)
        return lo["c"], lo["iiib"], lo["iiia"], lo["iiia"], lo["b"]
    if key == "lobatto-iiia-b-d":
        lo = lobatto(s)
        return lo["c"], lo["iiia"], lo["iiib"], lo["iiid"], lo["b"]
    if key in ("lobatto-iiia-b", "modified-lobatto-iiia-b"):
        lo = lobatto(s)
        return lo["c"], lo["iiia"], lo["iiib"], lo["iiib"], lo["b"]
    return None
