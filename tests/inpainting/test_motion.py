"""Motion between frames (issue 13 point 3): the flow against known motion,
the warp against scipy's interpolation, the motion-compensated neighbours of
a clip, and the blotch test on them against a plain NumPy version."""

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view
from scipy import ndimage
from skimage import data as skdata

from car_napari._progress import drain
from car_napari.inpainting import _detection, _motion, detect_scratches, iter_detect_scratches
from car_napari.inpainting._motion import (
    compensate_motion,
    estimate_motion,
    iter_compensate_motion,
    warp_frame,
)


def _camera(shape=(96, 128)):
    """A textured real grey frame (Lucas-Kanade sees only the normal motion
    of straight edges in a flat region: the aperture problem)."""
    from skimage.color import rgb2gray

    return rgb2gray(skdata.astronaut())[100 : 100 + shape[0], 150 : 150 + shape[1]]


def _reference_warp(image, flow):
    """Bilinear, edges repeated: scipy's map_coordinates (order 1, nearest)."""
    H, W = image.shape
    rows, cols = np.mgrid[:H, :W].astype(float)
    return ndimage.map_coordinates(image, [rows + flow[0], cols + flow[1]], order=1,
                                   mode="nearest")


def test_warp_frame_is_bilinear_interpolation():
    rng = np.random.default_rng(0)
    image = rng.random((23, 31))
    flow = rng.normal(0, 3, (2, 23, 31))  # some positions fall outside: edges repeated
    np.testing.assert_allclose(warp_frame(image, flow), _reference_warp(image, flow),
                               rtol=0, atol=1e-12)
    colour = rng.random((23, 31, 3))
    got = warp_frame(colour, flow)
    for c in range(3):
        np.testing.assert_allclose(got[..., c], _reference_warp(colour[..., c], flow),
                                   atol=1e-12)
    first = np.moveaxis(colour, -1, 0)
    np.testing.assert_allclose(warp_frame(first, flow, channel_axis=0),
                               np.moveaxis(got, -1, 0), atol=1e-12)
    u8 = (colour * 255).astype(np.uint8)  # integers are scaled to [0, 1]
    np.testing.assert_allclose(warp_frame(u8, np.zeros((2, 23, 31))), u8 / 255.0, atol=1e-12)


def test_a_coarse_flow_is_interpolated_to_the_frame():
    """The fused warp by a flow of a coarser grid: the flow sampled bilinearly
    at the pixel centres (aligned extents), scaled to frame pixels, then the
    plain warp."""
    rng = np.random.default_rng(1)
    image = rng.random((20, 30))
    coarse = rng.normal(0, 1, (2, 7, 11))
    H, W = image.shape
    h, w = coarse.shape[1:]
    rows = np.clip((np.arange(H) + 0.5) * h / H - 0.5, 0, h - 1)
    cols = np.clip((np.arange(W) + 0.5) * w / W - 0.5, 0, w - 1)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    full = np.stack([ndimage.map_coordinates(coarse[k], [rr, cc], order=1, mode="nearest")
                     for k in range(2)])
    full *= np.array([H / h, W / w])[:, None, None]
    np.testing.assert_allclose(_motion._warp(image[..., None], coarse)[..., 0],
                               _reference_warp(image, full), atol=1e-10)
    np.testing.assert_allclose(_motion._full_flow(coarse.astype(np.float32), (H, W)), full,
                               atol=1e-4)


@pytest.mark.parametrize("shift", [(0.0, 3.0), (1.5, -2.25), (-4.0, 0.5)])
def test_the_flow_of_a_known_translation(shift):
    frame = _camera()
    moved = ndimage.shift(frame, shift, order=3, mode="nearest")  # content moves by shift
    flow = estimate_motion(frame, moved)
    assert flow.shape == (2,) + frame.shape and flow.dtype == np.float32
    inner = flow[:, 12:-12, 12:-12]
    for k in range(2):
        assert abs(np.median(inner[k]) - shift[k]) < 0.15
        assert np.median(np.abs(inner[k] - shift[k])) < 0.35
    # the warped frame is the reference again, up to interpolation
    back = warp_frame(moved, flow)
    assert np.abs(back - frame)[12:-12, 12:-12].mean() < 0.25 * np.abs(
        moved - frame)[12:-12, 12:-12].mean()


