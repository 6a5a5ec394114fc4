"""Masks of another size (fit_mask); the detector and the fill in bands and
chunks (a record every fraction of a second on a large frame, so that a
Cancel is quick): the same results, bit for bit, whatever the sizes."""

import numpy as np
import pytest
from scipy import ndimage

from car_napari._progress import drain
from car_napari.inpainting import (
    _detection,
    _filling,
    detect_scratches,
    fit_mask,
    inpaint,
    iter_detect_scratches,
    iter_inpaint,
)


def _nearest(mask, H, W):
    """Nearest neighbour by pixel centres, one pixel at a time."""
    h, w = mask.shape[-2:]
    out = np.zeros(mask.shape[:-2] + (H, W), bool)
    for i in range(H):
        for j in range(W):
            out[..., i, j] = mask[..., int((i + 0.5) * h / H), int((j + 0.5) * w / W)]
    return out


def test_fit_mask_resizes_by_nearest_neighbour():
    rng = np.random.default_rng(0)
    small = rng.integers(0, 3, (7, 11)).astype(np.uint8)  # labels: any non-zero is damage
    for H, W in [(7, 11), (14, 22), (20, 13), (3, 5), (1, 1)]:
        got = fit_mask(small, (H, W))
        assert got.dtype == bool and got.shape == (H, W)
        np.testing.assert_array_equal(got, _nearest(small != 0, H, W))
    # an integer upscale repeats each pixel, and back again is exact
    big = np.repeat(np.repeat(small != 0, 3, axis=0), 3, axis=1)
    np.testing.assert_array_equal(fit_mask(small, (21, 33)), big)
    np.testing.assert_array_equal(fit_mask(big, (7, 11)), small != 0)
    same = small != 0
    assert fit_mask(same, same.shape) is not same  # a new array


def test_fit_mask_colour_and_clips():
    rgb = np.zeros((4, 6, 3), np.uint8)
    rgb[1, 2, 1] = 9  # damaged when any channel is non-zero
    got = fit_mask(rgb, (8, 12), channel_axis=-1)
    assert got.sum() == 4 and got[2:4, 4:6].all()
    first = np.moveaxis(rgb, -1, 0)
    np.testing.assert_array_equal(fit_mask(first, (8, 12), channel_axis=0), got)
    # one mask for all frames of a clip, or one per frame
    assert fit_mask(rgb[..., 1], (5, 8, 12)).shape == (8, 12)
    per_frame = np.stack([rgb[..., 1], np.zeros((4, 6), np.uint8)])
    fitted = fit_mask(per_frame, (2, 8, 12))
    assert fitted.shape == (2, 8, 12) and fitted[0].sum() == 4 and not fitted[1].any()
    assert fit_mask(np.ones((1, 3, 3)), (6, 6)).shape == (6, 6)  # one frame for a frame


def test_fit_mask_errors():
    with pytest.raises(ValueError, match="3 frames, for a clip of 2"):
        fit_mask(np.zeros((3, 4, 4)), (2, 8, 8))
    with pytest.raises(ValueError, match="for a single frame"):
        fit_mask(np.zeros((3, 4, 4)), (8, 8))
    with pytest.raises(TypeError, match="boolean or numeric"):
        fit_mask(np.array([["a"]]), (2, 2))
    with pytest.raises(ValueError, match="empty"):
        fit_mask(np.zeros((0, 4)), (2, 2))
    with pytest.raises(ValueError, match=r"\(h, w\) or \(t, h, w\)"):
        fit_mask(np.zeros((2, 2, 2, 2)), (2, 2))
    with pytest.raises(ValueError, match="colour mask"):
        fit_mask(np.zeros((4, 4)), (2, 2), channel_axis=-1)
    with pytest.raises(ValueError, match="positive"):
        fit_mask(np.zeros((4, 4)), (0, 2))


# --- the detector in bands -----------------------------------------------------------


