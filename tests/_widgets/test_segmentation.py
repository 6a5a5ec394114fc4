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
    shown = []  # the dtype of every labels array the layer is given
    plain_put = w.record.put
    w.record.put = lambda name, data, add: shown.append(data.dtype) or plain_put(name, data, add)
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.updates >= 2
    result = w.result
    labels = viewer.layers["mosaic segments"].data
    assert labels.shape == image.shape and labels.max() >= 1
    # napari shows uint8 labels as they are (int32 it hashes in the viewer's thread);
    # the result keeps the core's int32 labels, the same values
    assert set(shown) == {np.dtype(np.uint8)} and len(shown) == w.updates + 1
    assert result.labels.dtype == np.int32
    np.testing.assert_array_equal(labels, result.labels)
    np.testing.assert_array_equal(layer.data, image)
    # re-cut the merge history: a re-cut in a worker, no run; labels change
    ks = [m.k for m in result.history]
    before = viewer.layers["mosaic segments"].data.copy()
    target = max(ks) if result.n_segments != max(ks) else min(ks)
    w._cut.value = target
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=60000)
    after = viewer.layers["mosaic segments"].data
    assert after.dtype == np.uint8
    assert w._job is job and not np.array_equal(before, after)
    assert len(np.unique(after[after > 0])) <= target
    np.testing.assert_array_equal(after, result.labels_at(target, threshold=0.0))


def test_merge_similar_regions_refines_the_automatic_k_only(widget, qtbot):
    """The folded "merge similar regions" box is segment's region_threshold
    (0 = off): on one texture, which the automatic K splits, a large value
    merges the segments into one; a given number of segments ignores it."""
    viewer, w = widget
    w._image.value = viewer.add_image(skdata.grass()[:128, :128] / 255.0, name="mosaic")
    w._levels.value, w._n_init.value = 2, 8
    assert w._merge_regions.value == 0.0 and "0 = off" in w._merge_regions.tooltip
    w._merge_regions.value = 10.0
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.result.n_segments == 1
    assert viewer.layers["mosaic segments"].data.max() == 1
    w._segments.value = 2
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.result.n_segments == 2


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


# --- the segments box (defect f) -------------------------------------------------------

def test_segments_box_is_bounded_by_the_initial_k_and_zero_says_auto(widget):
    _, w = widget
    box = w._segments
    assert box.value == 0 and box.label == "segments (0 = auto)"
    assert "0 = automatic" in box.tooltip
    assert box.max == w._n_init.value == 16
    box.value = 12
    w._n_init.value = 8  # the box follows the initial K and its value is clipped
    assert box.max == 8 and box.value == 8
    with pytest.raises(ValueError):
        box.value = 9
    w._n_init.value = 20
    assert box.max == 20 and box.value == 8
    box.value = 20
    assert box.value == 20


def test_core_errors_speak_of_the_controls(widget):
    from car_napari.segmentation import iter_segment

    _, w = widget
    with pytest.raises(ValueError) as caught:
        next(iter_segment(_two_textures(), n_segments=9, n_init=8))
    message = w.message(caught.value)
    assert "'segments'" in message and "'initial K'" in message
    assert "n_segments" not in message and "n_init" not in message


# --- re-cuts and cancel on a 1024x1024 image (features precomputed: the merging) ---------

