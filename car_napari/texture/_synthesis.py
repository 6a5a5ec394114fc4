"""Synthesis of a :class:`~car_napari.texture.TextureModel`: every band's
field, its tiling (for tileable textures) and histogram matching, the
collapse, the restore of the input's mean, contrast, histogram and colours."""

from __future__ import annotations

import numpy as np

from .._progress import Progress, drain, stage
from .._validation import check_memory, check_seed, output_shape
from ..model.synthesis import burn_in, cached_radius, iter_synthesize
from . import _palette, _spectral
from ._blocks import _row_chunks
from ._histogram import _iter_clip, _iter_match, _iter_restore
from ._pyramid import _iter_collapse, _level_shapes

# relative cost per pixel of the parts of a fit (progress fractions), measured
_SHARE_READ, _SHARE_QUANTILES, _SHARE_PYRAMID, _SHARE_FIT = 0.3, 1.0, 0.5, 20.0
# cost per value of the parts of a synthesis (progress fractions), in
# multiply-adds of the synthesis kernel, measured: a band's field (its noise
# and crop; the kernel adds its parameters a pixel), the tiling, a histogram
# matching, the collapse, the restore of the mean and contrast
_COST_FIELD, _COST_TORUS, _COST_MATCH, _COST_COLLAPSE, _COST_RESTORE = 30, 10, 75, 14, 25
_COST_SPLIT = 20  # a band's projection onto its frequencies (two transforms), estimated
# float64 arrays of the output's size a synthesis holds at its peak (the
# bands, the finest field with its margin, the collapse and the result)
_SYNTHESIS_COPIES = 6
# a band field's burn-in: its transient's amplitude left at the band's edge,
# relative to the field's (a variance share of 1e-4; synthesize's default
# 1e-4, a share of 1e-8, cost as many rows again for no measurable change)
_BAND_TRANSIENT = 1e-2
# the longest burn-in of a band's field: near-unit-root bands asked for 256
# (the cap of burn_in) at every level, three times the finest band's pixels
# and most of the synthesis's time. Chosen on the 17 TUNING textures of
# benchmarks/bench_synthesis.py among 256 / 64 / 32 (autocorrelation L1
# 0.0308 / 0.0272 / 0.0310, colour-histogram 0.0460 / 0.0443 / 0.0461, LBP
# 0.1315 / 0.1307 / 0.1300, spurious colours 0.194 / 0.190 / 0.195 %)
_MAX_BAND_MARGIN = 64


def _torus(field, shape, mean):
    """Cut a periodic (h, w) field out of a larger (h + bh, w + bw) one.

    The first ``b`` columns cross-fade from the extra columns beyond ``w``
    (which continue column ``w - 1`` naturally) to the field's own columns,
    with weights ``cos`` and ``sin`` so that two independent stationary fields
    mix without losing variance; then the same for the rows. Column 0 then
    equals the old column ``w``, the true neighbour of column ``w - 1``.
    """
    return drain(_iter_torus(field, shape, mean))


def _fade(b, axis):
    """The weights of the own and the extra samples of a cross-fade over
    ``b`` samples, shaped to broadcast along ``axis`` of an (h, w, d) array."""
    t = 0.5 * np.pi * np.arange(b) / b
    shape = [1, 1, 1]
    shape[axis] = b
    return np.sin(t).reshape(shape), np.cos(t).reshape(shape)


def _iter_torus(field, shape, mean):
    """:func:`_torus` as a job, by blocks of output rows (a record after
    each, stage ``"tiling"``): the same numbers."""
    h, w = shape
    bh, bw = field.shape[0] - h, field.shape[1] - w
    cols = _fade(bw, 1) if bw > 0 else None
    rows = _fade(bh, 0) if bh > 0 else None

    def faded(r0, r1):  # rows r0:r1 of the field, centred, its columns cross-faded
        f = field[r0:r1] - mean
        if cols is None:
            return f
        own, extra = cols
        return np.concatenate([own * f[:, :bw] + extra * f[:, w:], f[:, bw:w]], axis=1)

    out = np.empty((h, w, field.shape[2]))
    for a, b in _row_chunks(h, w):
        if rows is not None and a < bh:
            m = min(b, bh)
            own, extra = rows
            out[a:m] = own[a:m] * faded(a, m) + extra[a:m] * faded(h + a, h + m) + mean
            if m < b:
                out[m:b] = faded(m, b) + mean
        else:
            out[a:b] = faded(a, b) + mean
        yield Progress("tiling", b / h, f"rows {b}/{h}")
    return out



