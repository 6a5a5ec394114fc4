"""Local CAR models of a frame for the conditional mean (:mod:`._conditional`):
one model per tile, fitted on a window around it from the known pixels, and
the whitened residual rows they give (:func:`model_rows`, :func:`_row_sets`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .._progress import Progress, Span, drain, row_blocks

__all__ = ["DEFAULT_MARGIN", "DEFAULT_TILE", "LocalModels", "PREVIOUS_OFFSETS",
           "fit_local_models", "iter_fit_local_models", "model_rows"]

DEFAULT_TILE = 48  # pixels: each tile has its own model
DEFAULT_MARGIN = 16  # pixels around a tile in its fitting window
_MIN_ROWS_PER_REGRESSOR = 4  # a window with fewer fitting pixels grows
_PRIOR = 1e-3  # V_0 = _PRIOR * variance * I per regressor: a light ridge
# The statistics of the fit go by bands of blocks of about _FIT_RECORD_PIXELS
# pixels, a record between them.
_FIT_RECORD_PIXELS = 1 << 16
_ESTIMATE_TILES = 512  # tiles' models estimated between records
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


def _fit_bands(H, W):
    """The bands of rows of the passes over the known pixels."""
    return row_blocks(H, _FIT_RECORD_PIXELS * 16 // max(W, 1))


def _iter_fold_known_bands(frame, known, fold, total, message, span=None):
    """``total = fold(total, values)`` over the known pixels of ``frame``
    (H, W, d) by bands of rows (``values`` (n, d) a band's, in raster
    order: no copy of all the known pixels at once), as a job: a record
    after each band (fractions over the :class:`~car_napari._progress.Span`
    ``span``, default all of [0, 1]), then the last ``total``."""
    span = Span(0.0, 1.0) if span is None else span
    H, W = known.shape
    for r0, r1 in _fit_bands(H, W):
        total = fold(total, frame[r0:r1][known[r0:r1]])
        yield Progress("fit", span.at(r1, H), message)
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
        for r0, r1 in _fit_bands(H, W):
            _known_range_kernel(frame, known, r0, r1, lo, hi)
            yield Progress("fit", r1 / H, message)
        return lo, hi

    def widen(bounds, values):
        if not len(values):
            return bounds
        return np.minimum(bounds[0], values.min(axis=0)), np.maximum(bounds[1], values.max(axis=0))

    return (yield from _iter_fold_known_bands(frame, known, widen, (lo, hi), message))


def _iter_known_variance(frame, known, message, fraction):
    """The variance per channel of the known pixels (two passes: the mean,
    then the centred squares), as a job."""
    H, W, C = frame.shape
    if _compiled_sums(frame):  # the same sums, without copies of the known pixels
        bands = _fit_bands(H, W)
        n, total = 0, np.zeros(C)
        for r0, r1 in bands:
            part, count = _known_sums_kernel(frame, known, r0, r1, total, False)
            n += count
            total += part
            yield Progress("fit", fraction, message)
        mean = total / max(n, 1)
        squares = np.zeros(C)
        for r0, r1 in bands:
            squares += _known_sums_kernel(frame, known, r0, r1, mean, True)[0]
            yield Progress("fit", fraction, message)
        return squares / max(n, 1)
    n, total = yield from _iter_fold_known_bands(
        frame, known, lambda acc, values: (acc[0] + len(values), acc[1] + values.sum(axis=0)),
        (0, np.zeros(C)), message, Span(fraction, fraction))
    mean = total / max(n, 1)
    squares = yield from _iter_fold_known_bands(
        frame, known, lambda acc, values: acc + ((values - mean) ** 2).sum(axis=0),
        np.zeros(C), message, Span(fraction, fraction))
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
        for k, part in row_blocks(flat.shape[2], step):
            _window_sums_kernel(flat, corner_rows, a0, a1, b0, b1, k, part, out)
            yield Progress("fit", Span(start, stop).at(part, flat.shape[2]), "fitting")
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
    each of their :data:`PREVIOUS_OFFSETS` less the tile's previous-frame
    mean: ``(ii, jj, [(n, d)] * 5)``. A tap outside the frame repeats the
    frame's edge pixel: the previous frame is known data, so a row at the
    edge keeps its pixel's link to it (0 there pulled edge fills towards
    ``-B mu_p``: up to 174 grey levels off). The models of the scan
    directions share the mean, so they share these."""
    H, W, _ = previous.shape
    if where is None:
        ii, jj = (a.ravel() for a in np.indices((H, W)))
    else:
        ii, jj = np.nonzero(where)
    pmean = models.previous_mean[ii // models.tile, jj // models.tile]
    centred = []
    for di, dj in PREVIOUS_OFFSETS:
        si, sj = np.clip(ii - di, 0, H - 1), np.clip(jj - dj, 0, W - 1)
        centred.append(previous[si, sj] - pmean)
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
