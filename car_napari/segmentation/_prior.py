"""A spatial prior on the labels: Potts smoothing of the neighbourhood-weighted
posteriors by mean field (labelling, section 14.4, docs/segmentation.md).

The labelling takes, at every pixel, the component ``j`` of the largest
neighbourhood-weighted posterior ``pbar_j`` (SPEC 3.7). With a Potts prior
of strength ``beta`` on the label field (8-neighbourhood, diagonal
neighbours weighted ``1/sqrt(2)``), the mean-field approximation of the
labels' posterior marginals ``q`` is the fixed point of

    q_j(r) ∝ pbar_j(r) exp(beta * sum_s w_s q_j(r + s)),

iterated ``iterations`` times from ``q = pbar`` by synchronous (Jacobi)
sweeps, so that the result at a pixel depends only on ``pbar`` within
``iterations`` pixels of it: a band of rows with a halo that wide gives
the whole image's numbers. A pixel then takes the component of the largest
``q_j``: boundaries follow the textures' regions rather than the noise of
the posteriors, and components that win only in thin strips (between two
textures) lose them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# weight of a diagonal neighbour in the Potts sum
_DIAGONAL = 1.0 / math.sqrt(2.0)
# smallest posterior whose logarithm is taken (exact zeros from underflow)
_TINY = 1e-300


def mean_field(post, strength, iterations):
    """Mean-field Potts marginals of the posteriors ``post`` (K, H, W), in place.

    Parameters
    ----------
    post : (K, H, W) ndarray of float64
        Per-pixel posteriors of every component (each pixel's sum 1); they
        are replaced by the marginals ``q``.
    strength : float
        ``beta`` >= 0, the Potts interaction.
    iterations : int
        Synchronous sweeps (the reach of the prior in pixels).

    Returns
    -------
    (K, H, W) ndarray of float64
        ``post`` itself.
    """
    if strength > 0 and iterations > 0:
        k, h, w = post.shape
        # q and the next q with a border of zeros (no neighbours outside)
        q = np.zeros((k, h + 2, w + 2))
        nxt = np.zeros((k, h + 2, w + 2))
        _mean_field(post, float(strength), int(iterations), q, nxt)
    return post


@njit(cache=True, nogil=True)
def _mean_field(post, strength, iterations, q, nxt):
    """:func:`mean_field`'s work: ``q`` and ``nxt`` are (K, H + 2, W + 2)
    zeros; ``post`` becomes its logarithm, then the marginals. Each sweep
    sums the neighbours plane by plane (contiguous), then normalises every
    pixel over the components."""
    k, h, w = post.shape
    for j in range(k):
        for y in range(h):
            for x in range(w):
                q[j, y + 1, x + 1] = post[j, y, x]
                post[j, y, x] = math.log(max(post[j, y, x], _TINY))
    top = np.empty(w)
    total = np.empty(w)
    for _ in range(iterations):
        for j in range(k):
            for y in range(h):
                for x in range(w):
                    side = (q[j, y, x + 1] + q[j, y + 2, x + 1]) + q[j, y + 1, x] \
                        + q[j, y + 1, x + 2]
                    diag = (q[j, y, x] + q[j, y, x + 2]) + q[j, y + 2, x] + q[j, y + 2, x + 2]
                    nxt[j, y + 1, x + 1] = post[j, y, x] + strength * (side + _DIAGONAL * diag)
        for y in range(h):
            top[:] = -np.inf
            for j in range(k):
                for x in range(w):
                    top[x] = max(top[x], nxt[j, y + 1, x + 1])
            total[:] = 0.0
            for j in range(k):
                for x in range(w):
                    e = math.exp(nxt[j, y + 1, x + 1] - top[x])
                    nxt[j, y + 1, x + 1] = e
                    total[x] += e
            for j in range(k):
                for x in range(w):
                    nxt[j, y + 1, x + 1] /= total[x]
        q, nxt = nxt, q
    for j in range(k):
        for y in range(h):
            for x in range(w):
                post[j, y, x] = q[j, y + 1, x + 1]
