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

The parts live in their own modules: the local fits (:mod:`._local_fits`),
the sparse assembly (:mod:`._stencil`), the solves (:mod:`._solver`) and the
edge test's statistics (:mod:`._edges`); this module fills a frame with them.
"""

from __future__ import annotations

import numpy as np

from .._progress import Progress, drain, stage
from ..model.neighbourhood import causal_neighbourhood
from ._edges import EDGE_PROBES, iter_edge_statistics
from ._local_fits import (
    DEFAULT_MARGIN,
    DEFAULT_TILE,
    LocalModels,
    _dilate,
    _iter_known_range,
    _previous_taps,
    _row_set,
    _row_sets,
    iter_fit_local_models,
)
from ._solver import _iter_stencil_system, stencil_solve

__all__ = ["DIRECTIONS", "conditional_mean", "direction_offsets", "fill_conditional",
           "iter_fill_conditional"]

DIRECTIONS = ("down", "up", "right", "left")
HALO_BLEND = 0.1  # the least blend towards the damage the edge test calls damage
# Soft-edged damage leaves a fringe all along its border, hard-edged none: a
# ring pixel is called damaged only where the blend pooled over the ring
# within EDGE_REGION pixels (._edges) also exceeds HALO_REGION_BLEND.
HALO_REGION_BLEND = 0.05
HALO_UNBLEND = 0.5  # a pixel called damaged stays known, less half its blend (see _filling)


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
