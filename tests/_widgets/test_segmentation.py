"""The "Texture segmentation" widget in a real napari viewer."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._widgets.segmentation import SegmentationWidget


def _two_textures():
    a = skdata.brick()[:128, :64] / 255.0
    b = skdata.grass()[:128, :64] / 255.0
    return np.concatenate([a, b], axis=1)


@pytest.fixture
def widget(docked):
    return docked(SegmentationWidget, "Texture segmentation")


def test_live_merging_then_instant_recut(widget, qtbot):
    viewer, w = widget
    image = _two_textures()
    layer = viewer.add_image(image, name="mosaic")
    w._image.value = layer
    w._levels.value, w._n_init.value = 2, 8
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.updates >= 2
    result = w.result
    labels = viewer.layers["mosaic segments"].data
    assert labels.shape == image.shape and labels.max() >= 1
    np.testing.assert_array_equal(layer.data, image)
    # re-cut the merge history: no new worker, labels change
    ks = [m.k for m in result.history]
    before = viewer.layers["mosaic segments"].data.copy()
    target = max(ks) if result.n_segments != max(ks) else min(ks)
    w._cut.value = target
    after = viewer.layers["mosaic segments"].data
    assert w._job is job and not np.array_equal(before, after)
    assert len(np.unique(after[after > 0])) <= target


def test_cancel_mid_run_leaves_layer_list_as_it_was(widget, qtbot):
    viewer, w = widget
    layer = viewer.add_image(_two_textures(), name="mosaic")
    w._image.value = layer
    w._levels.value, w._n_init.value = 2, 8
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    names = [lay.name for lay in viewer.layers]
    kept = viewer.layers["mosaic segments"].data.copy()
    job = w.start()  # second run: cancel as soon as it shows something
    qtbot.waitUntil(lambda: w.updates >= 1 or job.done, timeout=120000)
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert [lay.name for lay in viewer.layers] == names
    np.testing.assert_array_equal(viewer.layers["mosaic segments"].data, kept)


def test_cancel_first_run_adds_no_layer(widget, qtbot):
    viewer, w = widget
    layer = viewer.add_image(_two_textures(), name="mosaic")
    w._image.value = layer
    w._levels.value = 2
    job = w.start()
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert [lay.name for lay in viewer.layers] == ["mosaic"]


def test_bad_input_is_a_notification(widget, qtbot):
    from napari.utils.notifications import notification_manager

    viewer, w = widget
    w._image.value = viewer.add_image(np.full((128, 128), 3.0), name="flat")
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert "constant" in str(notification_manager.records[-1].message)
    assert [lay.name for lay in viewer.layers] == ["flat"]
