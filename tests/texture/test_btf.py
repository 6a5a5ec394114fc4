"""BTF subspace models (SPEC 7) on a stack built from a real texture under
simulated illuminations: shading of a height map (the texture's own smoothed
grey) by a set of light directions, times its colour (albedo)."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata

from car_napari.texture.btf import BTFModel, cumulative_histograms


def _lit_stack(n_lights=8):
    albedo = skdata.astronaut()[300:428, 0:128] / 255.0  # grass
    height = ndimage.gaussian_filter(albedo.mean(axis=2), 2.0) * 20.0
    gy, gx = np.gradient(height)
    normal = np.dstack([-gx, -gy, np.ones_like(gx)])
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    stack, elevations = [], []
    for k in range(n_lights):
        azimuth = 2 * np.pi * k / n_lights
        elevation = np.deg2rad(20 if k % 2 else 70)  # two groups: grazing and steep
        light = np.array([np.cos(azimuth) * np.cos(elevation),
                          np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
        shading = np.clip(normal @ light, 0, None)
        stack.append(np.clip(albedo * shading[..., None], 0, 1))
        elevations.append(k % 2)
    return np.stack(stack), np.array(elevations)


def test_subspaces_follow_the_illumination_and_synthesis_keeps_each_image():
    stack, group = _lit_stack()
    btf = BTFModel.fit(stack, n_subspaces=2, levels=2)
    # the two illumination groups (grazing vs steep light) are the two subspaces
    same = btf.assignment[:, None] == btf.assignment[None, :]
    assert np.array_equal(same, group[:, None] == group[None, :])
    out = btf.synthesize((96, 80), seed=0)
    assert out.shape == (8, 96, 80, 3)
    np.testing.assert_allclose(out.mean(axis=(1, 2)), stack.mean(axis=(1, 2)), atol=0.01)
    assert btf.compression_ratio(stack.shape) > 100
    again = btf.synthesize((96, 80), seed=0)
    np.testing.assert_array_equal(out, again)


def test_cumulative_histograms_are_monotone_and_end_at_one():
    stack, _ = _lit_stack(2)
    f = cumulative_histograms(stack)
    assert f.shape == (2, 96)
    per_channel = f.reshape(2, 3, 32)
    assert np.all(np.diff(per_channel, axis=2) >= 0) and np.all(per_channel[..., -1] == 1)


def test_bad_input():
    stack, _ = _lit_stack(2)
    with pytest.raises(ValueError, match="n_subspaces"):
        BTFModel.fit(stack, n_subspaces=3)
    with pytest.raises(ValueError, match="channel_axis=None"):
        BTFModel.fit(stack[0])
