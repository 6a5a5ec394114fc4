"""The widget base in a real napari viewer: the run record, Cancel, the
status line and messages in the widget's terms."""

import threading

import numpy as np
import pytest
from magicgui.widgets import SpinBox

from car_napari._progress import Progress
from car_napari._widgets._base import JobWidget, guarded
from car_napari._widgets._layers import RunRecord, layer_array


def _steps(image, gate, n_steps=3, fail=None):
    """A core-like job: previews of a growing image, held at ``gate`` after
    the first record so that a test can cancel mid-run."""
    out = np.zeros_like(image)
    for k in range(n_steps):
        out[: (k + 1) * image.shape[0] // n_steps] = 1.0
        yield Progress("rows", (k + 1) / n_steps, f"step {k + 1}/{n_steps}", out.copy())
        if k == 0 and not gate.wait(30):
            raise TimeoutError("the test never opened the gate")
    if fail is not None:
        raise ValueError(fail)
    return out


class StepsWidget(JobWidget):
    """A minimal widget on the base: one control, one action."""

    control_labels = {"n_steps": "steps"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer)
        self.gate = threading.Event()
        self.fail = None
        self._steps = SpinBox(value=3, min=1, max=10, label="steps")
        self._run = self.action("Run", self.start)
        self.arrange([self._steps, self._run])

    @guarded
    def start(self, *_):
        data, _ = self.input_array()
        name = f"{self._image.value.name} steps"

        def put(out):
            self.record.put(name, out, lambda d, n: self._viewer.add_image(d, name=n))

        return self.run(_steps(data, self.gate, int(self._steps.value), self.fail),
                        preview=put, done=put)


@pytest.fixture
def widget(docked):
    return docked(StepsWidget, "steps")


def test_cancel_undoes_what_the_run_added_and_changed(widget, qtbot):
    viewer, w = widget
    layer = viewer.add_image(np.full((12, 8), 0.5), name="img")
    w._image.value = layer
    job = w.start()
    qtbot.waitUntil(lambda: "img steps" in viewer.layers, timeout=30000)
    assert not w._run.enabled and w._cancel.enabled
    w.cancel()
    w.gate.set()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    assert [lay.name for lay in viewer.layers] == ["img"]
    assert w._status.value == "cancelled" and w._run.enabled and not w._cancel.enabled
    # a completed run, then a cancelled one: the first run's output comes back
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    kept = viewer.layers["img steps"].data.copy()
    assert kept.all()
    w.gate.clear()
    job = w.start()
    qtbot.waitUntil(lambda: w._status.value.startswith("rows"), timeout=30000)
    assert not np.array_equal(viewer.layers["img steps"].data, kept)  # the live preview
    job.cancel()  # the job's own cancel undoes as the button does
    w.gate.set()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    assert [lay.name for lay in viewer.layers] == ["img", "img steps"]
    np.testing.assert_array_equal(viewer.layers["img steps"].data, kept)


def test_status_after_cancel_then_success_says_done(widget, qtbot):
    viewer, w = widget
    w._image.value = viewer.add_image(np.zeros((9, 9)), name="img")
    job = w.start()
    w.cancel()
    w.gate.set()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    assert w._status.value == "cancelled" and w._progress.value == 0
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    assert w._status.value == "done" and w._progress.value == 100
    assert "img steps" in viewer.layers


def test_an_error_names_the_control_and_undoes(widget, qtbot, last_notification):
    viewer, w = widget
    w._image.value = viewer.add_image(np.zeros((9, 9)), name="img")
    w.gate.set()
    w.fail = "n_steps (3) must be at most 2; got n_steps=3."
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=30000)
    message = last_notification()
    assert message == "'steps' (3) must be at most 2; got 'steps'=3."
    assert [lay.name for lay in viewer.layers] == ["img"]  # the previews are undone
    assert w._status.value == "failed" and w._run.enabled


def test_no_layer_is_a_notification(widget, last_notification):
    _, w = widget
    assert w.start() is None
    assert "no image layer" in last_notification()


def test_segmentation_error_names_the_controls(docked, qtbot, last_notification):
    from car_napari._widgets.segmentation import SegmentationWidget

    viewer, w = docked(SegmentationWidget, "Texture segmentation")
    w._image.value = viewer.add_image(np.random.default_rng(0).random((64, 64)), name="noise")
    w._segments.value, w._n_init.value = 20, 8
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    message = last_notification()
    assert "'segments'" in message and "'initial K'" in message
    assert "n_segments" not in message and "n_init" not in message
    assert [lay.name for lay in viewer.layers] == ["noise"]


def test_run_record_puts_everything_back(make_napari_viewer):
    viewer = make_napari_viewer()
    a = viewer.add_image(np.zeros((4, 4)), name="a")
    viewer.add_image(np.ones((4, 4)), name="b")
    viewer.add_image(np.full((4, 4), 2.0), name="c")
    record = RunRecord(viewer)
    record.put("a", np.full((4, 4), 9.0), None)
    record.put("a", np.full((4, 4), 8.0), None)  # backed up once: the original comes back
    record.put("new", np.zeros((4, 4)), lambda d, n: viewer.add_image(d, name=n))
    record.replace("b", lambda n: viewer.add_labels(np.zeros((4, 4), int), name=n))
    record.remove("c")
    assert [lay.name for lay in viewer.layers] == ["a", "new", "b"]
    record.undo()
    assert [lay.name for lay in viewer.layers] == ["a", "b", "c"]
    assert viewer.layers["a"] is a and not a.data.any()
    assert viewer.layers["b"].data.all() and (viewer.layers["c"].data == 2).all()
    clip = viewer.add_image(np.zeros((5, 4, 4)), name="clip")
    step = viewer.dims.current_step[0]
    record.set_step(0, 3)
    record.set_step(0, 4)
    assert viewer.dims.current_step[0] == 4
    record.undo()
    assert viewer.dims.current_step[0] == step
    viewer.layers.remove(clip)
    record.put("a", np.ones((4, 4)), None)
    record.commit()
    record.undo()  # nothing left to undo once committed
    assert a.data.all()


def test_layer_array_crops_and_copies(make_napari_viewer):
    viewer = make_napari_viewer()
    rgba = np.random.default_rng(1).random((20, 30, 4))
    layer = viewer.add_image(rgba, rgb=True, name="rgba")
    box = viewer.add_shapes([[[2, 3], [2, 13], [9, 13], [9, 3]]], shape_type="rectangle")
    data, channel_axis = layer_array(layer, box)
    assert channel_axis == -1 and data.shape == (7, 10, 3)
    np.testing.assert_array_equal(data, rgba[2:9, 3:13, :3])
    data[:] = 0
    assert layer.data.any()
    stack = viewer.add_image(np.zeros((3, 8, 8)), name="stack")
    with pytest.raises(ValueError, match="3 non-colour axes"):
        layer_array(stack)
    assert layer_array(stack, ndims=(3,))[0].shape == (3, 8, 8)
