"""Region-level CAR test of the automatic K (issue 32, item 13;
docs/segmentation.md).

The mixture's features are local (a window of about ten pixels), so the
parts of one texture can lie farther apart in them than two textures do and
the automatic K over-splits. Here every segment of the chosen state gets
one CAR model fitted on all its interior pixels (least squares on the
causal neighbours ``_OFFSETS`` plus a constant, a Gaussian residual over the
channels): a model from ten thousand pixels rather than a window. Two
segments are one texture when each one's model predicts the other's pixels
almost as well as their own: the symmetric cross-prediction loss, in nats
per pixel and channel,

    D(A, B) = [l_B(B) - l_A(B)] + [l_A(A) - l_B(A)],

where ``l_M(S)`` is the mean log density of segment ``S``'s pixels under
model ``M``; it is the sample symmetric Kullback-Leibler divergence of the
two predictive models, independent of the segments' sizes. All of it comes
from each segment's moment matrix ``sum z z^T`` of ``z = [y, x, 1]``
(pixel, neighbours, constant), so a union of segments is a sum of moments.
"""

from __future__ import annotations

import numpy as np

from .._progress import Progress, drain, stage
from .._validation import as_channel_last_float

# causal neighbours of the region models (row, column offsets): the
# half-plane of order 2 with the second lags along rows and columns
_OFFSETS = ((0, -1), (-1, -1), (-1, 0), (-1, 1), (0, -2), (-2, 0))
# how far they reach up, left and right (the pixels along the image's edges
# within that reach have no complete neighbourhood)
_TOP = -min(dr for dr, _ in _OFFSETS)
_LEFT = -min(dc for _, dc in _OFFSETS)
_RIGHT = max(dc for _, dc in _OFFSETS)
# rows of the design built at once (a band of z vectors, float64)
_BAND_PIXELS = 1 << 15
# segments with fewer interior pixels get no model of their own: their
# losses are not taken (noise of a few dozen pixels)
_MIN_PIXELS = 50
# floor of the residual covariance, relative to the variance of the
# modelled pixels (a flat segment predicts itself perfectly)
_RESIDUAL_FLOOR = 1e-4
_RIDGE = 1e-6


def region_moments(image, labels, ids):
    """Moment matrices of each segment's interior pixels
    (:func:`iter_region_moments` run to its end).

    Parameters
    ----------
    image : (H, W, C) ndarray
        The image, channels last, any numeric dtype (integers are scaled
        to [0, 1]; a view is read band by band, never copied whole).
    labels : (H, W) ndarray of int
        Segment ids (0: none).
    ids : sequence of int
        The segments wanted.

    Returns
    -------
    moments : (len(ids), D, D) ndarray of float64
        ``sum z z^T`` over each segment's pixels whose causal neighbours
        (``_OFFSETS``) lie in the same segment, ``z`` = the pixel's ``C``
        channels, its neighbours' ``6 C`` values, then 1 (``D = 7 C + 1``).
    counts : (len(ids),) ndarray of int
        Those pixels' numbers.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((8, 8, 1))
    >>> labels = np.ones((8, 8), int)
    >>> moments, counts = region_moments(image, labels, [1])
    >>> moments.shape, int(counts[0])  # 2 rows, 2 + 1 columns lack neighbours
    ((1, 8, 8), 30)
    """
    return drain(iter_region_moments(image, labels, ids))


