"""Multiresolution texture synthesis and compression (section 14.8, docs/texture.md)."""

import json

import numpy as np
import pytest
from skimage import data as skdata

from car_napari import Progress, fit_car, spectral_radius
from car_napari._progress import drain
from car_napari.texture import (
    FORMAT_VERSION,
    TextureModel,
    _spectral,
    collapse_pyramid,
    iter_fit_texture,
    laplacian_pyramid,
)


@pytest.fixture(scope="module")
def gravel_model():
    return TextureModel.fit(skdata.gravel())


@pytest.fixture(scope="module")
def colour_model():
    return TextureModel.fit(skdata.astronaut()[300:450, 30:180], levels=2)  # grass crop


def test_pyramid_collapse_is_exact_at_odd_sizes():
    x = np.random.default_rng(0).random((67, 93, 2))
    bands = laplacian_pyramid(x, levels=4)
    assert [b.shape[:2] for b in bands] == [(67, 93), (34, 47), (17, 24), (9, 12)]
    np.testing.assert_allclose(collapse_pyramid(bands), x, atol=1e-12)


def test_pyramid_of_grey_and_channel_first_images_keeps_the_layout():
    x = np.random.default_rng(1).random((40, 51, 2))
    channel_last = laplacian_pyramid(x, levels=3)
    grey = laplacian_pyramid(x[..., 0], levels=3)
    first = laplacian_pyramid(np.moveaxis(x, -1, 0), levels=3, channel_axis=0)
    for c, g, f in zip(channel_last, grey, first, strict=True):
        assert g.shape == c.shape[:2] and f.shape == (2,) + c.shape[:2]
        np.testing.assert_array_equal(g, c[..., 0])  # channels are filtered independently
        np.testing.assert_array_equal(f, np.moveaxis(c, -1, 0))
    np.testing.assert_allclose(collapse_pyramid(grey), x[..., 0], atol=1e-12)
    np.testing.assert_allclose(collapse_pyramid(first, channel_axis=0),
                               np.moveaxis(x, -1, 0), atol=1e-12)
    with pytest.raises(ValueError, match="levels"):
        laplacian_pyramid(x, levels=0)
    with pytest.raises(ValueError, match="2-D"):
        collapse_pyramid([grey[0], channel_last[1]])


def _same_texture_model(a, b):
    assert a.orders == b.orders and a.fallbacks == b.fallbacks and a.grey == b.grey
    for ma, mb in zip(a.models, b.models, strict=True):
        np.testing.assert_array_equal(ma.gamma, mb.gamma)
        np.testing.assert_array_equal(ma.sigma, mb.sigma)
    np.testing.assert_array_equal(a.quantiles, b.quantiles)
    np.testing.assert_array_equal(a.synthesize((40, 30), seed=3), b.synthesize((40, 30), seed=3))


def test_iter_fit_texture_reports_every_level_and_returns_the_fit():
    texture = skdata.gravel()[:128, :160]
    job = iter_fit_texture(texture, levels=3, neighbourhood=2)
    records = []
    result = drain(job, records.append)
    assert all(isinstance(r, Progress) for r in records)
    # the input's quantiles, the pyramid, the fits, the bands' quantiles
    assert list(dict.fromkeys(r.stage for r in records)) == [
        "reading", "quantiles", "pyramid", "fitting"]
    assert records[-1].message == "3 levels fitted" and records[-1].fraction == 1
    fits = [r.message for r in records if r.stage == "fitting"]
    for k in (1, 2, 3):  # every band's fit reports its blocks of rows
        assert any(m.startswith(f"level {k}/3: rows ") for m in fits), fits
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and 0 < fractions[0] and fractions[-1] == 1
    _same_texture_model(result, TextureModel.fit(texture, levels=3, neighbourhood=2))


def test_iter_fit_texture_yields_often_on_a_large_texture(monkeypatch):
    # every pass runs by blocks of rows: with small blocks, many records per
    # part, and the same model as with the default blocks

    texture = skdata.gravel()[:256, :256]
    whole = TextureModel.fit(texture, levels=3, neighbourhood=2, pyramid="gaussian")
    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", 4096)
    records = []
    chunked = drain(iter_fit_texture(texture, levels=3, neighbourhood=2, pyramid="gaussian"),
                    records.append)
    by_stage = {s: sum(r.stage == s for r in records) for s in ("reading", "quantiles",
                                                                 "pyramid")}
    assert by_stage["reading"] >= 16 and by_stage["quantiles"] >= 3 * 16, by_stage
    assert by_stage["pyramid"] >= 16, by_stage
    _same_texture_model(whole, chunked)


def test_exact_quantiles_by_blocks_equal_numpys(monkeypatch):
    from car_napari.texture import _histogram

    rng = np.random.default_rng(0)
    cases = [rng.random((100, 70, 3)), rng.standard_normal((257, 33, 1)) ** 3,
             np.round(rng.random((50, 60, 2)) * 4) / 4,  # heavy ties
             np.concatenate([np.zeros((40, 40, 1)), rng.random((3, 40, 1))]),
             rng.random((1, 1, 2)), np.full((10, 10, 1), 0.3)]
    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", 997)
    for values in cases:
        for n in (32, 64, 5):
            q, lo, hi = drain(_histogram._iter_quantiles(values, n))
            expected = np.quantile(values.reshape(-1, values.shape[2]),
                                   np.linspace(0, 1, n), axis=0)
            np.testing.assert_array_equal(q, expected.astype(np.float32).astype(float))
            np.testing.assert_array_equal(lo, values.min(axis=(0, 1)))
            np.testing.assert_array_equal(hi, values.max(axis=(0, 1)))


