"""The input image as channel-last float64, converted in strips of rows with
a record between them (a 4000 x 4000 colour image takes about 1 s of one
core to convert and summarise: too long without a chance to cancel).

Bit for bit what :func:`car_napari._validation.as_channel_last_float` returns
(the conversion is elementwise; the summary's sums run in the same order,
carried from strip to strip), with the same messages.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._progress import Progress
from .._validation import Summary, as_channel_last_float

# Values (pixels x channels) converted per strip: about 10-30 ms of one core.
STRIP_VALUES = 1 << 21


@njit(cache=True, nogil=True)
def _first_pass(data, lo, hi, total, count, bad):
    """The min, max, sum and counts of :func:`channel_summary`, continued
    over the rows of (N, d) ``data``."""
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
def _second_pass(data, mean, acc):
    """The squared deviations of :func:`channel_summary`, continued over the
    rows of (N, d) ``data``."""
    n, d = data.shape
    for i in range(n):
        for c in range(d):
            val = data[i, c]
            if math.isfinite(val):
                acc[c] += (val - mean[c]) * (val - mean[c])


def channel_last_shape(image, *, channel_axis=-1, name="image"):
    """The (H, W, C) shape ``image`` will have, checking what needs no pass
    over the values (type, dimensions, channel axis), with the messages of
    :func:`as_channel_last_float`."""
    as_channel_last_float(_probe(image), channel_axis=channel_axis, name=name)
    shape = np.shape(image)
    if len(shape) == 2:
        return (*shape, 1)
    axis = channel_axis % 3
    return tuple(n for k, n in enumerate(shape) if k != axis) + (shape[axis],)


def _probe(image):
    """A small corner of ``image`` with its dtype and number of dimensions
    (its errors are the whole image's, but for the size checks)."""
    arr = np.asarray(image)
    if arr.ndim in (2, 3) and arr.size:
        return arr[tuple(slice(0, 2) if n > 64 else slice(None) for n in arr.shape)]
    return arr


def iter_channel_last_float(image, *, channel_axis=-1, name="image", copy=True):
    """:func:`as_channel_last_float` with ``with_summary=True`` as a job:
    yields Progress('reading', ...) after each strip of rows, returns
    ``(data, summary)``, the same bit for bit. Call
    :func:`channel_last_shape` first (it checks what this does not)."""
    arr = np.asarray(image)
    if arr.size <= STRIP_VALUES:
        return as_channel_last_float(arr, channel_axis=channel_axis, name=name,
                                     with_summary=True, copy=copy)
    if arr.ndim == 2:
        arr = arr[..., np.newaxis]
    else:
        arr = np.moveaxis(arr, channel_axis, -1)
    H, W, d = arr.shape
    if d > 64:
        raise ValueError(
            f"{name} has {d} channels on axis {channel_axis}; is the channel "
            "axis right? Pass channel_axis=None for a grey image or the correct axis."
        )
    kind = arr.dtype.kind
    keep = kind == "f" and arr.dtype == np.float64 and not copy and arr.flags.c_contiguous
    out = arr if keep else np.empty(arr.shape, np.float64)
    rows = max(1, STRIP_VALUES // (W * d))
    strips = [(a, min(H, a + rows)) for a in range(0, H, rows)]
    lo, hi = np.full(d, np.inf), np.full(d, -np.inf)
    total, count, bad = np.zeros(d), np.zeros(d), np.zeros(d)
    for k, (a, b) in enumerate(strips, start=1):
        if not keep:
            part = out[a:b]
            part[...] = arr[a:b]  # exact: every integer and float fits a float64
            if kind in "iu":
                info = np.iinfo(arr.dtype)
                part /= info.max
                if info.min < 0:
                    np.maximum(part, -1.0, out=part)
        _first_pass(out[a:b].reshape(-1, d), lo, hi, total, count, bad)
        yield Progress("reading", 0.7 * k / len(strips), f"rows {b}/{H}")
    mean = total / np.maximum(count, 1.0)
    acc = np.zeros(d)
    for k, (a, b) in enumerate(strips, start=1):
        _second_pass(out[a:b].reshape(-1, d), mean, acc)
        yield Progress("reading", 0.7 + 0.3 * k / len(strips), f"summary {b}/{H}")
    summary = Summary(*np.stack([lo, hi, mean, acc / np.maximum(count, 1.0), bad]))
    if summary.nonfinite.any():
        n_bad = int(summary.nonfinite.sum())
        raise ValueError(
            f"{name} contains {n_bad} NaN or infinite values; fill or mask them first "
            "(e.g. np.nan_to_num, or restrict the fit to a finite rectangle)."
        )
    return out, summary
