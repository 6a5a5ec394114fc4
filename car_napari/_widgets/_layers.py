"""Reading image data out of napari layers without modifying them."""

from __future__ import annotations

import numpy as np


def image_data(layer, region=None):
    """(array, channel_axis) of a 2-D grey or RGB(A) image layer, optionally
    cropped to the first rectangle of a Shapes layer. Always a copy."""
    if layer is None:
        raise ValueError("no image layer selected: open an image (or a sample) first.")
    data = np.asarray(layer.data)
    if data.size == 0:
        raise ValueError(f"layer {layer.name!r} is empty.")
    rgb = bool(getattr(layer, "rgb", False))
    if rgb:
        data = data[..., :3]
    if data.ndim != (3 if rgb else 2):
        raise ValueError(
            f"layer {layer.name!r} has shape {data.shape}; choose a 2-D grey or RGB layer "
            "(for a stack, split it or pick one plane)."
        )
    if region is not None and len(region.data):
        rows, cols = rectangle_bounds(region, data.shape[:2])
        data = data[rows, cols]
        if data.shape[0] < 2 or data.shape[1] < 2:
            raise ValueError(f"the rectangle in {region.name!r} hardly overlaps the image.")
    return data.copy(), (-1 if rgb else None)


def rectangle_bounds(shapes, shape):
    """Row and column slices of the first shape's bounding box, clipped."""
    vertices = np.asarray(shapes.data[0])[:, -2:]
    lo = np.clip(np.floor(vertices.min(axis=0)).astype(int), 0, shape)
    hi = np.clip(np.ceil(vertices.max(axis=0)).astype(int), 0, shape)
    return slice(lo[0], hi[0]), slice(lo[1], hi[1])


def value_range(data):
    """(min, max) of ``data`` in the core's float units (integers scaled to
    [0, 1] as the core does), to clip synthesised samples for display."""
    if data.dtype.kind in "ui":
        info = np.iinfo(data.dtype)
        return float(data.min()) / info.max, float(data.max()) / info.max
    return float(data.min()), float(data.max())


class RunLayers:
    """What one run writes into the viewer, so that a cancelled or failed run
    can be undone: layers it created are removed, layers it overwrote get
    their data back. :meth:`commit` when the run completes."""

    def __init__(self, viewer):
        self._viewer = viewer
        self._created = []
        self._backup = {}

    def put(self, name, data, add):
        """Set layer ``name``'s data, or create it with ``add(data, name)``."""
        layers = self._viewer.layers
        if name in layers:
            if name not in self._backup and name not in self._created:
                self._backup[name] = layers[name].data
            layers[name].data = data
            return layers[name]
        layer = add(data, name)
        self._created.append(name)
        return layer

    def undo(self):
        layers = self._viewer.layers
        for name in self._created:
            if name in layers:
                layers.remove(name)
        for name, data in self._backup.items():
            if name in layers:
                layers[name].data = data
        self.commit()

    def commit(self):
        self._created, self._backup = [], {}