def test_pyramid_by_blocks_is_the_same(monkeypatch):
    from car_napari.texture import _pyramid

    x = np.random.default_rng(2).random((67, 93, 2))
    whole = laplacian_pyramid(x, levels=4)
    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", 64)  # a row or two a block
    for a, b in zip(whole, laplacian_pyramid(x, levels=4), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(_pyramid._expand(x, (131, 180), wrap=True),
                                  _pyramid._cubic_axis(_pyramid._cubic_axis(x, 131, 0, True),
                                                       180, 1, True))


@pytest.mark.parametrize("shape", [(20, 26), (21, 17)])
def test_pyramid_levels_are_the_blur_and_block_mean_and_keys_cubic(shape):
    """The Gaussian pyramid's operators against plain SciPy/NumPy: a level
    down is a Gaussian blur (sigma 1, reflected borders) averaged over 2 x 2
    blocks, odd sides padded by their last row or column; a level up is
    Keys cubic convolution (a = -0.5) with aligned pixel extents, which
    reproduces a quadratic exactly where its four taps are inside."""
    from scipy import ndimage

    from car_napari.texture._pyramid import _expand

    x = np.random.default_rng(5).random(shape + (2,))
    blurred = ndimage.gaussian_filter(x, sigma=(1.0, 1.0, 0), mode="reflect")
    blurred = np.pad(blurred, ((0, shape[0] % 2), (0, shape[1] % 2), (0, 0)), mode="edge")
    h, w = blurred.shape[0] // 2, blurred.shape[1] // 2
    want = blurred.reshape(h, 2, w, 2, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(laplacian_pyramid(x, levels=2)[1], want, rtol=0, atol=1e-14)

    def quadratic(i, j):
        return 0.3 + 0.1 * i - 0.05 * j + 0.002 * i * i + 0.001 * i * j - 0.003 * j * j

    i, j = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    out_shape = (2 * shape[0] + 1, 2 * shape[1] - 3)
    got = _expand(quadratic(i, j)[..., None], out_shape)[..., 0]
    ci = (np.arange(out_shape[0]) + 0.5) * shape[0] / out_shape[0] - 0.5
    cj = (np.arange(out_shape[1]) + 0.5) * shape[1] / out_shape[1] - 0.5
    inside_i = (np.floor(ci) >= 1) & (np.floor(ci) + 2 <= shape[0] - 1)
    inside_j = (np.floor(cj) >= 1) & (np.floor(cj) + 2 <= shape[1] - 1)
    want = quadratic(ci[:, None], cj[None, :])
    np.testing.assert_allclose(got[np.ix_(inside_i, inside_j)],
                               want[np.ix_(inside_i, inside_j)], rtol=0, atol=1e-12)

def test_iter_fit_texture_validates_before_the_first_record_and_can_be_closed():
    with pytest.raises(ValueError, match="64x64"):
        next(iter_fit_texture(np.random.default_rng(0).random((60, 200)), levels=3))
    job = iter_fit_texture(skdata.gravel()[:64, :64], levels=2)
    assert next(job).stage == "reading"
    job.close()  # a cancel: no error, no further work
    with pytest.raises(StopIteration):
        next(job)


@pytest.mark.parametrize("name, other", [("gravel", "brick"), ("brick", "gravel")])
def test_refit_of_synthesis_matches_the_fit(name, other):
    # Order 1 everywhere so the bands' parameters are directly comparable.
    fits = {n: TextureModel.fit(getattr(skdata, n)(), neighbourhood=1, levels=3,
                                pyramid="gaussian") for n in (name, other)}
    sample = fits[name].synthesize((512, 512), seed=0)
    refit = TextureModel.fit(sample, neighbourhood=1, channel_axis=None, levels=3,
                             pyramid="gaussian")
    diff = [np.abs(a.gamma - b.gamma).max()
            for a, b in zip(fits[name].models, refit.models, strict=True)]
    # The coarse bands come back closely; the finest band less so, because the
    # independently generated bands leak into it when the synthesis is re-analysed.
    assert max(diff[1:]) < 0.06, diff
    assert diff[0] < 0.2, diff
    # ... and still, the synthesis is far closer to its own texture than to another.
    to_other = [np.abs(a.gamma - b.gamma).max()
                for a, b in zip(fits[other].models, refit.models, strict=True)]
    assert sum(diff) < 0.5 * sum(to_other), (diff, to_other)


def test_output_restores_mean_contrast_and_range(gravel_model):
    texture = skdata.gravel() / 255.0
    out = gravel_model.synthesize((300, 400), seed=1)
    assert out.dtype == np.float64 and out.shape == (300, 400)
    assert abs(out.mean() - texture.mean()) < 0.01
    assert abs(out.std() / texture.std() - 1) < 0.05
    # the range is stored in float32: equal to the input's within 1e-6
    assert texture.min() - 1e-6 <= out.min() and out.max() <= texture.max() + 1e-6


def test_each_band_gets_its_own_decision_rule_support(gravel_model):
    bands = _spectral.pyramid(skdata.gravel()[..., None] / 255.0, gravel_model.levels)
    for band, model in zip(bands, gravel_model.models, strict=True):
        assert model.order == fit_car(band, "auto").order
        assert spectral_radius(model) < 1


def test_arbitrary_shapes_seeds_and_channels(gravel_model, colour_model):
    a = gravel_model.synthesize((100, 300), seed=5)
    b = gravel_model.synthesize((100, 300), seed=5)
    c = gravel_model.synthesize((100, 300), seed=6)
    assert a.shape == (100, 300)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert gravel_model.synthesize((1, 1), seed=0).shape == (1, 1)
    colour = colour_model.synthesize((37, 211), seed=2)
    assert colour.shape == (37, 211, 3) and np.isfinite(colour).all()
    g = np.random.default_rng(3)
    assert gravel_model.synthesize((9, 7), seed=g).shape == (9, 7)


def test_channel_axis_and_2d_model():
    crop = skdata.astronaut()[300:450, 30:180]
    first = TextureModel.fit(np.moveaxis(crop, -1, 0), levels=2, channel_axis=0, model="2d")
    assert first.model == "2d" and first.n_channels == 3
    out = first.synthesize((64, 80), seed=0)
    assert out.shape == (64, 80, 3)  # channel-last, napari's order


def test_save_load_round_trip(tmp_path, colour_model):
    path = tmp_path / "grass.npz"
    colour_model.save(path)
    loaded = TextureModel.load(path)
    np.testing.assert_array_equal(
        loaded.synthesize((70, 90), seed=11), colour_model.synthesize((70, 90), seed=11)
    )
    np.testing.assert_array_equal(
        loaded.synthesize((40, 50), seed=1, tileable=True),
        colour_model.synthesize((40, 50), seed=1, tileable=True),
    )
    assert loaded.orders == colour_model.orders and loaded.nbytes == colour_model.nbytes
    with np.load(path) as archive:  # the header is plain JSON, readable without the package
        header = json.loads(str(archive["header"]))
    assert header["format"] == "car-napari texture model" and header["version"] == FORMAT_VERSION


def test_loads_version_1_files_without_quantiles(tmp_path, colour_model):
    path = tmp_path / "grass.npz"
    colour_model.save(path)
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files if "quantiles" not in k}
    header = json.loads(str(arrays["header"]))
    old = tmp_path / "old.npz"
    np.savez(old, **{**arrays, "header": np.array(json.dumps({**header, "version": 1}))})
    loaded = TextureModel.load(old)
    assert loaded.band_quantiles is None and loaded.quantiles is None
    assert loaded.nbytes < colour_model.nbytes
    out = loaded.synthesize((60, 70), seed=0)  # no histogram matching, as version 1 did
    assert out.shape == (60, 70, 3) and np.isfinite(out).all()
    assert not np.array_equal(out, colour_model.synthesize((60, 70), seed=0))


def test_histograms_of_bands_and_output_are_restored(gravel_model):
    texture = skdata.gravel() / 255.0
    out = gravel_model.synthesize((512, 512), seed=0)
    probs = np.linspace(0.05, 0.95, 19)
    assert np.abs(np.quantile(out, probs) - np.quantile(texture, probs)).max() < 0.02
    assert gravel_model.band_quantiles.shape == (gravel_model.levels, 32, 1)
    assert gravel_model.quantiles.shape == (64, 1)
    # the stored quantiles are those of the analysed bands, ends at min and max
    bands = _spectral.pyramid(texture[..., None], gravel_model.levels)
    stored = zip(bands, gravel_model.band_quantiles, gravel_model.band_ranges, strict=True)
    for band, q, r in stored:
        np.testing.assert_allclose(q[[0, -1]], r, atol=1e-6)
        np.testing.assert_allclose(q[16, 0], np.quantile(band, 16 / 31), atol=1e-6)


def test_load_rejects_corrupt_and_newer_files(tmp_path, gravel_model):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 definitely not a zip archive")
    with pytest.raises(ValueError, match="not a readable"):
        TextureModel.load(junk)
    other = tmp_path / "other.npz"
    np.savez(other, x=np.arange(3))
    with pytest.raises(ValueError, match="header"):
        TextureModel.load(other)

    path = tmp_path / "gravel.npz"
    gravel_model.save(path)
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files}
    header = json.loads(str(arrays["header"]))
    newer = tmp_path / "newer.npz"
    np.savez(newer, **{**arrays, "header": np.array(json.dumps({**header, "version": 99}))})
    with pytest.raises(ValueError, match="newer"):
        TextureModel.load(newer)
    damaged = tmp_path / "damaged.npz"
    np.savez(damaged, **{k: v for k, v in arrays.items() if k != "band1_gamma"})
    with pytest.raises(ValueError, match="damaged"):
        TextureModel.load(damaged)


