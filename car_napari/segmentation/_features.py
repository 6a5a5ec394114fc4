"""Per-pixel texture features of the segmentation: multiresolution local CAR
parameters ((14.33), section 14.4, docs/segmentation.md) and the pseudo-colour
of grey images."""

from __future__ import annotations

import numpy as np

from .._docstrings import shared_parameters
from .._progress import Progress, drain
from .._validation import as_channel_last_float, check_not_constant, summarize
from ..model.directions import DIRECTIONS, scan_view, unscan_view
from ..model.neighbourhood import Context, as_offsets
from ..model.recursive import adaptive_scan

__all__ = ["iter_local_features", "local_features", "pseudo_colour"]

# the coarsest pyramid level must keep at least this many pixels a side
_MIN_LEVEL_SIDE = 16


def pseudo_colour(grey, gammas=(0.5, 2.0)):
    """Pseudo-colour ``[Y, Y^g1, Y^g2]`` of a grey image scaled to [0, 1].

    A grey image gives the three-channel CAR models of the segmentation
    something to correlate (section 14.4, docs/mammography.md).

    Parameters
    ----------
    grey : (H, W) array_like
        Grey image, any numeric dtype; it is scaled to [0, 1] by its own
        minimum and maximum (a constant image becomes zeros).
    gammas : sequence of float, optional
        The gamma exponents of the channels after the first.

    Returns
    -------
    (H, W, 1 + len(gammas)) ndarray of float64
        The scaled image and its gamma transforms, channel last.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import pseudo_colour
    >>> pseudo_colour(np.array([[0, 1], [2, 4]]))[1, 0]
    array([0.5       , 0.70710678, 0.25      ])
    """
    g = np.asarray(grey, dtype=np.float64)
    lo, hi = g.min(), g.max()
    g = (g - lo) / (hi - lo) if hi > lo else np.zeros_like(g)
    return np.stack([g] + [g**gm for gm in gammas], axis=-1)


def _pca(X, n_components, rng, sample=20000):
    """Principal axes of the rows of X (fitted on a subsample)."""
    idx = rng.choice(X.shape[0], size=min(sample, X.shape[0]), replace=False)
    S = X[idx]
    mean = S.mean(axis=0)
    _, _, vt = np.linalg.svd(S - mean, full_matrices=False)
    return mean, vt[:n_components].T


def _whiten_channels(level):
    """Spectral Karhunen-Loeve transform with unit-variance factors.

    The 3DCAR parameters ((14.1)-(14.4), docs/model.md) transform as
    ``A -> B A B^{-1}`` under a channel mixing ``B`` (section 14.3,
    docs/model.md), so this changes no model, only how well the
    cross-spectral terms are conditioned (RGB channels are nearly collinear)
    and puts every parameter on a comparable scale.
    """
    h, w, d = level.shape
    flat = level.reshape(-1, d)
    mean = flat.mean(axis=0)
    if d == 1:
        std = flat.std()
        return np.ascontiguousarray((level - mean) / (std if std > 0 else 1.0))
    cov = np.cov((flat - mean).T)
    ev, vec = np.linalg.eigh(cov)
    ev = np.maximum(ev, 1e-6 * max(ev.max(), 1e-300))
    return np.ascontiguousarray(((flat - mean) @ (vec / np.sqrt(ev))).reshape(h, w, d))


def _recentre(field_, direction, lag):
    """Shift a scan's field back along the scan line by ``lag`` pixels.

    The recursive estimate at ``r`` describes the pixels scanned before
    ``r``; with forgetting ``phi`` its window trails ``r`` by
    ``phi^2 / (1 - phi^2)`` pixels on average. Shifting by that lag centres
    the window on ``r``, so boundaries are not displaced towards where each
    scan goes."""
    if lag <= 0:
        return field_
    g = scan_view(field_, direction)
    g = np.concatenate([g[:, lag:], np.repeat(g[:, -1:], lag, axis=1)], axis=1)
    return np.ascontiguousarray(unscan_view(g, direction))