def _reference_lines(g, w, length, threshold):
    """The line test on a whole frame at once (the detector before bands)."""
    left = g[:, w:-w] - g[:, : -2 * w]
    right = g[:, w:-w] - g[:, 2 * w :]
    both = np.where(left * right > 0, np.sign(left) * np.minimum(np.abs(left),
                                                                 np.abs(right)), 0.0)
    contrast = np.zeros_like(g)
    contrast[:, w:-w] = both
    scale = 1.4826 * np.median(np.abs(g[:, 1:] - g[:, :-1])) + 1e-12
    strong = np.abs(contrast) > threshold * scale
    signed = np.sign(contrast) * strong
    along = ndimage.uniform_filter1d(signed, length, axis=0, mode="nearest")
    lines = strong & (np.abs(along) > 0.5) & (np.sign(along) == np.sign(contrast))
    return ndimage.binary_dilation(lines, structure=np.ones((1, 3), bool))


def _reference_blotches(before, frame, after, threshold):
    prev_diff, next_diff = frame - before, frame - after
    spikes = (np.sign(prev_diff) == np.sign(next_diff)) & (
        np.minimum(np.abs(prev_diff), np.abs(next_diff)) > threshold)
    spikes = ndimage.binary_opening(spikes, structure=np.ones((2, 2), bool))
    return ndimage.binary_dilation(spikes, structure=np.ones((3, 3), bool))


def _damaged_clip(T=4, H=90, W=70, colour=True, seed=0):
    rng = np.random.default_rng(seed)
    shape = (T, H, W, 3) if colour else (T, H, W)
    clip = ndimage.uniform_filter(rng.random(shape), 3) * 0.6 + 0.2
    clip[:, :, 20:22] += 0.3  # line scratches
    clip[:, 10:, 45] -= 0.25
    clip[1:-1] += (rng.random(shape[1:]) > 0.985) * 0.5  # blotches
    clip[2, 30:36, 50:58] = 1.0
    return np.clip(clip, 0, 1)


@pytest.mark.parametrize("band", [1, 50, 333, 4096, 1 << 19])
def test_detector_in_bands_equals_the_whole_frame_at_once(monkeypatch, band):
    clip = _damaged_clip()
    grey = clip.mean(axis=-1)
    T, H, W = grey.shape
    expected = np.zeros(grey.shape, bool)
    for t in range(T):
        expected[t] = _reference_lines(grey[t], 3, max(3, int(0.5 * H) | 1), 4.0)
    for t in range(1, T - 1):
        expected[t] |= _reference_blotches(grey[t - 1], grey[t], grey[t + 1], 0.12)
    assert expected.any() and expected[2, 30:36, 50:58].all()
    monkeypatch.setattr(_detection, "BAND_PIXELS", band)
    # the raw neighbours (SDIa); the motion-compensated test: tests/inpainting/test_motion.py
    np.testing.assert_array_equal(detect_scratches(clip, motion=False), expected)
    single = detect_scratches(clip[2])  # a frame: lines only
    np.testing.assert_array_equal(single, _reference_lines(grey[2], 3, 45, 4.0))


def test_a_large_frame_reports_after_each_band(monkeypatch):
    clip = _damaged_clip(T=3, H=120, W=100, colour=False)
    monkeypatch.setattr(_detection, "BAND_PIXELS", 1000)  # 10 rows or columns a band
    records = []
    banded = drain(iter_detect_scratches(clip, motion=False), records.append)
    monkeypatch.setattr(_detection, "BAND_PIXELS", 1 << 19)
    whole = []
    np.testing.assert_array_equal(banded, drain(iter_detect_scratches(clip, motion=False),
                                                whole.append))
    # a whole frame fits one band: one record a frame, as before
    assert [r.stage for r in whole] == ["lines"] * 3 + ["blotches"]
    assert [r.message for r in whole] == ["frame 1/3", "frame 2/3", "frame 3/3", "frame 2/3"]
    # in bands: records between them, each stage named, the fraction by the work done
    assert len(records) > 100
    assert {r.stage for r in records} == {"reading", "lines", "blotches"}
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    steps = np.diff([0.0] + fractions)
    passes = 3 + 5 * 3 + 2 * 1  # reading, the line passes, the blotch test (twice a pass)
    assert steps.max() <= 1 / passes + 1e-12  # at most one pass (the median) between records
    # closing the job between two bands (a Cancel) stops it
    job = iter_detect_scratches(clip)
    monkeypatch.setattr(_detection, "BAND_PIXELS", 1000)
    next(job)
    job.close()


