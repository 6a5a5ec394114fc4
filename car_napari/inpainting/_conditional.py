"""The CAR model's exact conditional mean of the missing pixels
(docs/inpainting.md, "The conditional mean").

A causal CAR model ``Y~_r = sum_k A_k Y~_{r-s_k} + e_r``, ``e_r ~ N(0, Sigma)``
(SPEC 1.2, ``Y~ = Y - mu``) is a Gaussian field: its density over a window is
``prod_r N(e_r; 0, Sigma)``, so the negative log density is
``1/2 sum_r |L^-1 e_r|^2`` with ``Sigma = L L^T``. Stack the whitened residuals
``w_r = L^-1 e_r = sum_k G_k Y_{r-s_k} + c`` (``G_0 = L^-1``,
``G_k = -L^-1 A_k``, ``c = -sum_k G_k mu``) of every pixel ``r`` as ``w = M y + c``;
the precision is ``Q = M^T M`` (``(I - A)^T (I (x) Sigma^-1) (I - A)`` in the
pixel-channel ordering, pixel-major). Given the known pixels ``y_K``, the
missing ``x = y_U`` minimise ``|M_U x + (M_K y_K + c)|^2``: the conditional mean
solves ``(M_U^T M_U) x = -M_U^T (M_K y_K + c)``, i.e. ``Q_UU x = -Q_UK y_K - ...``.
Only rows ``r`` that touch a missing pixel enter ``M_U``. A pixel of the hole
whose neighbourhood leaves the frame has no model row; it gets the marginal
row ``e_r = Y_r - mu ~ N(0, Sigma_marginal)`` (the boundary's density replaced
by independent marginals), so ``M_U`` always has full column rank.

The model is local: one fit per tile of ``tile`` pixels, on a window of
``margin`` more pixels around it, from the known pixels whose neighbourhood
is known; each row uses the model of the tile it lies in.
"""

from __future__ import annotations

import math
from concurrent.futures import FIRST_COMPLETED, wait
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import ndimage, sparse
from scipy.sparse.linalg import splu

from .._progress import Progress, drain, stage
from .._threads import job_pool
from ..model.neighbourhood import causal_neighbourhood

__all__ = ["DIRECTIONS", "LocalModels", "conditional_mean", "direction_offsets",
           "fill_conditional", "fit_local_models", "iter_fill_conditional",
           "iter_fit_local_models", "iter_stencil_solve", "stencil_solve"]

DEFAULT_TILE = 48  # pixels: each tile has its own model
DEFAULT_MARGIN = 16  # pixels around a tile in its fitting window
_MIN_ROWS_PER_REGRESSOR = 4  # a window with fewer fitting pixels grows
_PRIOR = 1e-3  # V_0 = _PRIOR * variance * I per regressor: a light ridge
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
DIRECTIONS = ("down", "up", "right", "left")
HALO_BLEND = 0.1  # the least blend towards the damage the edge test calls damage
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
HALO_REGION_BLEND = 0.05
HALO_UNBLEND = 0.5  # a pixel called damaged stays known, less half its blend (see _filling)
# The work between records: the statistics of the fit by bands of blocks of
# about _FIT_RECORD_PIXELS pixels; the solves by batches of coupled groups of
# about SOLVE_UNKNOWNS unknowns, run on the job pool's threads, a record every
# SOLVE_RECORD_SECONDS while they run (a Cancel returns at the next record;
# a factorisation running finishes in its thread, its result dropped).
_FIT_RECORD_PIXELS = 1 << 16
_ESTIMATE_TILES = 512  # tiles' models estimated between records
_ASSEMBLE_ROWS = 1 << 15  # rows of the normal equations added between records
SOLVE_UNKNOWNS = 1 << 14
SOLVE_RECORD_SECONDS = 0.25
# The widest band (half-bandwidth, in unknowns) of a batch solved by the band
# Cholesky factorisation rather than SuperLU: on 640x480 RGB holes, the band
# solve is 3-5x faster on 3-8 px wide scratches (half-bandwidth 32-77), 1.2x
# at 221 (24 px wide) and slower from about 290 (32 px) on
BAND_WIDTH = 200
PREVIOUS_OFFSETS = np.array([(0, 0), (0, 1), (1, 0), (0, -1), (-1, 0)], np.int64)


class LocalModels(NamedTuple):
    """One CAR model per tile (arrays indexed by tile row, tile column).

    ``offsets`` (eta, 2) causal offsets of the current frame; ``gamma``
    (ty, tx, d, d*eta + d*p) ``[A_1 .. A_eta, B_1 .. B_p]`` (columns
    ``k*d + c``; the ``B`` act on the previous frame at ``PREVIOUS_OFFSETS``,
    ``p = 0`` without one); ``sigma`` (ty, tx, d, d) innovation covariance;
    ``mean`` and ``previous_mean`` (ty, tx, d); ``marginal`` (ty, tx, d, d)
    the covariance of the window's known pixels."""

    tile: int
    offsets: np.ndarray
    gamma: np.ndarray
    sigma: np.ndarray
    mean: np.ndarray
    previous_mean: np.ndarray | None
    marginal: np.ndarray


def _shifted(arr, di, dj, fill):
    """``out[i, j] = arr[i - di, j - dj]`` (``fill`` outside)."""
    H, W = arr.shape[:2]
    out = np.full_like(arr, fill)
    a0, a1 = max(di, 0), min(H, H + di)
    b0, b1 = max(dj, 0), min(W, W + dj)
    if a0 < a1 and b0 < b1:
        out[a0:a1, b0:b1] = arr[a0 - di : a1 - di, b0 - dj : b1 - dj]
    return out


@njit(cache=True, nogil=True)
def _dilate_kernel(mask, radius, square, out):
    H, W = mask.shape
    for i in range(H):
        for j in range(W):
            if not mask[i, j]:
                continue
            for di in range(-radius, radius + 1):
                ii = i + di
                if ii < 0 or ii >= H:
                    continue
                reach = radius if square else radius - abs(di)
                for jj in range(max(j - reach, 0), min(j + reach + 1, W)):
                    out[ii, jj] = True


def _dilate(mask, radius, square=False):
    """``ndimage.binary_dilation(mask, iterations=radius)`` with the cross
    (the pixels within ``radius`` steps of a true one) or, ``square``, with
    the 3x3 square (within ``radius`` in both coordinates): the same set,
    made by marking each true pixel's neighbourhood (the masks are sparse;
    SciPy's passes over the whole frame took most of the time on small
    damage)."""
    out = np.zeros(mask.shape, bool)
    _dilate_kernel(np.ascontiguousarray(mask, bool), int(radius), bool(square), out)
    return out


def _inside(shape, offsets):
    """Pixels ``r`` whose every ``r - s`` lies in the frame."""
    H, W = shape
    di, dj = offsets[:, 0], offsets[:, 1]
    rows = np.arange(H)[:, None]
    cols = np.arange(W)[None, :]
    return ((rows >= di.max()) & (rows < H + di.min())
            & (cols >= dj.max()) & (cols < W + dj.min()))


