"""Whole-image preparation by blocks of rows (issue 12): the float copy, the
centring, the whitening and the spectral decorrelation of the fits run in
blocks with a yield between them, and give what the one-call forms give."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari._progress import drain
from car_napari._validation import as_channel_last_float, channel_last_shape, summarize
from car_napari.model import blocks, estimation, fit_car, iter_fit_car, select_support
from car_napari.model.blocks import iter_centre, iter_channel_last_float, row_ranges


@pytest.fixture
def small_blocks(monkeypatch):
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 999)


def _images():
    rng = np.random.default_rng(0)
    rgb = skdata.astronaut()[:40, :30]
    return [
        (rgb, {}),
        (skdata.camera()[:37, :41], {}),
        (np.moveaxis(rgb, -1, 0), {"channel_axis": 0}),
        ((rng.random((33, 29, 2)) * 65535).astype(np.uint16), {}),
        ((rng.standard_normal((31, 30, 3)) * 20000).astype(np.int16), {}),
        (rng.random((30, 35)) > 0.5, {}),
        (rng.random((32, 30, 3)).astype(np.float32), {}),
        (rng.random((30, 33, 3))[:, ::-1], {}),
        (rng.random((30, 33, 3)) * 7 - 3, {}),
        (rng.random((34, 30)), {"channel_axis": None}),
    ]


@pytest.mark.parametrize("k", range(10))
def test_float_copy_by_blocks_is_as_channel_last_float(small_blocks, k):
    image, kwargs = _images()[k]
    records = []
    data, summary = drain(iter_channel_last_float(image, **kwargs), records.append)
    want, want_summary = as_channel_last_float(image, with_summary=True, **kwargs)
    np.testing.assert_array_equal(data, want)
    assert data.flags.c_contiguous and data.dtype == np.float64
    for a, b in zip(summary, want_summary, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(records) > 2 and records[-1].fraction == 1.0


@pytest.mark.parametrize("bad, error", [
    (None, TypeError), (np.zeros((0, 4)), ValueError), (np.zeros((4, 4, 4, 4)), ValueError),
    (np.zeros((40, 40, 3)).astype(object), TypeError), (np.zeros((40, 40, 70)), ValueError),
])
def test_bad_input_says_what_as_channel_last_float_says(small_blocks, bad, error):
    with pytest.raises(error) as ours:
        drain(iter_channel_last_float(bad))
    with pytest.raises(error) as theirs:
        as_channel_last_float(bad)
    assert str(ours.value) == str(theirs.value)


def test_non_finite_values_are_counted_over_the_whole_image(small_blocks):
    image = np.random.default_rng(1).random((60, 50))
    image[[3, 30, 59], [1, 2, 3]] = [np.nan, np.inf, -np.inf]
    with pytest.raises(ValueError, match="contains 3 NaN or infinite values"):
        drain(iter_channel_last_float(image))


@pytest.mark.parametrize("budget", [7, 500, 4096, 10**9])
def test_reader_is_as_channel_last_float_for_every_dtype_and_strip(monkeypatch, budget):
    """Bit for bit the one-call conversion and summary, whatever the strips
    (one row, a few rows, whole; the last one shorter), for every dtype,
    channel-first layouts, NaN-free and with copy=False."""
    monkeypatch.setattr(blocks, "BLOCK_VALUES", budget)
    rng = np.random.default_rng(6)
    rgb = skdata.astronaut()[:47, :43]
    images = [
        (rgb, {}),
        ((rng.random((45, 41, 2)) * 65535).astype(np.uint16), {}),
        ((rng.standard_normal((43, 39, 3)) * 20000).astype(np.int16), {}),
        ((rng.standard_normal((43, 39, 3)) * 1e4).astype(np.float32), {}),
        (rng.standard_normal((41, 37, 4)) * 1e6 + 3, {}),
        (np.moveaxis(rng.random((40, 38, 3)), -1, 0), {"channel_axis": 0}),
        (np.moveaxis(rgb, -1, 1), {"channel_axis": 1}),
        (rng.random((39, 44)), {"channel_axis": None}),
    ]
    for image, kwargs in images:
        want, want_summary = as_channel_last_float(image, with_summary=True, **kwargs)
        for copy in (True, False):
            got, summary = drain(iter_channel_last_float(image, copy=copy, **kwargs))
            np.testing.assert_array_equal(got, want)
            assert got.dtype == np.float64 and got.flags.c_contiguous
            for a, b in zip(summary, want_summary, strict=True):
                np.testing.assert_array_equal(a, b)
                assert a.dtype == b.dtype == np.float64
        assert not np.shares_memory(drain(iter_channel_last_float(image, **kwargs))[0], image)
    grey = images[-1][0]
    # copy=False keeps a float64 C-contiguous input (a view with the channel axis)
    assert drain(iter_channel_last_float(grey, copy=False))[0].base is grey


def test_summary_is_the_sequential_sums():
    """Independently (NumPy's cumsum adds in order, as the passes do): the
    min, max, mean and variance of the finite values, the non-finite count."""
    rng = np.random.default_rng(8)
    data = rng.standard_normal((3001, 3)) * [1.0, 1e3, 1e-3] + [0.5, -7.0, 1e3]
    data[[5, 70, 3000], [0, 0, 2]] = [np.nan, np.inf, -np.inf]
    summary = summarize(data.reshape(1, -1, 3))
    for c in range(3):
        x = data[np.isfinite(data[:, c]), c]
        mean = np.cumsum(x)[-1] / x.size
        assert summary.min[c] == x.min() and summary.max[c] == x.max()
        assert summary.mean[c] == mean
        assert summary.var[c] == np.cumsum((x - mean) * (x - mean))[-1] / x.size
        assert summary.nonfinite[c] == data.shape[0] - x.size
    np.testing.assert_allclose(summary.var, np.nanvar(np.where(np.isfinite(data), data,
                                                               np.nan), axis=0), rtol=1e-12)


def test_values_beyond_the_magnitude_limit_in_a_later_block(small_blocks):
    image = np.random.default_rng(9).random((60, 50))
    image[55, 3] = -2e151
    with pytest.raises(ValueError, match="magnitude 2e.151: .* Rescale") as ours:
        drain(iter_channel_last_float(image))
    with pytest.raises(ValueError) as theirs:
        as_channel_last_float(image)
    assert str(ours.value) == str(theirs.value)


def test_channel_last_shape_needs_no_pass(small_blocks):
    rgb = skdata.astronaut()[:40, :30]
    assert channel_last_shape(np.moveaxis(rgb, -1, 0), channel_axis=0) == (40, 30, 3)
    assert channel_last_shape(rgb[..., 0], channel_axis=None) == (40, 30, 1)
    bad = np.full((40, 30), np.nan)
    assert channel_last_shape(bad) == (40, 30, 1)  # the values are the reader's business
    with pytest.raises(ValueError, match="70 channels"):
        channel_last_shape(np.zeros((40, 40, 70)))


def test_centring_by_blocks(small_blocks):
    data = np.random.default_rng(2).random((50, 40, 3))
    mean = data.mean(axis=(0, 1))
    got = data.copy()
    records = list(iter_centre(got, mean))
    assert len(records) > 2
    np.testing.assert_array_equal(got, data - mean)


def test_row_ranges_cover_the_rows():
    assert row_ranges(10, 3, 7) == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    assert row_ranges(3, 100, 7) == [(0, 1), (1, 2), (2, 3)]


def test_whitening_and_covariance_by_blocks(monkeypatch):
    monkeypatch.setattr(estimation, "_WHITEN_ROWS", 4096)
    rng = np.random.default_rng(3)
    centred = rng.standard_normal((150, 140, 3)) @ rng.random((3, 3))
    centred -= centred.mean(axis=(0, 1))
    flat = centred.reshape(-1, 3)
    cov = flat.T @ flat / flat.shape[0]
    cov += 1e-12 * np.trace(cov) / 3 * np.eye(3)
    want = np.linalg.solve(np.linalg.cholesky(cov), flat.T).T.reshape(centred.shape)
    records = []
    got = drain(estimation._iter_whiten(centred), records.append)
    assert len(records) == 5  # 21000 pixels in blocks of 4096, the short tail merged
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(drain(estimation._iter_covariance(flat)),
                                  np.cov(flat, rowvar=False))


@pytest.mark.parametrize("kwargs", [
    dict(neighbourhood=2),
    dict(neighbourhood="auto", orders=[1, 2]),
    dict(neighbourhood="auto", orders=[1, 2], model="2d"),
])
def test_fits_do_not_depend_on_the_blocks(monkeypatch, kwargs):
    image = skdata.astronaut()[:96, :90]
    want = fit_car(image, **kwargs)
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 2000)
    monkeypatch.setattr(estimation, "_WHITEN_ROWS", 4096)
    records = []
    got = drain(iter_fit_car(image, **kwargs), records.append)
    for name in ("gamma", "sigma", "mean", "lam", "vx", "beta", "n_pixels"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.scores == want.scores
    # the preparation yields before the statistics, in the first stage's name
    first = records[0]
    assert first.stage == ("support" if kwargs["neighbourhood"] == "auto" else "statistics")
    assert first.message.startswith("image: rows")
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0


def test_select_support_does_not_depend_on_the_blocks(monkeypatch):
    image = skdata.coffee()[:80, :100]
    want = select_support(image, orders=[1, 2, 3])
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 2000)
    monkeypatch.setattr(estimation, "_WHITEN_ROWS", 4096)
    assert select_support(image, orders=[1, 2, 3]) == want