def _robust_scale(flat, clip=4.0):
    """Columns centred on the median, scaled by the MAD and clipped: a few
    ill-conditioned local fits must not dominate the PCA."""
    sample = flat[:: max(1, flat.shape[0] // 20000)]
    med = np.median(sample, axis=0)
    mad = np.median(np.abs(sample - med), axis=0) * 1.4826
    spread = np.where(mad > 0, mad, np.maximum(sample.std(axis=0), 1e-12))
    out = (flat - med) / spread
    return np.clip(out, -clip, clip, out=out)


def _check_levels(shape, levels, neighbourhood):
    if not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be a positive int; got {levels!r}.")
    offsets, _ = as_offsets(neighbourhood)
    reach = Context.spatial(offsets, 1).reach
    need = (2 ** (levels - 1)) * max(_MIN_LEVEL_SIDE, 4 * (1 + sum(reach[1]) + sum(reach[0])))
    if min(shape[:2]) < need:
        raise ValueError(
            f"image {shape[0]}x{shape[1]} is too small for {levels} resolution "
            f"levels: each side needs at least {need} pixels. Use fewer levels or a "
            "larger image."
        )


_FEATURE_PARAMETERS = """
image : (H, W) or (H, W, C) array_like
    The image, any numeric dtype (integers are scaled to [0, 1]).
levels : int, optional
    Resolutions; each halves the previous one.
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the local models: an order or explicit
    (row, column) offsets (causal neighbourhoods, docs/model.md).
forgetting : float, optional
    Forgetting factor of the adaptive models, in (0, 1].
components : int, optional
    PCA components kept per direction (and ``components + 1`` per level).
smoothing : float, optional
    Gaussian width (pixels) of the smoothing of the stacked parameters.
mean_smoothing : float, optional
    Gaussian width of the local mean spectrum (default: ``smoothing``).
decorrelate : bool, optional
    Decorrelate the channels (spectral Karhunen-Loeve transform) first.
centre : bool, optional
    Re-centre each scan's estimates on the pixel (undo the forgetting lag).
clip : float, optional
    Robust standardisation clip (in MADs) of the parameters; 0 turns the
    standardisation off.
energy : bool, optional
    Append the log prediction-error energy of the local models.
level_smoothing : {'same', 'scaled'}, optional
    'same': the same widths on every level; otherwise halved per level.
channel_axis : int or None, optional
    Axis of the channels; a 2-D image is grey, None forces grey.
seed : int, optional
    Seed of the PCA subsampling.
"""


@shared_parameters(_FEATURE_PARAMETERS)
def iter_local_features(
    image,
    *,
    levels=3,
    neighbourhood=2,
    forgetting=0.99,
    components=3,
    smoothing=10.0,
    mean_smoothing=None,
    decorrelate=True,
    centre=True,
    clip=4.0,
    energy=True,
    level_smoothing="same",
    channel_axis=-1,
    seed=0,
):
    """Per-pixel texture features as a job: yield progress, return the features.

    See :func:`local_features` for what is computed.

    Parameters
    ----------
    {parameters}

    Returns
    -------
    (H, W, D) ndarray of float32
        The features, what :func:`local_features` returns (the generator's return value).

    Yields
    ------
    Progress
        Stage "features": one record at the start, one after each
        directional scan and one after each level.

    Raises
    ------
    ValueError
        If the image is constant, has NaN or infinite values, or is too
        small for ``levels`` resolutions.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import iter_local_features
    >>> job = iter_local_features(np.random.default_rng(0).random((32, 32)), levels=1)
    >>> [record.message for record in job][:2]
    ['level 1/1', 'level 1/1: down scan']
    """
    from scipy import ndimage
    from skimage.transform import pyramid_reduce, resize

    data = as_channel_last_float(image, channel_axis=channel_axis)
    check_not_constant(data, summary=summarize(data))
    _check_levels(data.shape, levels, neighbourhood)
    offsets, _ = as_offsets(neighbourhood)
    if mean_smoothing is None:
        mean_smoothing = smoothing
    rng = np.random.default_rng(seed)
    h, w, d = data.shape
    level = data
    blocks = []
    steps = levels * (len(DIRECTIONS) + 1)
    done = 0
    q = float(forgetting) ** 2
    lag = int(round(q / (1.0 - q))) if (centre and q < 1) else 0
    yield Progress("features", 0.0, f"level 1/{levels}")
    for m in range(levels):
        if m:
            level = pyramid_reduce(level, downscale=2, channel_axis=-1)
        hm, wm = level.shape[:2]
        sig = smoothing if level_smoothing == "same" else smoothing / 2**m
        msig = mean_smoothing if level_smoothing == "same" else mean_smoothing / 2**m
        source = _whiten_channels(level) if decorrelate else level
        summary = summarize(source)
        centred = np.ascontiguousarray(source - summary.mean)
        ctx = Context.spatial(offsets, d)
        reduced = []
        err = np.zeros((hm, wm))
        for direction in DIRECTIONS:
            res = adaptive_scan(centred, ctx, summary.var, forgetting=forgetting,
                                direction=direction, outputs=("gamma", "mean"))
            gamma = res["gamma"].reshape(hm, wm, -1)
            shift = min(lag, (wm if direction in ("down", "up") else hm) // 4)
            gamma = _recentre(gamma, direction, shift)
            if energy:
                err2 = np.nan_to_num(((centred - res["mean"]) ** 2).sum(axis=2))
                err += err2 / len(DIRECTIONS)
            flat = gamma.reshape(hm * wm, -1)
            if clip:
                flat = _robust_scale(flat, clip)
            mean, axes = _pca(flat, components, rng)
            reduced.append(((flat - mean) @ axes).reshape(hm, wm, -1))
            del gamma, flat, res
            done += 1
            yield Progress("features", done / steps, f"level {m + 1}/{levels}: {direction} scan")
        stacked = np.concatenate(reduced, axis=2)
        if sig > 0:
            stacked = ndimage.gaussian_filter(stacked, sigma=(sig, sig, 0))
        flat = stacked.reshape(hm * wm, -1)
        mean, axes = _pca(flat, components + 1, rng)
        parts = [((flat - mean) @ axes).reshape(hm, wm, -1)]
        if energy:
            # the local models' prediction-error energy (their Sigma), log scale
            e = ndimage.gaussian_filter(err, sig) if sig > 0 else err
            parts.append(np.log(e + 1e-6 * float(np.mean(summary.var)))[..., None])
        local_mean = level
        if msig > 0:
            local_mean = ndimage.gaussian_filter(level, sigma=(msig, msig, 0))
        parts.append(local_mean)
        feats = np.concatenate(parts, axis=2)
        if m:
            feats = resize(feats, (h, w), order=1, mode="edge", anti_aliasing=False)
        blocks.append(feats)
        done += 1
        yield Progress("features", done / steps, f"level {m + 1}/{levels} done")
    theta = np.concatenate(blocks, axis=2)
    theta -= theta.mean(axis=(0, 1))
    std = theta.std(axis=(0, 1))
    theta /= np.where(std > 0, std, 1.0)
    return theta.astype(np.float32)


@shared_parameters(_FEATURE_PARAMETERS)
def local_features(
    image,
    *,
    levels=3,
    neighbourhood=2,
    forgetting=0.99,
    components=3,
    smoothing=10.0,
    mean_smoothing=None,
    decorrelate=True,
    centre=True,
    clip=4.0,
    energy=True,
    level_smoothing="same",
    channel_axis=-1,
    seed=0,
):
    """Per-pixel texture features ``Theta_r`` of the segmentation, at full resolution.

    On each level of a Gaussian pyramid (colour first decorrelated by a
    spectral Karhunen-Loeve transform), the adaptive parameters of the four
    directional models (re-centred on the pixel, robustly standardised) are
    each reduced by PCA to ``components`` values, stacked, smoothed
    (Gaussian, ``smoothing`` pixels), reduced by PCA again to
    ``components + 1`` values, and joined by the log prediction-error energy
    of the local models and the local mean spectrum; coarse levels are
    interpolated to full resolution. Every feature is standardised. This is
    the feature vector of (14.33), section 14.4, docs/segmentation.md.

    Parameters
    ----------
    {parameters}

    Returns
    -------
    (H, W, D) ndarray of float32
        The features, standardised features (zero mean, unit variance each).

    Raises
    ------
    ValueError
        If the image is constant, has NaN or infinite values, or is too
        small for ``levels`` resolutions.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import local_features
    >>> local_features(np.random.default_rng(0).random((32, 32)), levels=1).shape
    (32, 32, 6)
    """
    return drain(iter_local_features(
        image, levels=levels, neighbourhood=neighbourhood, forgetting=forgetting,
        components=components, smoothing=smoothing, mean_smoothing=mean_smoothing,
        decorrelate=decorrelate, centre=centre, clip=clip, energy=energy,
        level_smoothing=level_smoothing, channel_axis=channel_axis, seed=seed,
    ))
