"""Validation of image stacks and clips: (n, H, W) grey, (n, H, W, C) colour."""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float, check_channel_axis


def as_stack(stack, channel_axis, *, name="stack", item="image", minimum=1, what=None):
    """Return ``(images, grey)``: a (n, H, W, d) float64 stack and whether it
    is grey.

    A stack of fewer than ``minimum`` images is refused (``"{what} needs at
    least {minimum} {item}s"``; by default ``"the {name} is empty"``).

    A 3-D array is n grey images whatever ``channel_axis`` says (it has no
    room for a channel axis); a 4-D array has its channels on axis
    ``channel_axis`` of the array (not axis 0, the images), moved last.
    Every image is converted like a single image (integers scaled to [0, 1],
    NaN refused), named ``"{item} {i}"`` in the messages.
    """
    check_channel_axis(channel_axis)
    if stack is None:
        raise TypeError(f"{name} is None: pass an (n, H, W) or (n, H, W, C) array.")
    arr = np.asarray(stack)
    if arr.ndim == 4:
        if channel_axis is None:
            raise ValueError(
                f"{name} is 4-D {arr.shape} but channel_axis=None; pass the channel axis "
                f"(e.g. channel_axis=-1 for (n, H, W, C)), or a 3-D (n, H, W) grey {name}."
            )
        valid = isinstance(channel_axis, (int, np.integer)) and not isinstance(channel_axis, bool)
        if not valid or not -4 <= channel_axis < 4 or channel_axis % 4 == 0:
            raise ValueError(
                f"channel_axis must be 1, 2 or 3 (or -1, -2, -3) for a 4-D {name}: axis 0 "
                f"holds the {item}s; got {channel_axis!r}."
            )
        arr = np.moveaxis(arr, int(channel_axis), -1)
    elif arr.ndim != 3:
        raise ValueError(
            f"{name} must be (n, H, W) grey or (n, H, W, C) colour with the {item}s along "
            f"axis 0; got shape {arr.shape}."
        )
    if arr.shape[0] < 1:
        raise ValueError(f"the {name} is empty.")
    grey = arr.ndim == 3
    images = np.stack([
        as_channel_last_float(a, channel_axis=None if grey else -1, name=f"{item} {i}")
        for i, a in enumerate(arr)
    ])
    if images.shape[0] < minimum:
        raise ValueError(f"{what or 'a ' + name} needs at least {minimum} {item}s; got "
                         f"{images.shape[0]}.")
    return images, grey