def _quadrant_features(n=1024, d=8, seed=0):
    """Features of four textures in the quadrants of an n x n image, with noise."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=3.0, size=(4, d))
    quadrant = np.zeros((n, n), int)
    quadrant[: n // 2, n // 2 :] = 1
    quadrant[n // 2 :, : n // 2] = 2
    quadrant[n // 2 :, n // 2 :] = 3
    noise = ndimage.gaussian_filter(rng.normal(size=(n, n, d)), (1.5, 1.5, 0)) * 3
    return (centres[quadrant] + noise).astype(np.float32)


@pytest.fixture
def merging_only(widget, monkeypatch):
    """The widget on a 1024x1024 RGB layer whose job gets precomputed
    features (so that it runs only the mixture, the merging and the labelling)."""
    import functools

    from car_napari._widgets import segmentation as segmentation_widget
    from car_napari.segmentation import iter_segment

    viewer, w = widget
    features = _quadrant_features()
    monkeypatch.setattr(segmentation_widget, "iter_segment",
                        functools.partial(iter_segment, features=features))
    image = np.random.default_rng(1).random((1024, 1024, 3))
    w._image.value = viewer.add_image(image, name="big", rgb=True)
    return viewer, w


def _moved(w, control, value, qtbot):
    """Set a slider as a user does; a changed value starts a re-cut in a
    worker (even a look-up: it passes over every pixel). Waits until shown."""
    changed = control.value != value
    control.value = value
    assert (w._recut_job is not None) == changed
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=60000)


def test_slider_moves_run_in_a_worker(merging_only, qtbot, event_loop_monitor):
    viewer, w = merging_only
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=300000)
    result, layer = w.result, viewer.layers["big segments"]
    ks = sorted({m.k for m in result.history})
    qtbot.wait(300)  # the viewer draws the labels
    # "show K" over the whole history and "min probability" on the final K: look-ups,
    # in a worker; the viewer does not stall (bound for a loaded CI machine; the
    # figures are the GUI benchmark's)
    with event_loop_monitor:
        for k in [*ks, result.n_segments]:
            _moved(w, w._cut, k, qtbot)
            np.testing.assert_array_equal(layer.data, result.labels_at(k, threshold=0.0))
            assert w._status.value.endswith(f"(K = {k})")
        for threshold in (0.3, 0.6, 0.9):
            _moved(w, w._threshold, threshold, qtbot)
            np.testing.assert_array_equal(
                layer.data, result.labels_at(result.n_segments, threshold=threshold))
    assert event_loop_monitor.longest_ms < 500, event_loop_monitor.summary()
    assert (layer.data == 0).any()
    # another K under a threshold needs that state's probabilities: a worker
    # re-cuts; a newer value cancels it and wins
    others = [k for k in ks if k != result.n_segments]
    with event_loop_monitor:
        w._cut.value = others[-1]
        first = w._recut_job
        assert first is not None and w._status.value.startswith("re-cutting")
        w._cut.value = others[0]
        second = w._recut_job
        assert first.cancelled and second is not None and second is not first
        qtbot.waitUntil(lambda: w._recut_job is None, timeout=60000)
    assert event_loop_monitor.longest_ms < 1000, event_loop_monitor.summary()
    np.testing.assert_array_equal(layer.data, result.labels_at(others[0], threshold=0.9))
    assert w._status.value.endswith(f"(K = {others[0]})")
    assert w._job is job  # re-cuts are not runs: nothing to undo, no Run button change


def test_a_quick_drag_shows_the_last_value_only(merging_only, qtbot, event_loop_monitor):
    """The sliders dragged faster than the re-cuts run (no event-loop turn
    between the values): each value cancels the re-cut before it, none of
    those is shown, and the layer ends showing the last values' labels."""
    viewer, w = merging_only
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=300000)
    result, layer = w.result, viewer.layers["big segments"]
    ks = sorted({m.k for m in result.history})
    qtbot.wait(300)
    shown = []
    show = w._show_cut
    w._show_cut = lambda result_, labels, n, k: (shown.append((k, w._threshold.value)),
                                                 show(result_, labels, n, k))
    with event_loop_monitor:
        jobs = []
        for k in [*(k for k in ks[::-1] if k != result.n_segments), result.n_segments]:
            w._cut.value = k  # each value differs from the one before
            jobs.append(w._recut_job)
        for threshold in (0.2, 0.5, 0.3):
            w._threshold.value = threshold
            jobs.append(w._recut_job)
        assert all(j is not None for j in jobs) and len(set(map(id, jobs))) == len(jobs)
        assert all(j.cancelled for j in jobs[:-1]) and not jobs[-1].cancelled
        qtbot.waitUntil(lambda: w._recut_job is None, timeout=60000)
        qtbot.wait(200)  # a cancelled worker that was mid-way hands nothing over
    assert event_loop_monitor.longest_ms < 500, event_loop_monitor.summary()
    assert shown == [(result.n_segments, 0.3)]
    np.testing.assert_array_equal(layer.data, result.labels_at(result.n_segments, threshold=0.3))
    assert w._status.value == (f"{int(layer.data.max())} segments shown "
                               f"(K = {result.n_segments})")
    assert w._job is job


def test_cancel_during_the_merging_is_prompt(merging_only, qtbot, cancel_latency):
    viewer, w = merging_only
    job = w.start()
    qtbot.waitUntil(lambda: w.updates >= 2 or job.done, timeout=300000)
    assert not job.done and w._status.value.startswith("merging")
    latency = cancel_latency(w, job, timeout=3.0)
    assert latency is not None, "the worker was still running 3 s after Cancel"
    print(f"cancel during the merging (1024x1024): {latency:.2f} s")
    assert [lay.name for lay in viewer.layers] == ["big"] and w._run.enabled
