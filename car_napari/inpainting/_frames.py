"""Clips longer than memory, a block of frames at a time, on the shared
driver :func:`car_napari._frames.iter_frame_blocks`: the fill
(:func:`iter_inpaint_frames`) and detection with the fill
(:func:`iter_descratch_frames`). Each block gets the context the whole clip
gives its frames (the restored frame before it; for the blotch test one
source frame each side), so the output equals the in-memory call's.
"""

from __future__ import annotations

import numpy as np

from .._docstrings import documents_job
from .._frames import DEFAULT_BLOCK, check_clip, iter_frame_blocks
from .._progress import Progress, drain, stage
from .._tiles import read_array
from ._detection import iter_detect_scratches
from ._filling import iter_inpaint_in_memory
from ._layout import fit_mask

__all__ = ["descratch_frames", "inpaint_frames", "iter_descratch_frames", "iter_inpaint_frames"]


def _block_masks(mask, block, shape):
    """The masks of the block's frames ``(n, H, W)`` bool: one mask for every
    frame (``(h, w)``) or the block's part of a mask per frame, fitted to
    the frames ``shape`` (nearest neighbour when drawn at another size)."""
    n = block.stop - block.start
    if mask.ndim == 2:  # fitted once, before the first block
        return np.broadcast_to(mask, (n, *mask.shape))
    own = read_array(mask[block.start:block.stop])
    fitted = fit_mask(own, (n, *shape))
    return fitted if fitted.ndim == 3 else np.broadcast_to(fitted, (n, *fitted.shape))


def _inpaint_frames(frames, masks, previous, temporal, channel_axis, options):
    """Inpaint a block's ``frames`` with ``masks`` (n, H, W); with
    ``temporal``, the restored frame before the block (``previous``, None for
    the first block) as the first frame's context, exactly as in the
    whole clip. A job returning the block's restored frames."""
    if not np.any(masks):  # what iter_inpaint returns then, without its warning
        yield Progress("frames", 1.0, "no damage")
        return np.array(frames, copy=True)
    lead = 0
    if temporal and previous is not None:  # undamaged, it is the next frame's context
        frames = np.concatenate([previous[-1:].astype(frames.dtype, copy=False), frames])
        masks = np.concatenate([np.zeros((1, *masks.shape[1:]), bool), masks])
        lead = 1
    axis = None if channel_axis is None else -1
    restored = yield from iter_inpaint_in_memory(frames, masks, temporal=temporal,
                                                 channel_axis=axis, **options)
    return restored[lead:]


def iter_inpaint_frames(clip, mask, restored, *, block=DEFAULT_BLOCK, temporal=True,
                        channel_axis=None, **options):
    """Fill the damaged pixels of a clip, a block of frames at a time, as a job.

    {plain form}

    Yields
    ------
    Progress
        The fill's records of each block (stage ``'frames'``, fractions of
        the whole clip, messages prefixed ``'frames a-b/T: '``), and a record
        with ``preview=(start, stop)`` when a block is written.

    Examples
    --------
    >>> from car_napari.inpainting import inpaint
    >>> clip = np.random.default_rng(0).random((5, 16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[:, 7] = True
    >>> out = np.zeros_like(clip)
    >>> drain(iter_inpaint_frames(clip, mask, out, block=2))
    5
    >>> bool(np.array_equal(out, inpaint(clip, mask, channel_axis=None)))
    True
    """
    check_clip(clip, channel_axis)
    mask_ndim = len(getattr(mask, "shape", np.shape(mask)))
    if mask_ndim not in (2, 3):
        raise ValueError(f"mask must be (h, w) for every frame or (T, h, w) one per frame; "
                         f"got shape {tuple(np.shape(mask))}.")
    if mask_ndim == 3 and mask.shape[0] != clip.shape[0]:
        raise ValueError(f"mask has {mask.shape[0]} frames and the clip {clip.shape[0]}.")
    frame_shape = tuple(clip.shape[1:3])
    mask = mask if hasattr(mask, "ndim") else np.asarray(mask)
    if mask.ndim == 2:
            mask = fit_mask(np.asarray(mask), frame_shape)

    def job(block):
        masks = _block_masks(mask, block, frame_shape)
        return (yield from _inpaint_frames(block.own, masks, block.previous, bool(temporal),
                                           channel_axis, options))

    return (yield from iter_frame_blocks(clip, job, restored, block=block,
                                         carry=1 if temporal else 0))


