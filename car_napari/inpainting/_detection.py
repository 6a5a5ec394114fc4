"""Proposing a damage mask (section 14.7, docs/inpainting.md).

:func:`detect_scratches` finds vertical line scratches (thin, brighter or
darker than both sides, persisting down the frame) and, in clips, blotches
(pixels that disagree with both neighbouring frames, warped onto the frame
by the estimated motion, in the same direction).
"""

from __future__ import annotations

import numpy as np

from .._docstrings import documents_job, shared_parameters
from .._progress import Progress, drain, mapped, row_blocks
from .._validation import as_channel_last_float, check_real
from . import _motion
from ._layout import read_layout

__all__ = ["detect_scratches", "iter_detect_scratches"]

KINDS = ("line", "blotch")


# Work between two progress records, in pixels of one pass over a frame: a
# 4000x4000 frame is cut into row (or column) bands of about 0.05-0.1 s each,
# so a Cancel stops the detector within a fraction of a second. Every pass is
# exact per band (row-local, column-local or with a halo of rows), so the mask
# does not depend on the band size.
BAND_PIXELS = 1 << 19
_BLOTCH_HALO = 4  # rows: the reach of the opening (2x2) and the dilation (3x3), and a spare
_LINE_PASSES = 5  # contrast, median, strong, persistence, dilation
_MIN_LINE_ROWS = 3  # the shortest vertical run the line search looks along
_BLOTCH_PASSES = 2  # the blotch test is about twice as heavy as one line pass
_MOTION_PASSES = 12  # the two flows of a frame weigh about twelve passes of a frame
# The blotch test on motion-compensated neighbours compares a pixel with the
# neighbours' pixels within MOTION_TOLERANCE pixels of it (a flow is right to
# about a pixel at edges; 0.5: half a pixel, the mean of a pixel and its
# 4-neighbours' extreme), and asks the two neighbours to agree with each
# other to within AGREEMENT times the spike (None: not asked), with a
# threshold of COMPENSATED_THRESHOLD. Chosen on the TUNING clips of
# benchmarks/bench_clip.py (tolerance 0.5 or 1, agreement 0.5, 1 or none,
# threshold 0.08-0.12: the best recall with at most 0.5 % of the undamaged
# moving pixels flagged), never on its REPORT clips. Also measured there and
# left out: a round-trip (forward-backward) flow check, which drops the
# recall to 0.16-0.77 (a blotch makes the flows disagree too).
MOTION_TOLERANCE = 1
AGREEMENT = 1.0
COMPENSATED_THRESHOLD = 0.04  # image scale [0, 1]
# The 3x3 growth round what the compensated test finds reaches only pixels
# whose spike exceeds GROW_SPIKE times the threshold (None: all of them).
# Most undamaged moving pixels flagged (0.37 % on the TUNING clips, 1.85 % on
# one REPORT clip) were that growth, two pixels from the damage, not
# occlusions or flow errors at the borders. With the growth so limited the
# threshold went from 0.08 to 0.04: on the TUNING clips (threshold 0.04-0.08
# x GROW_SPIKE 0-1) the best recall with every clip's moving fraction under
# 0.3 % (recall 0.832, precision 0.977, worst moving 0.25 %; before: 0.821,
# 0.966, 0.85 %).
GROW_SPIKE = 0.5
BLOTCH_THRESHOLD = 0.12  # the raw test (motion=False), image scale [0, 1]
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)


