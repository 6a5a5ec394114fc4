"""Dock widget "Restoration": one degraded image, or a stack of degraded
versions of one scene, restored live; a kappa slider re-thresholds instantly."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FloatSlider,
    Label,
    ProgressBar,
    PushButton,
    SpinBox,
    create_widget,
)
from napari.utils.notifications import show_error

from ..restoration import (
    DEFAULT_KAPPA,
    RestorationResult,
    iter_restore,
    iter_restore_multichannel,
)
from .._progress import relay
from ._jobs import Job
from ._layers import RunLayers

SINGLE = "single image"


def _restore_job(data, channel_axis, stack_axis, options):
    """Relay a core generator: progress floats, running images; returns the result."""
    if stack_axis is None:
        gen = iter_restore(data, channel_axis=channel_axis, **options)
    else:
        gen = iter_restore_multichannel(data, axis=stack_axis, channel_axis=channel_axis,
                                        **options)
    return (yield from relay(gen))


def _layer_array(layer):
    """(copy of the data, channel_axis) of an image layer; never a view."""
    if layer is None:
        raise ValueError("no image layer selected: open an image (or a sample) first.")
    data = np.array(layer.data, copy=True)
    rgb = bool(getattr(layer, "rgb", False))
    if rgb:
        data = data[..., :3]
    return data, (-1 if rgb else None)


class RestorationWidget(Container):
    """Restore an image layer by the conditional mean of adaptive CAR models
    (SPEC 4), or the sharpest version of a stack with the 2.5D model (SPEC 5)."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self.result: RestorationResult | None = None
        self._job = None
        self._run_layers = RunLayers(napari_viewer)  # undone if a run is cancelled
        self.updates = 0
        self._image = create_widget(annotation="napari.layers.Image", label="image")
        self._axis = ComboBox(value=SINGLE, choices=[SINGLE, "axis 0", "axis 1", "axis 2"],
                              label="versions",
                              tooltip="a stack: the axis holding the degraded versions")
        self._order = SpinBox(value=0, min=0, max=5, label="order",
                              tooltip="causal neighbourhood order; 0: the default (1)")
        self._keep_edges = CheckBox(value=True, text="keep edges (14.40)")
        self._run = PushButton(text="Restore")
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._status = Label(value="")
        self._kappa = FloatSlider(value=0.0, min=0.0, max=0.99, step=0.01, label="kappa",
                                  enabled=False,
                                  tooltip="pixels whose prediction probability is at most "
                                          "kappa keep their observed value (14.50)")
        self._show_changed = CheckBox(value=False, text="show changed pixels", enabled=False)
        self.extend([self._image, self._axis, self._order, self._keep_edges, self._run,
                     self._cancel, self._progress, self._status, self._kappa,
                     self._show_changed])
        self._image.changed.connect(self._guess_axis)
        self._run.changed.connect(self.start)
        self._cancel.changed.connect(self.cancel)
        self._kappa.changed.connect(self._rethreshold)
        self._show_changed.changed.connect(self._rethreshold)
        self._guess_axis()

    # --- parameters -------------------------------------------------------------

    def _guess_axis(self, *_):
        layer = self._image.value
        if layer is None:
            return
        ndim = layer.data.ndim - (1 if getattr(layer, "rgb", False) else 0)
        self._axis.value = "axis 0" if ndim == 3 else SINGLE

    def _stack_axis(self):
        value = self._axis.value
        return None if value == SINGLE else int(value.split()[-1])

    # --- running ----------------------------------------------------------------

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()
            self._run_layers.undo()

    def start(self, *_):
        try:
            layer = self._image.value
            data, channel_axis = _layer_array(layer)
            stack_axis = self._stack_axis()
            spatial = data.ndim - (channel_axis is not None)
            if stack_axis is None and spatial != 2:
                raise ValueError(
                    f"layer {layer.name!r} has {spatial} non-colour axes; choose the axis "
                    "holding the degraded versions (a stack), or a 2-D image.")
            if stack_axis is not None and (spatial != 3 or stack_axis >= spatial):
                raise ValueError(
                    f"layer {layer.name!r} is not a stack with versions along axis "
                    f"{stack_axis}; choose '{SINGLE}' or another axis.")
        except ValueError as exc:
            show_error(str(exc))
            return None
        options = dict(keep_edges=bool(self._keep_edges.value))
        if self._order.value:
            options["neighbourhood"] = int(self._order.value)
        if stack_axis is not None:
            options["kappa"] = DEFAULT_KAPPA
        self._source = layer
        self._name = layer.name
        self._rgb = channel_axis is not None
        self._run_layers.commit()
        self.updates = 0
        self._kappa.enabled = self._show_changed.enabled = False
        self._status.value = ""
        self._job = Job(_restore_job, data, channel_axis, stack_axis, options,
                        progress=self._progress, cancel=self._cancel, buttons=(self._run,),
                        on_yield=self._show_state, on_done=self._finished,
                        on_error=lambda exc: self._run_layers.undo())
        return self._job

    # --- layers -----------------------------------------------------------------

    def _names(self):
        base = self._name
        return (f"{base} restored", f"{base} prediction probability", f"{base} changed pixels")

    def _add_restored(self, data, name):
        source = self._source
        kwargs = dict(name=name, rgb=self._rgb)
        if not self._rgb:  # values are on the core's [0, 1] scale, not the source's
            kwargs.update(colormap=source.colormap.name)
        return self._viewer.add_image(data, **kwargs)

    def _add_probability(self, data, name):
        return self._viewer.add_image(data, name=name, colormap="viridis", opacity=0.5,
                                      contrast_limits=(0.0, 1.0), blending="translucent")

    def _display(self, image):
        """(H, W, C) float -> what the layer shows: (H, W) for grey."""
        image = np.asarray(image)
        return image if self._rgb else image[..., 0]

    def _show_state(self, state):
        if isinstance(state, float) or state.restored is None:
            if not isinstance(state, float):
                self._status.value = state.stage
            return
        self._run_layers.put(self._names()[0], self._display(state.restored), self._add_restored)
        self.updates += 1
        self._status.value = state.stage

    def _finished(self, result):
        self.result = result
        restored_name, probability_name, _ = self._names()
        with self._kappa.changed.blocked():
            self._kappa.value = result.kappa
        self._run_layers.put(restored_name, self._display(result.restored()), self._add_restored)
        self._run_layers.put(probability_name, result.probability, self._add_probability)
        self._run_layers.commit()  # this run is complete: nothing to undo
        self._kappa.enabled = self._show_changed.enabled = True
        self._rethreshold()
        ref = "" if result.reference is None else f"reference: version {result.reference}; "
        self._status.value = f"{ref}noise {np.mean(result.noise):.3g}"

    def _rethreshold(self, *_):
        """New kappa or toggle: recompute from the stored result, no worker."""
        if self.result is None:
            return
        restored_name, _, changed_name = self._names()
        kappa = float(self._kappa.value)
        layers = self._viewer.layers
        if restored_name in layers:
            layers[restored_name].data = self._display(self.result.restored(kappa))
        if self._show_changed.value:
            changed = self.result.changed(kappa).astype(np.uint8)
            if changed_name in layers:
                layers[changed_name].data = changed
            else:
                self._viewer.add_labels(changed, name=changed_name, opacity=0.5)
        elif changed_name in layers:
            layers.remove(changed_name)
