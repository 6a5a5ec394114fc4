"""The spectral pyramid (car_napari/texture/_spectral.py) against plain NumPy
matrices: the cosine (DCT-II) and Fourier resampling written out entry by
entry, no FFT."""

import numpy as np
import pytest

from car_napari.texture import _spectral


def _dct_matrix(n):
    """Orthonormal DCT-II: row k, column i."""
    k, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = np.sqrt(2.0 / n) * np.cos(np.pi * (i + 0.5) * k / n)
    c[0] /= np.sqrt(2.0)
    return c


def _cosine_resize(n_in, n_out):
    """(n_out, n_in) matrix keeping the lowest min(n_in, n_out) cosine
    frequencies, scaled by sqrt(n_out / n_in) so that constants stay."""
    n = min(n_in, n_out)
    scale = np.sqrt(n_out / n_in)
    return scale * _dct_matrix(n_out)[:n].T @ _dct_matrix(n_in)[:n]


def _fourier_resize(n_in, n_out):
    """(n_out, n_in) matrix: the trigonometric interpolant of the lowest
    min(n_in, n_out) Fourier frequencies (the Nyquist term of an even count
    split evenly between +n/2 and -n/2), sampled at the output points."""
    n = min(n_in, n_out)
    i = np.arange(n_in)[None, :]
    j = np.arange(n_out)[:, None]
    out = np.zeros((n_out, n_in))
    for f in range(-((n - 1) // 2), n // 2 + 1):
        if n % 2 == 0 and f == n // 2:
            # the Nyquist term of the shorter length: a cosine at +-n/2; going
            # down, the longer length's +n/2 and -n/2 both fold onto it
            both = np.cos(2 * np.pi * f * i / n_in) * np.cos(2 * np.pi * f * j / n_out)
            out += (2.0 if n_out < n_in else 1.0) * both
        else:
            out += np.cos(2 * np.pi * f * (j / n_out - i / n_in))
    return out / n_in


def _apply(mats, image):
    rows, cols = mats
    # optimize: two matrix products, not one loop over all four indices
    # (under a second instead of 40 s at 300x257)
    return np.einsum("ai,ijc,bj->abc", rows, image, cols, optimize=True)


@pytest.mark.parametrize("shape", [(16, 16), (15, 22), (9, 7), (2, 3), (1, 5)])
@pytest.mark.parametrize("wrap", [False, True])
def test_reduce_and_expand_equal_the_matrices(shape, wrap):
    rng = np.random.default_rng(0)
    x = rng.standard_normal(shape + (2,))
    h, w = shape
    h2, w2 = (h + 1) // 2, (w + 1) // 2
    resize = _fourier_resize if wrap else _cosine_resize
    small = _apply((resize(h, h2), resize(w, w2)), x)
    np.testing.assert_allclose(_spectral.reduce(x, wrap=wrap), small, atol=1e-12)
    up = _apply((resize(h2, h), resize(w2, w)), small)
    np.testing.assert_allclose(_spectral.expand(small, shape, wrap=wrap), up, atol=1e-12)
    np.testing.assert_allclose(_spectral.highpass(x, wrap=wrap), x - up, atol=1e-12)


@pytest.mark.parametrize("shape", [(16, 16), (15, 22), (9, 7), (1, 5), (300, 257)])
def test_single_precision_transforms_are_close_to_the_matrices(shape):
    # synthesis runs the cosine transforms in float32: the same maps as the
    # matrices, to float32's precision (relative to the values' scale)
    rng = np.random.default_rng(1)
    x = rng.standard_normal(shape + (3,))
    h, w = shape
    h2, w2 = (h + 1) // 2, (w + 1) // 2
    small = _apply((_cosine_resize(h, h2), _cosine_resize(w, w2)), x)
    up = _apply((_cosine_resize(h2, h), _cosine_resize(w2, w)), small)
    expanded = _spectral.expand(small, shape, single=True)
    assert expanded.dtype == np.float32
    np.testing.assert_allclose(expanded, up, atol=2e-6 * np.abs(x).max())
    np.testing.assert_allclose(_spectral.highpass(x, single=True), x - up,
                               atol=2e-6 * np.abs(x).max())
    collapsed = _spectral.collapse(_spectral.pyramid(x, 2), single=True)
    assert collapsed.dtype == np.float64
    np.testing.assert_allclose(collapsed, x, atol=2e-6 * np.abs(x).max())


def test_bands_are_exact_disjoint_and_keep_constants():
    rng = np.random.default_rng(1)
    x = rng.random((67, 93, 3))
    bands = _spectral.pyramid(x, 4)
    assert [b.shape[:2] for b in bands] == [(67, 93), (34, 47), (17, 24), (9, 12)]
    np.testing.assert_allclose(_spectral.collapse(bands), x, atol=1e-12)
    # a band-pass band is orthogonal to everything coarser (no shared frequency)
    low = _spectral.expand(_spectral.reduce(x), (67, 93))
    assert abs(np.sum(bands[0] * low)) < 1e-9 * np.sum(x * x)
    np.testing.assert_allclose(_spectral.highpass(bands[0]), bands[0], atol=1e-12)
    # a constant image stays constant at every level, its bands are zero
    c = np.full((20, 13, 1), 0.7)
    np.testing.assert_allclose(_spectral.reduce(c), 0.7, atol=1e-12)
    np.testing.assert_allclose(_spectral.reduce(c, wrap=True), 0.7, atol=1e-12)
    np.testing.assert_allclose(_spectral.expand(c, (40, 25), wrap=True), 0.7, atol=1e-12)


def test_periodic_collapse_is_periodic_and_exact():
    rng = np.random.default_rng(2)
    x = rng.random((30, 42, 1))
    g1 = _spectral.reduce(x, wrap=True)
    band = x - _spectral.expand(g1, (30, 42), wrap=True)
    np.testing.assert_allclose(_spectral.collapse([band, g1], wrap=True), x, atol=1e-12)
    # shifting the input circularly by two pixels shifts the coarse level by one
    shifted = _spectral.reduce(np.roll(x, 2, axis=1), wrap=True)
    np.testing.assert_allclose(shifted, np.roll(g1, 1, axis=1), atol=1e-12)
