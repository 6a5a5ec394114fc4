"""Input checks shared by every public function: fail early, say what to do."""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def channel_summary(data):
    """One pass over (N, d) data: per-channel min, max, mean, variance, and
    the count of non-finite values (which are left out of the others)."""
    n, d = data.shape
    out = np.zeros((5, d))
    lo = np.full(d, np.inf)
    hi = np.full(d, -np.inf)
    total = np.zeros(d)
    count = np.zeros(d)
    bad = np.zeros(d)
    for i in range(n):
        for c in range(d):
            val = data[i, c]
            if math.isfinite(val):
                lo[c] = min(lo[c], val)
                hi[c] = max(hi[c], val)
                total[c] += val
                count[c] += 1.0
            else:
                bad[c] += 1.0
    for c in range(d):
        mean = total[c] / max(count[c], 1.0)
        acc = 0.0
        for i in range(n):
            val = data[i, c]
            if math.isfinite(val):
                acc += (val - mean) * (val - mean)
        out[0, c] = lo[c]
        out[1, c] = hi[c]
        out[2, c] = mean
        out[3, c] = acc / max(count[c], 1.0)
        out[4, c] = bad[c]
    return out


def as_channel_last_float(image, *, channel_axis=-1, name="image", with_summary=False,
                          copy=True):
    """Return ``image`` as a C-contiguous float64 array of shape (H, W, d)
    (and its :func:`summarize`, computed anyway, with ``with_summary``).

    Integer images are scaled to [0, 1] like ``skimage.util.img_as_float``;
    float images keep their values. ``channel_axis=None`` means a grey image.
    The input is never modified (a copy is made whenever the dtype or layout
    changes; a float64 C-contiguous input is copied too, so callers may write,
    unless ``copy`` is False: then it may be returned as it is, read only).
    """
    if image is None:
        raise TypeError(f"{name} is None: pass a 2-D grey or 3-D multichannel array.")
    try:
        arr = np.asarray(image)
    except Exception as exc:  # pragma: no cover - exotic array-likes
        raise TypeError(f"{name} could not be converted to an array: {exc}") from exc
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(
            f"{name} has dtype {arr.dtype}; pass a numeric (integer or float) array."
        )
    if arr.size == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}); pass a non-empty image.")
    if arr.ndim == 2:
        arr = arr[..., np.newaxis]
    elif arr.ndim == 3:
        if channel_axis is None:
            raise ValueError(
                f"{name} is 3-D {arr.shape} but channel_axis=None; pass the channel "
                "axis (e.g. channel_axis=-1 for (H, W, C)) or a 2-D grey image."
            )
        arr = np.moveaxis(arr, channel_axis, -1)
    else:
        raise ValueError(
            f"{name} must be 2-D (H, W) or 3-D (H, W, C) with channel_axis; got "
            f"{arr.ndim}-D shape {arr.shape}. For a stack, pass one image at a time."
        )
    if arr.dtype.kind in "biu":
        if arr.dtype.kind == "b":
            out = arr.astype(np.float64)
        else:
            info = np.iinfo(arr.dtype)
            out = arr.astype(np.float64) / info.max
            if info.min < 0:
                out = np.maximum(out, -1.0)
    else:
        out = arr.astype(np.float64, copy=copy)
    out = np.ascontiguousarray(out)
    if out.shape[-1] > 64:
        raise ValueError(
            f"{name} has {out.shape[-1]} channels on axis {channel_axis}; is the channel "
            "axis right? Pass channel_axis=None for a grey image or the correct axis."
        )
    summary = summarize(out)
    check_values(summary, name=name)
    return (out, summary) if with_summary else out


# The models square the values (covariances, data matrices): beyond this
# magnitude the squares leave float64's range (about 1e-308 to 1e308).
MAGNITUDE_LIMIT = 1e150


def check_values(summary, *, name="image"):
    """Finite values of a magnitude whose squares float64 holds (from
    :func:`summarize`), or a ValueError that says what to do."""
    if summary.nonfinite.any():
        bad = int(summary.nonfinite.sum())
        raise ValueError(
            f"{name} contains {bad} NaN or infinite values; fill or mask them first "
            "(e.g. np.nan_to_num, or restrict the fit to a finite rectangle)."
        )
    largest = float(np.max(np.maximum(np.abs(summary.min), np.abs(summary.max))))
    spread = summary.max - summary.min
    smallest = float(np.min(spread[spread > 0])) if np.any(spread > 0) else None
    if largest > MAGNITUDE_LIMIT or (smallest is not None and smallest < 1 / MAGNITUDE_LIMIT):
        size = largest if largest > MAGNITUDE_LIMIT else smallest
        raise ValueError(
            f"{name} has values of magnitude {size:.3g}: the model's variances (their "
            "squares) would leave float64's range. Rescale it to a moderate range first "
            f"(e.g. divide by {size:.3g}) and scale the result back."
        )


