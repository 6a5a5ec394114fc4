"""Clips by blocks of frames (car_napari._frames): every block sees the context
the whole-clip call gives its frames, so the outputs equal the in-memory ones,
and memory does not grow with the clip's length."""

import numpy as np
import pytest

from car_napari._frames import iter_frame_blocks, lazy_output
from car_napari._progress import Progress, drain, row_blocks
from car_napari.inpainting import descratch_frames, detect_scratches, inpaint, inpaint_frames
from car_napari.restoration import restore, restore_frames

_FILM = []


@pytest.fixture
def film(shared_data):
    """The 24 real archival film frames, grey uint8, a 64x80 piece with line
    scratches and dust."""
    from PIL import Image

    if not _FILM:
        files = sorted((shared_data / "old-film-clips" / "001").glob("*.png"))
        if len(files) < 24:
            pytest.skip("old-film-clips/001 not found")
        _FILM.append(np.stack([np.asarray(Image.open(f).convert("L"))[60:124, 180:260]
                               for f in files]))
    return _FILM[0]


def test_blocks_cover_the_clip():
    assert row_blocks(10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert row_blocks(3, 8) == [(0, 3)]


def test_each_block_gets_its_context_and_the_outputs_before_it():
    clip = np.random.default_rng(0).random((11, 3, 2))

    def job(block):  # a running sum (needs the output before) of a 3-frame mean
        yield Progress("work", 0.5)
        frames = block.frames
        padded = np.concatenate([frames[:1], frames, frames[-1:]])
        mean = (padded[:-2] + padded[1:-1] + padded[2:]) / 3
        if block.start == 0:  # the clip's ends: the frame itself stands in
            mean[0] = (2 * frames[0] + frames[1]) / 3
        if block.stop == block.total:
            mean[-1] = (frames[-2] + 2 * frames[-1]) / 3
        mean = mean[block.lead:len(frames) - block.trail]
        base = 0.0 if block.previous is None else block.previous[-1]
        return base + np.cumsum(mean, axis=0)

    out = np.zeros_like(clip)
    records = []
    assert drain(iter_frame_blocks(clip, job, out, block=3, before=1, after=1, carry=1),
                 records.append) == 11
    # plain NumPy on the whole clip
    padded = np.concatenate([clip[:1], clip, clip[-1:]])
    mean = (padded[:-2] + padded[1:-1] + padded[2:]) / 3
    np.testing.assert_allclose(out, np.cumsum(mean, axis=0), rtol=1e-12)
    written = [r.preview for r in records if r.preview is not None]
    assert written == [(0, 3), (3, 6), (6, 9), (9, 11)]
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0


def test_options_are_checked_up_front():
    clip = np.zeros((4, 8, 8))
    with pytest.raises(ValueError, match="block"):
        drain(iter_frame_blocks(clip, None, None, block=0))
    with pytest.raises(ValueError, match="carry must be an integer"):
        drain(iter_frame_blocks(clip, None, None, carry=1.5))
    with pytest.raises(ValueError, match="grey clip"):
        restore_frames(np.zeros((8, 8)), np.zeros((8, 8)))
    with pytest.raises(ValueError, match="mask has 3 frames"):
        inpaint_frames(clip, np.zeros((3, 8, 8)), np.zeros_like(clip))


def _damage(film):
    mask = np.zeros(film.shape, bool)
    for t in range(len(film)):
        mask[t, :, 20 + t % 9] = True
        if t % 4 == 1:
            mask[t, 30:38, 40:50] = True
    return mask


@pytest.mark.parametrize("temporal", [True, False])
def test_scratch_fill_by_blocks_equals_the_whole_clip(film, temporal):
    da = pytest.importorskip("dask.array")
    clip = film[:13]
    mask = _damage(clip)
    out = lazy_output(clip.shape, clip.dtype)  # zarr: what the widget writes into
    inpaint_frames(da.from_array(clip, chunks=(2, 64, 80)), da.from_array(mask), out,
                   block=5, temporal=temporal)
    whole = inpaint(clip, mask, channel_axis=None, temporal=temporal)
    np.testing.assert_array_equal(out[:], whole)
    assert not np.array_equal(whole, clip)


def test_descratch_by_blocks_equals_the_whole_clip(film):
    clip = film[:11]  # real dust and line scratches; blocks of 4 cut 2 boundaries
    restored = np.zeros_like(clip)
    masks = np.zeros(clip.shape, bool)
    descratch_frames(clip, restored, masks, block=4)
    found = detect_scratches(clip, channel_axis=None)
    assert found[1:-1].any()
    np.testing.assert_array_equal(masks, found)
    np.testing.assert_array_equal(restored, inpaint(clip, found, channel_axis=None))


def test_restore_by_frames_is_each_frame_restored(film):
    clip = film[:3, :40, :48]
    out = np.zeros(clip.shape, np.float32)
    probability = np.zeros(clip.shape, np.float32)
    restore_frames(clip, out, probability, neighbourhood=2)
    for t in range(3):
        result = restore(clip[t], neighbourhood=2, return_result=True)
        np.testing.assert_array_equal(out[t], result.restored()[..., 0].astype(np.float32))
        np.testing.assert_array_equal(probability[t], result.probability.astype(np.float32))


def test_colour_clip_by_frames():
    rng = np.random.default_rng(3)
    clip = rng.random((2, 24, 24, 3))
    out = np.zeros_like(clip)
    restore_frames(clip, out, channel_axis=-1)
    np.testing.assert_allclose(out[1], restore(clip[1]), rtol=0, atol=1e-12)
