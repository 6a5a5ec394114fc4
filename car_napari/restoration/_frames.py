"""Restoring a clip longer than memory, a block of frames at a time (each
frame restored on its own, as :func:`~car_napari.restoration.restore`
restores it), on the shared driver :func:`car_napari._frames.iter_frame_blocks`.
"""

from __future__ import annotations

import numpy as np

from .._docstrings import documents_job
from .._frames import auto_block, check_clip, iter_frame_blocks
from .._progress import drain, stage
from ._restore import iter_restore

__all__ = ["iter_restore_frames", "restore_frames"]


def _restore_block(options):
    def job(block):
        restored, probability = [], []
        for i, frame in enumerate(block.own):
            result = yield from stage(iter_restore(frame, return_result=True, **options),
                                      i / len(block.own), (i + 1) / len(block.own))
            restored.append(result.restored().reshape(frame.shape))
            probability.append(result.probability)
        return np.stack(restored), np.stack(probability)

    return job


def iter_restore_frames(clip, restored, probability=None, *, block=None, channel_axis=None,
                        **options):
    """Restore every frame of a clip, a block of frames at a time, as a job.

    {plain form}

    Yields
    ------
    Progress
        Each frame's :func:`~car_napari.restoration.iter_restore` records,
        its previews dropped, as fractions of the clip (messages prefixed
        ``'frames a-b/T: '``); ``preview=(start, stop)`` when a block is
        written (:func:`~car_napari._frames.iter_frame_blocks`).

    Examples
    --------
    >>> from car_napari.restoration import restore
    >>> clip = np.random.default_rng(0).random((3, 24, 24))
    >>> out = np.zeros_like(clip)
    >>> drain(iter_restore_frames(clip, out))
    3
    >>> bool(np.allclose(out[1], restore(clip[1])))
    True
    """
    check_clip(clip, channel_axis)
    if "return_result" in options:
        raise TypeError("return_result is not an option of iter_restore_frames.")
    job = _restore_block(dict(options, channel_axis=channel_axis))
    block = auto_block(clip) if block is None else block
    return (yield from iter_frame_blocks(clip, job, (restored, probability), block=block))


@documents_job(iter_restore_frames)
def restore_frames(clip, restored, probability=None, *, block=None, channel_axis=None,
                   **options):
    """Restore every frame of a clip, a block of frames at a time.

    Each frame is restored on its own by
    :func:`~car_napari.restoration.iter_restore` (the result equals that of
    ``restore(clip[t], ...)`` for every ``t``).

    Parameters
    ----------
    clip : array_like
        ``(T, H, W)`` grey or ``(T, H, W, C)`` colour (``channel_axis=-1``):
        a NumPy, dask or zarr array, only read.
    restored : array_like or callable
        Where the restored frames go (``restored[start:stop] = frames``, or
        ``restored(start, frames)``); frames in the layout of ``clip``'s,
        float64 values on the core's [0, 1] scale (cast to the target's
        dtype).
    probability : array_like or callable, optional
        Where the prediction probabilities ``(T, H, W)`` go.
    block : int, optional
        Frames read at a time; default :func:`auto_block`.
    channel_axis : {None, -1}, optional
        None: a grey clip; -1: a colour clip.
    **options
        :func:`~car_napari.restoration.restore`'s options (``neighbourhood``,
        ``keep_edges``, ``kappa``, ...).

    Returns
    -------
    int
        The number of frames restored.

    Examples
    --------
    >>> clip = np.random.default_rng(0).random((2, 24, 24))
    >>> restore_frames(clip, np.zeros_like(clip))
    2
    """
    return drain(iter_restore_frames(clip, restored, probability, block=block,
                                     channel_axis=channel_axis, **options))
