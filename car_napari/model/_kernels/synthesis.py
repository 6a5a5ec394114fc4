"""Numba kernel of CAR synthesis: the causal recursion driven by noise.

A pixel's value is a chain of additions in a fixed order (its innovation,
then every tap's term): its latency, not the arithmetic, sets the pace of a
pixel-by-pixel field. Two pixels that do not depend on each other, one of
row ``i`` and one of row ``i + 1`` a few columns behind, are computed side by
side (a wavefront of two rows), each with its own chains, the channels of
colour fields together: the same operations in the same order per pixel, so
the same numbers, about three times sooner.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def synthesize_field(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, row_start=0,
                     row_stop=-1):
    """Generate a zero-mean CAR field in raster order (synthesis, docs/model.md).

    Rows ``row_start .. row_stop - 1`` (default: all): the field's state is
    the array itself, so consecutive row ranges give, bit for bit, the
    one-call field (a long synthesis runs in chunks with a yield between).

    ``noise`` (H, W, C) holds standard normal draws in its first ``d``
    channels (``d`` = rows of ``gamma``); they are overwritten by the field.
    Further channels are fixed context the taps may read (the previous frame
    of the 3.5D model). Pixels whose neighbours leave the lattice use zeros
    (the burn-in margin removed by the caller absorbs that transient).
    Returns False as soon as a value exceeds ``limit`` (an unstable model).

    A C-contiguous ``noise`` of a grey or colour field (``d`` 1 or 3) whose
    taps are causal takes the two-row wavefront of :func:`_field_wavefront`,
    anything else the pixel-by-pixel scan of :func:`_field_scan`: the same
    numbers either way.
    """
    if noise.flags.c_contiguous and gamma.shape[0] in (1, 3):
        return _field_wavefront(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit,
                                row_start, row_stop)
    return _field_scan(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, row_start,
                       row_stop)


@njit(cache=True, nogil=True)
def _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, i, j, x, innov):
    """Pixel (i, j) of the field, its neighbours off the lattice read as
    zeros; False if a value exceeds ``limit``. ``x`` (taps) and ``innov``
    (d) are scratch."""
    W = noise.shape[1]
    d = gamma.shape[0]
    m = tap_di.shape[0]
    for k in range(m):
        ii = i - tap_di[k]
        jj = j - tap_dj[k]
        if ii >= 0 and jj >= 0 and jj < W:
            x[k] = noise[ii, jj, tap_ch[k]]
        else:
            x[k] = 0.0
    for t in range(d):
        acc = 0.0
        for c in range(t + 1):
            acc += chol_sigma[t, c] * noise[i, j, c]
        innov[t] = acc
    for t in range(d):
        acc = innov[t]
        for k in range(m):
            acc += gamma[t, k] * x[k]
        if not (abs(acc) <= limit):
            return False
        noise[i, j, t] = acc
    return True


@njit(cache=True, nogil=True)
def _field_scan(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, row_start, row_stop):
    """:func:`synthesize_field` pixel by pixel in raster order (any layout,
    any taps)."""
    H, W, _ = noise.shape
    x = np.empty(tap_di.shape[0])
    innov = np.empty(gamma.shape[0])
    stop = H if row_stop < 0 else min(row_stop, H)
    for i in range(max(row_start, 0), stop):
        for j in range(W):
            if not _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, i, j, x,
                          innov):
                return False
    return True


@njit(cache=True, nogil=True)
def _pair_rgb(gamma_t, chol_sigma, flat, back, limit, a, b):
    """Two interior pixels of a 3-channel field at flat indices ``a`` and
    ``b`` (neither reads the other), their six chains side by side: each
    value the sum :func:`_pixel` forms, in its order. ``back[k]``: how far
    before a pixel's index tap ``k`` reads; ``gamma_t`` is gamma (taps, 3)."""
    c = chol_sigma
    n0, n1, n2 = flat[a], flat[a + 1], flat[a + 2]
    a0 = 0.0 + c[0, 0] * n0
    a1 = (0.0 + c[1, 0] * n0) + c[1, 1] * n1
    a2 = ((0.0 + c[2, 0] * n0) + c[2, 1] * n1) + c[2, 2] * n2
    n0, n1, n2 = flat[b], flat[b + 1], flat[b + 2]
    b0 = 0.0 + c[0, 0] * n0
    b1 = (0.0 + c[1, 0] * n0) + c[1, 1] * n1
    b2 = ((0.0 + c[2, 0] * n0) + c[2, 1] * n1) + c[2, 2] * n2
    for k in range(back.shape[0]):
        xa = flat[a - back[k]]
        xb = flat[b - back[k]]
        g0, g1, g2 = gamma_t[k, 0], gamma_t[k, 1], gamma_t[k, 2]
        a0 += g0 * xa
        a1 += g1 * xa
        a2 += g2 * xa
        b0 += g0 * xb
        b1 += g1 * xb
        b2 += g2 * xb
    if not (abs(a0) <= limit and abs(a1) <= limit and abs(a2) <= limit
            and abs(b0) <= limit and abs(b1) <= limit and abs(b2) <= limit):
        return False
    flat[a], flat[a + 1], flat[a + 2] = a0, a1, a2
    flat[b], flat[b + 1], flat[b + 2] = b0, b1, b2
    return True


