"""Input checks shared by every public function: fail early, say what to do."""

from __future__ import annotations

import math
import os
from collections import namedtuple

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def summary_first_pass(data, lo, hi, total, count, bad):
    """The first pass of :func:`channel_summary`, continued over the rows of
    (N, d) ``data``: per-channel min, max, sum and count of the finite
    values (in ``lo``, ``hi``, ``total``, ``count``) and count of the others
    (``bad``), updated in place."""
    n, d = data.shape
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


@njit(cache=True, nogil=True)
def summary_second_pass(data, mean, acc):
    """The second pass of :func:`channel_summary`, continued over the rows of
    (N, d) ``data``: per-channel sum of the finite values' squared
    deviations from ``mean``, added to ``acc`` in place."""
    n, d = data.shape
    for c in range(d):
        m = mean[c]
        total = acc[c]
        for i in range(n):
            val = data[i, c]
            if math.isfinite(val):
                total += (val - m) * (val - m)
        acc[c] = total


class SummaryPasses:
    """The two passes of :func:`channel_summary`, resumable over blocks of rows.

    Feed every block of (N, d) rows to :meth:`first`, then every block, in
    the same order, to :meth:`second`; :meth:`result` is then the
    :class:`Summary` of all the rows, bit for bit whatever the blocks (each
    channel's sums run over the rows in order, carried from block to block).
    """

    def __init__(self, d):
        self.lo, self.hi = np.full(d, np.inf), np.full(d, -np.inf)
        self.total, self.count, self.bad = np.zeros(d), np.zeros(d), np.zeros(d)
        self.acc = np.zeros(d)
        self.mean = None

    def first(self, rows):
        """Min, max, sum and counts over (N, d) ``rows``."""
        summary_first_pass(rows, self.lo, self.hi, self.total, self.count, self.bad)

    def second(self, rows):
        """Squared deviations over (N, d) ``rows`` (after every :meth:`first`)."""
        if self.mean is None:
            self.mean = self.total / np.maximum(self.count, 1.0)
        summary_second_pass(rows, self.mean, self.acc)

    def result(self):
        """The :class:`Summary` of the rows seen."""
        if self.mean is None:
            self.mean = self.total / np.maximum(self.count, 1.0)
        var = self.acc / np.maximum(self.count, 1.0)
        return Summary(*np.stack([self.lo, self.hi, self.mean, var, self.bad]))


def channel_summary(data):
    """Two passes over (N, d) data: per-channel min, max, mean, variance, and
    the count of non-finite values (which are left out of the others), as a
    (5, d) array; the mean and variance are sums in row order divided by the
    count of finite values."""
    passes = SummaryPasses(data.shape[1])
    passes.first(data)
    passes.second(data)
    return np.stack(passes.result())


MAX_CHANNELS = 64  # more channels than this: the channel axis is probably wrong


def channel_last_view(image, *, channel_axis=-1, name="image"):
    """``image`` as an (H, W, d) array (a view where it can be), checked for
    everything but its values: type, size, dimensions, channel axis, number
    of channels, with the messages of :func:`as_channel_last_float`. No pass
    over the values (cheap on any image)."""
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
    if channel_axis is not None:
        channel_axis = check_axis(channel_axis, 3, "channel_axis")
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
    if arr.shape[-1] > MAX_CHANNELS:
        raise ValueError(
            f"{name} has {arr.shape[-1]} channels on axis {channel_axis}; is the channel "
            "axis right? Pass channel_axis=None for a grey image or the correct axis."
        )
    return arr


