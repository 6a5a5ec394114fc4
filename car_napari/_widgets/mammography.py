"""Dock widget "Mammogram ROI": candidate masses as labels, outlines (each
with its score) and a table sorted by score, at an operating point in marks
per image that moves without recomputing the segmentation; and, from the same
segmentation, the breast tissue: a fibroglandular overlay (toggled) and the
percent density and tissue class in a one-row table."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox, FloatSpinBox, Label
from napari.layers import Labels, Shapes
from napari.utils.notifications import show_info
from qtpy.QtCore import Qt
from qtpy.QtWidgets import QHeaderView, QTableWidget, QTableWidgetItem

from .._progress import Progress, stage
from ..mammography import (
    DEFAULT_MARKS_PER_IMAGE,
    OPERATING_POINTS,
    TISSUE_CLASSES,
    MammogramROIs,
    iter_analyse_mammogram,
    operating_point,
    region_outlines,
    score_threshold,
    select_marks,
)
from ._base import JobWidget
from ._layers import compact_labels

# The dock's table: (header, table column, format, header tooltip). Short
# headers and numbers so that it fits the dock without scrolling sideways;
# the units are in the tooltips, the centroid and bounding box in each row's
# tooltip, and the outlines layer's features keep every column.
SHOWN_COLUMNS = (
    ("#", "label", "{:d}", "region number: its label in the ROI labels layer, best first"),
    ("score", "score", "{:.2f}",
     "the scoring model's score in (0, 1) (CAR texture, grey level, contrast, size and "
     "shape of the region); rows sorted by it"),
    ("area", "area", "{:d}", "area in pixels"),
    ("grey", "mean_grey", "{:.2f}", "mean grey level inside the region, on a [0, 1] scale"),
    ("contr.", "contrast", "{:.3f}",
     "contrast: mean grey minus the mean grey of a ring around the region ([0, 1] scale)"),
)


# Outlines are simplified to within this many pixels of the region's contour:
# napari draws a polygon of a few hundred vertices at once, one of the
# thousands of a large region's staircase contour in seconds. They are shown
# as paths (region_outlines closes them), not polygons: napari triangulates a
# polygon's face (in Python, ~17 ms for one outline) even when it is transparent.
OUTLINE_TOLERANCE = 1.0
OUTLINE_STYLE = dict(edge_color="yellow", edge_width=2)
OUTLINE_TEXT = {"string": "{score:.2f}", "color": "yellow", "size": 10, "anchor": "upper_left"}


# The breast-tissue table: (header, format, tooltip) of its one row.
TISSUE_COLUMNS = (
    ("density", "{:.0f} %", "percent density: fibroglandular area over breast area (the "
                            "pectoral muscle is not breast)"),
    ("class", "{}", "tissue class: F fatty, G fatty-glandular, D dense-glandular (mini-MIAS), "
                    "the most probable"),
    *((f"P({c})", "{:.2f}", f"the tissue model's probability of class {c}")
      for c in TISSUE_CLASSES),
)


def _with_outlines(job):
    """The detection job (ROIs and tissue from one segmentation), then (in
    the worker too) the regions' outlines and the labels in the smallest
    integer type that holds them (napari shows uint8 labels without
    converting them)."""
    (labels, table), tissue = yield from stage(job, 0.0, 0.97)
    yield Progress("outlines", 0.97, "outlines of the regions")
    outlines = region_outlines(labels, tolerance=OUTLINE_TOLERANCE)
    return MammogramROIs(compact_labels(labels), table), outlines, tissue


def _outlines_of(layer):
    """An outlines layer's (paths, features): what a re-cut puts back on undo."""
    return layer.data, layer.features.copy()


def _set_outlines(layer, content):
    """The outlines layer's paths and their features, ``content``, replaced
    in place (see :meth:`~._layers.RunRecord.put`)."""
    outlines, features = content
    layer.data = []
    if len(outlines):
        layer.add(outlines, shape_type="path", **OUTLINE_STYLE)
    layer.features = features


