"""Sufficient statistics of the CAR model and the Bayesian estimates from them
(SPEC 1.3)."""

from __future__ import annotations

import numpy as np

from .directions import scan_view

__all__ = ["data_statistics", "design_chunks", "estimate_parameters"]

_CHUNK_ELEMENTS = 4_000_000


def design_chunks(view, context):
    """Yield blocks of the augmented design matrix [X | Y] over the scan
    positions whose taps are all inside ``view`` (raster order), leaving out
    flat neighbourhoods (every tap equal to its channel's value at ``r``): they
    have probability zero under the model, come from clipping, saturation or
    padding, and carry no texture information (the recursive kernel skips
    them too)."""
    hs, ws = view.shape[:2]
    (up, down), (left, right) = context.reach
    a0, a1, b0, b1 = up, hs - down, left, ws - right
    m, d = context.n_regressors, context.n_targets
    rows_per_chunk = max(1, _CHUNK_ELEMENTS // max(1, (b1 - b0) * (m + d)))
    for start in range(a0, a1, rows_per_chunk):
        stop = min(start + rows_per_chunk, a1)
        Z = np.empty((stop - start, b1 - b0, m + d))
        for k, (di, dj, ch) in enumerate(context.taps):
            Z[:, :, k] = view[start - di : stop - di, b0 - dj : b1 - dj, ch]
        for t, ch in enumerate(context.targets):
            Z[:, :, m + t] = view[start:stop, b0:b1, ch]
        centre = view[start:stop, b0:b1][:, :, context.taps[:, 2]]
        flat = np.all(Z[:, :, :m] == centre, axis=2)
        Z = Z.reshape(-1, m + d)
        yield Z[~flat.ravel()] if flat.any() else Z


def data_statistics(centred, context, *, direction="down"):
    """``V = sum z z^T`` of ``z = [X_r; Y_r]`` over complete neighbourhoods.

    Returns ``(V, n_pixels)``; no prior is included. Vectorised over pixels
    (one slice per tap, one BLAS product per chunk).
    """
    view = scan_view(centred, direction)
    n = context.n_regressors + context.n_targets
    V = np.zeros((n, n))
    count = 0
    for Z in design_chunks(view, context):
        V += Z.T @ Z
        count += Z.shape[0]
    return V, count


def estimate_parameters(V, n_pixels, m, d, prior):
    """Bayesian estimates of SPEC 1.3 from the augmented statistics + prior.

    One Cholesky factor of the augmented ``V`` gives everything: its leading
    block factors ``V_x`` and its trailing block factors ``lambda``, which is
    then positive definite even for nearly collinear channels (a subtraction
    ``V_y - V_xy^T V_x^{-1} V_xy`` can go indefinite there).

    Returns ``gamma, lambda, V_x, beta, L`` with ``L`` the lower factor of
    the augmented matrix.
    """
    Vp = V + np.diag(prior)
    L = np.linalg.cholesky(Vp)
    L11, L21, L22 = L[:m, :m], L[m:, :m], L[m:, m:]
    gamma = np.linalg.solve(L11.T, L21.T).T  # gamma^T = V_x^{-1} V_xy = L11^{-T} L21^T
    lam = L22 @ L22.T
    beta = (m - 1) + n_pixels
    return gamma, lam, Vp[:m, :m], float(beta), L
