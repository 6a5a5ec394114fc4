"""How a frame or a clip is read: the channel_axis rule of inpainting.

One rule serves :func:`~car_napari.inpainting.inpaint` and
:func:`~car_napari.inpainting.detect_scratches`:

* ``(H, W)``: a grey frame, whatever ``channel_axis`` says;
* 3-D with an integer ``channel_axis``: a colour frame ``(H, W, C)`` when that
  axis has at most :data:`MAX_COLOURS` entries, else a grey clip ``(T, H, W)``
  (no colour image has more channels than that, no frame is that narrow);
* 4-D: a colour clip ``(T, H, W, C)``;
* ``channel_axis=None`` forces grey: ``(H, W)`` or ``(T, H, W)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._validation import (
    check_axis,
    check_channel_axis,
    check_mask,
    check_memory,
    check_shape,
)

MAX_COLOURS = 4  # more entries on the channel axis of a 3-D array: a grey clip


class ClipLayout(NamedTuple):
    """A frame or clip as a channel-last clip view, and how it was read."""

    clip: np.ndarray  # (T, H, W, C) view of the input, its dtype
    single: bool  # one frame, not a clip
    colour: bool  # the input has a channel axis
    channel_axis: int | None  # that axis, normalised to >= 0 (None for grey)

    @property
    def reading(self):
        """The layout in words, for error messages."""
        if self.single:
            return "a colour frame (H, W, C)" if self.colour else "a grey frame (H, W)"
        return "a colour clip (T, H, W, C)" if self.colour else "a grey clip (T, H, W)"

    def to_input(self, arr):
        """A channel-last (T, H, W, C) working array in the input's layout."""
        arr = arr[0] if self.single else arr
        if not self.colour:
            return arr[..., 0]
        return np.moveaxis(arr, -1, self.channel_axis)

    def frame_to_input(self, frame):
        """One channel-last (H, W, C) frame in the layout of the input's frames."""
        if not self.colour:
            return frame[..., 0]
        # a clip's frame loses the time axis, which comes first after the colour
        axis = self.channel_axis if self.single else max(self.channel_axis - 1, 0)
        return np.moveaxis(frame, -1, axis)


def read_layout(arr, channel_axis):
    """Read ``arr`` as a frame or clip by the module's rule; a clear
    ValueError when it is neither."""
    check_channel_axis(channel_axis)
    if channel_axis is None:
        if arr.ndim not in (2, 3):
            raise ValueError(
                f"with channel_axis=None, image must be a grey frame (H, W) or a grey clip "
                f"(T, H, W); got shape {arr.shape}. For colour pass channel_axis=-1.")
        colour, axis = False, None
    elif arr.ndim == 2:
        colour, axis = False, None
    elif arr.ndim in (3, 4):
        axis = _normalised_axis(channel_axis, arr.ndim)
        colour = arr.ndim == 4 or arr.shape[axis] <= MAX_COLOURS
        if arr.ndim == 4 and arr.shape[axis] > MAX_COLOURS:
            raise ValueError(
                f"image of shape {arr.shape} reads as a colour clip (T, H, W, C), but its "
                f"channel axis ({channel_axis}) has {arr.shape[axis]} entries, more than "
                f"{MAX_COLOURS}: pass the right channel_axis.")
        if not colour:
            axis = None
    else:
        raise ValueError(
            f"image must be a frame (H, W) or (H, W, C), or a clip (T, H, W) or "
            f"(T, H, W, C); got {arr.ndim}-D shape {arr.shape}.")
    work = np.moveaxis(arr, axis, -1) if colour else arr[..., None]
    single = work.ndim == 3
    return ClipLayout(work[None] if single else work, single, colour, axis)


def _normalised_axis(channel_axis, ndim):
    return check_axis(channel_axis, ndim, "channel_axis") % ndim


