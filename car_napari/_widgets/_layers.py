"""Layers in and out: a layer's data as an array, and the record of what a run
writes into the viewer (so that a cancelled or failed run can be undone)."""

from __future__ import annotations

import numpy as np
from napari.utils.notifications import show_info

from .._validation import float_range

NO_LAYER = "no image layer selected: open an image (or a sample) first."
NOT_2D = "choose a 2-D grey or RGB layer (for a stack, split it or pick one plane)."


def grey_alpha(layer):
    """``layer`` is a grey image with an alpha channel, as napari opens a
    grey + alpha PNG: not RGB, shape ``(H, W, 2)``.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> grey_alpha(SimpleNamespace(data=np.zeros((8, 9, 2)), rgb=False))
    True
    >>> grey_alpha(SimpleNamespace(data=np.zeros((2, 8, 9)), rgb=False))
    False
    """
    if layer is None or bool(getattr(layer, "rgb", False)):
        return False
    shape = tuple(layer.data.shape)
    return len(shape) == 3 and shape[2] == 2 and min(shape[:2]) > 2


def layer_array(layer, region=None, *, ndims=(2,), hint=NOT_2D, copy=True, on_note=show_info):
    """The data of an image layer as a fresh array (or a view), and its channel axis.

    Parameters
    ----------
    layer : napari.layers.Image or None
        The layer; its data is never modified (the array is a copy).
    region : napari.layers.Shapes, optional
        Crop to the bounding box of its first shape (when it has one).
    ndims : tuple of int, optional
        The numbers of non-colour axes accepted (2: an image; 3: a stack or
        a clip).
    hint : str, optional
        What to do when the layer has another number of axes.
    copy : bool, optional
        False: the layer's data itself (sliced, not converted: a job that
        reads it in its worker and never writes it needs no copy, and the
        viewer's thread makes none).
    on_note : callable or None, optional
        Called with a one-line note when an alpha channel is dropped (by
        default a napari info notification; None: silent).

    Returns
    -------
    data : ndarray
        A copy of the data (a view with ``copy=False``); an RGBA layer loses
        its alpha, a grey + alpha layer (:func:`grey_alpha`) is grey.
    channel_axis : int or None
        -1 for an RGB(A) layer, None (grey) otherwise.

    Raises
    ------
    ValueError
        No layer, an empty one, one with the wrong number of axes, or a
        rectangle that hardly overlaps it.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> layer = SimpleNamespace(name="grey", data=np.zeros((4, 5)), rgb=False)
    >>> data, channel_axis = layer_array(layer)
    >>> data.shape, channel_axis, data is layer.data
    ((4, 5), None, False)
    """
    if layer is None:
        raise ValueError(NO_LAYER)
    data = np.asarray(layer.data) if copy else layer.data
    if data.size == 0:
        raise ValueError(f"layer {layer.name!r} is empty.")
    rgb = bool(getattr(layer, "rgb", False))
    grey_with_alpha = grey_alpha(layer)
    alpha = grey_with_alpha or (rgb and data.shape[-1] == 4)
    if grey_with_alpha:
        data = data[..., 0]  # the models see grey or colour only, as the CLI's read_image
    spatial = data.ndim - rgb
    if spatial not in ndims:
        raise ValueError(f"layer {layer.name!r} has shape {data.shape} ({spatial} non-colour "
                         f"axes); {hint}")
    if rgb:
        data = data[..., :3]
    if region is not None and len(region.data):
        rows, cols = rectangle_bounds(region, data.shape[spatial - 2:spatial])
        data = data[(Ellipsis, rows, cols) + ((slice(None),) if rgb else ())]
        if min(data.shape[spatial - 2:spatial]) < 2:
            raise ValueError(f"the rectangle in {region.name!r} hardly overlaps the image.")
    if alpha and on_note is not None:
        on_note(f"layer {layer.name!r}: its alpha (transparency) channel is not used; "
                f"the image is read as {'colour' if rgb else 'grey'}.")
    return (np.array(data, copy=True) if copy else data), (-1 if rgb else None)


def rectangle_bounds(shapes, shape):
    """Row and column slices of the first shape's bounding box, clipped to
    ``shape`` (rows, columns).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> box = SimpleNamespace(data=[np.array([[1.5, 2.0], [8.2, 30.0]])])
    >>> rectangle_bounds(box, (6, 20))
    (slice(1, 6, None), slice(2, 20, None))
    """
    vertices = np.asarray(shapes.data[0])[:, -2:]
    lo = np.clip(np.floor(vertices.min(axis=0)).astype(int), 0, shape)
    hi = np.clip(np.ceil(vertices.max(axis=0)).astype(int), 0, shape)
    return slice(int(lo[0]), int(hi[0])), slice(int(lo[1]), int(hi[1]))


