"""The four scan directions: views in which each scan is the plain raster."""

from __future__ import annotations

__all__ = ["DIRECTIONS", "scan_shape", "scan_view", "unscan_view"]

DIRECTIONS = ("down", "up", "right", "left")


def scan_shape(shape, direction):
    """(rows, columns) of the image as the scan sees it."""
    h, w = shape[:2]
    return (w, h) if direction in ("right", "left") else (h, w)


def scan_view(image, direction):
    """A view of ``image`` (H, W, ...) in which the scan is the plain raster."""
    if direction == "down":
        return image
    if direction == "up":
        return image[::-1]
    if direction == "right":
        return image.swapaxes(0, 1)
    if direction == "left":
        return image[:, ::-1].swapaxes(0, 1)
    raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")


def unscan_view(field, direction):
    """The inverse of :func:`scan_view`: the image whose scan reads ``field``."""
    if direction == "down":
        return field
    if direction == "up":
        return field[::-1]
    if direction == "right":
        return field.swapaxes(0, 1)
    if direction == "left":
        return field.swapaxes(0, 1)[:, ::-1]
    raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
