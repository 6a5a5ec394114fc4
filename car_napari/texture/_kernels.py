"""Numba kernels of the texture synthesis's histogram matching (``_iter_match``)
and of its restore of the mean and contrast (``_iter_restore``).

Each does, for a block of rows of a channel-last (h, w, d) array, in one
compiled pass, what the plain NumPy form did in several: the same IEEE
operations in the same order (no fast-math, so no fused multiply-adds), so
the same numbers (tested against that form in ``tests/texture``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "block_centred_sum", "block_histogram", "block_map", "block_range", "block_rescale",
]


@numba.njit(cache=True, nogil=True)
def block_range(block, lo, hi):
    """Into (d,) ``lo`` and ``hi``: their minimum and maximum with every
    channel of (h, w, d) ``block`` (a NaN propagates, as ``ndarray.min``)."""
    h, w, d = block.shape
    for i in range(h):
        for j in range(w):
            for c in range(d):
                v = block[i, j, c]
                if v < lo[c] or v != v:
                    lo[c] = v
                if v > hi[c] or v != v:
                    hi[c] = v


@numba.njit(cache=True, nogil=True)
def block_histogram(block, active, first, last, edges, counts):
    """Add to (d, n) ``counts`` the histogram of every ``active`` channel
    ``c`` of (h, w, d) ``block`` as ``numpy.histogram(values, bins=n,
    range=(first[c], last[c]))`` counts it (bin ``edges[c]`` from it: the
    same index arithmetic and edge checks). One pass over the block, all
    channels: the counts do not depend on the order."""
    h, w, d = block.shape
    n = counts.shape[1]
    for i in range(h):
        for j in range(w):
            for c in range(d):
                if not active[c]:
                    continue
                v = block[i, j, c]
                if not (v >= first[c] and v <= last[c]):
                    continue
                k = int(((v - first[c]) / (last[c] - first[c])) * n)
                if k == n:
                    k -= 1
                if v < edges[c, k]:
                    k -= 1
                if v >= edges[c, k + 1] and k != n - 1:
                    k += 1
                counts[c, k] += 1


@numba.njit(cache=True, nogil=True)
def block_map(block, active, lo, scale, cdf, quantiles, top, bottom, clip_lo, clip_hi, clip,
              out):
    """Every ``active`` channel ``c`` of (h, w, d) ``block`` mapped through
    its ``cdf[c]`` (``cdf.shape[1] - 1`` bins from ``lo[c]``, ``scale[c]``
    bins a unit) onto its ``quantiles[c]``, with exponential tails of scales
    ``top[c]`` and ``bottom[c]`` (0: none) and, with ``clip``, clipped to
    [``clip_lo[c]``, ``clip_hi[c]``]; into ``out`` (the per-value arithmetic
    of ``_iter_match``; the other channels of ``out`` are left as they are)."""
    h, w, d = block.shape
    bins = cdf.shape[1] - 1
    q = quantiles.shape[1]
    for i in range(h):
        for j in range(w):
            for c in range(d):
                if not active[c]:
                    continue
                pos = (block[i, j, c] - lo[c]) * scale[c]
                k = min(int(pos), bins - 1)
                p = cdf[c, k] + (pos - k) * (cdf[c, k + 1] - cdf[c, k])
                pos = p * (q - 1)
                k = min(int(pos), q - 2)
                mapped = quantiles[c, k] + (pos - k) * (quantiles[c, k + 1] - quantiles[c, k])
                if k == q - 2 and top[c] > 0:
                    tail = quantiles[c, q - 2] - top[c] * math.log((q - 1) - pos)
                    if tail != tail or mapped != mapped:
                        mapped = np.nan
                    elif tail < mapped:
                        mapped = tail
                elif k == 0 and bottom[c] > 0:
                    tail = quantiles[c, 1] + bottom[c] * math.log(pos)
                    if tail != tail or mapped != mapped:
                        mapped = np.nan
                    elif tail > mapped:
                        mapped = tail
                if clip:
                    if mapped < clip_lo[c]:
                        mapped = clip_lo[c]
                    elif mapped > clip_hi[c]:
                        mapped = clip_hi[c]
                out[i, j, c] = mapped


@numba.njit(cache=True, nogil=True)
def block_centred_sum(block, shift, centre, squared, total):
    """Add to (d,) ``total``, pixel after pixel in raster order, every
    channel of (h, w, d) ``block`` less ``shift`` and less ``centre``,
    squared with ``squared``: for d >= 2, ``np.add.reduce(x, axis=(0, 1))``
    of those values adds them in that order too. Start ``total`` at -0.0,
    which adds to any value exactly (as NumPy's first pixel does)."""
    h, w, d = block.shape
    for i in range(h):
        for j in range(w):
            for c in range(d):
                x = (block[i, j, c] - shift[c]) - centre[c]
                if squared:
                    x = x * x
                total[c] += x


@numba.njit(cache=True, nogil=True)
def block_rescale(block, shift, mean, gain):
    """In place: every channel ``c`` of (h, w, d) ``block`` becomes
    ``mean[c] + (block - shift[c]) * gain[c]``."""
    h, w, d = block.shape
    for i in range(h):
        for j in range(w):
            for c in range(d):
                block[i, j, c] = mean[c] + (block[i, j, c] - shift[c]) * gain[c]