def test_too_small_texture_names_the_minimum():
    small = np.random.default_rng(0).random((60, 200))
    with pytest.raises(ValueError, match="64x64"):
        TextureModel.fit(small, levels=3)
    with pytest.raises(ValueError, match="128x128"):
        TextureModel.fit(small, levels=4)
    assert TextureModel.fit(small, levels=2).levels == 2  # 32x32 suffices for 2 levels


def test_bad_arguments():
    texture = skdata.gravel()[:64, :64]
    with pytest.raises(ValueError, match="levels"):
        TextureModel.fit(texture, levels=0)
    with pytest.raises(ValueError, match="model"):
        TextureModel.fit(texture, levels=1, model="4d")
    with pytest.raises(ValueError, match="constant"):
        TextureModel.fit(np.ones((64, 64)), levels=1)
    model = TextureModel.fit(texture, levels=1)
    with pytest.raises(ValueError, match="shape"):
        model.synthesize((0, 5))


def test_compression_ratio_at_512x512x3():
    model = TextureModel.fit(skdata.astronaut(), levels=3)  # 512 x 512 x 3
    # independent count: gamma d x d*eta, sigma d x d, band mean, band range,
    # offsets eta x 2, 32 quantiles x d per band; global mean, std, range and
    # 64 quantiles x d
    d = 3
    expected = sum(d * d * m.eta + d * d + d + 2 * d + 2 * m.eta + 32 * d for m in model.models)
    k = model.palette.shape[0]  # the palette: k colours and their radii
    expected = 4 * (expected + d + d + 2 * d + 64 * d + k * d + k)
    assert model.nbytes == expected
    assert model.compression_ratio((512, 512, 3)) >= 500
    assert model.compression_ratio((512, 512)) == model.compression_ratio((512, 512, 3))


