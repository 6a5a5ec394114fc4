"""The noise level of an image, for the edge rule of restoration."""

from __future__ import annotations

import numpy as np
from numba import njit

from .._validation import as_channel_last_float

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


_FAST = {"reassoc", "contract", "arcp"}


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _laplacian_abs(channel, i, j):
    return abs(channel[i - 1, j - 1] + channel[i - 1, j + 1] + channel[i + 1, j - 1]
               + channel[i + 1, j + 1]
               - 2.0 * (channel[i - 1, j] + channel[i + 1, j] + channel[i, j - 1]
                        + channel[i, j + 1])
               + 4.0 * channel[i, j])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def median_abs_laplacian(channel):
    """The median of ``|[[1,-2,1],[-2,4,-2],[1,-2,1]] * channel|`` over the
    interior, exactly as ``np.median`` (the mean of the two middle values
    for an even count), in O(n) and without storing the responses: one pass
    histograms them (the range from a sample, with an overflow bin), a
    second collects the values of the bins holding the two middle ranks,
    which alone are sorted. Falls back to the exact maximum as the range if
    a middle rank lands in the overflow bin."""
    H, W = channel.shape
    n = (H - 2) * (W - 2)
    if n <= 0:
        return 0.0
    top = 0.0
    step = max(1, n // 4096)  # a sample of the responses sets the range
    for k in range(0, n, step):
        top = max(top, _laplacian_abs(channel, 1 + k // (W - 2), 1 + k % (W - 2)))
    low, high = (n - 1) // 2, n // 2
    for attempt in range(2):
        if top == 0.0:
            return 0.0
        bins = 4096
        hist = np.zeros(bins + 1, np.int64)  # the last bin: above ``top``
        scale = bins / top
        for i in range(1, H - 1):
            for j in range(1, W - 1):
                hist[min(int(_laplacian_abs(channel, i, j) * scale), bins)] += 1
        b_low, below_low = _bin_of(hist, low)
        b_high, below_high = _bin_of(hist, high)
        if b_high < bins or attempt == 1:
            break
        top = 0.0  # rare: the sample missed the range; take the exact maximum
        for i in range(1, H - 1):
            for j in range(1, W - 1):
                top = max(top, _laplacian_abs(channel, i, j))
    lows = np.empty(hist[b_low])
    highs = np.empty(hist[b_high])
    n_low = n_high = 0
    for i in range(1, H - 1):
        for j in range(1, W - 1):
            v = _laplacian_abs(channel, i, j)
            b = min(int(v * scale), bins)
            if b == b_low:
                lows[n_low] = v
                n_low += 1
            if b == b_high:
                highs[n_high] = v
                n_high += 1
    lows.sort()
    highs.sort()
    return 0.5 * (lows[low - below_low] + highs[high - below_high])


@njit(cache=True, nogil=True, error_model="numpy")
def _bin_of(hist, rank):
    """(bin holding the ``rank``-th smallest value, count below that bin)."""
    below = 0
    b = 0
    while below + hist[b] <= rank:
        below += hist[b]
        b += 1
    return b, below
