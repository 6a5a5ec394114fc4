"""Numba kernel of CAR synthesis: the causal recursion driven by noise."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
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
    """
    H, W, _ = noise.shape
    d = gamma.shape[0]
    m = tap_di.shape[0]
    x = np.empty(m)
    innov = np.empty(d)
    stop = H if row_stop < 0 else min(row_stop, H)
    for i in range(max(row_start, 0), stop):
        for j in range(W):
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
