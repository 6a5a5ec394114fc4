"""The noise level of an image, for the edge rule of restoration."""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float
from ._windowed import median_abs_laplacian

# Immerkaer's kernel [[1,-2,1],[-2,4,-2],[1,-2,1]] is 6 sigma on white noise
# (root of the sum of its squared taps), and the median of |N(0, s)| is 0.6745 s.
_LAPLACIAN_SIGMAS = 6.0 * 0.6745


def estimate_noise(image, *, channel_axis=-1):
    """Estimate the standard deviation of white Gaussian noise, per channel.

    Immerkaer's (1996) Laplacian-difference estimate made robust: the median
    absolute response of the kernel ``[[1,-2,1],[-2,4,-2],[1,-2,1]]`` (which
    cancels planes and is ``6 sigma`` on white noise) divided by
    ``6 * 0.6745``. Edges and texture raise it a little; blur does not.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The noisy image; integers are scaled to [0, 1].
    channel_axis : int or None, optional
        The colour axis of a 3-D image (default -1); None for a grey image.
        A 2-D image is always grey.

    Returns
    -------
    noise : (C,) float64 array
        The noise standard deviation of each channel (``C = 1`` for grey),
        in image units after scaling.

    Raises
    ------
    ValueError
        If the image is smaller than 3 x 3 pixels, contains NaN or infinite
        values, or has the wrong number of dimensions.
    TypeError
        If the image is not numeric.

    Examples
    --------
    >>> from car_napari.restoration import estimate_noise
    >>> rng = np.random.default_rng(0)
    >>> ramp = np.add.outer(np.linspace(0, 1, 64), np.linspace(0, 1, 64)) / 2
    >>> sigma = estimate_noise(ramp + rng.normal(0, 0.05, ramp.shape))
    >>> sigma.shape, bool(abs(sigma[0] - 0.05) < 0.01)
    ((1,), True)
    """
    data = as_channel_last_float(image, channel_axis=channel_axis)
    if min(data.shape[:2]) < 3:
        raise ValueError(f"the image {data.shape[:2]} is too small to estimate noise "
                         "(needs at least 3 x 3 pixels).")
    return noise_channel_last(data)


def noise_channel_last(data):
    """:func:`estimate_noise` of validated channel-last (H, W, C) float data."""
    return noise_channel_first(np.moveaxis(data, -1, 0))


def noise_channel_first(planes):
    """:func:`estimate_noise` of channel-first (C, H, W) planes."""
    return noise_from_medians([median_abs_laplacian(plane) for plane in planes])


def noise_from_medians(medians):
    """The noise levels from the channels' :func:`median_abs_laplacian`."""
    return np.array(medians) / _LAPLACIAN_SIGMAS