def test_unstable_band_falls_back_and_says_so():
    # brick's order-1 model of band 1 is (just) unstable, and so would explode
    model = TextureModel.fit(skdata.brick(), neighbourhood=1, levels=3, pyramid="gaussian")
    assert model.fallbacks and "band 1" in model.fallbacks[0]
    assert all(spectral_radius(m) < 1 for m in model.models)
    out = model.synthesize((128, 128), seed=0)
    assert np.isfinite(out).all()
    auto = TextureModel.fit(skdata.brick(), neighbourhood=2, levels=3, pyramid="gaussian")
    assert auto.fallbacks and all(spectral_radius(m) < 1 for m in auto.models)


def _seam_ratios(texture):
    """Mean |difference| across the wrap (last vs first column, last vs first
    row) over the median of the same for interior neighbouring columns/rows."""
    t = texture if texture.ndim == 3 else texture[..., None]
    cols = np.abs(np.diff(t, axis=1)).mean(axis=(0, 2))
    rows = np.abs(np.diff(t, axis=0)).mean(axis=(1, 2))
    wrap_col = np.abs(t[:, -1] - t[:, 0]).mean()
    wrap_row = np.abs(t[-1] - t[0]).mean()
    return wrap_col / np.median(cols), wrap_row / np.median(rows)


@pytest.mark.parametrize("shape", [(256, 256), (100, 300), (97, 131)])
def test_tileable_has_no_seam(gravel_model, shape):
    ratios = np.array([_seam_ratios(gravel_model.synthesize(shape, seed=s, tileable=True))
                       for s in range(4)])
    assert ratios.mean(axis=0).max() < 1.2, ratios
    plain = np.array([_seam_ratios(gravel_model.synthesize(shape, seed=s)) for s in range(2)])
    assert plain.mean(axis=0).min() > 1.5, plain  # the test does see a seam when there is one


def test_tileable_colour(colour_model):
    outs = [colour_model.synthesize((90, 120), seed=s, tileable=True) for s in range(4)]
    assert outs[0].shape == (90, 120, 3)
    assert np.mean([_seam_ratios(o) for o in outs], axis=0).max() < 1.2


def test_vistex_texture(shared_data):
    from skimage import io

    path = shared_data / "textures" / "vistex" / "VS1.png"
    if not path.exists():
        pytest.skip(f"{path} not found")
    texture = io.imread(path)[:256, :256]
    model = TextureModel.fit(texture)
    out = model.synthesize((128, 192), seed=0)
    assert out.shape == (128, 192, 3)
    ref = texture / 255.0
    assert np.all(np.abs(out.mean(axis=(0, 1)) - ref.mean(axis=(0, 1))) < 0.02)


def _isolated_fraction(image, threshold=0.25):
    """Fraction of pixels differing from their 3x3 median by more than
    ``threshold`` in some channel (values in [0, 1]): isolated speckle."""
    from scipy import ndimage as ndi

    x = np.asarray(image, float)
    x = x[..., None] if x.ndim == 2 else x
    median = np.stack([ndi.median_filter(x[..., c], size=3) for c in range(x.shape[2])], -1)
    return float((np.abs(x - median).max(axis=-1) > threshold).mean())


