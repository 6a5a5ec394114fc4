"""Illumination invariants (SPEC section 2): invariance under Y -> B Y."""

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
