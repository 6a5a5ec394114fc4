"""Dock widget "CAR model": fit with automatic support selection, inspect the
parameters, synthesise a sample of any size."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import Container, Label, ProgressBar, PushButton, SpinBox, TextEdit
from magicgui.widgets import create_widget

from .. import fit_car, synthesize
from ._jobs import Job
from ._layers import image_data, value_range


def _fit_job(data, channel_axis, max_order):
    yield 0.05
    model = fit_car(data, "auto", orders=range(1, max_order + 1), channel_axis=channel_axis)
    yield 0.9
    return model


def describe(model):
    """Plain-text summary: decision-rule scores, gamma, Sigma."""
    lines = ["decision-rule score D_j (larger is more probable):"]
    for order, score in (model.scores or {}).items():
        mark = "  <- chosen" if order == model.order else ""
        lines.append(f"  order {order}: {score:,.1f}{mark}")
    lines.append(f"support: order {model.order}, {model.eta} offsets "
                 f"{[tuple(s) for s in model.offsets.tolist()]}")
    lines.append(f"pixels used: {model.n_pixels}")
    with np.printoptions(precision=4, suppress=True, linewidth=120):
        for s, A in zip(model.offsets.tolist(), model.A):
            lines.append(f"A{tuple(s)} =\n{A}")
        lines.append(f"Sigma =\n{model.sigma}")
        lines.append(f"mean = {model.mean}")
    return "\n".join(lines)


class CARModelWidget(Container):
    """Fit a CAR model to an image layer (or a rectangle on it) and synthesise."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self.model = None
        self._source = None
        self._job = None
        self._image = create_widget(annotation="napari.layers.Image", label="image")
        self._region = create_widget(
            annotation="napari.layers.Shapes", label="rectangle",
            options={"nullable": True, "tooltip": "optional: fit only inside its first shape"},
        )
        self._max_order = SpinBox(value=5, min=1, max=8, label="max order",
                                  tooltip="candidates 1..max for the decision rule (14.6)")
        self._fit = PushButton(text="Fit")
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._report = TextEdit(value="", label="model")
        self._report.native.setReadOnly(True)
        self._height = SpinBox(value=256, min=4, max=8192, label="height")
        self._width = SpinBox(value=256, min=4, max=8192, label="width")
        self._seed = SpinBox(value=0, min=0, max=2**31 - 1, label="seed")
        self._synth = PushButton(text="Synthesize", enabled=False)
        self.extend([
            self._image, self._region, self._max_order, self._fit, self._cancel,
            self._progress, self._report, Label(value="synthesis"), self._height,
            self._width, self._seed, self._synth,
        ])
        self._fit.changed.connect(self.start_fit)
        self._synth.changed.connect(self.start_synthesis)
        self._cancel.changed.connect(self.cancel)

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()

    def start_fit(self, *_):
        try:
            layer = self._image.value
            data, channel_axis = image_data(layer, self._region.value)
        except ValueError as exc:
            from napari.utils.notifications import show_error

            show_error(str(exc))
            return
        self._source = layer.name
        self._range = value_range(data)
        self._job = Job(
            _fit_job, data, channel_axis, int(self._max_order.value),
            progress=self._progress, cancel=self._cancel, buttons=(self._fit, self._synth),
            on_done=self._fitted,
        )
        return self._job

    def _fitted(self, model):
        self.model = model
        self._report.value = describe(model)
        self._synth.enabled = True

    def start_synthesis(self, *_):
        if self.model is None:
            from napari.utils.notifications import show_error

            show_error("fit a model first.")
            return
        shape = (int(self._height.value), int(self._width.value))
        self._job = Job(
            synthesize, self.model, shape, seed=int(self._seed.value),
            progress=self._progress, cancel=self._cancel, buttons=(self._fit, self._synth),
            on_done=self._add_sample,
        )
        return self._job

    def _add_sample(self, sample):
        # the model lives in the core's float units (integers scaled to [0, 1])
        sample = np.clip(sample, *self._range)
        rgb = sample.ndim == 3 and sample.shape[2] == 3
        self._viewer.add_image(sample, name=f"{self._source} CAR sample", rgb=rgb)