def test_histogram_matching_does_not_scatter_pixels_to_the_extremes():
    # A Gaussian band mapped onto the 32 quantiles of a heavy-tailed band:
    # linear between the last stored quantile and the maximum would put 1.8 %
    # of the pixels beyond the band's 0.999 quantile (isolated bright and
    # dark pixels: speckle); the band itself has 0.1 % there.
    from car_napari.texture import _blocks, _histogram

    rng = np.random.default_rng(0)
    band = rng.laplace(size=(300, 300, 1))
    quantiles = _blocks._f32(np.quantile(band.reshape(-1, 1), np.linspace(0, 1, 32), axis=0))
    out = _histogram._match(rng.standard_normal((300, 300, 1)), quantiles)
    for p in (0.999, 0.001):
        beyond = np.quantile(band, p)
        share = (out > beyond).mean() if p > 0.5 else (out < beyond).mean()
        assert share < 0.003, (p, share)
    # still monotone, onto the band's range, and the body untouched
    assert out.min() >= quantiles[0, 0] and out.max() <= quantiles[-1, 0]
    probs = np.linspace(0.1, 0.9, 17)  # (the stored quantiles are 1/31 apart)
    assert np.abs(np.quantile(out, probs) - np.quantile(band, probs)).max() < 0.02


def test_synthesis_of_the_vistex_sample_has_no_speckle():
    # Synthesised textures showed isolated single-pixel speckle (2 % of the
    # pixels against 0.01 % in the texture): the histogram matching spread the
    # extreme quantile intervals evenly up to the bands' minimum and maximum.
    from skimage import io

    from car_napari.io.sample_data import resource_path

    texture = io.imread(resource_path("texture_vistex_VS50.png"))[..., :3]
    model = TextureModel.fit(texture)
    own = _isolated_fraction(texture / 255.0)
    for seed in (0, 1):
        out = model.synthesize((256, 256), seed=seed)
        speckle = _isolated_fraction(out)
        assert speckle < max(10 * own, 1e-3), (seed, speckle, own)


# ---------------------------------------------------------------- synthesis as a job
# Today's (session 19's) one-call synthesis, kept verbatim as the reference of
# the job form: whole-array passes, no blocks.

