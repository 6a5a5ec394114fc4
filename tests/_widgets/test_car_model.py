"""The "CAR model" widget in a real napari viewer (pytest-qt, Xvfb)."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._widgets.car_model import CARModelWidget

pytest.importorskip("napari")


@pytest.fixture
def widget(docked):
    return docked(CARModelWidget, "CAR model")


def _wait(qtbot, job, timeout=60000):
    qtbot.waitUntil(lambda: job.done, timeout=timeout)


def test_fit_and_synthesize_rgb(widget, qtbot):
    viewer, w = widget
    texture = skdata.astronaut()[300:428, 0:128]
    layer = viewer.add_image(texture, name="grass", rgb=True)
    before = layer.data.copy()
    w._image.value = layer
    w._max_order.value = 3
    job = w.start_fit()
    qtbot.waitUntil(lambda: w.model is not None, timeout=60000)
    _wait(qtbot, job)  # the buttons come back when the worker has finished
    assert "order 1" in w._report.value and "Sigma" in w._report.value
    assert set(w.model.scores) == {1, 2, 3}
    assert w._synth.enabled
    w._height.value, w._width.value, w._seed.value = 40, 70, 3
    w.start_synthesis()
    qtbot.waitUntil(lambda: "grass CAR sample" in viewer.layers, timeout=60000)
    sample = viewer.layers["grass CAR sample"]
    assert sample.data.shape == (40, 70, 3) and sample.rgb
    assert np.isfinite(sample.data).all()
    np.testing.assert_array_equal(layer.data, before)


def test_fit_grey_inside_rectangle(widget, qtbot):
    viewer, w = widget
    layer = viewer.add_image(skdata.camera(), name="camera")
    shapes = viewer.add_shapes([[[10, 20], [10, 120], [90, 120], [90, 20]]],
                               shape_type="rectangle", name="roi")
    w._image.value, w._region.value = layer, shapes
    w.start_fit()
    qtbot.waitUntil(lambda: w.model is not None, timeout=60000)
    assert w.model.n_channels == 1
    assert w.model.n_pixels < 80 * 100
    w._height.value, w._width.value = 33, 21
    w.start_synthesis()
    qtbot.waitUntil(lambda: "camera CAR sample" in viewer.layers, timeout=60000)
    assert viewer.layers["camera CAR sample"].data.shape == (33, 21)


def test_errors_become_notifications(widget, qtbot, last_notification):
    viewer, w = widget
    w.start_fit()  # no layer at all
    assert "no image layer" in last_notification()
    layer = viewer.add_image(np.random.default_rng(0).random((3, 3)), name="tiny")
    w._image.value = layer
    job = w.start_fit()
    _wait(qtbot, job)
    assert "too small" in last_notification()
    flat = viewer.add_image(np.full((64, 64), 7.0), name="flat")
    w._image.value = flat
    job = w.start_fit()
    _wait(qtbot, job)
    assert "constant" in last_notification()
    assert w._fit.enabled and not w._cancel.enabled
    assert w.model is None
    w.start_synthesis()
    assert "fit a model first" in last_notification()
    stack = viewer.add_image(np.zeros((4, 32, 32)), name="stack")
    w._image.value = stack
    w.start_fit()
    assert "2-D grey or RGB" in last_notification()


def test_cancel_leaves_the_viewer_unchanged(widget, qtbot):
    viewer, w = widget
    layer = viewer.add_image(skdata.astronaut()[:256, :256], name="astro", rgb=True)
    w._image.value = layer
    job = w.start_fit()
    job.cancel()
    _wait(qtbot, job)
    assert w.model is None
    assert [lay.name for lay in viewer.layers] == ["astro"]
    assert w._fit.enabled and not w._cancel.enabled
