"""Dock widget "Restoration": one degraded image, or a stack of degraded
versions of one scene, restored live; a kappa slider re-thresholds instantly."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox, ComboBox, FloatSlider, SpinBox

from ..restoration import DEFAULT_KAPPA, iter_restore, iter_restore_multichannel
from ._base import JobWidget

SINGLE = "single image"


class RestorationWidget(JobWidget):
    """Restore an image layer by the conditional mean of adaptive CAR models
    (section 14.5, docs/restoration.md), or the sharpest version of a stack
    with the 2.5D model (section 14.6, docs/restoration.md); the restored
    layer fills in live, and a kappa slider re-thresholds instantly.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer.
    """

    control_labels = {"neighbourhood": "order", "keep_edges": "keep edges", "axis": "versions"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer)
        self.result = None  # the last RestorationResult
        self.updates = 0
        self._axis = ComboBox(value=SINGLE, choices=[SINGLE, "axis 0", "axis 1", "axis 2"],
                              label="versions",
                              tooltip="a stack: the axis holding the degraded versions")
        self._order = SpinBox(value=0, min=0, max=5, label="order",
                              tooltip="causal neighbourhood order; 0: the default (1)")
        self._keep_edges = CheckBox(value=True, text="keep edges (14.40)")
        self._run = self.action("Restore", self.start)
        self._kappa = FloatSlider(value=0.0, min=0.0, max=0.99, step=0.01, label="kappa",
                                  enabled=False,
                                  tooltip="pixels whose prediction probability is at most "
                                          "kappa keep their observed value (14.50)")
        self._show_changed = CheckBox(value=False, text="show changed pixels", enabled=False)
        self.arrange([self._axis, self._order, self._keep_edges, self._run],
                     after=[self._kappa, self._show_changed])
        self._image.changed.connect(self._guess_axis)
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

    def _start(self):
        """Restore the picked layer (or stack), shown live."""
        stack_axis = self._stack_axis()
        if stack_axis is None:
            data, channel_axis = self.input_array(
                hint="choose the axis holding the degraded versions (a stack), or a 2-D image.")
        else:
            data, channel_axis = self.input_array(
                ndims=(3,), hint=f"it is not a stack with versions along axis {stack_axis}; "
                                 f"choose '{SINGLE}' or another axis.")
        options = dict(keep_edges=bool(self._keep_edges.value), channel_axis=channel_axis,
                       return_result=True)
        if self._order.value:
            options["neighbourhood"] = int(self._order.value)
        if stack_axis is None:
            job = iter_restore(data, **options)
        else:
            job = iter_restore_multichannel(data, axis=stack_axis, kappa=DEFAULT_KAPPA,
                                            **options)
        self._source = self._image.value
        self._out = self._names(self._source.name)
        self._rgb = channel_axis is not None
        self.updates = 0
        self._kappa.enabled = self._show_changed.enabled = False
        return self.run(job, preview=self._show_running, done=self._finished)

    # --- layers -----------------------------------------------------------------

    @staticmethod
    def _names(base):
        return (f"{base} restored", f"{base} prediction probability", f"{base} changed pixels")

    def _add_restored(self, data, name):
        kwargs = dict(name=name, rgb=self._rgb)
        if not self._rgb:  # values are on the core's [0, 1] scale, not the source's
            kwargs.update(colormap=self._source.colormap.name)
        return self._viewer.add_image(data, **kwargs)

    def _add_probability(self, data, name):
        return self._viewer.add_image(data, name=name, colormap="viridis", opacity=0.5,
                                      contrast_limits=(0.0, 1.0), blending="translucent")

    @staticmethod
    def _display(image, rgb):
        """What the layer shows: a grey image without its channel axis."""
        image = np.asarray(image)
        return image[..., 0] if not rgb and image.ndim == 3 else image

    def _show_running(self, restored):
        self.record.put(self._out[0], self._display(restored, self._rgb), self._add_restored)
        self.updates += 1

    def _finished(self, result):
        restored_name, probability_name, _ = self._out
        self.record.put(restored_name, self._display(result.restored(), self._rgb),
                        self._add_restored)
        self.record.put(probability_name, result.probability, self._add_probability)
        self.result = result
        self._shown = self._out, self._rgb  # what the kappa slider re-thresholds
        with self._kappa.changed.blocked():
            self._kappa.value = result.kappa
        self._kappa.enabled = self._show_changed.enabled = True
        self._rethreshold()
        ref = "" if result.reference is None else f"reference: version {result.reference}; "
        self._status.value = f"{ref}noise {np.mean(result.noise):.3g}"

    def _rethreshold(self, *_):
        """New kappa or toggle: recompute from the stored result, no worker."""
        if self.result is None:
            return
        (restored_name, _, changed_name), rgb = self._shown
        kappa = float(self._kappa.value)
        layers = self._viewer.layers
        if restored_name in layers:
            layers[restored_name].data = self._display(self.result.restored(kappa), rgb)
        if self._show_changed.value:
            changed = self.result.changed(kappa).astype(np.uint8)
            if changed_name in layers:
                layers[changed_name].data = changed
            else:
                self._viewer.add_labels(changed, name=changed_name, opacity=0.5)
        elif changed_name in layers:
            layers.remove(changed_name)