def iter_descratch_frames(clip, restored, masks=None, *, block=DEFAULT_BLOCK,
                          kinds=("line", "blotch"), temporal=True, channel_axis=None,
                          detect_options=None, **options):
    """Detect and fill scratches and blotches in a clip, by blocks, as a job.

    {plain form}

    Yields
    ------
    Progress
        For each block, the detection's records (the first 30 % of its
        share), then the fill's; messages prefixed ``'frames a-b/T: '``;
        ``preview=(start, stop)`` when a block and its masks are written.

    Examples
    --------
    >>> from car_napari.inpainting import detect_scratches, inpaint
    >>> clip = np.random.default_rng(0).random((5, 24, 24))
    >>> clip[1:4, :, 9] = 1.0
    >>> out = np.zeros_like(clip)
    >>> drain(iter_descratch_frames(clip, out, block=2))
    5
    >>> whole = inpaint(clip, detect_scratches(clip, channel_axis=None), channel_axis=None)
    >>> bool(np.array_equal(out, whole))
    True
    """
    check_clip(clip, channel_axis)
    kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
    detect_options = dict(detect_options or {})
    axis = None if channel_axis is None else -1
    n = clip.shape[0]
    # the whole clip's detector runs the blotch test only on a clip of 3 frames or more
    kinds = kinds if n >= 3 else tuple(k for k in kinds if k != "blotch")
    if not kinds:
        raise ValueError("kinds must name 'line' (a clip of fewer than 3 frames has no "
                         "blotch test).")

    def job(block):
        found = yield from stage(
            iter_detect_scratches(block.frames, kinds=kinds, channel_axis=axis,
                                  **detect_options), 0.0, 0.3)
        found = np.asarray(found)
        found = found[block.lead:len(found) - block.trail]
        if found.ndim == 2:
            found = found[None]
        frames = yield from stage(
            _inpaint_frames(block.own, found, block.previous, bool(temporal), channel_axis,
                            options), 0.3, 1.0)
        return frames, found

    return (yield from iter_frame_blocks(clip, job, (restored, masks), block=block,
                                         before=1, after=1, carry=1 if temporal else 0))


@documents_job(iter_inpaint_frames)
def inpaint_frames(clip, mask, restored, *, block=DEFAULT_BLOCK, temporal=True,
                   channel_axis=None, **options):
    """Fill the damaged pixels of a clip, a block of frames at a time.

    With ``temporal`` each block gets the restored frame before it as the
    context of its first frame, so the result equals
    ``inpaint(clip, mask, ...)`` on the whole clip in memory.

    Parameters
    ----------
    clip : array_like
        ``(T, H, W)`` grey or ``(T, H, W, C)`` colour (``channel_axis=-1``),
        any dtype :func:`~car_napari.inpainting.inpaint` takes; only read.
    mask : array_like
        ``(h, w)`` for every frame, or ``(T, h, w)`` one per frame (lazy
        too: read by block); non-zero is damaged; drawn at another size it
        is resized (nearest neighbour, :func:`~car_napari.inpainting.fit_mask`).
    restored : array_like or callable
        Where the restored frames go (``restored[start:stop] = frames`` or
        ``restored(start, frames)``), in the clip's layout and dtype.
    block : int, optional
        Frames read at a time.
    temporal : bool, optional
        Use the previous restored frame as context (across blocks too).
    channel_axis : {None, -1}, optional
        None: a grey clip; -1: a colour clip.
    **options
        :func:`~car_napari.inpainting.inpaint`'s other options.

    Returns
    -------
    int
        The number of frames.

    Raises
    ------
    ValueError
        If the clip or the mask has the wrong shape, or an option is out of
        range.

    Examples
    --------
    >>> clip = np.random.default_rng(0).random((2, 16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[3, 3] = True
    >>> inpaint_frames(clip, mask, np.zeros_like(clip))
    2
    """
    return drain(iter_inpaint_frames(clip, mask, restored, block=block, temporal=temporal,
                                     channel_axis=channel_axis, **options))


@documents_job(iter_descratch_frames)
def descratch_frames(clip, restored, masks=None, *, block=DEFAULT_BLOCK,
                     kinds=("line", "blotch"), temporal=True, channel_axis=None,
                     detect_options=None, **options):
    """Detect and fill scratches and blotches in a clip, a block of frames at a time.

    Each block is detected with one source frame of context on each side
    (the blotch test compares a frame with both neighbours), then filled
    with the restored frame before it as context: the result equals
    ``inpaint(clip, detect_scratches(clip, ...), ...)`` on the whole clip.

    Parameters
    ----------
    clip : array_like
        ``(T, H, W)`` grey or ``(T, H, W, C)`` colour (``channel_axis=-1``);
        only read.
    restored : array_like or callable
        Where the restored frames go (``restored[start:stop] = frames`` or
        ``restored(start, frames)``).
    masks : array_like or callable, optional
        Where the detected masks ``(T, H, W)`` bool go.
    block : int, optional
        Frames a block.
    kinds : sequence of {'line', 'blotch'}, optional
        What :func:`~car_napari.inpainting.detect_scratches` looks for.
    temporal : bool, optional
        Use the previous restored frame as context (across blocks too).
    channel_axis : {None, -1}, optional
        None: a grey clip; -1: a colour clip.
    detect_options : dict, optional
        Other options of :func:`~car_napari.inpainting.detect_scratches`.
    **options
        :func:`~car_napari.inpainting.inpaint`'s other options.

    Returns
    -------
    int
        The number of frames.

    Examples
    --------
    >>> clip = np.random.default_rng(0).random((3, 24, 24))
    >>> descratch_frames(clip, np.zeros_like(clip))
    3
    """
    return drain(iter_descratch_frames(clip, restored, masks, block=block, kinds=kinds,
                                       temporal=temporal, channel_axis=channel_axis,
                                       detect_options=detect_options, **options))
