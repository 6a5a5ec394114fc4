"""Dock widget "Mammogram ROI": candidate masses as labels, outlines and a table."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import FloatSpinBox, SpinBox
from napari.utils.notifications import show_info
from qtpy.QtWidgets import QTableWidget, QTableWidgetItem

from ..mammography import (
    DEFAULT_MAX_REGIONS,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    iter_detect_mammogram_rois,
    region_outlines,
)
from ._base import JobWidget

# Columns shown in the dock's table (the layer's features keep them all).
SHOWN_COLUMNS = ("label", "area", "mean_grey", "contrast", "centroid_row", "centroid_col",
                 "score")


class MammogramWidget(JobWidget):
    """Regions of interest (candidate masses) in a grey mammogram (section
    14.4.1, docs/mammography.md): labels, outlines and a table of features.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer.
    """

    control_labels = {"reference": "reference grey", "tolerance": "tolerance",
                      "max_regions": "max regions"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, image_label="mammogram")
        self.table = None  # the last result's table (dict of columns)
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
        self._run = self.action("Detect", self.start)
        self._table = QTableWidget()
        self._table.setMinimumHeight(140)
        self._table.setEditTriggers(QTableWidget.NoEditTriggers)
        self.arrange([self._reference, self._tolerance, self._max_regions, self._run])
        self.native.layout().addWidget(self._table)

    def _start(self):
        """Detect the regions of interest of the picked layer."""
        data, channel_axis = self.input_array()
        layer = self._image.value
        self._name = layer.name
        self._geometry = dict(scale=tuple(layer.scale[-2:]),
                              translate=tuple(layer.translate[-2:]))
        job = iter_detect_mammogram_rois(
            data, channel_axis=channel_axis, reference=float(self._reference.value),
            tolerance=float(self._tolerance.value),
            max_regions=int(self._max_regions.value) or None)
        return self.run(job, done=self._show)

    def _show(self, result):
        labels, table = result
        geometry = self._geometry
        self.record.replace(f"{self._name} ROI labels",
                            lambda name: self._viewer.add_labels(labels, name=name, opacity=0.4,
                                                                 **geometry))
        outlines = region_outlines(labels)
        if outlines:
            self.record.replace(
                f"{self._name} ROI outlines",
                lambda name: self._viewer.add_shapes(
                    outlines, shape_type="polygon", name=name, edge_color="yellow",
                    face_color="transparent", edge_width=2, features=table, **geometry),
            )
        else:
            self.record.remove(f"{self._name} ROI outlines")
        self.table = table
        self._fill_table(table)
        n = len(table["label"])
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