def test_detector_errors():
    with pytest.raises(ValueError, match="empty"):
        detect_scratches(np.zeros((0, 10)))
    with pytest.raises(ValueError, match="NaN"):
        bad = np.zeros((20, 20))
        bad[5, 5] = np.nan
        detect_scratches(bad)


# --- the fill in chunks --------------------------------------------------------------


def _fill_cases():
    rng = np.random.default_rng(1)
    colour = (ndimage.uniform_filter(rng.random((70, 90, 3)), (3, 3, 1)) * 255).astype(np.uint8)
    mask = np.zeros((70, 90), bool)
    mask[:, 30:33] = mask[40:50, 60:75] = mask[:2, :] = True
    colour[mask] = 255
    grey = ndimage.uniform_filter(rng.random((60, 64)), 3)
    gmask = np.zeros((60, 64), bool)
    gmask[:, 10:12] = gmask[20:30, 40:44] = True
    clip = np.stack([np.roll(colour, 3 * t, axis=1) for t in range(3)])
    cmask = np.stack([np.roll(mask, 7 * t, axis=1) for t in range(3)])
    return [
        (colour, mask, {}),
        (colour, mask, {"neighbourhood": 2, "halo": None}),
        (grey, gmask, {"channel_axis": None}),
        (clip, cmask, {}),
        (clip, cmask, {"temporal": False}),
        (clip[..., 0], cmask, {"channel_axis": None}),
    ]


def test_fill_in_chunks_and_bands_equals_the_fill_in_one_go(monkeypatch):
    """Scans resumed every row or two and the whole-frame passes cut into
    bands of a few rows give, bit for bit, the fill of one kernel call per
    scan and one pass per step."""
    whole = [inpaint(image, mask, **options) for image, mask, options in _fill_cases()]
    for chunk, band, every in [(64, 50, 1), (300, 700, 2000)]:
        monkeypatch.setattr(_filling, "SCAN_CHUNK_PIXELS", chunk)
        monkeypatch.setattr(_filling, "BAND_PIXELS", band)
        monkeypatch.setattr(_filling, "PASS_RECORD_PIXELS", every)
        for (image, mask, options), expected in zip(_fill_cases(), whole, strict=True):
            records = []
            got = drain(iter_inpaint(image, mask, **options), records.append)
            np.testing.assert_array_equal(got, expected)
            fractions = [r.fraction for r in records]
            assert fractions == sorted(fractions) and fractions[-1] == 1.0
            assert all(r.stage == "frames" and r.message.startswith("frame ") for r in records)


def test_a_large_frame_reports_every_chunk_of_its_scans(monkeypatch):
    image, mask, _ = _fill_cases()[0]
    monkeypatch.setattr(_filling, "SCAN_CHUNK_PIXELS", 2 * 94)  # two scan rows a chunk
    monkeypatch.setattr(_filling, "BAND_PIXELS", 10 * 90)
    monkeypatch.setattr(_filling, "PASS_RECORD_PIXELS", 10 * 90)
    records = []
    drain(iter_inpaint(image, mask, method="scans"), records.append)
    scans = [r for r in records if ", scan " in r.message]
    # (70 + 4) rows down and up, (90 + 4) columns right and left, about 2 a chunk
    assert len(scans) >= (2 * 74 + 2 * 94) // 4
    assert any("preparing" in r.message for r in records)
    assert any("combining" in r.message for r in records)
    # closing the job between two chunks (a Cancel) stops it, its threads too
    import threading

    before = threading.active_count()
    job = iter_inpaint(image, mask, method="scans")
    while ", scan " not in next(job).message:
        pass
    job.close()
    assert threading.active_count() <= before