def _reference_match(values, quantiles, bins=4096):
    h, w, d = values.shape
    flat = values.reshape(-1, d)
    out = np.empty_like(flat)
    q = quantiles.shape[0]
    for c in range(d):
        v = flat[:, c]
        lo, hi = float(v.min()), float(v.max())
        if hi <= lo:
            out[:, c] = quantiles[q // 2, c]
            continue
        counts, _ = np.histogram(v, bins=bins, range=(lo, hi))
        cdf = np.concatenate([[0.0], np.cumsum(counts) / v.size])
        pos = (v - lo) * (bins / (hi - lo))
        k = np.minimum(pos.astype(np.int64), bins - 1)
        p = cdf[k] + (pos - k) * (cdf[k + 1] - cdf[k])
        pos = p * (q - 1)
        k = np.minimum(pos.astype(np.int64), q - 2)
        mapped = quantiles[k, c] + (pos - k) * (quantiles[k + 1, c] - quantiles[k, c])
        if q >= 4:  # exponential tails (written out from the rule stated in _iter_match)
            qc = quantiles[:, c]
            # top: at t = q - 1 - pos from probability 1, q[-2] + s log(1 / t),
            # through q[-3] at t = 2; the linear map where it is lower, or s = 0
            s = (qc[-2] - qc[-3]) / np.log(2.0)
            top = k == q - 2
            if s > 0:
                mapped[top] = np.minimum(mapped[top], qc[-2] - s * np.log((q - 1) - pos[top]))
            s = (qc[2] - qc[1]) / np.log(2.0)  # bottom: the same mirrored, t = pos
            bottom = k == 0
            if s > 0:
                mapped[bottom] = np.maximum(mapped[bottom], qc[1] + s * np.log(pos[bottom]))
        out[:, c] = mapped
    return out.reshape(h, w, d)


def _reference_torus(field, shape, mean):
    h, w = shape
    f = field - mean
    for axis, n in ((1, w), (0, h)):
        b = f.shape[axis] - n
        if b > 0:
            t = 0.5 * np.pi * np.arange(b) / b
            shape_w = [1, 1, 1]
            shape_w[axis] = b
            own, extra = np.sin(t).reshape(shape_w), np.cos(t).reshape(shape_w)
            head = np.take(f, np.arange(b), axis=axis)
            tail = np.take(f, np.arange(n, n + b), axis=axis)
            body = np.take(f, np.arange(b, n), axis=axis)
            f = np.concatenate([own * head + extra * tail, body], axis=axis)
    return f + mean


def _reference_synthesis(self, shape, seed, tileable=False):
    from car_napari import synthesize
    from car_napari.model.synthesis import burn_in, spectral_radius
    from car_napari.texture._pyramid import _expand, _level_shapes
    from car_napari.texture._synthesis import _BAND_TRANSIENT, _MAX_BAND_MARGIN, _blend_width

    h, w = shape
    rng = np.random.default_rng(seed)
    streams = [np.random.default_rng(s) for s in rng.integers(0, 2**63, size=self.levels)]
    bands = []
    for k, (model, (hk, wk)) in enumerate(zip(self.models, _level_shapes((h, w), self.levels),
                                              strict=True)):
        margin = min(burn_in(spectral_radius(model), _BAND_TRANSIENT), _MAX_BAND_MARGIN)
        if tileable:
            bh, bw = _blend_width(hk), _blend_width(wk)
            big = synthesize(model, (hk + bh, wk + bw), seed=streams[k], margin=margin)
            band = _reference_torus(big.reshape(hk + bh, wk + bw, -1), (hk, wk), model.mean)
        else:
            band = synthesize(model, (hk, wk), seed=streams[k], margin=margin).reshape(hk, wk,
                                                                                     -1)
        if self.pyramid == "spectral" and k < self.levels - 1:
            band = drain(_spectral.iter_highpass(band, wrap=bool(tileable), single=True))
        if self.band_quantiles is not None:
            band = _reference_match(band, self.band_quantiles[k])
        bands.append(np.clip(band, self.band_ranges[k, 0], self.band_ranges[k, 1]))
    if self.pyramid == "spectral":
        out = _spectral.collapse(bands, wrap=bool(tileable), single=True)
    else:
        out = bands[-1]
        for band in bands[-2::-1]:
            out = band + _expand(out, band.shape[:2], wrap=bool(tileable))
    centred = out - out.mean(axis=(0, 1))
    spread = centred.std(axis=(0, 1))
    gain = np.where(spread > 0, self.std / np.where(spread > 0, spread, 1.0), 1.0)
    out = self.mean + centred * gain
    if self.quantiles is not None:
        out = _reference_match(out, self.quantiles)
    out = np.clip(out, self.value_range[0], self.value_range[1])
    if self.palette is not None:  # (its numbers against plain NumPy: test_palette_snap_...)
        from car_napari.texture import _palette

        out = _palette.snap(out, self.palette, self.palette_radius)
    return out[..., 0] if self.grey else out


def _reference_snap(values, centres, radius):
    """Plain NumPy: every pixel farther from its nearest centre than that
    centre's radius, moved onto the radius along the line to it."""
    flat = values.reshape(-1, values.shape[-1])
    dist = np.sqrt(((flat[:, None, :] - centres[None]) ** 2).sum(-1))
    near = np.argmin(dist, axis=1)
    d = dist[np.arange(len(flat)), near]
    r = radius[near]
    factor = np.where(d > r, r / np.where(d > 0, d, 1.0), 1.0)
    out = centres[near] + (flat - centres[near]) * factor[:, None]
    return out.reshape(values.shape)


def test_palette_snap_equals_plain_numpy_and_keeps_inliers():
    from car_napari.texture import _palette

    rng = np.random.default_rng(4)
    image = np.concatenate([rng.normal(0.2, 0.03, (40, 50, 3)),
                            rng.normal(0.7, 0.05, (40, 50, 3))], axis=1)
    centres, radius = _palette.fit_palette(image, 4)
    assert centres.shape == (4, 3) and (radius > 0).all()
    # every centre sits in one of the two clusters
    assert np.all((np.abs(centres - 0.2) < 0.1).all(1) | (np.abs(centres - 0.7) < 0.1).all(1))
    values = rng.random((30, 20, 3))
    np.testing.assert_allclose(_palette.snap(values, centres, radius),
                               _reference_snap(values, centres, radius), atol=1e-12)
    inside = image[:5, :5]  # pixels near a centre: most stay
    moved = np.any(_palette.snap(inside, centres, radius) != inside, axis=-1)
    assert moved.mean() < 0.2


@pytest.mark.parametrize("k, channels", [(1, 3), (2, 3), (7, 3), (32, 3), (5, 1), (9, 2)])
def test_palette_snap_search_finds_the_nearest_colour_with_ties(k, channels):
    # the kernel scans the colours a colour at a time over blocks of pixels:
    # on a coarse grid (many equal distances, repeated colours) it must pick
    # the nearest colour, the lowest index among equals, with the distances
    # summed as plain NumPy sums them; also in place, and for any pixel
    # count (1200: not a whole number of blocks)
    from car_napari.texture import _palette

    rng = np.random.default_rng(k)
    centres = np.round(rng.random((k, channels)), 1)
    centres[k // 2] = centres[0]
    radius = rng.random(k) * 0.2
    values = np.round(rng.random((40, 30, channels)), 1)
    flat = values.reshape(-1, channels)
    squared = ((flat[:, None, :] - centres[None]) ** 2).sum(-1)  # (the kernel's sums)
    nearest = np.argmin(squared, axis=1)
    best = squared[np.arange(len(flat)), nearest]
    r = radius[nearest]
    want = np.where((best > r * r)[:, None],
                    centres[nearest] + (flat - centres[nearest]) * (r / np.sqrt(best))[:, None],
                    flat)
    got = _palette.snap(values, centres, radius)
    np.testing.assert_array_equal(got.reshape(-1, channels), want)
    np.testing.assert_array_equal(_palette.snap(values, centres, radius, out=values), got)


@pytest.mark.parametrize("tileable", [False, True])
def test_synthesis_job_is_bit_identical_to_the_one_call_synthesis(gravel_model, colour_model,
                                                                  tileable, monkeypatch):

    two_d = TextureModel.fit(skdata.astronaut()[300:364, 0:64], levels=1, model="2d")
    cases = [(gravel_model, (37, 53)), (colour_model, (64, 41)), (two_d, (20, 30))]
    expected = [_reference_synthesis(m, shape, 3, tileable) for m, shape in cases]
    for (model, shape), want in zip(cases, expected, strict=True):
        np.testing.assert_array_equal(model.synthesize(shape, seed=3, tileable=tileable), want)
    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", 97)  # blocks of a row or two
    for (model, shape), want in zip(cases, expected, strict=True):
        records = []
        got = drain(model.iter_synthesize(shape, seed=3, tileable=tileable), records.append)
        np.testing.assert_array_equal(got, want)
        assert got.shape == want.shape
        fractions = [r.fraction for r in records]
        assert fractions == sorted(fractions) and fractions[-1] == 1.0
        previews = [r.preview for r in records if r.preview is not None]
        assert previews[-1] is got  # the texture filling in, the array returned
        stages = list(dict.fromkeys(r.stage for r in records))
        assert stages == ["synthesis", "collapse", "restore"] or (
            model.levels == 1 and stages == ["synthesis", "restore"])
    # a version-1 model (no quantiles): clipping only, the same numbers
    v1 = TextureModel(**{**colour_model.__dict__, "band_quantiles": None, "quantiles": None})
    np.testing.assert_array_equal(drain(v1.iter_synthesize((33, 30), seed=1)),
                                  _reference_synthesis(v1, (33, 30), 1))


def test_synthesis_job_yields_between_blocks_and_stops_when_closed(colour_model, monkeypatch):
    # fractions in proportion to the work: no part of the job jumps far
    from car_napari.model import blocks, synthesis

    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", 512)
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 1500)
    monkeypatch.setattr(synthesis, "_CHUNK_FLOPS", 1e5)
    records = list(colour_model.iter_synthesize((160, 200), seed=0))
    fractions = np.array([r.fraction for r in records])
    assert len(records) > 100 and np.diff(fractions).max() < 0.1
    job = colour_model.iter_synthesize((160, 200), seed=0)
    for record in job:
        if record.stage == "collapse":
            break
    job.close()
    assert list(job) == []


@pytest.mark.parametrize("pixels", [1 << 19, 97, 1])
def test_blocked_sums_are_numpys_mean_and_std(pixels, monkeypatch):
    # the restore's sums by blocks of rows add as NumPy's mean and std do:
    # the same numbers (if a NumPy release changed its order, this fails)
    from car_napari.texture import _histogram

    monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", pixels)
    rng = np.random.default_rng(2)
    for shape in [(37, 41, 3), (64, 50, 1), (5, 7, 2), (300, 200, 4)]:
        values = rng.standard_normal(shape) * 1e3 + 1
        before = values.copy()
        np.testing.assert_array_equal(drain(_histogram._iter_channel_sum(values)),
                                      before.sum(axis=(0, 1)))
        np.testing.assert_array_equal(values, before)  # the running sum is put back
        mean, std = rng.random(shape[2]), rng.random(shape[2]) + 0.5
        centred = values - values.mean(axis=(0, 1))
        spread = centred.std(axis=(0, 1))
        want = mean + centred * (std / spread)
        np.testing.assert_array_equal(drain(_histogram._iter_restore(values, mean, std)), want)


def test_version_2_files_load_as_the_gaussian_pyramid_they_were(tmp_path):
    texture = skdata.astronaut()[300:428, 30:158]
    old = TextureModel.fit(texture, levels=2, pyramid="gaussian")
    path = tmp_path / "new.npz"
    old.save(path)
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files if not k.startswith("palette")}
    header = json.loads(str(arrays["header"]))
    header = {**header, "version": 2, "pyramid": {"blur_sigma": 1.0}}  # as version 2 wrote it
    v2 = tmp_path / "v2.npz"
    np.savez(v2, **{**arrays, "header": np.array(json.dumps(header))})
    loaded = TextureModel.load(v2)
    assert loaded.pyramid == "gaussian" and loaded.palette is None
    no_palette = TextureModel(**{**old.__dict__, "palette": None, "palette_radius": None})
    np.testing.assert_array_equal(loaded.synthesize((40, 30), seed=2),
                                  no_palette.synthesize((40, 30), seed=2))
    bad = tmp_path / "bad.npz"
    header = {**header, "version": 3, "pyramid": {"kind": "wavelet"}}
    np.savez(bad, **{**arrays, "header": np.array(json.dumps(header))})
    with pytest.raises(ValueError, match="format-version-3 .* 'wavelet'"):
        TextureModel.load(bad)


