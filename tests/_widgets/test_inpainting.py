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
    assert mask_layer.mode == "paint" and viewer.layers.selection.active == mask_layer
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
    assert 1 <= w.updates <= 3  # live updates (throttled: at most one per frame)
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
    names = [lay.name for lay in viewer.layers]
    job = w.start()  # the mask is read in the worker: an empty one is said at the end
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert "empty" in last_notification() and "empty" in w._status.value
    assert [lay.name for lay in viewer.layers] == names and w._run.enabled
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


def test_a_mask_opened_from_a_file_of_another_size_is_used(widget, qtbot, tmp_path,
                                                           last_notification):
    """Defect d: a film scan and its mask.png (RGB, twice the scan's size),
    both opened from files: the mask is chosen, resized to the frame with a
    note, and the restoration fills exactly its pixels."""
    from skimage import io

    viewer, w = widget
    frame = skdata.astronaut()[:96, :128].copy()
    damage = np.zeros(frame.shape[:2], bool)
    damage[:, 50:53] = True
    damage[30:40, 90:100] = True
    frame[damage] = 255
    io.imsave(tmp_path / "damaged.png", frame, check_contrast=False)
    big = np.repeat(np.repeat(damage, 2, axis=0), 2, axis=1)  # drawn at twice the size
    io.imsave(tmp_path / "mask.png", np.repeat(big[..., None] * np.uint8(255), 3, axis=2),
              check_contrast=False)
    [scan] = viewer.open(str(tmp_path / "damaged.png"))
    [opened] = viewer.open(str(tmp_path / "mask.png"))
    assert opened.data.shape == (192, 256, 3)
    w._image.value = scan
    choices = [layer.name for layer in w._mask.choices if layer is not None]
    assert choices == ["damaged", "mask"]  # every Image (and Labels) layer
    assert w._mask.value is opened  # a layer named like a mask is the default
    w._mask.value = opened  # as the user chooses it
    job = w.start()
    assert "resized" in last_notification() and "192x256" in last_notification()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["damaged restored"].data
    assert out.shape == frame.shape and out.dtype == frame.dtype
    np.testing.assert_array_equal(out[~damage], frame[~damage])  # the mask, resized exactly
    assert np.all(out[damage].max(axis=-1) < 255)  # every damaged pixel is filled
    np.testing.assert_array_equal(opened.data[..., 0] != 0, big)  # the mask layer untouched


def test_a_labels_mask_is_choosable_and_the_own_mask_is_the_default(widget, qtbot):
    """Defect d: the picker lists Labels layers too; the source's "scratch
    mask" is chosen by default, another one when the user picks it."""
    viewer, w = widget
    frame = skdata.camera()[:64, :64].copy()
    frame[:, 20:22] = 255
    source = viewer.add_image(frame, name="cam")
    w._image.value = source
    painted = viewer.add_labels(np.zeros((32, 32), np.uint8), name="painted")
    painted.data[:, 10] = 3  # any label value marks damage
    viewer.add_points([[5, 5]], name="points")
    own = w.mask_layer()
    assert w._mask.value == own  # the new "scratch mask" is chosen
    listed = {lay.name for lay in w._mask.choices if lay is not None}
    assert listed == {"cam", "painted", "cam scratch mask"}  # Labels and Image layers only
    w._mask.value = painted
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["cam restored"].data
    changed = out != frame
    assert changed[:, 20:22].all() and not changed[:, :20].any() and not changed[:, 22:].any()


def test_a_clip_run_stays_on_the_users_frame_unless_asked(widget, qtbot):
    """Defect g: by default the viewer does not jump to each frame as it is
    restored; with 'follow progress' it does."""
    viewer, w = widget
    base = skdata.camera()[:48, :48]
    clip = np.stack([base.copy() for _ in range(4)])
    clip[:, :, 20:22] = 255
    w._image.value = viewer.add_image(clip, name="clip")
    w.mask_layer().data[:, :, 20:22] = 1
    viewer.dims.set_current_step(0, 1)
    steps = []
    viewer.dims.events.current_step.connect(lambda e: steps.append(viewer.dims.current_step[0]))
    assert not w._follow.value
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.updates >= 1 and viewer.layers["clip restored"].data[:, :, 20:22].max() < 255
    assert viewer.dims.current_step[0] == 1 and set(steps) <= {1}
    w._follow.value = True
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    # the frames shown live (previews are throttled; the last one is always shown)
    assert 3 in steps and viewer.dims.current_step[0] == 3


def _large_frame(n=2048):
    """A 2048x2048 RGB frame (the astronaut, each pixel 4x4) with two scratches."""
    frame = np.kron(skdata.astronaut(), np.ones((n // 512, n // 512, 1), np.uint8))
    frame[:, n // 3 : n // 3 + 3] = 250
    frame[:, 2 * n // 3 : 2 * n // 3 + 2] = 5
    return frame


def _cancel_while_running(w, job, qtbot, started):
    """Wait until ``started()`` (the job is under way), click Cancel as the
    user does; returns the seconds until the worker has ended."""
    import time

    qtbot.waitUntil(lambda: started() or job.done, timeout=60000)
    assert not job.done, "the job ended before the cancel: enlarge the input"
    t0 = time.perf_counter()
    w._cancel.native.click()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    return time.perf_counter() - t0


def test_cancel_during_detect_on_a_large_clip_is_prompt(widget, qtbot):
    viewer, w = widget
    frame = _large_frame()
    clip = np.stack([np.roll(frame, 5 * t, axis=1) for t in range(3)])  # 3 x 2048 x 2048 RGB
    w._image.value = viewer.add_image(clip, name="clip", rgb=True)
    before = [lay.name for lay in viewer.layers]
    step = viewer.dims.current_step
    job = w.detect()
    latency = _cancel_while_running(w, job, qtbot, lambda: w._progress.value > 0)
    assert latency < 3.0, f"the detector ran on {latency:.1f} s after Cancel"
    assert [lay.name for lay in viewer.layers] == before and viewer.dims.current_step == step
    assert w._status.value == "cancelled" and w._detect.enabled and not w._cancel.enabled


def test_cancel_during_restore_on_a_large_frame_is_prompt(widget, qtbot):
    import time

    viewer, w = widget
    frame = _large_frame()
    # warm-up on a crop: the kernels loaded (or compiled on a cold cache) before timing
    w._image.value = viewer.add_image(frame[:96, :96].copy(), name="crop", rgb=True)
    w.mask_layer().data[:, 40:42] = 1
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=300000)
    viewer.layers.clear()
    source = viewer.add_image(frame, name="film", rgb=True)
    w._image.value = source
    mask = w.mask_layer()
    mask.data[:, 2048 // 3 : 2048 // 3 + 3] = 1
    mask.data[:, 2 * 2048 // 3 : 2 * 2048 // 3 + 2] = 1
    before = [lay.name for lay in viewer.layers]
    t0 = time.perf_counter()
    job = w.start()
    start_s = time.perf_counter() - t0  # the mask and the frame are read in the worker
    assert job is not None and start_s < 1.0, f"the start took {start_s:.2f} s"
    # cancel once the frame's restoration is under way (the mask fitted in the worker)
    latency = _cancel_while_running(w, job, qtbot,
                                    lambda: w._status.value.startswith("frames: frame 1/1,"))
    assert latency < 3.0, f"the restoration ran on {latency:.1f} s after Cancel"
    assert [lay.name for lay in viewer.layers] == before
    np.testing.assert_array_equal(source.data, frame)
    assert w._status.value == "cancelled" and w._run.enabled and not w._cancel.enabled
