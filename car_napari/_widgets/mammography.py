"""Dock widget "Mammogram ROI": candidate masses as labels, outlines and a table."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import (
    Container,
    FloatSpinBox,
    Label,
    ProgressBar,
    PushButton,
    SpinBox,
    create_widget,
)
from napari.utils.notifications import show_error, show_info
from qtpy.QtWidgets import QTableWidget, QTableWidgetItem

from ..mammography import (
    DEFAULT_MAX_REGIONS,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    iter_detect_mammogram_rois,
    region_outlines,
)
from ._jobs import Job
from ._layers import image_data

# Columns shown in the dock's table (the layer's features keep them all).
SHOWN_COLUMNS = ("label", "area", "mean_grey", "contrast", "centroid_row", "centroid_col",
                 "score")


def _detect_job(data, options):
    """Relay the core generator: progress floats, then return (labels, table)."""
    for item in iter_detect_mammogram_rois(data, **options):
        if isinstance(item, tuple):
            return item
        yield float(item)


class MammogramWidget(Container):
    """Regions of interest (candidate masses) in a grey mammogram (SPEC 3.1)."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self._job = None
        self.table = None  # the last result's table (dict of columns)
        self._image = create_widget(annotation="napari.layers.Image", label="mammogram")
        self._reference = FloatSpinBox(
            value=REFERENCE_GREY, min=0.0, max=1.0, step=0.005, label="reference grey",
            tooltip="mean grey of a mass on a [0, 1] scale; learned from mini-MIAS "
                    "ground truth (benchmarks/bench_mammography.py)")
        self._tolerance = FloatSpinBox(
            value=REFERENCE_TOLERANCE, min=0.01, max=1.0, step=0.01, label="tolerance",
            tooltip="regions whose mean grey is further than this from the reference "
                    "are dropped")
        self._max_regions = SpinBox(value=DEFAULT_MAX_REGIONS, min=0, max=50,
                                    label="max regions", tooltip="0: keep every region")
        self._run = PushButton(text="Detect")
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._status = Label(value="")
        self._table = QTableWidget()
        self._table.setMinimumHeight(140)
        self._table.setEditTriggers(QTableWidget.NoEditTriggers)
        self.extend([self._image, self._reference, self._tolerance, self._max_regions,
                     self._run, self._cancel, self._progress, self._status])
        self.native.layout().addWidget(self._table)
        self._run.changed.connect(self.start)
        self._cancel.changed.connect(self.cancel)

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()

    def start(self, *_):
        try:
            layer = self._image.value
            data, channel_axis = image_data(layer)
        except ValueError as exc:
            show_error(str(exc))
            return None
        options = dict(channel_axis=channel_axis, reference=float(self._reference.value),
                       tolerance=float(self._tolerance.value),
                       max_regions=int(self._max_regions.value) or None)
        self._name = layer.name
        self._scale = tuple(layer.scale[-2:])
        self._translate = tuple(layer.translate[-2:])
        self._status.value = ""
        self._job = Job(_detect_job, data, options, progress=self._progress,
                        cancel=self._cancel, buttons=(self._run,), on_done=self._show)
        return self._job

    def _replace(self, name, add):
        """Re-running replaces this widget's output layers for that image."""
        if name in self._viewer.layers:
            self._viewer.layers.remove(name)
        return add(name)

    def _show(self, result):
        labels, table = result
        self.table = table
        n = len(table["label"])
        geometry = dict(scale=self._scale, translate=self._translate)
        self._replace(f"{self._name} ROI labels",
                      lambda name: self._viewer.add_labels(labels, name=name, opacity=0.4,
                                                           **geometry))
        outlines = region_outlines(labels)
        if outlines:
            self._replace(
                f"{self._name} ROI outlines",
                lambda name: self._viewer.add_shapes(
                    outlines, shape_type="polygon", name=name, edge_color="yellow",
                    face_color="transparent", edge_width=2, features=table, **geometry),
            )
        elif f"{self._name} ROI outlines" in self._viewer.layers:
            self._viewer.layers.remove(f"{self._name} ROI outlines")
        self._fill_table(table)
        self._status.value = f"{n} region{'s' * (n != 1)} of interest"
        if n == 0:
            show_info("no region of interest passed the grey-level filter; widen the "
                      "tolerance or check the reference grey.")

    def _fill_table(self, table):
        rows = len(table["label"])
        self._table.clear()
        self._table.setColumnCount(len(SHOWN_COLUMNS))
        self._table.setRowCount(rows)
        self._table.setHorizontalHeaderLabels(list(SHOWN_COLUMNS))
        for j, key in enumerate(SHOWN_COLUMNS):
            for i, value in enumerate(np.asarray(table[key]).tolist()):
                text = f"{value:.3g}" if isinstance(value, float) else str(value)
                self._table.setItem(i, j, QTableWidgetItem(text))
