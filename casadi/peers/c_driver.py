"""What the C drivers of the CasADi peers (``peers.py``'s Newton-QR,
``newton_lu.py``'s Newton-LU) share: the head of the driver source (sizes of
the SPARK step, the weights ``b``, the wall and thread-CPU clocks, the
comparison for ``qsort``), its fields, and writing CasADi's generated C into
a build directory.

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
