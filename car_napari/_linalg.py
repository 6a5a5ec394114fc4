"""Small dense linear algebra for the Numba kernels: a Cholesky factor, its
log-determinant and a Mahalanobis norm (shared by the recursive estimator and
the windowed restoration models)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def cholesky_lower(A, L, n, floor):
    """Lower Cholesky factor of a small SPD matrix into ``L`` (the upper part
    zeroed); pivots below ``floor`` are raised to it (-inf: none)."""
    for i in range(n):
        for j in range(i + 1):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(max(acc, floor))
            else:
                L[i, j] = acc / L[j, j]
        for j in range(i + 1, n):
            L[i, j] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def cholesky_logdet(A, L, d):
    """Lower Cholesky factor of a small SPD matrix; returns log det A."""
    cholesky_lower(A, L, d, -np.inf)
    logdet = 0.0
    for i in range(d):
        logdet += 2.0 * math.log(L[i, i])
    return logdet


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def mahalanobis(L, e, u, d):
    """``e^T (L L^T)^-1 e`` by forward substitution (``u`` scratch)."""
    maha = 0.0
    for t in range(d):
        acc = e[t]
        for k in range(t):
            acc -= L[t, k] * u[k]
        u[t] = acc / L[t, t]
        maha += u[t] * u[t]
    return maha