def beside(layer, ndim, *, gap=0.05):
    """Where a layer of ``ndim`` non-colour axes made from ``layer`` goes so
    that it sits to the right of it, not over it: ``{"scale": ...,
    "translate": ...}`` for ``viewer.add_image``.

    The new layer keeps the source's scale and its offset on every axis but
    the columns, where it starts one gap after the source's last column (a
    gap of ``gap`` times the source's width, at least 4 pixels).

    Parameters
    ----------
    layer : napari.layers.Image or None
        The source layer (None: no placement).
    ndim : int
        The new layer's number of non-colour axes (its last ones are
        matched with the source's; a grey + alpha source's plane is its
        first two axes).
    gap : float, optional
        The gap, as a fraction of the source's width.

    Returns
    -------
    dict
        ``scale`` and ``translate`` (length ``ndim``); empty when there is
        no source or it has fewer axes.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> layer = SimpleNamespace(data=np.zeros((10, 100)), rgb=False, multiscale=False,
    ...                         ndim=2, scale=(2.0, 0.5), translate=(3.0, 1.0))
    >>> beside(layer, 2)
    {'scale': (2.0, 0.5), 'translate': (3.0, 53.5)}
    """
    if layer is None:
        return {}
    shape = np.shape(layer.data[0] if getattr(layer, "multiscale", False) else layer.data)
    axes = list(range(layer.ndim))  # napari's count leaves out the colour axis
    if grey_alpha(layer):
        axes = axes[:2]  # the alpha axis is no axis of the image
    if len(axes) < ndim:
        return {}
    axes = axes[-ndim:]
    scale = [float(layer.scale[k]) for k in axes]
    translate = [float(layer.translate[k]) for k in axes]
    width = shape[axes[-1]]
    translate[-1] += (width + max(4.0, gap * width)) * scale[-1]
    return {"scale": tuple(scale), "translate": tuple(translate)}


def value_range(data):
    """(min, max) of ``data`` in the core's float units (integers scaled as
    the core scales them: :func:`car_napari._validation.float_range`), to
    clip synthesised samples for display.

    Examples
    --------
    >>> value_range(np.array([0, 255], np.uint8))
    (0.0, 1.0)
    """
    return float_range(data)


def compact_labels(labels):
    """``labels`` in the smallest unsigned dtype that holds its values.

    napari draws uint8 and uint16 labels as they are, but remaps int32 and
    int64 labels into a texture dtype (a pass over the slice, on the main
    thread) when the layer is made and at every refresh; the values do not
    change (labels 0..255 become uint8, up to 65535 uint16). Call it where
    the result is made (in the worker), not in the viewer.

    Parameters
    ----------
    labels : array_like of int
        Labels (0 the background).

    Returns
    -------
    ndarray
        uint8 or uint16 when all values are in its range, else ``labels``
        as it is (also a float or negative array).

    Examples
    --------
    >>> compact_labels(np.array([0, 3, 255], np.int32)).dtype
    dtype('uint8')
    >>> compact_labels(np.array([0, 256], np.int64)).dtype
    dtype('uint16')
    >>> compact_labels(np.array([-1, 2], np.int32)).dtype
    dtype('int32')
    """
    labels = np.asarray(labels)
    if labels.dtype.kind not in "iu" or labels.size == 0 or labels.dtype in (np.uint8, np.uint16):
        return labels
    if labels.min() < 0:
        return labels
    top = labels.max()
    for dtype in (np.uint8, np.uint16):
        if top <= np.iinfo(dtype).max:
            return labels.astype(dtype)
    return labels


def _identity(layer):
    """The layer's identity, the same through any proxy of it.

    napari hands a plugin its viewer behind a proxy that wraps each layer it
    returns anew, so two look-ups of one layer are different objects.
    """
    return id(getattr(layer, "__wrapped__", layer))