Summary = namedtuple("Summary", "min max mean var nonfinite")


def summarize(image):
    """Per-channel min, max, mean, variance and non-finite count of (H, W, d)
    in one Numba pass (numpy's axis=(0, 1) reductions take several slow
    passes over channel-last data)."""
    return Summary(*channel_summary(image.reshape(-1, image.shape[-1])))


def check_not_constant(image, *, name="image", summary=None):
    """A CAR model needs variation: a constant channel has no texture to fit."""
    summary = summary if summary is not None else summarize(image)
    spread = summary.max - summary.min
    scale = np.maximum(np.abs(summary.max), np.abs(summary.min))
    flat = np.flatnonzero((spread == 0) | (spread <= 1e-12 * scale))
    if flat.size:
        raise ValueError(
            f"{name} is constant in channel(s) {flat.tolist()}: a CAR model needs "
            "texture to estimate. Select a textured region or drop the flat channel."
        )


def check_size(image, reach, *, minimum_pixels=1, name="image"):
    """The image must be larger than the neighbourhood with pixels to spare."""
    (top, bottom), (left, right) = reach
    h, w = image.shape[:2]
    usable = max(h - top - bottom, 0) * max(w - left - right, 0)
    if usable < minimum_pixels:
        raise ValueError(
            f"{name} of size {h}x{w} is too small for this neighbourhood (it reaches "
            f"{top} rows up, {left} columns left and {right} right): only {usable} pixels "
            f"have a complete neighbourhood and at least {minimum_pixels} are needed. "
            "Use a larger image or a lower order."
        )


def output_shape(shape):
    """(height, width) as positive ints, or a ValueError that says so."""
    try:
        h, w = (int(v) for v in shape)
    except Exception:
        raise ValueError(f"shape must be (height, width); got {shape!r}.") from None
    if h < 1 or w < 1:
        raise ValueError(f"shape must be positive; got {(h, w)}.")
    return h, w


def float_range(image):
    """The smallest and largest value of ``image`` in the core's float units.

    The core works on integer images scaled as :func:`as_channel_last_float`
    scales them (unsigned and signed integers divided by their dtype's
    maximum, signed ones clipped at -1, booleans as 0 and 1; floats as they
    are); this is the range of the values it would see, computed from the
    raw minimum and maximum (no float copy of the image). Non-finite values
    are not left out.

    Parameters
    ----------
    image : array_like
        A numeric image of any shape.

    Returns
    -------
    low, high : float
        The range, e.g. to clip a synthesised sample to the values of the
        image its model was fitted to.

    Raises
    ------
    TypeError
        ``image`` is not numeric.
    ValueError
        ``image`` is empty.

    Examples
    --------
    >>> float_range(np.array([0, 51, 255], np.uint8))
    (0.0, 1.0)
    >>> float_range(np.array([-32768, 0], np.int16))
    (-1.0, 0.0)
    >>> float_range(np.array([[0.5, -2.0]]))
    (-2.0, 0.5)
    """
    arr = np.asarray(image)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"image has dtype {arr.dtype}; pass a numeric (integer or float) array.")
    if arr.size == 0:
        raise ValueError(f"image is empty (shape {arr.shape}); pass a non-empty image.")
    ends = np.array([arr.min(), arr.max()])
    if arr.dtype.kind == "b":
        ends = ends.astype(np.float64)
    elif arr.dtype.kind in "iu":
        info = np.iinfo(arr.dtype)
        ends = ends.astype(np.float64) / info.max  # as as_channel_last_float scales
        if info.min < 0:
            ends = np.maximum(ends, -1.0)
    return float(ends[0]), float(ends[1])


def check_real(value, name, *, low=None, high=None, low_open=False, high_open=False,
               integer=False):
    """``value`` as a float (an int with ``integer``) within its range, or a
    TypeError / ValueError that names the argument and says what is allowed.
    Checked before any work, so that a bad option never costs a pass over
    the image."""
    kind = "an integer" if integer else "a number"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f"{name} must be {kind}; got {value!r}.")
    if integer and not float(value).is_integer():
        raise ValueError(f"{name} must be {kind}; got {value!r}.")
    number = int(value) if integer else float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be a finite number; got {value!r}.")
    below = low is not None and (number <= low if low_open else number < low)
    above = high is not None and (number >= high if high_open else number > high)
    if below or above:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        span = f"{left}{'-inf' if low is None else low}, {'inf' if high is None else high}{right}"
        raise ValueError(f"{name} must be in {span}; got {value!r}.")
    return number
