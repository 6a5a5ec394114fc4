"""Restoration (sections 14.5 and 14.6, docs/restoration.md): each piece
against an independent computation."""

import threading

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata
from skimage import img_as_float
from skimage.metrics import peak_signal_noise_ratio as psnr

from car_napari._progress import Progress, drain
from car_napari.model.neighbourhood import causal_neighbourhood
from car_napari.restoration import (
    MultichannelRestoration,
    RestorationResult,
    estimate_noise,
    estimate_psf,
    iter_restore,
    iter_restore_multichannel,
    psf_width,
    restore,
    restore_multichannel,
    sharpness,
)


def _dense_one_step(image, offsets, strength=1e-6):
    """One-step prediction and relative density by plain NumPy: for every
    pixel, the regression of Y on [neighbours, 1] over all earlier pixels
    (raster order, prior V_0 as in the core), the Student-t predictive
    density (14.23)-(14.25)."""
    y = image - image.mean()
    H, W = y.shape
    m = len(offsets)
    p = m + 1
    V = np.diag(np.r_[np.full(m, strength * y.var()), strength, strength * y.var()])
    count = 0
    pred = np.full((H, W), np.nan)
    rel = np.full((H, W), np.nan)
    for i in range(H):
        for j in range(W):
            nb = [(i - di, j - dj) for di, dj in offsets]
            if any(not (0 <= a < H and 0 <= b < W) for a, b in nb):
                continue
            x = np.r_[[y[a, b] for a, b in nb], 1.0]
            Vxx, Vxy, Vyy = V[:p, :p], V[:p, p], V[p, p]
            gamma = np.linalg.solve(Vxx, Vxy)
            lam = Vyy - Vxy @ gamma
            q = 1.0 + x @ np.linalg.solve(Vxx, x)
            e = y[i, j] - gamma @ x
            nu = (p - 1 + count) - p + 2
            pred[i, j] = gamma @ x + image.mean()
            rel[i, j] = (1.0 + e * e / (q * lam)) ** (-(nu + 1) / 2)
            z = np.r_[x, y[i, j]]
            V = V + np.outer(z, z)
            count += 1
    return pred, rel


def test_conditional_mean_and_probability_match_dense_numpy():
    rng = np.random.default_rng(3)
    image = ndimage.uniform_filter(rng.random((14, 15)), 3) + 0.05 * rng.random((14, 15))
    result = drain(iter_restore(image, channel_axis=None, estimator="recursive", neighbourhood=2,
                                forgetting=1.0, directions=("down",), keep_edges=False,
                                return_result=True))
    pred, rel = _dense_one_step(image, causal_neighbourhood(2))
    have = np.isfinite(pred)
    np.testing.assert_allclose(result.prediction[..., 0][have], pred[have], rtol=1e-6)
    np.testing.assert_allclose(result.probability[have], rel[have], rtol=1e-6, atol=1e-12)
    # pixels without a whole neighbourhood keep their value, probability 1
    np.testing.assert_array_equal(result.prediction[..., 0][~have], image[~have])
    assert np.all(result.probability[~have] == 1.0)


