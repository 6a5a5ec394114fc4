"""Histograms of the texture model, by blocks of rows: exact quantiles,
histogram matching onto stored quantiles (with exponential tails), the
clip to a range and the restore of the mean and contrast."""

from __future__ import annotations

import math

import numpy as np

from .._progress import Progress, drain, stage
from . import _blocks, _kernels
from ._blocks import _f32, _row_chunks

_HIST_BINS = 1 << 16  # bins of the first pass of the exact quantiles


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
    record after every block of rows of every pass. The same numbers as
    ``values.mean(axis=(0, 1))`` and ``.std`` and the elementwise formula;
    ``values`` is overwritten (and returned).

    Colour values take four compiled passes (the three sums, in NumPy's
    order, and the rescale) and no scratch array; grey ones the NumPy passes
    of :func:`_iter_restore_numpy` (NumPy sums one channel pairwise, which a
    running sum would not reproduce).
    """
    h, w, d = values.shape
    if d == 1 or not values.flags.c_contiguous:
        return (yield from _iter_restore_numpy(values, mean, std))
    n = h * w
    mean = np.ascontiguousarray(np.broadcast_to(mean, (d,)), np.float64)
    chunks = _row_chunks(h, w)
    passes = 4
    step = 0

    def channel_sum(shift, centre, squared, message):
        nonlocal step
        total = np.full(d, -0.0)  # -0.0 + x is x: the first pixel starts the sum
        for a, b in chunks:
            _kernels.block_centred_sum(values[a:b], shift, centre, squared, total)
            yield Progress("restore", (step + b / h) / passes, f"{message}, rows {b}/{h}")
        step += 1
        return total

    zeros = np.zeros(d)
    # values.mean(axis=(0, 1)), then centred.std(axis=(0, 1)) as NumPy's _var computes it
    m = (yield from channel_sum(zeros, zeros, False, "mean")) / n
    centre = (yield from channel_sum(m, zeros, False, "contrast")) / n
    spread = np.sqrt((yield from channel_sum(m, centre, True, "contrast")) / n)
    gain = np.where(spread > 0, std / np.where(spread > 0, spread, 1.0), 1.0)
    gain = np.ascontiguousarray(np.broadcast_to(gain, (d,)), np.float64)
    for a, b in chunks:
        _kernels.block_rescale(values[a:b], m, mean, gain)
        yield Progress("restore", min((step + b / h) / passes, 1.0), f"rows {b}/{h}")
    return values


def _iter_restore_numpy(values, mean, std):
    """:func:`_iter_restore` by NumPy passes: three sums (by
    :func:`_iter_channel_sum`) and three elementwise passes, by blocks of
    rows; ``values`` is used as scratch and returned."""
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
    chunks = _row_chunks(h, w, max(_blocks._CHUNK_PIXELS // 4, 1))
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
    # the end intervals capped by exponential tails: with ``pos`` the
    # probability in units of the quantile spacing, a value at ``t = q - 1 -
    # pos`` (in (0, 1]) from probability 1 maps to ``q[-2] + s log(1 / t)``,
    # ``s = (q[-2] - q[-3]) / log 2`` (the tail passes through q[-3]: an
    # exponential's quantile function), mirrored at the bottom; a scale of 0
    # (an empty next interval) keeps the linear map
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