def fit_mask(mask, shape, *, channel_axis=None, invert=False):
    """A damage mask fitted to a frame or a clip: True where damaged,
    resized by nearest neighbour when its size differs.

    A mask drawn or saved at another resolution (a scan's ``mask.png``, a
    Labels layer painted on a preview) is mapped onto the frame's pixel grid:
    each frame pixel takes the mask pixel under its centre. Non-zero is
    damaged; in a colour mask, a pixel is damaged when any channel is
    non-zero. With ``invert``, zero is damaged instead: the convention of
    tools that mark the hole black on white.

    Parameters
    ----------
    mask : array_like
        Boolean or numeric: ``(h, w)`` for every frame, or ``(t, h, w)``
        one per frame of a clip of ``t`` frames; with ``channel_axis``, a
        colour mask with that channel axis (``(h, w, C)`` or
        ``(t, h, w, C)`` for ``channel_axis=-1``).
    shape : tuple of int
        The frame ``(H, W)`` or the clip ``(T, H, W)`` the mask is for.
    channel_axis : int or None, optional
        The mask's colour axis; None (the default) for a grey or label mask.
    invert : bool, optional
        The mask marks the damage with zero (black) and the known pixels
        with non-zero: the result is True where the mask is zero (in a
        colour mask, where every channel is zero).

    Returns
    -------
    ndarray of bool
        ``(H, W)`` for a mask of one frame (it applies to every frame of a
        clip), ``(T, H, W)`` for a mask per frame; a new array.

    Raises
    ------
    TypeError
        If the mask is not boolean or numeric, ``invert`` not a bool, or
        ``channel_axis`` not None or an integer.
    ValueError
        If ``shape`` is not ``(H, W)`` or ``(T, H, W)`` of positive sizes,
        the mask is empty or has another number of axes, or a mask per
        frame has another number of frames than the clip.

    Examples
    --------
    >>> small = np.array([[0, 255], [0, 0]], np.uint8)
    >>> fit_mask(small, (4, 4)).astype(int)
    array([[0, 0, 1, 1],
           [0, 0, 1, 1],
           [0, 0, 0, 0],
           [0, 0, 0, 0]])
    >>> fit_mask(np.ones((2, 3, 3), bool), (2, 6, 6)).shape
    (2, 6, 6)
    >>> fit_mask(small, (2, 2), invert=True).astype(int)  # the hole drawn black
    array([[1, 0],
           [1, 1]])
    """
    try:
        shape = check_shape(shape, "shape")
    except ValueError:
        raise ValueError(f"shape must be a frame (H, W) or a clip (T, H, W) of positive "
                         f"sizes; got {shape!r}.") from None
    check_memory(math.prod(shape), "shape")
    check_channel_axis(channel_axis)
    if not isinstance(invert, (bool, np.bool_)):
        raise TypeError(f"invert must be True or False; got {invert!r}.")
    m = check_mask(mask, "mask", meaning="True (non-zero) where pixels are damaged")
    if m.size == 0:
        raise ValueError(f"mask is empty (shape {m.shape}).")
    damaged = m != 0
    if channel_axis is not None:
        if m.ndim not in (3, 4):
            raise ValueError(f"a colour mask is (h, w, C) or (t, h, w, C); got shape "
                             f"{m.shape}.")
        damaged = damaged.any(axis=_normalised_axis(channel_axis, m.ndim))
    if damaged.ndim not in (2, 3):
        raise ValueError(f"mask must be (h, w) or (t, h, w); got shape {damaged.shape}.")
    if invert:
        damaged = ~damaged
    frames = shape[0] if len(shape) == 3 else 1
    if damaged.ndim == 3:
        if damaged.shape[0] != frames:
            what = f"a clip of {frames} frames" if len(shape) == 3 else "a single frame"
            raise ValueError(f"mask has {damaged.shape[0]} frames, for {what}: draw one "
                             "(h, w) mask for all frames or one per frame.")
        if len(shape) == 2:
            damaged = damaged[0]
    H, W = shape[-2:]
    h, w = damaged.shape[-2:]
    if (h, w) == (H, W):
        return np.array(damaged, copy=True)
    # the mask pixel under each frame pixel's centre: floor((i + 1/2) h / H), exactly
    rows = (2 * np.arange(H) + 1) * h // (2 * H)
    cols = (2 * np.arange(W) + 1) * w // (2 * W)
    return damaged[..., rows[:, None], cols[None, :]]
