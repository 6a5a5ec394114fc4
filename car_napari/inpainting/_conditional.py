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

from typing import NamedTuple

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.linalg import splu

from .._progress import Progress, drain
from ..model.neighbourhood import causal_neighbourhood
from ..model.statistics import estimate_parameters

__all__ = ["DIRECTIONS", "LocalModels", "conditional_mean", "direction_offsets",
           "fill_conditional", "fit_local_models", "iter_fill_conditional", "stencil_solve"]

DEFAULT_TILE = 48  # pixels: each tile has its own model
DEFAULT_MARGIN = 16  # pixels around a tile in its fitting window
_MIN_ROWS_PER_REGRESSOR = 4  # a window with fewer fitting pixels grows
_PRIOR = 1e-3  # V_0 = _PRIOR * variance * I per regressor: a light ridge
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
DIRECTIONS = ("down", "up", "right", "left")
HALO_BLEND = 0.1  # the least blend towards the damage the edge test calls damage
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


def _inside(shape, offsets):
    """Pixels ``r`` whose every ``r - s`` lies in the frame."""
    H, W = shape
    di, dj = offsets[:, 0], offsets[:, 1]
    rows = np.arange(H)[:, None]
    cols = np.arange(W)[None, :]
    return ((rows >= di.max()) & (rows < H + di.min())
            & (cols >= dj.max()) & (cols < W + dj.min()))


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
    H, W, C = frame.shape
    offset_sets = [np.asarray(o, np.int64) for o in offset_sets]
    n_prev = 0 if previous is None else len(PREVIOUS_OFFSETS)
    union = sorted({(int(di), int(dj)) for o in offset_sets for di, dj in o} - {(0, 0)})
    taps = np.array([(0, 0)] + union, np.int64)  # the centre first
    where = {tuple(t): k for k, t in enumerate(taps.tolist())}
    reach = int(np.abs(np.vstack([taps, PREVIOUS_OFFSETS])).max())
    ty, tx = -(-H // tile), -(-W // tile)
    if need is None:
        need = np.ones((ty, tx), bool)
    known = ~unknown
    ok = known & _inside((H, W), taps)
    for di, dj in taps[1:]:
        ok &= _shifted(known, di, dj, False)
    if previous is not None:
        ok &= _inside((H, W), PREVIOUS_OFFSETS)
    padded = np.pad(frame, ((reach, reach), (reach, reach), (0, 0)))
    ppad = None if previous is None else np.pad(previous, ((reach, reach), (reach, reach),
                                                           (0, 0)))
    n_cols = C * (len(taps) + n_prev)
    results = []
    for o in offset_sets:
        m = C * (len(o) + n_prev)
        eye = np.broadcast_to(np.eye(C), (ty, tx, C, C))
        results.append(dict(gamma=np.zeros((ty, tx, C, m)), sigma=eye.copy(),
                            marginal=eye.copy()))
    mean = np.zeros((ty, tx, C))
    pmean = None if previous is None else np.zeros((ty, tx, C))
    overall_var = frame[known].var(axis=0) + 1e-12
    ridge = np.diag(1e-6 * overall_var)
    m_max = max(C * (len(o) + n_prev) for o in offset_sets)
    for a, b in zip(*np.nonzero(need), strict=True):
        grow = margin
        while True:
            i0, i1 = max(a * tile - grow, 0), min((a + 1) * tile + grow, H)
            j0, j1 = max(b * tile - grow, 0), min((b + 1) * tile + grow, W)
            win = ok[i0:i1, j0:j1]
            n = int(np.count_nonzero(win))
            whole = i0 == 0 and j0 == 0 and i1 == H and j1 == W
            if n >= _MIN_ROWS_PER_REGRESSOR * (m_max + 1) or whole:
                break
            grow *= 2
        if n < 2:
            continue
        Z = np.empty((n, n_cols))
        for k, (di, dj) in enumerate(taps):
            Z[:, k * C : (k + 1) * C] = padded[i0 + reach - di : i1 + reach - di,
                                               j0 + reach - dj : j1 + reach - dj][win]
        for k, (di, dj) in enumerate(PREVIOUS_OFFSETS[:n_prev]):
            c0 = (len(taps) + k) * C
            Z[:, c0 : c0 + C] = ppad[i0 + reach - di : i1 + reach - di,
                                     j0 + reach - dj : j1 + reach - dj][win]
        mu = Z[:, :C].mean(axis=0)
        mean[a, b] = mu
        centre = np.tile(mu, len(taps))
        Z[:, : C * len(taps)] -= centre
        if n_prev:
            pmu = Z[:, len(taps) * C : (len(taps) + 1) * C].mean(axis=0)
            pmean[a, b] = pmu
            Z[:, len(taps) * C :] -= np.tile(pmu, n_prev)
        V = Z.T @ Z
        marginal = V[:C, :C] / n + ridge
        scale = float(np.trace(marginal)) / C
        for o, res in zip(offset_sets, results, strict=True):
            cols = [c for di, dj in o for c in range(where[(int(di), int(dj))] * C,
                                                      where[(int(di), int(dj))] * C + C)]
            cols += list(range(len(taps) * C, n_cols))  # the previous frame's taps
            m = len(cols)
            res["marginal"][a, b] = marginal
            if n < m + 2:  # no texture to learn: independent pixels around the mean
                res["sigma"][a, b] = marginal
                continue
            order = cols + list(range(C))
            Vd = V[np.ix_(order, order)]
            est = estimate_parameters(Vd, n, m, C, np.full(m + C, prior * scale * n / n))
            res["gamma"][a, b] = est.gamma
            res["sigma"][a, b] = est.lam / max(n - m, 1) + ridge
    return [LocalModels(tile, o, r["gamma"], r["sigma"], mean, pmean, r["marginal"])
            for o, r in zip(offset_sets, results, strict=True)]


def _inv_chol(S):
    """``L^-1`` for ``S = L L^T``, batched over leading axes."""
    L = np.linalg.cholesky(S)
    eye = np.broadcast_to(np.eye(S.shape[-1]), S.shape)
    return np.linalg.solve(L, eye)


def _rows(frame, unknown, index, offsets, coeffs, constant, tile, extra, border, first):
    """COO pieces and constants of one set of rows (see :func:`stencil_solve`)."""
    H, W, C = frame.shape
    offsets = np.asarray(offsets, np.int64)
    inside = _inside((H, W), offsets)
    touches = np.zeros((H, W), bool)
    for di, dj in offsets:
        touches |= _shifted(unknown, di, dj, False)  # r - s unknown <=> r in U + s
    ri, rj = np.nonzero(touches & inside)
    n_r = len(ri)
    t_i, t_j = ri // tile, rj // tile
    const = constant[t_i, t_j].copy()  # (n_r, d)
    if extra is not None:
        const += extra[ri, rj]
    data, row_ids, col_ids = [], [], []
    known_frame = np.where(unknown[..., None], 0.0, frame)
    block_r = (first + np.arange(n_r))[:, None, None] * C + np.arange(C)[None, :, None]
    for k, (di, dj) in enumerate(offsets):
        G = coeffs[t_i, t_j, k]  # (n_r, d, d)
        pi, pj = ri - di, rj - dj
        const += np.einsum("nab,nb->na", G, known_frame[pi, pj])
        col = index[pi, pj]
        hit = col >= 0
        if hit.any():
            cols = col[hit][:, None, None] * C + np.arange(C)[None, None, :]
            data.append(G[hit].ravel())
            row_ids.append(np.broadcast_to(block_r[hit], (hit.sum(), C, C)).ravel())
            col_ids.append(np.broadcast_to(cols, (hit.sum(), C, C)).ravel())
    lone = unknown & ~inside
    if border is not None and lone.any():
        G_b, c_b = border
        bi, bj = np.nonzero(lone)
        n_b = len(bi)
        G = G_b[bi // tile, bj // tile]
        const = np.concatenate([const, c_b[bi // tile, bj // tile]])
        rb = (first + n_r + np.arange(n_b))[:, None, None] * C + np.arange(C)[None, :, None]
        cb = index[bi, bj][:, None, None] * C + np.arange(C)[None, None, :]
        data.append(G.ravel())
        row_ids.append(np.broadcast_to(rb, (n_b, C, C)).ravel())
        col_ids.append(np.broadcast_to(cb, (n_b, C, C)).ravel())
    return data, row_ids, col_ids, const


def _system(frame, unknown, row_sets, tile):
    """The stacked whitened rows ``w = M y_U + c`` touching ``unknown``."""
    H, W, C = frame.shape
    n_u = int(unknown.sum())
    index = np.full((H, W), -1, np.int64)
    index[unknown] = np.arange(n_u)
    data, row_ids, col_ids, consts = [], [], [], []
    first = 0
    for offsets, coeffs, constant, extra, border in row_sets:
        d, r, c, const = _rows(frame, unknown, index, offsets, coeffs, constant, tile,
                               extra, border, first)
        data += d
        row_ids += r
        col_ids += c
        consts.append(const)
        first += len(const)
    const = np.concatenate(consts)
    M = sparse.csr_matrix((np.concatenate(data), (np.concatenate(row_ids),
                                                  np.concatenate(col_ids))),
                          shape=(first * C, n_u * C))
    return M, const.ravel()


def stencil_solve(frame, unknown, row_sets, tile):
    """Least-squares values of the ``unknown`` pixels for residual rows
    ``w_r = sum_k coeffs[t, k] Y_{r - offsets[k]} + constant[t] (+ extra[r])``.

    ``row_sets``: a list of ``(offsets, coeffs, constant, extra, border)``:
    ``coeffs`` (ty, tx, K, d, d), ``constant`` (ty, tx, d), ``t`` the tile of
    ``r``; rows are every ``r`` with all taps in the frame and at least one
    tap unknown. ``extra`` (H, W, d) or None. ``border``: ``(G, c)``, (ty,
    tx, d, d) and (ty, tx, d), the row ``G Y_r + c`` of an unknown pixel that
    has no full row, or None. Returns the (n_unknown, d) values in
    ``np.nonzero(unknown)`` order: ``x = -(M^T M)^-1 M^T c``, by a sparse LU
    factorisation (SuperLU) of ``Q_UU = M^T M``."""
    C = frame.shape[2]
    M, const = _system(frame, unknown, row_sets, tile)
    Q = (M.T @ M).tocsc()
    rhs = -(M.T @ const)
    x = splu(Q, permc_spec="COLAMD").solve(rhs)
    return x.reshape(-1, C)


def _row_sets(frame, models, previous):
    row_sets = []
    for model in models:
        offsets, coeffs, constant, border, Linv = model_rows(model)
        extra = None if previous is None else _previous_term(model, previous, Linv)
        row_sets.append((offsets, coeffs, constant, extra, border))
    return row_sets


def edge_statistics(frame, trial, damage, ring, Linv, tile):
    """The edge test's statistics of the ``ring`` pixels (known, bordering the
    ``damage``): ``(alpha, chi2)`` per ring pixel in ``np.nonzero(ring)`` order.

    ``trial`` is the frame with the damage and the ring both replaced by
    their conditional mean given the rest, so that neither sees the other.
    Soft-edged damage blends a ring pixel towards the damage: ``y_b = E_b +
    alpha D_b + e`` with ``E_b`` its prediction and ``D_b`` the damage's
    deviation from its prediction (mean over the pixel's 4-neighbours in the
    damage). ``alpha`` is the least-squares blend under the tile's
    innovation covariance ``L L^T`` and ``chi2 = (D^T S^-1 e)^2 / (D^T S^-1 D)``
    its generalised-likelihood statistic (chi-square with 1 degree of
    freedom for a clean pixel when ``S`` is its predictive covariance)."""
    H, W, C = frame.shape
    bi, bj = np.nonzero(ring)
    deviation = np.where(damage[..., None], frame - trial, 0.0)
    count = np.zeros((H, W))
    total = np.zeros((H, W, C))
    for di, dj in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        count += _shifted(damage.astype(float), di, dj, 0.0)
        total += np.stack([_shifted(deviation[..., c], di, dj, 0.0) for c in range(C)], -1)
    D = total[bi, bj] / np.maximum(count[bi, bj], 1)[:, None]
    G = Linv[bi // tile, bj // tile]
    wD = np.einsum("nab,nb->na", G, D)
    we = np.einsum("nab,nb->na", G, frame[bi, bj] - trial[bi, bj])
    dqd = np.maximum((wD * wD).sum(axis=1), 1e-300)
    proj = (wD * we).sum(axis=1)
    return proj / dqd, proj**2 / dqd


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


def _previous_term(models, previous, Linv):
    """``extra[r]``: the whitened contribution of the previous frame to row ``r``."""
    H, W, C = previous.shape
    tile = models.tile
    eta = len(models.offsets)
    rows, cols = np.arange(H) // tile, np.arange(W) // tile
    out = np.zeros((H, W, C))
    for k, (di, dj) in enumerate(PREVIOUS_OFFSETS):
        B = models.gamma[..., (eta + k) * C : (eta + k + 1) * C]  # (ty, tx, d, d)
        G = -np.einsum("tuab,tubc->tuac", Linv, B)[rows][:, cols]  # (H, W, d, d)
        shifted = np.stack([_shifted(previous[..., c], di, dj, 0.0) for c in range(C)], -1)
        shifted -= models.previous_mean[rows][:, cols]
        out += np.einsum("hwab,hwb->hwa", G, shifted)
    return out


def conditional_mean(frame, unknown, models, *, previous=None):
    """The conditional mean of the ``unknown`` pixels of ``frame`` (H, W, d)
    given the others under ``models`` (a :class:`LocalModels`, or a list of
    them: the product of their densities); (n, d) in ``np.nonzero(unknown)``
    order."""
    if isinstance(models, LocalModels):
        models = [models]
    return stencil_solve(frame, unknown, _row_sets(frame, models, previous), models[0].tile)


def _tiles_needed(unknown, offsets, tile):
    """Tiles holding a row that touches an unknown pixel."""
    H, W = unknown.shape
    reach = int(np.abs(offsets).max()) if len(offsets) else 0
    near = ndimage.binary_dilation(unknown, iterations=reach) if reach else unknown
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
                          halo_blend=HALO_BLEND, fill_range="known", message="frame"):
    """Conditional-mean fill of ``mask`` in the (H, W, d) float ``frame``, as
    a job: Progress records (stage ``"frames"``), then the (n_missing, d)
    values in ``np.nonzero(mask)`` order.

    ``directions``: one local model per scan direction (SPEC 1.1), their
    densities multiplied (the precision is the sum of theirs). ``halo``: a
    log density ratio <= 0 (None: no edge test). A known pixel bordering the
    damage is treated as damaged when, with it and the damage predicted from
    the rest, it is blended towards the damage by more than ``halo_blend``
    and ``-chi2 / 2 < halo`` (see :func:`edge_statistics`); then the next
    ring is tested, up to ``halo_rings`` rings. ``fill_range``: (lo, hi) per
    channel, "known" (the known pixels' range) or None."""
    base = causal_neighbourhood(order) if np.ndim(order) == 0 else np.asarray(order)
    if isinstance(fill_range, str):
        known_values = frame[~mask]
        fill_range = known_values.min(axis=0), known_values.max(axis=0)
    # the fit leaves out the ring around the damage: soft edges stay out of the model
    fit_out = ndimage.binary_dilation(mask, structure=_CROSS)
    rings = halo_rings if halo is not None else 0
    need = _tiles_needed(ndimage.binary_dilation(mask, structure=_CROSS, iterations=1 + rings),
                         np.vstack([base, -base, base[:, ::-1], -base[:, ::-1]]), tile)
    models = fit_local_models(frame, fit_out, [direction_offsets(base, d) for d in directions],
                              previous=previous, tile=tile, margin=margin, need=need)
    steps = 2 + rings
    yield Progress("frames", 1 / steps, f"{message}, models fitted")
    row_sets = _row_sets(frame, models, previous)
    Linv = _inv_chol(models[0].sigma)
    damage = mask.copy()
    for ring_number in range(rings):
        ring = ndimage.binary_dilation(damage, structure=_CROSS) & ~damage
        if not ring.any():
            break
        both = damage | ring
        trial = frame.copy()
        trial[both] = stencil_solve(frame, both, row_sets, tile)
        alpha, chi2 = edge_statistics(frame, trial, damage, ring, Linv, tile)
        bad = (alpha > halo_blend) & (-0.5 * chi2 < halo)
        yield Progress("frames", (2 + ring_number) / steps, f"{message}, edge test")
        if not bad.any():
            break
        bi, bj = np.nonzero(ring)
        damage[bi[bad], bj[bad]] = True
    values = stencil_solve(frame, damage, row_sets, tile)
    ui, uj = np.nonzero(damage)
    values = values[mask[ui, uj]]
    if fill_range is not None:
        values = np.clip(values, fill_range[0], fill_range[1])
    return values


def fill_conditional(frame, mask, **options):
    """:func:`iter_fill_conditional` run to its end."""
    return drain(iter_fill_conditional(frame, mask, **options))
