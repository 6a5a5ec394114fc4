"""Filling scratches and blotches (section 14.7, docs/inpainting.md).

:func:`inpaint` fills the masked pixels of a frame or a clip with the
conditional mean of adaptive CAR models that move towards the damage: four
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
from concurrent.futures import ThreadPoolExecutor, as_completed

import numpy as np

from .._progress import Progress, drain, stage
from ..model.neighbourhood import Context
from ..model.recursive import default_prior, scan
from ._layout import MAX_COLOURS, read_layout

__all__ = ["DEFAULT_INTERLEAVE", "EDGE_OUTLIER_LOGREL", "inpaint", "iter_inpaint",
           "line_offsets"]

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
    layout = read_layout(arr, channel_axis)
    clip = layout.clip
    if clip.dtype.kind == "f" and not np.all(np.isfinite(clip)):
        raise ValueError("image contains NaN or infinite values; replace them (they are "
                         "missing pixels: put them in the mask and fill them with 0).")
    m = np.asarray(mask)
    if m.dtype.kind not in "biuf":
        raise TypeError(f"mask must be boolean or numeric (nonzero = missing); got {m.dtype}.")
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
    if isinstance(depth, (bool, np.bool_)) or int(depth) != depth or not 1 <= depth <= 8:
        raise ValueError(f"neighbourhood (scan lines used) must be an int from 1 to 8; "
                         f"got {depth!r}.")
    return np.array([(di, dj) for di in range(1, int(depth) + 1)
                     for dj in range(-half_width, half_width + 1)], np.int64)


# --- one frame ----------------------------------------------------------------------


def _side_distance(mask):
    """Distance (pixels) from each pixel to the nearest known pixel to its
    left in the same row (1 for a missing pixel right of a known one); large
    where the row has no known pixel on that side."""
    H, W = mask.shape
    dist = np.zeros((H, W))
    run = np.full(H, float(W))  # rows starting in a hole: far from any known pixel
    for j in range(W):
        run = np.where(mask[:, j], run + 1.0, 0.0)
        dist[:, j] = run
    return dist


def _iter_fill_frame(frame, mask, previous, offsets, forgetting, interleave, prior, halo,
                     message):
    """Conditional-mean fill of one (H, W, C) float frame, a Progress record
    after each of the four scans but the last; returns the filled values at
    ``mask`` as (n_missing, C)."""
    H, W, C = frame.shape
    known = ~mask
    mean = frame[known].mean(axis=0)
    var = frame[known].var(axis=0)
    # fills stay within the known pixels' range: a chain of predictions
    # through a long hole (a full-height scratch seen by the vertical models)
    # can otherwise run away
    fill_range = (frame[known].min(axis=0) - mean, frame[known].max(axis=0) - mean)
    offsets = np.asarray(offsets, np.int64)
    taps = [(di, dj, c) for di, dj in offsets for c in range(C)]
    if previous is not None:  # 3.5D: the previous frame at r and at the same offsets
        taps += [(0, 0, C + c) for c in range(C)]
        taps += [(di, dj, C + c) for di, dj in offsets for c in range(C)]
    context = Context(np.array(taps, np.int64), np.arange(C))
    pad = max(max(context.reach[0]), max(context.reach[1]))
    parts = [frame - mean] + ([] if previous is None else [previous - mean])
    source = np.concatenate(parts, axis=2)
    source[mask, :C] = 0.0  # damaged values never enter (the previous frame is restored)
    source = np.ascontiguousarray(np.pad(source, ((pad, pad), (pad, pad), (0, 0)),
                                          mode="reflect"))
    # the known pixels bordering the damage are suspect: soft-edged damage
    # (a blotch or dust whose fringe is below the mask's threshold) leaves a
    # halo there, and a one-line model copies it into the hole. Each scan
    # tests them as it reaches them and fills the outliers (see
    # EDGE_OUTLIER_LOGREL); pixels outside the mask are still returned as given.
    from scipy import ndimage

    codes = mask.astype(np.uint8)
    if halo is not None:
        codes[ndimage.binary_dilation(mask, structure=_CROSS) & ~mask] = 2
    padded_codes = np.ascontiguousarray(np.pad(codes, pad, mode="reflect"))
    pri = default_prior(var, context.n_regressors, True, C, prior)

    def fill(direction):
        work = source.copy()
        scan(work, context, direction=direction, forgetting=forgetting, intercept=True,
             prior=pri, outputs=(), missing=padded_codes.copy(), fill_range=fill_range,
             suspect_logrel=-np.inf if halo is None else halo)
        out = work[pad:-pad, pad:-pad, :C] if pad else work[..., :C]
        return out[mask]

    # the scans are independent (two at a time: the machine's cores); a yield
    # after each lets a Cancel stop the frame between them
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = [pool.submit(fill, direction) for direction in _DIRECTIONS]
        try:
            for done, _ in enumerate(as_completed(futures), start=1):
                if done < len(futures):
                    yield Progress("frames", done / len(futures),
                                   f"{message}, scan {done}/{len(futures)}")
        finally:
            for future in futures:
                future.cancel()  # those not started yet, when the job is closed
        filled = [future.result() for future in futures]
    # exponential interleaving (section 14.7): each model's weight decays with the
    # distance from the known data on its side
    distance = [
        _side_distance(mask.T).T[mask],  # from the top
        _side_distance(mask[::-1].T).T[::-1][mask],  # from the bottom
        _side_distance(mask)[mask],  # from the left
        _side_distance(mask[:, ::-1])[:, ::-1][mask],  # from the right
    ]
    nearest = np.minimum.reduce(distance)  # exp of differences only: no underflow
    weights = [np.exp(-(d - nearest) / interleave)[:, None] for d in distance]
    values = sum(w * f for w, f in zip(weights, filled, strict=True)) / sum(weights)
    return values + mean


def _to_dtype(values, dtype):
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        return np.clip(np.round(values), info.min, info.max).astype(dtype)
    return values.astype(dtype)


def iter_inpaint(image, mask, *, temporal=True, neighbourhood=1, forgetting=0.9995,
                 interleave=DEFAULT_INTERLEAVE, halo=EDGE_OUTLIER_LOGREL, channel_axis=-1):
    """Fill damaged pixels, as a job: Progress records, then the result.

    The generator form of :func:`inpaint`, with the same parameters and
    result. Each frame is four scans; a record follows each scan, and the
    last record of frame ``t`` carries that frame restored, for live display.

    Parameters
    ----------
    image : ndarray
        A frame ``(H, W)`` or ``(H, W, C)``, or a clip ``(T, H, W)`` or
        ``(T, H, W, C)``; see :func:`inpaint` for how ``channel_axis`` reads it.
    mask : (H, W) or (T, H, W) array_like of bool
        True (nonzero) where pixels are missing; (H, W) applies to every frame.
    temporal : bool, optional
        Use the previous restored frame as context (clips only).
    neighbourhood : int, optional
        How many previous scan lines the models see (see :func:`inpaint`).
    forgetting : float in (0, 1], optional
        Forgetting factor of the adaptive models.
    interleave : float, optional
        Decay length (pixels) of each side's weight.
    halo : float <= 0 or None, optional
        Threshold of the edge test (see :func:`inpaint`); None disables it.
    channel_axis : int or None, optional
        The colour axis; None forces grey.

    Returns
    -------
    ndarray
        What :func:`inpaint` returns: like ``image`` (same shape and dtype),
        pixels outside the mask bit-identical to the input.

    Yields
    ------
    Progress
        Stage ``"frames"``, with a fraction proportional to the damaged
        frames done. After frame ``t`` of ``T``: message ``"frame t+1/T"`` and
        preview ``(t, restored_frame)``, the frame in the layout of the
        input's frames (a read-only view of the result). Between its scans:
        message ``"frame t+1/T, scan k/4"``, no preview.

    Raises
    ------
    TypeError
        If the image or the mask is not numeric.
    ValueError
        If the image is neither a frame nor a clip, holds NaN or infinite
        values, or is too small; if the mask has the wrong shape or covers a
        whole frame; if an option is out of range.

    Warns
    -----
    UserWarning
        When the mask is empty (the input is returned unchanged).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> frame = np.random.default_rng(0).random((16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[:, 7] = True
    >>> job = iter_inpaint(frame, mask)
    >>> records = []
    >>> restored = drain(job, records.append)
    >>> records[-1].message, records[-1].preview[0]
    ('frame 1/1', 0)
    >>> bool(np.array_equal(restored[~mask], frame[~mask]))
    True
    """
    layout, masks = _as_clip(image, mask, channel_axis)
    clip = layout.clip
    if not 0.0 < float(forgetting) <= 1.0:
        raise ValueError(f"forgetting must be in (0, 1]; got {forgetting}.")
    if not float(interleave) > 0:
        raise ValueError(f"interleave must be a positive length in pixels; got {interleave}.")
    if halo is not None and not float(halo) <= 0:
        raise ValueError(f"halo must be a log density ratio <= 0 (or None: off); got {halo}.")
    offsets = line_offsets(neighbourhood)
    T, H, W, C = clip.shape
    reach = int(np.abs(offsets).max())
    if H <= 2 * reach or W <= 2 * reach:
        raise ValueError(f"the frame ({H}x{W}) is too small for neighbourhood order "
                         f"{neighbourhood}: it needs more than {2 * reach} pixels each way.")
    out = np.array(clip, copy=True)
    damaged = [bool(np.asarray(masks[t]).any()) for t in range(T)]
    if not any(damaged):
        warnings.warn("the mask is empty: nothing to restore, the input is returned "
                      "unchanged.", UserWarning, stacklevel=2)
    work = np.cumsum([1.0 if d else _CLEAN_FRAME_WORK for d in damaged])
    work /= work[-1]
    previous = None
    for t in range(T):
        message = f"frame {t + 1}/{T}"
        if damaged[t]:
            frame_mask = np.asarray(masks[t])
            frame = clip[t].astype(np.float64)
            fill = _iter_fill_frame(frame, frame_mask, previous if temporal else None,
                                    offsets, float(forgetting), float(interleave), 1e-6,
                                    None if halo is None else float(halo), message)
            values = yield from stage(fill, work[t - 1] if t else 0.0, work[t])
            out[t][frame_mask] = _to_dtype(values, clip.dtype)
        previous = out[t].astype(np.float64)
        restored_frame = layout.frame_to_input(out[t]).view()
        restored_frame.flags.writeable = False
        yield Progress("frames", float(work[t]), message, (t, restored_frame))
    return layout.to_input(out)


def inpaint(image, mask, *, temporal=True, neighbourhood=1, forgetting=0.9995,
            interleave=DEFAULT_INTERLEAVE, halo=EDGE_OUTLIER_LOGREL, channel_axis=-1):
    """Fill damaged pixels with the conditional mean of adaptive CAR models.

    Section 14.7, docs/inpainting.md: four models move towards the damage
    (downwards, upwards, rightwards and leftwards), filled pixels serving as
    neighbours of later ones (14.54); the four fills are combined by
    exponential interleaving. Known pixels bordering the damage that a model
    finds improbable (the halo of soft-edged damage) are not used as its
    neighbours. In a clip the previous restored frame is part of each
    pixel's context (3.5D model) when ``temporal`` is True.

    Parameters
    ----------
    image : ndarray
        A frame or a clip, any integer or float32/64 dtype. How
        ``channel_axis`` reads it: ``(H, W)`` is a grey frame; a 3-D array is
        a colour frame ``(H, W, C)`` when the channel axis has at most 4
        entries and a grey clip ``(T, H, W)`` otherwise; a 4-D array is a
        colour clip ``(T, H, W, C)``; ``channel_axis=None`` forces grey
        (``(H, W)`` or ``(T, H, W)``, e.g. for a grey clip of 4 frames or
        fewer).
    mask : (H, W) or (T, H, W) array_like of bool
        True (nonzero) where pixels are missing (in every channel); (H, W)
        applies to every frame of a clip.
    temporal : bool, optional
        Use the previous restored frame as context (clips only).
    neighbourhood : int, optional
        How many previous scan lines the models see (default 1; see
        :func:`line_offsets`): 5 pixels of each. One line measured best on
        composited real scratches (+1.6 dB over two lines of 3 pixels): a
        deeper model extrapolates texture further into a large hole, which
        the mean squared error punishes.
    forgetting : float in (0, 1], optional
        Forgetting factor of the adaptive models.
    interleave : float, optional
        Decay length (pixels) of each side's weight.
    halo : float <= 0 or None, optional
        Known pixels next to the mask (4-neighbours) whose log predictive
        density relative to its peak is below this, when a model reaches
        them, are treated as damaged by that model (not used as its
        neighbours; still returned unchanged). Soft-edged damage leaves such
        a halo just outside a mask drawn at its core. Default
        ``EDGE_OUTLIER_LOGREL`` (-12); None disables the test.
    channel_axis : int or None, optional
        The colour axis (default -1, the last); None forces grey.

    Returns
    -------
    ndarray
        Like ``image`` (same shape and dtype); pixels outside the mask are
        bit-identical to the input.

    Raises
    ------
    TypeError
        If the image or the mask is not numeric.
    ValueError
        If the image is neither a frame nor a clip, holds NaN or infinite
        values, or is too small for the neighbourhood; if the mask has the
        wrong shape or covers a whole frame; if an option is out of range.

    Warns
    -----
    UserWarning
        When the mask is empty (the input is returned unchanged).

    See Also
    --------
    iter_inpaint : The same as a job, with progress and each restored frame.
    detect_scratches : Propose a mask.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.random.default_rng(0).random((16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[4:8, 4:8] = True
    >>> restored = inpaint(frame, mask)
    >>> restored.shape, bool(np.array_equal(restored[~mask], frame[~mask]))
    ((16, 16), True)
    """
    return drain(iter_inpaint(image, mask, temporal=temporal, neighbourhood=neighbourhood,
                              forgetting=forgetting, interleave=interleave, halo=halo,
                              channel_axis=channel_axis))