def _blend_width(n):
    """Cross-fade band for a periodic level of side ``n``: a quarter of it,
    at least 2 pixels, at most ``n`` (a level of side 1 fades over 1: its
    one pixel is the extra sample, trivially periodic)."""
    return min(max(2, n // 4), n)



def iter_synthesize_texture(texture, shape, *, seed=None, tileable=False):
    """:meth:`TextureModel.iter_synthesize <car_napari.texture.TextureModel.iter_synthesize>`
    of ``texture``: the same arguments, records and result."""
    h, w = output_shape(shape)
    if not isinstance(tileable, (bool, np.bool_)):
        raise TypeError(f"tileable must be True or False; got {tileable!r}.")
    check_memory(_SYNTHESIS_COPIES * 8 * h * w * texture.n_channels, f"shape {(h, w)}")
    rng = check_seed(seed)
    spectral = texture.pyramid == "spectral"
    # one independent stream per band, fixed by the seed
    streams = [np.random.default_rng(s) for s in rng.integers(0, 2**63, size=texture.levels)]
    shapes = _level_shapes((h, w), texture.levels)
    made = [(hk + _blend_width(hk), wk + _blend_width(wk)) if tileable else (hk, wk)
            for hk, wk in shapes]
    # the shares of the work, in values times their measured cost a value
    d = texture.n_channels
    parts = []
    for k, (model, (hk, wk), (gh, gw)) in enumerate(
            zip(texture.models, shapes, made, strict=True)):
        split = spectral and k < texture.levels - 1  # a band-pass band's projection
        parts += [gh * gw * (_COST_FIELD * d + model.gamma.size + d * d + 8),
                  _COST_TORUS * hk * wk * d if tileable else 0.0,
                  _COST_SPLIT * hk * wk * d if split else 0.0,
                  (_COST_MATCH if texture.band_quantiles is not None else 1.0) * hk * wk * d]
    parts += [_COST_COLLAPSE * sum(hk * wk for hk, wk in shapes[:-1]) * d,
              (_COST_RESTORE + (_COST_MATCH if texture.quantiles is not None else 1.0))
              * h * w * d]
    edges = (np.concatenate([[0.0], np.cumsum(parts)]) / sum(parts)).tolist()
    bands = []
    for k, (model, (hk, wk), (gh, gw)) in enumerate(
            zip(texture.models, shapes, made, strict=True)):
        part = f"band {k + 1}/{texture.levels}, "
        e = edges[4 * k : 4 * k + 5]
        margin = min(burn_in(cached_radius(model), _BAND_TRANSIENT), _MAX_BAND_MARGIN)
        field = yield from stage(iter_synthesize(model, (gh, gw), seed=streams[k],
                                                 margin=margin),
                                 e[0], e[1], prefix=part, name="synthesis")
        band = field.reshape(gh, gw, -1)
        if tileable:
            band = yield from stage(_iter_torus(band, (hk, wk), model.mean), e[1], e[2],
                                    prefix=part, name="synthesis")
        if spectral and k < texture.levels - 1:
            # a CAR field covers every frequency: keep its band's only
            band = yield from stage(
                _spectral.iter_highpass(band, wrap=bool(tileable), single=True), e[2], e[3],
                prefix=part, name="synthesis")
        bounds = texture.band_ranges[k]
        if texture.band_quantiles is not None:
            # in place: every band array here is the synthesis's own
            band = yield from stage(_iter_match(band, texture.band_quantiles[k], clip=bounds,
                                                out=band),
                                    e[3], e[4], prefix=part + "matching, ",
                                    name="synthesis")
        else:
            band = yield from stage(_iter_clip(band, bounds), e[3], e[4], prefix=part,
                                    name="synthesis")
        bands.append(band)
    if spectral:
        out = yield from stage(
            _spectral.iter_collapse(bands, wrap=bool(tileable), single=True), edges[-3],
            edges[-2])
    else:
        out = yield from stage(_iter_collapse(bands, bool(tileable)), edges[-3], edges[-2])
    del bands
    result = np.zeros((h, w, d))
    shown = result[..., 0] if texture.grey else result
    last = _COST_MATCH if texture.quantiles is not None else 1.0
    middle = edges[-2] + (1.0 - edges[-2]) * _COST_RESTORE / (_COST_RESTORE + last)
    out = yield from stage(_iter_restore(out, texture.mean, texture.std), edges[-2], middle,
                           name="restore")
    if texture.quantiles is not None:
        final = _iter_match(out, texture.quantiles, clip=texture.value_range, out=result,
                            preview=shown)
    else:
        final = _iter_clip(out, texture.value_range, out=result, preview=shown)
    end = 1.0 if texture.palette is None else middle + 0.8 * (1.0 - middle)
    yield from stage(final, middle, end, name="restore", prefix="histogram, ")
    if texture.palette is not None:
        for a, b in _row_chunks(h, w):
            _palette.snap(result[a:b], texture.palette, texture.palette_radius, out=result[a:b])
            yield Progress("restore", end + (1.0 - end) * b / h, f"colours, rows {b}/{h}",
                           shown)
    return shown