@pytest.mark.parametrize("q", [3, 32, 64])
def test_histogram_matching_kernels_equal_plain_numpy(q, monkeypatch):
    """The compiled matching (_kernels) against the plain NumPy one, bit for
    bit: heavy tails, a constant channel, ties, clipping, blocks of rows."""
    from car_napari.texture import _blocks, _histogram

    rng = np.random.default_rng(q)
    values = np.stack([rng.standard_t(3, (150, 131)), rng.random((150, 131)),
                       np.full((150, 131), 0.25), np.round(rng.normal(size=(150, 131)), 1)],
                      axis=-1)
    quantiles = np.sort(rng.normal(size=(q, 4)) * [1.0, 2.0, 1.0, 0.5], axis=0)
    clip = np.stack([quantiles[1], quantiles[-2]])
    want = _reference_match(values, quantiles)
    np.testing.assert_array_equal(_histogram._match(values, quantiles), want)
    for pixels in (_blocks._CHUNK_PIXELS, 97 * 4):
        monkeypatch.setattr("car_napari.texture._blocks._CHUNK_PIXELS", pixels)
        got = drain(_histogram._iter_match(values, quantiles, clip=clip))
        np.testing.assert_array_equal(got, np.clip(want, clip[0], clip[1]))
    # numpy.histogram's counts, edges included
    from car_napari.texture import _kernels

    v = values[..., 0]
    lo, hi = float(v.min()), float(v.max())
    counts = np.zeros(4096, np.int64)
    _kernels.block_histogram(values, 0, lo, hi, np.linspace(lo, hi, 4097), counts)
    np.testing.assert_array_equal(counts, np.histogram(v, bins=4096, range=(lo, hi))[0])


