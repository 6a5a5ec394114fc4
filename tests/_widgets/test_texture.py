"""The "Texture synthesis" widget in a real napari viewer."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._widgets.texture import TextureSynthesisWidget


@pytest.fixture
def widget(docked):
    return docked(TextureSynthesisWidget, "Texture synthesis")


def test_fit_synthesize_save_and_load(widget, qtbot, tmp_path, last_notification):
    viewer, w = widget
    w.start_synthesis()
    assert "fit a model first" in last_notification()
    texture = skdata.astronaut()[300:428, 0:128]  # grass, RGB
    layer = viewer.add_image(texture, name="grass")
    w._image.value = layer
    job = w.start_fit()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert w.model is not None and ":1" in w._model_info.value
    w._height.value, w._width.value, w._tileable.value = 150, 333, True
    job = w.start_synthesis()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["grass synthesis"].data
    assert out.shape == (150, 333, 3) and np.isfinite(out).all()
    np.testing.assert_array_equal(layer.data, texture)
    path = tmp_path / "grass.npz"
    w.save_model(path)
    assert path.exists()
    w.load_model(path)
    job = w.start_synthesis()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    np.testing.assert_array_equal(viewer.layers["texture model synthesis"].data, out)
    (tmp_path / "bad.npz").write_bytes(b"junk")
    w.load_model(tmp_path / "bad.npz")
    assert "not a readable" in last_notification()


def test_too_small_texture_is_a_notification(widget, qtbot, last_notification):
    viewer, w = widget
    w._image.value = viewer.add_image(np.random.default_rng(0).random((20, 20)), name="tiny")
    job = w.start_fit()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    assert "at least 64x64" in last_notification()
    assert w.model is None


def test_stack_modes_btf_and_dynamic(widget, qtbot, last_notification):
    from car_napari.io.sample_data import degraded_stack

    viewer, w = widget
    (stack, meta, _), = degraded_stack()
    layer = viewer.add_image(stack[:4, :96, :96], **meta)  # four "illuminations"
    w._image.value = layer
    assert w._mode.value.startswith("BTF")
    w._subspaces.value, w._levels.value = 2, 2
    job = w.start_fit()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert "BTF, 2 subspaces" in w._model_info.value
    w._height.value, w._width.value = 40, 50
    job = w.start_synthesis()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert viewer.layers["degraded burst synthesis"].data.shape == (4, 40, 50, 3)
    w._mode.value = "dynamic: frames"
    w._frames.value = 3
    job = w.start_fit()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert "dynamic" in w._model_info.value and not w._save.enabled
    job = w.start_synthesis()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert viewer.layers["degraded burst synthesis"].data.shape == (3, 40, 50, 3)
