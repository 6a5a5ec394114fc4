"""The Gaussian-Laplacian pyramid (Burt and Adelson) of the texture model:
``reduce``, the cubic ``expand``, the bands and their collapse, each by
blocks of rows; the public :func:`laplacian_pyramid` and
:func:`collapse_pyramid`. The operators are described in ``_model.py``."""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from .._progress import Progress, drain, stage
from .._validation import as_channel_last_float, check_axis, check_flag
from ._blocks import _row_chunks

_BLUR_SIGMA = 1.0  # pyramid smoothing before 2x2 decimation, in pixels
_BLUR_HALO = 8  # rows beyond a block that its blur reads (the kernel reaches 4)


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

