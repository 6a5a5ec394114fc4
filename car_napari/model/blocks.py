"""Whole-image array work by blocks of rows, with a yield between blocks.

A NumPy pass over a 4000x4000 RGB image in float64 takes ~0.1-0.5 s; the job
protocol wants a yield every ~0.1-0.25 s, so the jobs' preparation (the float
copy and its summary, the centring, the whitening) runs in blocks of about ``BLOCK_VALUES``
values. Every helper here gives, bit for bit, what the one-call form gives
(elementwise operations, or per-row linear algebra checked in the tests).
"""

from __future__ import annotations

import numpy as np

from .._progress import Progress, row_blocks
from .._validation import (
    SummaryPasses,
    as_channel_last_float,
    channel_last_view,
    check_values,
)

__all__ = ["BLOCK_VALUES", "iter_centre", "iter_channel_last_float", "row_ranges"]

# ~32 MB of float64: one elementwise pass over it is ~10-40 ms
BLOCK_VALUES = 1 << 22


def row_ranges(n_rows, values_per_row, budget=None):
    """Blocks of rows of about ``budget`` values each
    (:func:`~car_napari._progress.row_blocks` by a budget of values).

    Parameters
    ----------
    n_rows : int
        The rows to cover.
    values_per_row : int
        Values in one row.
    budget : int, optional
        Values per block (default ``BLOCK_VALUES``); a block has at least one row.

    Returns
    -------
    list of (int, int)
        ``(start, stop)`` pairs covering ``range(n_rows)`` in order.

    Examples
    --------
    >>> row_ranges(10, 3, 7)
    [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    """
    budget = BLOCK_VALUES if budget is None else budget
    return row_blocks(n_rows, budget // max(1, values_per_row))


def iter_channel_last_float(image, *, channel_axis=-1, name="image", stage="prepare",
                            copy=True):
    """The image as C-contiguous channel-last float64, by blocks of rows, as a job.

    What ``as_channel_last_float(image, with_summary=True, copy=copy)`` of
    :mod:`car_napari._validation` returns, bit for bit, with the same
    validation and errors (the NaN and magnitude checks included), in blocks
    of about ``BLOCK_VALUES`` values with a Progress record after each: the
    integer scaling is elementwise (it is repeated here, and a test holds
    the two equal for every dtype); the summary's two passes
    (:class:`~car_napari._validation.SummaryPasses`) carry their sums from
    block to block, in the same order. Small images take the one call.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array_like
        Any numeric dtype; integers are scaled to [0, 1] (signed ones to [-1, 1]).
    channel_axis : int or None, optional
        The channel axis of a 3-D image; None for grey.
    name : str, optional
        How errors and messages call the image.
    stage : str, optional
        The records' stage name.
    copy : bool, optional
        With False, a C-contiguous float64 channel-last input may be returned
        as it is (not to be written to).

    Returns
    -------
    data : (H, W, C) ndarray of float64
        The converted copy (or, without ``copy``, maybe ``image`` itself).
    summary : Summary
        Its per-channel min, max, mean, variance and non-finite count.

    Yields
    ------
    Progress
        After each block, converted and in the summary's first pass (message
        like ``"image: rows 512/4000"``), and after each block of the second
        pass (``"image: summary 512/4000"``).

    Raises
    ------
    ValueError
        As ``as_channel_last_float``: empty, not 2-D or 3-D, too many
        channels, NaN or infinite values, values too large or too finely
        spread for the models' squares.
    TypeError
        As ``as_channel_last_float``: None or not numeric.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> data, summary = drain(iter_channel_last_float(np.full((4, 5), 51, np.uint8)))
    >>> data.shape, float(data[0, 0, 0]), float(summary.max[0])
    ((4, 5, 1), 0.2, 0.2)
    """
    view = channel_last_view(image, channel_axis=channel_axis, name=name)
    if view.size <= BLOCK_VALUES:
        return as_channel_last_float(view, channel_axis=-1, name=name, with_summary=True,
                                     copy=copy)
    h, w, c = view.shape
    keep = view.dtype == np.float64 and not copy and view.flags.c_contiguous
    out = view if keep else np.empty((h, w, c))
    info = np.iinfo(view.dtype) if view.dtype.kind in "iu" else None
    passes = SummaryPasses(c)
    blocks = row_ranges(h, w * c)
    for k, (start, stop) in enumerate(blocks, start=1):
        part = out[start:stop]
        if not keep:
            part[...] = view[start:stop]  # exact: every integer and float fits a float64
            if info is not None:
                part /= info.max
                if info.min < 0:
                    np.maximum(part, -1.0, out=part)
        passes.first(part.reshape(-1, c))
        yield Progress(stage, 0.7 * k / len(blocks), f"{name}: rows {stop}/{h}")
    for k, (start, stop) in enumerate(blocks, start=1):
        passes.second(out[start:stop].reshape(-1, c))
        yield Progress(stage, 0.7 + 0.3 * k / len(blocks), f"{name}: summary {stop}/{h}")
    summary = passes.result()
    check_values(summary, name=name)
    return out, summary


def iter_centre(data, mean, *, stage="prepare", message="centring"):
    """``data -= mean`` in place, by blocks of rows, as a job.

    Parameters
    ----------
    data : (H, W, C) ndarray of float64
        Modified in place.
    mean : (C,) array_like
        Subtracted from every pixel.
    stage : str, optional
        The records' stage name.
    message : str, optional
        The records' message (followed by the rows done).

    Returns
    -------
    None
        ``data`` is centred in place.

    Yields
    ------
    Progress
        After each block, when there are several.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> data = np.arange(6.0).reshape(1, 3, 2)
    >>> drain(iter_centre(data, [2.0, 3.0]))
    >>> data[0].tolist()
    [[-2.0, -2.0], [0.0, 0.0], [2.0, 2.0]]
    """
    h, w, c = data.shape
    blocks = row_ranges(h, w * c)
    for k, (start, stop) in enumerate(blocks, start=1):
        data[start:stop] -= mean
        if len(blocks) > 1:
            yield Progress(stage, k / len(blocks), f"{message}: rows {stop}/{h}")
