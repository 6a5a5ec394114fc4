"""Numba kernels of restoration: directional predictions accumulated and
combined by local precision."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def accumulate_direction(observed, mean, logrel, radius, power, mean_sum, prob_sum,
                         weight_sum, plain_sum, square_sum, count, r0, r1):
    """Add one scan direction's prediction to the running combination, for
    rows ``r0 <= i < r1``.

    ``observed`` and ``mean`` are (H, W, C), ``logrel`` (H, W); NaN marks
    pixels without a prediction. The direction's weight at a pixel is its
    local precision, the number of predicted neighbours within ``radius``
    (the pixel itself left out) over their summed squared error, to the
    ``power``. Also accumulates the unweighted first and second moments.
    Rows are independent: any split into row ranges gives, bit for bit, the
    whole image in one call.
    """
    H, W, C = observed.shape
    a0, a1 = max(0, r0 - radius), min(H, r1 + radius)  # the rows the windows read
    err2 = np.zeros((max(a1 - a0, 0), W))
    ok = np.zeros((max(a1 - a0, 0), W), np.bool_)
    for i in range(a0, a1):
        for j in range(W):
            lr = logrel[i, j]
            if lr == lr and mean[i, j, 0] == mean[i, j, 0]:
                ok[i - a0, j] = True
                acc = 0.0
                for c in range(C):
                    e = observed[i, j, c] - mean[i, j, c]
                    acc += e * e
                err2[i - a0, j] = acc
    for i in range(r0, r1):
        for j in range(W):
            if not ok[i - a0, j]:
                continue
            total = 0.0
            n = 0
            for a in range(max(0, i - radius), min(H, i + radius + 1)):
                for b in range(max(0, j - radius), min(W, j + radius + 1)):
                    if (a != i or b != j) and ok[a - a0, b]:
                        total += err2[a - a0, b]
                        n += 1
            if n == 0:
                continue
            base = min(n / max(total, 1e-300), 1e30)
            precision = 1.0
            for _ in range(power):  # integer power: no pow() call
                precision *= base
            for c in range(C):
                m = mean[i, j, c]
                mean_sum[i, j, c] += precision * m
                plain_sum[i, j, c] += m
                square_sum[i, j, c] += m * m
            prob_sum[i, j] += precision * math.exp(logrel[i, j])
            weight_sum[i, j] += precision
            count[i, j] += 1.0


@njit(cache=True, nogil=True)
def combine_directions(mean_sum, prob_sum, weight_sum, observed, offset, pred_out, prob_out,
                       r0, r1):
    """Weighted averages of :func:`accumulate_direction`'s sums plus
    ``offset`` (C,); the observed value and probability 1 where no direction
    predicted; rows ``r0 <= i < r1``."""
    H, W, C = observed.shape
    for i in range(r0, r1):
        for j in range(W):
            w = weight_sum[i, j]
            if w > 0:
                for c in range(C):
                    pred_out[i, j, c] = mean_sum[i, j, c] / w + offset[c]
                prob_out[i, j] = prob_sum[i, j] / w
            else:
                for c in range(C):
                    pred_out[i, j, c] = observed[i, j, c] + offset[c]
                prob_out[i, j] = 1.0
