"""The "Mammogram ROI" widget in a real napari viewer."""

import numpy as np
import pytest

from car_napari._widgets.mammography import MammogramWidget
from car_napari.io.sample_data import mammogram


@pytest.fixture
def widget(docked):
    return docked(MammogramWidget, "Mammogram ROI")


@pytest.fixture(scope="module")
def small_mammogram():
    """The sample mdb001 block-averaged 2x (512x512): same anatomy, faster."""
    (image, _, _), = mammogram()
    return image.reshape(512, 2, 512, 2).mean(axis=(1, 3)).astype(np.uint8)


def test_detect_gives_labels_outlines_and_table(widget, qtbot, small_mammogram):
    viewer, w = widget
    layer = viewer.add_image(small_mammogram, name="mdb001")
    w._image.value = layer
    w._max_regions.value = 0  # every region in the band: something to show
    w._tolerance.value = 0.3
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=180000)
    labels = viewer.layers["mdb001 ROI labels"].data
    assert labels.shape == small_mammogram.shape
    n = len(w.table["label"])
    assert n >= 1 and labels.max() == n
    outlines = viewer.layers["mdb001 ROI outlines"]
    assert len(outlines.data) == n
    assert list(outlines.features["label"]) == list(range(1, n + 1))
    assert w._table.rowCount() == n
    # every outline encloses its region's centroid's row span
    rows = zip(outlines.data, w.table["bbox_min_row"], w.table["bbox_max_row"], strict=True)
    for poly, r0, r1 in rows:
        assert r0 - 1 <= poly[:, 0].min() and poly[:, 0].max() <= r1
    np.testing.assert_array_equal(layer.data, small_mammogram)
    # re-running replaces the outputs, it does not add more
    count = len(viewer.layers)
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=180000)
    assert len(viewer.layers) == count


def test_bad_input_is_a_notification(widget, qtbot, last_notification):
    viewer, w = widget
    w.start()
    assert "no image layer" in last_notification()
    black = viewer.add_image(np.zeros((256, 256), np.uint8), name="black")
    w._image.value = black
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert "constant" in last_notification()
    assert [lay.name for lay in viewer.layers] == ["black"]
    assert w._run.enabled and not w._cancel.enabled


def test_cancel_leaves_the_viewer_unchanged(widget, qtbot, small_mammogram):
    viewer, w = widget
    w._image.value = viewer.add_image(small_mammogram, name="mdb001")
    job = w.start()
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=180000)
    assert [lay.name for lay in viewer.layers] == ["mdb001"]
