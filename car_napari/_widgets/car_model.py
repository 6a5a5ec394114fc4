"""Dock widget "CAR model": fit with automatic support selection, inspect the
parameters, synthesise a sample of any size."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import Label, SpinBox, TextEdit

from ..model import iter_fit_car, iter_synthesize, spectral_radius
from ._base import ModelWidget
from ._layers import beside, value_range


def describe(model):
    """Plain-text summary of a fitted model: decision-rule scores, gamma, Sigma.

    Parameters
    ----------
    model : CARModel
        A fitted model.

    Returns
    -------
    str
        One line per score, then the support and the parameter matrices.

    Examples
    --------
    >>> import car_napari as car
    >>> image = np.random.default_rng(0).random((32, 32))
    >>> describe(car.fit_car(image, 1)).splitlines()[0]
    'decision-rule score D_j (larger is more probable):'
    """
    lines = ["decision-rule score D_j (larger is more probable):"]
    for order, score in (model.scores or {}).items():
        mark = "  <- chosen" if order == model.order else ""
        lines.append(f"  order {order}: {score:,.1f}{mark}")
    lines.append(f"support: order {model.order}, {model.eta} offsets "
                 f"{[tuple(s) for s in model.offsets.tolist()]}")
    lines.append(f"pixels used: {model.n_pixels}")
    with np.printoptions(precision=4, suppress=True, linewidth=120):
        for s, A in zip(model.offsets.tolist(), model.A, strict=True):
            lines.append(f"A{tuple(s)} =\n{A}")
        lines.append(f"Sigma =\n{model.sigma}")
        lines.append(f"mean = {model.mean}")
    return "\n".join(lines)


def _for_display(job, value_range):
    """The synthesis, then (in the worker) clipped to the fitted image's range
    (the model lives in the core's float units: integers scaled to [0, 1]) and
    as float32, which napari draws without converting it."""
    sample = yield from job
    return np.clip(sample, *value_range).astype(np.float32)


def _with_range(job, data):
    """The fit, then (in the worker) the value range of its input, to which the
    samples are clipped: ``(model, (low, high))``."""
    model = yield from job
    return model, value_range(data)


class CARModelWidget(ModelWidget):
    """Fit a CAR model to an image layer (or a rectangle on it) and synthesise.

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    control_labels = {"orders": "max order"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, size=256, min_size=4)
        self._source = None
        self._source_layer = None  # the fitted layer: the samples go to its right
        self._range = None
        self._max_order = SpinBox(value=5, min=1, max=8, label="max order",
                                  tooltip="candidates 1..max for the decision rule (14.6)")
        self._fit = self.action("Fit", self.start_fit,
                                tooltip="fit a CAR model to the image (or inside the "
                                        "rectangle), choosing its order automatically")
        self._report = TextEdit(value="", label="model",
                                tooltip="the fitted model: the score of each order, the "
                                        "chosen support and the parameters")
        self._report.native.setReadOnly(True)
        self.arrange([self._max_order, self._fit],
                     after=[self._report, Label(value="synthesis"), self._height,
                            self._width, self._seed, self._synth])

    def _start(self):
        """Fit a model to the picked layer (or its rectangle)."""
        # the layer's data itself, read in the worker only (the core never writes its
        # input): no copy and no scan of a large image in the viewer's thread
        data, channel_axis = self.input_array(copy=False)
        self._fitting = self._image.value
        orders = range(1, int(self._max_order.value) + 1)
        job = _with_range(iter_fit_car(data, "auto", orders=orders, channel_axis=channel_axis),
                          data)
        return self.run(job, done=self._fitted)

    def _fitted(self, fitted):
        model, value_range_ = fitted
        # what the samples are named after (and placed beside) and clipped to
        self._source_layer = self._fitting
        self._source, self._range = self._fitting.name, value_range_
        self.model = model
        self._report.value = describe(model)
        self._status.value = f"order {model.order} chosen"

    def _synthesis(self, shape, seed):
        radius = spectral_radius(self.model)
        if not radius < 1.0:
            raise ValueError(
                f"the fitted model is unstable (spectral radius {radius:.4g} >= 1): its "
                "samples would grow without bound. Fit again with a lower 'max order', or "
                "on a more uniform region (draw a rectangle).")
        # a job: progress by blocks of rows, and Cancel stops it at the next one
        job = _for_display(iter_synthesize(self.model, shape, seed=seed), self._range)
        return self.run(job, done=self._add_sample)

    def _add_sample(self, sample):
        """Show the sample (a generator: the job runs it a step per event-loop turn)."""
        # the model lives in the core's float units (integers scaled to [0, 1])
        rgb = sample.ndim == 3 and sample.shape[2] == 3
        # beside the fitted layer, not over it (while it is in the viewer)
        source = self._source_layer if self._source_layer in self._viewer.layers else None
        place = beside(source, sample.ndim - rgb)
        self.record.add(f"{self._source} CAR sample", sample,
                        lambda data, name: self._viewer.add_image(
                            data, name=name, rgb=rgb, contrast_limits=self._range, **place))
        # The layer is made (napari's cost, whatever the size); its first paint (the
        # texture upload, growing with the size) comes on the next turn, not in this one.
        yield
