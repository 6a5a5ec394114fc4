"""Grey conversion and integer resampling shared by the breast, region and job
modules of the mammogram pipeline."""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float


def _as_grey(image, channel_axis):
    """A colour export of a grey mammogram as its luminance in [0, 1]; a grey
    image (2-D, or ``channel_axis=None``) unchanged."""
    arr = np.asarray(image)
    if channel_axis is None or arr.ndim != 3:
        return image  # grey, or not an image at all: _grey01 says why
    arr = np.moveaxis(arr, channel_axis, -1)
    if arr.shape[-1] == 1:
        return arr[..., 0]
    if arr.shape[-1] not in (3, 4):
        raise ValueError(
            f"image has {arr.shape[-1]} channels on axis {channel_axis}; a colour export of "
            "a mammogram has 3 (RGB) or 4 (RGBA). Pass a 2-D grey image, or "
            "channel_axis=None for a grey image."
        )
    from skimage.color import rgb2gray

    return rgb2gray(arr[..., :3])


def _grey01(image, name="image"):
    """(H, W) float64 grey image scaled like img_as_float; clear errors."""
    data = as_channel_last_float(image, channel_axis=None, name=name)[..., 0]
    lo, hi = float(data.min()), float(data.max())
    if hi <= lo:
        raise ValueError(
            f"{name} is constant (every pixel is {lo:g}): there is no breast to find. "
            "Pass a mammogram with visible tissue."
        )
    return data


def _block_mean(data, factor):
    """Downsample by an integer factor (block mean, edges cropped)."""
    if factor <= 1:
        return data
    h, w = (data.shape[0] // factor) * factor, (data.shape[1] // factor) * factor
    return data[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


def _upsample_mask(small, shape, factor):
    """Nearest-neighbour upsampling of a mask to ``shape`` (edges padded)."""
    big = np.repeat(np.repeat(small, factor, axis=0), factor, axis=1)
    out = np.zeros(shape, bool)
    h, w = min(shape[0], big.shape[0]), min(shape[1], big.shape[1])
    out[:h, :w] = big[:h, :w]
    if h < shape[0]:
        out[h:, :w] = out[h - 1 : h, :w]
    if w < shape[1]:
        out[:, w:] = out[:, w - 1 : w]
    return out