def _iter_fold_known_bands(frame, known, fold, total, message, lo, hi):
    """``total = fold(total, values)`` over the known pixels of ``frame``
    (H, W, d) by bands of rows (``values`` (n, d) a band's, in raster
    order: no copy of all the known pixels at once), as a job: a record
    after each band (fractions ``lo`` to ``hi``), then the last ``total``."""
    H, W = known.shape
    rows = max(1, _FIT_RECORD_PIXELS * 16 // max(W, 1))
    for r0 in range(0, H, rows):
        total = fold(total, frame[r0 : r0 + rows][known[r0 : r0 + rows]])
        yield Progress("fit", lo + (hi - lo) * min(r0 + rows, H) / H, message)
    return total


@njit(cache=True, nogil=True)
def _known_sums_kernel(frame, known, r0, r1, centre, squares):
    """The sums per channel over the known pixels of rows ``r0:r1`` (in
    raster order, one after another: what NumPy's sum over the rows of an
    (n, d >= 2) array does) of the values, or with ``squares`` of their
    squared deviations from ``centre``; and the pixels summed."""
    C = frame.shape[2]
    out = np.zeros(C)
    n = 0
    for i in range(r0, r1):
        for j in range(frame.shape[1]):
            if not known[i, j]:
                continue
            n += 1
            for c in range(C):
                if squares:
                    d = frame[i, j, c] - centre[c]
                    out[c] += d * d
                else:
                    out[c] += frame[i, j, c]
    return out, n


@njit(cache=True, nogil=True)
def _known_range_kernel(frame, known, r0, r1, lo, hi):
    """``lo``, ``hi`` (d,) lowered and raised to the known pixels of rows ``r0:r1``."""
    for i in range(r0, r1):
        for j in range(frame.shape[1]):
            if known[i, j]:
                for c in range(frame.shape[2]):
                    v = frame[i, j, c]
                    lo[c] = min(lo[c], v)
                    hi[c] = max(hi[c], v)


def _compiled_sums(frame):
    """Whether :func:`_known_sums_kernel` sums ``frame`` as NumPy does: float64
    and at least two channels (NumPy sums one channel pairwise)."""
    return frame.dtype == np.float64 and frame.shape[2] >= 2


def _iter_known_range(frame, known, message):
    """(lo, hi) per channel of the known pixels, as a job."""
    H, W, C = frame.shape
    lo, hi = np.full(C, np.inf), np.full(C, -np.inf)
    if frame.dtype == np.float64:  # no copy of the known pixels
        rows = max(1, _FIT_RECORD_PIXELS * 16 // max(W, 1))
        for r0 in range(0, H, rows):
            _known_range_kernel(frame, known, r0, min(r0 + rows, H), lo, hi)
            yield Progress("fit", min(r0 + rows, H) / H, message)
        return lo, hi

    def widen(bounds, values):
        if not len(values):
            return bounds
        return np.minimum(bounds[0], values.min(axis=0)), np.maximum(bounds[1], values.max(axis=0))

    return (yield from _iter_fold_known_bands(frame, known, widen, (lo, hi), message, 0.0, 1.0))


def _iter_known_variance(frame, known, message, fraction):
    """The variance per channel of the known pixels (two passes: the mean,
    then the centred squares), as a job."""
    H, W, C = frame.shape
    if _compiled_sums(frame):  # the same sums, without copies of the known pixels
        rows = max(1, _FIT_RECORD_PIXELS * 16 // max(W, 1))
        n, total = 0, np.zeros(C)
        for r0 in range(0, H, rows):
            part, count = _known_sums_kernel(frame, known, r0, min(r0 + rows, H), total, False)
            n += count
            total += part
            yield Progress("fit", fraction, message)
        mean = total / max(n, 1)
        squares = np.zeros(C)
        for r0 in range(0, H, rows):
            squares += _known_sums_kernel(frame, known, r0, min(r0 + rows, H), mean, True)[0]
            yield Progress("fit", fraction, message)
        return squares / max(n, 1)
    n, total = yield from _iter_fold_known_bands(
        frame, known, lambda acc, values: (acc[0] + len(values), acc[1] + values.sum(axis=0)),
        (0, np.zeros(C)), message, fraction, fraction)
    mean = total / max(n, 1)
    squares = yield from _iter_fold_known_bands(
        frame, known, lambda acc, values: acc + ((values - mean) ** 2).sum(axis=0),
        np.zeros(C), message, fraction, fraction)
    return squares / max(n, 1)


@njit(cache=True, nogil=True)
def _fit_blocks_kernel(frame, previous, ok, taps, n_current, r0, cols, g, blocks, counts):
    """The regression rows of the fitting pixels of a row of blocks:
    ``blocks[n, y * g + x, k * d + c]`` the tap ``k`` (the first
    ``n_current`` of ``frame``, the others of ``previous``; 0 outside the
    frame) of pixel ``(r0 + y, cols[n] * g + x)`` times 1 when it is a
    fitting pixel (``ok``) and 0 when not; ``counts[n]`` the fitting pixels
    of block ``n``."""
    H, W, C = frame.shape
    K = taps.shape[0]
    for n in range(cols.shape[0]):
        c0 = cols[n] * g
        counts[n] = 0.0
        for y in range(g):
            i = r0 + y
            for x in range(g):
                j = c0 + x
                f = 1.0 if (i < H and j < W and ok[i, j]) else 0.0
                counts[n] += f
                row = y * g + x
                for k in range(K):
                    si = i - taps[k, 0]
                    sj = j - taps[k, 1]
                    inside = 0 <= si < H and 0 <= sj < W
                    for c in range(C):
                        v = 0.0
                        if inside:
                            v = frame[si, sj, c] if k < n_current else previous[si, sj, c]
                        blocks[n, row, k * C + c] = v * f


@njit(cache=True, nogil=True)
def _window_sums_kernel(flat, corner_rows, a0, a1, b0, b1, m0, m1, out):
    """``out[t, m] = I[a1, b1] - I[a0, b1] - I[a1, b0] + I[a0, b0]`` for the
    entries ``m0 <= m < m1`` of the (R, S, M) ``flat``, ``I`` its integral
    image (a zero row and column first): ``np.cumsum`` down the rows, then
    along them, the same additions in the same order, kept only at the
    ``corner_rows`` (sorted) that are read."""
    R, S, _ = flat.shape
    M = m1 - m0
    slot = np.full(R + 1, -1, np.int64)
    for r in range(corner_rows.shape[0]):
        slot[corner_rows[r]] = r
    rows = np.zeros((corner_rows.shape[0], S + 1, M))  # I at those rows
    down = np.empty((S, M))  # the running column sums (the first cumsum)
    for a in range(1, R + 1):
        for b in range(S):
            for m in range(M):
                if a == 1:
                    down[b, m] = flat[0, b, m0 + m]
                else:
                    down[b, m] = down[b, m] + flat[a - 1, b, m0 + m]
        r = slot[a]
        if r < 0:
            continue
        for m in range(M):
            acc = down[0, m]
            rows[r, 1, m] = acc
            for b in range(1, S):
                acc = acc + down[b, m]
                rows[r, b + 1, m] = acc
    for t in range(a0.shape[0]):
        r0, r1 = slot[a0[t]], slot[a1[t]]
        for m in range(M):
            out[t, m0 + m] = (rows[r1, b1[t], m] - rows[r0, b1[t], m] - rows[r1, b0[t], m]
                              + rows[r0, b0[t], m])


def iter_fit_local_models(frame, unknown, offset_sets, *, previous=None, tile=DEFAULT_TILE,
                          margin=DEFAULT_MARGIN, need=None, prior=_PRIOR):
    """:func:`fit_local_models` as a job: a record after every band of
    blocks of the statistics (stage ``"fit"``), then the models."""
    H, W, C = frame.shape
    offset_sets = [np.asarray(o, np.int64) for o in offset_sets]
    n_prev = 0 if previous is None else len(PREVIOUS_OFFSETS)
    union = sorted({(int(di), int(dj)) for o in offset_sets for di, dj in o} - {(0, 0)})
    taps = np.array([(0, 0)] + union, np.int64)  # the centre first
    where = {tuple(t): k for k, t in enumerate(taps.tolist())}
    ty, tx = -(-H // tile), -(-W // tile)
    if need is None:
        need = np.ones((ty, tx), bool)
    known = ~unknown
    ok = known & _inside((H, W), taps)
    for k, (di, dj) in enumerate(taps[1:]):
        ok &= _shifted(known, di, dj, False)
        if k % 8 == 7:
            yield Progress("fit", 0.0, "fitting")
    if previous is not None:
        ok &= _inside((H, W), PREVIOUS_OFFSETS)
    n_cols = C * (len(taps) + n_prev)
    m_max = max(C * (len(o) + n_prev) for o in offset_sets)
    # each needed tile's window: its margin doubled until it holds enough rows.
    # Its edges lie on a grid of unit pixels (tile and margin are multiples of
    # it): the fitting pixels are counted by cells of that grid
    unit = math.gcd(int(tile), int(margin)) if margin > 0 else 1
    cy, cx = -(-H // unit), -(-W // unit)
    cells = np.zeros((cy * unit, cx * unit), bool)
    cells[:H, :W] = ok
    cells = cells.reshape(cy, unit, cx, unit).sum(axis=(1, 3), dtype=np.int64)
    integral = np.zeros((cy + 1, cx + 1), np.int64)
    integral[1:, 1:] = np.cumsum(np.cumsum(cells, axis=0), axis=1)
    del cells
    yield Progress("fit", 0.05, "fitting")
    ta, tb = np.nonzero(need)
    grow = np.full(len(ta), int(margin), np.int64)
    while True:
        i0, i1 = np.maximum(ta * tile - grow, 0), np.minimum((ta + 1) * tile + grow, H)
        j0, j1 = np.maximum(tb * tile - grow, 0), np.minimum((tb + 1) * tile + grow, W)
        c0, c1, d0, d1 = i0 // unit, -(-i1 // unit), j0 // unit, -(-j1 // unit)
        n = integral[c1, d1] - integral[c0, d1] - integral[c1, d0] + integral[c0, d0]
        whole = (i0 == 0) & (j0 == 0) & (i1 == H) & (j1 == W)
        short = (n < _MIN_ROWS_PER_REGRESSOR * (m_max + 1)) & ~whole
        if not short.any():
            break
        grow[short] = np.maximum(2 * grow[short], 1) if unit == 1 else 2 * grow[short]
    g = math.gcd(math.gcd(int(tile), int(grow.min()) if len(grow) else int(tile)),
                 *[int(v) for v in np.unique(grow)]) if len(grow) else int(tile)
    g = max(g, 1)
    by, bx = -(-H // g), -(-W // g)
    wanted = np.zeros((by, bx), bool)  # blocks inside some window
    for a0, a1, b0, b1 in zip(i0 // g, -(-i1 // g), j0 // g, -(-j1 // g), strict=True):
        wanted[a0:a1, b0:b1] = True
    # the statistics are kept for the rows and columns of blocks that hold a
    # wanted block only (a scratch: a few columns of blocks down the frame);
    # the others are zero, so the windows' sums over this compressed grid are
    # their sums over the frame
    block_rows = np.nonzero(wanted.any(axis=1))[0]
    block_cols = np.nonzero(wanted.any(axis=0))[0]
    # the raw statistics of every wanted block: pixel count, sums, sums of products
    yield Progress("fit", 0.05, "fitting")
    # the kernel reads the frames with zeros outside (no padded copies)
    source = np.ascontiguousarray(frame, np.float64)
    psource = (np.zeros((0, 0, C)) if previous is None
               else np.ascontiguousarray(previous, np.float64))
    yield Progress("fit", 0.05, "fitting")
    shape = (len(block_rows), len(block_cols))
    count = np.zeros(shape)
    s1 = np.zeros((*shape, n_cols))
    s2 = np.zeros((*shape, n_cols, n_cols))
    taps_all = np.ascontiguousarray(np.vstack([taps, PREVIOUS_OFFSETS[:n_prev]]), np.int64)
    pixels_done = 0
    for row, a in enumerate(block_rows):
        cols = np.nonzero(wanted[a])[0]
        at = np.searchsorted(block_cols, cols)
        nc = len(cols)
        blocks = np.empty((nc, g * g, n_cols))
        counts = np.empty(nc)
        _fit_blocks_kernel(source, psource, ok, taps_all, len(taps), a * g, cols, g, blocks,
                           counts)
        count[row, at] = counts
        s1[row, at] = blocks.sum(axis=1)
        s2[row, at] = np.matmul(blocks.transpose(0, 2, 1), blocks)
        pixels_done += g * g * nc
        if pixels_done >= _FIT_RECORD_PIXELS:
            pixels_done = 0
            yield Progress("fit", 0.05 + 0.75 * (row + 1) / len(block_rows), "fitting")
    del source, psource
    # the window sums (integral images over the blocks) of every needed tile,
    # by slices of the statistics' columns, a record between them
    a0, a1 = (np.searchsorted(block_rows, i0 // g), np.searchsorted(block_rows, -(-i1 // g)))
    b0, b1 = (np.searchsorted(block_cols, j0 // g), np.searchsorted(block_cols, -(-j1 // g)))
    step = max(1, _FIT_RECORD_PIXELS * 64 // max(shape[0] * shape[1], 1))

    corner_rows = np.unique(np.concatenate([a0, a1]))  # the integral's rows read

    def window_sums(blocks, start, stop):
        flat = np.ascontiguousarray(blocks.reshape(*shape, math.prod(blocks.shape[2:])))
        out = np.empty((len(a0), flat.shape[2]))
        for k in range(0, flat.shape[2], step):
            part = min(k + step, flat.shape[2])
            _window_sums_kernel(flat, corner_rows, a0, a1, b0, b1, k, part, out)
            yield Progress("fit", start + (stop - start) * part / flat.shape[2], "fitting")
        return out.reshape(len(a0), *blocks.shape[2:])

    N = (yield from window_sums(count, 0.8, 0.8))
    S1 = yield from window_sums(s1, 0.8, 0.82)
    V = yield from window_sums(s2, 0.82, 1.0)
    del s2
    safe = np.maximum(N, 1)
    mu = S1[:, :C] / safe[:, None]
    centre = np.tile(mu, len(taps))
    if n_prev:
        pmu = S1[:, len(taps) * C : (len(taps) + 1) * C] / safe[:, None]
        centre = np.concatenate([centre, np.tile(pmu, n_prev)], axis=1)
    # V - s m^T - m s^T + n m m^T: the sums of products of the centred rows
    V = (V - S1[:, :, None] * centre[:, None, :] - centre[:, :, None] * S1[:, None, :]
         + N[:, None, None] * centre[:, :, None] * centre[:, None, :])
    overall_var = (yield from _iter_known_variance(frame, known, "estimating", 1.0)) + 1e-12
    ridge = np.diag(1e-6 * overall_var)
    marginal = V[:, :C, :C] / safe[:, None, None] + ridge
    scale = np.trace(marginal, axis1=1, axis2=2) / C
    fitted = N >= 2
    mean = np.zeros((ty, tx, C))
    mean[ta[fitted], tb[fitted]] = mu[fitted]
    pmean = None
    if n_prev:
        pmean = np.zeros((ty, tx, C))
        pmean[ta[fitted], tb[fitted]] = pmu[fitted]
    results = []
    for o in offset_sets:
        cols = [c for di, dj in o for c in range(where[(int(di), int(dj))] * C,
                                                  where[(int(di), int(dj))] * C + C)]
        cols += list(range(len(taps) * C, n_cols))  # the previous frame's taps
        m = len(cols)
        eye = np.broadcast_to(np.eye(C), (ty, tx, C, C))
        gamma, sigma, marg = np.zeros((ty, tx, C, m)), eye.copy(), eye.copy()
        marg[ta[fitted], tb[fitted]] = marginal[fitted]
        texture = N >= m + 2
        flat = fitted & ~texture  # no texture to learn: independent pixels around the mean
        sigma[ta[flat], tb[flat]] = marginal[flat]
        order = np.array(cols + list(range(C)))
        textured = np.nonzero(texture)[0]
        for start in range(0, len(textured), _ESTIMATE_TILES):  # a record between batches
            batch = textured[start : start + _ESTIMATE_TILES]
            Vd = V[batch][:, order[:, None], order[None, :]]
            Vd[:, np.arange(m + C), np.arange(m + C)] += (prior * scale[batch])[:, None]
            L = np.linalg.cholesky(Vd)
            L11, L21, L22 = L[:, :m, :m], L[:, m:, :m], L[:, m:, m:]
            g_t = np.linalg.solve(L11.transpose(0, 2, 1), L21.transpose(0, 2, 1))
            gamma[ta[batch], tb[batch]] = g_t.transpose(0, 2, 1)
            lam = L22 @ L22.transpose(0, 2, 1)
            dof = np.maximum(N[batch] - m, 1)
            sigma[ta[batch], tb[batch]] = lam / dof[:, None, None] + ridge
            if start + _ESTIMATE_TILES < len(textured):
                yield Progress("fit", 1.0, "estimating")
        results.append((gamma, sigma, marg))
        yield Progress("fit", 1.0, "estimating")
    return [LocalModels(tile, o, gamma, sigma, mean, pmean, marg)
            for o, (gamma, sigma, marg) in zip(offset_sets, results, strict=True)]


def fit_local_models(frame, unknown, offset_sets, *, previous=None, tile=DEFAULT_TILE,
                     margin=DEFAULT_MARGIN, need=None, prior=_PRIOR):
    """Fit one 3DCAR model per tile and per offset set (one per scan
    direction) from the known pixels: a list of :class:`LocalModels`.

    The fitting pixels are the known pixels whose every neighbour (under all
    the offset sets, and in the previous frame) is known and inside the
    frame; the statistics of a tile are summed over those in its window (the
    tile and ``margin`` more pixels each way; the window doubles its margin
    until it holds ``_MIN_ROWS_PER_REGRESSOR`` pixels per regressor). The
    estimate is the Bayesian one of SPEC 1.3 with a light ridge prior
    (``estimate_parameters``), ``Sigma = lambda / (n - m)``. ``need`` (ty, tx)
    bool: the tiles to fit (the others get an identity covariance and no
    texture)."""
    return drain(iter_fit_local_models(frame, unknown, offset_sets, previous=previous,
                                       tile=tile, margin=margin, need=need, prior=prior))


def _inv_chol(S):
    """``L^-1`` for ``S = L L^T``, batched over leading axes."""
    L = np.linalg.cholesky(S)
    eye = np.broadcast_to(np.eye(S.shape[-1]), S.shape)
    return np.linalg.solve(L, eye)


@njit(cache=True, nogil=True)
def _assemble_kernel(frame, index, offsets, coeffs, pairs, constant, extra, tile, slot_of,
                     reach2, rows, border, border_G, border_c, probes, state, Q, rhs, z,
                     with_q=True):
    """Add one set of whitened rows ``w_r = sum_k G_k Y_{r - s_k} + c (+
    extra_r)`` (every ``r`` with all taps inside the frame and one of them
    unknown) to the normal equations of the unknown pixels: ``Q[p, slot]
    += G_k^T G_l`` (``pairs[t, k, l]``) for unknown ``p = r - s_k`` and ``q
    = r - s_l`` (``slot`` the offset ``q - p`` in ``slot_of``), ``rhs[p] -=
    G_k^T (known part of w_r)``, and ``z[p, s] += G_k^T n_{r, s}`` for
    ``probes`` independent random signs ``n_{r, s}`` per channel (so that
    ``z`` has covariance ``Q``). ``rows`` (n, 2): the pixels ``r`` to visit,
    in raster order (those within ``reach`` of an unknown pixel: the others
    touch none); a call may take a part of them, ``state`` (1,) carries the
    random signs' generator from call to call. With ``border``: instead,
    an unknown pixel of ``rows`` without a full row gets ``border_G Y_p +
    border_c``. Without ``with_q``: ``rhs`` only (``Q`` and ``z`` left
    alone; no random signs drawn).

    ``Q`` holds the slots from the centre on only (offsets ``q - p`` at or
    after (0, 0) in ``slot_of``'s sorted order, ``Q[p, slot - centre]``):
    the block of the opposite offset is its transpose (``pairs[t, l, k] =
    pairs[t, k, l]^T``, added by the same rows in the same order)."""
    H, W, C = frame.shape
    K = offsets.shape[0]
    centre = slot_of[reach2, reach2]
    in_i, in_j, out_i, out_j = 0, 0, H, W
    for k in range(K):
        in_i = max(in_i, offsets[k, 0])
        out_i = min(out_i, H + offsets[k, 0])
        in_j = max(in_j, offsets[k, 1])
        out_j = min(out_j, W + offsets[k, 1])
    tap = np.empty(K, np.int64)
    kc = np.empty(C)
    noise = np.empty((probes, C))
    use_extra = extra.shape[0] == H
    rng = state[0]
    if border:
        for n in range(rows.shape[0]):
            i, j = rows[n, 0], rows[n, 1]
            p = index[i, j]
            if p < 0 or (in_i <= i < out_i and in_j <= j < out_j):
                continue
            ti = i // tile
            tj = j // tile
            if not with_q:
                for a in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * border_c[ti, tj, b]
                    rhs[p, a] -= acc
                continue
            for s in range(probes):
                for a in range(C):
                    rng ^= rng << np.uint64(13)
                    rng ^= rng >> np.uint64(7)
                    rng ^= rng << np.uint64(17)
                    noise[s, a] = 1.0 if (rng >> np.uint64(40)) & np.uint64(1) else -1.0
            for a in range(C):
                acc = 0.0
                for b in range(C):
                    acc += border_G[ti, tj, b, a] * border_c[ti, tj, b]
                rhs[p, a] -= acc
                for s in range(probes):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * noise[s, b]
                    z[p, s, a] += acc
                for c in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * border_G[ti, tj, b, c]
                    Q[p, 0, a, c] += acc
        state[0] = rng
        return
    # the slot of each pair of taps (their offsets are fixed) and the
    # blocks of Q and of the pairs as rows of C * C values
    slot_kk = np.empty((K, K), np.int64)
    for k in range(K):
        for k2 in range(K):
            slot_kk[k, k2] = slot_of[reach2 + offsets[k, 0] - offsets[k2, 0],
                                     reach2 + offsets[k, 1] - offsets[k2, 1]]
    CC = C * C
    S = Q.shape[1]
    Qf = Q.reshape(Q.shape[0] * S, CC)
    ty, tx = pairs.shape[0], pairs.shape[1]
    pf = pairs.reshape(ty * tx * K * K, CC)
    # G_k^T n for each of the 2^d sign vectors n, per tile and tap: a draw's
    # term is then looked up (the same products and sums, made once)
    patterns = 1 << C
    signed = np.zeros((0, 0, K, patterns, C))
    pattern = np.zeros(probes, np.int64)
    if with_q and probes:
        signed = np.empty((coeffs.shape[0], coeffs.shape[1], K, patterns, C))
        for t0 in range(coeffs.shape[0]):
            for t1 in range(coeffs.shape[1]):
                for k in range(K):
                    for pat in range(patterns):
                        for a in range(C):
                            acc = 0.0
                            for b in range(C):
                                acc += coeffs[t0, t1, k, b, a] * (1.0 if (pat >> b) & 1 else -1.0)
                            signed[t0, t1, k, pat, a] = acc
    for n in range(rows.shape[0]):
        i, j = rows[n, 0], rows[n, 1]
        if not (in_i <= i < out_i and in_j <= j < out_j):
            continue
        hit = False
        for k in range(K):
            tap[k] = index[i - offsets[k, 0], j - offsets[k, 1]]
            if tap[k] >= 0:
                hit = True
        if not hit:
            continue
        ti = i // tile
        tj = j // tile
        for a in range(C):
            kc[a] = constant[ti, tj, a] + (extra[i, j, a] if use_extra else 0.0)
        for k in range(K):
            if tap[k] < 0:
                pi = i - offsets[k, 0]
                pj = j - offsets[k, 1]
                for a in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += coeffs[ti, tj, k, a, b] * frame[pi, pj, b]
                    kc[a] += acc
        if with_q:
            for s in range(probes):
                pat = 0
                for a in range(C):  # xorshift64: a random sign
                    rng ^= rng << np.uint64(13)
                    rng ^= rng >> np.uint64(7)
                    rng ^= rng << np.uint64(17)
                    if (rng >> np.uint64(40)) & np.uint64(1):
                        pat |= 1 << a
                pattern[s] = pat
        tile_pairs = (ti * tx + tj) * K * K
        for k in range(K):
            p = tap[k]
            if p < 0:
                continue
            for a in range(C):
                acc = 0.0
                for b in range(C):
                    acc += coeffs[ti, tj, k, b, a] * kc[b]
                rhs[p, a] -= acc
            if not with_q:
                continue
            for s in range(probes):
                for a in range(C):
                    z[p, s, a] += signed[ti, tj, k, pattern[s], a]
            row_p = p * S - centre
            for k2 in range(K):
                if tap[k2] < 0 or slot_kk[k, k2] < centre:
                    continue
                q_row = row_p + slot_kk[k, k2]
                pair_row = tile_pairs + k * K + k2
                for m in range(CC):
                    Qf[q_row, m] += pf[pair_row, m]
    state[0] = rng


@njit(cache=True, nogil=True)
def _csr_kernel(Q, block_rows, pixels, index, slots, indptr, indices, data, count_only,
                start, stop, found, found_n):
    """The CSR pattern (``count_only``: the entries per row into
    ``indptr[1:]``) or the entries of ``Q`` (per unknown pixel, per slot of
    ``slots`` (S, 2) offsets, a C x C block; pixel ``p``'s blocks are
    ``Q[block_rows[p]]``), the unknown pixels (their ``pixels``
    coordinates) in ``index`` order, blocks that are all zero left out; of
    the pixels ``start`` to ``stop`` (whole groups: coupled with no other
    pixel), numbered from ``start``. The counting pass keeps the slots of
    each pixel's nonzero blocks (``found`` (stop - start, S), ``found_n``
    (stop - start,)) for the other. ``Q`` holds the slots from the centre
    of ``slots`` on (see :func:`_assemble_kernel`); a slot before it is
    the transpose of the opposite slot's block of the column pixel."""
    S, C = slots.shape[0], Q.shape[2]
    centre = (S - 1) // 2
    H, W = index.shape
    for p in range(start, stop):
        row = block_rows[p]
        lp = p - start
        if count_only:
            i, j = pixels[p, 0], pixels[p, 1]
            n = 0
            for s in range(S):
                qi, qj = i + slots[s, 0], j + slots[s, 1]
                if qi < 0 or qi >= H or qj < 0 or qj >= W:
                    continue
                q = index[qi, qj]
                if q < 0:
                    continue
                if s >= centre:
                    r, t = row, s - centre
                else:
                    r, t = block_rows[q], S - 1 - s - centre
                nonzero = False
                for b in range(C):
                    for c in range(C):
                        if Q[r, t, b, c] != 0.0:
                            nonzero = True
                            break
                    if nonzero:
                        break
                if nonzero:
                    found[lp, n] = s
                    n += 1
            found_n[lp] = n
            for a in range(C):
                indptr[lp * C + a + 1] = n * C
            continue
        n = found_n[lp]
        i, j = pixels[p, 0], pixels[p, 1]
        for a in range(C):
            at = indptr[lp * C + a]
            for t in range(n):
                s = found[lp, t]
                q = index[i + slots[s, 0], j + slots[s, 1]]
                if s >= centre:
                    for c in range(C):
                        indices[at] = (q - start) * C + c
                        data[at] = Q[row, s - centre, a, c]
                        at += 1
                else:
                    r, u = block_rows[q], S - 1 - s - centre
                    for c in range(C):
                        indices[at] = (q - start) * C + c
                        data[at] = Q[r, u, c, a]
                        at += 1


class _System(NamedTuple):
    """The normal equations ``Q x = rhs`` of the unknown pixels, pixels in
    ``index`` order grouped by coupled component: ``groups`` the (start,
    stop) pixel ranges (``Q`` is block diagonal over them); ``z`` (n, probes,
    d): draws of ``N(0, Q)``. ``Q`` is kept by blocks (``blocks``): each
    batch of groups is solved from them (:func:`_solve_block`)."""

    slots: np.ndarray  # (S, 2) the offsets q - p of the blocks, sorted
    rhs: np.ndarray
    z: np.ndarray
    groups: list
    pixels: np.ndarray  # (n, 2) the unknown pixels in index order
    diagonal: np.ndarray  # (n, d, d) the diagonal blocks of Q
    blocks: np.ndarray  # (m, slots, d, d) Q by pixel and offset from the centre on:
    # pixel p's at block_rows[p] (see _assemble_kernel)
    block_rows: np.ndarray  # (n,)
    index: np.ndarray  # (H, W) a pixel's place in index order, -1 if known


def _seed_state(seed):
    """The xorshift64 state of :func:`_assemble_kernel`'s random signs for ``seed``."""
    return (int(seed) * 6364136223846793005 + 1442695040888963407) % (1 << 64)


def _iter_assemble(frame, unknown, row_sets, tile, probes=0, seed=0, reuse=None):
    """The normal equations of the ``unknown`` pixels (a :class:`_System`),
    as a job: a record (stage ``"assembly"``) after each part of a set of
    rows. ``Q`` is kept by blocks; each batch's solve reads them
    (:func:`_solve_block`).

    ``reuse``: the :class:`_System` of a superset of the unknown pixels
    under the same rows. ``Q`` between two pixels sums the rows that touch
    both, the same rows (in the same order) whatever else is unknown: its
    blocks are taken from there, and only ``rhs`` is assembled."""
    H, W, C = frame.shape
    offsets_all = [np.asarray(r[0], np.int64) for r in row_sets]
    reach = max(int(np.abs(o).max()) if len(o) else 0 for o in offsets_all)
    reach2 = 2 * reach
    # pixels coupled through a row lie within 2 reach of each other: a group
    # is a connected component of the damage grown by ``reach``
    if reach:
        grown = _dilate(unknown, reach, square=True)
    else:
        grown = unknown
    yield Progress("assembly", 0.0, "assembling")
    labels, n_groups = ndimage.label(grown, structure=np.ones((3, 3), bool))
    yield Progress("assembly", 0.0, "assembling")
    ui, uj = np.nonzero(unknown)
    lab = labels[ui, uj]
    order = np.argsort(lab, kind="stable")  # row-major within a group
    ui, uj, lab = ui[order], uj[order], lab[order]
    n_u = len(ui)
    index = np.full((H, W), -1, np.int64)
    index[ui, uj] = np.arange(n_u)
    starts = np.searchsorted(lab, np.arange(1, n_groups + 2))
    groups = [(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True) if b > a]
    diffs = sorted({(int(a[0] - b[0]), int(a[1] - b[1])) for o in offsets_all
                    for a in o for b in o} | {(0, 0)})
    slots = np.array(diffs, np.int64)
    slot_of = np.full((2 * reach2 + 1, 2 * reach2 + 1), -1, np.int64)
    slot_of[slots[:, 0] + reach2, slots[:, 1] + reach2] = np.arange(len(slots))
    # sorted and symmetric: the opposite of slot s is len - 1 - s; Q keeps
    # the slots from the centre on (the others are their transposes)
    centre = (len(slots) - 1) // 2
    del labels
    yield Progress("assembly", 0.0, "assembling")
    rows = np.stack(np.nonzero(grown), axis=1).astype(np.int64)  # raster order
    del grown
    if reuse is not None:
        at = reuse.index[ui, uj]
        if len(at) and at.min() < 0:
            raise ValueError("reuse must be the system of a superset of the unknown pixels.")
        Q, block_rows = reuse.blocks, reuse.block_rows[at]  # read in place, not copied
        probes = 0
    else:
        Q, block_rows = np.zeros((n_u, len(slots) - centre, C, C)), np.arange(n_u)
    rhs = np.zeros((n_u, C))
    z = np.zeros((n_u, probes, C))
    frame = np.ascontiguousarray(frame, np.float64)
    parts = [(a, min(a + _ASSEMBLE_ROWS, len(rows))) for a in range(0, len(rows), _ASSEMBLE_ROWS)]
    steps = sum(2 if r[4] is not None else 1 for r in row_sets) * len(parts) + 1
    done = 0
    for number, (offsets, coeffs, constant, extra, border) in enumerate(row_sets):
        coeffs = np.ascontiguousarray(coeffs, np.float64)
        constant = np.ascontiguousarray(constant, np.float64)
        extra = np.zeros((0, 0, C)) if extra is None else np.ascontiguousarray(extra, float)
        if border is None:
            bG, bc = np.zeros((0, 0, C, C)), np.zeros((0, 0, C))
        else:
            bG, bc = (np.ascontiguousarray(b, np.float64) for b in border)
        if reuse is None:
            pairs = np.ascontiguousarray(np.einsum("tukba,tulbc->tuklac", coeffs, coeffs))
        else:  # Q is known: the pairs are not read
            pairs = np.zeros((1, 1, *coeffs.shape[2:3] * 2, C, C))
        offsets = np.ascontiguousarray(offsets, np.int64)
        # xorshift64's state, seeded per set of rows, carried from part to part
        state = np.array([_seed_state(1 + 7919 * int(seed) + number)], np.uint64)
        for phase in (False, True) if border is not None else (False,):
            for a, b in parts:
                _assemble_kernel(frame, index, offsets, coeffs, pairs, constant, extra,
                                 int(tile), slot_of, reach2, rows[a:b], phase, bG, bc,
                                 int(probes), state, Q, rhs, z, reuse is None)
                done += 1
                yield Progress("assembly", done / steps, "assembling")
    pixels = np.stack([ui, uj], axis=1).astype(np.int64)
    return _System(slots, rhs, z, groups, pixels, Q[block_rows, 0], Q, block_rows, index)


def _group_batches(groups, C):
    """Consecutive groups batched into solves of about :data:`SOLVE_UNKNOWNS`
    unknowns (a group never split)."""
    batches, start, size = [], None, 0
    for a, b in groups:
        if start is None:
            start = a
        size += (b - a) * C
        if size >= SOLVE_UNKNOWNS:
            batches.append((start, b))
            start, size = None, 0
    if start is not None:
        batches.append((start, groups[-1][1]))
    return batches


@njit(cache=True, nogil=True)
def _block_column(Q, block_rows, pixels, index, slots, start, p, t):
    """The column pixel (numbered from ``start``) of pixel ``p``'s ``t``-th
    block from the centre of ``slots`` on (see :func:`_assemble_kernel`):
    -1 where no unknown pixel lies or the block is all zero (left out, as
    the sparse matrix leaves it out)."""
    H, W = index.shape
    s = (slots.shape[0] - 1) // 2 + t
    qi, qj = pixels[p, 0] + slots[s, 0], pixels[p, 1] + slots[s, 1]
    if qi < 0 or qi >= H or qj < 0 or qj >= W or index[qi, qj] < 0:
        return -1
    row = block_rows[p]
    for b in range(Q.shape[2]):
        for c in range(Q.shape[3]):
            if Q[row, t, b, c] != 0.0:
                return index[qi, qj] - start
    return -1


@njit(cache=True, nogil=True)
def _block_bandwidth(Q, block_rows, pixels, index, slots, start, stop):
    """The half-bandwidth (in unknowns, pixel-major) of ``Q`` over the pixels
    ``start`` to ``stop`` (whole groups): the largest column less row of an
    entry of its upper triangle, all-zero blocks left out."""
    C = Q.shape[2]
    width = C - 1  # the diagonal blocks
    for p in range(start, stop):
        for t in range(1, Q.shape[1]):
            q = _block_column(Q, block_rows, pixels, index, slots, start, p, t)
            if q >= 0:
                width = max(width, (q - (p - start)) * C + C - 1)
    return width


@njit(cache=True, nogil=True)
def _band_cholesky(Q, block_rows, pixels, index, slots, start, stop, width, right):
    """Solve ``Q x = right`` in place over the pixels ``start`` to ``stop``
    (whole groups) for ``Q`` of half-bandwidth ``width``, by the band
    Cholesky factorisation ``Q = L L^T``; returns False (``right`` partly
    changed) if ``Q`` is not numerically positive definite there.

    ``L`` is kept by columns, ``band[j, t] = L[j + t, j]``: each update of
    a column by an earlier one is then a contiguous multiply-add (which the
    compiler vectorises), not a dot product. The band is read straight from
    the blocks from the centre on (the upper triangle of the pixel-major
    rows: the columns of the lower one)."""
    C = Q.shape[2]
    n = (stop - start) * C
    band = np.zeros((n, width + 1))
    for p in range(start, stop):
        u0 = (p - start) * C
        row = block_rows[p]
        for t in range(Q.shape[1]):
            q = _block_column(Q, block_rows, pixels, index, slots, start, p, t)
            if q < 0:
                continue
            for a in range(C):
                for c in range(a if t == 0 else 0, C):  # the diagonal block's upper half
                    band[u0 + a, q * C + c - u0 - a] = Q[row, t, a, c]
    for j in range(n):
        column = band[j]
        for k in range(max(0, j - width), j):
            earlier = band[k]
            off = j - k
            f = earlier[off]  # L[j, k]
            if f == 0.0:
                continue
            for t in range(width + 1 - off):
                column[t] -= f * earlier[off + t]
        if not column[0] > 0.0:
            return False
        pivot = math.sqrt(column[0])
        column[0] = pivot
        for t in range(1, width + 1):
            column[t] /= pivot
    m = right.shape[1]
    for j in range(n):  # L y = right
        for s in range(m):
            right[j, s] /= band[j, 0]
        for t in range(1, min(width, n - 1 - j) + 1):
            f = band[j, t]
            for s in range(m):
                right[j + t, s] -= f * right[j, s]
    for j in range(n - 1, -1, -1):  # L^T x = y
        for t in range(1, min(width, n - 1 - j) + 1):
            f = band[j, t]
            for s in range(m):
                right[j, s] -= f * right[j + t, s]
        for s in range(m):
            right[j, s] /= band[j, 0]
    return True


def _batch_csc(system, a, b, C):
    """``Q`` over the pixels ``a`` to ``b`` (whole groups) as a sparse
    matrix, the unknowns numbered from ``a``: its CSR arrays, which are its
    CSC arrays (``Q`` is symmetric)."""
    n = b - a
    S = len(system.slots)
    indptr = np.zeros(n * C + 1, np.int64)
    found = np.empty((n, S), np.uint8 if S <= 256 else np.int64)
    found_n = np.empty(n, np.int64)
    args = (system.blocks, system.block_rows, system.pixels, system.index, system.slots)
    _csr_kernel(*args, indptr, np.zeros(0, np.int64), np.zeros(0), True, a, b, found, found_n)
    np.cumsum(indptr, out=indptr)
    # 32-bit indices when they fit, as SciPy and SuperLU keep them (no conversion)
    small = max(indptr[-1], n * C) < np.iinfo(np.int32).max
    indices = np.empty(indptr[-1], np.int32 if small else np.int64)
    data = np.empty(indptr[-1])
    _csr_kernel(*args, indptr, indices, data, False, a, b, found, found_n)
    return sparse.csc_matrix((data, indices, indptr.astype(indices.dtype)),
                             shape=(n * C, n * C))


def _solve_block(system, a, b, C):
    """Solve ``Q x = rhs`` and ``Q x_s = z_s`` over the pixels ``a`` to
    ``b`` (whole groups).

    A narrow band (a scratch: its pixels in raster order couple only with
    pixels a few rows away) is solved by a band Cholesky factorisation,
    3-5 times faster than SuperLU there; any other by SuperLU."""
    rhs, z = system.rhs, system.z
    right = rhs[a:b].reshape(-1, 1)
    if z.shape[1]:
        right = np.concatenate([right, z[a:b].transpose(0, 2, 1).reshape(-1, z.shape[1])],
                               axis=1)
    args = (system.blocks, system.block_rows, system.pixels, system.index, system.slots, a, b)
    x = None
    width = _block_bandwidth(*args)
    if width <= BAND_WIDTH:
        x = np.array(right, order="C")
        if not _band_cholesky(*args, width, x):
            x = None  # not positive definite in floating point: SuperLU pivots
    if x is None:
        lu = splu(_batch_csc(system, a, b, C), permc_spec="MMD_AT_PLUS_A",
                  diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        x = lu.solve(right)
    values = x[:, 0].reshape(-1, C)
    draws = x[:, 1:].reshape(b - a, C, -1).transpose(0, 2, 1)
    return values, draws


def _iter_solve(system, C, message):
    """Solve a :class:`_System` group batch by group batch, in threads (the
    factorisation releases the GIL), with a record every
    :data:`SOLVE_RECORD_SECONDS` while one runs: ``(values (n, d), draws (n,
    probes, d))``, draws of ``N(0, Q^-1)``."""
    n = system.rhs.shape[0]
    values = np.empty((n, C))
    draws = np.empty((n, system.z.shape[1], C))
    batches = _group_batches(system.groups, C)
    if len(batches) == 1 and (batches[0][1] - batches[0][0]) * C < SOLVE_UNKNOWNS:
        a, b = batches[0]  # small: no thread
        values[a:b], draws[a:b] = _solve_block(system, a, b, C)
        return values, draws
    pool = job_pool()
    done_pixels = 0
    if pool is None:  # one thread: the batches one after the other, a record after each
        for a, b in batches:
            values[a:b], draws[a:b] = _solve_block(system, a, b, C)
            done_pixels += b - a
            yield Progress("solve", done_pixels / max(n, 1), f"{message}, solving")
        return values, draws
    pending = {}
    try:
        pending = {pool.submit(_solve_block, system, a, b, C): (a, b) for a, b in batches}
        while pending:
            finished, _ = wait(pending, timeout=SOLVE_RECORD_SECONDS,
                               return_when=FIRST_COMPLETED)
            for future in finished:
                a, b = pending.pop(future)
                values[a:b], draws[a:b] = future.result()
                done_pixels += b - a
            yield Progress("solve", done_pixels / max(n, 1), f"{message}, solving")
    finally:  # a Cancel: the batches not started are dropped, a running one finishes
        for future in pending:
            future.cancel()
    return values, draws


def iter_stencil_solve(frame, unknown, row_sets, tile, *, probes=0, seed=0,
                       message="frame"):
    """:func:`stencil_solve` as a job (records while the solves run), with
    ``probes`` draws of the conditional distribution's fluctuation: returns
    ``(values, draws, diagonal)``, (n, d), (n, probes, d) and (n, d, d) in
    ``np.nonzero(unknown)`` order: the draws have covariance ``Q_UU^-1``;
    ``diagonal`` is the diagonal blocks of ``Q_UU``."""
    values, draws, diagonal, _ = yield from _iter_stencil_system(
        frame, unknown, row_sets, tile, probes=probes, seed=seed, message=message)
    return values, draws, diagonal


def _iter_stencil_system(frame, unknown, row_sets, tile, *, probes=0, seed=0,
                         message="frame", reuse=None):
    """:func:`iter_stencil_solve`, returning its :class:`_System` too;
    ``reuse``: see :func:`_iter_assemble`."""
    C = frame.shape[2]
    system = yield from stage(_iter_assemble(frame, unknown, row_sets, tile, probes=probes,
                                             seed=seed, reuse=reuse), 0.0, 0.3,
                              name="solve", prefix=f"{message}, ")
    yield Progress("solve", 0.3, f"{message}, solving")
    values, draws = yield from stage(_iter_solve(system, C, message), 0.3, 1.0)
    ui, uj = np.nonzero(unknown)
    order = np.full(unknown.shape, -1, np.int64)
    order[system.pixels[:, 0], system.pixels[:, 1]] = np.arange(len(system.pixels))
    at = order[ui, uj]
    return values[at], draws[at], system.diagonal[at], system


def stencil_solve(frame, unknown, row_sets, tile):
    """Least-squares values of the ``unknown`` pixels for residual rows
    ``w_r = sum_k coeffs[t, k] Y_{r - offsets[k]} + constant[t] (+ extra[r])``.

    ``row_sets``: a list of ``(offsets, coeffs, constant, extra, border)``:
    ``coeffs`` (ty, tx, K, d, d), ``constant`` (ty, tx, d), ``t`` the tile of
    ``r``; rows are every ``r`` with all taps in the frame and at least one
    tap unknown. ``extra`` (H, W, d) or None. ``border``: ``(G, c)``, (ty,
    tx, d, d) and (ty, tx, d), the row ``G Y_r + c`` of an unknown pixel that
    has no full row, or None. Returns the (n_unknown, d) values in
    ``np.nonzero(unknown)`` order: ``x = -(M^T M)^-1 M^T c``. The normal
    equations ``Q_UU = M^T M`` are assembled row by row (a compiled kernel)
    and solved per batch of coupled groups of unknown pixels (``Q_UU`` is
    block diagonal over them): by a band Cholesky factorisation where the
    batch's band is narrow (scratches), else by a sparse LU factorisation
    (SuperLU)."""
    return drain(iter_stencil_solve(frame, unknown, row_sets, tile))[0]


def _row_set(model, previous, where=None, taps=None):
    """The rows of :func:`stencil_solve` of one :class:`LocalModels`;
    ``where`` (H, W) bool: the pixels whose previous-frame term is wanted
    (None: all); ``taps``: see :func:`_previous_term`."""
    offsets, coeffs, constant, border, Linv = model_rows(model)
    extra = None if previous is None else _previous_term(model, previous, Linv, where, taps)
    return offsets, coeffs, constant, extra, border


def _row_sets(models, previous):
    """:func:`_row_set` of each of ``models``, the previous-frame term at every pixel."""
    return [_row_set(model, previous) for model in models]


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


def model_rows(models):
    """The whitened row coefficients of :func:`stencil_solve` for ``models``:
    ``(offsets with (0, 0) first, coeffs, constant, border)``."""
    ty, tx, C, _ = models.sigma.shape
    eta = len(models.offsets)
    Linv = _inv_chol(models.sigma)  # (ty, tx, d, d)
    A = models.gamma[..., : C * eta].reshape(ty, tx, C, eta, C).transpose(0, 1, 3, 2, 4)
    coeffs = np.concatenate([Linv[:, :, None], -np.einsum("tuab,tukbc->tukac", Linv, A)],
                            axis=2)
    constant = -np.einsum("tukab,tub->tua", coeffs, models.mean)
    offsets = np.concatenate([np.zeros((1, 2), np.int64), models.offsets])
    Lm = _inv_chol(models.marginal)
    border = (Lm, -np.einsum("tuab,tub->tua", Lm, models.mean))
    return offsets, coeffs, constant, border, Linv


def _previous_taps(models, previous, where=None):
    """The pixels ``where`` (H, W) bool (None: all) and the previous frame at
    each of their :data:`PREVIOUS_OFFSETS` (0 outside the frame) less the
    tile's previous-frame mean: ``(ii, jj, [(n, d)] * 5)``. The models of
    the scan directions share the mean, so they share these."""
    H, W, C = previous.shape
    if where is None:
        ii, jj = (a.ravel() for a in np.indices((H, W)))
    else:
        ii, jj = np.nonzero(where)
    pmean = models.previous_mean[ii // models.tile, jj // models.tile]
    centred = []
    for di, dj in PREVIOUS_OFFSETS:
        si, sj = ii - di, jj - dj
        inside = (si >= 0) & (si < H) & (sj >= 0) & (sj < W)
        shifted = np.zeros((len(ii), C))  # 0 outside the frame
        shifted[inside] = previous[si[inside], sj[inside]]
        shifted -= pmean
        centred.append(shifted)
    return ii, jj, centred


def _previous_term(models, previous, Linv, where=None, taps=None):
    """``extra[r]``: the whitened contribution of the previous frame to row
    ``r``, at the pixels ``where`` (H, W) bool (None: all; elsewhere 0). A
    solve reads it only at the rows near the damage, a small part of the
    frame: the others are not computed. ``taps``: :func:`_previous_taps`
    of these pixels, if made already (models with the same previous-frame
    mean)."""
    H, W, C = previous.shape
    tile = models.tile
    eta = len(models.offsets)
    ii, jj, centred = _previous_taps(models, previous, where) if taps is None else taps
    ti, tj = ii // tile, jj // tile
    total = np.zeros((len(ii), C))
    for k, shifted in enumerate(centred):
        B = models.gamma[..., (eta + k) * C : (eta + k + 1) * C]  # (ty, tx, d, d)
        G = -np.einsum("tuab,tubc->tuac", Linv, B)[ti, tj]  # (n, d, d)
        total += np.einsum("nab,nb->na", G, shifted)
    out = np.zeros((H, W, C))
    out[ii, jj] = total
    return out


def conditional_mean(frame, unknown, models, *, previous=None):
    """The conditional mean of the ``unknown`` pixels of ``frame`` (H, W, d)
    given the others under ``models`` (a :class:`LocalModels`, or a list of
    them: the product of their densities); (n, d) in ``np.nonzero(unknown)``
    order."""
    if isinstance(models, LocalModels):
        models = [models]
    return stencil_solve(frame, unknown, _row_sets(models, previous), models[0].tile)


def _tiles_needed(unknown, offsets, tile):
    """Tiles holding a row that touches an unknown pixel."""
    H, W = unknown.shape
    reach = int(np.abs(offsets).max()) if len(offsets) else 0
    near = _dilate(unknown, reach) if reach else unknown
    ty, tx = -(-H // tile), -(-W // tile)
    need = np.zeros((ty, tx), bool)
    ii, jj = np.nonzero(near)
    need[ii // tile, jj // tile] = True
    return need


def direction_offsets(offsets, direction):
    """The causal ``offsets`` of the downward scan as seen by another scan
    (SPEC 1.1): ``up`` mirrors the rows, ``right`` and ``left`` transpose."""
    di, dj = offsets[:, 0], offsets[:, 1]
    return {"down": np.c_[di, dj], "up": np.c_[-di, dj], "right": np.c_[dj, di],
            "left": np.c_[dj, -di]}[direction].astype(np.int64)


def iter_fill_conditional(frame, mask, *, order=3, directions=DIRECTIONS, previous=None,
                          tile=DEFAULT_TILE, margin=DEFAULT_MARGIN, halo=None, halo_rings=1,
                          halo_blend=HALO_BLEND, halo_region_blend=HALO_REGION_BLEND,
                          halo_unblend=HALO_UNBLEND, probes=EDGE_PROBES, fill_range="known",
                          message="frame"):
    """Conditional-mean fill of ``mask`` in the (H, W, d) float ``frame``, as
    a job: Progress records (stage ``"frames"``), then the (n_missing, d)
    values in ``np.nonzero(mask)`` order.

    ``directions``: one local model per scan direction (SPEC 1.1), their
    densities multiplied (the precision is the sum of theirs). ``halo``: a
    log density ratio <= 0 (None: no edge test). A known pixel bordering the
    damage is treated as damaged when, with it and the damage predicted from
    the rest, it is blended towards the damage by more than ``halo_blend``
    and ``-chi2 / 2 < halo`` under its joint predictive covariance
    (estimated from ``probes`` draws; see :func:`edge_statistics`), and the
    ring within :data:`EDGE_REGION` pixels, pooled, by more than
    ``halo_region_blend`` (a fringe, not a lone edge of the scene); then the
    next ring is tested, up to ``halo_rings`` rings. ``halo_unblend``: None
    (such pixels join the unknowns) or a fraction ``f``: they stay known, less
    ``f`` times their estimated blend ``alpha D``. ``fill_range``: (lo,
    hi) per channel, "known" (the known pixels' range) or None.

    The work goes in short steps, a record after each: the statistics of
    the local models by bands of blocks, the sparse solves by batches of
    coupled groups of pixels (run in threads, a record every
    :data:`SOLVE_RECORD_SECONDS` while one runs)."""
    base = causal_neighbourhood(order) if np.ndim(order) == 0 else np.asarray(order)
    preparing = f"{message}, preparing"
    rings = halo_rings if halo is not None else 0
    steps = 2 + rings
    prepared = 0.02 / steps  # the share of the work before the fit
    if isinstance(fill_range, str):
        fill_range = yield from stage(_iter_known_range(frame, ~mask, preparing), 0.0,
                                      prepared / 2, name="frames")
    # the fit leaves out the ring around the damage: soft edges stay out of the model
    fit_out = _dilate(mask, 1)
    yield Progress("frames", 0.7 * prepared, preparing)
    near = _dilate(mask, 1 + rings)
    yield Progress("frames", 0.8 * prepared, preparing)
    need = _tiles_needed(near, np.vstack([base, -base, base[:, ::-1], -base[:, ::-1]]), tile)
    rows_near = None  # the rows the solves visit: within the models' reach of ``near``
    if previous is not None:
        rows_near = _dilate(near, int(np.abs(base).max()), square=True)
    del near
    yield Progress("frames", prepared, preparing)
    models = yield from stage(
        iter_fit_local_models(frame, fit_out, [direction_offsets(base, d) for d in directions],
                              previous=previous, tile=tile, margin=margin, need=need),
        prepared, 1 / steps, name="frames", prefix=f"{message}, ")
    yield Progress("frames", 1 / steps, f"{message}, models fitted")
    row_sets = []
    taps = None  # the previous frame's taps, shared by models with one previous-frame mean
    if previous is not None and all(m.previous_mean is models[0].previous_mean
                                    for m in models):
        taps = _previous_taps(models[0], previous, rows_near)
    for model in models:
        row_sets.append(_row_set(model, previous, rows_near, taps))
        yield Progress("frames", 1 / steps, f"{message}, models fitted")
    damage = mask.copy()
    known = frame  # the known pixels' values, unblended (a copy) where called damaged
    tested = None  # the last edge test's system: the damage is a part of its unknowns
    for ring_number in range(rings):
        ring = _dilate(damage, 1) & ~damage
        if not ring.any():
            break
        both = damage | ring
        values, draws, diagonal, tested = yield from stage(
            _iter_stencil_system(frame, both, row_sets, tile, probes=probes,
                                 seed=ring_number, message=message),
            (1 + ring_number) / steps, (2 + ring_number) / steps, name="frames")
        trial = frame.copy()
        trial[both] = values
        on_ring = ring[both]
        yield Progress("frames", (2 + ring_number) / steps, f"{message}, edge test")
        edge = yield from stage(
            iter_edge_statistics(frame, trial, damage, ring, draws[on_ring], diagonal[on_ring]),
            (2 + ring_number) / steps, (2 + ring_number) / steps, name="frames",
            prefix=f"{message}, ")
        del trial
        bad = (edge.alpha > halo_blend) & (-0.5 * edge.chi2 < halo) \
            & (edge.pooled > halo_region_blend)
        yield Progress("frames", (2 + ring_number) / steps, f"{message}, edge test")
        if not bad.any():
            break
        bi, bj = np.nonzero(ring)
        damage[bi[bad], bj[bad]] = True
        if halo_unblend is not None:
            if known is frame:
                known = frame.copy()
            known[bi[bad], bj[bad]] -= halo_unblend * edge.alpha[bad, None] \
                * edge.deviation[bad]
    unknown = damage if halo_unblend is None else mask
    values, _, _, _ = yield from stage(
        _iter_stencil_system(known, unknown, row_sets, tile, message=message, reuse=tested),
        (steps - 1) / steps, 1.0, name="frames")
    del tested
    ui, uj = np.nonzero(unknown)
    values = values[mask[ui, uj]]
    if fill_range is not None:
        values = np.clip(values, fill_range[0], fill_range[1])
    return values


def fill_conditional(frame, mask, **options):
    """:func:`iter_fill_conditional` run to its end."""
    return drain(iter_fill_conditional(frame, mask, **options))