def test_the_banded_passes_are_the_whole_frame_passes():
    rng = np.random.default_rng(2)
    for C in (1, 2, 3, 4):
        frame = rng.random((37, 23, C)) * np.exp(rng.normal(0, 4, (37, 23, C)))
        mask = rng.random((37, 23)) > 0.7
        known = frame[~mask]
        for band in (1, 7, 10000):
            old = _filling.BAND_PIXELS
            _filling.BAND_PIXELS = band
            try:
                stats = drain(_filling._iter_known_statistics(frame, mask, _filling._Meter(),
                                                              ""))
            finally:
                _filling.BAND_PIXELS = old
            expected = (known.mean(axis=0), known.var(axis=0), known.min(axis=0),
                        known.max(axis=0))
            for got, want in zip(stats, expected, strict=True):
                np.testing.assert_array_equal(got, want)
    for pad in (0, 1, 2, 3):
        padded = np.zeros((12 + 2 * pad, 9 + 2 * pad, 2))
        inner = rng.random((12, 9, 2))
        padded[pad : pad + 12, pad : pad + 9] = inner
        _filling._reflect_edges(padded, pad)
        np.testing.assert_array_equal(padded, np.pad(inner, ((pad, pad), (pad, pad), (0, 0)),
                                                     mode="reflect"))
    mask = rng.random((15, 11)) > 0.5
    mask[3] = True  # a row without a known pixel
    reference = np.zeros(mask.shape)
    run = np.full(15, 11.0)
    for j in range(11):
        run = np.where(mask[:, j], run + 1.0, 0.0)
        reference[:, j] = run
    for view in (mask, mask.T.copy().T, mask[::-1][::-1]):
        np.testing.assert_array_equal(_filling._side_distance(view), reference)


def test_fit_mask_inverts_a_black_hole_mask():
    white = np.array([[0, 255, 0], [0, 0, 0]], np.uint8)
    np.testing.assert_array_equal(fit_mask(255 - white, (2, 3), invert=True), white != 0)
    np.testing.assert_array_equal(fit_mask(255 - white, (4, 6), invert=True),
                                  fit_mask(white, (4, 6)))
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[0, 0, 2] = 9  # one channel set: known under invert
    assert not fit_mask(rgb, (2, 3), channel_axis=-1, invert=True)[0, 0]
    with pytest.raises(TypeError, match="invert must be True or False"):
        fit_mask(white, (2, 3), invert="yes")


def test_a_mostly_masked_frame_warns_before_the_fill():
    from car_napari import inpaint

    frame = np.random.default_rng(0).random((24, 24))
    mask = np.ones((24, 24), bool)
    mask[:6] = False
    with pytest.warns(UserWarning, match=r"covers 75\.0 % of the frame.*invert=True"):
        inpaint(frame, mask)
    with pytest.warns(UserWarning, match=r"covers 75\.0 % of frame 1"):
        inpaint(np.stack([frame, frame]), np.stack([~mask, mask]), channel_axis=None)