def channel_last_shape(image, *, channel_axis=-1, name="image"):
    """The (H, W, d) shape :func:`as_channel_last_float` gives ``image``,
    checked as :func:`channel_last_view` checks it (no pass over the values)."""
    return channel_last_view(image, channel_axis=channel_axis, name=name).shape


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
    arr = channel_last_view(image, channel_axis=channel_axis, name=name)
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
    in two Numba passes (:class:`SummaryPasses`; numpy's axis=(0, 1)
    reductions take several slow passes over channel-last data)."""
    passes = SummaryPasses(image.shape[-1])
    flat = image.reshape(-1, image.shape[-1])
    passes.first(flat)
    passes.second(flat)
    return passes.result()


# Spreads between 2**-SCALE_EXPONENT and 2**SCALE_EXPONENT are left as they
# are; beyond, :func:`scale_exponent` says by which power of two to scale
SCALE_EXPONENT = 32


def scale_exponent(image):
    """The ``e`` such that ``image * 2**-e`` has a spread near 1, when the
    spread of the finite float ``image`` is beyond ``2**±SCALE_EXPONENT``;
    0 otherwise (ordinary images, integers, constant or non-finite ones and
    values beyond ``MAGNITUDE_LIMIT``, whose reading gives its own
    message). Scaling by a power of two is exact, so a model that is
    scale-equivariant in its arithmetic gives, scaled back, exactly the
    result of the image at a moderate scale."""
    arr = np.asarray(image)
    if arr.dtype.kind != "f" or arr.size == 0:
        return 0
    low, high = float(np.min(arr)), float(np.max(arr))
    spread = high - low
    if not math.isfinite(spread) or spread <= 0 or max(-low, high) > MAGNITUDE_LIMIT:
        return 0  # beyond the limit: the reading's message (a huge outlier is likelier)
    exponent = int(np.round(np.log2(spread)))
    return exponent if abs(exponent) > SCALE_EXPONENT else 0


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


# the largest side and area an output may have: beyond them the arrays of a
# synthesis (several float64 copies of the output) would not fit in memory
MAX_SIDE = 1 << 20
MAX_PIXELS = 1 << 28


def output_shape(shape, *, name="shape"):
    """(height, width) as positive ints of a size that fits in memory, or a
    ValueError that says so."""
    if isinstance(shape, (str, bytes)) or not hasattr(shape, "__len__"):
        raise ValueError(f"{name} must be (height, width); got {shape!r}.")
    if len(shape) != 2:
        raise ValueError(f"{name} must be (height, width); got {shape!r}.")
    try:
        h, w = (check_real(v, name, integer=True) for v in shape)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be (height, width), two positive integers; got {shape!r}."
        ) from None
    if h < 1 or w < 1:
        raise ValueError(f"{name} must be positive; got {(h, w)}.")
    if max(h, w) > MAX_SIDE or h * w > MAX_PIXELS:
        raise ValueError(
            f"{name} {(h, w)} is too large: at most {MAX_SIDE} pixels a side and "
            f"{MAX_PIXELS} pixels in all (the arrays would not fit in memory). "
            "Synthesise smaller pieces."
        )
    return h, w


def memory_bytes():
    """The machine's physical memory in bytes (None when unknown)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        return None


def check_memory(n_bytes, what):
    """A ValueError, before any allocation, when a call would need more than
    the machine's physical memory (``n_bytes``, estimated by the caller);
    ``what`` names the argument that decides it."""
    total = memory_bytes()
    if total is not None and n_bytes > total:
        raise ValueError(
            f"{what} would need about {n_bytes / 2**30:.1f} GiB, more than this machine's "
            f"{total / 2**30:.1f} GiB of memory. Ask for a smaller size."
        )


def check_axis(axis, ndim, name="axis"):
    """``axis`` as an int in [-ndim, ndim) (not a bool), or a TypeError /
    ValueError naming it and the allowed range."""
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)):
        raise TypeError(f"{name} must be an integer in {-ndim}..{ndim - 1} (or None where "
                        f"allowed); got {axis!r}.")
    if not -ndim <= axis < ndim:
        raise ValueError(f"{name}={axis} is out of range for {ndim}-D data: use "
                         f"{-ndim}..{ndim - 1}.")
    return int(axis)


