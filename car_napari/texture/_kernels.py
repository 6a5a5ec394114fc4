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
    for c in range(d):
        a, b = lo[c], hi[c]
        for i in range(h):
            for j in range(w):
                v = block[i, j, c]
                if v < a or v != v:
                    a = v
                if v > b or v != v:
                    b = v
        lo[c], hi[c] = a, b


@numba.njit(cache=True, nogil=True)
def block_histogram(block, c, first, last, edges, counts):
    """Add to ``counts`` the histogram of channel ``c`` of ``block`` as
    ``numpy.histogram(values, bins=len(counts), range=(first, last))`` counts
    it (bin ``edges`` from it: the same index arithmetic and edge checks)."""
    h, w, _ = block.shape
    n = counts.shape[0]
    denom = last - first
    for i in range(h):
        for j in range(w):
            v = block[i, j, c]
            if not (v >= first and v <= last):
                continue
            k = int(((v - first) / denom) * n)
            if k == n:
                k -= 1
            if v < edges[k]:
                k -= 1
            if v >= edges[k + 1] and k != n - 1:
                k += 1
            counts[k] += 1


@numba.njit(cache=True, nogil=True)
def block_map(block, c, lo, scale, cdf, quantiles, top, bottom, clip_lo, clip_hi, clip,
              out):
    """Channel ``c`` of ``block`` mapped through its ``cdf`` (``len(cdf) - 1``
    bins from ``lo``, ``scale`` bins a unit) onto the ``quantiles``, with
    exponential tails of scales ``top`` and ``bottom`` (0: none) and, with
    ``clip``, clipped to [``clip_lo``, ``clip_hi``]; into channel ``c`` of
    ``out`` (the per-value arithmetic of ``_iter_match``)."""
    h, w, _ = block.shape
    bins = cdf.shape[0] - 1
    q = quantiles.shape[0]
    for i in range(h):
        for j in range(w):
            pos = (block[i, j, c] - lo) * scale
            k = min(int(pos), bins - 1)
            p = cdf[k] + (pos - k) * (cdf[k + 1] - cdf[k])
            pos = p * (q - 1)
            k = min(int(pos), q - 2)
            mapped = quantiles[k] + (pos - k) * (quantiles[k + 1] - quantiles[k])
            if k == q - 2 and top > 0:
                tail = quantiles[q - 2] - top * math.log((q - 1) - pos)
                if tail != tail or mapped != mapped:
                    mapped = np.nan
                elif tail < mapped:
                    mapped = tail
            elif k == 0 and bottom > 0:
                tail = quantiles[1] + bottom * math.log(pos)
                if tail != tail or mapped != mapped:
                    mapped = np.nan
                elif tail > mapped:
                    mapped = tail
            if clip:
                if mapped < clip_lo:
                    mapped = clip_lo
                elif mapped > clip_hi:
                    mapped = clip_hi
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