@njit(cache=True, nogil=True)
def _pair_grey(gamma_t, chol_sigma, flat, back, limit, a, b):
    """:func:`_pair_rgb` for a 1-channel field."""
    sa = 0.0 + chol_sigma[0, 0] * flat[a]
    sb = 0.0 + chol_sigma[0, 0] * flat[b]
    for k in range(back.shape[0]):
        g = gamma_t[k, 0]
        sa += g * flat[a - back[k]]
        sb += g * flat[b - back[k]]
    if not (abs(sa) <= limit and abs(sb) <= limit):
        return False
    flat[a] = sa
    flat[b] = sb
    return True


@njit(cache=True, nogil=True)
def _field_wavefront(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, row_start,
                     row_stop):
    """:func:`synthesize_field` of a C-contiguous ``noise``, ``d`` 1 or 3.

    Rows go by pairs: pixel (i, j) beside pixel (i + 1, j - lag), ``lag``
    one more than the farthest a tap reads to the right, so that the second
    reads of row ``i`` only what is done. Pixels whose taps may leave the
    lattice (the borders) and single rows go one by one through
    :func:`_pixel`. Taps that read a field channel not yet generated in
    raster order (a non-causal neighbourhood) or any row below send the
    whole call to :func:`_field_scan`.
    """
    H, W, C = noise.shape
    d = gamma.shape[0]
    m = tap_di.shape[0]
    top = left = right = 0
    for k in range(m):
        top = max(top, tap_di[k])
        left = max(left, tap_dj[k])
        right = max(right, -tap_dj[k])
        if tap_di[k] < 0 or (tap_ch[k] < d and not (
                tap_di[k] > 0 or (tap_di[k] == 0 and tap_dj[k] > 0))):
            return _field_scan(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit,
                               row_start, row_stop)
    lag = right + 1
    flat = noise.reshape(H * W * C)
    back = (tap_di * W + tap_dj) * C - tap_ch
    gamma_t = np.ascontiguousarray(gamma.T)
    x = np.empty(m)
    innov = np.empty(d)
    stop = H if row_stop < 0 else min(row_stop, H)
    i = max(row_start, 0)
    while i < stop:
        if i < top or i + 1 >= stop:  # a single row
            for j in range(W):
                if not _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, i, j,
                              x, innov):
                    return False
            i += 1
            continue
        for j in range(W):
            jb = j - lag
            if left <= jb and j < W - right:  # both interior
                a, b = (i * W + j) * C, ((i + 1) * W + jb) * C
                done = (_pair_rgb(gamma_t, chol_sigma, flat, back, limit, a, b) if d == 3
                        else _pair_grey(gamma_t, chol_sigma, flat, back, limit, a, b))
                if not done:
                    return False
                continue
            if not _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, i, j, x,
                          innov):
                return False
            if jb >= 0 and not _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit,
                                      i + 1, jb, x, innov):
                return False
        for jb in range(max(W - lag, 0), W):
            if not _pixel(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit, i + 1, jb,
                          x, innov):
                return False
        i += 2
    return True