def test_a_masked_blotch_does_not_steer_the_flow():
    frame = _camera()
    moved = ndimage.shift(frame, (0.0, 2.0), order=3, mode="nearest")
    damaged = frame.copy()
    damaged[40:56, 50:70] = 1.0  # a large blotch on the reference
    mask = np.zeros(frame.shape, bool)
    mask[40:56, 50:70] = True
    masked = estimate_motion(damaged, moved, mask=mask)
    assert np.abs(masked[1, 40:56, 50:70] - 2.0).max() < 0.5
    assert np.abs(masked[0, 40:56, 50:70]).max() < 0.5


def test_compensate_motion_on_a_pan():
    scene = _camera((96, 160))
    clip = np.stack([scene[:, 3 * t : 3 * t + 120] for t in range(4)])  # a pan of 3 px
    records = []
    previous, following = drain(iter_compensate_motion(clip), records.append)
    assert previous.shape == following.shape == clip.shape
    np.testing.assert_array_equal(previous[0], clip[0])
    np.testing.assert_array_equal(following[-1], clip[-1])
    inner = (slice(8, -8), slice(8, -8))
    for t in range(1, 4):
        raw = np.abs(clip[t] - clip[t - 1])[inner].mean()
        assert np.abs(previous[t] - clip[t])[inner].mean() < 0.2 * raw
        assert np.abs(following[t - 1] - clip[t - 1])[inner].mean() < 0.2 * raw
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert {r.stage for r in records} == {"motion"}
    # a colour clip: the warp of every channel by the grey frames' flow
    colour = np.stack([clip, clip, clip], axis=-1)
    p3, _ = compensate_motion(colour)
    np.testing.assert_allclose(p3[..., 2], previous, atol=1e-6)
    # one mask for all frames, or one per frame
    mask = np.zeros(clip.shape[1:], bool)
    mask[10:20, 10:20] = True
    assert compensate_motion(clip, mask=mask)[0].shape == clip.shape


def test_motion_errors():
    frame = np.zeros((32, 32))
    with pytest.raises(ValueError, match="differ in size"):
        estimate_motion(frame, np.zeros((32, 30)))
    with pytest.raises(ValueError, match="mask has shape"):
        estimate_motion(frame, frame, mask=np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="radius"):
        estimate_motion(frame, frame, radius=0)
    with pytest.raises(ValueError, match="NaN"):
        bad = frame.copy()
        bad[1, 1] = np.nan
        estimate_motion(bad, frame)
    with pytest.raises(ValueError, match=r"flow must be a finite \(2, H, W\)"):
        warp_frame(frame, np.zeros((2, 31, 32)))
    with pytest.raises(ValueError, match="2 frames or more"):
        compensate_motion(frame)
    with pytest.raises(ValueError, match="mask has shape"):
        compensate_motion(np.zeros((3, 32, 32)), mask=np.zeros((2, 32, 32), bool))
    with pytest.raises(TypeError, match="numeric"):
        compensate_motion(np.array([["a"]]))


# --- the blotch test on motion-compensated neighbours ----------------------------------


def _moving_clip(T=5, seed=0):
    """A panned real image with a region of another one sliding over it (grey),
    and a dark blotch on frame 2 (on the moving region) and a bright one off it."""
    rng = np.random.default_rng(seed)
    scene = skdata.camera().astype(float) / 255
    patch = skdata.coins().astype(float)[60:120, 60:140] / 255
    clip, moving = [], []
    for t in range(T):
        frame = scene[100 + t : 196 + t, 120 + 2 * t : 248 + 2 * t].copy()
        r, c = 20 + 2 * t, 70 - 3 * t
        frame[r : r + 40, c : c + 50] = patch[:40, 10:60]  # an object moving over the pan
        region = np.zeros(frame.shape, bool)
        region[r : r + 40, c : c + 50] = True
        clip.append(frame)
        moving.append(region)
    clip = np.stack(clip) + rng.normal(0, 0.005, (T,) + clip[0].shape)
    blotches = np.zeros(clip.shape, bool)
    blotches[2, 30:36, 60:67] = True  # on the moving region of frame 2
    blotches[2, 70:76, 20:28] = True
    clip[2][blotches[2]] = np.where(np.arange(blotches[2].sum()) < 42, 0.0, 1.0)
    return np.clip(clip, 0, 1), blotches, np.stack(moving)


