"""Proposing a damage mask (section 14.7, docs/inpainting.md).

:func:`detect_scratches` finds vertical line scratches (thin, brighter or
darker than both sides, persisting down the frame) and, in clips, blotches
(pixels that disagree with both neighbouring frames in the same direction).
"""

from __future__ import annotations

import numpy as np

from .._progress import Progress, drain
from .._validation import as_channel_last_float
from ._layout import read_layout

__all__ = ["detect_scratches", "iter_detect_scratches"]

KINDS = ("line", "blotch")


def _grey_frames(image, channel_axis):
    """The frames as a (T, H, W) float stack (the channel mean), and whether
    the input was one frame."""
    arr = np.asarray(image)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"image has dtype {arr.dtype}; pass a numeric (integer or float) "
                        "frame or clip.")
    layout = read_layout(arr, channel_axis)
    frames = []
    for f in layout.clip:
        g = as_channel_last_float(f if layout.colour else f[..., 0],
                                  channel_axis=-1 if layout.colour else None, name="frame")
        frames.append(g.mean(axis=2))
    return np.stack(frames), layout.single


def _line_mask(g, w, length, line_threshold):
    """Vertical line scratches of one grey (H, W) frame."""
    from scipy import ndimage

    left = g[:, w:-w] - g[:, : -2 * w]
    right = g[:, w:-w] - g[:, 2 * w :]
    # a line is brighter (darker) than *both* sides; a step edge is not
    both = np.where(left * right > 0, np.sign(left) * np.minimum(np.abs(left),
                                                                 np.abs(right)), 0.0)
    contrast = np.zeros_like(g)
    contrast[:, w:-w] = both
    scale = 1.4826 * np.median(np.abs(g[:, 1:] - g[:, :-1])) + 1e-12
    strong = np.abs(contrast) > line_threshold * scale
    signed = np.sign(contrast) * strong
    # persistence: most rows of a long vertical window agree in sign
    along = ndimage.uniform_filter1d(signed, length, axis=0, mode="nearest")
    lines = strong & (np.abs(along) > 0.5) & (np.sign(along) == np.sign(contrast))
    # fill the scratch's width (the contrast peaks at its centre)
    return ndimage.binary_dilation(lines, structure=np.ones((1, 3), bool))


def _blotch_mask(before, frame, after, blotch_threshold):
    """Blotches of one grey frame between its two neighbours (SDIa)."""
    from scipy import ndimage

    prev_diff = frame - before
    next_diff = frame - after
    same_sign = np.sign(prev_diff) == np.sign(next_diff)
    spikes = same_sign & (np.minimum(np.abs(prev_diff), np.abs(next_diff))
                          > blotch_threshold)
    spikes = ndimage.binary_opening(spikes, structure=np.ones((2, 2), bool))
    return ndimage.binary_dilation(spikes, structure=np.ones((3, 3), bool))