def check_channel_axis(channel_axis, name="channel_axis"):
    """``channel_axis`` as None or an int (not a bool, float or NaN), checked
    even where the data has no channel axis (a 2-D image ignores it): its
    range against the data is the reader's check (:func:`check_axis`)."""
    if channel_axis is None:
        return None
    if isinstance(channel_axis, (bool, np.bool_)) or not isinstance(channel_axis,
                                                                    (int, np.integer)):
        raise TypeError(f"{name} must be None (grey) or an integer, the axis of the "
                        f"channels (e.g. -1); got {channel_axis!r}.")
    return int(channel_axis)


def check_mask(mask, name="mask", *, meaning="True (non-zero) where it applies"):
    """``mask`` as an array of a boolean or numeric dtype without NaN, or a
    TypeError / ValueError naming it. A NaN is non-zero, so ``mask != 0``
    and ``astype(bool)`` would take it for True without a word: it is
    refused (it is usually a missing value, not a decision). Not converted
    to bool here: the callers keep their own reading (``!= 0``)."""
    try:
        m = np.asarray(mask)
    except Exception as exc:  # pragma: no cover - exotic array-likes
        raise TypeError(f"{name} could not be converted to an array: {exc}") from exc
    if m.dtype == object or m.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be boolean or numeric ({meaning}); got dtype "
                        f"{m.dtype}.")
    if m.dtype.kind == "f":
        nan = int(np.count_nonzero(np.isnan(m)))
        if nan:
            raise ValueError(
                f"{name} contains {nan} NaN value{'' if nan == 1 else 's'}: a mask is "
                f"{meaning}, and NaN is neither. Replace them by 0 (False) or 1 (True) "
                f"first, e.g. np.nan_to_num({name}) for False.")
    return m


# The smallest forgetting factor phi: the adaptive estimator's effective
# window is about 1 / (1 - phi**2) pixels, 1.33 at 0.5, so below it the local
# model forgets each pixel almost as soon as it is seen (and for phi**2 near
# 1e-170 its statistics leave float64's range: NaN output, without a word).
MIN_FORGETTING = 0.5


def check_forgetting(value, name="forgetting"):
    """``value`` as a float in [MIN_FORGETTING, 1], or a TypeError /
    ValueError naming it and saying why smaller values are refused."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f"{name} must be a number in [{MIN_FORGETTING}, 1]; got {value!r}.")
    # a huge int would overflow float(); anything beyond 1 is refused anyway
    number = float(value) if abs(value) <= 1 else 2.0
    if not (MIN_FORGETTING <= number <= 1.0):  # NaN too
        raise ValueError(
            f"{name} must be in [{MIN_FORGETTING}, 1]; got {value!r}. The local model's "
            f"window is about 1 / (1 - {name}**2) pixels (1.33 at {MIN_FORGETTING}, 100 at "
            "0.995): smaller values leave it no pixels to learn from. Use 0.99 or so for "
            "a local model, 1 for none forgotten.")
    return number


def check_flag(value, name):
    """``value`` as a bool (True, False or a numpy bool), or a TypeError naming it."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False; got {value!r}.")
    return bool(value)


def check_shape(shape, name, *, lengths=(2, 3), high=1 << 40):
    """A tuple of positive ints (up to ``high``) of one of ``lengths``, or a
    ValueError naming ``name``."""
    if isinstance(shape, (str, bytes)) or not hasattr(shape, "__len__") \
            or len(shape) not in lengths:
        raise ValueError(f"{name} must be a tuple of {' or '.join(map(str, lengths))} "
                         f"positive ints; got {shape!r}.")
    try:
        out = tuple(check_real(v, name, low=1, high=high, integer=True) for v in shape)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a tuple of positive ints; got {shape!r}.") from None
    return out


def check_path(path, name="path"):
    """``path`` as it is when it is a file name (a str, bytes or path-like
    object), else a TypeError (an int would be taken by ``open`` for a file
    descriptor: 0 reads stdin, 1 writes and closes stdout) or, when empty, a
    ValueError, naming it."""
    if not isinstance(path, (str, bytes, os.PathLike)):
        raise TypeError(f"{name} must be a file name (a str or path-like object); got "
                        f"{path!r}.")
    if not os.fspath(path):
        raise ValueError(f"{name} is empty; pass a file name.")
    return path