def _dense_windowed(image, offsets, corner, window, strength=1e-6):
    """The windowed estimator by plain NumPy: for every pixel, the least
    squares of its block's 3 x 3-block window (V_0 as in the core), the
    Student-t (14.23)-(14.25) with nu = count + 1."""
    mean = image.reshape(-1, image.shape[2]).mean(axis=0)
    y = image - mean
    H, W, C = y.shape
    si = -1 if corner.startswith("up") else 1
    sj = -1 if corner.endswith("left") else 1
    taps = [(si * di, sj * dj) for di, dj in offsets]
    union = {(a * di, b * dj) for di, dj in offsets for a in (-1, 1) for b in (-1, 1)}
    border = max(max(abs(a), abs(b)) for a, b in union)
    block = -(-window // 3)
    var = float(np.mean(image.reshape(-1, C).var(axis=0)))

    def regressors(i, j):
        return np.r_[[y[i + a, j + b, c] for a, b in taps for c in range(C)], 1.0]

    def block_model(bi, bj):  # the least squares of the block's window
        rows = [(a, b) for a in range(max(border, (bi - 1) * block),
                                      min(H - border, (bi + 2) * block))
                for b in range(max(border, (bj - 1) * block),
                               min(W - border, (bj + 2) * block))]
        X = np.array([regressors(a, b) for a, b in rows])
        Y = np.array([y[a, b] for a, b in rows])
        p = X.shape[1]
        prior = np.full(p, strength * var)
        prior[-1] = strength
        Vxx = X.T @ X + np.diag(prior)
        gamma = np.linalg.solve(Vxx, X.T @ Y)
        lam = Y.T @ Y + strength * var * np.eye(C) - (X.T @ Y).T @ gamma
        return rows, Vxx, gamma, lam

    models = {}
    pred = np.full((H, W, C), np.nan)
    rel = np.full((H, W), np.nan)
    for i in range(H):
        for j in range(W):
            if not all(0 <= i + a < H and 0 <= j + b < W for a, b in taps):
                continue
            key = (i // block, j // block)
            if key not in models:
                models[key] = block_model(*key)
            rows, Vxx, gamma, lam = models[key]
            z = regressors(i, j)
            e = y[i, j] - z @ gamma
            q = 1.0 + z @ np.linalg.solve(Vxx, z)
            pred[i, j] = z @ gamma + mean
            rel[i, j] = (1.0 + e @ np.linalg.solve(lam, e) / q) ** (-(len(rows) + 1 + C) / 2)
    return pred, rel


@pytest.mark.parametrize("corner", ["up-left", "down-right"])
def test_windowed_prediction_matches_dense_least_squares(corner):
    rng = np.random.default_rng(5)
    image = ndimage.uniform_filter(rng.random((17, 19, 3)), (3, 3, 1))
    image += 0.05 * rng.random(image.shape)
    result = restore(image, directions=(corner,), window=9, keep_edges=False,
                     return_result=True)
    pred, rel = _dense_windowed(image, causal_neighbourhood(1), corner, 9)
    have = np.isfinite(rel)
    # a lone direction votes where it has a predicted neighbour in 3 x 3
    np.testing.assert_allclose(result.prediction[have], pred[have], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.probability[have], rel[have], rtol=1e-7, atol=1e-12)
    np.testing.assert_array_equal(result.prediction[~have], image[~have])
    assert np.all(result.probability[~have] == 1.0)


def test_windowed_and_recursive_estimators_agree_on_quality():
    """Two estimators of one model: on a blurred noisy photo both restore
    to within half a dB of each other, and both well above the input."""
    rng = np.random.default_rng(0)
    clean = img_as_float(skdata.astronaut())[:160, :160]
    noisy = _degraded(clean, rng)
    windowed = psnr(clean, restore(noisy), data_range=1)
    recursive = psnr(clean, restore(noisy, estimator="recursive", neighbourhood=2),
                     data_range=1)
    assert windowed > psnr(clean, noisy, data_range=1) + 3.0
    assert abs(windowed - recursive) < 0.5


def _degraded(image, rng, blur=1.0, noise=0.05):
    sigma = (blur, blur, 0) if image.ndim == 3 else blur
    return ndimage.gaussian_filter(image, sigma) + rng.normal(0, noise, image.shape)


def test_restore_denoises_colour_and_grey_and_keeps_layout():
    rng = np.random.default_rng(0)
    clean = img_as_float(skdata.astronaut())[:128, :128]
    noisy = _degraded(clean, rng)
    given = noisy.copy()
    out = restore(noisy)
    np.testing.assert_array_equal(noisy, given)  # read, never written (it is not copied)
    assert out.shape == clean.shape and out.dtype == np.float64
    assert psnr(clean, out, data_range=1) > psnr(clean, noisy, data_range=1) + 2.0
    # channel_axis=0 gives the same numbers in that layout
    first = restore(np.moveaxis(noisy, -1, 0), channel_axis=0)
    np.testing.assert_allclose(np.moveaxis(first, 0, -1), out, atol=1e-12)
    grey = restore(noisy[..., 1], channel_axis=None)
    assert grey.shape == (128, 128)
    assert psnr(clean[..., 1], grey, data_range=1) > psnr(clean[..., 1], noisy[..., 1],
                                                          data_range=1) + 2.0


def _rise_distance(profile, lo=0.2, hi=0.8):
    """Pixels between the 10 % and 90 % crossings of a rising edge profile."""
    t = (profile - lo) / (hi - lo)
    x = np.arange(len(t), dtype=float)

    def crossing(level):
        k = int(np.argmax(t >= level))
        return x[k - 1] + (level - t[k - 1]) / (t[k] - t[k - 1])

    return crossing(0.9) - crossing(0.1)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_edge_rule_keeps_a_step_sharp_and_denoises_flat_parts(seed):
    rng = np.random.default_rng(seed)
    step = np.where(np.arange(64) < 32, 0.2, 0.8)[None, :].repeat(64, axis=0)
    noisy = step + rng.normal(0, 0.05, step.shape)
    out = restore(noisy, channel_axis=None)
    rows = slice(4, 60)
    # as sharp as the input (to 0.01 px: the row-averaged profiles are noisy)
    assert _rise_distance(out[rows].mean(axis=0)) <= _rise_distance(
        noisy[rows].mean(axis=0)) + 0.01
    flat = (slice(4, 60), slice(4, 24))
    assert out[flat].std() < 0.7 * noisy[flat].std()
    # without the rule the conditional mean blurs the step
    plain = restore(noisy, channel_axis=None, keep_edges=False)
    assert _rise_distance(plain[rows].mean(axis=0)) > _rise_distance(out[rows].mean(axis=0))


def test_noise_median_is_exactly_numpy_median():
    """The O(n) histogram median of the absolute Laplacian responses equals
    np.median on random, heavy-tailed, sparse and constant images, odd and
    even counts (the heavy tail exercises the overflow-bin fallback)."""
    from car_napari.restoration._noise import median_abs_laplacian

    kernel = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
    rng = np.random.default_rng(4)
    for shape in [(3, 3), (6, 7), (101, 100), (64, 300)]:
        for image in (rng.random(shape), rng.standard_cauchy(shape),
                      (rng.random(shape) > 0.999) * 1.0, np.full(shape, 0.3)):
            want = np.median(np.abs(ndimage.convolve(image, kernel))[1:-1, 1:-1])
            assert abs(median_abs_laplacian(image) - want) <= 1e-12 * max(1.0, abs(want))


def test_noise_estimate():
    rng = np.random.default_rng(1)
    clean = img_as_float(skdata.camera())[:256, :256]
    for sigma in (0.02, 0.05, 0.1):
        est = estimate_noise(_degraded(clean, rng, noise=sigma), channel_axis=None)
        assert est.shape == (1,) and abs(est[0] - sigma) < 0.15 * sigma


def _stack(clean, rng, blurs):
    return np.stack([_degraded(clean, rng, blur=b) for b in blurs])


def test_multichannel_beats_its_inputs_and_picks_the_sharpest():
    rng = np.random.default_rng(0)
    clean = img_as_float(skdata.camera())[100:228, 100:228]
    blurs = [1.5, 0.5, 2.0, 1.0, 1.75, 0.75]
    stack = _stack(clean, rng, blurs)
    assert int(np.argmax(sharpness(stack))) == 1
    restored, probability = restore_multichannel(stack)
    assert restored.shape == clean.shape and probability.shape == clean.shape
    assert probability.min() >= 0 and probability.max() <= 1
    ours = psnr(clean, restored, data_range=1)
    assert ours > psnr(clean, stack.mean(axis=0), data_range=1)
    assert ours > psnr(clean, stack[1], data_range=1) + 3
    # versions on another axis, and an explicit reference
    moved, _ = restore_multichannel(np.moveaxis(stack, 0, 2), axis=2, reference=1)
    np.testing.assert_allclose(moved, restored, atol=1e-12)


def test_kappa_rethresholds_without_recomputing():
    rng = np.random.default_rng(0)
    clean = img_as_float(skdata.astronaut())[:96, :96]
    stack = _stack(clean, rng, [0.5, 1.0, 1.5])
    result = drain(iter_restore_multichannel(stack, return_result=True))
    assert result.reference == 0
    changed = [result.changed(k).sum() for k in (0.0, 0.05, 0.3, 0.6, 0.9)]
    assert changed == sorted(changed, reverse=True) and changed[0] > changed[-1]
    high = result.restored(0.9)
    keep = result.probability <= 0.9
    np.testing.assert_array_equal(high[keep], result.observed[keep])
    restored, _ = restore_multichannel(stack, kappa=0.3, channel_axis=-1)
    np.testing.assert_allclose(restored, result.restored(0.3), atol=1e-12)


def _records_and_result(job):
    records = []
    result = drain(job, on_progress=records.append)
    return records, result


@pytest.mark.parametrize("channel_axis", [-1, 0])
def test_iter_restore_yields_progress_with_previews_and_returns_what_restore_does(
        channel_axis):
    rng = np.random.default_rng(0)
    noisy = _degraded(img_as_float(skdata.astronaut())[:96, :80], rng)
    noisy = np.moveaxis(noisy, -1, channel_axis)
    records, restored = _records_and_result(iter_restore(noisy, channel_axis=channel_axis))
    assert all(isinstance(r, Progress) for r in records)
    np.testing.assert_array_equal(restored, restore(noisy, channel_axis=channel_axis))
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and 0 <= fractions[0] and fractions[-1] <= 1
    rows = [r for r in records if r.stage == "rows"]
    assert rows[-1].message == "rows 96/96"
    previews = [r for r in records if r.preview is not None]
    assert len(previews) >= 2
    for record in previews:  # the image so far, in the input's layout
        assert record.preview.shape == noisy.shape
    # without the edge rule the restored rows of a preview are final, and the
    # rows not yet restored show the observation
    records, plain = _records_and_result(iter_restore(noisy, channel_axis=channel_axis,
                                                      keep_edges=False))
    first = next(r for r in records if r.preview is not None)
    done = int(first.message.split()[1].split("/")[0])
    preview, final = (np.moveaxis(a, channel_axis, -1) for a in (first.preview, plain))
    observed = np.moveaxis(noisy, channel_axis, -1)
    assert 0 < done < len(final)
    np.testing.assert_array_equal(preview[:done], final[:done])
    # (later strips may be running while the preview is copied; the
    # observation is shown as (x - mean) + mean, one rounding from x)
    assert np.all((np.abs(preview - observed) < 1e-12) | (preview == final))
    assert not np.array_equal(final[done:], observed[done:])


def test_iter_restore_with_return_result_equals_restore_and_recursive_previews():
    rng = np.random.default_rng(1)
    noisy = _degraded(img_as_float(skdata.camera())[:48, :56], rng)
    for options in ({}, {"estimator": "recursive", "kappa": 0.2}):
        records, result = _records_and_result(iter_restore(noisy, return_result=True,
                                                           **options))
        want = restore(noisy, return_result=True, **options)
        assert isinstance(result, RestorationResult)
        for name in ("observed", "prediction", "probability", "weight", "noise"):
            np.testing.assert_array_equal(getattr(result, name), getattr(want, name))
        assert result.kappa == want.kappa
        previews = [r.preview for r in records if r.preview is not None]
        assert previews and all(p.shape == noisy.shape for p in previews)
    # the recursive previews are in image units (the mean added back)
    assert abs(previews[-1].mean() - noisy.mean()) < 0.05


def test_closing_iter_restore_early_stops_the_work():
    rng = np.random.default_rng(2)
    noisy = rng.random((256, 64))
    threads = threading.active_count()
    job = iter_restore(noisy)
    first = next(job)
    assert first.stage == "start" and first.fraction == 0.0
    while next(job).stage != "rows":
        pass
    job.close()  # no error, the pool shut down, the generator finished
    assert threading.active_count() == threads
    with pytest.raises(StopIteration):
        next(job)
    job = iter_restore_multichannel(np.stack([noisy, noisy[::-1]]))
    next(job)
    next(job)
    job.close()
    assert threading.active_count() == threads


def test_iter_restore_multichannel_previews_and_returns_what_restore_multichannel_does():
    rng = np.random.default_rng(0)
    clean = img_as_float(skdata.astronaut())[:48, :48]
    stack = _stack(clean, rng, [0.5, 1.0])
    records, out = _records_and_result(iter_restore_multichannel(stack))
    want = restore_multichannel(stack)
    assert isinstance(out, MultichannelRestoration) and out._fields == ("restored",
                                                                        "probability")
    np.testing.assert_array_equal(out.restored, want.restored)
    np.testing.assert_array_equal(out.probability, want.probability)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] <= 1
    assert {"start", "sharpness", "reference", "directions", "edges"} <= {
        r.stage for r in records} <= {"start", "reading", "sharpness", "reference",
                                      "directions", "edges"}
    previews = [r for r in records if r.preview is not None]
    assert len(previews) == 3 * 4  # a running image after every channel and direction
    assert all(r.preview.shape == clean.shape for r in previews)
    assert previews[0].message == "channel 1/3, direction 1/4"
    # the channels not yet restored show the observation (version 0 is sharpest)
    np.testing.assert_array_equal(previews[0].preview[..., 1:], stack[0][..., 1:])
    result = drain(iter_restore_multichannel(stack, return_result=True))
    np.testing.assert_array_equal(result.restored(), want.restored)


def test_multichannel_channel_axis_default_and_layout():
    """(n, H, W) is grey and (n, H, W, C) colour with the default channel
    axis; the restored version comes back in the layout of one version."""
    rng = np.random.default_rng(3)
    clean = img_as_float(skdata.astronaut())[:40, :44]
    stack = _stack(clean, rng, [0.5, 1.0])  # (2, H, W, 3)
    colour = restore_multichannel(stack, reference=0)
    assert colour.restored.shape == clean.shape
    grey = restore_multichannel(stack[..., 0], reference=0)
    assert grey.restored.shape == clean.shape[:2]
    # colour first in each version: (n, C, H, W) -> (C, H, W)
    first = restore_multichannel(np.moveaxis(stack, -1, 1), channel_axis=1, reference=0)
    np.testing.assert_array_equal(np.moveaxis(first.restored, 0, -1), colour.restored)
    np.testing.assert_array_equal(first.probability, colour.probability)
    # versions last, colour before them: (H, W, C, n) -> (H, W, C)
    last = restore_multichannel(np.moveaxis(stack, 0, -1), axis=-1, channel_axis=2,
                                reference=0)
    np.testing.assert_array_equal(last.restored, colour.restored)
    # a list of versions
    listed = restore_multichannel(list(stack), reference=0)
    np.testing.assert_array_equal(listed.restored, colour.restored)


def test_psf_recovers_a_gaussian_width():
    rng = np.random.default_rng(0)
    sharp = img_as_float(skdata.astronaut())[:256, :256]
    for sigma in (1.0, 1.5):
        blurred = ndimage.gaussian_filter(sharp, (sigma, sigma, 0))
        observed = blurred + rng.normal(0, 0.01, sharp.shape)
        psf = estimate_psf(observed, sharp, size=9)
        assert psf.shape == (9, 9)
        assert abs(psf_width(psf) - sigma) < 0.2 * sigma
        assert abs(psf.sum() - 1) < 0.1
    local = estimate_psf(observed, sharp, size=9, window=128)
    assert local.shape == (2, 2, 9, 9)
    widths = [psf_width(local[i, j]) for i in range(2) for j in range(2)]
    assert all(abs(w - 1.5) < 0.3 for w in widths)


def test_bad_input():
    rng = np.random.default_rng(0)
    image = rng.random((32, 32))
    with pytest.raises(ValueError, match="differ in shape"):
        restore_multichannel([image, image[:30]])
    with pytest.raises(ValueError, match="at least 2"):
        restore_multichannel(image[None])
    bad = image.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        restore(bad, channel_axis=None)
    with pytest.raises(ValueError, match="NaN"):
        restore_multichannel(np.stack([image, bad]))
    for kappa in (-0.1, 1.0, 3):
        with pytest.raises(ValueError, match="kappa must be in"):
            restore_multichannel(np.stack([image, image]), kappa=kappa)
    with pytest.raises(ValueError, match="constant"):
        restore(np.ones((16, 16)), channel_axis=None)
    with pytest.raises(ValueError, match="too small|smaller"):
        restore(image[:1, :2], channel_axis=None)
    with pytest.raises(ValueError, match="reference"):
        restore_multichannel(np.stack([image, image]), reference=5)
    # the versions axis, checked against the stack's dimensions up front
    for axis in (3, -4):
        with pytest.raises(ValueError, match=f"axis={axis} is out of range for the 3-D"):
            restore_multichannel(np.stack([image, image]), axis=axis)
    with pytest.raises(ValueError, match="axis=4 is out of range for the 3-D"):
        sharpness([image, image], axis=4)
    with pytest.raises(TypeError, match="axis must be an integer"):
        restore_multichannel(np.stack([image, image]), axis=0.5)
    colour = np.stack([np.dstack([image, image.T])] * 2)
    with pytest.raises(ValueError, match="channel_axis and axis must differ"):
        restore_multichannel(colour, axis=-1)
    with pytest.raises(ValueError, match="channel_axis=None"):
        restore_multichannel(colour, channel_axis=None)
    with pytest.raises(ValueError, match="channel_axis=5 is out of range"):
        restore_multichannel(colour, channel_axis=5)
    with pytest.raises(ValueError, match="odd"):
        estimate_psf(image, image, size=4)
    with pytest.raises(ValueError, match="one shape"):
        estimate_psf(image, image[:16])
    with pytest.raises(ValueError, match="estimator must be"):
        restore(image, channel_axis=None, estimator="kalman")
    with pytest.raises(ValueError, match="window must be"):
        restore(image, channel_axis=None, window=3)
    with pytest.raises(ValueError, match="up-left"):  # the windowed estimator's names
        restore(image, channel_axis=None, directions=("down",))
    with pytest.raises(ValueError, match="'down'"):
        restore(image, channel_axis=None, estimator="recursive", directions=("up-left",))


def test_large_input_with_a_huge_value_is_rejected(monkeypatch):
    """The strip-wise reader ends with the whole image's value checks: a
    value beyond 1e150 in an image of several strips is a clear error (as
    it is for a small image), a NaN is counted over every strip."""
    from car_napari.model import blocks

    monkeypatch.setattr(blocks, "BLOCK_VALUES", 600)  # 10 rows a strip
    image = np.random.default_rng(5).random((70, 60))
    image[65, 7] = 3e150  # in the last strip
    for kwargs in ({}, {"estimator": "recursive"}, {"return_result": True}):
        with pytest.raises(ValueError, match="magnitude 3e.150: .* Rescale"):
            restore(image, channel_axis=None, **kwargs)
    with pytest.raises(ValueError, match="magnitude 3e.150"):
        restore_multichannel(np.stack([image[::-1], image]))
    records = []
    with pytest.raises(ValueError, match="magnitude 3e.150"):
        drain(iter_restore(image, channel_axis=None), records.append)
    reading = [r.message for r in records if r.stage == "reading"]
    assert reading[0] == "image: rows 10/70" and reading[-1] == "image: summary 70/70"
    image[65, 7] = np.nan
    image[2, 3] = np.inf
    with pytest.raises(ValueError, match="contains 2 NaN or infinite"):
        restore(image, channel_axis=None)


def test_return_result_matches_the_plain_call():
    rng = np.random.default_rng(0)
    noisy = _degraded(img_as_float(skdata.camera())[:64, :64], rng)
    result = restore(noisy, channel_axis=None, return_result=True)
    # the plain call blends in the edge kernel (one rounding apart)
    np.testing.assert_allclose(result.restored()[..., 0], restore(noisy, channel_axis=None),
                               rtol=0, atol=1e-12)
    for kappa in (0.0, 0.3):
        np.testing.assert_allclose(result.restored(kappa)[..., 0],
                                   restore(noisy, channel_axis=None, kappa=kappa),
                                   rtol=0, atol=1e-12)
    stack = np.stack([noisy, _degraded(img_as_float(skdata.camera())[:64, :64], rng)])
    result = restore_multichannel(stack, return_result=True)
    restored, probability = restore_multichannel(stack)
    np.testing.assert_array_equal(result.restored()[..., 0], restored)
    np.testing.assert_array_equal(result.probability, probability)
    assert restore_multichannel(stack).restored is not None  # a named result


def test_chunked_stages_give_the_outputs_of_one_call(monkeypatch):
    """Issue 12: the input conversion, statistics, models, strips, scans and
    edge rule run in chunks with a record between them; any chunking gives,
    bit for bit, the results of the whole-image calls (large chunks here),
    and the conversion is exactly as_channel_last_float's."""
    from car_napari._validation import as_channel_last_float, channel_last_shape
    from car_napari.model import blocks, recursive
    from car_napari.model.blocks import iter_channel_last_float
    from car_napari.restoration import _combine

    rng = np.random.default_rng(4)
    colour = (np.clip(_degraded(img_as_float(skdata.astronaut())[:71, :53], rng), 0, 1)
              * 255).astype(np.uint8)
    grey = _degraded(img_as_float(skdata.camera())[:45, :38], rng)
    stack = np.stack([colour, colour[::-1]]).astype(np.float32)

    def run_all():
        return [restore(colour, return_result=True), restore(colour),
                restore(grey, channel_axis=None, estimator="recursive", return_result=True),
                restore_multichannel(stack, return_result=True)]

    whole = run_all()
    monkeypatch.setattr(_combine, "CHUNK_VALUES", 200)  # a few rows a chunk
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 500)
    monkeypatch.setattr(recursive, "_CHUNK_WORK", 5e4)
    records = []
    drain(iter_restore(colour, return_result=True), records.append)
    assert {"reading", "centre", "moments", "models", "rows", "edges"} <= {
        r.stage for r in records}
    assert sum(r.stage == "models" for r in records) > 3
    chunked = run_all()
    for a, b in zip(whole, chunked, strict=True):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
            continue
        for name in ("observed", "prediction", "probability", "weight", "noise"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    # the conversion itself, for integer, float32, channel-first and float64 inputs
    for image, axis in ((colour, -1), (stack[0], -1), (np.moveaxis(colour, -1, 0), 0),
                        (grey, None), (-colour.astype(np.int16), -1)):
        assert channel_last_shape(image, channel_axis=axis) == as_channel_last_float(
            image, channel_axis=axis).shape
        want, want_summary = as_channel_last_float(image, channel_axis=axis,
                                                   with_summary=True)
        got, summary = drain(iter_channel_last_float(image, channel_axis=axis))
        np.testing.assert_array_equal(got, want)
        for x, y in zip(summary, want_summary, strict=True):
            np.testing.assert_array_equal(x, y)
    bad = grey.copy()
    bad[3, 4] = np.inf
    with pytest.raises(ValueError, match="1 NaN or infinite"):
        drain(iter_channel_last_float(bad, channel_axis=None))


def test_sharpness_in_strips_is_the_whole_image_measure(monkeypatch):
    from scipy import ndimage

    from car_napari.restoration import _combine

    rng = np.random.default_rng(6)
    stack = rng.random((3, 57, 41, 2))
    want = [np.mean([np.mean(ndimage.gaussian_laplace(v[..., c], 1.0) ** 2)
                     for c in range(2)]) for v in stack]
    monkeypatch.setattr(_combine, "CHUNK_VALUES", 100)
    np.testing.assert_array_equal(sharpness(stack), want)


@pytest.mark.parametrize("estimator", ["windowed", "recursive"])
@pytest.mark.parametrize("shape", [(64, 64), (48, 80, 3)])
@pytest.mark.parametrize("kappa", [0.0, 0.2])
def test_restore_and_the_results_restored_are_identical(estimator, shape, kappa):
    """restore() blends in the edge rule's kernel (one fused multiply-add);
    RestorationResult.restored() blended with NumPy, 1 ulp apart on about
    2 % of the values. Both now use the same expression under the same flags."""
    from car_napari.restoration import restore

    rng = np.random.default_rng(3)
    clean = np.add.outer(np.linspace(0, 1, shape[0]), np.linspace(0, 1, shape[1])) / 2
    if len(shape) == 3:
        clean = np.stack([clean, clean**2, 1 - clean], axis=-1)
    noisy = clean + rng.normal(0, 0.05, clean.shape)
    plain = restore(noisy, estimator=estimator, kappa=kappa)
    result = restore(noisy, estimator=estimator, kappa=kappa, return_result=True)
    assert result.weight is not None
    again = result.restored()
    np.testing.assert_array_equal(plain, again[..., 0] if plain.ndim == 2 else again)


def _window_mean(values, radius):
    """The mean of (H, W) or (H, W, C) ``values`` over the (2 radius + 1)^2
    square round each pixel, the part inside the image, by plain loops."""
    H, W = values.shape[:2]
    out = np.empty(values.shape)
    for i in range(H):
        for j in range(W):
            box = values[max(0, i - radius) : i + radius + 1, max(0, j - radius) : j + radius + 1]
            out[i, j] = box.reshape(-1, *values.shape[2:]).mean(axis=0)
    return out


def _numpy_edge_weight(observed, prediction, spread, noise):
    """The edge rule as docs/restoration.md states it: 1 where the 3 x 3 mean
    of the directions' spread exceeds EDGE_SPREAD mean(noise^2), else
    clip(1 - noise^2 / v, 0, 1) with v the 7 x 7 mean squared error."""
    from car_napari.restoration._combine import EDGE_SPREAD, EDGE_WINDOW

    v = _window_mean((observed - prediction) ** 2, EDGE_WINDOW // 2)
    weight = np.clip(1.0 - noise**2 / np.maximum(v, 1e-30), 0.0, 1.0)
    edge = _window_mean(spread, 1) > EDGE_SPREAD * np.mean(noise**2)
    return np.where(edge[..., None], 1.0, weight)


def test_edge_rule_is_the_windowed_noise_ratio_or_one_at_an_edge():
    """The edge rule's kernel (running sums, in halves) against plain loops
    over each pixel's 7 x 7 and 3 x 3 windows."""
    from car_napari.restoration._combine import edge_rule

    rng = np.random.default_rng(7)
    H, W, C = 19, 23, 2
    observed = rng.random((H, W, C))
    prediction = observed + rng.normal(0, 0.15, (H, W, C))
    noise = np.array([0.1, 0.2])
    # spread 0 or 0.1: 3 x 3 means at least 5 % from the threshold (0.0175)
    spread = np.where(rng.random((H, W)) < 0.15, 0.1, 0.0)
    want = _numpy_edge_weight(observed, prediction, spread, noise)
    assert 0 < np.mean(want == 1.0) < 1 and 0 < np.mean(want == 0.0) < 1  # all three cases
    for halves in (False, True):
        got = edge_rule(observed, prediction, spread, noise, halves=halves)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        blended = edge_rule(observed, prediction, spread, noise, blend=True, halves=halves)
        np.testing.assert_allclose(blended, prediction + want * (observed - prediction),
                                   rtol=0, atol=1e-12)


def _numpy_combination(observed, preds, rels):
    """Directions combined by local precision in plain NumPy: each direction
    weighted by (n / summed squared error)^DIRECTION_POWER over its predicted
    pixels in the 3 x 3 square round the pixel, the pixel left out; returns
    (prediction, probability, spread: the directions' variance averaged over
    channels where two or more vote)."""
    from car_napari.restoration._combine import DIRECTION_POWER

    H, W, C = observed.shape
    weights = []
    for pred in preds:
        ok = np.isfinite(pred[..., 0])
        err2 = np.where(ok, np.sum((observed - np.nan_to_num(pred)) ** 2, axis=-1), 0.0)
        weight = np.zeros((H, W))
        for i in range(H):
            for j in range(W):
                rows, cols = slice(max(0, i - 1), i + 2), slice(max(0, j - 1), j + 2)
                n = ok[rows, cols].sum() - ok[i, j]
                total = err2[rows, cols].sum() - err2[i, j]
                if ok[i, j] and n > 0:
                    weight[i, j] = min(n / max(total, 1e-300), 1e30) ** DIRECTION_POWER
        weights.append(weight)
    weights = np.array(weights)
    means = np.nan_to_num(np.array(preds))
    total = weights.sum(axis=0)
    votes = total > 0
    safe = np.where(votes, total, 1.0)
    prediction = np.where(votes[..., None],
                          np.einsum("khw,khwc->hwc", weights, means) / safe[..., None],
                          observed)
    probability = np.where(votes, np.sum(weights * np.nan_to_num(np.array(rels)), axis=0)
                           / safe, 1.0)
    voting = weights > 0
    count = voting.sum(axis=0)
    n = np.maximum(count, 1)[..., None]
    first = np.einsum("khw,khwc->hwc", voting, means) / n
    second = np.einsum("khw,khwc->hwc", voting, means**2) / n
    spread = np.where(count >= 2, (second - first**2).mean(axis=-1), 0.0)
    return prediction, probability, spread


def test_four_windowed_corners_combine_by_local_precision_as_in_numpy():
    """restore's four corners: each corner's model by dense least squares,
    their combination, probability and edge weights by plain NumPy."""
    rng = np.random.default_rng(5)
    image = ndimage.uniform_filter(rng.random((17, 19, 3)), (3, 3, 1))
    image += 0.05 * rng.random(image.shape)
    noise = np.array([0.03, 0.04, 0.05])  # edges at some pixels, not all
    result = restore(image, window=9, noise=noise, return_result=True)
    corners = ("up-left", "up-right", "down-left", "down-right")
    dense = [_dense_windowed(image, causal_neighbourhood(1), c, 9) for c in corners]
    pred, prob, spread = _numpy_combination(image, [p for p, _ in dense],
                                            [r for _, r in dense])
    np.testing.assert_allclose(result.prediction, pred, rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(result.probability, prob, rtol=1e-6, atol=1e-12)
    weight = _numpy_edge_weight(image, pred, spread, noise)
    assert 0 < np.mean(weight == 1.0) < 1
    np.testing.assert_allclose(result.weight, weight, rtol=1e-6, atol=1e-9)


def test_recursive_scans_down_and_up_combine_by_local_precision_as_in_numpy():
    """The recursive estimator's 'down' and 'up' scans (forgetting 1): each
    by the dense regression on the pixels before it ('up' is 'down' on the
    image upside down), combined by plain NumPy."""
    rng = np.random.default_rng(3)
    image = ndimage.uniform_filter(rng.random((14, 15)), 3) + 0.05 * rng.random((14, 15))
    result = restore(image, channel_axis=None, estimator="recursive", neighbourhood=2,
                     forgetting=1.0, directions=("down", "up"), noise=0.01,
                     return_result=True)
    offsets = causal_neighbourhood(2)
    down, rel_down = _dense_one_step(image, offsets)
    up, rel_up = (a[::-1] for a in _dense_one_step(image[::-1], offsets))
    pred, prob, spread = _numpy_combination(image[..., None], [down[..., None], up[..., None]],
                                            [rel_down, rel_up])
    np.testing.assert_allclose(result.prediction, pred, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(result.probability, prob, rtol=1e-6, atol=1e-10)
    weight = _numpy_edge_weight(image[..., None], pred, spread, np.array([0.01]))
    np.testing.assert_allclose(result.weight, weight, rtol=1e-5, atol=1e-8)


def test_psf_of_an_exact_convolution_is_its_kernel_unflipped():
    """observed = scipy's convolution of restored with an asymmetric kernel
    (wrapped, so that the means obey it too): estimate_psf gives the kernel
    itself, for a shared colour PSF and for each window's own kernel."""
    rng = np.random.default_rng(8)
    sharp = rng.random((40, 44, 3))
    kernel = rng.random((5, 5)) * np.add.outer(np.arange(5), 2 * np.arange(5))  # asymmetric
    observed = np.stack([ndimage.convolve(sharp[..., c], kernel, mode="wrap")
                         for c in range(3)], axis=-1)
    np.testing.assert_allclose(estimate_psf(observed, sharp, size=5), kernel, rtol=1e-9,
                               atol=1e-12)
    # a larger support finds zeros round the kernel
    wide = estimate_psf(observed, sharp, size=7)
    np.testing.assert_allclose(wide[1:-1, 1:-1], kernel, rtol=1e-9, atol=1e-11)
    assert np.abs(wide).sum() - np.abs(wide[1:-1, 1:-1]).sum() < 1e-10
    # windows: each 24 x 24 tile blurred by its own kernel
    grey = rng.random((48, 72))
    kernels = rng.random((2, 3, 3, 3))
    tiles = np.zeros_like(grey)
    for a in range(2):
        for b in range(3):
            part = (slice(24 * a, 24 * a + 24), slice(24 * b, 24 * b + 24))
            tiles[part] = ndimage.convolve(grey[part], kernels[a, b], mode="wrap")
    local = estimate_psf(tiles, grey, size=3, window=24, channel_axis=None)
    assert local.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(local, kernels, rtol=1e-9, atol=1e-12)


def test_psf_width_is_the_root_mean_second_moment():
    """psf_width of an asymmetric, partly negative PSF against the moments
    written out: negative taps clipped, centroid, variance along rows and
    columns averaged."""
    psf = np.array([[0.0, 1.0, 2.0, 0.5], [-1.0, 3.0, 4.0, 1.0], [0.0, 0.5, 1.0, -0.2]])
    w = np.clip(psf, 0, None)
    rows = np.array([0, 1, 2])[:, None] * np.ones(4)
    cols = np.ones(3)[:, None] * np.arange(4)
    mr, mc = (w * rows).sum() / w.sum(), (w * cols).sum() / w.sum()
    var_r = (w * (rows - mr) ** 2).sum() / w.sum()
    var_c = (w * (cols - mc) ** 2).sum() / w.sum()
    assert psf_width(psf) == pytest.approx(np.sqrt((var_r + var_c) / 2), rel=1e-12)


def _dense_versions(stack, offsets, reference, strength=1e-6, extra=None):
    """The 2.5D model of section 14.6 by plain NumPy, one colour channel:
    the reference version regressed on the causal neighbours in every
    version, the other versions at r, ``extra`` at r if given (an (H, W)
    image centred on its mean, like a version) and 1, over the earlier
    pixels (raster order; each version centred on its mean; V_0 as in the
    core); returns the one-step prediction and the relative Student-t
    density."""
    n = len(stack)
    if extra is not None:
        stack = np.concatenate([stack, extra[None]])
    means = stack.mean(axis=(1, 2))
    y = stack - means[:, None, None]
    _, H, W = y.shape
    var = y[reference].var()
    taps = [(di, dj, v) for v in range(n) for di, dj in offsets]
    taps += [(0, 0, v) for v in range(n) if v != reference]
    if extra is not None:
        taps.append((0, 0, n))
    p = len(taps) + 1
    V = np.diag(np.r_[np.full(p - 1, strength * var), strength, strength * var])
    count = 0
    pred = np.full((H, W), np.nan)
    rel = np.full((H, W), np.nan)
    for i in range(H):
        for j in range(W):
            if not all(0 <= i - di < H and 0 <= j - dj < W for di, dj, _ in taps):
                continue
            x = np.r_[[y[v, i - di, j - dj] for di, dj, v in taps], 1.0]
            gamma = np.linalg.solve(V[:p, :p], V[:p, p])
            lam = V[p, p] - V[:p, p] @ gamma
            q = 1.0 + x @ np.linalg.solve(V[:p, :p], x)
            e = y[reference, i, j] - gamma @ x
            pred[i, j] = gamma @ x + means[reference]
            rel[i, j] = (1.0 + e * e / (q * lam)) ** (-(count + 2) / 2)  # nu = count + 1
            z = np.r_[x, y[reference, i, j]]
            V = V + np.outer(z, z)
            count += 1
    return pred, rel


def test_multichannel_prediction_matches_the_dense_2_5d_regression():
    """One scan direction, forgetting 1: the 2.5D model's prediction and
    probability of a colour stack (one model per colour channel, the
    probability averaged over them) against the dense regression."""
    rng = np.random.default_rng(9)
    scene = ndimage.uniform_filter(rng.random((13, 14, 2)), (3, 3, 1))
    stack = scene + rng.normal(0, 0.03, (3, 13, 14, 2))
    stack[2] = 0.5 * stack[2] + 0.2  # versions of other gains and offsets
    result = restore_multichannel(stack, reference=1, directions=("down",), forgetting=1.0,
                                  keep_edges=False, reference_prediction=False,
                                  return_result=True)
    assert result.reference == 1
    offsets = causal_neighbourhood(1)
    dense = [_dense_versions(stack[..., c], offsets, 1) for c in range(2)]
    pred = np.stack([p for p, _ in dense], axis=-1)
    have = np.isfinite(pred[..., 0])
    np.testing.assert_allclose(result.prediction[have], pred[have], rtol=1e-6, atol=1e-12)
    # unpredicted pixels keep their value ((x - mean) + mean: one rounding)
    np.testing.assert_allclose(result.prediction[~have], stack[1][~have], rtol=0,
                               atol=1e-15)
    prob = np.mean([r for _, r in dense], axis=0)
    np.testing.assert_allclose(result.probability[have], prob[have], rtol=1e-6, atol=1e-12)
    assert np.all(result.probability[~have] == 1.0)



def test_the_reference_prediction_enters_the_2_5d_regression_as_one_more_regressor():
    """reference_prediction: the reference's single-image prediction
    (restore's defaults, edges not kept: its own tests compare it with
    dense least squares) is one more regressor at r, after the versions,
    centred on its mean like them; the prediction and probability against
    the dense regression with that column. A grey stack larger than half
    the default window (a narrower window would predict otherwise)."""
    rng = np.random.default_rng(10)
    scene = ndimage.uniform_filter(rng.random((30, 32)), 3)
    stack = scene + rng.normal(0, 0.03, (3, 30, 32))
    stack[0] = 0.8 * stack[0] + 0.1
    result = restore_multichannel(stack, reference=2, directions=("down",), forgetting=1.0,
                                  keep_edges=False, reference_prediction=True,
                                  return_result=True)
    single = restore(stack[2], keep_edges=False, return_result=True).prediction[..., 0]
    offsets = causal_neighbourhood(1)
    pred, prob = _dense_versions(stack, offsets, 2, extra=single)
    have = np.isfinite(pred)
    np.testing.assert_allclose(result.prediction[..., 0][have], pred[have], rtol=1e-6,
                               atol=1e-12)
    np.testing.assert_allclose(result.prediction[..., 0][~have], stack[2][~have], rtol=0,
                               atol=1e-15)
    np.testing.assert_allclose(result.probability[have], prob[have], rtol=1e-6, atol=1e-12)
    # the extra column changes the fit: without it the prediction differs
    without = _dense_versions(stack, offsets, 2)[0]
    assert np.abs(without[have] - pred[have]).max() > 1e-3

def test_a_far_image_is_restored_at_its_nearest_power_of_two_and_scaled_back():
    """An image whose spread is near 2**e (|e| > 32, e the integer nearest
    log2 of the spread, by np.frexp) is restored as the image times 2**-e,
    its observed, prediction, noise and restored values multiplied back by
    2**e, bit for bit; probabilities and weights unchanged. A given noise
    is scaled with the image."""
    rng = np.random.default_rng(2)
    unit = _degraded(img_as_float(skdata.camera())[:40, :40], rng) * 12.0  # spread 3.7
    for power in (70, -90):
        far = np.ldexp(unit, power)
        m, k = np.frexp(np.ptp(far))
        e = int(k) if m >= np.sqrt(0.5) else int(k) - 1
        assert abs(e) > 32 and e != power  # not the power it was made with
        near = np.ldexp(far, -e)
        for noise in (None, 0.04):
            far_noise = None if noise is None else np.ldexp(noise, power)
            near_noise = None if noise is None else np.ldexp(far_noise, -e)
            got = restore(far, channel_axis=None, noise=far_noise, return_result=True)
            want = restore(near, channel_axis=None, noise=near_noise, return_result=True)
            for name in ("observed", "prediction", "noise"):
                np.testing.assert_array_equal(getattr(got, name),
                                              np.ldexp(getattr(want, name), e), err_msg=name)
            np.testing.assert_array_equal(got.probability, want.probability)
            np.testing.assert_array_equal(got.weight, want.weight)
            np.testing.assert_array_equal(
                restore(far, channel_axis=None, noise=far_noise),
                np.ldexp(restore(near, channel_axis=None, noise=near_noise), e))
        stack = np.stack([far, np.ldexp(unit * 0.9 + 0.05, power)])
        got = restore_multichannel(stack, reference=0, return_result=True)
        want = restore_multichannel(np.ldexp(stack, -e), reference=0, return_result=True)
        for name in ("observed", "prediction", "noise"):
            np.testing.assert_array_equal(getattr(got, name),
                                          np.ldexp(getattr(want, name), e), err_msg=name)
        np.testing.assert_array_equal(got.probability, want.probability)
