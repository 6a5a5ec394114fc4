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
