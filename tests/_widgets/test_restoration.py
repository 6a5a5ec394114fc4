"""The "Restoration" widget in a real napari viewer."""

import time

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._progress import drain
from car_napari._widgets import restoration as restoration_widget
from car_napari._widgets.restoration import RestorationWidget
from car_napari.io.sample_data import degraded_stack


@pytest.fixture
def widget(docked):
    return docked(RestorationWidget, "Restoration")


@pytest.fixture(scope="module")
def burst():
    (stack, meta, _), = degraded_stack()
    return stack[:, :128, :128], meta


def noisy_camera(size=128):
    rng = np.random.default_rng(0)
    return skdata.camera()[:size, :size] / 255.0 + rng.normal(0, 0.05, (size, size))


def names(viewer):
    return [layer.name for layer in viewer.layers]


def test_stack_restores_live_and_kappa_rethresholds(widget, qtbot, burst):
    viewer, w = widget
    stack, meta = burst
    layer = viewer.add_image(stack, **meta)
    w._image.value = layer
    assert w._axis.value == "axis 0"  # guessed from the layer's shape
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=180000)
    assert w.updates >= 1  # the restored layer filled in before the end
    restored = viewer.layers["degraded burst restored"]
    probability = viewer.layers["degraded burst prediction probability"]
    assert restored.data.shape == stack.shape[1:] and restored.rgb
    assert probability.data.shape == stack.shape[1:3]
    assert 0 <= probability.data.min() and probability.data.max() <= 1
    assert w.result.reference is not None and "reference" in w._status.value
    # the layer shows the result as float32 (what napari puts on the screen)
    assert restored.data.dtype == np.float32 and probability.data.dtype == np.float32
    np.testing.assert_array_equal(restored.data, w.result.restored(float(w._kappa.value))
                                  .astype(np.float32))
    np.testing.assert_array_equal(layer.data, burst[0])  # input untouched
    # kappa: a re-threshold of the stored result in a worker, no new run;
    # moves in quick succession: the latest wins
    before = restored.data.copy()
    for kappa in (0.2, 0.4, 0.6):
        w._kappa.value = kappa
    assert w._job is job and w._recut_job is not None
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    after = viewer.layers["degraded burst restored"].data
    assert not np.array_equal(before, after)
    np.testing.assert_array_equal(after, w.result.restored(0.6).astype(np.float32))
    observed = w.result.observed.astype(np.float32)
    kept = w.result.probability <= 0.6
    np.testing.assert_array_equal(after[kept], observed[kept])
    # the changed-pixel toggle shows a labels layer and hides it again
    w._show_changed.value = True
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    changed = viewer.layers["degraded burst changed pixels"].data
    assert changed.shape == stack.shape[1:3] and 0 < changed.mean() < 1
    np.testing.assert_array_equal(changed, w.result.changed(0.6))
    w._show_changed.value = False
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    assert "degraded burst changed pixels" not in viewer.layers


def test_single_image_and_cancel(widget, qtbot):
    viewer, w = widget
    noisy = noisy_camera()
    layer = viewer.add_image(noisy, name="camera")
    w._image.value = layer
    assert w._axis.value == "single image"
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["camera restored"].data
    assert out.shape == noisy.shape and np.abs(out - noisy).std() > 0.01
    before = names(viewer)
    kept = out.copy()
    job = w.start()
    assert not w._kappa.enabled  # no re-threshold while a run writes the layers
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == before
    np.testing.assert_array_equal(viewer.layers["camera restored"].data, kept)
    np.testing.assert_array_equal(layer.data, noisy)
    assert w._kappa.enabled and w._show_changed.enabled  # the kept result re-thresholds
    # with the changed pixels shown: a cancel keeps the old ones, a run updates them
    w._show_changed.value = True
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    changed = viewer.layers["camera changed pixels"]
    old = changed.data.copy()
    before = names(viewer)
    job = w.start()
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == before
    np.testing.assert_array_equal(changed.data, old)
    w._order.value = 2
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == before
    np.testing.assert_array_equal(changed.data, w.result.changed(float(w._kappa.value)))
    assert not np.array_equal(changed.data, old)


