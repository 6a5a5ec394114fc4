"""The "Restoration" widget in a real napari viewer."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._widgets.restoration import RestorationWidget
from car_napari.io.sample_data import degraded_stack


@pytest.fixture
def widget(docked):
    return docked(RestorationWidget, "Restoration")


@pytest.fixture(scope="module")
def burst():
    (stack, meta, _), = degraded_stack()
    return stack[:, :128, :128], meta


def test_stack_restores_live_and_kappa_rethresholds(widget, qtbot, burst):
    viewer, w = widget
    stack, meta = burst
    layer = viewer.add_image(stack, **meta)
    w._image.value = layer
    assert w._axis.value == "axis 0"  # guessed from the layer's shape
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=180000)
    assert w.updates >= 2  # the restored layer filled in before the end
    restored = viewer.layers["degraded burst restored"]
    probability = viewer.layers["degraded burst prediction probability"]
    assert restored.data.shape == stack.shape[1:] and restored.rgb
    assert probability.data.shape == stack.shape[1:3]
    assert 0 <= probability.data.min() and probability.data.max() <= 1
    assert w.result.reference is not None and "reference" in w._status.value
    np.testing.assert_array_equal(layer.data, burst[0])  # input untouched
    # kappa: instant re-threshold, same worker, restored changes
    before = restored.data.copy()
    w._kappa.value = 0.6
    assert w._job is job
    after = viewer.layers["degraded burst restored"].data
    assert not np.array_equal(before, after)
    observed = w.result.observed
    kept = w.result.probability <= 0.6
    np.testing.assert_array_equal(after[kept], observed[kept])
    # the changed-pixel toggle shows a labels layer and hides it again
    w._show_changed.value = True
    changed = viewer.layers["degraded burst changed pixels"].data
    assert changed.shape == stack.shape[1:3] and 0 < changed.mean() < 1
    w._show_changed.value = False
    assert "degraded burst changed pixels" not in viewer.layers


def test_single_image_and_cancel(widget, qtbot):
    viewer, w = widget
    rng = np.random.default_rng(0)
    noisy = skdata.camera()[:128, :128] / 255.0 + rng.normal(0, 0.05, (128, 128))
    layer = viewer.add_image(noisy, name="camera")
    w._image.value = layer
    assert w._axis.value == "single image"
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["camera restored"].data
    assert out.shape == noisy.shape and np.abs(out - noisy).std() > 0.01
    names = [lay.name for lay in viewer.layers]
    kept = out.copy()
    job = w.start()
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert [lay.name for lay in viewer.layers] == names
    np.testing.assert_array_equal(viewer.layers["camera restored"].data, kept)
    np.testing.assert_array_equal(layer.data, noisy)


def test_bad_input_is_a_notification(widget, qtbot, last_notification):
    viewer, w = widget
    w.start()
    assert "no image layer" in last_notification()
    layer = viewer.add_image(np.zeros((3, 16, 16)), name="flat stack")
    w._image.value = layer
    w._axis.value = "single image"
    w.start()
    assert "non-colour axes" in last_notification()
    w._axis.value = "axis 0"
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert "constant" in last_notification()
    assert [lay.name for lay in viewer.layers] == ["flat stack"]
