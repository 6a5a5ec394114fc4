"""Restoration of images larger than memory, by tiles (issue 16, point 2;
docs/restoration.md).

What :func:`~car_napari.restoration.restore` (the windowed estimator)
computes over the whole image is of two kinds:

* global: the per-channel mean the image is centred by, its variance (the
  scale of the models' prior) and the noise level of the edge rule (the
  median absolute Laplacian of each channel, an order statistic of the whole
  image). These are computed first, in passes over the tiles: sums for the
  mean and variance (:class:`~car_napari._validation.SummaryPasses`), and the
  exact median by a histogram of the responses, then the values of the two
  bins that hold the middle ranks.
* local: everything else. A pixel's restored value depends on the models of
  the blocks around it (a window of 3 x 3 blocks), the directions' errors in
  the 3 x 3 square around it, and the edge rule's 7 x 7 window: nothing
  farther than two blocks plus the neighbourhood's reach. Tiles whose starts
  are multiples of the block side, read with a halo of :func:`tile_halo`
  pixels, give every core pixel the same value as the whole image does (to
  rounding: the sums run in another order).

The adaptive estimator (``estimator='recursive'``) is not tile-local: each of
its four scans carries one model through the whole image in raster order,
forgetting 0.995 per pixel, so a pixel's model depends on the ~200 pixels
scanned before it (to 1e-6: ~2800), which near the start of a row are the
end of the row before, across the image's full width. Tiles refuse it (the
smallest change making it tile-local, scans restarted per tile, would be a
different estimator; the windowed one is the default and as good on the
benchmark, docs/restoration.md).
"""

from __future__ import annotations

import numpy as np

from .._docstrings import documents_job, shared_parameters
from .._progress import Progress, Span, drain, spans
from .._threads import job_pool
from .._tiles import is_lazy, iter_map_tiles, lazy_map_tiles, read_tile, require, tile_grid
from .._validation import (
    MAX_SIDE,
    SummaryPasses,
    as_channel_last_float,
    check_channel_axis,
    check_not_constant,
    check_real,
)
from ..model.neighbourhood import as_offsets
from ._checks import (
    check_kappa,
    check_noise,
    check_noise_magnitude,
    check_options,
    check_restorable,
)
from ._noise import noise_from_medians
from ._single import (
    CORNERS,
    DEFAULT_WINDOW,
    WINDOWED_WORK,
    _iter_edges,
    _iter_windowed,
)

__all__ = ["DEFAULT_TILE", "iter_restore_large", "restore_large", "tile_halo"]

#: Side of a tile's core (pixels): a tile and its halo in float64 with the
#: restoration's arrays is about 0.4 GB per channel.
DEFAULT_TILE = 2048
# the noise pass's histogram bins: a float64's top 20 bits (sign, exponent,
# 8 bits of mantissa: bins 0.4 % wide)
_SHIFT = 44

# the Parameters of both forms of the job, written once
_PARAMETERS = """
    image : (H, W) or (H, W, C) array
        A dask or zarr array (or any sliceable array: a memory map, NumPy);
        integers are scaled to [0, 1]. Read a tile at a time.
    out : array, optional
        Where the restored image (float64 values; an integer array gets them
        as they are, so pass a float array) is written, tile by tile: a zarr
        array, a NumPy array or memory map of ``image``'s shape. Default: a
        lazy dask array when ``image`` is dask (its tiles computed when it
        is; the global passes already done), else a NumPy array.
    tile : int, optional
        Side of a tile's core (rounded up to whole blocks).
    neighbourhood : int or (eta, 2) array, optional
        As :func:`restore` ('auto' needs the whole image: not here).
    estimator : {'windowed'}, optional
        Only the windowed estimator is tile-local (see the module's notes).
    window, directions, keep_edges, kappa, noise : optional
        As :func:`restore`.
    forgetting : float in [0.5, 1], optional
        As :func:`restore`: checked as there, and unused (only the recursive
        estimator, which cannot run by tiles, forgets).
    channel_axis : -1 or None, optional
        A 3-D image is (H, W, C).
"""