def test_kappa_moves_re_cut_through_the_run_record(widget, qtbot):
    """Kappa moved several times quickly: the latest value wins, its layers
    are put as a run's (committed: an undo keeps them; a run cancelled after
    it comes back to them)."""
    viewer, w = widget
    layer = viewer.add_image(noisy_camera(), name="camera")
    w._image.value = layer
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    w._show_changed.value = True
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    before = names(viewer)
    restored, changed = viewer.layers["camera restored"], viewer.layers["camera changed pixels"]
    for kappa in (0.1, 0.2, 0.3, 0.4, 0.5):
        w._kappa.value = kappa
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    assert w._job is job and names(viewer) == before  # no run, the same layers
    fresh, fresh_changed, _ = drain(restoration_widget._iter_recut(w.result, 0.5, False, True))
    np.testing.assert_array_equal(restored.data, fresh)
    np.testing.assert_array_equal(changed.data, fresh_changed)
    assert viewer.layers["camera restored"] == restored
    w.record.undo()  # as after a run: the re-cut is committed, nothing to undo
    np.testing.assert_array_equal(viewer.layers["camera restored"].data, fresh)
    job = w.start()
    w.cancel()  # a cancelled run puts back the re-cut's layers
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == before
    np.testing.assert_array_equal(viewer.layers["camera restored"].data, fresh)
    np.testing.assert_array_equal(viewer.layers["camera changed pixels"].data, fresh_changed)


def test_restored_image_is_what_the_user_sees_first(widget, qtbot):
    """Defect a: the probability layer does not hide the restored image."""
    viewer, w = widget
    layer = viewer.add_image(noisy_camera(64), name="camera")
    w._image.value = layer
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == ["camera", "camera prediction probability", "camera restored"]
    restored = viewer.layers["camera restored"]
    probability = viewer.layers["camera prediction probability"]
    assert restored.visible and restored.opacity == 1.0  # on top, opaque, shown
    assert not probability.visible  # there to look at, hidden below
    assert viewer.layers.selection.active == restored
    assert "probability: hidden" in w._status.value
    # a second run keeps the arrangement the user made of the layers
    probability.visible = True
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == ["camera", "camera prediction probability", "camera restored"]
    assert probability.visible and viewer.layers.selection.active == restored


def test_versions_must_lie_along_a_stack_axis(widget, qtbot, last_notification):
    """Defect b: a spatial or colour axis cannot be the versions axis."""
    viewer, w = widget
    rng = np.random.default_rng(1)
    burst = rng.random((4, 32, 40, 3))
    layer = viewer.add_image(burst, name="burst", rgb=True)
    w._image.value = layer
    # only the axis the viewer's slider steps through is offered
    assert list(w._axis.choices) == ["single image", "axis 0"]
    assert w._axis.value == "axis 0"
    for axis in ("axis 1", "axis 2", "axis 3"):
        with pytest.raises(ValueError):
            w._axis.value = axis
    # the user rolls the view: the choice follows the slider's axis
    viewer.dims.order = (1, 0, 2)
    assert list(w._axis.choices) == ["single image", "axis 1"]
    assert w._axis.value == "axis 1"
    viewer.dims.order = (0, 1, 2)
    assert w._axis.value == "axis 0"
    # a stale choice (the view changed behind the widget's back) is refused at once
    with viewer.dims.events.order.blocker():
        viewer.dims.order = (2, 0, 1)  # axis 0 is now shown as the image's rows
    assert w._axis.value == "axis 0"
    t0 = time.perf_counter()
    assert w.start() is None
    assert time.perf_counter() - t0 < 1.0
    message = last_notification()
    assert "'versions' is axis 0" in message and "spatial axis" in message
    assert "'axis 2'" in message
    assert names(viewer) == ["burst"] and w._job is None


def test_order_says_what_its_default_is(widget, qtbot, monkeypatch):
    """Defect f (restoration): the order control says which value is the default."""
    viewer, w = widget
    assert w._order.value == 1 and w._order.native.currentText() == "1 (default)"
    labels = [w._order.native.itemText(k) for k in range(w._order.native.count())]
    assert labels == ["1 (default)", "2", "3", "4", "5"]
    assert "default" in w._order.tooltip
    asked = []

    def spy(image, **options):
        asked.append(options["neighbourhood"])
        return restoration_widget_iter_restore(image, **options)

    restoration_widget_iter_restore = restoration_widget.iter_restore
    monkeypatch.setattr(restoration_widget, "iter_restore", spy)
    w._image.value = viewer.add_image(noisy_camera(48), name="camera")
    w._order.value = 2
    assert w._order.native.currentText() == "2"
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert asked == [2] and "camera restored" in viewer.layers


