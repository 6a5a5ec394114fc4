"""Scratch and video restoration (SPEC 6)."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata

from car_napari.inpainting import detect_scratches, inpaint, iter_inpaint
from car_napari.model.neighbourhood import Context
from car_napari.model.recursive import default_prior, scan


def _scratched(image, columns=(40, 90), width=3, value=255):
    mask = np.zeros(image.shape[:2], bool)
    for c in columns:
        mask[:, c : c + width] = True
    damaged = image.copy()
    damaged[mask] = value
    return damaged, mask


def _psnr(truth, out, mask):
    err = truth[mask].astype(float) - out[mask].astype(float)
    return 10 * np.log10(255.0**2 / np.mean(err**2))


def test_fill_in_the_kernel_matches_a_plain_numpy_fill():
    """The kernel's fill, forgetting 1, one direction: each missing pixel is
    gamma X_r with the least-squares gamma of the known pixels before it (and
    earlier fills as neighbours)."""
    rng = np.random.default_rng(0)
    image = ndimage.uniform_filter(rng.random((12, 13)), 3)
    mask = np.zeros(image.shape, bool)
    mask[5:8, 6] = True
    mask[9, 2:4] = True
    offsets = np.array([(0, 1), (1, 0), (1, 1)])
    context = Context.spatial(offsets, 1)
    y = image - image.mean()
    prior = default_prior(np.array([y.var()]), 3, True, 1, 1e-6)
    work = np.ascontiguousarray(y[..., None].copy())
    scan(work, context, direction="down", forgetting=1.0, intercept=True, prior=prior,
         outputs=(), missing=mask)
    # plain NumPy: raster order, learn from known pixels with known neighbours
    ref = y.copy()
    V = np.diag(prior)
    H, W = y.shape
    for i in range(H):
        for j in range(W):
            nb = [(i - di, j - dj) for di, dj in offsets]
            if any(not (0 <= a < H and 0 <= b < W) for a, b in nb):
                continue
            x = np.r_[[ref[a, b] for a, b in nb], 1.0]
            if mask[i, j]:
                gamma = np.linalg.solve(V[:4, :4], V[:4, 4])
                ref[i, j] = gamma @ x
            elif not any(mask[a, b] for a, b in nb):
                z = np.r_[x, ref[i, j]]
                V = V + np.outer(z, z)
    np.testing.assert_allclose(work[..., 0][mask], ref[mask], rtol=1e-8, atol=1e-12)
    np.testing.assert_array_equal(work[..., 0][~mask], y[~mask])


def test_frame_outside_mask_is_bit_identical_and_scratches_are_filled():
    image = skdata.astronaut()[100:260, 100:260]
    damaged, mask = _scratched(image)
    out = inpaint(damaged, mask)
    assert out.dtype == image.dtype and out.shape == image.shape
    np.testing.assert_array_equal(out[~mask], damaged[~mask])
    assert _psnr(image, out, mask) > 22  # the white scratch itself: about 6 dB
    # grey frame, float input, mask touching the border
    grey = skdata.camera()[:128, :128] / 255.0
    mask = np.zeros(grey.shape, bool)
    mask[:, :3] = mask[:2, :] = mask[60:64, 60:70] = True
    out = inpaint(np.where(mask, 1.0, grey), mask, channel_axis=None)
    assert np.all(np.isfinite(out)) and out.dtype == np.float64
    err = np.abs(out - grey)[mask]
    assert err.mean() < 0.08


def test_suspect_edge_pixels_are_tested_and_filled_when_improbable():
    """The kernel's halo test: a known pixel marked 2 is filled (and marked
    1) when it is an outlier of the predictive density, kept (marked 0)
    otherwise; with the test off (threshold -inf) it is always kept."""
    rng = np.random.default_rng(1)
    image = ndimage.uniform_filter(rng.random((30, 31)), 5)
    y = image - image.mean()
    codes = np.zeros(image.shape, np.uint8)
    codes[10:20, 15] = 1  # the damage
    codes[10:20, 16] = 2  # its right edge: suspect
    y[10:15, 16] += 5.0  # a bright halo on half of the edge
    context = Context.spatial(np.array([(0, 1), (1, 0), (1, 1)]), 1)
    prior = default_prior(np.array([image.var()]), 3, True, 1, 1e-6)
    for threshold, halo_filled in ((-12.0, True), (-np.inf, False)):
        work = np.ascontiguousarray(y[..., None].copy())
        marks = codes.copy()
        scan(work, context, direction="down", forgetting=1.0, intercept=True, prior=prior,
             outputs=(), missing=marks, suspect_logrel=threshold)
        assert np.all(marks[10:15, 16] == (1 if halo_filled else 0))
        assert np.all(marks[15:20, 16] == 0)  # plausible edge pixels are kept
        np.testing.assert_array_equal(work[15:20, 16, 0], y[15:20, 16])
        if halo_filled:  # the halo is replaced by predictions near the image
            assert np.abs(work[10:15, 16, 0] - image[10:15, 16] + image.mean()).max() < 0.5


def test_halo_test_recovers_soft_edged_damage():
    """A blotch with a one-pixel fringe outside its mask (half blended with
    the blotch): with the halo test the fill is much closer to the truth
    (measured 5.6 -> 15.1 dB); pixels outside the mask are unchanged."""
    image = skdata.astronaut()[100:228, 100:228]
    mask = np.zeros(image.shape[:2], bool)
    mask[80:100, 60:100] = True
    fringe = ndimage.binary_dilation(mask) & ~mask
    damaged = image.copy()
    damaged[mask] = 250
    damaged[fringe] = (0.5 * image[fringe] + 0.5 * 250).astype(np.uint8)
    on = inpaint(damaged, mask)
    off = inpaint(damaged, mask, halo=None)
    np.testing.assert_array_equal(on[~mask], damaged[~mask])
    assert _psnr(image, on, mask) > _psnr(image, off, mask) + 5.0
    with pytest.raises(ValueError, match="halo"):
        inpaint(damaged, mask, halo=1.0)


def test_clip_uses_the_previous_frame():
    """A static scene with different scratches in each frame: the previous
    restored frame predicts the hole far better than the frame alone."""
    base = skdata.camera()[:96, :96]
    rng = np.random.default_rng(0)
    clip, masks = [], []
    for t in range(4):
        frame = np.clip(base + rng.normal(0, 2, base.shape), 0, 255).astype(np.uint8)
        damaged, m = _scratched(frame, columns=(10 + 20 * t, 50 + 10 * t), width=3)
        clip.append(damaged)
        masks.append(m)
    clip, masks = np.stack(clip), np.stack(masks)
    states = list(_states(iter_inpaint(clip, masks, channel_axis=None)))
    assert len(states) == 4 and states[-1].fraction == 1.0
    with_time = inpaint(clip, masks, channel_axis=None)
    without = inpaint(clip, masks, channel_axis=None, temporal=False)
    truth = np.broadcast_to(base, clip.shape)
    assert _psnr(truth[1:], with_time[1:], masks[1:]) > _psnr(truth[1:], without[1:],
                                                              masks[1:]) + 0.5
    np.testing.assert_array_equal(with_time[~masks], clip[~masks])


def _states(gen):
    while True:
        try:
            yield next(gen)
        except StopIteration:
            return


def test_mask_errors_and_empty_mask():
    image = skdata.astronaut()[:64, :64]
    with pytest.warns(UserWarning, match="empty"):
        out = inpaint(image, np.zeros((64, 64), bool))
    np.testing.assert_array_equal(out, image)
    with pytest.raises(ValueError, match="covers every pixel"):
        inpaint(image, np.ones((64, 64), bool))
    with pytest.raises(ValueError, match="mask has shape"):
        inpaint(image, np.zeros((32, 64), bool))
    with pytest.raises(ValueError, match="grey clip"):
        inpaint(np.zeros((64, 64, 10)), np.zeros((64, 64), bool))
    with pytest.raises(ValueError, match="NaN"):
        bad = image / 255.0
        bad[3, 3, 0] = np.nan
        inpaint(bad, np.zeros((64, 64), bool))
    with pytest.raises(ValueError, match="too small"):
        inpaint(image[:4, :4], np.eye(4, dtype=bool))


def test_detector_finds_vertical_scratches():
    frame = skdata.camera()[:200, :200].astype(float) / 255.0
    truth = np.zeros(frame.shape, bool)
    truth[:, 60:62] = True
    truth[:, 140:143] = True
    damaged = frame.copy()
    damaged[:, 60:62] += 0.25
    damaged[:, 140:143] -= 0.25
    proposed = detect_scratches(np.clip(damaged, 0, 1), kinds="line", channel_axis=None)
    hit = (proposed & truth).sum()
    recall, precision = hit / truth.sum(), hit / max(proposed.sum(), 1)
    assert recall > 0.7 and precision > 0.5


def test_detector_finds_blotches_in_a_clip():
    base = skdata.camera()[:96, :96] / 255.0
    rng = np.random.default_rng(0)
    clip = np.stack([np.clip(base + rng.normal(0, 0.01, base.shape), 0, 1) for _ in range(5)])
    clip[2, 30:36, 40:46] = 1.0
    proposed = detect_scratches(clip, kinds="blotch", channel_axis=None)
    assert proposed.shape == clip.shape
    assert proposed[2, 30:36, 40:46].mean() > 0.8
    assert proposed[[0, 1, 3, 4]].sum() == 0 and proposed[2].sum() < 100