def iter_region_moments(image, labels, ids):
    """:func:`region_moments` as a job: a record after every band of rows
    (about ``_BAND_PIXELS`` pixels), the moments returned."""
    h, w, c = image.shape
    ids = np.asarray(ids)
    lookup = np.full(int(max(labels.max(initial=0), ids.max(initial=0))) + 1, -1)
    lookup[ids] = np.arange(ids.size)
    d = c * (len(_OFFSETS) + 1) + 1
    moments = np.zeros((ids.size, d, d))
    counts = np.zeros(ids.size, np.int64)
    rows = max(1, _BAND_PIXELS // w)
    for r0 in range(_TOP, h, rows):
        r1 = min(h, r0 + rows)
        # the band's rows and those its neighbours reach, as floats (like
        # the features: integers scaled to [0, 1]); no whole-image copy
        block = as_channel_last_float(image[r0 - _TOP:r1], copy=False)
        band = labels[r0:r1, _LEFT:w - _RIGHT]
        same = np.ones(band.shape, bool)
        z = np.empty(band.shape + (d,))
        z[..., :c] = block[_TOP:, _LEFT:w - _RIGHT]
        for n, (dr, dc) in enumerate(_OFFSETS, 1):
            rs, cs = slice(r0 + dr, r1 + dr), slice(_LEFT + dc, w - _RIGHT + dc)
            same &= labels[rs, cs] == band
            z[..., n * c:(n + 1) * c] = block[_TOP + dr:_TOP + dr + r1 - r0, cs]
        z[..., -1] = 1.0
        which = lookup[band]
        which[~same] = -1
        order = np.argsort(which, axis=None, kind="stable")
        sorted_which = which.ravel()[order]
        bounds = np.searchsorted(sorted_which, np.arange(ids.size + 1))
        zs = z.reshape(-1, d)[order]
        for a in range(ids.size):
            part = zs[bounds[a]:bounds[a + 1]]
            moments[a] += part.T @ part
            counts[a] += part.shape[0]
        yield Progress("region models", r1 / h, f"rows {r1}/{h}")
    return moments, counts


def _model(moment, count, channels, floor):
    """Least-squares CAR model of a segment from its moments: the
    parameters (D - C, C) and the residual covariance (C, C)."""
    s = moment / count
    syy, sxy, sxx = s[:channels, :channels], s[channels:, :channels], s[channels:, channels:]
    theta = np.linalg.solve(sxx + _RIDGE * np.eye(sxx.shape[0]), sxy)
    residual = syy - theta.T @ sxy - sxy.T @ theta + theta.T @ sxx @ theta
    return theta, (residual + residual.T) / 2 + floor * np.eye(channels)


def _mean_log_density(theta, residual, moment, count, channels):
    """Mean Gaussian log density of a segment's pixels (its moments) under
    a model (``theta``, ``residual``)."""
    s = moment / count
    syy, sxy, sxx = s[:channels, :channels], s[channels:, :channels], s[channels:, channels:]
    error = syy - theta.T @ sxy - sxy.T @ theta + theta.T @ sxx @ theta
    _, logdet = np.linalg.slogdet(residual)
    return -0.5 * (channels * np.log(2 * np.pi) + logdet
                   + np.trace(np.linalg.solve(residual, error)))


def cross_prediction_loss(moments_a, count_a, moments_b, count_b, channels, floor=0.0):
    """Symmetric cross-prediction loss of two segments, nats per pixel and channel.

    Parameters
    ----------
    moments_a, moments_b : (D, D) ndarray
        The segments' moment matrices (:func:`region_moments`).
    count_a, count_b : int
        Their pixel counts.
    channels : int
        ``C``, the image's channels.
    floor : float, optional
        Added to the residual covariances' diagonal.

    Returns
    -------
    float
        ``D(A, B)`` of the module's docstring, over ``channels`` (>= 0 up
        to the floor and the ridge).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> image = rng.random((64, 64, 1))
    >>> labels = np.where(np.arange(64) < 32, 1, 2)[None, :].repeat(64, 0)
    >>> m, n = region_moments(image, labels, [1, 2])
    >>> loss = cross_prediction_loss(m[0], n[0], m[1], n[1], 1)
    >>> bool(0 <= loss < 0.01)  # the same white noise on both sides
    True
    """
    theta_a, residual_a = _model(moments_a, count_a, channels, floor)
    theta_b, residual_b = _model(moments_b, count_b, channels, floor)
    loss = (_mean_log_density(theta_b, residual_b, moments_b, count_b, channels)
            - _mean_log_density(theta_a, residual_a, moments_b, count_b, channels)
            + _mean_log_density(theta_a, residual_a, moments_a, count_a, channels)
            - _mean_log_density(theta_b, residual_b, moments_a, count_a, channels))
    return float(loss / channels)


def region_merge_order(image, labels, ids):
    """Greedy merging of segments by the cross-prediction loss.

    The pair of groups of least loss is merged (moments summed) until one
    group is left; pairs where a group has fewer than ``_MIN_PIXELS``
    interior pixels are taken last, in their order.

    Parameters
    ----------
    image : (H, W, C) ndarray
        The image, channels last (as :func:`region_moments` reads it).
    labels : (H, W) ndarray of int
        The segments' ids (0: none).
    ids : sequence of int
        The segments to merge (at least one).

    Returns
    -------
    list of (float, int, int)
        Per merge, its loss and one id of each of the two groups merged
        (any member's id names its group); ``len(ids) - 1`` merges.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> noise, ramp = rng.random((64, 32)), np.cumsum(rng.random((64, 32)), axis=1)
    >>> image = np.hstack([noise, noise[::-1], ramp / ramp.max()])[..., None]
    >>> labels = np.repeat([1, 2, 3], 32)[None, :].repeat(64, 0)
    >>> [(a, b) for _, a, b in region_merge_order(image, labels, [1, 2, 3])][0]
    (1, 2)
    """
    return drain(iter_region_merge_order(image, labels, ids))


def iter_region_merge_order(image, labels, ids):
    """:func:`region_merge_order` as a job: records while the moments are
    summed (in bands of rows) and after every merge; the merges returned."""
    ids = [int(i) for i in ids]
    channels = image.shape[2]
    moments, counts = yield from stage(iter_region_moments(image, labels, ids), 0.0, 0.9)
    # the channels' mean variance over all the modelled pixels, from their moments
    total, n = moments.sum(axis=0), max(int(counts.sum()), 1)
    mean = total[:channels, -1] / n
    variance = float(np.mean(np.diag(total[:channels, :channels]) / n - mean**2))
    floor = _RESIDUAL_FLOOR * max(variance, 1e-12)
    groups = {i: (moments[a], int(counts[a])) for a, i in enumerate(ids)}
    rank = {i: a for a, i in enumerate(ids)}  # pairs are (earlier, later) in ids

    def ordered(a, b):
        return (a, b) if rank[a] < rank[b] else (b, a)

    def loss(key_a, key_b):
        (m_a, n_a), (m_b, n_b) = groups[key_a], groups[key_b]
        if min(n_a, n_b) < _MIN_PIXELS:
            return np.inf
        return cross_prediction_loss(m_a, n_a, m_b, n_b, channels, floor)

    # every pair's loss once; after a merge only the new group's pairs change
    losses = {(a, b): loss(a, b) for x, a in enumerate(ids) for b in ids[x + 1:]}
    merges = []
    while len(groups) > 1:
        pair = min(losses, key=lambda key: (losses[key], rank[key[0]], rank[key[1]]))
        key_a, key_b = pair
        merges.append((float(losses[pair]), key_a, key_b))
        (m_a, n_a), (m_b, n_b) = groups[key_a], groups.pop(key_b)
        groups[key_a] = (m_a + m_b, n_a + n_b)
        losses = {key: value for key, value in losses.items()
                  if key_b not in key and key_a not in key}
        for other in groups:
            if other != key_a:
                key = ordered(key_a, other)
                losses[key] = loss(*key)
        yield Progress("region models", 0.9 + 0.1 * len(merges) / (len(ids) - 1),
                       f"{len(groups)} regions")
    return merges
