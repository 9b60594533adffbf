"""Small dense linear algebra with a fixed order of operations (numba-compiled).

numpy's `@`, `np.dot` and `np.linalg.solve` (in Python and inside numba-compiled code alike)
call OpenBLAS/LAPACK, whose kernels are chosen at run time by CPU: their blocking, their
reduction order and their use of fused multiply-add differ between CPUs, so the same clip gave
different last bits on different workers. These functions are plain loops: every sum runs in
index order, one rounding per multiply and per add (numba without fastmath neither reassociates
nor contracts a multiply and an add into an FMA), so they give the same bits on every x86-64
CPU, whatever BLAS kernel the process has. The simulation and the controllers use them for
every product and solve on a clip's path (docs/benchmarks.md, "Same bits on every worker").

The matrices here are small (a character's n <= ~40 coordinates plus a few constraint rows),
where a loop costs about what a BLAS call's dispatch does.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def dot(a, b):
    """sum_i a[i] b[i] (1-D, equal lengths), summed in index order."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def matvec(A, x):
    """A x for A (m, n), x (n,): each row's sum in column order."""
    m, n = A.shape
    y = np.empty(m)
    for i in range(m):
        s = 0.0
        for j in range(n):
            s += A[i, j] * x[j]
        y[i] = s
    return y


@njit(cache=True)
def tmatvec(A, x):
    """A^T x for A (m, n), x (m,): each column's sum in row order."""
    m, n = A.shape
    y = np.zeros(n)
    for i in range(m):
        xi = x[i]
        for j in range(n):
            y[j] += A[i, j] * xi
    return y


@njit(cache=True)
def gram(A):
    """A^T A for A (m, n), each entry summed in row order; exactly symmetric."""
    m, n = A.shape
    G = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(m):
                s += A[k, i] * A[k, j]
            G[i, j] = s
            G[j, i] = s
    return G


@njit(cache=True)
def matmul(A, B):
    """A B for A (m, k), B (k, n), each entry summed in order of k."""
    m, kk = A.shape
    n = B.shape[1]
    C = np.zeros((m, n))
    for i in range(m):
        for k in range(kk):
            a = A[i, k]
            for j in range(n):
                C[i, j] += a * B[k, j]
    return C


@njit(cache=True)
def solve(A, b):
    """x with A x = b for a square A (n, n) and b (n,): Gaussian elimination with partial
    pivoting (the first row of largest |pivot|), then back substitution; A and b are not
    changed. Raises np.linalg.LinAlgError for an exactly singular A, as np.linalg.solve does."""
    n = A.shape[0]
    U = A.copy()
    x = b.copy()
    for k in range(n):
        p = k
        big = abs(U[k, k])
        for i in range(k + 1, n):
            v = abs(U[i, k])
            if v > big:
                big = v
                p = i
        if big == 0.0:  # a NaN pivot is not singular: it carries on, as LAPACK's does
            raise np.linalg.LinAlgError("Singular matrix")
        if p != k:
            for j in range(k, n):
                U[k, j], U[p, j] = U[p, j], U[k, j]
            x[k], x[p] = x[p], x[k]
        piv = U[k, k]
        for i in range(k + 1, n):
            f = U[i, k] / piv
            if f != 0.0:
                for j in range(k + 1, n):
                    U[i, j] -= f * U[k, j]
                x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(i + 1, n):
            s -= U[i, j] * x[j]
        x[i] = s / U[i, i]
    return x