def test_cancel_on_a_large_image_is_prompt(widget, qtbot):
    """Cancel ends the worker within about a second on a 2048 x 2048 RGB
    image (the strips yield between them), and leaves the viewer as it was."""
    viewer, w = widget
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (2048, 2048, 3), dtype=np.uint8)
    layer = viewer.add_image(image, name="large", rgb=True)
    w._image.value = layer
    before = names(viewer)
    # once during the local models (the longest stretch without a record),
    # once while the restored layer fills in
    for ready in (lambda: w._status.value != "starting", lambda: w.updates >= 1):
        job = w.start()
        qtbot.waitUntil(lambda job=job, ready=ready: job.done or ready(), timeout=120000)
        assert not job.done
        t0 = time.perf_counter()
        w._cancel.native.click()
        qtbot.waitUntil(lambda job=job: job.done, timeout=10000)
        latency = time.perf_counter() - t0
        assert latency < 3.0, f"the worker ran on {latency:.2f} s after Cancel"
        assert names(viewer) == before
        assert w._run.enabled and not w._cancel.enabled and w._status.value == "cancelled"
    np.testing.assert_array_equal(layer.data, image)


def test_cancel_of_a_burst(widget, qtbot):
    """Cancel ends a burst's worker promptly too (the 2.5D scans yield
    between directions), and leaves the viewer as it was."""
    viewer, w = widget
    rng = np.random.default_rng(3)
    scene = np.linspace(0.1, 0.9, 512)[:, None, None] * np.ones((512, 512, 3))
    stack = np.clip(scene + rng.normal(0, 0.05, (4, 512, 512, 3)), 0, 1).astype(np.float32)
    w._image.value = viewer.add_image(stack, name="burst", rgb=True)
    assert w._axis.value == "axis 0"
    before = names(viewer)
    job = w.start()
    qtbot.waitUntil(lambda: job.done or w._status.value.startswith("directions"),
                    timeout=120000)
    assert not job.done
    t0 = time.perf_counter()
    w._cancel.native.click()
    qtbot.waitUntil(lambda: job.done, timeout=10000)
    latency = time.perf_counter() - t0
    assert latency < 3.0, f"the worker ran on {latency:.2f} s after Cancel"
    assert names(viewer) == before and w._run.enabled and w._status.value == "cancelled"


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
    assert names(viewer) == ["flat stack"]


def test_large_image_previews_are_decimated_and_the_result_full(widget, qtbot, monkeypatch):
    """Issue 12: a large image's live previews are written decimated (a layer
    at scale f over the same extent), so the viewer's thread does little; the
    result replaces them at full resolution, on top and selected."""
    monkeypatch.setattr(restoration_widget, "PREVIEW_PIXELS", 32 * 32)  # 128x128: f = 4
    viewer, w = widget
    noisy = noisy_camera()
    viewer.add_image(noisy, name="camera")
    w._image.value = viewer.layers["camera"]
    seen = []
    show = w._show_running

    def spy(preview):
        show(preview)
        seen.append({x.name: (x.data.shape, tuple(x.scale)) for x in viewer.layers})

    w._show_running = spy  # (not monkeypatch: magicgui takes delattr for removing a widget)
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    small = {"camera": ((128, 128), (1.0, 1.0)), "camera restored": ((32, 32), (4.0, 4.0))}
    assert seen and all(s == small for s in seen)
    restored = viewer.layers["camera restored"]
    assert names(viewer) == ["camera", "camera prediction probability", "camera restored"]
    assert restored.data.shape == noisy.shape and tuple(restored.scale) == (1.0, 1.0)
    np.testing.assert_array_equal(restored.data, w.result.restored()[..., 0]
                                  .astype(np.float32))
    assert viewer.layers.selection.active == restored
    # a second run: the first result stays as it is, the previews in a layer of their
    # own, which the new result replaces
    seen.clear()
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert seen and all(s["camera restored (preview)"] == ((32, 32), (4.0, 4.0))
                        and s["camera restored"] == ((128, 128), (1.0, 1.0)) for s in seen)
    assert names(viewer) == ["camera", "camera prediction probability", "camera restored"]
    # a cancelled run leaves no preview behind
    job = w.start()
    qtbot.waitUntil(lambda: w.updates >= 1 or job.done, timeout=120000)
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert names(viewer) == ["camera", "camera prediction probability", "camera restored"]
    assert tuple(viewer.layers["camera restored"].scale) == (1.0, 1.0)