def tile_halo(window=DEFAULT_WINDOW, reach=1):
    """Pixels a tile must read beyond its core for the windowed restoration.

    A core pixel's value depends on the predictions up to 4 pixels away (the
    edge rule's 7 x 7 window, the directions' 3 x 3 errors), each from the
    model of its block, fitted over the 3 x 3 blocks around it, whose
    statistics read ``reach`` pixels farther: two blocks plus the reach,
    rounded up to whole blocks (tile starts stay on the block grid).

    Parameters
    ----------
    window : int, optional
        The restoration's window (a block is a third of it).
    reach : int, optional
        The neighbourhood's largest offset.

    Returns
    -------
    int
        The halo in pixels, a multiple of the block side.

    Examples
    --------
    >>> tile_halo(48, 1)
    48
    """
    window = check_real(window, "window", low=6, high=MAX_SIDE, integer=True)
    reach = check_real(reach, "reach", low=0, high=MAX_SIDE, integer=True)
    block = _block(window)
    return block * (2 + -(-reach // block))


def _block(window):
    return max(2, -(-int(window) // 3))


def _check(image, neighbourhood, estimator, window, directions, kappa, noise, channel_axis,
           tile, forgetting=0.995):
    """The options validated up front: (offsets, directions, kappa, C, noise)."""
    if estimator != "windowed":
        raise ValueError(
            f"estimator={estimator!r} cannot run by tiles: the adaptive estimator's scans "
            "carry one model through the whole image in raster order (each pixel's model "
            "depends on thousands of pixels before it). Use estimator='windowed' (the "
            "default) for a large image.")
    if isinstance(neighbourhood, str):
        raise ValueError(
            f"neighbourhood={neighbourhood!r}: the decision rule chooses the order on the "
            "whole image; for a large image pass an order (e.g. 1) or offsets.")
    offsets, _ = as_offsets(neighbourhood)
    # pixels, bounded so that a halo or a tile never overflows (nor allocates a
    # window's buffers larger than the image)
    window = check_real(window, "window (an integer of at least 6 pixels)", low=6,
                        high=MAX_SIDE, integer=True)
    _, directions = check_options(forgetting, directions, CORNERS)  # as restore checks it
    kappa = check_kappa(kappa)
    tile = check_real(tile, "tile (a positive number of pixels)", low=1, high=MAX_SIDE,
                      integer=True)
    channel_axis = check_channel_axis(channel_axis)  # a 2-D image ignores it: checked
    shape = tuple(int(s) for s in np.shape(image))
    if len(shape) == 2:
        C = 1
    elif len(shape) == 3 and channel_axis is not None and channel_axis in (-1, 2):
        C = shape[2]
    else:
        raise ValueError(
            f"a large image must be (H, W) grey or (H, W, C) with channel_axis=-1; got shape "
            f"{shape} with channel_axis={channel_axis!r} (move the channel axis last).")
    dtype = np.dtype(getattr(image, "dtype", None) or np.asarray(image).dtype)
    if dtype.kind not in "biuf":
        raise TypeError(f"image has dtype {dtype}; pass a numeric (integer or float) array.")
    if window > max(*shape[:2], DEFAULT_WINDOW):  # as restore: its buffers grow with it
        raise ValueError(f"window {window} is larger than the image {shape[:2]}: use at most "
                         f"{max(*shape[:2], DEFAULT_WINDOW)}.")
    if noise is not None:
        noise = check_noise(noise, C)
        check_noise_magnitude(noise)
    check_restorable((*shape[:2], C), offsets, "windowed", directions)
    return offsets, directions, kappa, C, noise, window, tile


def _check_out(out, shape):
    """``out`` is None or an array of the image's shape to write into."""
    if out is None:
        return
    if not (hasattr(out, "shape") and hasattr(out, "__setitem__")):
        raise TypeError(f"out must be None or an array of shape {shape} to write into; got "
                        f"{type(out).__name__}.")
    if tuple(out.shape) != tuple(shape):
        raise ValueError(f"out has shape {tuple(out.shape)}; it must have the image's shape "
                         f"{tuple(shape)}.")


def _channel_last(part):
    return as_channel_last_float(part, channel_axis=None if part.ndim == 2 else -1)


def _responses(centred, tile, H, W):
    """|Laplacian| (the noise estimate's kernel) at the core pixels of
    ``tile`` inside the image's interior, (n, C), from the tile read with
    a 1-pixel halo (``centred``, channel-last)."""
    i0, i1 = max(tile.r0, 1), min(tile.r1, H - 1)
    j0, j1 = max(tile.c0, 1), min(tile.c1, W - 1)
    if i1 <= i0 or j1 <= j0:
        return np.empty((0, centred.shape[2]))

    def at(di, dj):
        return centred[i0 - tile.a0 + di : i1 - tile.a0 + di, j0 - tile.b0 + dj : j1 - tile.b0 + dj]

    r = (at(-1, -1) + at(-1, 1) + at(1, -1) + at(1, 1)
         - 2.0 * (at(-1, 0) + at(1, 0) + at(0, -1) + at(0, 1)) + 4.0 * at(0, 0))
    return np.abs(r).reshape(-1, centred.shape[2])


def _bins(values):
    """A histogram bin of each value >= 0 by its float64 bits (the exponent
    and the first mantissa bits, :data:`_SHIFT`): monotone in the value, no
    range needed beforehand."""
    return (np.ascontiguousarray(values).view(np.uint64) >> _SHIFT).astype(np.int64)


def _add_counts(keys, counts, bins):
    """The sparse histogram ``(keys, counts)`` (sorted bins, their counts)
    with ``bins`` added. Sparse, not the 2**20 bins a dense one holds per
    channel (8 MB each, all allocated before a constant channel is found):
    a tile's responses fill a few thousand bins."""
    new, n = np.unique(bins, return_counts=True)
    if keys.size == 0:
        return new, n.astype(np.int64)
    merged, where = np.unique(np.concatenate([keys, new]), return_inverse=True)
    total = np.zeros(merged.size, np.int64)
    np.add.at(total, where, np.concatenate([counts, n]))
    return merged, total


def _read_tiles(image, tiles, add, responses):
    """One pass over the tiles: each tile's core pixels given to ``add``
    (``(n, C)`` rows), then ``(k, its |Laplacian| responses or None)``."""
    H, W = image.shape[:2]
    for k, t in enumerate(tiles, start=1):
        data = _channel_last(read_tile(image, t))
        add(data[t.inner].reshape(-1, data.shape[2]))
        yield k, _responses(data, t, H, W) if responses else None


def _iter_statistics(image, want_noise, tile, span):
    """The global quantities: (Summary, noise or None), in two passes over
    the tiles, Progress records after each tile.

    Pass 1: the sums of the mean, the min and max (a constant channel is
    refused there), and a sparse histogram of the |Laplacian| responses by
    their float bits; pass 2: the squared deviations, and the responses
    that fall in the two bins holding the middle ranks, whose sorted values
    give the exact median (the responses are of the scaled image; the
    in-memory estimate takes them of the centred one: the same values but
    for rounding, the kernel's taps summing to 0)."""
    H, W = image.shape[:2]
    C = 1 if image.ndim == 2 else image.shape[2]
    tiles = tile_grid((H, W), tile, 1)
    lo, hi = span
    passes = Span(lo, (lo + hi) / 2), Span((lo + hi) / 2, hi)  # the two passes' halves
    summary = SummaryPasses(C)
    empty = np.zeros(0, np.int64)
    hist = [(empty, empty)] * C  # per channel: sorted bins, their counts
    for k, r in _read_tiles(image, tiles, summary.first, want_noise):
        for c in range(C) if want_noise else ():
            hist[c] = _add_counts(*hist[c], _bins(r[:, c]))
        yield Progress("statistics", passes[0].at(k, len(tiles)), f"mean: tile {k}/{len(tiles)}")
    # the min and max are known: refuse a constant channel before a second pass
    check_not_constant(None, summary=summary.result())
    n = (H - 2) * (W - 2)
    median = want_noise and n > 0  # no interior pixel: no response (noise 0)
    low, high = (n - 1) // 2, n // 2
    bins, first = [], []
    for keys, counts in hist if median else ():
        upto = np.cumsum(counts)  # the counts up to and including each bin
        i, j = np.searchsorted(upto, [low, high], side="right")
        bins.append((keys[i], keys[j]))
        first.append(int(upto[i] - counts[i]))  # rank of the first value kept
    picked = [[] for _ in range(C)]
    for k, r in _read_tiles(image, tiles, summary.second, median):
        for c in range(C) if median else ():
            b = _bins(r[:, c])
            picked[c].append(r[:, c][(b == bins[c][0]) | (b == bins[c][1])])
        yield Progress("statistics", passes[1].at(k, len(tiles)),
                       f"variance: tile {k}/{len(tiles)}")
    result = summary.result()
    if not want_noise:
        return result, None
    if not median:
        return result, np.zeros(C)
    medians = []
    for c in range(C):
        values = np.sort(np.concatenate(picked[c]))
        medians.append(0.5 * (values[low - first[c]] + values[high - first[c]]))
    return result, noise_from_medians(medians)


def _restore_part(part, *, mean, var, noise, offsets, directions, window, keep_edges, kappa):
    """The windowed restoration of one tile and its halo, with the image's
    global mean, variance and noise: what :func:`restore` computes there
    (:func:`~car_napari.restoration._single.iter_restoration`, windowed
    branch), in the part's layout."""
    data = _channel_last(part)
    H, W, C = data.shape
    probability = kappa > 0
    span = spans(dict(WINDOWED_WORK))
    planes = np.empty((C, H, W))
    np.subtract(np.moveaxis(data, -1, 0), mean[:, None, None], out=planes)
    pred = np.empty((H, W, C))
    pool = job_pool()
    pred, prob, spread = drain(_iter_windowed(
        planes, mean, var, offsets, directions, window, pool, False, probability,
        None, span, pred))
    if keep_edges:
        pred = drain(_iter_edges(data, pred, spread, noise, pool, span, blend=True,
                                 out=planes.reshape(data.shape), halves=True))
    if probability:
        pred = np.where((prob > kappa)[..., None], pred, data)
    return pred[..., 0] if part.ndim == 2 else pred


def iter_restore_large(image, *, out=None, tile=DEFAULT_TILE, neighbourhood=1,
                       estimator="windowed", window=DEFAULT_WINDOW, forgetting=0.995,
                       directions="all", keep_edges=True, kappa=0.0, noise=None,
                       channel_axis=-1):
    """Restore an image larger than memory by tiles, as a job.

    {plain form}

    Yields
    ------
    Progress
        Stages ``'statistics'`` (the global passes, a record per tile) and
        ``'tiles'`` (``'tile k/n'``; not with a lazy result).

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> noisy = np.random.default_rng(0).normal(0.5, 0.1, (200, 150))
    >>> restored = drain(iter_restore_large(noisy, tile=64))
    >>> restored.shape
    (200, 150)
    """
    if not (hasattr(image, "shape") and hasattr(image, "__getitem__")):
        image = np.asarray(image)  # a nested list: as restore takes it
    offsets, directions, kappa, C, noise, window, tile = _check(
        image, neighbourhood, estimator, window, directions, kappa, noise, channel_axis, tile,
        forgetting)
    _check_out(out, image.shape)
    H, W = image.shape[:2]
    yield Progress("start", 0.0, f"{H} x {W} image by tiles")
    lazy = out is None and is_lazy(image) and type(image).__module__.startswith("dask.")
    summary, estimated = yield from _iter_statistics(image, noise is None, tile,
                                                     (0.0, 1.0 if lazy else 0.3))
    noise = estimated if noise is None else noise
    function = _TilePart(mean=summary.mean, var=summary.var, noise=noise, offsets=offsets,
                         directions=directions, window=int(window),
                         keep_edges=bool(keep_edges), kappa=kappa)
    halo = tile_halo(window, int(np.abs(offsets).max()))
    block = _block(window)
    if lazy:
        require("dask.array", "a dask image")
        return lazy_map_tiles(image, function, tile=tile, halo=halo, align=block)
    if out is None:
        out = np.empty(image.shape)
    tiles = tile_grid((H, W), tile, halo, align=block)
    return (yield from iter_map_tiles(image, lambda part, _: function(part), out, tiles,
                                      span=(0.3, 1.0)))


class _TilePart:
    """A picklable ``part -> restored part`` (dask may send it to workers)."""

    def __init__(self, **options):
        self.options = options

    def __call__(self, part):
        return _restore_part(part, **self.options)


@documents_job(iter_restore_large)
@shared_parameters(_PARAMETERS)
def restore_large(image, *, out=None, tile=DEFAULT_TILE, neighbourhood=1,
                  estimator="windowed", window=DEFAULT_WINDOW, forgetting=0.995,
                  directions="all", keep_edges=True, kappa=0.0, noise=None,
                  channel_axis=-1):
    """Restore an image larger than memory by tiles.

    The same result as :func:`~car_napari.restoration.restore` with the
    windowed estimator (to rounding, 1e-12 on the tests' images): the
    image's mean, variance and noise level are computed first in passes over
    its tiles, then every tile is restored with its halo
    (:func:`tile_halo`) and its core kept.

    {parameters}

    Returns
    -------
    restored : array
        ``out``, a lazy dask array when ``image`` is dask (its tiles
        computed when it is; the global passes already done), or a NumPy
        array (see ``out``), in the layout of ``image``.

    Raises
    ------
    ValueError
        For ``estimator='recursive'``, ``neighbourhood='auto'``, a wrong
        shape or option, a constant image, NaN or infinite values (found in
        the tile that holds them).
    TypeError
        If the image is not numeric.

    Examples
    --------
    >>> from car_napari.restoration import restore
    >>> noisy = np.random.default_rng(0).normal(0.5, 0.1, (200, 150))
    >>> bool(np.allclose(restore_large(noisy, tile=64), restore(noisy), atol=1e-9))
    True
    """
    return drain(iter_restore_large(
        image, out=out, tile=tile, neighbourhood=neighbourhood, estimator=estimator,
        window=window, forgetting=forgetting, directions=directions, keep_edges=keep_edges,
        kappa=kappa, noise=noise, channel_axis=channel_axis))


# the names before issue 33 (public in car_napari.restoration), kept working
iter_restore_tiled = iter_restore_large
restore_tiled = restore_large
