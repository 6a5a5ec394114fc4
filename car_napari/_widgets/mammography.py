"""Dock widget "Mammogram ROI": candidate masses as labels, outlines and a table."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import FloatSpinBox, SpinBox
from napari.utils.notifications import show_info
from qtpy.QtCore import Qt
from qtpy.QtWidgets import QHeaderView, QTableWidget, QTableWidgetItem

from .._progress import Progress, stage
from ..mammography import (
    DEFAULT_MAX_REGIONS,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    MammogramROIs,
    iter_detect_mammogram_rois,
    region_outlines,
)
from ._base import JobWidget

# The dock's table: (header, table column, format, header tooltip). Short
# headers and numbers so that it fits the dock without scrolling sideways;
# the units are in the tooltips, the centroid and bounding box in each row's
# tooltip, and the outlines layer's features keep every column.
SHOWN_COLUMNS = (
    ("#", "label", "{:d}", "region number: its label in the ROI labels layer, best first"),
    ("area", "area", "{:d}", "area in pixels"),
    ("grey", "mean_grey", "{:.2f}", "mean grey level inside the region, on a [0, 1] scale"),
    ("contr.", "contrast", "{:.3f}",
     "contrast: mean grey minus the mean grey of a ring around the region ([0, 1] scale)"),
    ("score", "score", "{:.3f}",
     "ranking score: contrast x closeness to the reference grey x compactness x size prior"),
)


# Outlines are simplified to within this many pixels of the region's contour:
# napari draws a polygon of a few hundred vertices at once, one of the
# thousands of a large region's staircase contour in seconds.
OUTLINE_TOLERANCE = 1.0


def _with_outlines(job):
    """The detection job, then (in the worker too) the regions' outlines and
    the labels in the smallest integer type that holds them (napari shows
    uint8 labels without converting them)."""
    rois = yield from stage(job, 0.0, 0.97)
    yield Progress("outlines", 0.97, "outlines of the regions")
    labels, table = rois
    n = int(labels.max(initial=0))
    small = labels.astype(np.uint8 if n < 2**8 else np.uint16 if n < 2**16 else labels.dtype)
    return MammogramROIs(small, table), region_outlines(labels, tolerance=OUTLINE_TOLERANCE)


class MammogramWidget(JobWidget):
    """Regions of interest (candidate masses) in a grey mammogram (section
    14.4, docs/mammography.md): labels, outlines and a table of features.

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
        self._table = QTableWidget(0, len(SHOWN_COLUMNS))
        self._table.setMinimumHeight(140)
        self._table.setEditTriggers(QTableWidget.NoEditTriggers)
        self._table.verticalHeader().setVisible(False)  # the "#" column numbers the rows
        header = self._table.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeToContents)
        header.setMinimumSectionSize(24)
        for j, (title, _key, _fmt, tip) in enumerate(SHOWN_COLUMNS):
            item = QTableWidgetItem(title)
            item.setToolTip(tip)
            self._table.setHorizontalHeaderItem(j, item)
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
        return self.run(_with_outlines(job), done=self._show)

    def _show(self, result):
        (labels, table), outlines = result
        geometry = self._geometry
        self.record.replace(f"{self._name} ROI labels",
                            lambda name: self._viewer.add_labels(labels, name=name, opacity=0.4,
                                                                 **geometry))
        yield  # the viewer draws the labels before the outlines are added
        if outlines:
            self.record.replace(
                f"{self._name} ROI outlines",
                lambda name: self._viewer.add_shapes(
                    outlines, shape_type="polygon", name=name, edge_color="yellow",
                    face_color="transparent", edge_width=2, features=table, **geometry),
            )
        else:
            self.record.remove(f"{self._name} ROI outlines")
        yield
        self.table = table
        self._fill_table(table)
        n = len(table["label"])
        self._status.value = f"{n} region{'s' * (n != 1)} of interest"
        if n == 0:
            show_info("no region of interest passed the grey-level filter; widen the "
                      "tolerance or check the reference grey.")

    def _fill_table(self, table):
        rows = len(table["label"])
        self._table.clearContents()
        self._table.setRowCount(rows)
        for i in range(rows):
            where = (f"centroid (row, col) {table['centroid_row'][i]:.0f}, "
                     f"{table['centroid_col'][i]:.0f}; bounding box rows "
                     f"{table['bbox_min_row'][i]}-{table['bbox_max_row'][i]}, columns "
                     f"{table['bbox_min_col'][i]}-{table['bbox_max_col'][i]} (pixels)")
            for j, (_title, key, fmt, _tip) in enumerate(SHOWN_COLUMNS):
                value = table[key][i]
                value = int(value) if fmt.endswith("d}") else float(value)
                item = QTableWidgetItem(fmt.format(value))
                item.setTextAlignment(Qt.AlignRight | Qt.AlignVCenter)
                item.setToolTip(where)
                self._table.setItem(i, j, item)
