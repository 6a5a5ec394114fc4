"""Dock widget "Restoration": one degraded image, or a stack of degraded
versions of one scene, restored live; a kappa slider re-thresholds the
stored result in a worker."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from magicgui.widgets import CheckBox, ComboBox, FloatSlider

from .._frames import lazy_output
from .._progress import Progress, map_previews
from .._validation import from_unit, unit_dtype
from ..restoration import (
    DEFAULT_KAPPA,
    iter_restore,
    iter_restore_frames,
    iter_restore_multichannel,
)
from ._base import JobWidget
from ._layers import grey_alpha, layer_array

SINGLE = "single image"
FRAMES = "each frame (lazy clip)"  # a dask/zarr clip restored frame by frame into zarr
DEFAULT_ORDER = 1  # the core's default neighbourhood order (restore, restore_multichannel)
ORDERS = [(f"{k} (default)" if k == DEFAULT_ORDER else str(k), k) for k in range(1, 6)]


# A live preview larger than this (pixels) is shown decimated (every f-th row and
# column, a layer at scale f over the same extent): the viewer's thread then writes
# and draws about a megapixel per preview, not 16 (4000x4000); the result is
# shown at full resolution.
PREVIEW_PIXELS = 1 << 20


def _decimated(image, budget=None):
    """``(image[::f, ::f], f)``: the preview at most ``budget`` pixels (f = 1:
    the image itself), contiguous, made in the worker."""
    budget = PREVIEW_PIXELS if budget is None else budget
    pixels = image.shape[0] * image.shape[1]
    f = max(1, int(np.ceil(np.sqrt(pixels / budget))))
    return (image, 1) if f == 1 else (np.ascontiguousarray(image[::f, ::f]), f)


def _preview(image, rgb, dtype=np.float32):
    """A core preview as a layer shows it (:func:`_shown`), decimated
    (:func:`_decimated`) before it is converted: on 4000x4000 RGB the
    conversion of the whole image took 0.3-0.5 s between two records."""
    image = np.asarray(image)
    shown, f = _decimated(image)
    return _shown(shown, rgb, dtype), f


def _shown(image, rgb, dtype=np.float32):
    """What a layer shows of a core image: back in the input's ``dtype`` and
    range as the command line writes it (:func:`~car_napari._validation.from_unit`:
    uint8 and uint16 kept, anything else float32, which napari draws without
    converting it), done here, in the worker, not in the viewer's thread;
    a grey image without its channel axis."""
    image = np.asarray(image)
    if not rgb and image.ndim == 3:
        image = image[..., 0]
    return from_unit(image, dtype)


# The result is turned into what the layers show by bands of this many rows, a
# record between them: on 4000x4000 RGB the whole conversion takes about a
# second, which a Cancel would otherwise wait for.
DISPLAY_ROWS = 256


def _for_display(job, rgb, show_changed, dtype=np.float32):
    """``job`` run for the viewer, in the worker: its records with previews
    as :func:`_shown`, and its result with what the viewer shows of it:
    (result, restored, probability, changed pixels as uint8 or None)."""
    # the previews decimated here, in the worker
    result = yield from map_previews(job, lambda preview: _preview(preview, rgb, dtype))
    restored, changed, probability = yield from _iter_recut(result, None, rgb, show_changed,
                                                            dtype)
    return result, restored, probability, changed


def _rows(result, rows):
    """The part of ``result`` in the slice ``rows``: a result of its own."""
    def part(array):
        return None if array is None else array[rows]

    return replace(result, observed=result.observed[rows], prediction=result.prediction[rows],
                   probability=part(result.probability), weight=part(result.weight))


def _iter_recut(result, kappa, rgb, show_changed, dtype=np.float32):
    """What the layers show of ``result`` at ``kappa`` (None: the result's
    own), by bands of :data:`DISPLAY_ROWS` rows with a record after each:
    (restored as :func:`_shown`, changed pixels as uint8 or None,
    probability as float32)."""
    H = result.observed.shape[0]
    restored = changed = None
    probability = np.empty(result.probability.shape, np.float32)
    for start in range(0, H, DISPLAY_ROWS):
        rows = slice(start, min(start + DISPLAY_ROWS, H))
        band_restored, band_changed = _recut(_rows(result, rows), kappa, rgb, show_changed,
                                             dtype)
        if restored is None:
            restored = np.empty((H, *band_restored.shape[1:]), band_restored.dtype)
            changed = None if band_changed is None else np.empty((H, *band_changed.shape[1:]),
                                                                 np.uint8)
        restored[rows] = band_restored
        if changed is not None:
            changed[rows] = band_changed
        probability[rows] = result.probability[rows]
        yield Progress("showing", 1.0, f"showing the result: rows {rows.stop}/{H}")
    return restored, changed, probability


def _recut(result, kappa, rgb, show_changed, dtype=np.float32):
    """The restored image as shown (and the changed pixels as uint8, or
    None) of ``result`` at ``kappa`` (None: the result's own)."""
    changed = result.changed(kappa).astype(np.uint8) if show_changed else None
    return _shown(result.restored(kappa), rgb, dtype), changed


class RestorationWidget(JobWidget):
    """Restore an image layer by the conditional mean of adaptive CAR models
    (section 14.5, docs/restoration.md), or the sharpest version of a stack
    with the 2.5D model (section 14.6, docs/restoration.md); the restored
    layer fills in live, and a kappa slider re-thresholds the stored result.

    The restored layer ends on top and selected; the prediction probability
    is a hidden layer just below it. The "versions" of a stack lie along an
    axis the viewer's slider steps through (never the image's rows, columns
    or colours).

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    control_labels = {"neighbourhood": "order", "keep_edges": "keep edges", "axis": "versions"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer)
        self.result = None  # the last RestorationResult
        self._dtype = np.dtype(np.float32)  # the restored layer's (the input's, as the CLI)
        self.updates = 0
        self._preview_layer = None  # a large image's decimated preview, while it runs
        self._preview_owned = False  # ... in the result's own layer (made by this run)
        self._axis = ComboBox(value=SINGLE, choices=self._axis_choices, label="versions",
                              tooltip="a stack: the axis holding the degraded versions, one "
                                      "the viewer's slider steps through (not the image's "
                                      "rows, columns or colours)")
        self._order = ComboBox(value=DEFAULT_ORDER, choices=ORDERS, label="order",
                               tooltip="order of the causal neighbourhood: 1 (the default) "
                                       "uses the nearest neighbours, higher orders reach "
                                       "further (slower)")
        self._keep_edges = CheckBox(value=True, text="keep edges",
                                    tooltip="keep the observed value where the prediction "
                                            "error is larger than the noise explains, so that "
                                            "edges stay sharp (eq. 14.40)")
        self._run = self.action("Restore", self.start,
                                tooltip="restore the image (or the sharpest version of the "
                                        "stack); the result fills in live")
        self._kappa = FloatSlider(value=0.0, min=0.0, max=0.99, step=0.01, label="kappa",
                                  enabled=False,
                                  tooltip="pixels whose prediction probability is at most "
                                          "kappa keep their observed value (14.50)")
        self._show_changed = CheckBox(value=False, text="show changed pixels", enabled=False,
                                      tooltip="show the pixels the restoration changed as a "
                                              "labels layer")
        self.arrange([self._axis, *self.folded([self._order, self._keep_edges]), self._run],
                     after=[self._kappa, self._show_changed])
        self._image.changed.connect(self._guess_axis)
        dims = napari_viewer.dims.events
        dims.order.connect(self._update_axes)
        dims.ndim.connect(self._update_axes)
        self._kappa.changed.connect(self._rethreshold)
        self._show_changed.changed.connect(self._rethreshold)
        self._guess_axis()

    # --- parameters -------------------------------------------------------------

    def _stack_axes(self, layer):
        """The axes of ``layer`` that may hold the versions: with three
        non-colour axes, those the viewer does not show as the image plane
        (its slider steps through them); none otherwise."""
        spatial = layer.ndim  # napari's count leaves out the colour axis
        if spatial != 3 or grey_alpha(layer):  # its alpha is dropped: one image
            return []
        dims = self._viewer.dims
        shift = dims.ndim - spatial  # a layer's axes are the viewer's last ones
        plane = {axis - shift for axis in dims.order[-2:]}
        return [k for k in range(spatial) if k not in plane]

    @staticmethod
    def _lazy_clip(layer):
        """``layer`` is a clip (three non-colour axes) whose data is not in
        memory (a dask or zarr array): it may be restored frame by frame."""
        return (layer is not None and layer.ndim == 3
                and not isinstance(layer.data, np.ndarray))

    def _axis_choices(self, *_):
        """The "versions" choices: a single image, each frame of a lazy
        clip, or a stack axis of the picked layer (napari resets them when
        the layers change)."""
        layer = self._image.value
        axes = [] if layer is None else self._stack_axes(layer)
        frames = [FRAMES] if self._lazy_clip(layer) else []
        return [SINGLE] + frames + [f"axis {k}" for k in axes]

    def _update_axes(self, *_, guess=False):
        """Offer the picked layer's stack axes; ``guess``: pick one if any
        (each frame, for a lazy clip)."""
        current = self._axis.value
        self._axis.reset_choices()
        choices = list(self._axis.choices)
        if guess and FRAMES in choices:
            self._axis.value = FRAMES
        elif guess or current not in choices:
            self._axis.value = choices[-1] if len(choices) == 2 else (
                current if current in choices else SINGLE)

    def _guess_axis(self, *_):
        self._update_axes(guess=True)

    def _stack_axis(self):
        value = self._axis.value
        return None if value in (SINGLE, FRAMES) else int(value.split()[-1])

    def _check_axis(self, axis):
        """Raise a ValueError when ``axis`` of the picked layer (three
        non-colour axes) is not one that may hold the versions."""
        layer = self._image.value
        axes = self._stack_axes(layer)
        if axis in axes:
            return
        if axis < layer.ndim:
            what = "a spatial axis: the viewer shows it as the image's rows or columns"
        elif axis == layer.ndim and getattr(layer, "rgb", False):
            what = "its colour axis"
        else:
            what = "not an axis of it"
        options = " or ".join(f"'axis {k}'" for k in axes) or "none (change the view)"
        raise ValueError(
            f"'versions' is axis {axis}, but axis {axis} of layer {layer.name!r} (shape "
            f"{tuple(layer.data.shape)}) is {what}. The versions must lie along an axis the "
            f"viewer's slider steps through: choose {options}, or '{SINGLE}'.")

    # --- running ----------------------------------------------------------------

    def _start(self):
        """Restore the picked layer (or stack), shown live."""
        if self._axis.value == FRAMES:
            return self._start_frames()
        stack_axis = self._stack_axis()
        layer = self._image.value
        if stack_axis is None:
            data, channel_axis = layer_array(
                layer, ndims=(2,), copy=False,
                hint="choose the axis holding the degraded versions (a stack), or a 2-D image.")
        else:
            if layer is not None and layer.ndim == 3:
                self._check_axis(stack_axis)  # before any work
            data, channel_axis = layer_array(
                layer, ndims=(3,), copy=False, hint=f"it is not a stack with versions along axis "
                                        f"{stack_axis}; choose '{SINGLE}' or another axis.")
        options = dict(keep_edges=bool(self._keep_edges.value), channel_axis=channel_axis,
                       return_result=True, neighbourhood=int(self._order.value))
        if stack_axis is None:
            job = iter_restore(data, **options)
        else:
            job = iter_restore_multichannel(data, axis=stack_axis, kappa=DEFAULT_KAPPA,
                                            **options)
        self._source = self._image.value
        self._preview_layer = None
        self._out = self._names(self._source.name)
        self._rgb = channel_axis is not None
        self._dtype = unit_dtype(data.dtype)  # the restored layer's: the input's, as the CLI
        self.updates = 0
        self._kappa.enabled = self._show_changed.enabled = False
        return self.run(_for_display(job, self._rgb, bool(self._show_changed.value),
                                     self._dtype),
                        preview=self._show_running, done=self._finished)

    def _start_frames(self):
        """Restore each frame of a lazy clip into zarr stores (a temporary
        folder), block by block in the worker: the restored clip and its
        prediction probability are dask layers over them, filling in."""
        layer = self._image.value
        data, channel_axis = layer_array(layer, ndims=(3,), copy=False,
                                         hint="each frame: choose a clip (frames, rows, "
                                              "columns).")
        shape = tuple(data.shape)
        restored = lazy_output(shape, np.float32, name="restored")
        probability = lazy_output(shape[:3], np.float32, name="probability")
        job = iter_restore_frames(data, restored, probability, channel_axis=channel_axis,
                                  keep_edges=bool(self._keep_edges.value),
                                  neighbourhood=int(self._order.value))
        self.result = None  # nothing to re-threshold: the clip is on disk
        self._dtype = np.dtype(np.float32)  # the zarr stores'
        self._source = layer
        self._out = self._names(layer.name)
        self._rgb = channel_axis is not None
        self._stores = restored, probability
        self._written = []  # the blocks written since the layers were last refreshed
        self.updates = 0
        self._kappa.enabled = self._show_changed.enabled = False
        return self.run(job, collect=self._written.append, preview=self._show_block,
                        done=self._finished_frames)

    def _lazy_layers(self):
        """The restored and probability layers over the zarr stores (made
        the first time; fresh dask arrays afterwards: napari caches the
        chunks it read of a dask array by name)."""
        import dask.array as da

        token = f"{id(self)}-{self.updates}"
        arrays = [da.from_zarr(store, name=f"car-napari-{kind}-{token}")
                  for kind, store in zip(("restored", "probability"), self._stores,
                                         strict=True)]
        restored_name, probability_name, _ = self._out
        layers = self._viewer.layers
        shown = self.record.put(restored_name, arrays[0], self._add_lazy_restored)
        new = probability_name not in layers
        probability = self.record.put(probability_name, arrays[1], self._add_probability)
        if new and shown in layers:
            layers.move(layers.index(probability), layers.index(shown))
        self.updates += 1
        return shown

    def _add_lazy_restored(self, data, name):
        kwargs = dict(name=name, rgb=self._rgb, contrast_limits=(0.0, 1.0),
                      scale=self._source.scale, translate=self._source.translate)
        if not self._rgb:
            kwargs.update(colormap=self._source.colormap.name)
        return self._viewer.add_image(data, **kwargs)

    def _show_block(self, _block):
        """Blocks were written: show them when the viewer shows one of their
        frames (else nothing to redraw); the layers appear with the first."""
        written, self._written[:] = list(self._written), []
        step = self._viewer.dims.current_step[self._viewer.dims.ndim - 3]  # the frame shown
        if self.updates == 0 or any(a <= step < b for a, b in written):
            self._lazy_layers()

    def _finished_frames(self, n_frames):
        shown = self._lazy_layers()
        if shown in self._viewer.layers:
            self._viewer.layers.selection.active = shown
        root = getattr(self._stores[0].store, "root", None)
        where = "" if root is None else f" (zarr in {root.parent})"
        self._status.value = (f"{n_frames} frames restored{where}; prediction probability: "
                              "hidden layer below")

    def refresh_actions(self):
        """Enable the buttons, and the kappa controls when idle with a result."""
        super().refresh_actions()
        idle = not self._running()
        self._kappa.enabled = self._show_changed.enabled = idle and self.result is not None

    # --- layers -----------------------------------------------------------------

    @staticmethod
    def _names(base):
        return (f"{base} restored", f"{base} prediction probability", f"{base} changed pixels")

    def _limits(self):
        """The restored layer's contrast limits: the core's [0, 1] in the
        input's dtype (0-65535 for uint16), as the source shows it."""
        return tuple(float(v) for v in from_unit(np.array([0.0, 1.0]), self._dtype))

    def _add_restored(self, data, name, scale=None):
        # values are the core's [0, 1] in the input's dtype: limits given, no
        # pass over the data in the viewer's thread
        kwargs = dict(name=name, rgb=self._rgb, contrast_limits=self._limits())
        if scale is not None:
            kwargs.update(scale=scale, translate=(0.0, 0.0))
        if not self._rgb:
            kwargs.update(colormap=self._source.colormap.name)
        return self._viewer.add_image(data, **kwargs)

    def _add_probability(self, data, name):
        # hidden: the restored image is what the user sees first
        return self._viewer.add_image(data, name=name, colormap="viridis", visible=False,
                                      contrast_limits=(0.0, 1.0))

    def _add_changed(self, data, name):
        return self._viewer.add_labels(data, name=name, opacity=0.5)

    def _show_running(self, preview):
        restored, f = preview  # float32 from the worker, decimated by f there
        name = self._out[0]
        layers = self._viewer.layers
        if f == 1:  # one layer's data replaced by the preview: no copy
            self.record.put(name, restored, self._add_restored)
        elif self._preview_layer is not None and self._preview_layer in layers:
            self._preview_layer.data = restored
        elif name not in layers:
            # a large image: the result's layer made now, at scale f over the same
            # extent; the result gives it its full-resolution data and scale 1
            self._preview_layer = self.record.put(
                name, restored, lambda data, n: self._add_restored(data, n, scale=(f, f)))
            self._preview_owned = True
        else:  # an older result's layer stays as it is until the result: one of its own
            self._preview_layer = self.record.add(
                f"{name} (preview)", restored,
                lambda data, n: self._add_restored(data, n, scale=(f, f)))
            self._preview_owned = False
        self.updates += 1

    def _end_preview(self):
        """Before the result is written: the result's own layer back at scale
        1 (its data comes next); a preview layer of its own removed after."""
        layer = self._preview_layer
        if layer is not None and self._preview_owned:
            self._preview_layer = None
            if layer in self._viewer.layers:
                layer.scale = (1.0, 1.0)

    def _drop_preview(self):
        layer, self._preview_layer = self._preview_layer, None
        if layer is not None and layer in self._viewer.layers:
            self._viewer.layers.remove(layer)

    def _finished(self, outcome):
        """Show the result in steps, one per event-loop turn (see
        :meth:`~._base.JobWidget.run`): the restored image first."""
        result, restored, probability, changed = outcome
        restored_name, probability_name, changed_name = self._out
        layers = self._viewer.layers
        self._end_preview()
        shown = self.record.put(restored_name, restored, self._add_restored)
        self._drop_preview()  # the full-resolution result replaces it
        yield  # the viewer draws the restored image before the other layers come
        new = probability_name not in layers
        probability = self.record.put(probability_name, probability, self._add_probability)
        if new and shown in layers:  # just below the restored layer, which stays on top
            layers.move(layers.index(probability), layers.index(shown))
        self.result = result
        # what the kappa slider re-thresholds
        self._recut_target = self._out, self._rgb, self._dtype
        with self._kappa.changed.blocked():
            self._kappa.value = result.kappa
        self._kappa.enabled = self._show_changed.enabled = True
        if changed is not None:
            self.record.put(changed_name, changed, self._add_changed)
        elif changed_name in layers:
            self.record.remove(changed_name)
        if shown in layers:
            layers.selection.active = shown
        ref = "" if result.reference is None else f"reference: version {result.reference}; "
        self._status.value = (f"{ref}noise {np.mean(result.noise):.3g}; prediction "
                              f"probability: hidden layer below")
        if float(self._kappa.value) != result.kappa:  # the slider rounded it
            self._rethreshold()

    # --- re-thresholding ----------------------------------------------------------

    def _rethreshold(self, *_):
        """New kappa or toggle: re-cut the stored result in a worker (the
        latest request wins; no new restoration)."""
        if self.result is None:
            return
        kappa, show_changed = float(self._kappa.value), bool(self._show_changed.value)
        result, (names, rgb, dtype) = self.result, self._recut_target
        self.recut(lambda cut: self._apply_recut(cut, result, names),
                   _iter_recut(result, kappa, rgb, show_changed, dtype))

    def _apply_recut(self, cut, result, names):
        """The re-cut's layers, through the run record (as a run's)."""
        if result is not self.result:
            return  # a newer run owns the layers
        restored, changed, _ = cut
        restored_name, _, changed_name = names
        if restored_name in self._viewer.layers:  # one the user removed stays removed
            self.record.put(restored_name, restored, self._add_restored)
        if changed is None:
            self.record.remove(changed_name)
        else:
            self.record.put(changed_name, changed, self._add_changed)
