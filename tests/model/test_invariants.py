"""Illumination invariants (section 14.3, docs/model.md): invariance under Y -> B Y."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari import illumination_invariants


def _random_illumination(rng, d):
    while True:
        B = rng.uniform(0.2, 1.5, (d, d)) * np.eye(d) * 2 + rng.uniform(-0.3, 0.6, (d, d))
        if np.linalg.cond(B) < 50:
            return B


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("levels", [1, 2])
def test_invariant_under_random_invertible_B(seed, levels):
    rng = np.random.default_rng(seed)
    img = skdata.astronaut()[256:384, 0:128] / 255.0
    B = _random_illumination(rng, 3)
    f = illumination_invariants(img, 2, levels=levels)
    g = illumination_invariants(img @ B.T, 2, levels=levels)
    assert f.shape == (levels * (4 + 2 * 4 * 3 + 3),)
    np.testing.assert_allclose(g, f, rtol=1e-4, atol=1e-4 * np.abs(f).max())


def test_features_discriminate_textures():
    a = skdata.astronaut()
    grass, suit = a[300:428, 0:128], a[300:428, 300:428]
    f1 = illumination_invariants(grass)
    f2 = illumination_invariants(grass[::-1, ::-1].copy())
    f3 = illumination_invariants(suit)
    assert np.abs(f1 - f3).sum() > 2 * np.abs(f1 - f2).sum()


def test_too_small_for_pyramid():
    with pytest.raises(ValueError, match="too small"):
        illumination_invariants(skdata.camera()[:20, :20], levels=4)


def test_traces_equal_independent_least_squares():
    img = skdata.astronaut()[256:384, 0:128] / 255.0
    f = illumination_invariants(img, 1)
    Y = img - img.mean(axis=(0, 1))
    X = np.concatenate([Y[1:, :-1], Y[:-1, 1:]], axis=2).reshape(-1, 6)
    T = Y[1:, 1:].reshape(-1, 3)
    coef, *_ = np.linalg.lstsq(X, T, rcond=None)
    A = coef.T.reshape(3, 2, 3).transpose(1, 0, 2)
    # the covariant prior is one pixel's worth of data: O(1/N) from plain LS
    np.testing.assert_allclose(f[:2], np.trace(A, axis1=1, axis2=2), rtol=1e-3)
    resid = T - X @ coef
    lam = resid.T @ resid
    alpha3 = np.sqrt(np.sum(Y.reshape(-1, 3) * np.linalg.solve(lam, Y.reshape(-1, 3).T).T))
    assert f[-1] == pytest.approx(alpha3, rel=1e-3)


def test_dependent_channels_are_a_clear_error():
    grey = skdata.camera()[:64, :64]
    with pytest.raises(ValueError, match="linearly dependent"):
        illumination_invariants(np.repeat(grey[..., None], 3, axis=2))


def _degenerate_textures():
    i, j = np.indices((48, 48)).astype(float)
    stripes = np.repeat(np.random.default_rng(0).random((48, 1)), 48, axis=1)
    return {"ramp": i + j, "checkerboard": (i + j) % 2, "stripes": stripes,
            "step": (i >= 24).astype(float)}


@pytest.mark.parametrize("name", ["ramp", "checkerboard", "stripes", "step"])
def test_exactly_predictable_textures_get_finite_features(name):
    # their data matrix is singular: a regularised (still covariant) estimate
    image = _degenerate_textures()[name]
    f = illumination_invariants(image)
    assert np.isfinite(f).all()
    # still invariant to a gain, up to the conditioning of a near-singular fit
    np.testing.assert_allclose(illumination_invariants(3.0 * image), f, rtol=1e-2, atol=1e-3)


@pytest.mark.parametrize("scale", [1e-140, 1e-100, 1e100, 1e140])
def test_magnitude_does_not_decide(scale):
    img = skdata.astronaut()[256:320, 0:64] / 255.0
    # scaling is an illumination change B = scale * I: the features must not move
    np.testing.assert_allclose(illumination_invariants(img * scale), illumination_invariants(img),
                               rtol=1e-9, atol=1e-12)


def test_eigenvalues_and_alphas_equal_a_dense_numpy_computation():
    """Every feature of one level (order 1) from explicit matrices: the
    estimates with the covariant prior V / N (one pixel's worth of the data's
    own statistics, so gamma is plain least squares and lambda is (1 + 1/N)
    times its residual scatter); the eigenvalues of every A_m sorted by
    modulus, then real part; alpha_1 the mean of 1 + Z^T V_z^-1 Z and alpha_2
    the root of sum e^T lambda^-1 e over the one-step-ahead predictions, V_z
    and gamma from the prior plus the pixels before r (raster scan); alpha_3
    the root of sum (Y - mu)^T lambda^-1 (Y - mu)."""
    img = skdata.astronaut()[256:280, 0:26] / 255.0
    f = illumination_invariants(img, 1)
    Y = img - img.mean(axis=(0, 1))
    X = np.concatenate([Y[1:, :-1], Y[:-1, 1:]], axis=2).reshape(-1, 6)  # (0,1), (1,0)
    T = Y[1:, 1:].reshape(-1, 3)
    assert not np.any(np.all(X == np.tile(T, 2), axis=1))  # no flat neighbourhood
    n = X.shape[0]
    Z = np.hstack([X, T])
    prior = Z.T @ Z / n
    V = Z.T @ Z + prior
    gT = np.linalg.solve(V[:6, :6], V[:6, 6:])
    lam = V[6:, 6:] - V[6:, :6] @ gT
    A = gT.T.reshape(3, 2, 3).transpose(1, 0, 2)
    eig = [sorted(np.linalg.eigvals(a), key=lambda z: (abs(z), z.real)) for a in A]
    q, maha = [], []
    running = prior.copy()
    for x, y in zip(X, T, strict=True):  # raster order
        g = np.linalg.solve(running[:6, :6], running[:6, 6:])
        q.append(1 + x @ np.linalg.solve(running[:6, :6], x))
        e = y - g.T @ x
        maha.append(e @ np.linalg.solve(lam, e))
        running += np.outer(np.r_[x, y], np.r_[x, y])
    flat = Y.reshape(-1, 3)
    want = np.concatenate([
        np.trace(A, axis1=1, axis2=2),
        np.real(eig).ravel(), np.abs(np.imag(eig)).ravel(),
        [np.mean(q), np.sqrt(np.sum(maha)),
         np.sqrt(np.sum(flat * np.linalg.solve(lam, flat.T).T))],
    ])
    assert f.shape == want.shape == (2 + 2 * 2 * 3 + 3,)
    np.testing.assert_allclose(f, want, rtol=1e-7, atol=1e-10)