def iter_detect_scratches(image, *, kinds=KINDS, channel_axis=-1, line_width=3,
                          line_length=0.5, line_threshold=4.0, blotch_threshold=0.12):
    """Propose a damage mask, as a job: Progress records, then the mask.

    The generator form of :func:`detect_scratches`, with the same
    parameters and result.

    Parameters
    ----------
    image : ndarray
        A frame or a clip, read by the rule of :func:`detect_scratches`.
    kinds : str or sequence of {'line', 'blotch'}, optional
        What to look for.
    channel_axis : int or None, optional
        The colour axis; None forces grey.
    line_width : int, optional
        Distance (pixels) of the two side pixels a line pixel is compared to.
    line_length : float, optional
        Length of the persistence window, as a fraction of the frame height.
    line_threshold : float, optional
        Contrast a line needs, in robust standard deviations of the
        horizontal pixel differences.
    blotch_threshold : float, optional
        Difference from both neighbouring frames a blotch needs (image scale
        [0, 1]).

    Returns
    -------
    ndarray of bool
        What :func:`detect_scratches` returns: (H, W) for a frame, (T, H, W)
        for a clip.

    Yields
    ------
    Progress
        Stage ``"lines"`` after each frame's line search and ``"blotches"``
        after each inner frame's blotch test, message like ``"frame 3/24"``,
        no preview; the fraction counts the frames done.

    Raises
    ------
    TypeError
        If the image is not numeric.
    ValueError
        If ``kinds`` is not a subset of ('line', 'blotch'); if the image is
        neither a frame nor a clip, holds NaN or infinite values, or is too
        narrow for ``line_width``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> clip = np.random.default_rng(0).random((3, 16, 16)) * 0.05
    >>> records = []
    >>> mask = drain(iter_detect_scratches(clip, kinds="blotch"), records.append)
    >>> mask.shape, records[-1].stage, records[-1].fraction
    ((3, 16, 16), 'blotches', 1.0)
    """
    kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"kinds must be a subset of ('line', 'blotch'); got {kinds}.")
    grey, single = _grey_frames(image, channel_axis)
    T, H, W = grey.shape
    lines = "line" in kinds
    blotches = "blotch" in kinds and T >= 3
    w = int(line_width)
    if lines and W <= 2 * w:
        raise ValueError(f"the frame is too narrow ({W} px) for line_width {w}.")
    total = (T if lines else 0) + (T - 2 if blotches else 0)
    done = 0
    mask = np.zeros((T, H, W), bool)
    if lines:
        length = max(3, int(line_length * H) | 1)
        for t in range(T):
            mask[t] |= _line_mask(grey[t], w, length, line_threshold)
            done += 1
            yield Progress("lines", done / total, f"frame {t + 1}/{T}")
    if blotches:
        for t in range(1, T - 1):
            mask[t] |= _blotch_mask(grey[t - 1], grey[t], grey[t + 1], blotch_threshold)
            done += 1
            yield Progress("blotches", done / total, f"frame {t + 1}/{T}")
    return mask[0] if single else mask


def detect_scratches(image, *, kinds=KINDS, channel_axis=-1, line_width=3,
                     line_length=0.5, line_threshold=4.0, blotch_threshold=0.12):
    """Propose a damage mask for a frame or a clip.

    * ``'line'``: vertical line scratches. A pixel of the grey frame (the
      channel mean) is a line candidate when it is brighter (or darker) than
      both pixels ``w = line_width`` to its left and right by more than
      ``line_threshold`` robust standard deviations of the horizontal pixel
      differences (a step edge is brighter than one side only). It is
      proposed when more than half of the rows in a vertical window of
      ``line_length`` times the frame height are candidates of the same
      sign: the scratch persists down the frame.
    * ``'blotch'`` (clips of 3 frames or more): the spike detector index
      SDIa. A pixel is proposed when it differs from both the previous and
      the next frame by more than ``blotch_threshold`` (image scale [0, 1])
      in the same direction. Real motion fails the test on one side.

    Misses: scratches that are not vertical, lines fainter than the texture's
    own vertical structure, blotches that persist over two frames and damage
    on the first and last frames of a clip (they have one neighbour only).

    Parameters
    ----------
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
        [0, 1]).

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
        narrow for ``line_width``.

    See Also
    --------
    iter_detect_scratches : The same as a job, with progress.
    inpaint : Fill the proposed mask.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.full((32, 32), 0.5) + np.random.default_rng(0).normal(0, 0.01, (32, 32))
    >>> frame[:, 20] += 0.3  # a bright vertical scratch
    >>> mask = detect_scratches(frame, kinds="line")
    >>> bool(mask[:, 20].all()), int(mask[:, :15].sum())
    (True, 0)
    """
    return drain(iter_detect_scratches(
        image, kinds=kinds, channel_axis=channel_axis, line_width=line_width,
        line_length=line_length, line_threshold=line_threshold,
        blotch_threshold=blotch_threshold))