def _reference_compensated(before, frame, after, threshold, tolerance=1, agreement=1.0,
                           grow=_detection.GROW_SPIKE):
    """The compensated test in plain NumPy (a 3x3 window max and min; the
    growth by a pixel only into pixels whose spike exceeds ``grow`` times
    the threshold)."""
    def window(image, reduce):
        padded = np.pad(image, tolerance, mode="symmetric")
        return reduce(sliding_window_view(padded, (2 * tolerance + 1,) * 2), axis=(2, 3))

    brighter = np.minimum(frame - window(before, np.max), frame - window(after, np.max))
    darker = np.minimum(window(before, np.min) - frame, window(after, np.min) - frame)
    spike = np.maximum(brighter, darker)
    spikes = (spike > threshold) & (np.abs(before - after) < agreement * spike)
    spikes = ndimage.binary_opening(spikes, structure=np.ones((2, 2), bool))
    grown = sliding_window_view(np.pad(spikes, 1), (3, 3)).any(axis=(2, 3))
    return spikes | (grown & (spike > grow * threshold))


def test_the_compensated_blotch_test_is_the_plain_numpy_test():
    clip, _, _ = _moving_clip()
    previous, following = compensate_motion(clip)
    expected = np.zeros(clip.shape, bool)
    for t in range(1, len(clip) - 1):
        expected[t] = _reference_compensated(previous[t], clip[t], following[t],
                                             _detection.COMPENSATED_THRESHOLD)
    got = detect_scratches(clip, kinds="blotch")
    np.testing.assert_array_equal(got, expected)
    assert expected.any()


def test_motion_is_left_alone_and_blotches_found():
    clip, blotches, moving = _moving_clip()
    near = ndimage.binary_dilation(blotches, structure=np.ones((1, 3, 3), bool),
                                   iterations=2)
    found = detect_scratches(clip, kinds="blotch")
    assert found[blotches].mean() > 0.9  # both blotches, the one on the moving region too
    assert not (found & ~near).any()  # nothing else: the motion is left alone
    raw = detect_scratches(clip, kinds="blotch", motion=False)
    assert (raw & moving & ~near)[1:-1].sum() > 50  # what the old test did


@pytest.mark.parametrize("band", [1, 333, 1 << 19])
def test_the_compensated_detector_in_bands_is_the_same(monkeypatch, band):
    clip, _, _ = _moving_clip()
    whole = detect_scratches(clip)
    monkeypatch.setattr(_detection, "BAND_PIXELS", band)
    records = []
    np.testing.assert_array_equal(drain(iter_detect_scratches(clip), records.append), whole)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    if band == 333:
        assert {"reading", "lines", "motion", "blotches"} <= {r.stage for r in records}


def test_blotch_threshold_errors():
    with pytest.raises(ValueError, match="blotch_threshold"):
        detect_scratches(np.zeros((3, 16, 16)), blotch_threshold=0.0)


def test_the_flows_3x3_median_is_scipys_median_filter():
    """The compiled selection network against scipy's median filter (edges
    repeated), on random planes, ties and tiny planes included."""
    rng = np.random.default_rng(2)
    for field in (rng.random((2, 17, 23)), rng.integers(0, 3, (2, 9, 8)).astype(float),
                  rng.random((1, 1, 5)), rng.random((1, 2, 2)).astype(np.float32)):
        want = ndimage.median_filter(field, size=(1, 3, 3), mode="nearest")
        np.testing.assert_array_equal(_motion._median3x3(field), want)
