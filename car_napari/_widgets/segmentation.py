"""Dock widget "Texture segmentation": live KL merging, then instant re-cuts."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import (
    Container,
    FloatSlider,
    Label,
    ProgressBar,
    PushButton,
    Slider,
    SpinBox,
    create_widget,
)
from napari.utils.notifications import show_error

from ..segmentation import SegmentationResult, iter_segment
from ._jobs import Job
from ._layers import image_data


def _segment_job(data, channel_axis, options):
    """Relay the core generator: progress floats and states with labels."""
    for item in iter_segment(data, channel_axis=channel_axis, **options):
        if isinstance(item, SegmentationResult):
            return item
        yield float(item.fraction)
        if item.labels is not None:
            yield item


class SegmentationWidget(Container):
    """Unsupervised texture segmentation of an image layer (SPEC section 3)."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self.result = None
        self._job = None
        self._layer = None  # the labels layer being written
        self._backup = None  # its data before this run, or None if we created it
        self.updates = 0  # live updates shown during the current run
        self._image = create_widget(annotation="napari.layers.Image", label="image")
        self._segments = SpinBox(value=0, min=0, max=64, label="segments",
                                 tooltip="0: find the number automatically")
        self._levels = SpinBox(value=3, min=1, max=5, label="resolutions")
        self._order = SpinBox(value=2, min=1, max=5, label="order")
        self._n_init = SpinBox(value=16, min=2, max=64, label="initial K")
        self._run = PushButton(text="Run")
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._status = Label(value="")
        self._cut = Slider(value=1, min=1, max=1, label="show K", enabled=False,
                           tooltip="re-cut the merge history: no recomputation")
        self._threshold = FloatSlider(value=0.0, min=0.0, max=0.99, step=0.01,
                                      label="min probability", enabled=False,
                                      tooltip="pixels less probable than this are unclassified")
        self.extend([self._image, self._segments, self._levels, self._order, self._n_init,
                     self._run, self._cancel, self._progress, self._status, self._cut,
                     self._threshold])
        self._run.changed.connect(self.start)
        self._cancel.changed.connect(self.cancel)
        self._cut.changed.connect(self._recut)
        self._threshold.changed.connect(self._recut)

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()
            self._restore()

    def start(self, *_):
        try:
            layer = self._image.value
            data, channel_axis = image_data(layer)
        except ValueError as exc:
            show_error(str(exc))
            return
        options = dict(
            n_segments=int(self._segments.value) or None, levels=int(self._levels.value),
            neighbourhood=int(self._order.value), n_init=int(self._n_init.value),
        )
        self._name = f"{layer.name} segments"
        self._shape = data.shape[:2]
        existing = self._viewer.layers[self._name] if self._name in self._viewer.layers else None
        self._layer = existing
        self._backup = None if existing is None else existing.data.copy()
        self.updates = 0
        self._cut.enabled = self._threshold.enabled = False
        self._job = Job(
            _segment_job, data, channel_axis, options, progress=self._progress,
            cancel=self._cancel, buttons=(self._run,), on_yield=self._show_state,
            on_done=self._finished, on_error=lambda exc: self._restore(),
        )
        return self._job

    def _put(self, labels):
        labels = np.asarray(labels, dtype=np.int32)
        if self._layer is None or self._layer not in self._viewer.layers:
            self._layer = self._viewer.add_labels(labels, name=self._name, opacity=0.5)
        else:
            self._layer.data = labels

    def _show_state(self, state):
        self._put(state.labels)
        self.updates += 1
        kl = "" if state.kl is None else f", merged pair KL {state.kl:.3g}"
        self._status.value = f"{state.stage}: {state.n_components} components{kl}"

    def _restore(self):
        """Undo this run's live updates: the layer list is as it was."""
        if self._layer is None:
            return
        if self._backup is None:
            if self._layer in self._viewer.layers:
                self._viewer.layers.remove(self._layer)
        else:
            self._layer.data = self._backup
        self._layer = None

    def _finished(self, result):
        self.result = result
        ks = [mix.k for mix in result.history]
        self._put(result.labels)
        with self._cut.changed.blocked():
            self._cut.min, self._cut.max = min(ks), max(ks)
            self._cut.value = result.n_segments
        self._cut.enabled = self._threshold.enabled = True
        self._status.value = f"{result.n_segments} segments (history {min(ks)}..{max(ks)})"

    def _recut(self, *_):
        if self.result is None or self._layer is None:
            return
        labels = self.result.labels_at(int(self._cut.value),
                                       threshold=float(self._threshold.value))
        self._layer.data = labels
