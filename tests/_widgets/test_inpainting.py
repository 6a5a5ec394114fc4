"""The "Scratch restoration" widget in a real napari viewer."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._widgets.inpainting import InpaintingWidget


@pytest.fixture
def widget(docked):
    return docked(InpaintingWidget, "Scratch restoration")


def test_paint_a_stroke_and_restore(widget, qtbot):
    viewer, w = widget
    frame = skdata.astronaut()[:160, :160].copy()
    frame[:, 80:83] = 255  # a white vertical scratch
    layer = viewer.add_image(frame, name="frame")
    w._image.value = layer
    mask_layer = w.mask_layer()
    assert mask_layer.mode == "paint" and viewer.layers.selection.active is mask_layer
    # paint the scratch as a user would: a stroke of brush dabs down the column
    for row in range(0, 160, 2):
        mask_layer.paint((row, 81), 1)
    mask = mask_layer.data != 0
    assert mask[:, 80:83].all() and mask.mean() < 0.1
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["frame restored"].data
    assert out.shape == frame.shape and out.dtype == frame.dtype
    np.testing.assert_array_equal(out[~mask], frame[~mask])  # bit-identical outside
    assert np.all(out[:, 81] != 255)  # the scratch is gone
    np.testing.assert_array_equal(layer.data, frame)  # the source is untouched


def test_clip_restores_frame_by_frame_and_detect_is_undoable(widget, qtbot):
    viewer, w = widget
    base = skdata.camera()[:96, :96]
    clip = np.stack([base.copy() for _ in range(3)])
    clip[1, :, 40:42] = 255
    layer = viewer.add_image(clip, name="clip")
    w._image.value = layer
    job = w.detect()  # runs in a worker
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    mask_layer = viewer.layers["clip scratch mask"]
    assert "proposed" in w._status.value
    proposed = mask_layer.data.copy()
    assert proposed.shape == clip.shape and proposed[1, :, 40:42].mean() > 0.8
    mask_layer.undo()
    assert not mask_layer.data.any()
    mask_layer.redo()
    np.testing.assert_array_equal(mask_layer.data, proposed)
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.updates == 3  # one live update per frame
    out = viewer.layers["clip restored"].data
    assert np.abs(out[1, :, 40:42].astype(int) - base[:, 40:42]).mean() < 20
    np.testing.assert_array_equal(layer.data, clip)


def test_empty_mask_and_cancel(widget, qtbot, last_notification):
    viewer, w = widget
    w.start()
    assert "no image layer" in last_notification()
    layer = viewer.add_image(skdata.camera()[:64, :64], name="cam")
    w._image.value = layer
    w.start()
    assert "no scratch mask" in last_notification()
    w.mask_layer()
    assert w.start() is None
    assert "empty" in last_notification()
    names = [lay.name for lay in viewer.layers]
    viewer.layers["cam scratch mask"].data[10:20, 10:12] = 1
    job = w.start()
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert [lay.name for lay in viewer.layers] == names


def test_detect_runs_in_a_worker_and_cancel_adds_nothing(widget, qtbot):
    viewer, w = widget
    clip = np.stack([skdata.camera()[:96, :96] for _ in range(3)])
    w._image.value = viewer.add_image(clip, name="clip")
    job = w.detect()
    assert job is not None and not w._detect.enabled and w._cancel.enabled
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert [lay.name for lay in viewer.layers] == ["clip"]
    assert w._status.value == "cancelled" and w._detect.enabled
