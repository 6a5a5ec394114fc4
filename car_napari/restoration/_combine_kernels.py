"""Numba kernels of restoration's combination step: the directions'
predictions accumulated and combined by local precision, and the edge rule
that blends the combination with the observation (section 14.5,
docs/restoration.md). They take a range of rows, last, release the GIL and
are cached."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_FAST = {"reassoc", "contract", "arcp"}


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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def combine_predictions(planes, offset, means, err2, boxes, power, pred_out, weight_out,
                        spread_out, row0, r0, r1):
    """Combine the directions' predictions for pixel rows ``r0 <= i < r1``.

    Each direction is weighted by its local precision: the number of its
    predicted pixels in the 3 x 3 square around the pixel (the pixel itself
    left out) over their summed squared error, to ``power``. Writes the
    weighted mean prediction plus ``offset`` (C,) channel-last (H, W, C)
    (the observation, ``planes`` (C, H, W) plus ``offset``, where no
    direction predicts), each direction's normalised weight unless
    ``weight_out`` is empty (all 0 where none predicts), and the variance
    of the directions' predictions averaged over channels (0 with fewer
    than two). Direction ``k`` predicts the pixels of the rectangle
    ``boxes[k] = (i0, i1, j0, j1)`` (:func:`valid_box` of its taps);
    ``means`` (K, C, rows, W), ``err2`` (K, rows, W) (0 outside the
    rectangle) and ``weight_out`` (K, rows, W) are strip buffers whose row 0
    is image row ``row0``; they must hold rows ``r0 - 1`` to ``r1`` (within
    the image). Loops run along rows without branches, so they vectorise.
    """
    C, H, W = planes.shape
    K = means.shape[0]
    col_err = np.zeros(W + 2)  # 3-row sums, a zero column each side
    weight = np.empty((K, W))
    wsum = np.empty(W)
    count = np.empty(W)
    mean_sum = np.empty(W)
    square_sum = np.empty(W)
    acc = np.empty(W)
    for i in range(r0, r1):
        a0 = max(0, i - 1)
        a1 = min(H, i + 2)
        wsum[:] = 0.0
        count[:] = 0.0
        for k in range(K):
            i0, i1, j0, j1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
            rows_in = max(0, min(a1, i1) - max(a0, i0))  # predicted rows around i
            row_in = i0 <= i < i1
            col_err[1 : W + 1] = 0.0
            for a in range(a0, a1):
                for j in range(W):
                    col_err[j + 1] += err2[k, a - row0, j]
            for j in range(W):
                valid = row_in and j0 <= j < j1
                n = rows_in * max(0, min(j + 2, j1) - max(j - 1, j0)) - (1.0 if valid else 0.0)
                total = col_err[j] + col_err[j + 1] + col_err[j + 2] - err2[k, i - row0, j]
                base = min(n / max(total, 1e-300), 1e30)
                if power == 4:  # the default, by squaring (keeps the loop vectorised)
                    wk = base * base
                    wk *= wk
                else:
                    wk = base**power
                wk = wk if valid and n > 0.5 else 0.0
                weight[k, j] = wk
                wsum[j] += wk
                count[j] += 1.0 if wk > 0 else 0.0
        for j in range(W):
            wsum[j] = 1.0 / wsum[j] if wsum[j] > 0 else 0.0  # now the inverse
        square_sum[:] = 0.0
        spread_out[i, :] = 0.0
        for c in range(C):
            acc[:] = 0.0
            mean_sum[:] = 0.0
            for k in range(K):
                mrow = means[k, c, i - row0]
                for j in range(W):
                    mk = mrow[j] if weight[k, j] > 0 else 0.0
                    acc[j] += weight[k, j] * mk
                    mean_sum[j] += mk
                    square_sum[j] += mk * mk
            obs = planes[c, i]
            shift = offset[c]
            for j in range(W):
                pred_out[i, j, c] = (acc[j] * wsum[j] if wsum[j] > 0 else obs[j]) + shift
                m = mean_sum[j] / max(count[j], 1.0)
                spread_out[i, j] -= m * m
        for j in range(W):
            n = count[j]
            spread_out[i, j] = (max(spread_out[i, j] + square_sum[j] / n, 0.0) / C
                                if n > 1.5 else 0.0)
        if weight_out.shape[1] > 0:
            for k in range(K):
                for j in range(W):
                    weight_out[k, i - row0, j] = weight[k, j] * wsum[j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def blend_edges(observed, prediction, weight, out):
    """``out = prediction + weight (observed - prediction)``, (H, W, C)
    arrays, written as :func:`edge_weight` writes it with ``blend``: the
    same expression under the same flags (``contract`` makes it one fused
    multiply-add), so the restored image of a kept weight is, bit for bit,
    the one :func:`~car_napari.restore` blends in that kernel."""
    H, W, C = observed.shape
    for i in range(H):
        for j in range(W):
            for c in range(C):
                f = prediction[i, j, c]
                w = weight[i, j, c]
                out[i, j, c] = f + w * (observed[i, j, c] - f)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def edge_weight(observed, prediction, spread, noise2, radius, threshold, blend, out, r0, r1,
                i_from, i_to, cols, spread_cols):
    """The edge rule's weight of the observation (see restoration._edge_weight)
    for rows ``r0 <= i < r1``, all images channel-last (H, W, C): ``clip(1 -
    noise2[c] / v, 0, 1)`` with ``v`` the mean of ``(observed -
    prediction)^2`` over the (2 radius + 1)^2 square (its part inside the
    image), and 1 wherever the 3 x 3 mean of ``spread`` (H, W) exceeds
    ``threshold``. With ``blend``, writes the restored image ``prediction +
    weight (observed - prediction)`` instead of the weight. Running sums
    down the rows (started ``radius`` rows above ``r0``), then along each
    row.

    Resumable: the segment of rows [r0, r1) runs its steps ``i`` from ``r0 -
    2 radius - 1`` to ``r1`` (the first ones only fill the running sums); a
    call runs the steps ``i_from <= i < i_to`` of it, the running sums kept
    in ``cols`` (W, C) and ``spread_cols`` (W,), zero at the segment's first
    step. Any split of the steps gives, bit for bit, the one-call result.
    """
    H, W, C = observed.shape
    sums = np.empty(C)
    start = r0 - 2 * radius - 1  # at i = r0 the sums hold rows r0 - radius ... r0 + radius
    for i in range(max(i_from, start), min(i_to, r1)):
        # rows entering (i + radius) and leaving (i - radius - 1) the window;
        # a row leaves only if it entered
        for sign, a in ((1.0, i + radius), (-1.0, i - radius - 1)):
            if 0 <= a < H and a >= start + radius:
                o = observed[a]
                f = prediction[a]
                for j in range(W):
                    for c in range(C):
                        e = o[j, c] - f[j, c]
                        cols[j, c] += sign * e * e
        for sign, a in ((1.0, i + 1), (-1.0, i - 2)):
            if 0 <= a < H and a >= r0 - 1:
                row = spread[a]
                for j in range(W):
                    spread_cols[j] += sign * row[j]
        if i < r0:
            continue
        ni = min(H, i + radius + 1) - max(0, i - radius)
        ns = min(H, i + 2) - max(0, i - 1)
        sums[:] = 0.0
        for j in range(min(radius, W)):
            for c in range(C):
                sums[c] += cols[j, c]
        for j in range(W):
            if j + radius < W:
                for c in range(C):
                    sums[c] += cols[j + radius, c]
            if j - radius - 1 >= 0:
                for c in range(C):
                    sums[c] -= cols[j - radius - 1, c]
            area = ni * (min(W, j + radius + 1) - max(0, j - radius))
            total = 0.0
            for b in range(max(0, j - 1), min(W, j + 2)):
                total += spread_cols[b]
            edge = total / (ns * (min(W, j + 2) - max(0, j - 1))) > threshold
            for c in range(C):
                w = min(max(1.0 - noise2[c] / max(sums[c] / area, 1e-30), 0.0), 1.0)
                w = 1.0 if edge else w
                if blend:
                    f = prediction[i, j, c]
                    out[i, j, c] = f + w * (observed[i, j, c] - f)
                else:
                    out[i, j, c] = w
