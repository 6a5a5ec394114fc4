"""Dynamic textures (3.5D CAR): estimates vs the truth of a generated clip,
and vs plain NumPy least squares on the same design."""

import numpy as np
import pytest

from car_napari.model.synthesis import synthesize_field
from car_napari.texture.dynamic import DynamicTextureModel, temporal_context


def _generated_clip(gamma, sigma, shape=(80, 90), frames=12, seed=0):
    rng = np.random.default_rng(seed)
    ctx = temporal_context(np.array([(0, 1), (1, 0)]), 1)
    prev = np.zeros(shape + (1,))
    clip = []
    for _ in range(frames + 10):
        lattice = np.concatenate([rng.standard_normal(shape + (1,)), prev], axis=2)
        synthesize_field(gamma, np.array([[np.sqrt(sigma)]]), lattice, ctx.taps[:, 0].copy(),
                         ctx.taps[:, 1].copy(), ctx.taps[:, 2].copy(), 1e9)
        prev = lattice[..., :1].copy()
        clip.append(prev[..., 0])
    return np.stack(clip[10:])[:, 8:, 8:-8]  # drop burn-in frames and borders


TRUE_GAMMA = np.array([[0.3, 0.25, 0.3, -0.05, -0.05]])  # left, up, prev, prev-left, prev-up


def test_estimates_match_the_truth_and_plain_least_squares():
    clip = _generated_clip(TRUE_GAMMA, 0.5)
    model = DynamicTextureModel.fit(clip, neighbourhood=np.array([(0, 1), (1, 0)]),
                                    channel_axis=None)
    np.testing.assert_allclose(model.gamma, TRUE_GAMMA, atol=0.03)
    assert abs(model.sigma[0, 0] - 0.5) < 0.05
    # the same regression by numpy.linalg.lstsq
    y = clip - clip.mean()
    rows, targets = [], []
    for t in range(1, len(y)):
        cur, prev = y[t], y[t - 1]
        X = np.stack([cur[1:, :-1], cur[:-1, 1:], prev[1:, 1:], prev[1:, :-1], prev[:-1, 1:]],
                     axis=-1).reshape(-1, 5)
        rows.append(X)
        targets.append(cur[1:, 1:].ravel())
    coef, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(targets), rcond=None)
    np.testing.assert_allclose(model.gamma[0], coef, atol=2e-3)


def test_synthesis_has_the_temporal_correlation_of_the_clip():
    clip = _generated_clip(TRUE_GAMMA, 0.5)
    model = DynamicTextureModel.fit(clip, neighbourhood=np.array([(0, 1), (1, 0)]),
                                    channel_axis=None)
    out = model.synthesize(6, (50, 60), seed=1)
    assert out.shape == (6, 50, 60)

    def lag1(c):
        a, b = c[:-1] - c.mean(), c[1:] - c.mean()
        return float((a * b).mean() / c.var())

    assert abs(lag1(out) - lag1(clip)) < 0.15
    np.testing.assert_array_equal(out, model.synthesize(6, (50, 60), seed=1))


def test_bad_input():
    with pytest.raises(ValueError, match="at least 2 frames"):
        DynamicTextureModel.fit(np.zeros((1, 32, 32)), channel_axis=None)
    with pytest.raises(ValueError, match="channel_axis=None"):
        DynamicTextureModel.fit(np.zeros((4, 32, 32)))
    with pytest.raises(ValueError, match="constant"):
        DynamicTextureModel.fit(np.ones((3, 32, 32)), channel_axis=None)
