"""Multiresolution CAR texture synthesis and compression (section 14.8, docs/texture.md).

A texture is analysed by a Gaussian-Laplacian pyramid; every sub-band gets
its own CAR model with its own optimal support (the decision rule (14.6),
docs/model.md). The few numbers of those models are the compressed texture:
synthesis generates every sub-band from its model (synthesis, docs/model.md)
at any size, matches every generated band's histogram to a few stored
quantiles of the analysed band, collapses the pyramid and restores the
histogram of the input (from its stored quantiles).

The pyramid (Burt and Adelson, with operators chosen so that analysis and
synthesis match at any image size):

- ``reduce``: Gaussian blur (sigma 1 pixel), then the mean of 2 x 2 blocks;
  a level of size ``n`` gives ``ceil(n / 2)``.
- ``expand``: separable cubic convolution (Keys, a = -0.5) back to the finer
  level's size, pixel extents aligned; half-sample symmetric borders, or
  periodic ones for tileable synthesis.
- band ``k < levels - 1`` is ``G_k - expand(G_{k+1})`` (band-pass, about zero
  mean); the last band is the low-pass residual ``G_{levels-1}``. Collapsing
  ``G_k = band_k + expand(G_{k+1})`` reconstructs the input exactly.

The stored file format is described in :meth:`TextureModel.save`.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from scipy import ndimage as ndi

from .._progress import Progress, drain, stage
from .._validation import (
    as_channel_last_float,
    check_axis,
    check_channel_axis,
    check_flag,
    check_memory,
    check_not_constant,
    check_path,
    check_seed,
    check_shape,
    output_shape,
    summarize,
)
from ..model.directions import DIRECTIONS
from ..model.estimation import CARModel, iter_fit_car
from ..model.neighbourhood import as_offsets
from ..model.synthesis import burn_in, cached_radius, iter_synthesize, spectral_radius
from . import _kernels, _palette, _spectral

__all__ = [
    "TextureModel", "iter_fit_texture", "laplacian_pyramid", "collapse_pyramid", "FORMAT_NAME",
    "FORMAT_VERSION",
]

FORMAT_NAME = "car-napari texture model"
FORMAT_VERSION = 3
PYRAMIDS = ("spectral", "gaussian")  # the kinds of pyramid a model can use
_AUTO_LEVELS = 5  # levels=None: this many when the texture is large enough

_BLUR_SIGMA = 1.0  # pyramid smoothing before 2x2 decimation, in pixels
_MIN_TOP = 16  # smallest side of the coarsest level: the order-5 decision rule needs it
_MAX_ORDER = 5  # largest candidate order for neighbourhood='auto'
_SHRINK_RADIUS = 0.99  # last-resort target when even order 1 is unstable
# a fit is usable below this radius: degenerate textures (ramps, step edges)
# fit unit roots, 1 - 1e-12, that the float32 rounding of the file and of
# the fit's end pushes to 1 or beyond (synthesis then refuses them)
_STABLE_RADIUS = 1.0 - 1e-6
_BAND_QUANTILES = 32  # stored quantiles per band and channel (histogram matching)
_OUT_QUANTILES = 64  # stored quantiles of the input per channel
_CHUNK_PIXELS = 1 << 19  # pixels per block of a long pass (a record between blocks)
_BLUR_HALO = 8  # rows beyond a block that its blur reads (the kernel reaches 4)
_HIST_BINS = 1 << 16  # bins of the first pass of the exact quantiles
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


def _row_chunks(n_rows, width, pixels=None):
    """``(start, stop)`` row ranges of about ``pixels`` pixels each (at least
    one row): the pieces a long pass over an image is cut into, with a
    record between them."""
    step = max(1, (pixels or _CHUNK_PIXELS) // max(int(width), 1))
    return [(a, min(a + step, n_rows)) for a in range(0, n_rows, step)]


def _reduce(image):
    """One pyramid step down: blur, then average 2 x 2 blocks (odd sides are
    padded by reflection so a size ``n`` level gives ``ceil(n / 2)``)."""
    return drain(_iter_reduce(image))


def _iter_reduce(image):
    """:func:`_reduce` as a job, by blocks of output rows (a record after
    each, fractions of the rows), then the reduced image. Each block blurs
    its rows with a halo of :data:`_BLUR_HALO` rows: the same numbers as
    blurring the whole image."""
    h, w, d = image.shape
    out = np.empty(((h + 1) // 2, (w + 1) // 2, d))
    chunks = _row_chunks(out.shape[0], 4 * w)
    for a, b in chunks:
        r0, r1 = 2 * a, min(2 * b, h)
        s0, s1 = max(r0 - _BLUR_HALO, 0), min(r1 + _BLUR_HALO, h)
        blurred = ndi.gaussian_filter(image[s0:s1], sigma=(_BLUR_SIGMA, _BLUR_SIGMA, 0),
                                      mode="reflect")[r0 - s0 : r1 - s0]
        blurred = np.pad(blurred, ((0, 2 * (b - a) - (r1 - r0)), (0, w % 2), (0, 0)),
                         mode="symmetric")
        out[a:b] = 0.25 * (
            blurred[0::2, 0::2] + blurred[1::2, 0::2] + blurred[0::2, 1::2] + blurred[1::2, 1::2]
        )
        yield Progress("pyramid", b / out.shape[0], f"rows {b}/{out.shape[0]}")
    return out


def _cubic_axis(image, n_out, axis, wrap, rows=None):
    """Resample one axis to ``n_out`` samples by Keys cubic convolution
    (a = -0.5), pixel extents aligned: output pixel ``i`` sits at input
    coordinate ``(i + 0.5) * n_in / n_out - 0.5``. Borders are half-sample
    symmetric, or periodic with ``wrap``. ``rows`` (a slice) computes only
    those output samples."""
    n_in = image.shape[axis]
    x = (np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5
    if rows is not None:
        x = x[rows]
    base = np.floor(x).astype(np.int64)
    t = x - base
    out = 0.0
    for shift in (-1, 0, 1, 2):
        s = np.abs(t - shift)
        weight = np.where(
            s <= 1, (1.5 * s - 2.5) * s * s + 1,
            np.where(s < 2, ((-0.5 * s + 2.5) * s - 4) * s + 2, 0.0),
        )
        idx = base + shift
        if wrap:
            idx = idx % n_in
        else:  # half-sample symmetric: -1 -> 0, n -> n - 1
            idx = np.where(idx < 0, -idx - 1, idx)
            idx = np.where(idx >= n_in, 2 * n_in - idx - 1, idx)
            idx = np.clip(idx, 0, n_in - 1)
        shape = [1] * image.ndim
        shape[axis] = x.size
        out = out + weight.reshape(shape) * np.take(image, idx, axis=axis)
    return out


def _expand_rows(image, shape, rows, wrap=False):
    """Rows ``rows`` (a slice) of ``_expand(image, shape, wrap=wrap)``, the
    same numbers, computed from the input rows they need."""
    out = _cubic_axis(image, int(shape[0]), 0, wrap, rows=rows)
    return _cubic_axis(out, int(shape[1]), 1, wrap)


def _expand(image, shape, *, wrap=False):
    """Cubic upsampling of (h, w, d) ``image`` to ``shape`` (h2, w2).

    Pixel extents are aligned, which matches the 2 x 2 block averaging of
    :func:`_reduce` (a coarse pixel's centre is the centre of its block).
    With ``wrap`` the image is one period of a torus, so a periodic coarse
    level expands to a periodic fine level at any size. (Separable Keys cubic
    convolution: ten times faster than a spline zoom, same role.) Computed
    by blocks of rows (less memory; the same numbers).
    """
    h2, w2 = int(shape[0]), int(shape[1])
    out = np.empty((h2, w2, image.shape[2]))
    for a, b in _row_chunks(h2, w2):
        out[a:b] = _expand_rows(image, (h2, w2), slice(a, b), wrap)
    return out


def _level_shapes(shape, levels):
    shapes = [tuple(int(v) for v in shape)]
    for _ in range(levels - 1):
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def _pyramid(image, levels):
    """Bands of the pyramid of a channel-last (H, W, d) float image."""
    return drain(_iter_pyramid(image, levels))


def _iter_pyramid(image, levels, *, overwrite=False):
    """:func:`_pyramid` as a job (stage ``"pyramid"``): a record after every
    block of rows of every reduce and every band, fractions by pixels; then
    the bands. With ``overwrite`` the finest band is written into ``image``
    (and every band into its Gaussian level): the pyramid then takes a
    third of the image's memory more, not twice it."""
    shapes = _level_shapes(image.shape[:2], levels)
    pixels = np.array([h * w for h, w in shapes], float)
    # reducing level k and forming band k each cost about level k's pixels
    total = max(2.0 * pixels[:-1].sum(), 1.0)
    done = 0.0
    gauss = [image]
    for k in range(levels - 1):
        start, share = done / total, pixels[k] / total
        gauss.append((yield from stage(_iter_reduce(gauss[-1]), start, start + share,
                                       prefix=f"level {k + 2}/{levels}, ")))
        done += pixels[k]
    bands = []
    for k in range(levels - 1):
        g = gauss[k]
        gauss[k] = None  # the bands replace the Gaussian levels one by one
        band = g if overwrite else np.empty_like(g)
        h, w = g.shape[:2]
        for a, b in _row_chunks(h, w):
            band[a:b] = g[a:b] - _expand_rows(gauss[k + 1], (h, w), slice(a, b))
            fraction = (done + pixels[k] * b / h) / total
            yield Progress("pyramid", fraction, f"band {k + 1}/{levels}, rows {b}/{h}")
        done += pixels[k]
        bands.append(band)
        del g, band
    bands.append(gauss[-1])
    return bands


def _collapse(bands, wrap):
    """Inverse of :func:`_pyramid` on channel-last bands."""
    return drain(_iter_collapse(bands, wrap))


def _iter_collapse(bands, wrap):
    """:func:`_collapse` as a job: ``band + expand(coarser)`` by blocks of
    rows (those of :func:`_expand`: the same numbers), a record after each
    (stage ``"collapse"``, fractions by pixels); then the collapsed image."""
    out = bands[-1]
    finer = bands[-2::-1]
    pixels = np.array([band.shape[0] * band.shape[1] for band in finer], float)
    total, done = max(pixels.sum(), 1.0), 0.0
    for k, band in enumerate(finer):
        h, w = band.shape[:2]
        level = np.empty(band.shape)
        for a, b in _row_chunks(h, w):
            level[a:b] = band[a:b] + _expand_rows(out, (h, w), slice(a, b), wrap)
            yield Progress("collapse", (done + pixels[k] * b / h) / total,
                           f"level {len(finer) - k}, rows {b}/{h}")
        done += pixels[k]
        out = level
    return out


# more pyramid levels than this halve any image below one pixel
MAX_PYRAMID_LEVELS = 32


def _positive_int(value, name, high=None):
    """``value`` as an int when it is a positive int (not a bool) up to
    ``high``, else the ValueError ``"{name} must be a positive int"``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < 1:
        raise ValueError(f"{name} must be a positive int; got {value!r}.")
    if high is not None and value > high:
        raise ValueError(f"{name} must be a positive int up to {high}; got {value!r}.")
    return int(value)


def _check_pyramid_levels(levels):
    return _positive_int(levels, "levels", MAX_PYRAMID_LEVELS)


def laplacian_pyramid(image, *, levels=3, channel_axis=-1):
    """Decompose an image into its Gaussian-Laplacian pyramid, finest band first.

    Band ``k < levels - 1`` is ``G_k - expand(G_{k+1})`` (band-pass), the
    last band is the low-pass residual ``G_{levels-1}``; see the module
    docstring for the operators. :func:`collapse_pyramid` inverts it exactly.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Grey or multichannel image; integer images are scaled to [0, 1].
    levels : int, optional
        Number of bands: ``levels - 1`` band-pass bands and the low-pass
        residual.
    channel_axis : int or None, optional
        Axis of the channels of a 3-D image (default the last); a 2-D image
        is always grey.

    Returns
    -------
    bands : list of ndarray
        ``levels`` float64 bands in the input's layout; band ``k`` is
        ``ceil(H / 2**k) x ceil(W / 2**k)``.

    Raises
    ------
    ValueError
        If ``levels`` is not a positive int, or the image is not 2-D or 3-D,
        or not finite.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import laplacian_pyramid
    >>> bands = laplacian_pyramid(np.ones((9, 12)), levels=3)
    >>> [band.shape for band in bands]
    [(9, 12), (5, 6), (3, 3)]
    """
    levels = _check_pyramid_levels(levels)
    data = as_channel_last_float(image, channel_axis=channel_axis)
    bands = _pyramid(data, levels)
    if np.ndim(image) == 2:
        return [band[..., 0] for band in bands]
    return [np.moveaxis(band, -1, channel_axis) for band in bands]


def collapse_pyramid(bands, *, wrap=False, channel_axis=-1):
    """Inverse of :func:`laplacian_pyramid`: ``G_k = band_k + expand(G_{k+1})``.

    Parameters
    ----------
    bands : sequence of (h_k, w_k) or (h_k, w_k, C) arrays
        Finest first, each about twice the size of the next, all 2-D (grey)
        or all 3-D with the same channels.
    wrap : bool, optional
        Expand periodically (for bands that are each one period of a torus).
    channel_axis : int or None, optional
        Axis of the channels of 3-D bands (default the last); 2-D bands are
        grey.

    Returns
    -------
    image : (h_0, w_0) or (h_0, w_0, C) ndarray of float64
        The collapsed image, in the bands' layout.

    Raises
    ------
    ValueError
        If there are no bands, or grey and multichannel bands are mixed, or
        3-D bands come with ``channel_axis=None``, or a band is not half the
        size of the finer one (rounded up) or has other channels, or holds
        NaN or infinite values.
    TypeError
        If ``bands`` is not a list or tuple, a band is not real-valued, or
        ``wrap`` is not a bool.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import collapse_pyramid, laplacian_pyramid
    >>> image = np.random.default_rng(0).random((20, 30, 3))
    >>> bands = laplacian_pyramid(image, levels=3)
    >>> np.allclose(collapse_pyramid(bands), image)
    True
    """
    wrap = check_flag(wrap, "wrap")
    arrays = _check_bands(bands, channel_axis)
    out = _collapse([a if a.ndim == 3 else a[..., np.newaxis] for a in arrays], wrap)
    if arrays[0].ndim == 2:
        return out[..., 0]
    return np.moveaxis(out, -1, channel_axis)


def _check_bands(bands, channel_axis):
    """The bands of :func:`collapse_pyramid` as float64 arrays (3-D ones
    channel-last), checked for what a pyramid is: numeric, finite, all grey
    or all with the same channels, each band half the size of the finer one
    (rounded up, as :func:`laplacian_pyramid` makes them); else a ValueError
    or TypeError naming the band. Checked before any work."""
    if isinstance(bands, np.ndarray) or not isinstance(bands, (list, tuple)):
        raise TypeError("bands must be a list of arrays (those of laplacian_pyramid, finest "
                        f"first); got {type(bands).__name__}.")
    if not bands:
        raise ValueError("bands is empty: pass the bands of laplacian_pyramid, finest first.")
    if len(bands) > MAX_PYRAMID_LEVELS:
        raise ValueError(f"bands has {len(bands)} bands; a pyramid has at most "
                         f"{MAX_PYRAMID_LEVELS}.")
    arrays = []
    for k, band in enumerate(bands):
        try:
            arr = np.asarray(band)
        except (ValueError, TypeError) as exc:  # ragged nested lists
            raise ValueError(f"bands[{k}] is not an array: {exc}") from None
        if arr.dtype == object or arr.dtype.kind not in "biuf":
            raise TypeError(f"bands[{k}] has dtype {arr.dtype}; pass real (integer or float) "
                            "arrays.")
        if arr.size == 0:
            raise ValueError(f"bands[{k}] is empty (shape {arr.shape}).")
        arrays.append(arr)
    ndims = {a.ndim for a in arrays}
    if ndims not in ({2}, {3}):
        raise ValueError(
            f"bands must be all 2-D (grey) or all 3-D (multichannel); got dimensions "
            f"{sorted(ndims)}."
        )
    if ndims == {3}:
        if channel_axis is None:
            raise ValueError("the bands are 3-D but channel_axis=None; pass the channel axis "
                             "(e.g. channel_axis=-1) or 2-D grey bands.")
        axis = check_axis(channel_axis, 3, "channel_axis")
        arrays = [np.moveaxis(a, axis, -1) for a in arrays]
    expected = _level_shapes(arrays[0].shape[:2], len(arrays))
    for k, (a, shape) in enumerate(zip(arrays, expected, strict=True)):
        if a.shape[:2] != shape or a.shape[2:] != arrays[0].shape[2:]:
            want = shape + arrays[0].shape[2:]
            raise ValueError(
                f"bands[{k}] has shape {a.shape} (channels last) but a pyramid whose finest "
                f"band is {arrays[0].shape} needs {want} there: each band is half the size "
                "of the finer one, rounded up. Pass the bands of laplacian_pyramid, finest "
                "first."
            )
    arrays = [a.astype(np.float64) for a in arrays]
    for k, a in enumerate(arrays):
        if not np.isfinite(a).all():
            raise ValueError(f"bands[{k}] contains NaN or infinite values.")
    return arrays


def _max_order_below(offsets):
    """Largest hierarchical order with fewer offsets than ``offsets``."""
    eta = len(offsets)
    best = 0
    for k in range(1, _MAX_ORDER + 1):
        if len(as_offsets(k)[0]) < eta:
            best = k
    return best


def _fallback_orders(first):
    """Orders to try, in turn, when the first fitted model is unstable."""
    if first.scores is not None and all(isinstance(k, int) for k in first.scores):
        ranked = sorted(first.scores, key=first.scores.get, reverse=True)
        return [k for k in ranked if k != first.order]
    if first.factors is not None:
        top = max(int(f.order or _max_order_below(f.offsets) + 1) for f in first.factors)
        # a 2DCAR whose factors all have the same order falls to the next lower one
        return list(range(top - 1, 0, -1)) if top > 1 else []
    top = first.order if first.order is not None else _max_order_below(first.offsets) + 1
    return list(range(top - 1, 0, -1))


def _iter_scale(radius, target=_SHRINK_RADIUS, steps=40):
    """The largest factor ``c`` in [0, 1] (by ``steps`` bisection steps) for
    which ``radius(c) < target``: how far to scale a ``gamma`` down. A job: a
    record every few steps (each costs a stability test), then ``c``."""
    lo, hi = 0.0, 1.0
    for step in range(steps):
        if step % 4 == 0:
            yield Progress("stabilising", step / steps, f"gamma scale, step {step + 1}/{steps}")
        mid = 0.5 * (lo + hi)
        if radius(mid) < target:
            lo = mid
        else:
            hi = mid
    return lo


def _iter_shrunk(model, target=_SHRINK_RADIUS):
    """Copy of ``model`` with ``gamma`` scaled down until its spectral radius is
    ``target``: the last resort when even order 1 is unstable. A job (see
    :func:`_iter_scale`); returns ``(model, scale)``."""
    trial = CARModel(**{**model.__dict__})

    def radius(scale):
        trial.gamma = model.gamma * scale
        return spectral_radius(trial)

    scale = yield from _iter_scale(radius, target)
    trial.gamma = model.gamma * scale
    trial.factors = None  # the per-factor models no longer match gamma
    return trial, scale


def _stored_radius(model):
    """The spectral radius of ``model`` with ``gamma`` rounded to float32, as
    a fitted texture keeps it (the stability that synthesis will test)."""
    rounded = CARModel(**{**model.__dict__})
    rounded.gamma = _f32(model.gamma)
    return spectral_radius(rounded)


def _radius_text(radius):
    """``radius`` to 4 digits, or to 10 when those would show a unit root as 1."""
    text = f"{radius:.4g}"
    return f"{radius:.10g}" if text == "1" else text


def _iter_stable_fit(band, neighbourhood, *, model="3d", orders=range(1, _MAX_ORDER + 1),
                     what="the fitted model"):
    """Fit ``band`` (channel-last) by :func:`~car_napari.model.iter_fit_car`
    and fall back to lower orders while the model is unstable; as a job.

    The first fit's records cover [0, 1]; a fallback's refits repeat the last
    fraction (their records keep a cancel prompt). Returns ``(CARModel,
    note)`` where ``note`` is None when the first fit was stable, else a
    sentence saying what was done.
    """
    first = yield from iter_fit_car(band, neighbourhood, model=model, orders=orders,
                                    channel_axis=-1)
    radius = _stored_radius(first)
    if radius < _STABLE_RADIUS:
        return first, None
    label = first.order if first.order is not None else f"{first.eta} offsets"
    for order in _fallback_orders(first):
        trial = yield from stage(iter_fit_car(band, order, model=model, channel_axis=-1),
                                 1.0, 1.0, prefix=f"unstable, refitting order {order}: ")
        if _stored_radius(trial) < _STABLE_RADIUS:
            return trial, (
                f"{what} (order {label}) was unstable (spectral radius "
                f"{_radius_text(radius)}); used order {order} instead"
            )
    lowest = yield from stage(iter_fit_car(band, 1, model=model, channel_axis=-1), 1.0, 1.0,
                              prefix="unstable, refitting order 1: ")
    shrunk, scale = yield from stage(_iter_shrunk(lowest), 1.0, 1.0)
    return shrunk, (
        f"{what} (order {label}) was unstable (spectral radius {_radius_text(radius)}) "
        f"and so was every lower order; used order 1 with gamma scaled by {scale:.4g} "
        f"(spectral radius {_SHRINK_RADIUS})"
    )


def _torus(field, shape, mean):
    """Cut a periodic (h, w) field out of a larger (h + bh, w + bw) one.

    The first ``b`` columns cross-fade from the extra columns beyond ``w``
    (which continue column ``w - 1`` naturally) to the field's own columns,
    with weights ``cos`` and ``sin`` so that two independent stationary fields
    mix without losing variance; then the same for the rows. Column 0 then
    equals the old column ``w``, the true neighbour of column ``w - 1``.
    """
    return drain(_iter_torus(field, shape, mean))


def _fade(n, b, axis):
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
    cols = _fade(w, bw, 1) if bw > 0 else None
    rows = _fade(h, bh, 0) if bh > 0 else None

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


def _iter_clip(values, bounds, *, out=None, preview=None):
    """``np.clip(values, bounds[0], bounds[1])`` by blocks of rows, as a job
    (stage ``"clipping"``), into ``out`` (default: in place); the records
    carry ``preview``."""
    h, w = values.shape[:2]
    out = values if out is None else out
    for a, b in _row_chunks(h, w):
        out[a:b] = np.clip(values[a:b], bounds[0], bounds[1])
        yield Progress("clipping", b / h, f"rows {b}/{h}", preview)
    return out


def _iter_channel_sum(values, *, name="sum"):
    """``np.add.reduce(values, axis=(0, 1))`` of (h, w, d) ``values``, the
    same numbers, as a job. For d >= 2 NumPy adds the pixels one after the
    other (a long strided pass): here by blocks of rows, each block's first
    pixel carrying the running sum in (and put back after), with a record
    between blocks. A grey image is one call (NumPy's fast pairwise sum)."""
    h, w, d = values.shape
    chunks = _row_chunks(h, w)
    if d == 1 or len(chunks) == 1:
        return np.add.reduce(values, axis=(0, 1))
    total = None
    for a, b in chunks:
        block = values[a:b]
        if total is None:
            total = np.add.reduce(block, axis=(0, 1))
        else:
            first = block[0, 0].copy()
            block[0, 0] += total  # the running sum, then this block's pixels in order
            try:
                total = np.add.reduce(block, axis=(0, 1))
            finally:
                block[0, 0] = first
        yield Progress(name, b / h, f"rows {b}/{h}")
    return total


def _iter_restore(values, mean, std):
    """``mean + (values - m) * gain``, where ``m`` and ``s`` are the channel
    means and standard deviations of (h, w, d) ``values`` and ``gain`` is
    ``std / s`` (1 where ``s`` is 0), as a job (stage ``"restore"``): a
    record after every block of rows of the elementwise passes, between
    which the sums over the image run one NumPy call each, as
    ``values.mean(axis=(0, 1))`` and ``.std`` sum. The same numbers as those
    one-call forms; ``values`` is overwritten (used as scratch, and returned).
    """
    h, w, d = values.shape
    n = h * w
    parts = [(k / 6, (k + 1) / 6) for k in range(6)]  # three sums, three passes
    # values.mean(axis=(0, 1))
    m = (yield from stage(_iter_channel_sum(values), *parts[0], prefix="mean, ")) / n
    centred = np.empty_like(values)
    for a, b in _row_chunks(h, w):
        np.subtract(values[a:b], m, out=centred[a:b])
        yield Progress("restore", parts[1][0] + b / h / 6, f"mean, rows {b}/{h}")
    # centred.std(axis=(0, 1)), as NumPy's _var computes it
    centre = (yield from stage(_iter_channel_sum(centred), *parts[2], prefix="contrast, "))
    centre = centre.reshape(1, 1, d) / n
    for a, b in _row_chunks(h, w):
        np.subtract(centred[a:b], centre, out=values[a:b])
        np.square(values[a:b], out=values[a:b])
        yield Progress("restore", parts[3][0] + b / h / 6, f"contrast, rows {b}/{h}")
    spread = yield from stage(_iter_channel_sum(values), *parts[4], prefix="contrast, ")
    spread = np.sqrt(spread / n)
    gain = np.where(spread > 0, std / np.where(spread > 0, spread, 1.0), 1.0)
    for a, b in _row_chunks(h, w):
        values[a:b] = mean + centred[a:b] * gain
        yield Progress("restore", min(parts[5][0] + b / h / 6, 1.0), f"rows {b}/{h}")
    return values


def _probabilities(n):
    """Probabilities of ``n`` stored quantiles: equally spaced, 0 and 1 included
    (the minimum and the maximum)."""
    return np.linspace(0.0, 1.0, n)


def _quantiles(values, n):
    """(n, d) quantiles of each channel of (h, w, d) ``values``, float32-exact
    (``numpy.quantile`` at :func:`_probabilities`, by blocks of rows)."""
    return drain(_iter_quantiles(values, n))[0]


def _iter_quantiles(values, n, *, stage_name="quantiles"):
    """:func:`_quantiles` as a job, by blocks of rows: the same numbers.

    Three passes, a record after every block: the channels' minima and
    maxima; a histogram of :data:`_HIST_BINS` bins per channel, which tells
    in which bin every needed order statistic lies; the values of those bins
    only, whose partition gives the order statistics exactly. They are
    interpolated as ``numpy.quantile`` does (its default 'linear' method).

    Returns ``(quantiles, minimum, maximum)``: (n, d) float32-exact
    quantiles and the (d,) exact extremes.
    """
    h, w, d = values.shape
    chunks = _row_chunks(h, w)
    steps, step = 3 * len(chunks) + d, 0
    lo, hi = np.full(d, np.inf), np.full(d, -np.inf)
    for a, b in chunks:
        block = values[a:b]
        lo = np.minimum(lo, block.min(axis=(0, 1)))
        hi = np.maximum(hi, block.max(axis=(0, 1)))
        step += 1
        yield Progress(stage_name, step / steps, "range")
    scale = np.where(hi > lo, _HIST_BINS / np.where(hi > lo, hi - lo, 1.0), 0.0)

    def bins_of(block, c):
        index = ((block[..., c] - lo[c]) * scale[c]).astype(np.int64).ravel()
        return np.minimum(index, _HIST_BINS - 1)

    counts = np.zeros((d, _HIST_BINS), np.int64)
    for a, b in chunks:
        block = values[a:b]
        for c in range(d):
            counts[c] += np.bincount(bins_of(block, c), minlength=_HIST_BINS)
        step += 1
        yield Progress(stage_name, step / steps, "histogram")
    # numpy.quantile's 'linear' method: the order statistics either side of
    # the virtual index (n - 1) p, interpolated (numpy's _lerp)
    size = h * w
    virtual = (size - 1) * _probabilities(n)
    previous = np.floor(virtual)
    following = previous + 1
    above = virtual >= size - 1
    previous[above] = following[above] = size - 1
    gamma = virtual - previous
    previous, following = previous.astype(np.int64), following.astype(np.int64)
    ranks = np.unique(np.r_[previous, following])
    cumulative = np.zeros((d, _HIST_BINS + 1), np.int64)
    np.cumsum(counts, axis=1, out=cumulative[:, 1:])
    wanted = [np.unique(np.searchsorted(cumulative[c], ranks, side="right") - 1)
              for c in range(d)]
    picked = [[] for _ in range(d)]
    for a, b in chunks:
        block = values[a:b]
        for c in range(d):
            mask = np.zeros(_HIST_BINS, bool)
            mask[wanted[c]] = True
            picked[c].append(block[..., c].ravel()[mask[bins_of(block, c)]])
        step += 1
        yield Progress(stage_name, step / steps, "order statistics")
    out = np.empty((n, d))
    for c in range(d):
        chosen = np.concatenate(picked[c])
        picked[c] = None
        # the rank of an order statistic within the picked values: its rank
        # less the values of the bins below its own that were not picked
        kept = np.zeros(_HIST_BINS + 1, np.int64)
        kept[wanted[c] + 1] = counts[c, wanted[c]]
        skipped = cumulative[c] - np.cumsum(kept)
        where = np.searchsorted(cumulative[c], ranks, side="right") - 1
        local = ranks - skipped[where]
        chosen.partition(np.unique(local))
        order = dict(zip(ranks.tolist(), chosen[local].tolist(), strict=True))
        first = np.array([order[r] for r in previous.tolist()])
        second = np.array([order[r] for r in following.tolist()])
        diff = second - first
        value = first + diff * gamma
        np.subtract(second, diff * (1 - gamma), out=value, where=gamma >= 0.5)
        out[:, c] = value
        step += 1  # (the partition of a channel of few distinct values can be long)
        yield Progress(stage_name, step / steps, "order statistics")
    return _f32(out), lo, hi


def _match(values, quantiles, bins=4096):
    """Map each channel of (h, w, d) ``values`` monotonically onto the
    quantile function given by (q, d) ``quantiles`` (equally spaced
    probabilities 0..1, linear in between): histogram matching.

    Each value's probability is read off its channel's empirical CDF, taken
    from a ``bins``-bin histogram (linear within a bin) rather than a full
    sort: O(n) arithmetic, within 1/bins of the exact rank.

    The two end intervals reach the minimum and the maximum, which only a
    handful of pixels of the analysed band attained; spread linearly there,
    1/(q - 1) of the output (3 % for 32 quantiles) would be scattered evenly
    up to the extremes: isolated pixels far brighter or darker than their
    neighbours (the speckle of heavy-tailed band-pass bands). There the
    quantile function follows an exponential tail instead, its scale read off
    the next interval inward, and never goes beyond the linear one.
    """
    return drain(_iter_match(values, quantiles, bins))


# relative costs of the passes of a histogram matching (progress fractions)
_MATCH_PASSES = (1.0, 3.0, 8.0)


def _iter_match(values, quantiles, bins=4096, *, clip=None, out=None, preview=None,
                stage_name="matching"):
    """:func:`_match` as a job, by blocks of rows: the same numbers.

    Three passes, a record after every block: the channels' ranges, their
    histograms (summed over the blocks: the same counts), the mapping.
    ``clip`` (a (2, d) array) clips every mapped channel to its range, as
    ``np.clip`` after the matching would; ``out`` receives the result
    (default a new array); the mapping's records carry ``preview``.
    """
    h, w, d = values.shape
    out = np.empty_like(values) if out is None else out
    q = quantiles.shape[0]
    # the mapping costs about ten passes over a block: smaller blocks
    chunks = _row_chunks(h, w, max(_CHUNK_PIXELS // 4, 1))
    weights = np.repeat(np.array(_MATCH_PASSES) / sum(_MATCH_PASSES) / len(chunks), len(chunks))
    fractions = np.minimum(np.cumsum(weights), 1.0).tolist()
    fractions[-1] = 1.0
    fractions = iter(fractions)
    lo, hi = np.full(d, np.inf), np.full(d, -np.inf)
    for a, b in chunks:
        _kernels.block_range(values[a:b], lo, hi)
        yield Progress(stage_name, next(fractions), f"range, rows {b}/{h}")
    lo, hi = [float(v) for v in lo], [float(v) for v in hi]
    counts = np.zeros((d, bins), np.int64)
    # numpy.histogram's bin edges for range (lo, hi): its index checks use them
    edges = [np.linspace(lo[c], hi[c], bins + 1) if hi[c] > lo[c] else None for c in range(d)]
    for a, b in chunks:
        for c in range(d):
            if hi[c] > lo[c]:
                _kernels.block_histogram(values[a:b], c, lo[c], hi[c], edges[c], counts[c])
        yield Progress(stage_name, next(fractions), f"histogram, rows {b}/{h}")
    cdfs = [np.concatenate([[0.0], np.cumsum(counts[c]) / (h * w)]) for c in range(d)]
    # the exponential tails' scales (see _exponential_tails; 0: none)
    tails = np.zeros((d, 2))
    if q >= 4:
        tails[:, 0] = (quantiles[-2] - quantiles[-3]) / math.log(2.0)
        tails[:, 1] = (quantiles[2] - quantiles[1]) / math.log(2.0)
    bounds = np.zeros((2, d)) if clip is None else np.asarray(clip, np.float64)
    for a, b in chunks:
        for c in range(d):
            if not hi[c] > lo[c]:
                mapped = np.full((b - a, w), quantiles[q // 2, c])
                if clip is not None:
                    mapped = np.clip(mapped, clip[0, c], clip[1, c])
                out[a:b, :, c] = mapped
            else:
                _kernels.block_map(values[a:b], c, lo[c], bins / (hi[c] - lo[c]), cdfs[c],
                                   np.ascontiguousarray(quantiles[:, c], np.float64),
                                   float(tails[c, 0]), float(tails[c, 1]),
                                   float(bounds[0, c]), float(bounds[1, c]), clip is not None,
                                   out[a:b])
        yield Progress(stage_name, next(fractions), f"rows {b}/{h}", preview)
    return out


def _exponential_tails(mapped, pos, k, quantiles):
    """In place: cap the end intervals of :func:`_match` by exponential tails.

    With ``pos`` the probability in units of the quantile spacing, a value in
    the last interval at distance ``t = q - 1 - pos`` (in (0, 1]) from
    probability 1 is mapped to ``q[-2] + s log(1 / t)``, where ``s`` makes the
    tail pass through ``q[-3]`` (``s = (q[-2] - q[-3]) / log 2``): the
    quantile function of an exponential tail. The same mirrored at the
    bottom. Where the next interval is empty (``s = 0``) the linear map
    stays.
    """
    n = quantiles.size
    with np.errstate(divide="ignore"):
        scale = (quantiles[-2] - quantiles[-3]) / math.log(2.0)
        top = k == n - 2
        if scale > 0 and top.any():
            tail = quantiles[-2] - scale * np.log((n - 1) - pos[top])
            mapped[top] = np.minimum(mapped[top], tail)
        scale = (quantiles[2] - quantiles[1]) / math.log(2.0)
        bottom = k == 0
        if scale > 0 and bottom.any():
            tail = quantiles[1] + scale * np.log(pos[bottom])
            mapped[bottom] = np.maximum(mapped[bottom], tail)


def _blend_width(n):
    """Cross-fade band for a periodic level of side ``n``: a quarter of it,
    at least 2 pixels, at most ``n`` (a level of side 1 fades over 1: its
    one pixel is the extra sample, trivially periodic)."""
    return min(max(2, n // 4), n)


def _f32(values):
    """float64 array holding exactly float32-representable values."""
    return np.asarray(values, dtype=np.float64).astype(np.float32).astype(np.float64)


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


@dataclass(eq=False)
class TextureModel:
    """A multiresolution CAR texture model: the compressed texture.

    The texture model of section 14.8 (docs/texture.md). Build one with
    :meth:`fit` (or :func:`iter_fit_texture`) or :meth:`load`; generate
    textures of any size with :meth:`synthesize`. The fields below are
    also the constructor's parameters.

    Parameters
    ----------
    models : tuple of CARModel
        One model per pyramid band, finest first; the last models the low-pass
        residual. Models read by :meth:`load` carry only what synthesis needs
        (``vx`` is NaN; do not use them with :func:`car_napari.predict`).
    band_ranges : (levels, 2, d) ndarray
        Per band, the minimum and maximum of the analysed band; synthesised
        bands are clipped to it (keeps rare outliers of the Gaussian model
        from adding up across levels).
    mean : (d,) ndarray
        Mean of the input, restored after the collapse.
    std : (d,) ndarray
        Standard deviation of the input, restored after the collapse: the
        bands are generated independently, which drops the (positive)
        covariance between neighbouring bands of a real texture and would
        leave the result with about 20 % less contrast.
    value_range : (2, d) ndarray
        Per-channel minimum and maximum of the input; the output is clipped
        to it (the histogram-range restore).
    grey : bool
        True when the input was a 2-D grey image (synthesis then returns 2-D).
    model : {'3d', '2d'}
        The CAR variant of every band (see :func:`car_napari.fit_car`).
    fallbacks : tuple of str
        One entry per band whose first fitted model was unstable, saying what
        was used instead (a lower order, chosen by the decision-rule score
        when the support was 'auto'; as a last resort order 1 with a scaled
        ``gamma``). Empty when every first fit was stable.
    band_quantiles : (levels, 32, d) ndarray or None
        Per band and channel, the quantiles of the analysed band at the
        probabilities 0, 1/31, ..., 1. Every synthesised band is mapped onto
        them by rank (histogram matching): the CAR models are Gaussian, the
        bands of real textures are not (heavy-tailed, skewed), and the local
        sign patterns of a texture (LBP) depend on those marginals. The
        quantile function is linear between them but for the two end
        intervals, which follow an exponential tail up to the minimum and the
        maximum (a linear end interval scatters 1/31 of the pixels evenly up to
        the extremes: isolated speckle). None for models read from version-1
        files (no matching).
    quantiles : (64, d) ndarray or None
        Per channel, the quantiles of the input at 0, 1/63, ..., 1; the
        collapsed output is mapped onto them (the histogram restore, after
        the mean and contrast restore). None for version-1 files (then only
        the mean, contrast and range are restored).
    pyramid : {'gaussian', 'spectral'}
        How the bands split the texture: 'gaussian', the Gaussian-Laplacian
        pyramid (models of format versions 1 and 2); 'spectral', bands that
        share no frequency (what :meth:`fit` makes; see
        ``car_napari/texture/_spectral.py``): independently generated bands
        then keep the texture's spectrum, which overlapping bands lose.
    palette : (k, d) ndarray or None
        Colours of the input (k-means centres, ``k`` at most 32); with
        ``palette_radius`` they bound the synthesis's colours: a pixel
        farther from its nearest palette colour than that colour's radius is
        moved onto the radius, after the histogram restore (see
        ``car_napari/texture/_palette.py``). None for grey models and for
        files before version 3.
    palette_radius : (k,) ndarray or None
        Per palette colour, the distance that holds 95 % of the input's
        (sampled) pixels nearest to it.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import TextureModel
    >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
    >>> model.synthesize((40, 50), seed=0).shape
    (40, 50)
    >>> model.nbytes
    728
    """

    models: tuple
    band_ranges: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    value_range: np.ndarray
    grey: bool
    model: str = "3d"
    fallbacks: tuple = field(default=())
    band_quantiles: np.ndarray = field(default=None)
    quantiles: np.ndarray = field(default=None)
    pyramid: str = "gaussian"
    palette: np.ndarray = field(default=None)
    palette_radius: np.ndarray = field(default=None)

    # ------------------------------------------------------------------ fit
    @classmethod
    def fit(cls, image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
            pyramid="spectral"):
        """Fit a multiresolution CAR model to a texture.

        The same as running :func:`iter_fit_texture` to its end.

        Parameters
        ----------
        image : (H, W) or (H, W, C) array
            The texture; any dtype (integer images are scaled to [0, 1]).
            Every side must be at least ``16 * 2**(levels - 1)`` pixels
            (64 for 3 levels), so that the coarsest band can be modelled.
        levels : int or None, optional
            Number of pyramid bands: ``levels - 1`` band-pass (Laplacian)
            bands plus the low-pass residual. 1 means no pyramid. None (the
            default): 5, or as many as the texture's size allows (see
            above), at least 1.
        model : {'3d', '2d'}, optional
            '3d': one 3DCAR per band with full colour matrices. '2d': per band,
            a spectral PCA and one 2DCAR per factor.
        neighbourhood : 'auto', int or (eta, 2) array, optional
            'auto' chooses each band's support among orders 1 to 5 by the
            decision rule (14.6), independently per band. An int or offsets
            use the same support in every band.
        channel_axis : int or None, optional
            Axis of the channels of a 3-D image (default the last). A 2-D
            image is always grey; None requires one.
        pyramid : {'spectral', 'gaussian'}, optional
            The bands: 'spectral' (default) splits the frequencies so that no
            two bands share one; 'gaussian' is the Gaussian-Laplacian
            pyramid of :func:`laplacian_pyramid` (the models of format
            versions 1 and 2; its bands overlap, and their independent
            synthesis loses the texture's autocorrelation).

        Returns
        -------
        TextureModel
            The fitted model.

        Raises
        ------
        ValueError
            If the texture is too small for the pyramid, constant, or not
            finite, or ``levels``, ``model`` or ``neighbourhood`` is invalid.
        TypeError
            If ``levels`` is not an int, or the image is not numeric.

        See Also
        --------
        iter_fit_texture : The same fit as a job that reports its progress.

        Notes
        -----
        A band whose fitted model is unstable (spectral radius >= 1, its field
        would explode) falls back to a lower order; see ``fallbacks``.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> texture = np.random.default_rng(0).random((64, 64))
        >>> model = TextureModel.fit(texture, levels=2)
        >>> model.levels, model.n_channels, model.grey
        (2, 1, True)
        """
        return drain(iter_fit_texture(image, levels=levels, model=model,
                                      neighbourhood=neighbourhood, channel_axis=channel_axis,
                                      pyramid=pyramid))

    @staticmethod
    def levels_for(shape, most=_AUTO_LEVELS):
        """The pyramid levels ``fit(levels=None)`` uses for a texture of ``shape``.

        Parameters
        ----------
        shape : tuple of int
            (height, width) of the texture.
        most : int, optional
            The most levels wanted (5, the default of :meth:`fit`).

        Returns
        -------
        int
            ``most``, or fewer so that the coarsest band keeps at least 16
            pixels a side; at least 1.

        Examples
        --------
        >>> from car_napari.texture import TextureModel
        >>> TextureModel.levels_for((512, 640)), TextureModel.levels_for((64, 96))
        (5, 3)
        >>> TextureModel.levels_for((512, 512), 2)
        2
        """
        return _auto_levels(shape, most)

    # ----------------------------------------------------------- properties
    @property
    def levels(self):
        """Number of pyramid bands (int).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> model.levels
        2
        """
        return len(self.models)

    @property
    def n_channels(self):
        """Number of channels of the fitted texture (int; 1 for grey).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> model.n_channels
        1
        """
        return int(self.mean.shape[0])

    @property
    def orders(self):
        """Neighbourhood order of every band (tuple; None for a custom support).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2,
        ...                           neighbourhood=1)
        >>> model.orders
        (1, 1)
        """
        return tuple(m.order for m in self.models)

    def _parameter_arrays(self):
        """The arrays that define the model, by file key (see :meth:`save`)."""
        arrays = {"mean": self.mean, "std": self.std, "value_range": self.value_range}
        for k, m in enumerate(self.models):
            arrays[f"band{k}_gamma"] = m.gamma
            arrays[f"band{k}_sigma"] = m.sigma
            arrays[f"band{k}_mean"] = m.mean
            arrays[f"band{k}_offsets"] = m.offsets
            arrays[f"band{k}_range"] = self.band_ranges[k]
            if self.band_quantiles is not None:
                arrays[f"band{k}_quantiles"] = self.band_quantiles[k]
        if self.quantiles is not None:
            arrays["quantiles"] = self.quantiles
        if self.palette is not None:
            arrays["palette"] = self.palette
            arrays["palette_radius"] = self.palette_radius
        return arrays

    @property
    def nbytes(self):
        """Bytes of the stored parameters (int): the compressed size.

        Every number (including the integer offsets) counts as a float32.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> model.nbytes
        728
        """
        return 4 * sum(int(np.size(a)) for a in self._parameter_arrays().values())

    def compression_ratio(self, input_shape):
        """Raw float32 bytes of an image of ``input_shape`` over :attr:`nbytes`.

        Parameters
        ----------
        input_shape : tuple of int
            (H, W) (then ``H * W * n_channels`` values) or (H, W, C). The model
            synthesises any size, so the ratio grows with the size.

        Returns
        -------
        float
            ``4 * number of values / nbytes``.

        Raises
        ------
        ValueError
            If ``input_shape`` is not (H, W) or (H, W, C) with positive sides.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> round(model.compression_ratio((512, 512)), 1)
        1440.4
        """
        shape = check_shape(input_shape, "input_shape ((H, W) or (H, W, C))")
        values = math.prod(shape) * (self.n_channels if len(shape) == 2 else 1)
        return 4.0 * values / self.nbytes

    # ------------------------------------------------------------ synthesis
    def synthesize(self, shape, *, seed=None, tileable=False):
        """Generate a texture of any size from the model.

        Every band is generated from its CAR model at its pyramid size
        (synthesis, docs/model.md), mapped by rank onto the band's stored
        quantiles (histogram matching) and clipped to its analysed range; the pyramid is collapsed
        (expand and add, as in the analysis); the input's per-channel mean
        and standard deviation are restored, the result is mapped onto the
        input's stored quantiles and clipped to its value range (the
        histogram restore). The matching is monotone per pixel value, so
        it keeps a tileable texture periodic.

        Parameters
        ----------
        shape : tuple of 2 ints
            (height, width) of the output; any size of at least 1 x 1.
        seed : int, numpy Generator or None, optional
            The same seed gives the same texture.
        tileable : bool, optional
            Make the texture periodic: tiles placed side by side (or the
            texture wrapped on a torus) show no seam. Each band is generated
            larger and its opposite edges cross-faded over a quarter of its
            size; the pyramid is collapsed with periodic expansion.

        Returns
        -------
        texture : (H, W) or (H, W, C) ndarray of float64
            2-D when the model was fitted to a grey image, channel-last
            otherwise.

        Raises
        ------
        ValueError
            If ``shape`` is not two positive sizes.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> texture = model.synthesize((30, 40), seed=1, tileable=True)
        >>> texture.shape
        (30, 40)
        >>> np.array_equal(texture, model.synthesize((30, 40), seed=1, tileable=True))
        True
        """
        return drain(self.iter_synthesize(shape, seed=seed, tileable=tileable))

    def iter_synthesize(self, shape, *, seed=None, tileable=False):
        """Generate a texture from the model, as a job: Progress, then the texture.

        The generator form of :meth:`synthesize`, with the same parameters
        and, bit for bit, the same result. Every part runs by blocks of rows
        with a :class:`~car_napari.Progress` record between them (each
        band's field by :func:`~car_napari.iter_synthesize`, its tiling,
        its histogram matching; the collapse; the restore of the mean,
        contrast and histogram), so closing the generator (a Cancel) stops
        the synthesis within a fraction of a second even at 4000 x 4000.

        Parameters
        ----------
        shape : tuple of 2 ints
            (height, width) of the output; any size of at least 1 x 1.
        seed : int, numpy Generator or None, optional
            The same seed gives the same texture.
        tileable : bool, optional
            Make the texture periodic (see :meth:`synthesize`).

        Returns
        -------
        texture : (H, W) or (H, W, C) ndarray of float64
            What :meth:`synthesize` returns.

        Yields
        ------
        Progress
            Stage ``"synthesis"`` (each band's field, tiling and matching,
            message ``"band 2/3, rows 512/1024"``), ``"collapse"``, then
            ``"restore"`` (the mean, contrast and histogram of the input);
            fractions in proportion to each part's measured cost. The
            records of the last pass carry a preview: the texture filling in
            (rows not yet done are 0; it is the array returned, do not
            modify it).

        Raises
        ------
        ValueError
            If ``shape`` is not two positive sizes (before the first record).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari._progress import drain
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> records = []
        >>> texture = drain(model.iter_synthesize((30, 40), seed=1), records.append)
        >>> list(dict.fromkeys(r.stage for r in records))
        ['synthesis', 'collapse', 'restore']
        >>> records[-1].fraction, np.array_equal(texture, model.synthesize((30, 40), seed=1))
        (1.0, True)
        """
        h, w = output_shape(shape)
        if not isinstance(tileable, (bool, np.bool_)):
            raise TypeError(f"tileable must be True or False; got {tileable!r}.")
        check_memory(_SYNTHESIS_COPIES * 8 * h * w * self.n_channels, f"shape {(h, w)}")
        rng = check_seed(seed)
        spectral = self.pyramid == "spectral"
        # one independent stream per band, fixed by the seed
        streams = [np.random.default_rng(s) for s in rng.integers(0, 2**63, size=self.levels)]
        shapes = _level_shapes((h, w), self.levels)
        made = [(hk + _blend_width(hk), wk + _blend_width(wk)) if tileable else (hk, wk)
                for hk, wk in shapes]
        # the shares of the work, in values times their measured cost a value
        d = self.n_channels
        parts = []
        for k, (model, (hk, wk), (gh, gw)) in enumerate(
                zip(self.models, shapes, made, strict=True)):
            split = spectral and k < self.levels - 1  # a band-pass band's projection
            parts += [gh * gw * (_COST_FIELD * d + model.gamma.size + d * d + 8),
                      _COST_TORUS * hk * wk * d if tileable else 0.0,
                      _COST_SPLIT * hk * wk * d if split else 0.0,
                      (_COST_MATCH if self.band_quantiles is not None else 1.0) * hk * wk * d]
        parts += [_COST_COLLAPSE * sum(hk * wk for hk, wk in shapes[:-1]) * d,
                  (_COST_RESTORE + (_COST_MATCH if self.quantiles is not None else 1.0))
                  * h * w * d]
        edges = (np.concatenate([[0.0], np.cumsum(parts)]) / sum(parts)).tolist()
        bands = []
        for k, (model, (hk, wk), (gh, gw)) in enumerate(
                zip(self.models, shapes, made, strict=True)):
            part = f"band {k + 1}/{self.levels}, "
            e = edges[4 * k : 4 * k + 5]
            margin = burn_in(cached_radius(model), _BAND_TRANSIENT)
            field = yield from stage(iter_synthesize(model, (gh, gw), seed=streams[k],
                                                     margin=margin),
                                     e[0], e[1], prefix=part, name="synthesis")
            band = field.reshape(gh, gw, -1)
            if tileable:
                band = yield from stage(_iter_torus(band, (hk, wk), model.mean), e[1], e[2],
                                        prefix=part, name="synthesis")
            if spectral and k < self.levels - 1:
                # a CAR field covers every frequency: keep its band's only
                band = yield from stage(_spectral.iter_highpass(band, wrap=bool(tileable)),
                                        e[2], e[3], prefix=part, name="synthesis")
            bounds = self.band_ranges[k]
            if self.band_quantiles is not None:
                band = yield from stage(_iter_match(band, self.band_quantiles[k], clip=bounds),
                                        e[3], e[4], prefix=part + "matching, ",
                                        name="synthesis")
            else:
                band = yield from stage(_iter_clip(band, bounds), e[3], e[4], prefix=part,
                                        name="synthesis")
            bands.append(band)
        if spectral:
            out = yield from stage(_spectral.iter_collapse(bands, wrap=bool(tileable)),
                                   edges[-3], edges[-2])
        else:
            out = yield from stage(_iter_collapse(bands, bool(tileable)), edges[-3], edges[-2])
        del bands
        result = np.zeros((h, w, d))
        shown = result[..., 0] if self.grey else result
        last = _COST_MATCH if self.quantiles is not None else 1.0
        middle = edges[-2] + (1.0 - edges[-2]) * _COST_RESTORE / (_COST_RESTORE + last)
        out = yield from stage(_iter_restore(out, self.mean, self.std), edges[-2], middle,
                               name="restore")
        if self.quantiles is not None:
            final = _iter_match(out, self.quantiles, clip=self.value_range, out=result,
                                preview=shown)
        else:
            final = _iter_clip(out, self.value_range, out=result, preview=shown)
        end = 1.0 if self.palette is None else middle + 0.8 * (1.0 - middle)
        yield from stage(final, middle, end, name="restore", prefix="histogram, ")
        if self.palette is not None:
            for a, b in _row_chunks(h, w):
                _palette.snap(result[a:b], self.palette, self.palette_radius, out=result[a:b])
                yield Progress("restore", end + (1.0 - end) * b / h, f"colours, rows {b}/{h}",
                               shown)
        return shown

    # ---------------------------------------------------------- persistence
    def save(self, path):
        """Write the model to an ``.npz`` file.

        Format (version 3): a compressed NumPy ``.npz`` archive (no pickles) holding

        - ``header``: a JSON string ``{"format": "car-napari texture model",
          "version": 3, "levels": L, "n_channels": d, "grey": bool,
          "model": "3d"|"2d", "direction": [...], "order": [...], "beta": [...],
          "n_pixels": [...], "fallbacks": [...], "pyramid": {...}}``;
        - ``mean`` (d,), ``std`` (d,), ``value_range`` (2, d) and, per band ``k``,
          ``band{k}_gamma`` (d, d*eta), ``band{k}_sigma`` (d, d),
          ``band{k}_mean`` (d,), ``band{k}_offsets`` (eta, 2) int16,
          ``band{k}_range`` (2, d), ``band{k}_quantiles`` (32, d);
          ``quantiles`` (64, d) (the quantiles at equally spaced
          probabilities from 0 to 1, see :attr:`band_quantiles`); from
          version 3, for colour models, ``palette`` (k, d) and
          ``palette_radius`` (k,) (see :attr:`palette`).

        The header's ``pyramid`` names the kind of pyramid
        (``{"kind": "spectral"}`` or ``{"kind": "gaussian", ...}``, see
        :attr:`pyramid`). Version 2 is the same with a Gaussian pyramid
        always (its ``pyramid`` has no ``kind``); version 1 is version 2
        without the quantiles. :meth:`load` reads all three (a version-1
        model synthesises without histogram matching).

        Numbers are stored as float32 (offsets as int16); :meth:`fit` rounds
        the parameters to float32 already, so a loaded model synthesises
        exactly what the original does. :attr:`nbytes` counts 4 bytes a
        number (2 an offset coordinate would do; we count 4).

        Parameters
        ----------
        path : str or path-like
            Destination; NumPy adds ``.npz`` when the name has no suffix.

        Raises
        ------
        OSError
            If the file cannot be written; IsADirectoryError (before
            anything is written) if ``path`` is an existing folder.
        TypeError
            If ``path`` is not a file name (a str or path-like object).

        See Also
        --------
        load : Read the file back.

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = os.path.join(folder, "noise.npz")
        ...     model.save(path)
        ...     loaded = TextureModel.load(path)
        >>> loaded.levels, loaded.nbytes == model.nbytes
        (2, True)
        """
        header = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "levels": self.levels,
            "n_channels": self.n_channels,
            "grey": bool(self.grey),
            "model": self.model,
            "direction": [m.direction for m in self.models],
            "order": [m.order for m in self.models],
            "beta": [float(m.beta) for m in self.models],
            "n_pixels": [int(m.n_pixels) for m in self.models],
            "fallbacks": list(self.fallbacks),
            "pyramid": ({"kind": "spectral", "split": "lowest ceil(n/2) cosine (DCT-II) "
                         "frequencies per axis; Fourier ones when tileable"}
                        if self.pyramid == "spectral" else
                        {"kind": "gaussian", "blur_sigma": _BLUR_SIGMA,
                         "expand": "Keys cubic convolution, pixel extents aligned"}),
        }
        check_path(path)
        if os.path.isdir(path):  # np.savez would write "<folder>.npz" beside it
            raise IsADirectoryError(
                f"{os.fsdecode(path)!r} is an existing folder; pass a file name, e.g. "
                f"{os.path.join(os.fsdecode(path), 'texture.npz')!r}.")
        arrays = {key: (a.astype(np.int16) if key.endswith("_offsets") else
                        np.asarray(a, np.float64).astype(np.float32))
                  for key, a in self._parameter_arrays().items()}
        np.savez_compressed(path, header=np.array(json.dumps(header)), **arrays)

    @classmethod
    def load(cls, path):
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : str or path-like
            An ``.npz`` file of format version 1, 2 or 3.

        Returns
        -------
        TextureModel
            The model; it synthesises exactly what the saved one did. Its band
            models carry only what synthesis needs (``vx`` is NaN).

        Raises
        ------
        ValueError
            If the file is not a readable texture model, or was written by a
            newer version of the format than this code reads.
        FileNotFoundError
            If ``path`` does not exist.
        TypeError
            If ``path`` is not a file name (a str or path-like object; an int
            would be taken for a file descriptor).

        See Also
        --------
        save : The file format.

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     model.save(os.path.join(folder, "noise.npz"))
        ...     loaded = TextureModel.load(os.path.join(folder, "noise.npz"))
        >>> np.array_equal(loaded.synthesize((20, 20), seed=0), model.synthesize((20, 20), seed=0))
        True
        """
        arrays, header, version = _read_model_file(path)
        try:
            model = cls._from_arrays(header, arrays, version)
        except (KeyError, ValueError, TypeError, IndexError, np.linalg.LinAlgError) as exc:
            raise ValueError(
                f"{path} is a damaged texture model: {type(exc).__name__}: {exc}."
            ) from exc
        for k, band in enumerate(model.models):
            radius = cached_radius(band)  # synthesis asks again: remembered
            if not radius < 1.0:
                raise ValueError(
                    f"{path} is a damaged texture model: band {k} is unstable (spectral "
                    f"radius {radius:.4g} >= 1), its field would grow without bound."
                )
        return model

    @classmethod
    def _from_arrays(cls, header, arrays, version=FORMAT_VERSION):
        levels, d = int(header["levels"]), int(header["n_channels"])
        mean = np.asarray(arrays["mean"], float).reshape(d)
        std = np.asarray(arrays["std"], float).reshape(d)
        value_range = np.asarray(arrays["value_range"], float).reshape(2, d)
        models, ranges, band_quantiles, quantiles = [], [], [], None
        if version >= 2:
            quantiles = np.asarray(arrays["quantiles"], float).reshape(-1, d)
        for k in range(levels):
            gamma = np.asarray(arrays[f"band{k}_gamma"], float)
            offsets, _ = as_offsets(np.asarray(arrays[f"band{k}_offsets"]))
            eta = len(offsets)
            gamma = gamma.reshape(d, d * eta)
            sigma = np.asarray(arrays[f"band{k}_sigma"], float).reshape(d, d)
            beta = float(header["beta"][k])
            if not (np.all(np.isfinite(gamma)) and np.all(np.isfinite(sigma))):
                raise ValueError(f"band {k} has non-finite parameters")
            models.append(CARModel(
                gamma=gamma, sigma=sigma,
                mean=np.asarray(arrays[f"band{k}_mean"], float).reshape(d),
                offsets=offsets, lam=sigma * beta,
                vx=np.full((d * eta, d * eta), np.nan),  # not stored: synthesis does not need it
                beta=beta, n_pixels=int(header["n_pixels"][k]),
                order=header["order"][k], direction=str(header["direction"][k]),
            ))
            ranges.append(np.asarray(arrays[f"band{k}_range"], float).reshape(2, d))
            if version >= 2:
                band_quantiles.append(
                    np.asarray(arrays[f"band{k}_quantiles"], float).reshape(-1, d)
                )
        return cls(
            models=tuple(models), band_ranges=np.stack(ranges), mean=mean, std=std,
            value_range=value_range, grey=bool(header["grey"]),
            model=str(header.get("model", "3d")),
            fallbacks=tuple(header.get("fallbacks", ())),
            band_quantiles=np.stack(band_quantiles) if version >= 2 else None,
            quantiles=quantiles, pyramid=_pyramid_kind(header, version),
            palette=(np.asarray(arrays["palette"], float).reshape(-1, d)
                     if "palette" in arrays else None),
            palette_radius=(np.asarray(arrays["palette_radius"], float).reshape(-1)
                            if "palette" in arrays else None),
        )


def _pyramid_kind(header, version):
    """The pyramid of a model file: 'gaussian' before version 3, else the
    header's ``pyramid.kind``."""
    if version < 3:
        return "gaussian"
    kind = header.get("pyramid", {}).get("kind") if isinstance(header.get("pyramid"),
                                                                dict) else None
    if kind not in PYRAMIDS:
        raise ValueError(f"the format-version-{version} header names pyramid kind {kind!r}, "
                         f"not one of {PYRAMIDS}")
    return kind


# ------------------------------------------------------------ model files
# What a model file may hold (the loader refuses anything else before reading
# it): the bounds of the format, far beyond what a fit produces (order 5
# reaches 2 pixels with 12 offsets, order 30 reaches 8 with 106).
MAX_FILE_LEVELS = 8
MAX_FILE_CHANNELS = 64
MAX_FILE_REACH = 16  # largest |di| or |dj| of a neighbour offset
MAX_FILE_OFFSETS = 256  # largest number of offsets per band
_MAX_FILE_QUANTILES = 4096
_MAX_FILE_PALETTE = 4096  # colours of a palette
_HEADER_BYTES = 1 << 16  # the JSON header's largest size
_NPY_HEADER_BYTES = 1 << 12  # room for an .npy member's own header


def _model_file_error(path, what):
    return ValueError(f"{path} is not a readable car-napari texture model (.npz): {what}. "
                      "Re-save the model with TextureModel.save.")


def _read_member(archive, path, key, *, kinds, count=None, max_count=None):
    """The array ``key`` of the open ``archive``: its declared sizes and its
    .npy header checked before any of its data is read (a bounded read)."""
    try:
        info = archive.getinfo(key + ".npy")
    except KeyError:
        raise ValueError(f"{path} is a damaged texture model: member {key!r} is missing."
                         ) from None
    if max_count is None:
        max_count = count
    limit = _NPY_HEADER_BYTES + 8 * max_count if kinds != "U" else _HEADER_BYTES
    if info.file_size > limit:
        raise ValueError(
            f"{path} is a damaged texture model: member {key!r} declares "
            f"{info.file_size} bytes, more than the {limit} it can take."
        )
    with archive.open(info) as stream:
        try:
            major, _ = np.lib.format.read_magic(stream)
            reader = (np.lib.format.read_array_header_1_0 if major == 1
                      else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = reader(stream)
        except ValueError as exc:
            raise ValueError(f"{path} is a damaged texture model: member {key!r} is not a "
                             f"NumPy array ({exc}).") from None
        if dtype.hasobject or dtype.kind not in kinds:
            raise ValueError(
                f"{path} is a damaged texture model: member {key!r} has dtype {dtype} "
                f"(allowed kinds {kinds!r}; objects and pickles are refused)."
            )
        n = math.prod(shape)
        if (count is not None and n != count) or (max_count is not None and n > max_count) \
                or n == 0:
            want = count if count is not None else f"1 to {max_count}"
            raise ValueError(
                f"{path} is a damaged texture model: member {key!r} has shape {shape} "
                f"({n} values) but needs {want}."
            )
        data = stream.read(n * dtype.itemsize)
    if len(data) != n * dtype.itemsize:
        raise ValueError(f"{path} is a damaged texture model: member {key!r} is truncated.")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def _header_value(header, path, key, kind, low, high):
    value = header.get(key)
    if isinstance(value, bool) or not isinstance(value, kind) or not low <= value <= high:
        raise ValueError(f"{path} has an invalid texture-model header: {key!r} is "
                         f"{value!r}, not in {low} to {high}.")
    return value


def _check_header(header, path):
    """The header's fields that decide what is read, checked (the rest is
    checked as the model is built)."""
    levels = _header_value(header, path, "levels", int, 1, MAX_FILE_LEVELS)
    d = _header_value(header, path, "n_channels", int, 1, MAX_FILE_CHANNELS)
    for key in ("beta", "n_pixels", "order", "direction"):
        if not isinstance(header.get(key), list) or len(header[key]) != levels:
            raise ValueError(f"{path} has an invalid texture-model header: {key!r} must be "
                             f"a list of {levels} entries.")
    for k in range(levels):
        beta, n_pixels = header["beta"][k], header["n_pixels"][k]
        order, direction = header["order"][k], header["direction"][k]
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) \
                or not math.isfinite(beta) or beta < 0:
            raise ValueError(f"{path} has an invalid texture-model header: beta of band {k} "
                             f"is {beta!r}.")
        if isinstance(n_pixels, bool) or not isinstance(n_pixels, int) or n_pixels < 0:
            raise ValueError(f"{path} has an invalid texture-model header: n_pixels of band "
                             f"{k} is {n_pixels!r}.")
        if order is not None and (isinstance(order, bool) or not isinstance(order, int)):
            raise ValueError(f"{path} has an invalid texture-model header: order of band {k} "
                             f"is {order!r}.")
        if direction not in DIRECTIONS:
            raise ValueError(f"{path} has an invalid texture-model header: direction of band "
                             f"{k} is {direction!r}, not one of {DIRECTIONS}.")
    if not isinstance(header.get("grey"), bool) or (header["grey"] and d != 1):
        raise ValueError(f"{path} has an invalid texture-model header: grey is "
                         f"{header.get('grey')!r} for {d} channels.")
    if header.get("model", "3d") not in ("3d", "2d"):
        raise ValueError(f"{path} has an invalid texture-model header: model is "
                         f"{header.get('model')!r}.")
    fallbacks = header.get("fallbacks", [])
    if not isinstance(fallbacks, list) or not all(isinstance(f, str) for f in fallbacks):
        raise ValueError(f"{path} has an invalid texture-model header: fallbacks is "
                         f"{fallbacks!r}.")
    return levels, d


def _check_parameters(arrays, path, levels, d):
    """Every stored number finite and every array consistent: ranges
    ordered, quantiles non-decreasing, covariances symmetric positive
    semi-definite, offsets causal and within the format's bounds."""
    for key, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{path} is a damaged texture model: {key} holds NaN or "
                             "infinite values.")
    if np.any(arrays["std"] < 0):
        raise ValueError(f"{path} is a damaged texture model: std is negative.")
    if "palette" in arrays and (arrays["palette"].size % d
                                or np.any(arrays["palette_radius"] < 0)):
        raise ValueError(f"{path} is a damaged texture model: the palette has "
                         f"{arrays['palette'].size} values for {d} channels or a negative "
                         "radius.")
    keys = ["value_range"] + [f"band{k}_range" for k in range(levels)]
    for key in keys:
        lo, hi = arrays[key].reshape(2, d)
        if np.any(lo > hi):
            raise ValueError(f"{path} is a damaged texture model: {key} has its minimum "
                             "above its maximum.")
    for key in [k for k in arrays if k.endswith("quantiles")]:
        if arrays[key].size % d or arrays[key].size < 2 * d:
            raise ValueError(f"{path} is a damaged texture model: {key} has "
                             f"{arrays[key].size} values, not at least 2 per channel.")
        if np.any(np.diff(arrays[key].reshape(-1, d), axis=0) < 0):
            raise ValueError(f"{path} is a damaged texture model: {key} are not "
                             "non-decreasing.")
    for k in range(levels):
        offsets = arrays[f"band{k}_offsets"]
        if np.abs(offsets).max() > MAX_FILE_REACH:
            raise ValueError(
                f"{path} is a damaged texture model: band {k} has a neighbour offset "
                f"reaching {int(np.abs(offsets).max())} pixels (the format allows at most "
                f"{MAX_FILE_REACH})."
            )
        sigma = arrays[f"band{k}_sigma"].reshape(d, d).astype(float)
        scale = max(float(np.abs(sigma).max()), np.finfo(float).tiny)
        symmetric = np.abs(sigma - sigma.T).max() <= 1e-5 * scale
        if not symmetric or np.linalg.eigvalsh(sigma).min() < -1e-5 * scale:
            raise ValueError(f"{path} is a damaged texture model: band {k}'s covariance "
                             "is not symmetric positive semi-definite.")


def _read_model_file(path):
    """The header, the arrays and the format version of a model file, every
    member checked before it is read; a ValueError naming the file and what
    is wrong for anything else."""
    check_path(path)
    try:
        with open(path, "rb") as file:
            magic = file.read(6)
    except FileNotFoundError:
        raise
    except (OSError, TypeError) as exc:
        raise _model_file_error(path, exc) from exc
    if magic == b"\x93NUMPY":
        raise _model_file_error(path, "it is a single NumPy array (.npy), not the .npz "
                                "archive TextureModel.save writes")
    try:
        with zipfile.ZipFile(path) as archive:
            return _read_members(archive, path)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError,
            RuntimeError) as exc:
        raise _model_file_error(path, f"{type(exc).__name__}: {exc}") from exc


def _read_members(archive, path):
    if "header.npy" not in archive.namelist():
        raise ValueError(f"{path} has no texture-model header; it was not written by "
                         "TextureModel.save or is corrupt.")
    text = _read_member(archive, path, "header", kinds="U", max_count=1)
    try:
        header = json.loads(str(text.reshape(())))
    except (ValueError, TypeError) as exc:
        raise ValueError(
            f"{path} has no valid texture-model header ({exc}); it was not written "
            "by TextureModel.save or is corrupt."
        ) from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise ValueError(
            f"{path} is not a car-napari texture model (format "
            f"{header.get('format') if isinstance(header, dict) else header!r})."
        )
    version = header.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ValueError(f"{path} has an invalid format version {version!r}.")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{path} uses texture-model format version {version}, newer than this "
            f"car-napari reads (up to {FORMAT_VERSION}); upgrade car-napari to load it."
        )
    levels, d = _check_header(header, path)
    floats = "fi"
    read = partial(_read_member, archive, path)
    arrays = {"mean": read("mean", kinds=floats, count=d),
              "std": read("std", kinds=floats, count=d),
              "value_range": read("value_range", kinds=floats, count=2 * d)}
    if version >= 2:
        arrays["quantiles"] = read("quantiles", kinds=floats,
                                   max_count=_MAX_FILE_QUANTILES * d)
    if version >= 3 and "palette.npy" in archive.namelist():
        arrays["palette"] = read("palette", kinds=floats, max_count=_MAX_FILE_PALETTE * d)
        arrays["palette_radius"] = read("palette_radius", kinds=floats,
                                        count=arrays["palette"].size // d)
    for k in range(levels):
        offsets = read(f"band{k}_offsets", kinds="iu", max_count=2 * MAX_FILE_OFFSETS)
        arrays[f"band{k}_offsets"] = offsets
        eta = offsets.size // 2
        arrays[f"band{k}_gamma"] = read(f"band{k}_gamma", kinds=floats, count=d * d * eta)
        arrays[f"band{k}_sigma"] = read(f"band{k}_sigma", kinds=floats, count=d * d)
        arrays[f"band{k}_mean"] = read(f"band{k}_mean", kinds=floats, count=d)
        arrays[f"band{k}_range"] = read(f"band{k}_range", kinds=floats, count=2 * d)
        if version >= 2:
            arrays[f"band{k}_quantiles"] = read(f"band{k}_quantiles", kinds=floats,
                                                max_count=_MAX_FILE_QUANTILES * d)
    _check_parameters(arrays, path, levels, d)
    return arrays, header, version


def iter_fit_texture(image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
                     pyramid="spectral"):
    """Fit a multiresolution CAR texture model, as a job reporting progress.

    The generator form of :meth:`TextureModel.fit` (same arguments, same
    result): every long pass runs by blocks of rows with a
    :class:`~car_napari.Progress` record between them (the reading of the
    image, its quantiles, the pyramid, each band's fit by
    :func:`~car_napari.iter_fit_car`, the bands' quantiles), a last record
    comes when all is done, and it returns the :class:`TextureModel`.
    Closing the generator (a Cancel) stops the fit at the next record.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The texture; see :meth:`TextureModel.fit`.
    levels : int or None, optional
        Number of pyramid bands (None: as many as the size allows, up to 5).
    model : {'3d', '2d'}, optional
        The CAR variant of every band.
    neighbourhood : 'auto', int or (eta, 2) array, optional
        The support of every band; 'auto' chooses it per band.
    channel_axis : int or None, optional
        Axis of the channels of a 3-D image; a 2-D image is always grey.
    pyramid : {'spectral', 'gaussian'}, optional
        The kind of pyramid (see :meth:`TextureModel.fit`).

    Returns
    -------
    TextureModel
        The fitted model (the generator's return value).

    Yields
    ------
    Progress
        Stage ``"reading"`` (the conversion to float, ``"rows 512/2048"``),
        ``"quantiles"`` (message ``"texture, histogram"``), then
        ``"pyramid"`` (``"band 1/3, rows 512/1024"``), then ``"fitting"``,
        the records of each band's fit (``"level 2/3: rows 120/512"``,
        ``"level 2/3: order 3: D = ..."``), then ``"quantiles"`` of every
        band and a last ``"fitting"`` record at fraction 1. ``fraction``
        grows in proportion to the work: each part costs about its pixels.

    Raises
    ------
    ValueError
        As :meth:`TextureModel.fit`: bad options, layout or size before the
        first record; non-finite or constant values while the image is read
        (the first records).
    TypeError
        As :meth:`TextureModel.fit`, before the first record.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import iter_fit_texture
    >>> texture = np.random.default_rng(0).random((64, 64))
    >>> records = list(iter_fit_texture(texture, levels=2))
    >>> list(dict.fromkeys(r.stage for r in records))  # in their order
    ['reading', 'quantiles', 'pyramid', 'fitting']
    >>> all(a.fraction <= b.fraction for a, b in zip(records, records[1:]))
    True
    >>> records[-1].message, records[-1].fraction
    ('2 levels fitted', 1.0)
    """
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
    return TextureModel(
        models=tuple(models), band_ranges=_f32(band_ranges), mean=_f32(summary.mean),
        std=_f32(np.sqrt(np.asarray(summary.var, float))),
        value_range=_f32(np.stack([summary.min, summary.max])), grey=grey,
        model=model, fallbacks=tuple(fallbacks), band_quantiles=band_quantiles,
        quantiles=quantiles, pyramid=pyramid, palette=palette, palette_radius=radius,
    )
