"""The windowed CAR estimate behind single-image restoration (section 14.5,
docs/restoration.md).

Restoration needs, at every pixel and for each of four neighbourhoods, the
one-step conditional mean ``gamma_hat Z_r`` and the predictive density
((14.23)-(14.25), docs/model.md) of a CAR model that is valid *around* the
pixel. The adaptive estimator ((14.26)-(14.32), section 14.2.1,
docs/model.md) gets ``gamma_hat`` by a recursive update with forgetting:
about ``p^2`` operations per pixel and direction, serial along the scan, too slow for the
chapter's speed claim (five times faster than a 5x5 median). Here the local
model is instead the least-squares estimate over a window of pixels, as the
chapter itself estimates local PSFs (14.46)-(14.47):

1. One pass sums the outer products of the augmented vector (the pixel, its
   neighbours in all four neighbourhoods, 1) over blocks of pixels. All
   four models read their statistics from these sums.
2. A window is 3 x 3 blocks; its statistics are the sum of theirs, and its
   model (``gamma``, ``lambda``, the factor of ``V_x``) is solved once per
   block with NumPy's batched linear algebra.
3. Each pixel's prediction uses the model of its block: a product with
   ``gamma`` and two small triangular products for the density.

The kernels take a range of block rows (or pixel rows), last, so that two
threads can share an image; they release the GIL (``nogil``) and are cached.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba import uint64 as u8

from .._linalg import cholesky_lower

_FAST = {"reassoc", "contract", "arcp"}


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def valid_box(shape_h, shape_w, rows, cols):
    """The rectangle [i0, i1) x [j0, j1) of pixels whose displaced pixels
    ``(i + rows[k], j + cols[k])`` all lie inside an (H, W) image."""
    i0, i1, j0, j1 = 0, shape_h, 0, shape_w
    for k in range(rows.shape[0]):
        i0 = max(i0, -rows[k])
        i1 = min(i1, shape_h - rows[k])
        j0 = max(j0, -cols[k])
        j1 = min(j1, shape_w - cols[k])
    return i0, max(i0, i1), j0, max(j0, j1)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def block_moments(planes, disp_i, disp_j, block, out, b0, b1):
    """Add, for block rows ``b0 <= bi < b1``, ``sum a a^T`` to ``out[bi, bj]``
    (full and symmetric), where ``a = [X(r + disp_k) for k, by channel; 1]``
    and ``r`` runs over the block's pixels whose every displacement lies
    inside the image. ``planes`` is the image channel-first (C, H, W).

    Speed: each block's vectors ``a`` are copied into the rows of a small
    matrix (contiguous row segments), whose row products are dot products
    that vectorise; indices are unsigned (``u8``) so that Numba adds no
    negative-index check, which would stop the vectoriser.
    """
    C, H, W = planes.shape
    K = disp_i.shape[0]
    A = K * C + 1
    i0, i1, j0, j1 = valid_box(H, W, disp_i, disp_j)
    z = np.empty((A, block * block))
    z[A - 1, :] = 1.0
    for bi in range(b0, b1):
        ia = max(bi * block, i0)
        ib = min((bi + 1) * block, i1)
        if ib <= ia:
            continue
        for bj in range(out.shape[1]):
            ja = max(bj * block, j0)
            w = min((bj + 1) * block, j1) - ja
            if w <= 0:
                continue
            n = 0
            for i in range(ia, ib):
                for k in range(K):
                    first = u8(ja + disp_j[k])
                    for c in range(C):
                        src = planes[c, i + disp_i[k]]
                        row = z[k * C + c]
                        for s in range(w):
                            row[u8(n) + u8(s)] = src[first + u8(s)]
                n += w
            for u in range(A):
                zu = z[u]
                for v in range(u, A):
                    zv = z[v]
                    total = 0.0
                    for s in range(n):
                        total += zu[u8(s)] * zv[u8(s)]
                    out[bi, bj, u, v] += total
                    if v != u:
                        out[bi, bj, v, u] += total


@njit(cache=True, nogil=True, error_model="numpy")
def window_models(moments, ix, iy, prior_x, prior_y, want_density, gamma, x_inv, lam_inv,
                  exponent, b0, b1):
    """Per block and direction, the least-squares model of the window of
    3 x 3 blocks around the block (the part inside the image).

    ``moments`` (nbi, nbj, A, A) the blocks' sums of ``a a^T`` (the last
    entry of ``a`` is 1, so ``moments[..., -1, -1]`` counts pixels); ``ix``
    (n_dir, p) and ``iy`` (d,) index the regressors and targets in ``a``;
    ``prior_x`` (p,) and ``prior_y`` (d,) the diagonal prior ``V_0``.
    Writes ``gamma`` (n_dir, nbi, nbj, d, p), the inverses of the lower
    Cholesky factors of ``V_x`` (p, p) and of ``lambda`` (d, d), and
    ``exponent = (nu + d) / 2`` with ``nu = count + 1`` ((14.23)-(14.25); the
    recursion started from ``beta(0) = p - 1`` has this ``nu``), for block
    rows ``b0 <= bi < b1``. Without ``want_density`` only ``gamma`` is
    written (``x_inv`` and ``lam_inv`` may be empty).
    """
    nbi, nbj, A = moments.shape[0], moments.shape[1], moments.shape[2]
    n_dir, p = ix.shape
    d = iy.shape[0]
    S = np.empty((A, A))
    Vxx = np.empty((p, p))
    Lx = np.empty((p, p))
    B = np.empty((p, d))
    lam = np.empty((d, d))
    Ll = np.empty((d, d))
    for bi in range(b0, b1):
        for bj in range(nbj):
            S[:, :] = 0.0
            for a in range(max(0, bi - 1), min(nbi, bi + 2)):
                for b in range(max(0, bj - 1), min(nbj, bj + 2)):
                    S += moments[a, b]
            exponent[bi, bj] = 0.5 * (S[A - 1, A - 1] + 1.0 + d)
            for k in range(n_dir):
                for u in range(p):
                    for v in range(p):
                        Vxx[u, v] = S[ix[k, u], ix[k, v]]
                    Vxx[u, u] += prior_x[u]
                    for t in range(d):
                        B[u, t] = S[ix[k, u], iy[t]]
                cholesky_lower(Vxx, Lx, p, 1e-300)
                # lambda = Vyy - (Lx^-1 Vxy)^T (Lx^-1 Vxy); B <- Lx^-1 Vxy
                _forward(Lx, B, p, d)
                for t in range(d):
                    for c in range(d):
                        acc = S[iy[t], iy[c]]
                        for u in range(p):
                            acc -= B[u, t] * B[u, c]
                        lam[t, c] = acc
                    lam[t, t] += prior_y[t]
                _backward(Lx, B, p, d)  # B = Vxx^-1 Vxy
                for t in range(d):
                    for u in range(p):
                        gamma[k, bi, bj, t, u] = B[u, t]
                if want_density:
                    cholesky_lower(lam, Ll, d, 1e-300)
                    _lower_inverse(Lx, x_inv[k, bi, bj], p)
                    _lower_inverse(Ll, lam_inv[k, bi, bj], d)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _forward(L, B, n, m):
    """B <- L^-1 B (L lower)."""
    for c in range(m):
        for i in range(n):
            acc = B[i, c]
            for k in range(i):
                acc -= L[i, k] * B[k, c]
            B[i, c] = acc / L[i, i]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _backward(L, B, n, m):
    """B <- L^-T B (L lower)."""
    for c in range(m):
        for i in range(n - 1, -1, -1):
            acc = B[i, c]
            for k in range(i + 1, n):
                acc -= L[k, i] * B[k, c]
            B[i, c] = acc / L[i, i]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lower_inverse(L, out, n):
    for j in range(n):
        for i in range(n):
            out[i, j] = 0.0
        out[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            acc = 0.0
            for k in range(j, i):
                acc -= L[i, k] * out[k, j]
            out[i, j] = acc / L[i, i]


def predict_scratch_rows(p, C):
    """Rows of scratch :func:`predict_block_models` needs for p regressors."""
    return p + C * p + p * (p + 1) // 2 + C * (C + 1) // 2 + C + 4


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def predict_block_models(planes, block, gamma, x_inv, lam_inv, tap_i, tap_j, tap_c,
                         want_ratio, scratch, mean_out, ratio_out, err2_out, row0, r0, r1):
    """One direction's one-step prediction for pixel rows ``r0 <= i < r1``.

    ``planes`` (C, H, W) the centred image channel-first; ``gamma`` (nbi,
    nbj, C, p), ``x_inv`` (nbi, nbj, p, p) and ``lam_inv`` (nbi, nbj, C, C)
    from :func:`window_models`; taps (m,) give the displacement and channel
    of each regressor (the last regressor is the intercept). Writes, in
    buffers whose row 0 is image row ``row0``, the conditional mean
    (C, rows, W), the density's ratio ``e' lambda^-1 e / q``
    with ``q = 1 + z' V_x^-1 z`` (the log density relative to its peak is
    ``-exponent * log1p(ratio)``, left to NumPy's vectorised log1p) and the
    squared error summed over channels. Where a tap leaves the image: mean
    NaN, ratio infinite (density 0), squared error 0. Without ``want_ratio``
    ``ratio_out`` may be empty and is not written (two thirds of the work
    saved when no density is asked for). ``scratch`` holds at least
    :func:`predict_scratch_rows` rows of W.

    Speed: the models of a block row are spread along the row once (one
    value per pixel), so every loop runs the length of a row, contiguous and
    without branches, and vectorises (unsigned indices: no negative-index
    checks).
    """
    C, H, W = planes.shape
    m = tap_i.shape[0]
    p = m + 1
    i0, i1, j0, j1 = valid_box(H, W, tap_i, tap_j)
    n = j1 - j0
    # views of the caller's scratch rows: no allocation here (a kernel called
    # per strip that allocates rows of a large image pays mmap and munmap)
    z = scratch[:p]
    z[m, :] = 1.0
    g_row = scratch[p : p + C * p].reshape((C, p, W))
    at = p + C * p
    x_row = scratch[at : at + p * (p + 1) // 2]
    at += p * (p + 1) // 2
    l_row = scratch[at : at + C * (C + 1) // 2]
    at += C * (C + 1) // 2
    e = scratch[at : at + C]
    at += C
    acc = scratch[at]
    q = scratch[at + 1]
    maha = scratch[at + 2]
    err2 = scratch[at + 3]
    current = -1
    for i in range(r0, r1):
        for j in range(W):
            if i < i0 or i >= i1 or j < j0 or j >= j1:
                for c in range(C):
                    mean_out[c, i - row0, j] = np.nan
                if want_ratio:
                    ratio_out[i - row0, j] = np.inf
                err2_out[i - row0, j] = 0.0
        if i < i0 or i >= i1 or n <= 0:
            continue
        bi = i // block
        if bi != current:  # spread this block row's models along the row
            current = bi
            for bj in range(j0 // block, (j1 + block - 1) // block):
                s0 = max(bj * block, j0) - j0  # this block's pixels in the row
                s1 = min((bj + 1) * block, j1) - j0
                for t in range(C):
                    for k in range(p):
                        g_row[t, k, s0:s1] = gamma[bi, bj, t, k]
                if want_ratio:
                    ak = 0
                    for a in range(p):
                        for k in range(a + 1):
                            x_row[ak, s0:s1] = x_inv[bi, bj, a, k]
                            ak += 1
                    ak = 0
                    for a in range(C):
                        for k in range(a + 1):
                            l_row[ak, s0:s1] = lam_inv[bi, bj, a, k]
                            ak += 1
        for k in range(m):
            src = planes[tap_c[k], i + tap_i[k]]
            first = u8(j0 + tap_j[k])
            row = z[k]
            for s in range(n):
                row[u8(s)] = src[first + u8(s)]
        err2[:n] = 0.0
        for t in range(C):
            acc[:n] = 0.0
            for k in range(p):
                gk = g_row[t, k]
                zk = z[k]
                for s in range(n):
                    acc[u8(s)] += gk[u8(s)] * zk[u8(s)]
            obs = planes[t, i]
            out = mean_out[t, i - row0]
            et = e[t]
            for s in range(n):
                out[u8(j0) + u8(s)] = acc[u8(s)]
                et[u8(s)] = obs[u8(j0) + u8(s)] - acc[u8(s)]
                err2[u8(s)] += et[u8(s)] * et[u8(s)]
        for s in range(n):
            err2_out[i - row0, j0 + s] = err2[u8(s)]
        if not want_ratio:
            continue
        q[:n] = 1.0
        _add_lower_norm2(x_row, z, p, n, acc, q)  # q = 1 + |x_inv z|^2
        maha[:n] = 0.0
        _add_lower_norm2(l_row, e, C, n, acc, maha)  # |lam_inv e|^2
        for s in range(n):
            ratio_out[i - row0, j0 + s] = maha[u8(s)] / q[u8(s)]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _add_lower_norm2(rows, vectors, size, n, acc, out):
    """``out[s] += |M_s v_s|^2`` for the first ``n`` pixels ``s`` of a row,
    ``M_s`` lower triangular (size x size) packed by rows in ``rows`` (one
    entry per pixel) and ``v_s`` the columns of ``vectors``."""
    ak = 0
    for a in range(size):
        acc[:n] = 0.0
        for k in range(a + 1):
            mk = rows[ak]
            vk = vectors[k]
            for s in range(n):
                acc[u8(s)] += mk[u8(s)] * vk[u8(s)]
            ak += 1
        for s in range(n):
            out[u8(s)] += acc[u8(s)] * acc[u8(s)]


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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _laplacian_abs(channel, i, j):
    return abs(channel[i - 1, j - 1] + channel[i - 1, j + 1] + channel[i + 1, j - 1]
               + channel[i + 1, j + 1]
               - 2.0 * (channel[i - 1, j] + channel[i + 1, j] + channel[i, j - 1]
                        + channel[i, j + 1])
               + 4.0 * channel[i, j])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def median_abs_laplacian(channel):
    """The median of ``|[[1,-2,1],[-2,4,-2],[1,-2,1]] * channel|`` over the
    interior, exactly as ``np.median`` (the mean of the two middle values
    for an even count), in O(n) and without storing the responses: one pass
    histograms them (the range from a sample, with an overflow bin), a
    second collects the values of the bins holding the two middle ranks,
    which alone are sorted. Falls back to the exact maximum as the range if
    a middle rank lands in the overflow bin."""
    H, W = channel.shape
    n = (H - 2) * (W - 2)
    if n <= 0:
        return 0.0
    top = 0.0
    step = max(1, n // 4096)  # a sample of the responses sets the range
    for k in range(0, n, step):
        top = max(top, _laplacian_abs(channel, 1 + k // (W - 2), 1 + k % (W - 2)))
    low, high = (n - 1) // 2, n // 2
    for attempt in range(2):
        if top == 0.0:
            return 0.0
        bins = 4096
        hist = np.zeros(bins + 1, np.int64)  # the last bin: above ``top``
        scale = bins / top
        for i in range(1, H - 1):
            for j in range(1, W - 1):
                hist[min(int(_laplacian_abs(channel, i, j) * scale), bins)] += 1
        b_low, below_low = _bin_of(hist, low)
        b_high, below_high = _bin_of(hist, high)
        if b_high < bins or attempt == 1:
            break
        top = 0.0  # rare: the sample missed the range; take the exact maximum
        for i in range(1, H - 1):
            for j in range(1, W - 1):
                top = max(top, _laplacian_abs(channel, i, j))
    lows = np.empty(hist[b_low])
    highs = np.empty(hist[b_high])
    n_low = n_high = 0
    for i in range(1, H - 1):
        for j in range(1, W - 1):
            v = _laplacian_abs(channel, i, j)
            b = min(int(v * scale), bins)
            if b == b_low:
                lows[n_low] = v
                n_low += 1
            if b == b_high:
                highs[n_high] = v
                n_high += 1
    lows.sort()
    highs.sort()
    return 0.5 * (lows[low - below_low] + highs[high - below_high])


@njit(cache=True, nogil=True, error_model="numpy")
def _bin_of(hist, rank):
    """(bin holding the ``rank``-th smallest value, count below that bin)."""
    below = 0
    b = 0
    while below + hist[b] <= rank:
        below += hist[b]
        b += 1
    return b, below


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