@pytest.mark.parametrize("lo, hi", [(-1.2345, 3.14159), (0.1, 0.1 + 1e-12), (0.0, 1e-306),
                                    (-1e300, 1e300)])
def test_histogram_kernel_counts_values_on_and_beside_every_edge_as_numpy(lo, hi):
    # on the edges themselves and one float either side the kernel's bins
    # must be NumPy's (also for a range of tiny and of huge bins)
    from car_napari.texture import _kernels

    edges = np.linspace(lo, hi, 4097)
    values = np.concatenate([edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf),
                             np.random.default_rng(0).uniform(lo, hi, 5000)])
    counts = np.zeros(4096, np.int64)
    _kernels.block_histogram(values.reshape(-1, 1, 1), 0, lo, hi, edges, counts)
    np.testing.assert_array_equal(counts, np.histogram(values, bins=4096, range=(lo, hi))[0])


def _reference_fit_palette(image, k, seed=0):
    """The palette fit before issue 34's speed-up (every centre's distances
    recomputed each k-means++ round, np.add.at sums), kept as the reference."""
    from car_napari.texture._palette import _COVER, _ITERATIONS, _SAMPLE, _nearest

    rng = np.random.default_rng(seed)
    pixels = image.reshape(-1, image.shape[-1])
    n = len(pixels)
    sample = pixels[np.sort(rng.choice(n, _SAMPLE, replace=False))] if n > _SAMPLE else pixels
    centres = sample[[int(rng.integers(len(sample)))]]
    for _ in range(k - 1):
        _, d2 = _nearest(sample, centres)
        total = d2.sum()
        if total <= 0:
            break
        centres = np.vstack([centres, sample[rng.choice(len(sample), p=d2 / total)]])
    for _ in range(_ITERATIONS):
        index, _ = _nearest(sample, centres)
        counts = np.bincount(index, minlength=len(centres))
        sums = np.zeros_like(centres)
        np.add.at(sums, index, sample)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled, None]
    index, d2 = _nearest(sample, centres)
    radius = np.zeros(len(centres))
    for c in range(len(centres)):
        mine = d2[index == c]
        if mine.size:
            radius[c] = np.sqrt(np.quantile(mine, _COVER))
    return centres, radius


@pytest.mark.parametrize("k", [1, 5, 32])
def test_palette_fit_equals_its_reference(k):
    from car_napari.texture import _palette

    image = skdata.astronaut()[100:300, 150:350] / 255.0
    few = np.repeat(np.array([[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]]), 50, axis=0).reshape(10, 10, 3)
    for img in (image, few):  # (few: k-means++ stops early, fewer distinct colours)
        got, want = _palette.fit_palette(img, k), _reference_fit_palette(img, k)
        np.testing.assert_array_equal(got[0], want[0])
        # the 95 % radii, then their cut to the covered balls (tests/texture/test_palette.py)
        cut = _palette._covered_radius(img.reshape(-1, 3), want[0], want[1])
        np.testing.assert_array_equal(got[1], cut)


def test_jobs_and_their_plain_forms_document_the_same_parameters():
    # shared_parameters fills methods (indented deeper) as it fills functions
    import inspect

    from car_napari.texture import (
        BTFModel,
        DynamicTextureModel,
        iter_fit_btf,
        iter_fit_dynamic_texture,
        iter_rank,
        rank,
    )

    def parameters(func):
        doc = inspect.getdoc(func)
        assert "{parameters}" not in doc
        return doc[doc.index("Parameters\n") : doc.index("Returns\n")]

    pairs = [(TextureModel.fit, iter_fit_texture), (BTFModel.fit, iter_fit_btf),
             (DynamicTextureModel.fit, iter_fit_dynamic_texture), (rank, iter_rank),
             (TextureModel.synthesize, TextureModel.iter_synthesize),
             (BTFModel.synthesize, BTFModel.iter_synthesize),
             (DynamicTextureModel.synthesize, DynamicTextureModel.iter_synthesize)]
    for plain, job in pairs:
        assert parameters(plain) == parameters(job)
        assert "\n    " in parameters(plain)  # the entries' descriptions stay indented