def test_back_to_the_input_dtype_rounds_half_to_even_and_clips():
    """Integer dtypes: the nearest integer (ties to even, as Python's round)
    clipped to the dtype's range; float dtypes: the nearest value of the
    dtype (float32 by struct's IEEE rounding)."""
    import struct

    values = np.array([-300.4, -128.5, -0.5, 0.5, 1.5, 2.5, 2.4999, 2.5001, 127.5,
                       254.5, 255.5, 256.0, 1e300, -1e300, 40000.0, 65535.5, 1 / 3])
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.int32):
        lo, hi = int(np.iinfo(dtype).min), int(np.iinfo(dtype).max)
        expected = [min(max(round(v), lo), hi) for v in values.tolist()]
        got = _filling._to_dtype(values, np.dtype(dtype))
        assert got.dtype == dtype
        assert got.tolist() == expected
    got = _filling._to_dtype(values[np.abs(values) < 1e30], np.dtype(np.float32))
    expected = [struct.unpack("f", struct.pack("f", v))[0]
                for v in values[np.abs(values) < 1e30].tolist()]
    assert got.dtype == np.float32 and got.tolist() == expected
    got = _filling._to_dtype(values, np.dtype(np.float64))
    assert got.dtype == np.float64 and got.tolist() == values.tolist()


def test_working_units_map_a_far_float_clip_onto_minus_one_to_one():
    """Far from unit scale: shift = (min + max) / 2 and scale = (max - min) / 2
    (exact rational arithmetic in the test), so that (clip - shift) / scale
    runs from -1 to 1; within reach (8- and 16-bit ranges, unit floats,
    integer dtypes): None."""
    from fractions import Fraction

    rng = np.random.default_rng(4)
    unit = rng.random((9, 7, 1))
    unit.flat[[0, 1]] = 0.0, 1.0
    for near in (unit, unit * 255, unit * 65535 - 32768, (unit * 255).astype(np.uint8),
                 (unit * 65535).astype(np.uint16), unit.astype(np.float32)):
        assert _filling._working_units(near) is None
    for far in (unit * 1e300, unit * 1.7e308 - 0.85e308, unit * 1e-300,
                unit + 1e10, -unit * 3e9 - 1e20):
        lo, hi = Fraction(float(far.min())), Fraction(float(far.max()))
        shift, scale = _filling._working_units(far)
        assert shift == pytest.approx(float((lo + hi) / 2), rel=1e-15, abs=1e-320)
        assert scale == pytest.approx(float((hi - lo) / 2), rel=1e-15, abs=1e-320)
        mapped = (far - shift) / scale
        rounding = 4 * np.spacing(abs(shift)) / scale + 1e-15  # 1e10 + [0, 1]: 4e-6
        assert mapped.min() == pytest.approx(-1, abs=rounding)
        assert mapped.max() == pytest.approx(1, abs=rounding)
    # a constant far clip: shifted to 0, scaled by its magnitude
    assert _filling._working_units(np.full((3, 3, 1), -4e20)) == (-4e20, 4e20)


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.float32])
def test_the_fill_of_a_narrow_dtype_is_the_float_fill_rounded_and_clipped(dtype):
    """inpaint works on the clip as float64: the fill of an integer image is
    the fill of the same values as float64, rounded (ties to even) and
    clipped to the dtype's range; of a float32 image, rounded to float32.
    (The fill stays within the known pixels' range, so the clipping is a
    safety net only, compared in the test above.)"""
    import struct

    rng = np.random.default_rng(8)
    r, c = np.mgrid[0:40, 0:40]
    frame = np.clip(0.5 + 0.6 * np.sin(c / 2.5 + r / 4.0)
                    + 0.03 * rng.standard_normal((40, 40)), 0, 1)
    mask = np.zeros(frame.shape, bool)
    mask[8:32, 18:21] = True
    if dtype == np.float32:
        image = frame.astype(np.float32)
    else:
        lo, hi = int(np.iinfo(dtype).min), int(np.iinfo(dtype).max)
        image = np.clip(np.round(frame * (hi - lo) + lo), lo, hi).astype(dtype)
    fill = inpaint(image.astype(np.float64), mask)[mask]
    got = inpaint(image, mask)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got[~mask], image[~mask])
    if dtype == np.float32:
        expected = [struct.unpack("f", struct.pack("f", v))[0] for v in fill.tolist()]
    else:
        expected = [min(max(round(v), lo), hi) for v in fill.tolist()]
    assert got[mask].tolist() == expected
