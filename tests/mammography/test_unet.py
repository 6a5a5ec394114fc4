"""The tissue model's U-Net forward pass in NumPy (car_napari.mammography._unet),
each operation against an independent computation."""

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from car_napari.mammography import _tissue, _unet


def _plain_conv(x, weight, bias):
    """Each output map the sum over input maps of scipy's correlation with
    zero boundaries, plus the bias."""
    return np.array([sum(ndimage.correlate(x[c].astype(np.float64), weight[o, c], mode="constant")
                         for c in range(len(x))) + bias[o] for o in range(len(weight))])


def test_conv3x3_against_scipy_correlation():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 7, 10)).astype(np.float32)
    weight = rng.standard_normal((4, 3, 3, 3)).astype(np.float32)
    bias = rng.standard_normal(4).astype(np.float32)
    out = _unet.conv3x3(x, weight, bias)
    assert out.shape == (4, 7, 10) and out.dtype == np.float32
    np.testing.assert_allclose(out, _plain_conv(x, weight, bias), rtol=1e-5, atol=1e-5)


def test_pooling_and_upsampling_against_loops():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((2, 6, 8)).astype(np.float32)
    pooled = _unet.max_pool2(x)
    want = np.array([[[max(x[c, 2 * i, 2 * j], x[c, 2 * i + 1, 2 * j], x[c, 2 * i, 2 * j + 1],
                           x[c, 2 * i + 1, 2 * j + 1]) for j in range(4)] for i in range(3)]
                     for c in range(2)])
    np.testing.assert_array_equal(pooled, want)
    up = _unet.upsample2(x)
    rr, cc = np.mgrid[:12, :16]
    np.testing.assert_array_equal(up, x[:, rr // 2, cc // 2])


def test_bilinear2_against_interpolation_at_half_pixel_centres():
    """Output pixel o of a 2x upsampling samples the input at (o + 0.5) / 2 -
    0.5, clamped to the input's first and last pixel (np.interp clamps)."""
    rng = np.random.default_rng(2)
    image = rng.random((5, 7)).astype(np.float32)
    where_r = (np.arange(10) + 0.5) / 2 - 0.5
    where_c = (np.arange(14) + 0.5) / 2 - 0.5
    rows = np.array([np.interp(where_c, np.arange(7), row) for row in image])
    want = np.array([np.interp(where_r, np.arange(5), col) for col in rows.T]).T
    np.testing.assert_allclose(_unet.bilinear2(image), want, rtol=1e-6, atol=1e-6)


def _random_weights(rng, cin, base):
    sizes = {"e1": (cin, base), "e2": (base, 2 * base), "e3": (2 * base, 4 * base),
             "e4": (4 * base, 8 * base), "d3": (12 * base, 4 * base), "d2": (6 * base, 2 * base),
             "d1": (3 * base, base)}
    weights = {}
    for name, (i, o) in sizes.items():
        for k, inputs in enumerate((i, o)):
            weights[f"{name}.{k}.weight"] = rng.standard_normal((o, inputs, 3, 3)).astype(
                np.float32) / np.sqrt(9 * inputs)
            weights[f"{name}.{k}.bias"] = 0.1 * rng.standard_normal(o).astype(np.float32)
    weights["head.weight"] = rng.standard_normal((1, base, 1, 1)).astype(np.float32)
    weights["head.bias"] = np.array([0.3], np.float32)
    return weights


def test_unet_against_plain_composition():
    """The whole network against the same architecture written with scipy's
    correlations, explicit block maxima and index-repeated upsampling."""
    rng = np.random.default_rng(3)
    x = rng.standard_normal((2, 16, 8)).astype(np.float32)
    w = _random_weights(rng, 2, 2)

    def block(name, v):
        for k in (0, 1):
            v = np.maximum(_plain_conv(v, w[f"{name}.{k}.weight"], w[f"{name}.{k}.bias"]), 0)
        return v

    def pool(v):
        return np.maximum.reduce([v[:, i::2, j::2] for i in (0, 1) for j in (0, 1)])

    def up(v):
        return v.repeat(2, axis=1).repeat(2, axis=2)

    e1 = block("e1", x)
    e2 = block("e2", pool(e1))
    e3 = block("e3", pool(e2))
    e4 = block("e4", pool(e3))
    d = block("d1", np.concatenate([up(block("d2", np.concatenate(
        [up(block("d3", np.concatenate([up(e4), e3]))), e2]))), e1]))
    want = np.tensordot(w["head.weight"][0, :, 0, 0], d, axes=1) + w["head.bias"][0]
    np.testing.assert_allclose(_unet.unet_logits(x, w), want, rtol=1e-4, atol=1e-4)


def test_unet_against_pytorch():
    """A small network (3 input maps, 2 channels at the first resolution)
    with random weights and batch norms of random statistics, run once by
    PyTorch 2.13 (``benchmarks/train_tissue_unet.py``'s ``unet`` in
    evaluation mode, its weights folded by ``folded_weights``): its logits
    and its bilinearly upsampled probability, stored beside this file."""
    with np.load(Path(__file__).with_name("unet_reference.npz")) as ref:
        weights = {k[2:]: ref[k] for k in ref.files if k.startswith("w:")}
        x, logits, probability = ref["input"], ref["logits"], ref["probability"]
    mine = _unet.unet_logits(x, weights)
    np.testing.assert_allclose(mine, logits, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(_unet.bilinear2(1 / (1 + np.exp(-mine))), probability,
                               rtol=1e-5, atol=1e-5)


def test_spatial_input_against_block_means():
    """The input maps: each channel's breast values placed in the crop, the
    mean of every 2x2 block (odd sides padded with zeros), zeros beyond."""
    rng = np.random.default_rng(4)
    h, w = 41, 30
    rr, cc = np.mgrid[:h, :w]
    breast = ((rr - h / 2) / (h / 2 - 2)) ** 2 + (cc / (w - 3)) ** 2 < 1
    grey = rng.random((h, w))
    work = _tissue._Working(grey, None, breast, None)
    x = _tissue._spatial_input(work)
    c = len(_tissue.SPATIAL_CHANNELS)
    assert x.shape[0] == c and x.dtype == np.float32
    assert x.shape[1] % _unet.MULTIPLE == 0 == x.shape[2] % _unet.MULTIPLE
    assert x.shape[1] >= 21 + _tissue._SPATIAL_MARGIN and x.shape[2] >= 15 + _tissue._SPATIAL_MARGIN
    g = grey[breast]
    z = (g - g.mean()) / g.std()
    for k, values in ((0, z), (6, z), (c - 1, np.ones(breast.sum()))):
        full = np.zeros((h + 1, w))
        full[:h][breast] = values
        want = np.array([[full[2 * i : 2 * i + 2, 2 * j : 2 * j + 2].mean() for j in range(15)]
                         for i in range(21)])
        np.testing.assert_allclose(x[k, :21, :15], want, rtol=1e-5, atol=1e-6)
    assert not x[:, 21:].any() and not x[:, :, 15:].any()


def test_shipped_spatial_model_loads_and_is_a_probability():
    model = _tissue.shipped_tissue_model()
    if model.spatial is None:
        pytest.skip("the shipped tissue model has no spatial part")
    assert model.threshold == model.spatial.threshold
    spec = model.spatial.spec  # with its provenance
    assert "train_tissue_unet.py --write" in spec["made_by"] and spec["date"] and spec["fit"]
    assert tuple(spec["channels"]) == _tissue.SPATIAL_CHANNELS
    rng = np.random.default_rng(5)
    breast = np.zeros((60, 40), bool)
    breast[5:55, :30] = True
    work = _tissue._Working(rng.random((60, 40)), None, breast, None)
    p = model.spatial.probability(work)
    assert p.shape == breast.shape and np.all((p >= 0) & (p <= 1)) and not p[~breast].any()