def check_seed(seed, name="seed"):
    """``seed`` (None, a non-negative int, a SeedSequence, BitGenerator or
    Generator) as a numpy Generator, or a TypeError / ValueError naming it."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is not None and not isinstance(
            seed, (np.random.SeedSequence, np.random.BitGenerator)):
        if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
            raise TypeError(
                f"{name} must be None, a non-negative int or a numpy Generator; got {seed!r}."
            )
        if seed < 0:
            raise ValueError(f"{name} must be a non-negative int; got {seed!r}.")
        seed = int(seed)
    return np.random.default_rng(seed)


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


def unit_dtype(dtype):
    """The dtype :func:`from_unit` gives for ``dtype``: uint8 and uint16
    kept, anything else float32.

    Examples
    --------
    >>> unit_dtype(np.uint16), unit_dtype(np.float64)
    (dtype('uint16'), dtype('float32'))
    """
    return np.dtype(dtype) if dtype in (np.uint8, np.uint16) else np.dtype(np.float32)


def from_unit(values, dtype):
    """Float values on the core's [0, 1] scale back as ``dtype``, the
    reverse of the scaling of :func:`as_channel_last_float`: uint8 and
    uint16 scaled to their range and rounded (clipped to it), anything else
    float32 as it is. The command line writes its results with it, and the
    widgets show them with it, in the input's dtype and range.

    Parameters
    ----------
    values : array_like of float
        Values in the core's units.
    dtype : dtype
        The input's dtype.

    Returns
    -------
    ndarray
        Of :func:`unit_dtype` ``(dtype)``.

    Examples
    --------
    >>> from_unit(np.array([0.0, 0.5, 1.2]), np.uint8)
    array([  0, 128, 255], dtype=uint8)
    >>> from_unit(np.array([-0.1, 0.5]), np.float64)
    array([-0.1,  0.5], dtype=float32)
    """
    if dtype in (np.uint8, np.uint16):
        return np.round(np.clip(values, 0.0, 1.0) * np.iinfo(dtype).max).astype(dtype)
    return np.asarray(values).astype(np.float32)


def check_real(value, name, *, low=None, high=None, low_open=False, high_open=False,
               integer=False, strict=False):
    """``value`` as a float (an int with ``integer``) within its range, or a
    TypeError / ValueError that names the argument and says what is allowed.
    Checked before any work, so that a bad option never costs a pass over
    the image. With ``integer``, a float of integral value (2.0) is taken
    unless ``strict``: then only an int (Python or numpy) is, as for a
    count (a float there is usually a mistake, e.g. a ratio); a float is a
    ValueError, as ``levels=2.0`` is for :func:`illumination_invariants`."""
    kind = "an integer" if integer else "a number"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f"{name} must be {kind}; got {value!r}.")
    if integer and strict and not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer (an int, not a float); got {value!r}. "
                         f"Pass int({name}) if a whole number was meant.")
    if isinstance(value, (int, np.integer)):
        number = int(value) if integer else _as_float(value, name)
    else:
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"{name} must be a finite number; got {value!r}.")
        if integer:
            if not number.is_integer():
                raise ValueError(f"{name} must be {kind}; got {value!r}.")
            number = int(number)
    below = low is not None and (number <= low if low_open else number < low)
    above = high is not None and (number >= high if high_open else number > high)
    if below or above:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        span = f"{left}{'-inf' if low is None else low}, {'inf' if high is None else high}{right}"
        raise ValueError(f"{name} must be in {span}; got {value!r}.")
    return number


def _as_float(value, name):
    """An int as a float, or the ValueError of one beyond float64's range."""
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{name} must be a finite number; got an integer of "
                         f"{len(str(abs(int(value))))} digits.") from None
