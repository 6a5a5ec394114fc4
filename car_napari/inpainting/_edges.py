"""The edge test's statistics (:mod:`._conditional`): how far each known pixel
bordering the damage is blended towards it, and its likelihood-ratio statistic."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage

from .._progress import Progress, drain

__all__ = ["EDGE_POOL", "EDGE_PROBES", "EDGE_REGION", "EdgeStatistics",
           "edge_statistics", "iter_edge_statistics"]

EDGE_PROBES = 8  # draws per pixel of the joint predictive fluctuation in the edge test
EDGE_POOL = 4  # pixels: the draws' variance ratio is averaged over the ring within this
# Soft-edged damage leaves a fringe all along its border, hard-edged none: a
# ring pixel is called damaged only where the blend pooled over the ring
# within EDGE_REGION pixels also exceeds HALO_REGION_BLEND. Lone edges of the
# scene that happen to resemble the damage pool to ~0. Chosen on TUNING
# (benchmarks/bench_inpainting.py): at 8 px and 0.05 the ring pixels called
# damaged on hard-edged composites fell from 0.5-5 % to 0-0.9 %, on
# soft-edged ones from 44-65 % to 43-64 %.
EDGE_REGION = 8


class EdgeStatistics(NamedTuple):
    """The edge test's statistics, one row per ring pixel (in
    ``np.nonzero(ring)`` order): see :func:`iter_edge_statistics`."""

    alpha: np.ndarray  # (n_ring,) the blend towards the damage
    chi2: np.ndarray  # (n_ring,) its generalised-likelihood statistic
    pooled: np.ndarray  # (n_ring,) the blend of the ring within ``region`` pixels together
    deviation: np.ndarray  # (n_ring, d) D: the damage's deviation from its prediction


def edge_statistics(frame, trial, damage, ring, draws, diagonal, region=EDGE_REGION):
    """:func:`iter_edge_statistics` run to its end."""
    return drain(iter_edge_statistics(frame, trial, damage, ring, draws, diagonal, region))


def iter_edge_statistics(frame, trial, damage, ring, draws, diagonal,
                         region=EDGE_REGION):
    """The edge test's statistics of the ``ring`` pixels (known, bordering
    the ``damage``): an :class:`EdgeStatistics` ``(alpha, chi2, pooled, D)``
    per ring pixel in ``np.nonzero(ring)`` order, as a job (a record between
    its passes over the ring's bounding box).

    ``trial`` is the frame with the damage and the ring both replaced by
    their conditional mean given the rest, so that neither sees the other.
    Soft-edged damage blends a ring pixel towards the damage: ``y_b = E_b +
    alpha D_b + e`` with ``E_b`` its prediction, ``D_b`` the damage's
    deviation from its prediction (mean over the pixel's 4-neighbours in the
    damage) and ``e ~ N(0, S_b)``, ``S_b`` the covariance of the joint
    prediction (the ring and the damage predicted together from the rest:
    ``[Q^-1]_bb`` over them, larger than the one-step innovation covariance
    of a pixel whose neighbours are known). ``S_b = kappa_b R_b``: ``R_b =
    Q_bb^-1`` (``diagonal``, (n_ring, d, d) the blocks ``Q_bb``) is the
    pixel's covariance given every other pixel, and ``kappa_b`` the ratio
    ``tr(Q_bb C_b) / d`` of the covariance ``C_b`` of the ``draws`` (n_ring,
    probes, d) of ``N(0, Q^-1)``, averaged over the ring pixels within
    :data:`EDGE_POOL` pixels (a few draws per pixel, pooled). ``alpha`` is
    the generalised least-squares blend and ``chi2 = (D^T S^-1 e)^2 / (D^T
    S^-1 D)`` its generalised-likelihood statistic (chi-square with 1 degree
    of freedom for a clean pixel). ``pooled`` is the generalised
    least-squares blend of the ring pixels within ``region`` pixels together
    (``sum D^T S^-1 e / sum D^T S^-1 D`` over them); ``D`` (n_ring, d)."""
    H, W, C = frame.shape
    bi, bj = np.nonzero(ring)
    if not len(bi):
        return EdgeStatistics(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, C)))
    count = np.zeros(len(bi))
    total = np.zeros((len(bi), C))
    for di, dj in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        ni, nj = np.clip(bi + di, 0, H - 1), np.clip(bj + dj, 0, W - 1)
        hit = damage[ni, nj] & (ni == bi + di) & (nj == bj + dj)
        count += hit
        total += np.where(hit[:, None], frame[ni, nj] - trial[ni, nj], 0.0)
    D = total / np.maximum(count, 1)[:, None]
    e = frame[bi, bj] - trial[bi, bj]
    sample = np.einsum("nsa,nsb->nab", draws, draws) / max(draws.shape[1], 1)
    kappa = np.einsum("nab,nba->n", diagonal, sample) / C
    # The sums over the ring are filtered on its bounding box only: outside it
    # they are 0, as the filters' constant padding is (a thin scratch's box
    # is a sliver of the frame).
    top, left = bi.min(), bj.min()
    box = (slice(top, bi.max() + 1), slice(left, bj.max() + 1))
    bi, bj = bi - top, bj - left  # within the box
    box_shape = ring[box].shape
    spread = np.zeros(box_shape)
    spread[bi, bj] = kappa
    size = 2 * EDGE_POOL + 1
    yield Progress("frames", 0.0, "edge test")
    pooled = ndimage.uniform_filter(spread, size, mode="constant")[bi, bj]
    del spread
    yield Progress("frames", 0.0, "edge test")
    pooled /= np.maximum(ndimage.uniform_filter(ring[box].astype(float), size,
                                                mode="constant")[bi, bj], 1e-12)
    QD = np.einsum("nab,nb->na", diagonal, D) / pooled[:, None]  # S^-1 D
    dqd = np.maximum((QD * D).sum(axis=1), 1e-300)
    proj = (QD * e).sum(axis=1)
    yield Progress("frames", 0.0, "edge test")
    size = 2 * region + 1
    sums = np.zeros((2, *box_shape))
    sums[0, bi, bj] = proj
    sums[1, bi, bj] = dqd
    sums = ndimage.uniform_filter(sums, (1, size, size), mode="constant")[:, bi, bj]
    return EdgeStatistics(proj / dqd, proj**2 / dqd, sums[0] / np.maximum(sums[1], 1e-300), D)
