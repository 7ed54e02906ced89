"""What the C drivers of the CasADi peers (``peers.py``'s Newton-QR,
``newton_lu.py``'s Newton-LU) share: the head of the driver source (sizes of
the SPARK step, the weights ``b``, the wall and thread-CPU clocks, the
comparison for ``qsort``, and a run's cold start, step parameters and end of
step), its fields, and writing CasADi's generated C into a build directory.

A driver's source is ``HEAD`` followed by its own part, one ``%``-format
string (``%%`` for a literal ``%``), filled with :func:`fields` and the
driver's own entries.
"""

from __future__ import annotations

import os
from pathlib import Path

import casadi as ca

from spark_check.system import CasadiSystem

HEAD = r"""
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "%(header)s"

#define N %(n)d
#define M %(m)d
#define S %(s)d
#define NP %(np)d
#define DIM (S * (N + M) + N)
#define NPAR (2 + 2 * N + NP)
static const double B[S] = {%(b)s};

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double cpu_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static int cmp(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

/* The start of a run: q = q0, v = v0, and the unknowns of the first step
   cold, V_j = v0, Psi_j = 0, v1 = v0. */
static void cold_start(double* q, double* v, double* x, const double* q0, const double* v0) {
    memcpy(q, q0, sizeof(double) * N);
    memcpy(v, v0, sizeof(double) * N);
    for (int j = 0; j < S; ++j) memcpy(x + j * N, v0, sizeof(double) * N);
    for (int j = 0; j < S * M; ++j) x[S * N + j] = 0.0;
    memcpy(x + S * (N + M), v0, sizeof(double) * N);
}

/* The parameters of the step of size h from (t, q, v): [t, h, q, v, p]. */
static void step_parameters(double* par, double t, double h, const double* q, const double* v, const double* p) {
    par[0] = t;
    par[1] = h;
    memcpy(par + 2, q, sizeof(double) * N);
    memcpy(par + 2 + N, v, sizeof(double) * N);
    for (int i = 0; i < NP; ++i) par[2 + 2 * N + i] = p[i];
}

/* The end of a step of size h from its unknowns x: q += h sum_j b_j V_j,
   v = v1. */
static void advance(double* q, double* v, const double* x, double h) {
    for (int i = 0; i < N; ++i) {
        double dq = 0.0;
        for (int j = 0; j < S; ++j) dq += B[j] * x[j * N + i];
        q[i] += h * dq;
        v[i] = x[S * (N + M) + i];
    }
}
"""


def fields(system: CasadiSystem, tableau, header: str) -> dict:
    """The entries of :data:`HEAD`: the sizes of ``system``'s SPARK step with
    ``tableau``, its weights ``b``, and the generated header to include."""
    return {
        "header": header, "n": system.n, "m": system.m, "s": int(tableau["stages"]), "np": len(system.parameters),
        "b": ", ".join(repr(float(b)) for b in tableau["b"]),
    }


def generate(cg: ca.CodeGenerator, directory: Path) -> None:
    """Writes the C of ``cg`` into ``directory`` (CasADi writes into the
    working directory)."""
    cwd = os.getcwd()
    os.chdir(directory)
    try:
        cg.generate()
    finally:
        os.chdir(cwd)
