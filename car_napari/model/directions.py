"""The four scan directions: views in which each scan is the plain raster
(causal neighbourhoods, docs/model.md)."""

from __future__ import annotations

from .._docstrings import shared_sections
from ._doc_sections import RAISES_DIRECTION

__all__ = ["DIRECTIONS", "check_direction", "scan_shape", "scan_view", "unscan_view"]

DIRECTIONS = ("down", "up", "right", "left")


def check_direction(direction):
    """Refuse anything but one of the four scan directions.

    Parameters
    ----------
    direction : object
        What a caller passed as a scan direction.

    Raises
    ------
    ValueError
        If ``direction`` is not one of :data:`DIRECTIONS`.

    Examples
    --------
    >>> check_direction("up")
    >>> check_direction("sideways")
    Traceback (most recent call last):
    ...
    ValueError: direction must be one of ('down', 'up', 'right', 'left'); got 'sideways'.
    """
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")


def scan_shape(shape, direction):
    """(rows, columns) of the image as the scan sees it.

    Parameters
    ----------
    shape : tuple of int
        The image's shape, (H, W, ...).
    direction : {'down', 'up', 'right', 'left'}
        The scan direction.

    Returns
    -------
    tuple of 2 ints
        ``(W, H)`` for the column scans 'right' and 'left', else ``(H, W)``.

    Examples
    --------
    >>> scan_shape((4, 7, 3), "right")
    (7, 4)
    """
    h, w = shape[:2]
    return (w, h) if direction in ("right", "left") else (h, w)


@shared_sections(raises_direction=RAISES_DIRECTION)
def scan_view(image, direction):
    """A view of ``image`` in which the scan is the plain raster.

    Parameters
    ----------
    image : (H, W, ...) ndarray
        The image.
    direction : {'down', 'up', 'right', 'left'}
        The scan direction.

    Returns
    -------
    ndarray
        A view (no copy): flipped for 'up', transposed for 'right',
        transposed and flipped for 'left'.

    {raises_direction}

    Examples
    --------
    >>> import numpy as np
    >>> scan_view(np.arange(6).reshape(2, 3), "left").tolist()
    [[2, 5], [1, 4], [0, 3]]
    """
    if direction == "down":
        return image
    if direction == "up":
        return image[::-1]
    if direction == "right":
        return image.swapaxes(0, 1)
    check_direction(direction)
    return image[:, ::-1].swapaxes(0, 1)  # 'left'


@shared_sections(raises_direction=RAISES_DIRECTION)
def unscan_view(field, direction):
    """The inverse of :func:`scan_view`: the image whose scan reads ``field``.

    Parameters
    ----------
    field : ndarray
        An array in scan order, (rows, columns, ...) as the scan sees them.
    direction : {'down', 'up', 'right', 'left'}
        The scan direction.

    Returns
    -------
    ndarray
        A view in image geometry.

    {raises_direction}

    Examples
    --------
    >>> import numpy as np
    >>> image = np.arange(6).reshape(2, 3)
    >>> bool(np.array_equal(unscan_view(scan_view(image, "left"), "left"), image))
    True
    """
    if direction == "left":  # the one view that is not its own inverse
        return field.swapaxes(0, 1)[:, ::-1]
    return scan_view(field, direction)
