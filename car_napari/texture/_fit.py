"""The fit of a :class:`~car_napari.texture.TextureModel`: the reading of
the texture, its quantiles and palette, the pyramid, each band's CAR model
and quantiles; and the checks of the fit's options."""

from __future__ import annotations

import numpy as np

from .._progress import Progress, stage
from .._validation import (
    as_channel_last_float,
    check_channel_axis,
    check_not_constant,
    summarize,
)
from ..model.neighbourhood import as_offsets
from . import _palette, _spectral
from ._bandfit import _iter_stable_fit
from ._blocks import _f32, _row_chunks
from ._format import MAX_FILE_OFFSETS, MAX_FILE_REACH, PYRAMIDS
from ._histogram import _iter_quantiles
from ._pyramid import _iter_pyramid, _level_shapes

_AUTO_LEVELS = 5  # levels=None: this many when the texture is large enough
_MIN_TOP = 16  # smallest side of the coarsest level: the order-5 decision rule needs it
_BAND_QUANTILES = 32  # stored quantiles per band and channel (histogram matching)
_OUT_QUANTILES = 64  # stored quantiles of the input per channel
# relative cost per pixel of the parts of a fit (progress fractions), measured
_SHARE_READ, _SHARE_QUANTILES, _SHARE_PYRAMID, _SHARE_FIT = 0.3, 1.0, 0.5, 20.0


def _plane_shape(image, channel_axis):
    """(height, width) of a 2-D image or of a 3-D one with a valid
    ``channel_axis``; None for any other layout (the reading says why)."""
    shape = np.shape(image) if image is not None else ()
    if len(shape) == 2:
        return tuple(int(n) for n in shape)
    if len(shape) == 3 and isinstance(channel_axis, (int, np.integer)) \
            and not isinstance(channel_axis, (bool, np.bool_)) and -3 <= channel_axis < 3:
        return tuple(int(n) for axis, n in enumerate(shape) if axis != channel_axis % 3)
    return None


def _iter_float_image(image, channel_axis):
    """``as_channel_last_float(image, channel_axis=channel_axis)`` and the
    image's :func:`summarize`, as a job: the conversion runs by blocks of
    rows with a record (stage ``"reading"``) after each.

    The layout, dtype and channel checks run on one row first, so their
    errors come before the first record, with the same messages; a
    non-finite value is reported as the whole-image check reports it.
    """
    check_channel_axis(channel_axis)  # a 2-D image ignores it: checked still
    plane = _plane_shape(image, channel_axis)
    arr = np.asarray(image) if plane is not None else None
    if arr is None or arr.size == 0 or arr.dtype == object or arr.dtype.kind not in "biuf":
        return as_channel_last_float(image, channel_axis=channel_axis, with_summary=True)
    if arr.ndim == 2:
        view = arr[..., np.newaxis]
    else:
        # the checks and messages of the whole image, on its first row
        row_axis = [axis for axis in range(3) if axis != channel_axis % 3][0]
        as_channel_last_float(np.take(arr, [0], axis=row_axis), channel_axis=channel_axis)
        view = np.moveaxis(arr, channel_axis, -1)
    h, w = plane
    data = np.empty(view.shape, np.float64)
    for a, b in _row_chunks(h, w):
        try:
            data[a:b] = as_channel_last_float(view[a:b], channel_axis=-1, copy=False)
        except ValueError:  # non-finite values: the message of the whole image
            as_channel_last_float(image, channel_axis=channel_axis)
            raise
        yield Progress("reading", b / h, f"rows {b}/{h}")
    return data, summarize(data)



def _check_options(levels, model, neighbourhood):
    """Validate the options of :func:`iter_fit_texture`; return ``levels`` as an int."""
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)):
        raise TypeError(f"levels must be an int >= 1; got {levels!r}.")
    levels = int(levels)
    if not 1 <= levels <= 8:
        raise ValueError(f"levels must be between 1 and 8; got {levels}.")
    if model not in ("3d", "2d"):
        raise ValueError(f"model must be '3d' or '2d'; got {model!r}.")
    if isinstance(neighbourhood, str):
        if neighbourhood != "auto":
            raise ValueError(
                f"neighbourhood must be 'auto', an order or offsets; got {neighbourhood!r}."
            )
    else:
        offsets, _ = as_offsets(neighbourhood)
        reach = int(np.abs(offsets).max())
        if reach > MAX_FILE_REACH or len(offsets) > MAX_FILE_OFFSETS:
            raise ValueError(
                f"neighbourhood has {len(offsets)} offsets reaching {reach} pixels; a texture "
                f"model holds at most {MAX_FILE_OFFSETS} offsets reaching {MAX_FILE_REACH} "
                "(the file format's bounds). Use a lower order."
            )
    return levels