def _iter_grey(clip, colour, grey, t, band_pixels):
    """Fill ``grey[t]`` with frame ``t`` as grey floats (the channel mean) by
    row bands; yields the pixels done after each band."""
    _, H, W = grey.shape
    for a, b in row_blocks(H, band_pixels // W):
        f = clip[t, a:b]
        g = as_channel_last_float(f if colour else f[..., 0],
                                  channel_axis=-1 if colour else None, name="frame")
        grey[t, a:b] = g.mean(axis=2)
        yield (b - a) * W


def _iter_line_mask(g, w, length, line_threshold, band_pixels, out):
    """Vertical line scratches of one grey (H, W) frame into ``out``, in
    bands; yields the pixels done after each band (:data:`_LINE_PASSES`
    passes of H * W)."""
    from scipy import ndimage

    H, W = g.shape
    rows = row_blocks(H, band_pixels // W)
    contrast = np.zeros_like(g)
    steps = np.empty((H, W - 1))
    for a, b in rows:  # row-local: the contrast with both sides, the horizontal steps
        band = g[a:b]
        left = band[:, w:-w] - band[:, : -2 * w]
        right = band[:, w:-w] - band[:, 2 * w :]
        # a line is brighter (darker) than *both* sides; a step edge is not
        contrast[a:b, w:-w] = np.where(left * right > 0, np.sign(left) * np.minimum(
            np.abs(left), np.abs(right)), 0.0)
        steps[a:b] = np.abs(band[:, 1:] - band[:, :-1])
        yield (b - a) * W
    scale = 1.4826 * np.median(steps, overwrite_input=True) + 1e-12  # one call: ~0.3 s
    del steps
    yield H * W
    strong = np.empty((H, W), bool)
    signed = np.empty((H, W))
    for a, b in rows:
        strong[a:b] = np.abs(contrast[a:b]) > line_threshold * scale
        signed[a:b] = np.sign(contrast[a:b]) * strong[a:b]
        yield (b - a) * W
    lines = np.empty((H, W), bool)
    for c, d in row_blocks(W, band_pixels // H):  # column-local: persistence down the frame
        # most rows of a long vertical window agree in sign
        along = ndimage.uniform_filter1d(signed[:, c:d], length, axis=0, mode="nearest")
        lines[:, c:d] = strong[:, c:d] & (np.abs(along) > 0.5) & (
            np.sign(along) == np.sign(contrast[:, c:d]))
        yield H * (d - c)
    del contrast, signed, strong
    for a, b in rows:  # fill the scratch's width (the contrast peaks at its centre)
        out[a:b] |= ndimage.binary_dilation(lines[a:b], structure=np.ones((1, 3), bool))
        yield (b - a) * W


def _blotch_mask(before, frame, after, blotch_threshold):
    """Blotches of one grey frame (or a band of rows) between its two
    neighbours (SDIa)."""
    from scipy import ndimage

    prev_diff = frame - before
    next_diff = frame - after
    same_sign = np.sign(prev_diff) == np.sign(next_diff)
    spikes = same_sign & (np.minimum(np.abs(prev_diff), np.abs(next_diff))
                          > blotch_threshold)
    spikes = ndimage.binary_opening(spikes, structure=np.ones((2, 2), bool))
    return ndimage.binary_dilation(spikes, structure=np.ones((3, 3), bool))


def _compensated_blotch_mask(before, frame, after, blotch_threshold):
    """Blotches of one grey frame (or a band of rows) between its two
    neighbours warped onto it: a pixel brighter (darker) than every pixel
    within :data:`MOTION_TOLERANCE` of it in both warped neighbours by more
    than the threshold (the tolerance absorbs the flow's sub-pixel errors
    at edges)."""
    from scipy import ndimage

    if MOTION_TOLERANCE >= 1:
        size = 2 * int(MOTION_TOLERANCE) + 1
        brighter = np.minimum(frame - ndimage.maximum_filter(before, size),
                              frame - ndimage.maximum_filter(after, size))
        darker = np.minimum(ndimage.minimum_filter(before, size) - frame,
                            ndimage.minimum_filter(after, size) - frame)
    elif MOTION_TOLERANCE:  # half a pixel: the extremes of the neighbours moved by 1/2 px
        def high(image):
            return 0.5 * (image + ndimage.maximum_filter(image, footprint=_CROSS))

        def low(image):
            return 0.5 * (image + ndimage.minimum_filter(image, footprint=_CROSS))

        brighter = np.minimum(frame - high(before), frame - high(after))
        darker = np.minimum(low(before) - frame, low(after) - frame)
    else:
        brighter = np.minimum(frame - before, frame - after)
        darker = np.minimum(before - frame, after - frame)
    spike = np.maximum(brighter, darker)
    spikes = spike > blotch_threshold
    if AGREEMENT is not None:  # the two neighbours agree with each other (SDIp)
        spikes &= np.abs(before - after) < AGREEMENT * spike
    spikes = ndimage.binary_opening(spikes, structure=np.ones((2, 2), bool))
    grown = ndimage.binary_dilation(spikes, structure=np.ones((3, 3), bool))
    if GROW_SPIKE is None:
        return grown
    # grown only into pixels that still stand out (hysteresis): the fringe of a
    # blotch does, the clean pixels around it (moving content) do not
    return spikes | (grown & (spike > GROW_SPIKE * blotch_threshold))


def _iter_blotch_mask(before, frame, after, blotch_threshold, band_pixels, out,
                      compensated=False):
    """Blotches of a grey (H, W) frame between its neighbours (warped onto
    it when ``compensated``) into ``out``, by row bands with a halo (exact);
    yields the pixels done (:data:`_BLOTCH_PASSES` passes of H * W)."""
    H, W = frame.shape
    for a, b in row_blocks(H, band_pixels // W):
        lo, hi = max(a - _BLOTCH_HALO, 0), min(b + _BLOTCH_HALO, H)
        if compensated:
            found = _compensated_blotch_mask(before[lo:hi], frame[lo:hi], after[lo:hi],
                                             blotch_threshold)
        else:
            found = _blotch_mask(before[lo:hi], frame[lo:hi], after[lo:hi],
                                 blotch_threshold)
        out[a:b] |= found[a - lo : b - lo]
        yield _BLOTCH_PASSES * (b - a) * W


def _iter_flows(grey, mask, pairs, cache, pixels):
    """The coarse flows from frame ``a`` to frame ``b`` of the grey clip for
    ``(a, b)`` in ``pairs`` into ``cache`` (those not there yet), each
    estimated with frame ``a``'s damage found so far (``mask``) ignored;
    yields the pixels done (``pixels`` a unit of a flow's work)."""
    for a, b in pairs:
        if (a, b) in cache:
            continue
        job = _motion._iter_flow(grey[a].astype(np.float32), grey[b].astype(np.float32),
                                 (~mask[a]).astype(np.float32), _motion.RADIUS,
                                 _motion.ITERATIONS, _motion.REGULARISATION,
                                 _motion.FLOW_PIXELS)
        cache[(a, b)] = yield from mapped(job, lambda units: units * pixels)


def _iter_compensated(grey, t, mask, out, cache):
    """Frame ``t``'s two neighbours in the grey clip warped onto it into
    ``out`` (2, H, W); yields the pixels done (:data:`_MOTION_PASSES` / 2
    passes of H * W a flow). Flows go through ``cache``, emptied of those
    later frames do not need."""
    _, H, W = grey.shape
    per_flow = _motion._work_units(H, W, _motion.ITERATIONS, _motion.FLOW_PIXELS)
    pixels = _MOTION_PASSES * H * W / 2 / per_flow  # a flow's unit of work, in pixels
    yield from _iter_flows(grey, mask, [(t, t - 1), (t, t + 1)], cache, pixels)
    for k, other in enumerate((t - 1, t + 1)):
        out[k] = _motion._warp(grey[other][..., None], cache[(t, other)])[..., 0]
    for key in [key for key in cache if min(key) <= t]:
        del cache[key]


def _iter_records(work, stage, fraction, message, band_pixels):
    """Run ``work`` (a generator of pixels done, see above); a Progress
    record each time ``band_pixels`` more are done. ``fraction(done)`` maps
    the job's pixels done to its fraction; returns the pixels done."""
    done = pending = 0
    for pixels in work:
        done += pixels
        pending += pixels
        if pending >= band_pixels:
            pending = 0
            yield Progress(stage, fraction(done), message)
    return done


# the Parameters of detect_scratches and iter_detect_scratches, written once
_DETECT_SCRATCHES_PARAMETERS = """
    image : ndarray
        A frame or a clip, any numeric dtype (integers are scaled to [0, 1]).
        How ``channel_axis`` reads it (the rule of :func:`inpaint`):
        ``(H, W)`` is a grey frame; a 3-D array is a colour frame
        ``(H, W, C)`` when the channel axis has at most 4 entries and a grey
        clip ``(T, H, W)`` otherwise; a 4-D array is a colour clip
        ``(T, H, W, C)``; ``channel_axis=None`` forces grey.
    kinds : str or sequence of {'line', 'blotch'}, optional
        What to look for.
    channel_axis : int or None, optional
        The colour axis (default -1, the last); None forces grey.
    line_width : int, optional
        Distance (pixels) of the two side pixels a line pixel is compared to.
    line_length : float, optional
        Length of the persistence window, as a fraction of the frame height.
    line_threshold : float, optional
        Contrast a line needs, in robust standard deviations of the
        horizontal pixel differences.
    blotch_threshold : float, optional
        Difference from both neighbouring frames a blotch needs (image scale
        [0, 1]); default :data:`COMPENSATED_THRESHOLD` (0.04) with motion
        compensation, :data:`BLOTCH_THRESHOLD` (0.12) without.
    motion : bool, optional
        True (default): compare each frame with its neighbours warped onto
        it by the estimated motion (see above), so that moving content is
        left alone; False: with the raw neighbours (plain SDIa, which flags
        whatever moves).
"""


def iter_detect_scratches(image, *, kinds=KINDS, channel_axis=-1, line_width=3,
                          line_length=0.5, line_threshold=4.0,
                          blotch_threshold=None, motion=True):
    """Propose a damage mask, as a job: Progress records, then the mask.

    {plain form}

    Yields
    ------
    Progress
        Stage ``"lines"`` after each frame's line search and ``"blotches"``
        after each inner frame's blotch test, message like ``"frame 3/24"``,
        no preview. A large frame is worked on in bands of rows (or columns)
        of about :data:`BAND_PIXELS` pixels, with a record (stage
        ``"reading"``, ``"lines"``, ``"motion"`` or ``"blotches"``) after
        each (the motion estimate: after every warp of its pyramid): on a
        4000x4000 frame one every tenth of a second or so. The fraction is
        proportional to the pixels processed.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> clip = np.random.default_rng(0).random((3, 16, 16)) * 0.05
    >>> records = []
    >>> mask = drain(iter_detect_scratches(clip, kinds="blotch"), records.append)
    >>> mask.shape, records[-1].stage, records[-1].fraction
    ((3, 16, 16), 'blotches', 1.0)
    """
    if isinstance(kinds, str):
        kinds = (kinds,)
    elif isinstance(kinds, (tuple, list, set, frozenset)):
        kinds = tuple(kinds)
    else:
        raise TypeError(f"kinds must be 'line', 'blotch' or a tuple of them; got {kinds!r}.")
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"kinds must be a subset of ('line', 'blotch'); got {kinds}.")
    arr = np.asarray(image)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"image has dtype {arr.dtype}; pass a numeric (integer or float) "
                        "frame or clip.")
    layout = read_layout(arr, channel_axis)
    if arr.size == 0:
        raise ValueError(f"image is empty (shape {arr.shape}); pass a non-empty frame or clip.")
    T, H, W = layout.clip.shape[:3]
    lines = "line" in kinds
    blotches = "blotch" in kinds and T >= 3
    w = check_real(line_width, "line_width (pixels)", low=1, high=1 << 16, integer=True)
    line_length = check_real(line_length, "line_length (a fraction of the frame's height)",
                             low=0.0, high=1.0, low_open=True)
    check_real(line_threshold, "line_threshold", low=0.0, low_open=True)
    if lines and (W <= 2 * w or H < _MIN_LINE_ROWS):
        # the line search compares each column with the columns line_width away on
        # both sides, over vertical runs of at least _MIN_LINE_ROWS rows
        raise ValueError(
            f"the frame ({H}x{W}) is too small for the line search with line_width {w}: it "
            f"needs at least {_MIN_LINE_ROWS} rows and more than {2 * w} columns (2 * "
            f"line_width). Pass a larger frame, a smaller line_width, or kinds='blotch'.")
    band = int(BAND_PIXELS)
    # the work in pixels of one pass: reading every frame, then each frame's passes
    motion = bool(motion)
    if blotch_threshold is None:
        blotch_threshold = COMPENSATED_THRESHOLD if motion else BLOTCH_THRESHOLD
    blotch_threshold = check_real(blotch_threshold, "blotch_threshold (a difference on the "
                                  "image scale [0, 1])", low=0.0, low_open=True)
    total = H * W * (T + (_LINE_PASSES * T if lines else 0)
                     + (_BLOTCH_PASSES * (T - 2) if blotches else 0)
                     + (_MOTION_PASSES * (T - 2) if blotches and motion else 0))
    done = 0

    def at(start):  # the job's fraction when a stage begun at ``start`` has done ``pixels``
        return lambda pixels: (start + pixels) / total

    grey = np.empty((T, H, W))
    for t in range(T):
        done += yield from _iter_records(
            _iter_grey(layout.clip, layout.colour, grey, t, band), "reading", at(done),
            f"frame {t + 1}/{T}", band)
    mask = np.zeros((T, H, W), bool)
    if lines:
        length = max(_MIN_LINE_ROWS, int(line_length * H) | 1)
        for t in range(T):
            message = f"frame {t + 1}/{T}"
            done += yield from _iter_records(
                _iter_line_mask(grey[t], w, length, line_threshold, band, mask[t]), "lines",
                at(done), message, band)
            yield Progress("lines", done / total, message)
    if blotches:
        neighbours = np.empty((2, H, W)) if motion else None
        flows = {}
        for t in range(1, T - 1):
            message = f"frame {t + 1}/{T}"
            if motion:  # the lines found are damage: they do not steer the motion
                done += yield from _iter_records(
                    _iter_compensated(grey, t, mask, neighbours, flows), "motion", at(done),
                    message, band)
                before, after = neighbours
            else:
                before, after = grey[t - 1], grey[t + 1]
            done += yield from _iter_records(
                _iter_blotch_mask(before, grey[t], after, blotch_threshold, band, mask[t],
                                  compensated=motion), "blotches", at(done), message, band)
            yield Progress("blotches", done / total, message)
    return mask[0] if layout.single else mask


@documents_job(iter_detect_scratches)
@shared_parameters(_DETECT_SCRATCHES_PARAMETERS)
def detect_scratches(image, *, kinds=KINDS, channel_axis=-1, line_width=3,
                     line_length=0.5, line_threshold=4.0, blotch_threshold=None,
                     motion=True):
    """Propose a damage mask for a frame or a clip.

    * ``'line'``: vertical line scratches. A pixel of the grey frame (the
      channel mean) is a line candidate when it is brighter (or darker) than
      both pixels ``w = line_width`` to its left and right by more than
      ``line_threshold`` robust standard deviations of the horizontal pixel
      differences (a step edge is brighter than one side only). It is
      proposed when more than half of the rows in a vertical window of
      ``line_length`` times the frame height are candidates of the same
      sign: the scratch persists down the frame.
    * ``'blotch'`` (clips of 3 frames or more): a spike detector on
      motion-compensated frames. The motion from each frame to the previous
      and the next one is estimated (:func:`estimate_motion`, the lines
      found ignored) and both neighbours are warped onto the frame; a pixel
      is proposed when it is brighter (darker) than every pixel within
      :data:`MOTION_TOLERANCE` (1) pixel of it in both warped neighbours by
      more than ``blotch_threshold`` (image scale [0, 1]) and the two
      neighbours agree with each other to within that difference. Moving
      content agrees with its warped neighbours; a blotch, on one frame
      only, disagrees with both. Regions thinner than 2x2 pixels are
      dropped and the rest grown by a pixel into pixels that still stand out by
      half the threshold (:data:`GROW_SPIKE`). With ``motion=False``: the
      spike detector index SDIa on the raw neighbours (brighter or darker
      than both by more than the threshold), which also flags motion.

    Misses: scratches that are not vertical, lines fainter than the texture's
    own vertical structure, lines in the first and last ``line_width`` columns
    (a line is told from a step edge by both sides, and those have one only:
    the frame's own border would be a step), blotches that persist over two
    frames, blotches
    no more different from the neighbours than their own detail within a
    pixel, and damage on the first and last frames of a clip (they have one
    neighbour only). Motion the estimate cannot follow (an occlusion, a
    fast non-rigid change) can still be flagged.

    {parameters}

    Returns
    -------
    ndarray of bool
        (H, W) for a frame, (T, H, W) for a clip; True where damage is
        proposed.

    Raises
    ------
    TypeError
        If the image is not numeric.
    ValueError
        If ``kinds`` is not a subset of ('line', 'blotch'); if the image is
        neither a frame nor a clip, holds NaN or infinite values, or is too
        small for the line search (fewer than 3 rows, or at most
        ``2 * line_width`` columns: lines are vertical, so a 1x64 frame is
        refused as a 64x1 one is); if ``blotch_threshold`` is not positive.

    See Also
    --------
    iter_detect_scratches : The same as a job, with progress.
    inpaint : Fill the proposed mask.
    compensate_motion : The warped neighbours the blotch test compares with.

    Notes
    -----
    A constant frame or clip is accepted: with no contrast there is no line
    and no blotch, so the mask is all False.

    Examples
    --------
    >>> frame = np.full((32, 32), 0.5) + np.random.default_rng(0).normal(0, 0.01, (32, 32))
    >>> frame[:, 20] += 0.3  # a bright vertical scratch
    >>> mask = detect_scratches(frame, kinds="line")
    >>> bool(mask[:, 20].all()), int(mask[:, :15].sum())
    (True, 0)
    """
    return drain(iter_detect_scratches(
        image, kinds=kinds, channel_axis=channel_axis, line_width=line_width,
        line_length=line_length, line_threshold=line_threshold,
        blotch_threshold=blotch_threshold, motion=motion))
