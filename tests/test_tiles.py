"""Images larger than memory (issue 16, point 2): the tile grid, the tiled
restoration and inpainting against the in-memory calls, zarr and TIFF."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata

from car_napari._progress import drain
from car_napari._tiles import tile_grid
from car_napari.inpainting import inpaint, inpaint_large, iter_inpaint, iter_inpaint_frames
from car_napari.inpainting._tiled import iter_inpaint_tiles
from car_napari.restoration import estimate_noise, restore, restore_large, tile_halo
from car_napari.restoration._tiled import _iter_statistics


def _noisy(image, sigma, seed=0):
    rng = np.random.default_rng(seed)
    return np.clip(image / 255.0 + rng.normal(0, sigma, image.shape), 0, 1)


@pytest.fixture(scope="module")
def camera():
    return _noisy(skdata.camera()[100:300, 60:270].astype(float), 0.05)  # 200 x 210, real


def test_the_grid_covers_the_image_once_on_the_block_grid():
    shape = (300, 170)
    tiles = tile_grid(shape, 64, 40, align=16)  # both rounded up: 64, 48
    cover = np.zeros(shape, int)
    for t in tiles:
        cover[t.core] += 1
        assert t.r0 % 16 == 0 and t.c0 % 16 == 0 and t.a0 % 16 == 0 and t.b0 % 16 == 0
        assert t.a0 == max(0, t.r0 - 48) and t.a1 == min(300, t.r1 + 48)
        assert t.r1 - t.r0 >= 48 and t.c1 - t.c0 >= 48  # a short last tile is merged
    np.testing.assert_array_equal(cover, 1)


def test_the_global_noise_is_the_exact_median(camera):
    # an independent computation: scipy's convolution and np.median
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)
    response = np.abs(ndimage.convolve(camera, kernel))[1:-1, 1:-1]
    expected = np.median(response) / (6 * 0.6745)
    summary, noise = drain(_iter_statistics(camera, True, 48, (0.0, 1.0)))
    assert noise[0] == pytest.approx(expected, rel=1e-12)
    assert noise[0] == pytest.approx(estimate_noise(camera)[0], rel=1e-12)
    assert summary.mean[0] == pytest.approx(camera.mean(), rel=1e-12)
    assert summary.var[0] == pytest.approx(camera.var(), rel=1e-12)


@pytest.mark.parametrize("options", [{}, {"neighbourhood": 2, "window": 30, "kappa": 0.2},
                                     {"keep_edges": False}])
def test_tiled_restore_equals_the_in_memory_one(camera, options):
    expected = restore(camera, **options)
    got = restore_large(camera, tile=48, **options)  # many tiles, short last ones
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)


def test_tiled_restore_of_colour_integers_from_dask_and_zarr(tmp_path):
    da = pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    from car_napari.io.arrays import create_array, open_array

    colour = skdata.astronaut()[:150, 100:260]  # uint8, real
    expected = restore(colour)
    lazy = restore_large(da.from_array(colour, chunks=(50, 70, 3)), tile=64)
    assert isinstance(lazy, da.Array)
    np.testing.assert_allclose(lazy.compute(), expected, rtol=0, atol=1e-6)
    store = create_array(tmp_path / "in.zarr", colour.shape, np.uint8, chunks=40)
    store[:] = colour
    out = create_array(tmp_path / "out.zarr", colour.shape, np.float64, chunks=40)
    restore_large(open_array(tmp_path / "in.zarr"), out=out, tile=64)
    np.testing.assert_allclose(open_array(tmp_path / "out.zarr")[:], expected, rtol=0,
                               atol=1e-6)


def test_a_lazy_restore_passes_forgetting_on(camera, monkeypatch):
    """``restore`` and ``iter_restore`` of a dask image pass ``forgetting``
    to the tiles (they dropped it): checked as for an image in memory, the
    windowed result the same whatever its value."""
    da = pytest.importorskip("dask.array")
    from car_napari.restoration import _restore, iter_restore

    lazy = da.from_array(camera, chunks=(100, 105))
    for bad in (0.2, 2.0):
        with pytest.raises(ValueError, match="forgetting"):
            restore(camera, forgetting=bad)
        with pytest.raises(ValueError, match="forgetting"):
            restore(lazy, forgetting=bad)
        with pytest.raises(ValueError, match="forgetting"):
            drain(iter_restore(lazy, forgetting=bad))
    seen = []
    passed_on = _restore.iter_restore_large

    def spy(image, **options):
        seen.append(options["forgetting"])
        return passed_on(image, **options)

    monkeypatch.setattr(_restore, "iter_restore_large", spy)
    restored = restore(lazy, forgetting=0.9)
    assert seen == [0.9]
    np.testing.assert_array_equal(np.asarray(restored), np.asarray(restore(lazy)))


def test_what_is_not_tile_local_is_refused(camera):
    with pytest.raises(ValueError, match="estimator='recursive' cannot run by tiles"):
        restore_large(camera, estimator="recursive")
    with pytest.raises(ValueError, match="neighbourhood='auto'"):
        restore_large(camera, neighbourhood="auto")
    with pytest.raises(ValueError, match="channel_axis=-1"):
        restore_large(np.zeros((3, 40, 40)), channel_axis=0)
    with pytest.raises(ValueError, match="constant"):
        restore_large(np.ones((60, 60)), tile=32)


def test_the_halo_is_enough_and_one_block_less_is_not(camera):
    from car_napari.model.neighbourhood import as_offsets
    from car_napari.restoration._tiled import CORNERS, _restore_part

    halo = tile_halo(48, 1)
    assert halo == 48  # blocks of 16: two blocks and the reach, rounded up
    summary, noise = drain(_iter_statistics(camera, True, 64, (0.0, 1.0)))
    options = dict(mean=summary.mean, var=summary.var, noise=noise, offsets=as_offsets(1)[0],
                   directions=CORNERS, window=48, keep_edges=True, kappa=0.0)
    full = restore(camera)
    core = slice(96, 144)
    for h, enough in ((halo, True), (halo - 16, False)):
        part = _restore_part(camera[96 - h : 144 + h, 96 - h : 144 + h], **options)
        same = np.allclose(part[h:-h, h:-h], full[core, core], rtol=0, atol=1e-6)
        assert same == enough


def _clip():
    base = skdata.camera()[:72, :96]  # real, moving two pixels a frame
    clip = np.stack([np.roll(base, 2 * t, axis=1) for t in range(3)])
    mask = np.zeros(clip.shape, bool)
    mask[:, 20:50, 40:43] = True
    mask[1] = False  # an undamaged frame in the middle
    return clip, mask


def test_a_clip_frame_by_frame_is_the_in_memory_fill():
    clip, mask = _clip()
    np.testing.assert_array_equal(inpaint_large(clip, mask), inpaint(clip, mask))
    colour = np.stack([np.roll(skdata.astronaut()[:60, :80], 2 * t, axis=1) for t in range(2)])
    cmask = np.zeros(colour.shape[:3], bool)
    cmask[:, 20:40, 30:32] = True
    np.testing.assert_array_equal(inpaint_large(colour, cmask, temporal=True),
                                  inpaint(colour, cmask))


def test_a_zarr_clip_is_filled_into_zarr(tmp_path):
    pytest.importorskip("zarr")
    from car_napari.io.arrays import create_array, open_array

    clip, mask = _clip()
    store = create_array(tmp_path / "clip.zarr", clip.shape, clip.dtype, chunks=32)
    store[:] = clip
    out = create_array(tmp_path / "out.zarr", clip.shape, clip.dtype, chunks=32)
    drain(iter_inpaint_frames(open_array(tmp_path / "clip.zarr"), mask, out,
                              channel_axis=None))
    np.testing.assert_array_equal(open_array(tmp_path / "out.zarr")[:], inpaint(clip, mask))


def test_a_frame_by_tiles_keeps_the_known_pixels_and_copies_clean_tiles():
    frame = skdata.camera()[:160, :160]
    mask = np.zeros(frame.shape, bool)
    mask[10:40, 20:23] = True  # damage in the first tile only
    got = drain(iter_inpaint_tiles(frame, mask, tile=80, tile_halo=32))
    np.testing.assert_array_equal(got[~mask], frame[~mask])
    alone = inpaint(frame[:112, :112], mask[:112, :112])  # the first tile with its halo
    np.testing.assert_array_equal(got[mask], alone[mask[:112, :112]])


def test_a_large_frame_is_filled_by_the_same_tiles_in_memory_and_from_dask(monkeypatch):
    """A frame larger than DEFAULT_TILE is defined by its tiles: in memory
    and from a dask array the same tiles run the same code (smaller tiles
    here, for time), so the two are equal; a scratch crosses every tile."""
    da = pytest.importorskip("dask.array")
    from car_napari.inpainting import _tiled

    monkeypatch.setattr(_tiled, "DEFAULT_TILE", 64)
    monkeypatch.setattr(_tiled, "DEFAULT_HALO", 24)
    frame = skdata.astronaut()[:150, 100:250]
    mask = np.zeros(frame.shape[:2], bool)
    mask[:, 70:73] = True  # down the whole frame, across two tile rows
    mask[100:104, 20:130] = True
    in_memory = inpaint(frame, mask)
    lazy = inpaint(da.from_array(frame, chunks=(50, 50, 3)), mask)
    np.testing.assert_array_equal(lazy, in_memory)
    np.testing.assert_array_equal(in_memory[~mask], frame[~mask])
    # what defines it: each tile with its halo filled alone, its core kept
    first = inpaint(frame[:88, :88], mask[:88, :88])
    np.testing.assert_array_equal(in_memory[:64, :64], first[:64, :64])
    from car_napari.inpainting._filling import iter_inpaint_in_memory

    one_solve = drain(iter_inpaint_in_memory(frame, mask))
    assert not np.array_equal(one_solve, in_memory)  # the tiles are in effect
    records = []
    drain(iter_inpaint(frame, mask), records.append)
    assert records[-1].preview[0] == 0
    np.testing.assert_array_equal(records[-1].preview[1], in_memory)
    assert all(r.preview is None for r in records[:-1])  # no tile passes for the frame


def test_the_names_before_issue_33_still_work():
    from car_napari import restoration

    assert restoration.restore_tiled is restoration.restore_large
    assert restoration.iter_restore_tiled is restoration.iter_restore_large
