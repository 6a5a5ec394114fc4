"""Every widget stays interactive on a large input, in a real napari viewer:
started through its own entry point, cancelled after about a second, the
worker is gone within 3 s, the button is back and the viewer's layers are as
before; the event loop never stalls for a second meanwhile.

The bounds are generous (CI on 2 loaded cores); ``benchmarks/bench_gui.py``
reports the real figures on 4000x4000. Each test first runs its widget to the
end on a small crop, so that Numba's compilation (a cold cache on CI) is not
counted as a pause.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
import pytest
from skimage import data as skdata
from skimage import io

from car_napari.io.sample_data import resource_path

pytest.importorskip("napari")

RUN_BEFORE_CANCEL = 1.0  # s
CANCEL_BOUND = 3.0  # s: "within 1 s" with room for a loaded CI machine
PAUSE_BOUND = 1000.0  # ms: a gross freeze fails; the benchmark gives the real figure
WARM_UP = 128  # px: the crop each widget first runs on


# --- inputs (shipped resources and scikit-image's images) --------------------------------

def _mirror_tile(texture, n):
    """``texture`` repeated by reflection (no seams), cropped to ``n x n``."""
    block = np.concatenate([texture, texture[::-1]], axis=0)
    block = np.concatenate([block, block[:, ::-1]], axis=1)
    reps = (-(-n // block.shape[0]), -(-n // block.shape[1])) + (1,) * (block.ndim - 2)
    return np.ascontiguousarray(np.tile(block, reps)[:n, :n])


def _textures():
    return [io.imread(resource_path("texture_vistex_VS50.png"))[..., :3],
            skdata.astronaut()[300:428, 0:128], skdata.coffee()[:200, :300],
            skdata.chelsea()[:150, :200]]


@functools.cache
def _mosaic(n):
    """Four real colour textures in the four quadrants of an ``n x n`` image (n even)."""
    h = n // 2
    tiles = [_mirror_tile(texture, h) for texture in _textures()]
    return np.concatenate([np.concatenate(tiles[:2], axis=1),
                           np.concatenate(tiles[2:], axis=1)])


def _noisy(image, seed, blur=0.0):
    from scipy import ndimage

    out = image.astype(np.float32)
    if blur:
        out = ndimage.gaussian_filter(out, (blur, blur, 0))
    out += np.random.default_rng(seed).normal(0, 12.0, out.shape).astype(np.float32)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


@functools.cache
def _film():
    """The shipped damaged film scan and its real mask, upsampled 2x (1056x1536)."""
    frame = io.imread(resource_path("film_cinestill50d_damaged.jpg"))[..., :3]
    mask = io.imread(resource_path("film_cinestill50d_mask.png"))
    mask = mask[..., :3].max(axis=2) if mask.ndim == 3 else mask
    if mask.shape != frame.shape[:2]:  # nearest-neighbour to the frame
        rows = np.arange(frame.shape[0]) * mask.shape[0] // frame.shape[0]
        cols = np.arange(frame.shape[1]) * mask.shape[1] // frame.shape[1]
        mask = mask[rows][:, cols]
    up = np.ones((2, 2, 1), np.uint8)
    return np.kron(frame, up), np.kron((mask > 127).astype(np.uint8), np.ones((2, 2), np.uint8))


def _mammogram(n):
    """The shipped mini-MIAS mdb001 (1024x1024), upsampled to ``n x n``."""
    from car_napari.io.sample_data import mammogram

    (image, _, _), = mammogram()
    k = max(1, n // image.shape[0])
    return np.kron(image, np.ones((k, k), image.dtype)) if k > 1 else image


# --- the widgets ---------------------------------------------------------------------------

def _crop(array, small, stack=False):
    if not small:
        return array
    return np.ascontiguousarray(array[:, :small, :small] if stack else array[:small, :small])


def _car(viewer, w, small):
    # 2048: at 1024 the fit (order chosen) ended after 0.98 s once, before the cancel
    w._image.value = viewer.add_image(_crop(_mosaic(2048), small), name="mosaic", rgb=True)
    return w.start_fit


def _segmentation(viewer, w, small):
    w._image.value = viewer.add_image(_crop(_mosaic(1024), small), name="mosaic", rgb=True)
    return w.start


def _mammography(viewer, w, small):
    image = _mammogram(2048)
    if small:  # the whole breast, block-averaged
        step = image.shape[0] // (2 * small)
        image = image.reshape(2 * small, step, 2 * small, step).mean(axis=(1, 3))
        image = image.astype(np.uint8)
    w._image.value = viewer.add_image(image, name="mammogram")
    return w.start


def _restoration(viewer, w, small):
    image = _noisy(_mosaic(2048), 0)
    w._image.value = viewer.add_image(_crop(image, small), name="noisy", rgb=True)
    single = [c for c in w._axis.choices if "single" in str(c)]
    w._axis.value = single[0]
    return w.start


def _burst(viewer, w, small):
    mosaic = _mosaic(1024)
    stack = np.stack([_noisy(mosaic, k, blur) for k, blur in enumerate((1.5, 0.5, 2.0, 1.0))])
    w._image.value = viewer.add_image(_crop(stack, small, stack=True), name="burst", rgb=True)
    assert "axis 0" in list(w._axis.choices), (
        f"the versions box offers {list(w._axis.choices)} for a (4, H, W, 3) stack")
    w._axis.value = "axis 0"
    return w.start


def _detect(viewer, w, small):
    frame, _ = _film()
    clip = np.stack([np.roll(frame, 7 * k, axis=1) for k in range(8)])  # a clip of 8 frames
    w._image.value = viewer.add_image(_crop(clip, small, stack=True), name="clip", rgb=True)
    return w.detect


def _restore(viewer, w, small):
    frame, mask = _film()
    frame, mask = _crop(frame, small), _crop(mask, small)
    if small is None:  # 2112x3072: a restore of the 2x frame alone can end within the 1 s
        frame, mask = np.tile(frame, (2, 2, 1)), np.tile(mask, (2, 2))
    if small:
        mask[:, small // 2] = 1  # a crop of a sparse mask may be empty
    layer = viewer.add_image(frame, name="film", rgb=True)
    labels = viewer.add_labels(mask, name="film scratch mask", opacity=0.6)
    for child in w:  # a mask picker, if the widget has one
        if "mask" in str(getattr(child, "label", "")).lower() and \
                labels in (getattr(child, "choices", None) or ()):
            child.value = labels
    w._image.value = layer
    return w.start


def _texture(viewer, w, small):
    w._image.value = viewer.add_image(_crop(_mosaic(2048), small), name="mosaic", rgb=True)
    w._mode.value = w._mode.choices[0]  # a single texture
    return w.start_fit


def _retrieval(viewer, w, small):
    # 2048: at 1024 the whole job took about the 1 s before the cancel
    query = viewer.add_image(_crop(_mosaic(2048), small), name="query", rgb=True)
    for k, texture in enumerate(_textures()[1:]):
        viewer.add_image(_crop(_mirror_tile(texture, 2048), small), name=f"gallery {k}",
                         rgb=True)
    w._image.value = query
    return w.start


@dataclass
class Case:
    id: str
    module: str
    cls: str
    button: str
    setup: object


CASES = [
    Case("car_model_fit", "car_model", "CARModelWidget", "_fit", _car),
    Case("segmentation", "segmentation", "SegmentationWidget", "_run", _segmentation),
    Case("mammogram_roi", "mammography", "MammogramWidget", "_run", _mammography),
    Case("restoration_single", "restoration", "RestorationWidget", "_run", _restoration),
    Case("restoration_burst", "restoration", "RestorationWidget", "_run", _burst),
    Case("scratch_detect", "inpainting", "InpaintingWidget", "_detect", _detect),
    Case("scratch_restore", "inpainting", "InpaintingWidget", "_run", _restore),
    Case("texture_fit", "texture", "TextureSynthesisWidget", "_fit", _texture),
    Case("retrieval", "retrieval", "TextureRetrievalWidget", "_run", _retrieval),
]


def _names(viewer):
    return [layer.name for layer in viewer.layers]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_cancel_on_a_large_input_is_prompt_and_the_viewer_responsive(
        case, docked, qtbot, event_loop_monitor, cancel_latency, last_notification):
    import importlib

    module = importlib.import_module(f"car_napari._widgets.{case.module}")
    viewer, w = docked(getattr(module, case.cls), case.id)
    button = getattr(w, case.button)
    # warm-up: the whole job on a small crop (Numba kernels compiled or loaded)
    job = case.setup(viewer, w, WARM_UP)()
    assert job is not None, last_notification()
    qtbot.waitUntil(lambda: job.done, timeout=300000)
    assert w._status.value != "failed", f"the warm-up failed: {last_notification()}"
    viewer.layers.clear()

    entry = case.setup(viewer, w, None)
    qtbot.wait(300)  # the viewer draws the new layers
    before = _names(viewer)
    with event_loop_monitor:
        t0 = time.perf_counter()
        job = entry()
        assert job is not None, last_notification()
        try:
            qtbot.waitUntil(lambda: job.done, timeout=int(RUN_BEFORE_CANCEL * 1000))
        except qtbot.TimeoutError:
            pass  # still running, as it should be
        assert not job.done, (f"the job ended after {time.perf_counter() - t0:.2f} s, before "
                              f"the cancel (status {w._status.value!r}): enlarge the input")
        latency = cancel_latency(w, job, timeout=CANCEL_BOUND)
        if latency is None:  # let the worker end before the viewer is closed
            status = w._status.value
            t1 = time.perf_counter()
            qtbot.waitUntil(lambda: job.done, timeout=600000)
            ended = time.perf_counter() - t1 + CANCEL_BOUND
            pytest.fail(f"the worker was still running {CANCEL_BOUND:g} s after Cancel "
                        f"(status {status!r}); it ended {ended:.1f} s after the click")
        qtbot.waitUntil(lambda: button.enabled, timeout=2000)
    print(f"{case.id}: cancel {latency:.2f} s, {event_loop_monitor.summary()}")
    assert not w._cancel.enabled
    assert _names(viewer) == before
    assert len(event_loop_monitor.gaps) > 20  # the event loop ran meanwhile
    assert event_loop_monitor.longest_ms < PAUSE_BOUND, event_loop_monitor.summary()