def _marks_tooltip():
    """The control's tooltip: what an operating point means, from the shipped
    FROC table (cross-validated by patient on CBIS-DDSM films)."""
    rows = [f"{p['marks_per_image']:g}: {p['cv_sensitivity_strict']:.2f}"
            for p in OPERATING_POINTS if "cv_sensitivity_strict" in p]
    return ("false marks per image on average (cross-validated on CBIS-DDSM screening "
            "films); more marks find more masses. Share of masses found at " + ", ".join(rows)
            + ". Moving it re-cuts the last result: no new detection.")


def _expected_text(marks_per_image):
    """The line beside the control: the operating point's cross-validated
    sensitivity and the no-CAR control's."""
    point = operating_point(marks_per_image)
    if point["sensitivity"] is None:
        return ""
    text = f"finds {point['sensitivity']:.0%} of masses"
    if point["interval"]:
        text += f" ({point['interval'][0]:.0%}-{point['interval'][1]:.0%})"
    if point["control"] is not None:
        text += f"; without the CAR model {point['control']:.0%}"
    return text


class MammogramWidget(JobWidget):
    """Regions of interest (candidate masses) in a grey mammogram (section
    14.4, docs/mammography.md): labels, outlines labelled with their score
    and a table sorted by score, at an operating point in marks per image.

    Detect finds and scores every candidate once; the "marks per image"
    control then shows those above its score threshold, without running the
    detection again.

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    control_labels = {"marks_per_image": "marks per image"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, image_label="mammogram",
                         image_tooltip="the mammogram layer to search for regions of "
                                       "interest")
        self.table = None  # the marks' table (dict of columns)
        self._found = None  # (every finding's MammogramROIs, their outlines)
        self._found_for = None  # (the image layer's name, its scale and translate)
        self._marks = FloatSpinBox(
            value=DEFAULT_MARKS_PER_IMAGE, min=0.25, max=12.0, step=0.25,
            label="marks per image", tooltip=_marks_tooltip())
        self._marks.changed.connect(self._on_marks)
        self._expected = Label(value=_expected_text(DEFAULT_MARKS_PER_IMAGE),
                               tooltip="cross-validated by patient on CBIS-DDSM screening films "
                                       "(95 % interval over patients), at the nearest tabled "
                                       "operating point at or below the control's value")
        self.tissue = None  # the last TissueResult
        self._overlay = CheckBox(value=True, text="fibroglandular overlay",
                                 tooltip="show the breast's fibroglandular (dense) tissue, "
                                         "found on the same CAR segmentation")
        self._overlay.changed.connect(self._on_overlay)
        self._run = self.action("Detect", self.start,
                                tooltip="find and mark candidate regions of interest in the "
                                        "breast")
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
        self._tissue_table = QTableWidget(1, len(TISSUE_COLUMNS))
        self._tissue_table.setEditTriggers(QTableWidget.NoEditTriggers)
        self._tissue_table.verticalHeader().setVisible(False)
        self._tissue_table.horizontalHeader().setSectionResizeMode(QHeaderView.Stretch)
        self._tissue_table.setMaximumHeight(60)
        for j, (title, _fmt, tip) in enumerate(TISSUE_COLUMNS):
            item = QTableWidgetItem(title)
            item.setToolTip(tip)
            self._tissue_table.setHorizontalHeaderItem(j, item)
        self.arrange([self._marks, self._expected, self._overlay, self._run],
                     fill=self._table)
        # the one-row tissue table just above the regions' table
        layout = self.body.layout()
        layout.insertWidget(layout.indexOf(self._table), self._tissue_table)

    def _start(self):
        """Detect and score every region of interest of the picked layer."""
        data, channel_axis = self.input_array(copy=False)
        layer = self._image.value
        self._name = layer.name
        self._geometry = dict(scale=tuple(layer.scale[-2:]),
                              translate=tuple(layer.translate[-2:]))
        job = iter_analyse_mammogram(data, channel_axis=channel_axis, marks_per_image=None)
        return self.run(_with_outlines(job), done=self._show)

    def _show(self, result):
        previous = self._found, self._found_for, self.tissue
        self._found = tuple(result[:2])
        self.tissue = result[2] if len(result) > 2 else None
        self._found_for = (self._name, self._geometry)
        try:
            yield from self._show_marks()
            yield from self._show_tissue()
        except BaseException:  # a Cancel or an error in between: the layers are put back,
            self._found, self._found_for, self.tissue = previous  # and what the control
            raise  # re-cuts with them

    def _tissue_name(self):
        return f"{self._found_for[0]} fibroglandular"

    def _show_tissue(self):
        """The fibroglandular overlay (visible as the toggle says) and the
        density and class in the tissue table."""
        tissue, geometry = self.tissue, self._found_for[1]
        if tissue is None:
            return
        mask = tissue.fibroglandular.astype(np.uint8)
        self.record.replace(
            self._tissue_name(), mask,
            lambda data, layer_name: self._viewer.add_labels(
                data, name=layer_name, opacity=0.35, visible=bool(self._overlay.value),
                **geometry))
        yield
        values = (tissue.density, tissue.tissue_class,
                  *(tissue.probabilities[c] for c in TISSUE_CLASSES))
        for j, ((_title, fmt, _tip), value) in enumerate(zip(TISSUE_COLUMNS, values,
                                                             strict=True)):
            item = QTableWidgetItem(fmt.format(value))
            item.setTextAlignment(Qt.AlignCenter)
            self._tissue_table.setItem(0, j, item)

    def _on_overlay(self, *_):
        """The overlay toggle: show or hide the fibroglandular layer."""
        if self._found_for is None:
            return
        name = self._tissue_name()
        if name in self._viewer.layers:
            self._viewer.layers[name].visible = bool(self._overlay.value)

    def _on_marks(self, *_):
        """The operating point moved: re-cut the last result (no new job)."""
        self._expected.value = _expected_text(float(self._marks.value))
        if self._found is not None:  # a running job shows the current value when it is done
            self.recut(lambda: self._show_marks(recut=True))

    def _show_marks(self, recut=False):
        """Show the marks of the current operating point (a generator: the
        viewer draws the labels before the outlines are added). A new result
        replaces the layers of an older one; a ``recut`` of the same result
        writes into its layers where they are still there (napari takes
        about 0.3 s to remove and add a labels and a shapes layer, a few
        tens of ms to change their data)."""
        (labels, table), outlines = self._found
        name, geometry = self._found_for
        threshold = score_threshold(float(self._marks.value))
        cut_labels, cut = select_marks(MammogramROIs(labels, table), threshold=threshold)
        m = len(cut["label"])
        labels_name, outlines_name = f"{name} ROI labels", f"{name} ROI outlines"
        layers = self._viewer.layers

        def add_labels(data, layer_name):
            return self._viewer.add_labels(data, name=layer_name, opacity=0.4, **geometry)

        def add_outlines(content, layer_name):
            paths, features = content
            return self._viewer.add_shapes(paths, shape_type="path", name=layer_name,
                                           features=features, text=OUTLINE_TEXT,
                                           **OUTLINE_STYLE, **geometry)

        def ours(layer_name, kind):  # a re-cut writes into its own kinds of layer only
            return recut and layer_name in layers and isinstance(layers[layer_name], kind)

        if ours(labels_name, Labels):
            self.record.put(labels_name, cut_labels, add_labels)
        else:
            self.record.replace(labels_name, cut_labels, add_labels)
        yield
        if ours(outlines_name, Shapes):  # in place: emptied when no region is marked
            self.record.put(outlines_name, (outlines[:m], cut), add_outlines,
                            read=_outlines_of, write=_set_outlines)
        elif m:
            self.record.replace(outlines_name, (outlines[:m], cut), add_outlines)
        else:
            self.record.remove(outlines_name)
        yield
        self.table = cut
        self._fill_table(cut)
        n = len(table["label"])
        self._status.value = (f"{m} mark{'s' * (m != 1)} (score >= {threshold:.2f}) of "
                              f"{n} scored region{'s' * (n != 1)}")
        if n == 0:
            show_info("no candidate region was found in the breast.")
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