class RunRecord:
    """What one run adds to or changes in the viewer, to undo it.

    Every change a run makes goes through this record: a layer it creates,
    a layer whose data it overwrites, a layer it replaces or removes, the
    slider step it moves. :meth:`undo` (a Cancel, an error) puts the viewer
    back as it was before the run, newest change first; :meth:`commit` (the
    run completed) forgets the changes.

    Parameters
    ----------
    viewer : napari.Viewer
        The viewer the run writes into.
    later : callable, optional
        ``later(callback)`` calls ``callback()`` on a later turn of the event
        loop. With it, :meth:`undo` takes one change per turn: napari takes
        0.1-0.2 s to remove or insert a layer, so undoing three layers at
        once would pause the viewer three times as long. Any other use of
        the record first finishes an undo under way.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> record = RunRecord(SimpleNamespace(layers={}))
    >>> record.commit()
    """

    def __init__(self, viewer, *, later=None):
        self._viewer = viewer
        self._later = later
        self._undo = []  # closures, oldest first
        self._saved = {}  # id -> layer whose data is backed up (or that this run created)
        self._undoing = False
        self._undos = 0  # undos started, to number their turns

    @property
    def undoing(self):
        """An undo is under way, one change per event-loop turn."""
        return self._undoing

    def _layers(self):
        return self._viewer.layers

    def put(self, name, data, add, *, read=None, write=None):
        """Set layer ``name``'s data, or create the layer.

        Parameters
        ----------
        name, data, add
            As :meth:`add`: ``add(data, name)`` creates the layer when there
            is none of that name.
        read, write : callable, optional
            What a layer's data is, when not its ``data`` (a Shapes layer's
            paths with their features): ``read(layer)`` gets it (kept for
            undo), ``write(layer, data)`` sets it in place.

        Returns
        -------
        napari.layers.Layer
            The layer written.
        """
        self.settle()
        read = read or (lambda layer: layer.data)
        write = write or (lambda layer, value: setattr(layer, "data", value))
        layers = self._layers()
        if name in layers:
            layer = layers[name]
            if _identity(layer) not in self._saved:
                self._saved[_identity(layer)] = layer
                old = read(layer)
                self._undo.append(lambda: write(layer, old))
            write(layer, data)
            return layer
        return self.add(name, data, add)  # created: removing it undoes all

    def replace(self, name, data, add):
        """Remove layer ``name`` if there is one, then create it anew.

        Parameters
        ----------
        name, data, add
            As :meth:`add`.

        Returns
        -------
        napari.layers.Layer
            The new layer.
        """
        self.remove(name)  # each finishes an undo under way first
        return self.add(name, data, add)

    def add(self, name, data, add):
        """Create a layer with ``add(data, name)``; undo removes it.

        Parameters
        ----------
        name : str
            The layer's name (napari renames a duplicate name).
        data : array
            Its data.
        add : callable
            ``add(data, name)`` creates the layer, with its display options
            (the one shape of every method's ``add``: :meth:`put`,
            :meth:`replace`).

        Returns
        -------
        napari.layers.Layer
            The new layer.
        """
        self.settle()
        layer = add(data, name)
        self._saved[_identity(layer)] = layer
        self._undo.append(lambda: self._drop(layer))
        return layer

    def remove(self, name):
        """Remove layer ``name`` (if there is one); undo puts it back in place.

        Parameters
        ----------
        name : str
            The layer's name.
        """
        self.settle()
        layers = self._layers()
        if name not in layers:
            return
        layer = layers[name]
        index = layers.index(layer)
        layers.remove(layer)
        self._undo.append(lambda: self._layers().insert(index, layer))

    def set_step(self, axis, value):
        """Move the viewer's slider on ``axis`` to ``value``.

        Parameters
        ----------
        axis : int
            The dimension of the slider.
        value : int
            Its new step.
        """
        self.settle()
        dims = self._viewer.dims
        old = dims.current_step[axis]
        self._undo.append(lambda: dims.set_current_step(axis, old))
        dims.set_current_step(axis, value)

    def _drop(self, layer):
        if layer in self._layers():
            self._layers().remove(layer)

    def undo(self):
        """Put the viewer back as it was before the run, newest change first.

        The newest change is undone now; with ``later``, each older one on
        a later turn of the event loop (see :attr:`undoing`).
        """
        self.settle()
        self._undoing = True
        self._undos += 1  # a stale turn of an earlier undo finds another number
        if self._later is None:
            self.settle()
        else:
            self._undo_turn(self._undos)

    def _undo_turn(self, number):
        if not self._undoing or number != self._undos:
            return  # finished meanwhile
        if self._undo:
            try:
                self._undo.pop()()
            except Exception:
                self._forget()  # as a failed undo in one go: the rest is dropped
                raise
        if self._undo:
            self._later(lambda: self._undo_turn(number))
        else:
            self._forget()

    def settle(self):
        """Finish an undo under way, at once."""
        if self._undoing:
            while self._undo:
                self._undo.pop()()
            self._forget()

    def commit(self):
        """The run is complete: forget its changes."""
        self.settle()
        self._forget()

    def _forget(self):
        self._undoing = False
        self._undo, self._saved = [], {}