def test_decimation_keeps_every_fth_pixel():
    image = np.arange(10 * 7, dtype=np.float32).reshape(10, 7)
    small, f = restoration_widget._decimated(image, budget=20)
    assert f == 2 and small.flags.c_contiguous
    np.testing.assert_array_equal(small, image[::2, ::2])
    same, one = restoration_widget._decimated(image, budget=70)
    assert one == 1 and same is image


@pytest.mark.parametrize("kappa", [None, 0.0, 0.4])
def test_display_by_bands_is_the_whole_result_as_shown(monkeypatch, kappa):
    """The result turned into layer data by bands of rows (a record between
    them, so that a Cancel need not wait) equals the whole conversion."""
    from car_napari.restoration import restore

    monkeypatch.setattr(restoration_widget, "DISPLAY_ROWS", 7)
    rgb = np.stack([noisy_camera(40)] * 3, axis=-1)
    result = restore(rgb, channel_axis=-1, return_result=True)
    records = []
    restored, changed, probability = drain(
        restoration_widget._iter_recut(result, kappa, True, True), records.append)
    assert len(records) == 6  # ceil(40 / 7) bands
    np.testing.assert_array_equal(restored, result.restored(kappa).astype(np.float32))
    np.testing.assert_array_equal(changed, result.changed(kappa).astype(np.uint8))
    np.testing.assert_array_equal(probability, result.probability.astype(np.float32))


def test_grey_alpha_png_is_one_grey_image(widget, qtbot, last_notification):
    """Issue 32 item 9: a grey + alpha PNG (napari opens it as (H, W, 2)) is
    one grey image without its alpha, as the CLI reads it, with a note."""
    viewer, w = widget
    grey = noisy_camera(48)
    data = np.stack([grey, np.ones_like(grey)], axis=-1)  # grey + opaque alpha
    layer = viewer.add_image(data, name="la")
    assert not layer.rgb and layer.data.shape == (48, 48, 2)
    w._image.value = layer
    assert list(w._axis.choices) == ["single image"]  # not 48 versions of 48 x 2 images
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert "alpha" in last_notification() and "'la'" in last_notification()
    out = viewer.layers["la restored"].data
    assert out.shape == (48, 48) and not viewer.layers["la restored"].rgb
    np.testing.assert_array_equal(layer.data, data)  # input untouched


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
def test_integer_layer_keeps_its_dtype_and_range(widget, qtbot, dtype):
    """Issue 32 item 8: a uint16 (or uint8) layer is restored into a layer
    of its dtype and range, as the CLI writes it, not float32 in 0-1; a
    re-threshold keeps it."""
    from car_napari._validation import from_unit

    viewer, w = widget
    top = np.iinfo(dtype).max
    image = np.round(np.clip(noisy_camera(48), 0, 1) * top).astype(dtype)
    layer = viewer.add_image(image, name="int")
    w._image.value = layer
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    restored = viewer.layers["int restored"]
    assert restored.data.dtype == dtype and restored.data.shape == image.shape
    assert tuple(restored.contrast_limits) == (0.0, float(top))
    assert restored.data.max() > 0.5 * top  # the input's range, not 0-1
    np.testing.assert_array_equal(restored.data, from_unit(w.result.restored()[..., 0], dtype))
    w._kappa.value = 0.3
    qtbot.waitUntil(lambda: w._recut_job is None, timeout=30000)
    after = viewer.layers["int restored"].data
    assert after.dtype == dtype
    np.testing.assert_array_equal(after, from_unit(w.result.restored(0.3)[..., 0], dtype))
    np.testing.assert_array_equal(layer.data, image)
