"""Filling scratches and blotches (section 14.7, docs/inpainting.md).

:func:`inpaint` fills the masked pixels of a frame or a clip, by default
with the exact conditional mean under local CAR models (``_conditional``);
``method="scans"`` (this module) with the one-step conditional means of
adaptive CAR models that move towards the damage: four
scans, downwards (from the damage's top edge), upwards (from its bottom
edge), rightwards (from its left edge) and leftwards (from its right edge),
each predicting a pixel from the previous scan line only; predicted pixels
serve as neighbours of later ones (14.54). The four fills are combined by
exponential interleaving: each model's weight decays as
``exp(-distance / interleave)`` with the distance (along its scan) from the
known pixels on its side. Known pixels bordering the damage are tested by
each scan as it reaches them and filled too when the model finds them
improbable (the halo of soft-edged damage). In a clip, the previous (already
restored) frame joins the regression vector (the 3.5D model). Models learn
only from undamaged pixels whose neighbourhood is undamaged; pixels outside
the mask are returned bit-identical.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from .._progress import Progress, mapped, row_blocks, stage
from .._threads import job_pool, pool_threads, submit
from .._validation import check_forgetting, check_mask, check_real
from ..model.neighbourhood import Context, causal_neighbourhood
from ..model.recursive import RecursiveScan, default_prior
from ._conditional import HALO_BLEND, HALO_REGION_BLEND, HALO_UNBLEND, iter_fill_conditional
from ._layout import MAX_COLOURS, read_layout
from ._motion import iter_estimate_motion, warp_frame

__all__ = ["CONDITIONAL_HALO", "CONDITIONAL_ORDER", "DEFAULT_INTERLEAVE",
           "EDGE_OUTLIER_LOGREL", "METHODS", "Tiling", "iter_inpaint_in_memory",
           "line_offsets"]

METHODS = ("conditional", "scans")
# the conditional mean (method="conditional"): the hierarchical order of each
# local model and the halo threshold (a log density ratio, as for the scans).
# Both chosen on the benchmark's TUNING part only (benchmarks/bench_inpainting.py).
CONDITIONAL_ORDER = 3
# TUNING (bench_inpainting.py --tune-halo, hard / soft / real, dB): off 30.03
# / 19.14 / 19.98; biharmonic 29.24 / 18.09 / 19.68, Telea 26.90 / 21.20 /
# 19.60. -4 joining the unknowns 28.95 / 24.43 / 18.46; with the pooled blend
# 29.95 / 24.22 / 18.58. The hand restorations of the real scans continue
# from the fringe (on their top halves biharmonic and Navier-Stokes lose
# 0.8-1.3 dB against them when the ring joins the mask), so a ring pixel
# called damaged is unblended by half: 29.97 / 22.01 / 19.86 (0.4: 21.41 /
# 19.99; 0.6: 22.61 / 19.68): the largest least margin over issue 13's bounds
# (the best baseline of each kind, less 0.1 dB on the real scans).
CONDITIONAL_HALO = -4.0


@dataclass(frozen=True)
class EdgeTest:
    """The conditional fill's edge test beyond its ``halo`` threshold (the
    ``halo_*`` options of :func:`~car_napari.inpainting._conditional.iter_fill_conditional`)."""

    rings: int = 1  # rings of known pixels round the damage the edge test reaches
    blend: float = HALO_BLEND  # the least blend towards the damage it calls damage
    region_blend: float = HALO_REGION_BLEND  # ... and pooled over the ring nearby
    unblend: float | None = HALO_UNBLEND  # such a pixel stays known, less half its blend


CONDITIONAL_EDGE_TEST = EdgeTest()  # read at each call: a benchmark may swap it

DEFAULT_INTERLEAVE = 2.0  # pixels: decay length of each side's weight
# A known pixel bordering the damage is treated as damaged by a scan when its
# predictive density relative to the peak is below exp(-12) (for 3 bands about
# a chi-square of 24, p ~ 3e-5; natural images are heavy-tailed, so this
# catches only halos). Chosen on composited scratches (benchmark part (b))
# against real scans (part (a)): -4 fills most edge pixels and loses 0.7 dB
# on real scans, -60 leaves the halos.
EDGE_OUTLIER_LOGREL = -12.0
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
_DIRECTIONS = ("down", "up", "right", "left")  # from the top, bottom, left, right
_CLEAN_FRAME_WORK = 0.01  # a frame without damage is only copied: its share of the work
# Pixels of one scan per kernel call (a chunk of scan rows), with a record
# after each: about 0.1-0.3 s of one core, so a Cancel stops a large frame
# quickly. The scans resume exactly (model.recursive.RecursiveScan): the fill
# does not depend on the chunks.
SCAN_CHUNK_PIXELS = 1 << 18
# The passes over a whole frame before and after the scans (statistics, the
# scans' source, the side distances) go by bands of rows of BAND_PIXELS
# pixels, bit for bit the whole-frame passes, with a record after every
# PASS_RECORD_PIXELS pixels of them (a few hundredths of a second).
BAND_PIXELS = 1 << 20
PASS_RECORD_PIXELS = 1 << 20


# --- validation ------------------------------------------------------------------


def _as_clip(image, mask, channel_axis):
    """The image read by the channel_axis rule (see ``_layout``) and its
    masks as (T, H, W) bool."""
    try:
        arr = np.asarray(image)
    except Exception as exc:
        raise TypeError(f"image could not be converted to an array: {exc}") from exc
    if arr.dtype.kind not in "uif" or arr.dtype == np.float16:
        raise TypeError(f"image must be numeric (integer or float32/64); got {arr.dtype}.")
    m = check_mask(mask, "mask", meaning="True (non-zero) where pixels are missing")
    layout = read_layout(arr, channel_axis)
    clip = layout.clip
    if clip.dtype.kind == "f" and not np.all(np.isfinite(clip)):
        raise ValueError("image contains NaN or infinite values; replace them (they are "
                         "missing pixels: put them in the mask and fill them with 0).")
    T, H, W = clip.shape[:3]
    if m.shape == (H, W):
        masks = np.broadcast_to(m != 0, (T, H, W))
    elif m.shape == (T, H, W) and not layout.single:
        masks = m != 0
    else:
        want = f"({H}, {W})" + ("" if layout.single else f" or ({T}, {H}, {W})")
        raise ValueError(f"mask has shape {m.shape}; the image {arr.shape} reads as "
                         f"{layout.reading}, so the mask must be {want} (True where pixels "
                         f"are missing).{_layout_hint(arr, m, layout, channel_axis)}")
    full = [t for t in range(T) if masks[t].all()]
    if full:
        raise ValueError(
            f"the mask covers every pixel of frame {full[0]}: there is nothing to learn the "
            "texture from. Mark only the damaged pixels.")
    return layout, masks


#: A mask covering more than this fraction of a frame probably marks the
#: known pixels (a mask drawn with the hole black): said before the work.
MOSTLY_MASKED = 0.5


def _warn_if_mostly_masked(masks):
    """A UserWarning when the mask covers more than half of a frame."""
    for t in range(masks.shape[0]):
        share = float(np.mean(masks[t]))
        if share > MOSTLY_MASKED:
            where = "the frame" if masks.shape[0] == 1 else f"frame {t}"
            warnings.warn(
                f"the mask covers {100 * share:.1f} % of {where}: True (nonzero) marks the "
                "pixels to fill. If your mask marks the damage black (zero), invert it: "
                "~mask, or fit_mask(mask, shape, invert=True).", UserWarning, stacklevel=4)
            return


def _layout_hint(arr, mask, layout, channel_axis):
    """What to pass when the mask fits another reading of a 3-D image."""
    if arr.ndim != 3 or channel_axis is None:
        return ""
    if layout.colour and mask.shape == arr.shape:
        return (" A colour frame takes one (H, W) mask for all its channels; for a grey "
                "clip (T, H, W) pass channel_axis=None.")
    if not layout.colour and mask.ndim == 2:
        return (f" A colour frame (H, W, C) has at most {MAX_COLOURS} channels; this "
                "array's last axis is longer, so it is read as a grey clip.")
    return ""


def line_offsets(depth, half_width=2):
    """Causal offsets in the previous ``depth`` scan lines only.

    A model moving towards the damage predicts a missing pixel from the lines
    it has already passed, never from the pixel before it on its own line:
    along a scratch that pixel is itself a prediction, and chaining
    predictions along the scratch drifts (measured: the hierarchical order-2
    neighbourhood loses 2 dB on vertical scratches).

    Parameters
    ----------
    depth : int
        Scan lines used, 1 to 8.
    half_width : int, optional
        Pixels either side of the pixel's own column in each line.

    Returns
    -------
    (depth * (2 * half_width + 1), 2) ndarray of int64
        ``(di, dj)`` for ``di = 1..depth`` and ``|dj| <= half_width``.

    Raises
    ------
    ValueError
        If ``depth`` is not an int from 1 to 8.

    Examples
    --------
    >>> line_offsets(1, half_width=1).tolist()
    [[1, -1], [1, 0], [1, 1]]
    """
    check_real(depth, "neighbourhood (scan lines used)", low=1, high=8, integer=True)
    return np.array([(di, dj) for di in range(1, int(depth) + 1)
                     for dj in range(-half_width, half_width + 1)], np.int64)


# --- one frame ----------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _side_runs(mask, out):
    """``out[i, j]``: 0 at a known pixel, else 1 more than at ``(i, j - 1)``;
    a row that starts in a hole starts from its width."""
    H, W = mask.shape
    for i in range(H):
        run = float(W)  # rows starting in a hole: far from any known pixel
        for j in range(W):
            run = run + 1.0 if mask[i, j] else 0.0
            out[i, j] = run


def _side_distance(mask):
    """Distance (pixels) from each pixel to the nearest known pixel to its
    left in the same row (1 for a missing pixel right of a known one); large
    where the row has no known pixel on that side."""
    dist = np.empty(mask.shape)
    _side_runs(np.ascontiguousarray(mask), dist)  # one compiled layout
    return dist


class _Meter:
    """Work done since the last record, in pixels of one pass over a frame:
    :meth:`due` says when another record is due (every
    :data:`PASS_RECORD_PIXELS`), so that a small frame makes no extra
    records and a large one one every fraction of a second."""

    def __init__(self, every=None):
        self.every = PASS_RECORD_PIXELS if every is None else every
        self.pending = 0

    def due(self, pixels):
        self.pending += pixels
        if self.pending < self.every:
            return False
        self.pending = 0
        return True


def _as_float(array, out, meter, fraction, message, units=None):
    """``array.astype(np.float64)`` into ``out``, by bands (exact: element
    by element), in ``units`` ``(shift, scale)`` if given; a record (at
    ``fraction``) when due."""
    H, W = array.shape[:2]
    for a, b in row_blocks(H, BAND_PIXELS // max(1, W)):
        out[a:b] = array[a:b]
        if units is not None:
            out[a:b] -= units[0]
            out[a:b] /= units[1]
        if meter.due((b - a) * W):
            yield Progress("frames", fraction, message)
    return out


def _working_units(clip):
    """``(shift, scale)`` that bring a float clip far from unit scale (values
    near 1e300 or 1e-300, or 1e10 plus small noise) to [-1, 1], or None
    for one within reach (every 8- and 16-bit image). The fill is affine-
    equivariant, so this changes rounding only, and magnitude never decides
    whether the fits and sparse solves succeed."""
    if clip.dtype.kind != "f":
        return None
    lo, hi = float(clip.min()), float(clip.max())
    half, middle = hi / 2 - lo / 2, lo / 2 + hi / 2  # no overflow near 1.8e308
    if 1e-6 <= half <= 1e8 and abs(middle) <= 1e6 * half:
        return None
    return middle, half if half > 0 else max(abs(middle), 1.0)


def _iter_known_statistics(frame, mask, meter, message):
    """Per channel mean, variance, min and max of the known pixels of an
    (H, W, C) frame, bit for bit what ``frame[~mask].mean(axis=0)``,
    ``.var(axis=0)``, ``.min(axis=0)`` and ``.max(axis=0)`` give, by bands.

    NumPy sums the rows of an (n, C >= 2) array one after another, so a sum
    continued band by band is the same sum; an (n, 1) array is summed
    pairwise, so a grey frame's variance is one call (a third of the data)."""
    H, W, C = frame.shape
    bands = row_blocks(H, BAND_PIXELS // max(1, W))
    counts = [int(np.count_nonzero(~mask[a:b])) for a, b in bands]
    n = sum(counts)
    known = np.empty((n, C))
    total = None  # C >= 2: the sum of the rows so far, continued band by band
    at = 0
    for (a, b), count in zip(bands, counts, strict=True):
        part = known[at : at + count]
        part[...] = frame[a:b][~mask[a:b]]
        at += count
        if C > 1 and count:
            total = _continued_sum(total, part)
        if meter.due((b - a) * W):
            yield Progress("frames", 0.0, message)
    if C == 1:
        stats = known.mean(axis=0), known.var(axis=0), known.min(axis=0), known.max(axis=0)
        if meter.due(H * W):
            yield Progress("frames", 0.0, message)
        return stats
    mean = total / n  # numpy's mean: the sum over the count
    centre = mean[None, :]  # as numpy's var subtracts it (keepdims)
    squares = lo = hi = None
    rows = max(1, BAND_PIXELS // C)
    for r in range(0, n, rows):
        part = known[r : r + rows]
        deviation = part - centre
        np.square(deviation, out=deviation)
        squares = _continued_sum(squares, deviation)
        part_lo, part_hi = part.min(axis=0), part.max(axis=0)
        lo = part_lo if lo is None else np.minimum(lo, part_lo)
        hi = part_hi if hi is None else np.maximum(hi, part_hi)
        if meter.due(part.size):  # a band of values: a record each, on a large frame
            yield Progress("frames", 0.0, message)
    return mean, squares / n, lo, hi


def _continued_sum(total, rows):
    """The sum over axis 0 of the rows before (``total``, None for none) and
    ``rows``, in order: numpy adds the rows of an (n, C >= 2) array one after
    another, so this is, bit for bit, the sum of all of them at once."""
    if total is None:
        return np.add.reduce(rows, axis=0)
    return np.add.reduce(np.concatenate([total[None, :], rows]), axis=0)


def _reflect_edges(padded, pad):
    """Fill the ``pad`` rows and columns around the interior of ``padded``
    by reflection about the edge (``np.pad(..., mode="reflect")``: rows
    first over the interior columns, then columns over all rows)."""
    if not pad:
        return
    H = padded.shape[0] - 2 * pad
    W = padded.shape[1] - 2 * pad
    inner = slice(pad, pad + W)
    padded[:pad, inner] = padded[2 * pad : pad : -1, inner]
    padded[pad + H :, inner] = padded[pad + H - 2 : H - 2 : -1, inner]
    padded[:, :pad] = padded[:, 2 * pad : pad : -1]
    padded[:, pad + W :] = padded[:, pad + W - 2 : W - 2 : -1]


def _iter_source(frame, previous, mean, mask, pad, meter, message):
    """The scans' source: the centred frame (damaged values 0) and the
    centred previous frame side by side on the channel axis, padded by
    reflection; built by bands, bit for bit the whole-frame construction."""
    H, W, C = frame.shape
    channels = C if previous is None else 2 * C
    source = np.empty((H + 2 * pad, W + 2 * pad, channels))
    for a, b in row_blocks(H, BAND_PIXELS // max(1, W)):
        rows = source[pad + a : pad + b, pad : pad + W]
        np.subtract(frame[a:b], mean, out=rows[..., :C])
        if previous is not None:
            np.subtract(previous[a:b], mean, out=rows[..., C:])
        target = rows[..., :C]
        target[mask[a:b]] = 0.0  # damaged values never enter (the previous frame is restored)
        if meter.due((b - a) * W):
            yield Progress("frames", 0.0, message)
    _reflect_edges(source, pad)
    return source


def _iter_scans(source, codes, options, buffers, finish, meter, message):
    """The four scans of a frame (:data:`_DIRECTIONS`), one a thread of the
    job pool at a time (:func:`~car_napari._threads.job_pool`; the kernel
    releases the GIL), each in chunks of about
    :data:`SCAN_CHUNK_PIXELS` pixels, a Progress record after every chunk but
    the last. Each scan works on a copy of ``source`` (copied by bands into
    one of the reused ``buffers``) and of ``codes``; ``finish(work)`` gives a
    finished scan's result; returns the four results.

    Closing the generator (a Cancel) waits only for the chunks running (a
    fraction of a second each) and starts no other."""
    height, width = source.shape[:2]
    length = {"down": width, "up": width, "right": height, "left": height}  # pixels a row
    chunk = {k: max(1, SCAN_CHUNK_PIXELS // length[k]) for k in _DIRECTIONS}
    copy_bands = row_blocks(height, BAND_PIXELS // max(1, width))
    total = 4 * height * width
    pool = job_pool()  # None: one scan after the other, here
    scanners = pool_threads(pool)
    while len(buffers) < scanners:
        buffers.append(None)
    for k, buffer in enumerate(buffers):
        if buffer is None or buffer.shape != source.shape:
            buffers[k] = np.empty_like(source)
    free = list(buffers)
    scans, results = {}, {}
    waiting = list(_DIRECTIONS)
    done_pixels = 0

    def step(direction):
        """In a thread: copy the next band of the source (returns its pixels
        and 0 scan rows), or scan the next rows (0 and the rows)."""
        state = scans[direction]
        if state["copied"] < len(copy_bands):
            a, b = copy_bands[state["copied"]]
            state["work"][a:b] = source[a:b]
            state["copied"] += 1
            return (b - a) * width, 0
        if state["scanner"] is None:
            state["scanner"] = RecursiveScan(state["work"], direction=direction,
                                             missing=codes.copy(), **options)
        piece = state["scanner"].advance(chunk[direction])
        return 0, piece.stop - piece.start

    def start(direction):
        if direction not in scans:
            scans[direction] = {"work": free.pop(), "copied": 0, "scanner": None}
        running[submit(pool, step, direction)] = direction

    running = {}
    try:
        while waiting and len(running) < scanners:
            start(waiting.pop(0))
        while running:
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            # in a fixed order: the records do not depend on the threads' timing
            for future in sorted(finished, key=lambda f: _DIRECTIONS.index(running[f])):
                direction = running.pop(future)
                copied, rows = future.result()
                done_pixels += rows * length[direction]
                state = scans[direction]
                if state["scanner"] is not None and state["scanner"].done:
                    results[direction] = finish(state["work"])
                    free.append(scans.pop(direction)["work"])
                    if waiting:
                        start(waiting.pop(0))
                else:
                    start(direction)
                if running and (rows or meter.due(copied)):
                    yield Progress("frames", done_pixels / total,
                                   f"{message}, scan {len(results)}/{len(_DIRECTIONS)}")
    finally:
        for future in running:
            future.cancel()  # those not started yet; the running chunks end soon
        wait(running)
    return [results[k] for k in _DIRECTIONS]


def _iter_fill_frame(frame, mask, previous, offsets, forgetting, interleave, prior, halo,
                     message, buffers):
    """Conditional-mean fill of one (H, W, C) float frame; returns the filled
    values at ``mask`` as (n_missing, C).

    A Progress record after each chunk of its four scans but the last (see
    :func:`_iter_scans`), and, on a large frame, between the bands of the
    passes before and after them. ``buffers`` are the scans' work arrays,
    reused from frame to frame."""
    H, W, C = frame.shape
    meter = _Meter()
    preparing = f"{message}, preparing"
    mean, var, lo, hi = yield from _iter_known_statistics(frame, mask, meter, preparing)
    # fills stay within the known pixels' range: a chain of predictions
    # through a long hole (a full-height scratch seen by the vertical models)
    # can otherwise run away
    fill_range = (lo - mean, hi - mean)
    offsets = np.asarray(offsets, np.int64)
    taps = [(di, dj, c) for di, dj in offsets for c in range(C)]
    if previous is not None:  # 3.5D: the previous frame at r and at the same offsets
        taps += [(0, 0, C + c) for c in range(C)]
        taps += [(di, dj, C + c) for di, dj in offsets for c in range(C)]
    context = Context(np.array(taps, np.int64), np.arange(C))
    pad = max(max(context.reach[0]), max(context.reach[1]))
    source = yield from _iter_source(frame, previous, mean, mask, pad, meter, preparing)
    # the known pixels bordering the damage are suspect: soft-edged damage
    # (a blotch or dust whose fringe is below the mask's threshold) leaves a
    # halo there, and a one-line model copies it into the hole. Each scan
    # tests them as it reaches them and fills the outliers (see
    # EDGE_OUTLIER_LOGREL); pixels outside the mask are still returned as given.
    from scipy import ndimage

    codes = mask.astype(np.uint8)
    if halo is not None:
        # not within two reaches (2 * pad) of the frame's edge: there the taps
        # (or theirs) reach into the reflected pad, where the damage's mirror
        # image is filled from nothing yet (a scratch in column 1 came out 92
        # grey levels off, 10 without the test; one reach left some misfiring)
        inner = np.zeros((H, W), bool)
        inner[2 * pad:H - 2 * pad, 2 * pad:W - 2 * pad] = True
        codes[ndimage.binary_dilation(mask, structure=_CROSS) & ~mask & inner] = 2
    padded_codes = np.ascontiguousarray(np.pad(codes, pad, mode="reflect"))
    options = dict(context=context, forgetting=forgetting, intercept=True,
                   prior=default_prior(var, context.n_regressors, True, C, prior),
                   outputs=(), fill_range=fill_range,
                   suspect_logrel=-np.inf if halo is None else halo)

    def finish(work):
        out = work[pad:-pad, pad:-pad, :C] if pad else work[..., :C]
        return out[mask]

    filled = yield from _iter_scans(source, padded_codes, options, buffers, finish, meter,
                                    message)
    del source
    # exponential interleaving (section 14.7): each model's weight decays with the
    # distance from the known data on its side
    sides = (
        lambda: _side_distance(mask.T).T[mask],  # from the top
        lambda: _side_distance(mask[::-1].T).T[::-1][mask],  # from the bottom
        lambda: _side_distance(mask)[mask],  # from the left
        lambda: _side_distance(mask[:, ::-1])[:, ::-1][mask],  # from the right
    )
    distance = []
    for side in sides:
        distance.append(side())
        if meter.due(H * W):
            yield Progress("frames", 1.0, f"{message}, combining")
    nearest = np.minimum.reduce(distance)  # exp of differences only: no underflow
    weights = [np.exp(-(d - nearest) / interleave)[:, None] for d in distance]
    values = sum(w * f for w, f in zip(weights, filled, strict=True)) / sum(weights)
    return values + mean


def _to_dtype(values, dtype):
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        return np.clip(np.round(values), info.min, info.max).astype(dtype)
    return values.astype(dtype)


def _as_frame_records(job, fraction, message):
    """A sub-job's records as the fill's own ("frames" at ``fraction``), and
    its result."""
    return (yield from mapped(job, lambda _: Progress("frames", fraction, message)))


class Tiling(NamedTuple):
    """How :func:`iter_inpaint_in_memory` fills a single frame larger than
    ``side`` pixels a side: by the tiles of ``fill``
    (:func:`._tiled.iter_inpaint_tiles`, passed in by
    :func:`~car_napari.inpainting.iter_inpaint`, which imports both: no
    import cycle), its default tile being ``side``."""

    fill: Callable
    side: int


def _iter_by_tiles(layout, mask, iter_inpaint_tiles, **options):
    """A single frame filled by :func:`._tiled.iter_inpaint_tiles`, with the
    in-memory job's last record (the frame restored)."""
    colour = layout.colour
    frame = layout.clip[0] if colour else layout.clip[0, ..., 0]
    out = np.empty(frame.shape, frame.dtype)
    yield from iter_inpaint_tiles(frame, mask, out=out, channel_axis=-1 if colour else None,
                                  **options)
    out = out if colour else out[..., None]
    restored_frame = layout.frame_to_input(out).view()
    restored_frame.flags.writeable = False
    yield Progress("frames", 1.0, "frame 1/1", (0, restored_frame))
    return layout.to_input(out[None])


def iter_inpaint_in_memory(image, mask, *, temporal=True, neighbourhood=None, forgetting=0.9995,
                           interleave=DEFAULT_INTERLEAVE, halo="auto", channel_axis=-1,
                           method="conditional", motion=True, by_tiles=None):
    """:func:`~car_napari.inpainting.iter_inpaint` of a frame or clip in
    memory (NumPy): the parameters, records and result documented there.
    ``by_tiles``: a :class:`Tiling`, by which a single frame larger than
    its side is filled (what defines it; :mod:`._tiled`); None (its tiles
    themselves) fills the frame as one."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}.")
    if not isinstance(motion, (bool, np.bool_)):
        raise TypeError(f"motion must be True or False; got {motion!r}.")
    conditional = method == "conditional"
    layout, masks = _as_clip(image, mask, channel_axis)
    clip = layout.clip
    forgetting = check_forgetting(forgetting)
    interleave = check_real(interleave, "interleave (pixels)", low=0.0, low_open=True)
    if isinstance(halo, str):
        if halo != "auto":
            raise ValueError(f"halo must be 'auto', a log density ratio <= 0 or None (off); "
                             f"got {halo!r}.")
        halo = CONDITIONAL_HALO if conditional else EDGE_OUTLIER_LOGREL
    if halo is not None:
        halo = check_real(halo, "halo (a log density ratio <= 0, 'auto' or None)", high=0.0)
    if neighbourhood is None:
        neighbourhood = CONDITIONAL_ORDER if conditional else 1
    if conditional:
        check_real(neighbourhood, "neighbourhood (the models' hierarchical order)", low=1,
                   high=8, integer=True)
        offsets = causal_neighbourhood(int(neighbourhood))
    else:
        offsets = line_offsets(neighbourhood)
    T, H, W, C = clip.shape
    reach = int(np.abs(offsets).max())
    if H <= 2 * reach or W <= 2 * reach:
        raise ValueError(f"the frame ({H}x{W}) is too small for neighbourhood order "
                         f"{neighbourhood}: it needs more than {2 * reach} pixels each way.")
    damaged = [bool(np.asarray(masks[t]).any()) for t in range(T)]
    if not any(damaged):
        warnings.warn("the mask is empty: nothing to restore, the input is returned "
                      "unchanged.", UserWarning, stacklevel=2)
    if by_tiles is not None:  # the caller's own mask (not a tile's or a block's)
        _warn_if_mostly_masked(masks)
    if by_tiles is not None and layout.single and any(damaged) \
            and max(H, W) > by_tiles.side:
        return (yield from _iter_by_tiles(
                layout, masks[0], by_tiles.fill, temporal=temporal,
                neighbourhood=neighbourhood, forgetting=forgetting, interleave=interleave,
                halo=halo, method=method, motion=motion))
    out = np.array(clip, copy=True)
    units = _working_units(clip)
    edge_test = CONDITIONAL_EDGE_TEST
    work = np.cumsum([1.0 if d else _CLEAN_FRAME_WORK for d in damaged])
    work /= work[-1]
    previous = None
    frame = np.empty((H, W, C))  # the frame being restored, as float
    buffers = []  # the scans' work arrays, reused from frame to frame
    for t in range(T):
        message = f"frame {t + 1}/{T}"
        meter = _Meter()
        if damaged[t]:
            frame_mask = np.asarray(masks[t])
            yield from _as_float(clip[t], frame, meter, work[t - 1] if t else 0.0,
                                 f"{message}, preparing", units=units)
            context = previous if temporal else None
            if context is not None and motion:  # the previous frame moved onto this one
                flow = yield from _as_frame_records(
                    iter_estimate_motion(frame, context, mask=frame_mask),
                    work[t - 1] if t else 0.0, f"{message}, motion")
                context = warp_frame(context, flow)
            if conditional:
                fill = iter_fill_conditional(
                    frame, frame_mask, order=int(neighbourhood),
                    previous=context,
                    halo=None if halo is None else float(halo), halo_rings=edge_test.rings,
                    halo_blend=edge_test.blend, halo_region_blend=edge_test.region_blend,
                    halo_unblend=edge_test.unblend, message=message)
            else:
                fill = _iter_fill_frame(frame, frame_mask, context,
                                        offsets, float(forgetting), float(interleave), 1e-6,
                                        None if halo is None else float(halo), message,
                                        buffers)
            values = yield from stage(fill, work[t - 1] if t else 0.0, work[t])
            if units is not None:
                values = values * units[1] + units[0]
            out[t][frame_mask] = _to_dtype(values, clip.dtype)
        if temporal and t + 1 < T:  # the next frame's context: this one, restored
            if previous is None:
                previous = np.empty((H, W, C))
            yield from _as_float(out[t], previous, meter, float(work[t]),
                                 f"{message}, preparing", units=units)
        restored_frame = layout.frame_to_input(out[t]).view()
        restored_frame.flags.writeable = False
        yield Progress("frames", float(work[t]), message, (t, restored_frame))
    return layout.to_input(out)