def _auto_levels(shape, most=_AUTO_LEVELS):
    """The levels of ``levels=None``: ``most`` (:data:`_AUTO_LEVELS`), fewer
    when the coarsest band would be smaller than :data:`_MIN_TOP` (at least
    1) for a texture of ``shape`` (height, width)."""
    side = min(int(n) for n in shape)
    levels = 1
    while levels < most and _MIN_TOP * 2 ** levels <= side:
        levels += 1
    return levels


def _check_texture_size(shape, levels, *, name="the texture"):
    """The coarsest band must be at least ``_MIN_TOP`` pixels a side."""
    h, w = shape
    minimum = _MIN_TOP * 2 ** (levels - 1)
    if min(h, w) < minimum:
        raise ValueError(
            f"{name} is {h}x{w} but {levels} pyramid levels need at least "
            f"{minimum}x{minimum} pixels (the coarsest band must be {_MIN_TOP}x{_MIN_TOP} "
            "or larger). Use a larger texture or fewer levels."
        )


def iter_fit_fields(image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
                    pyramid="spectral"):
    """:func:`~car_napari.texture.iter_fit_texture`, returning the fitted
    model's fields (its constructor's arguments) rather than the model."""
    if pyramid not in PYRAMIDS:
        raise ValueError(f"pyramid must be one of {PYRAMIDS}; got {pyramid!r}.")
    grey = np.ndim(image) == 2
    plane = _plane_shape(image, channel_axis)
    if plane is None or np.asarray(image).dtype.kind not in "biuf" or 0 in plane:
        # an input the reading refuses: its error, before any record
        plane = as_channel_last_float(image, channel_axis=channel_axis).shape[:2]
    if levels is None:
        levels = _auto_levels(plane)
    levels = _check_options(levels, model, neighbourhood)
    _check_texture_size(plane, levels)
    # shares of the whole: every part costs about its passes over the pixels
    shapes = _level_shapes(plane, levels)
    pixels = np.array([h * w for h, w in shapes], float)
    parts = np.array([_SHARE_READ * pixels[0], _SHARE_QUANTILES * pixels[0],
                      _SHARE_PYRAMID * pixels[:-1].sum(), _SHARE_FIT * pixels.sum(),
                      _SHARE_QUANTILES * pixels.sum()])
    edges = np.concatenate([[0.0], np.cumsum(parts)]) / parts.sum()
    data, summary = yield from stage(_iter_float_image(image, channel_axis), edges[0],
                                     edges[1])
    check_not_constant(data, summary=summary)
    # the input's quantiles first: the finest band then overwrites the input
    quantiles, _, _ = yield from stage(
        _iter_quantiles(data, _OUT_QUANTILES), edges[1], edges[2],
        prefix="texture, ")
    palette = radius = None
    if data.shape[2] >= 2:  # the colours a synthesis may use
        palette, radius = (_f32(a) for a in _palette.fit_palette(data))
        yield Progress("quantiles", edges[2], "texture, palette")
    if pyramid == "spectral":
        bands = yield from stage(_spectral.iter_pyramid(data, levels), edges[2], edges[3])
    else:
        bands = yield from stage(_iter_pyramid(data, levels, overwrite=True), edges[2],
                                 edges[3])
    del data
    fit_edges = edges[3] + (edges[4] - edges[3]) * np.concatenate(
        [[0.0], np.cumsum(pixels)]) / pixels.sum()
    models, fallbacks = [], []
    for k, band in enumerate(bands):
        fitted, note = yield from stage(
            _iter_stable_fit(band, neighbourhood, model=model), fit_edges[k], fit_edges[k + 1],
            name="fitting", prefix=f"level {k + 1}/{levels}: ")
        models.append(fitted)
        if note is not None:
            fallbacks.append(f"band {k}: {note}")
    q_edges = edges[4] + (edges[5] - edges[4]) * np.concatenate(
        [[0.0], np.cumsum(pixels)]) / pixels.sum()
    band_quantiles, band_ranges = [], []
    for k, band in enumerate(bands):
        q, lo, hi = yield from stage(_iter_quantiles(band, _BAND_QUANTILES), q_edges[k],
                                     q_edges[k + 1], prefix=f"level {k + 1}/{levels}, ")
        band_quantiles.append(q)
        band_ranges.append(np.stack([lo, hi]))
    band_quantiles, band_ranges = np.stack(band_quantiles), np.stack(band_ranges)
    yield Progress("fitting", 1.0, f"{levels} level{'s' if levels > 1 else ''} fitted")
    # The file stores float32: round now, so that a saved and loaded model
    # synthesises exactly what this one does.
    for m in models:
        m.gamma, m.sigma, m.mean = _f32(m.gamma), _f32(m.sigma), _f32(m.mean)
    return dict(
        models=tuple(models), band_ranges=_f32(band_ranges), mean=_f32(summary.mean),
        std=_f32(np.sqrt(np.asarray(summary.var, float))),
        value_range=_f32(np.stack([summary.min, summary.max])), grey=grey,
        model=model, fallbacks=tuple(fallbacks), band_quantiles=band_quantiles,
        quantiles=quantiles, pyramid=pyramid, palette=palette, palette_radius=radius,
    )
