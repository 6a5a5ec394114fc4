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


def test_cancelled_fit_keeps_the_model_and_name_of_the_previous_one(widget, qtbot):
    # After a cancelled fit of B, Synthesize named the sample after B but used
    # A's model: the name and the model must both stay A's.
    from car_napari._widgets._layers import value_range
    from car_napari.model import synthesize

    viewer, w = widget
    a = viewer.add_image(skdata.astronaut()[300:428, 0:128], name="A", rgb=True)
    b = viewer.add_image(skdata.camera(), name="B")
    w._image.value, w._max_order.value = a, 3
    job = w.start_fit()
    _wait(qtbot, job)
    model_a = w.model
    report_a = w._report.value
    w._image.value, w._max_order.value = b, 5
    job = w.start_fit()
    qtbot.waitUntil(lambda: w._progress.value > 0 or job.done, timeout=60000)
    w._cancel.native.click()
    _wait(qtbot, job)
    assert w.model is model_a and w._report.value == report_a
    w._height.value, w._width.value, w._seed.value = 30, 40, 7
    job = w.start_synthesis()
    _wait(qtbot, job)
    assert [layer.name for layer in viewer.layers] == ["A", "B", "A CAR sample"]
    sample = viewer.layers["A CAR sample"]
    assert sample.rgb and sample.data.shape == (30, 40, 3)  # A is RGB, B grey
    expected = np.clip(synthesize(model_a, (30, 40), seed=7), *value_range(a.data))
    # shown as float32 (what napari draws without a conversion)
    np.testing.assert_array_equal(sample.data, expected.astype(np.float32))


def test_cancel_of_a_large_fit_ends_the_worker_quickly(widget, qtbot, cancel_latency):
    # On a 4000 x 4000 image the Run button stayed disabled for minutes after
    # Cancel; here a 2048 x 2048 RGB image, cancelled in the middle of the fit.
    viewer, w = widget
    big = np.tile(skdata.astronaut(), (4, 4, 1))  # 2048 x 2048 x 3, uint8
    w._image.value = viewer.add_image(big, name="big", rgb=True)
    job = w.start_fit()
    qtbot.waitUntil(lambda: w._progress.value >= 5 or job.done, timeout=120000)
    assert not job.done
    latency = cancel_latency(w, job, timeout=3.0)
    assert latency is not None, f"the worker ran on after Cancel ({w._status.value})"
    assert w._fit.enabled and not w._cancel.enabled and w.model is None
    assert w._status.value == "cancelled"
    assert [layer.name for layer in viewer.layers] == ["big"]


def test_unstable_model_is_explained_in_the_widgets_terms(widget, qtbot, last_notification):
    viewer, w = widget
    w._image.value = viewer.add_image(skdata.astronaut()[300:428, 0:128], name="grass",
                                      rgb=True)
    w._max_order.value = 2  # this crop's order-2 model is (just) unstable
    job = w.start_fit()
    _wait(qtbot, job)
    assert w.start_synthesis() is None
    assert "unstable" in last_notification() and "lower 'max order'" in last_notification()
    assert [layer.name for layer in viewer.layers] == ["grass"]


def test_synthesize_reports_progress_and_cancel_ends_it_quickly(widget, qtbot, cancel_latency):
    # Synthesize ran as one call: no progress, and Cancel waited for its end.
    # Now it is a job by blocks of rows: a 2048 x 2048 RGB sample, cancelled.
    viewer, w = widget
    w._image.value = viewer.add_image(skdata.astronaut()[300:428, 0:128], name="grass",
                                      rgb=True)
    w._max_order.value = 1
    _wait(qtbot, w.start_fit())
    model = w.model
    w._height.value, w._width.value = 2048, 2048
    job = w.start_synthesis()
    qtbot.waitUntil(lambda: w._progress.value >= 1 or job.done, timeout=60000)
    assert not job.done and w._status.value.startswith("synthesis")
    latency = cancel_latency(w, job, timeout=3.0)
    assert latency is not None, f"the worker ran on after Cancel ({w._status.value})"
    assert [layer.name for layer in viewer.layers] == ["grass"]
    assert w.model is model and w._synth.enabled and w._fit.enabled
    assert not w._cancel.enabled and w._status.value == "cancelled"


def test_fit_reads_the_layer_in_the_worker_and_shows_the_sample_in_two_turns(widget, qtbot,
                                                                            monkeypatch):
    # The viewer froze at the start of a large fit (a copy of the layer and a scan
    # of its range, in the viewer's thread) and when the sample was shown (the
    # layer made and its first paint in one turn).
    import threading

    from car_napari._widgets import car_model

    viewer, w = widget
    texture = skdata.astronaut()[300:428, 0:128]
    layer = viewer.add_image(texture, name="grass", rgb=True)
    w._image.value, w._max_order.value = layer, 1
    seen = {}
    fit, value_range = car_model.iter_fit_car, car_model.value_range

    def spy_fit(data, *args, **kwargs):
        seen["shares"] = np.shares_memory(data, layer.data)
        return fit(data, *args, **kwargs)

    def spy_range(data):
        seen["range thread"] = threading.current_thread()
        return value_range(data)

    monkeypatch.setattr(car_model, "iter_fit_car", spy_fit)
    monkeypatch.setattr(car_model, "value_range", spy_range)
    _wait(qtbot, w.start_fit())
    assert seen["shares"], "the layer was copied in the viewer's thread"
    assert seen["range thread"] is not threading.main_thread()
    assert w._range == value_range(texture)
    np.testing.assert_array_equal(layer.data, texture)  # read, never written
    w._height.value, w._width.value, w._seed.value = 24, 30, 2
    # the state of the job when the layer is made
    viewer.layers.events.inserted.connect(
        lambda event: seen.setdefault("adding", (w._job.showing, w._job.done)))
    job = w.start_synthesis()
    _wait(qtbot, job)
    assert seen["adding"] == (True, False)  # the layer made; its paint on the next turn
    assert w._synth.enabled and not w._cancel.enabled
    assert viewer.layers["grass CAR sample"].data.shape == (24, 30, 3)


def _right_edge(layer):
    """The world column just right of a 2-D layer's last pixel."""
    return layer.translate[-1] + (layer.data.shape[1] - 0.5) * layer.scale[-1]


def _left_edge(layer):
    return layer.translate[-1] - 0.5 * layer.scale[-1]


def test_sample_is_placed_beside_its_source(widget, qtbot):
    """Issue 32 item 11: the sample sits to the right of the fitted layer
    (a small gap, the source's scale and rows), not over it."""
    viewer, w = widget
    layer = viewer.add_image(skdata.camera()[:64, :80], name="camera",
                             scale=(2.0, 0.5), translate=(10.0, -3.0))
    w._image.value = layer
    w._max_order.value = 1
    job = w.start_fit()
    _wait(qtbot, job)
    w._height.value, w._width.value = 30, 20
    job = w.start_synthesis()
    _wait(qtbot, job)
    sample = viewer.layers["camera CAR sample"]
    assert tuple(sample.scale) == (2.0, 0.5)
    assert sample.translate[0] == 10.0  # the same top row
    gap = _left_edge(sample) - _right_edge(layer)
    assert 0 < gap <= 0.1 * 80 * 0.5  # beside it: a gap, and a small one
    assert layer.visible
