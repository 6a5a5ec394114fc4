"""Lazy (dask) clips in the Restoration and Scratch restoration widgets, in a
real viewer: processed by blocks of frames into zarr, the output a dask layer,
equal to the in-memory result, memory independent of the clip's length."""

import tracemalloc

import numpy as np
import pytest

da = pytest.importorskip("dask.array")
pytest.importorskip("zarr")

from car_napari._widgets.inpainting import InpaintingWidget  # noqa: E402
from car_napari._widgets.restoration import FRAMES, RestorationWidget  # noqa: E402
from car_napari.inpainting import inpaint  # noqa: E402
from car_napari.restoration import restore  # noqa: E402

ROWS, COLS = slice(100, 140), slice(200, 248)  # a small piece of real film: runs in seconds


_FILM = []


@pytest.fixture
def film(shared_data):
    """24 real archival film frames (grey uint8, 40x48), read once."""
    from PIL import Image

    if _FILM:
        return _FILM[0]
    files = sorted((shared_data / "old-film-clips" / "001").glob("*.png"))
    if len(files) < 24:
        pytest.skip("old-film-clips/001 not found")
    frames = [np.asarray(Image.open(f).convert("L"))[ROWS, COLS] for f in files]
    _FILM.append(np.stack(frames))
    return _FILM[0]


def lazy_clip(film, n_frames):
    """A dask clip of ``n_frames`` (the real frames repeated), a chunk a frame."""
    return da.from_array(film, chunks=(1, *film.shape[1:]))[np.arange(n_frames) % len(film)]


def scratches(film, n_frames):
    """A real-looking damage mask per frame: a line that drifts, a blotch now and then."""
    mask = np.zeros((n_frames, *film.shape[1:]), np.uint8)
    for t in range(n_frames):
        mask[t, :, 10 + t % 7] = 1
        if t % 5 == 2:
            mask[t, 20:25, 30:36] = 1
    return mask


def test_restoration_of_a_lazy_clip_is_each_frame_restored(docked, qtbot, film):
    viewer, w = docked(RestorationWidget, "Restoration")
    clip = lazy_clip(film, 5)
    layer = viewer.add_image(clip, name="film")
    w._image.value = layer
    assert w._axis.value == FRAMES  # guessed: a lazy clip is restored frame by frame
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    restored = viewer.layers["film restored"]
    assert isinstance(restored.data, da.Array)  # lazy: a dask array over a zarr store
    expected = np.stack([restore(f, keep_edges=True) for f in film[:5]]).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(restored.data), expected)
    probability = viewer.layers["film prediction probability"]
    assert not probability.visible and probability.data.shape == clip.shape
    assert viewer.layers.selection.active == restored  # what the user sees first
    assert [x.name for x in viewer.layers][-1] == "film restored"
    assert not w._kappa.enabled  # nothing in memory to re-threshold


def test_scratch_restoration_of_a_lazy_clip_equals_the_in_memory_one(docked, qtbot, film):
    viewer, w = docked(InpaintingWidget, "Scratch restoration")
    n = 19  # blocks of 8, 8, 3: two boundaries the temporal context crosses
    clip = lazy_clip(film, n)
    mask = scratches(film, n)
    viewer.add_image(clip, name="film")
    viewer.add_labels(da.from_array(mask, chunks=(1, *mask.shape[1:])), name="film scratch mask")
    w._image.value = viewer.layers["film"]
    w._temporal.value = True
    step = viewer.dims.current_step
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=60000)
    restored = viewer.layers["film restored"]
    assert isinstance(restored.data, da.Array)
    expected = inpaint(np.asarray(clip), mask.astype(bool), channel_axis=None)
    np.testing.assert_array_equal(np.asarray(restored.data), expected)
    assert w.updates >= 1
    assert viewer.dims.current_step == step  # the viewer stayed put


def test_new_mask_layer_of_a_lazy_clip_is_on_disk(docked, film):
    viewer, w = docked(InpaintingWidget, "Scratch restoration")
    viewer.add_image(lazy_clip(film, 30), name="film")
    w._image.value = viewer.layers["film"]
    mask = w.mask_layer()
    assert mask.data.shape == (30, *film.shape[1:]) and not isinstance(mask.data, np.ndarray)
    mask.data_setitem((np.array([3]), np.array([4]), np.array([5])), 1)  # a brush stroke
    assert np.asarray(mask.data[3])[4, 5] == 1


def test_cancel_of_a_lazy_clip_undoes_the_run(docked, qtbot, film):
    viewer, w = docked(InpaintingWidget, "Scratch restoration")
    n = 200
    viewer.add_image(lazy_clip(film, n), name="film")
    mask = np.zeros(film.shape[1:], np.uint8)
    mask[:, 11] = 1
    viewer.add_labels(mask, name="film scratch mask")
    w._image.value = viewer.layers["film"]
    job = w.start()
    qtbot.waitUntil(lambda: w.updates >= 1, timeout=60000)
    assert "film restored" in viewer.layers
    w.cancel()
    qtbot.waitUntil(lambda: job.done, timeout=1000)  # the worker gone within a second
    assert [x.name for x in viewer.layers] == ["film", "film scratch mask"]


def _peak(run):
    """The peak of the memory traced while ``run()`` runs (bytes over the start)."""
    tracemalloc.start()
    try:
        start, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        run()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak - start


@pytest.mark.parametrize("kind", ["scratches"])  # restoration: tests/test_frames.py
def test_memory_does_not_grow_with_the_clip(docked, qtbot, film, kind):
    """A lazy 200-frame clip peaks within 20 % of the 50-frame clip's memory
    (all the memory Python and NumPy allocate, the viewer's too), as issue
    16 asks. Measured: 1.12x (4.0 and 4.5 MB); a clip held whole, even as
    40x48 float64 frames, would add 3 MB."""
    if kind == "scratches":
        viewer, w = docked(InpaintingWidget, "Scratch restoration")
        mask = np.zeros(film.shape[1:], np.uint8)
        mask[:, 11] = 1
        viewer.add_labels(mask, name="mask")
    else:
        viewer, w = docked(RestorationWidget, "Restoration")

    def run(n):
        if "film" in viewer.layers:
            viewer.layers.remove("film")
        for name in [x.name for x in viewer.layers if x.name.startswith("film ")]:
            viewer.layers.remove(name)
        viewer.add_image(lazy_clip(film, n), name="film")
        w._image.value = viewer.layers["film"]
        if kind == "scratches":
            w._mask.value = viewer.layers["mask"]
        job = w.start()
        qtbot.waitUntil(lambda: job.done, timeout=120000)
        assert viewer.layers["film restored"].data.shape[0] == n

    run(12)  # warm-up: the kernels loaded, the viewer's first layers drawn
    # the lower of two peaks each: a collection that comes late in one run
    # (a CI run once measured 1.21x) is not the clip's length
    short = min(_peak(lambda: run(50)) for _ in range(2))
    long = min(_peak(lambda: run(200)) for _ in range(2))
    assert long <= 1.2 * short, (short, long)
