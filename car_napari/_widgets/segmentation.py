"""Dock widget "Texture segmentation": live KL merging, then instant re-cuts."""

from __future__ import annotations

from magicgui.widgets import FloatSlider, FloatSpinBox, Slider, SpinBox

from .._progress import Progress, map_previews
from ..segmentation import iter_segment
from ._base import JobWidget
from ._layers import compact_labels


class SegmentationWidget(JobWidget):
    """Unsupervised texture segmentation of an image layer (section 14.4,
    docs/segmentation.md): the labels layer shows the mixture merging live,
    then the merge history can be re-cut without recomputing.

    Re-cuts ("show K", "min probability") run in a worker, the latest slider
    value winning (a stale one is never shown): most are look-ups of the
    stored merge states, yet still passes over every pixel (tens of ms on
    4000x4000); one that needs the pixels labelled again (a threshold on a
    state whose probabilities are not kept) takes longer.

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    recuts_interrupt = True  # a stale re-cut is not worth the wait: the latest starts at once
    control_labels = {"n_segments": "segments", "levels": "resolutions",
                      "neighbourhood": "order", "n_init": "initial K",
                      "threshold": "min probability",
                      "region_threshold": "merge similar regions"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer)
        self.result = None
        self.updates = 0  # live updates shown during the current run
        self._name = None  # the labels layer the current run writes
        self._layer = None  # the labels layer of self.result
        self._n_init = SpinBox(value=16, min=2, max=64, label="initial K",
                               tooltip="components of the initial division of the image")
        # (magicgui's spin box shows no special value text: the label says it)
        self._segments = SpinBox(value=0, min=0, max=self._n_init.value,
                                 label="segments (0 = auto)",
                                 tooltip="0 = automatic: the merging finds the number; "
                                         "at most the initial K")
        self._levels = SpinBox(value=3, min=1, max=5, label="resolutions",
                               tooltip="number of resolution levels: coarser levels "
                                       "segment faster, the finest one refines the borders")
        self._order = SpinBox(value=2, min=1, max=5, label="order",
                              tooltip="order of the neighbourhood of each texture model: "
                                      "higher orders capture larger structures (slower)")
        self._merge_regions = FloatSpinBox(
            value=0.0, min=0.0, max=10.0, step=0.05, label="merge similar regions",
            tooltip="0 = off. With automatic segments: also merge segments whose "
                    "whole-region texture models predict each other within this many "
                    "nats per pixel (0.1 was chosen on tuning mosaics: fewer segments on "
                    "images of 2-3 textures, but it can join two similar textures)")
        self._n_init.changed.connect(self._bound_segments)
        self._run = self.action("Run", self.start,
                                tooltip="segment the image into textures; the merges are "
                                        "shown as they happen")
        self._cut = Slider(value=1, min=1, max=1, label="show K", enabled=False,
                           tooltip="re-cut the merge history: no recomputation")
        self._threshold = FloatSlider(value=0.0, min=0.0, max=0.99, step=0.01,
                                      label="min probability", enabled=False,
                                      tooltip="pixels less probable than this are unclassified")
        self.arrange([self._segments,
                      *self.folded([self._levels, self._order, self._n_init,
                                    self._merge_regions]), self._run],
                     after=[self._cut, self._threshold])
        self._cut.changed.connect(self._recut)
        self._threshold.changed.connect(self._recut)

    def _bound_segments(self, *_):
        """The segments box goes up to the initial K (its value is clipped)."""
        self._segments.max = int(self._n_init.value)

    def _start(self):
        """Segment the picked layer, the merges shown live."""
        data, channel_axis = self.input_array(copy=False)  # read in the worker only
        self._name = f"{self._image.value.name} segments"
        self.updates = 0
        self._cut.enabled = self._threshold.enabled = False
        n_segments = int(self._segments.value) or None
        # the region merging refines the automatic K only
        merge = float(self._merge_regions.value) if n_segments is None else 0.0
        job = iter_segment(
            data, channel_axis=channel_axis, n_segments=n_segments,
            levels=int(self._levels.value), neighbourhood=int(self._order.value),
            n_init=int(self._n_init.value), region_threshold=merge or None,
        )
        return self.run(_compact(job), preview=self._show_labels, done=self._finished)

    def _add_labels(self, data, name):
        return self._viewer.add_labels(data, name=name, opacity=0.5)

    def _put(self, labels):
        return self.record.put(self._name, labels, self._add_labels)

    def _show_labels(self, labels):
        self._put(labels)
        self.updates += 1

    def _finished(self, outcome):
        result, labels = outcome
        self.result = result
        ks = [mix.k for mix in result.history]
        self._layer = self._put(labels)
        with self._cut.changed.blocked():
            self._cut.min, self._cut.max = min(ks), max(ks)
            self._cut.value = result.n_segments
        self._cut.enabled = self._threshold.enabled = True
        self._status.value = f"{result.n_segments} segments (history {min(ks)}..{max(ks)})"

    # --- re-cuts ----------------------------------------------------------------------

    def _recut(self, *_):
        """Show the stored history cut at the sliders' values, computed in a
        worker (a newer value cancels it); here only the layer is set."""
        if self.result is None or self._layer not in self._viewer.layers:
            return
        k, threshold = int(self._cut.value), float(self._threshold.value)
        result = self.result
        self._status.value = f"re-cutting: K = {k}"
        self.recut(lambda cut: self._show_cut(result, *cut, k),
                   _recut_labels(result, k, threshold))

    def _show_cut(self, result, labels, n, k):
        if result is not self.result or self._layer not in self._viewer.layers:
            return  # a newer run took over, or its layer was removed
        self.record.put(self._layer.name, labels, self._add_labels)  # the result's own layer
        self._status.value = f"{n} segments shown (K = {k})"


def _compact(job):
    """The segmentation job with every labels array it shows (previews, then
    the result's) in the smallest integer type that holds it, converted in
    the worker: napari would remap int32 labels pixel by pixel in the viewer
    (twice per new layer and once per data change; on 4000x4000, measured
    in stop 44, 70-80 ms at the first preview and 43-64 ms per change).
    Returns (result, its labels as shown); the result keeps its int32 labels."""
    result = yield from map_previews(job, compact_labels)
    return result, compact_labels(result.labels)


def _recut_labels(result, k, threshold):
    """A re-cut as a worker's job: the labels of ``result`` at ``k`` and
    ``threshold`` and their number of segments (every pass over the pixels
    here, none in the main thread).

    Even a look-up decompresses, thresholds and renumbers every pixel (tens
    of ms on 4000x4000), so it runs here too. Its first record comes before any
    work: a newer slider value cancels a re-cut that has not begun."""
    yield Progress("re-cutting", 0.0, f"K = {k}")
    labels = yield from result.iter_labels_at(k, threshold=threshold)
    return compact_labels(labels), int(labels.max(initial=0))
