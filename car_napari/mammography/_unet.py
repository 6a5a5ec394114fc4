"""A small U-Net's forward pass in NumPy (the tissue model's spatial part).

The network is trained with PyTorch by ``benchmarks/train_tissue_unet.py``,
which folds each batch normalisation into its convolution and writes the
weights to ``tissue_unet.npz``; the package only runs it, so it needs no
deep-learning library. The architecture: four resolutions of two 3x3
convolutions with ReLU each (``e1``..``e4``, F, 2F, 4F, 8F channels, 2x2
max pooling between them), a decoder of nearest-neighbour 2x upsampling,
concatenation with the encoder's map of that resolution and two 3x3
convolutions (``d3``, ``d2``, ``d1``), and a 1x1 convolution to one logit
(``head``).
"""

from __future__ import annotations

import numpy as np

BLOCKS = ("e1", "e2", "e3", "e4", "d3", "d2", "d1")
MULTIPLE = 8  # the input's sides must divide by 2 ** (encoder resolutions - 1)


def conv3x3(x, weight, bias):
    """A 3x3 convolution (cross-correlation, zero padding 1), as PyTorch's
    ``Conv2d(C, O, 3, padding=1)``.

    Parameters
    ----------
    x : ndarray, shape (C, H, W)
    weight : ndarray, shape (O, C, 3, 3)
    bias : ndarray, shape (O,)

    Returns
    -------
    ndarray, shape (O, H, W), float32
    """
    c, h, w = x.shape
    padded = np.pad(np.asarray(x, np.float32), ((0, 0), (1, 1), (1, 1)))
    # the nine shifted maps as one (C*9, H*W) matrix: a single matrix product
    cols = np.empty((c, 3, 3, h, w), np.float32)
    for i in range(3):
        for j in range(3):
            cols[:, i, j] = padded[:, i : i + h, j : j + w]
    out = np.asarray(weight, np.float32).reshape(len(weight), -1) @ cols.reshape(c * 9, h * w)
    out += np.asarray(bias, np.float32)[:, None]
    return out.reshape(len(weight), h, w)


def max_pool2(x):
    """2x2 max pooling of ``x`` (C, H, W), H and W even."""
    c, h, w = x.shape
    return x.reshape(c, h // 2, 2, w // 2, 2).max(axis=(2, 4))


def upsample2(x):
    """Nearest-neighbour 2x upsampling of ``x`` (C, H, W)."""
    return np.repeat(np.repeat(x, 2, axis=1), 2, axis=2)


def bilinear2(image):
    """2x bilinear upsampling of ``image`` (H, W) with half-pixel centres and
    clamped edges (PyTorch's ``interpolate(scale_factor=2, mode="bilinear",
    align_corners=False)``)."""
    out = np.asarray(image, np.float32)
    for axis in (0, 1):
        a = np.moveaxis(out, axis, 0)
        before = np.concatenate([a[:1], a[:-1]])
        after = np.concatenate([a[1:], a[-1:]])
        up = np.empty((2 * len(a),) + a.shape[1:], np.float32)
        up[0::2] = 0.25 * before + 0.75 * a  # output pixel 2i lies a quarter before i
        up[1::2] = 0.75 * a + 0.25 * after
        out = np.moveaxis(up, 0, axis)
    return out


def _double_conv(x, convs):
    for weight, bias in convs:
        x = np.maximum(conv3x3(x, weight, bias), 0.0)
    return x


def unet_logits(x, weights):
    """The network's logit map of its input channels.

    Parameters
    ----------
    x : ndarray, shape (C, H, W)
        H and W multiples of :data:`MULTIPLE`.
    weights : mapping
        ``"<block>.<k>.weight"`` (O, C, 3, 3) and ``"<block>.<k>.bias"`` (O,)
        for each block of :data:`BLOCKS` and k = 0, 1 (batch norms folded
        in), ``"head.weight"`` (1, F, 1, 1) and ``"head.bias"`` (1,).

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    def block(name, inp):
        return _double_conv(inp, [(weights[f"{name}.{k}.weight"], weights[f"{name}.{k}.bias"])
                                  for k in (0, 1)])

    e1 = block("e1", x)
    e2 = block("e2", max_pool2(e1))
    e3 = block("e3", max_pool2(e2))
    e4 = block("e4", max_pool2(e3))
    d = block("d3", np.concatenate([upsample2(e4), e3]))
    d = block("d2", np.concatenate([upsample2(d), e2]))
    d = block("d1", np.concatenate([upsample2(d), e1]))
    head = np.asarray(weights["head.weight"], np.float32).reshape(1, -1)
    return (head @ d.reshape(len(d), -1)).reshape(d.shape[1:]) + np.float32(weights["head.bias"][0])
