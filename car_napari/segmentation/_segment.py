"""Unsupervised multiresolution texture segmentation (SPEC section 3).

Four directional adaptive 3DCAR models at several resolutions give a feature
vector ``Theta_r`` per pixel; a Gaussian mixture with diagonal covariances is
fitted by EM from a regular initialisation and shrunk by Kullback-Leibler
merging; pixels are labelled by the neighbourhood-weighted posterior.

:func:`iter_segment` is a generator yielding a :class:`SegmentationState`
after the features, after initialisation and after every merge, and finally
the :class:`SegmentationResult`, so a GUI can show the segments merging live.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import as_channel_last_float, check_not_constant, summarize
from ..model.neighbourhood import Context, as_offsets
from ..model.directions import DIRECTIONS, scan_view, unscan_view
from ..model.recursive import adaptive_scan

__all__ = [
    "segment",
    "iter_segment",
    "local_features",
    "SegmentationState",
    "SegmentationResult",
    "pseudo_colour",
]

_MIN_LEVEL_SIDE = 16


@dataclass
class SegmentationState:
    """One step of :func:`iter_segment`, for progress and live display."""

    stage: str
    fraction: float
    labels: np.ndarray | None
    n_components: int
    kl: float | None = None


@dataclass
class Mixture:
    """Gaussian mixture with diagonal covariances; ``ids`` name components
    stably across merges (a merged component keeps its stronger partner's id)."""

    weights: np.ndarray
    means: np.ndarray
    variances: np.ndarray
    ids: np.ndarray
    loglik: float = np.nan

    def copy(self):
        return Mixture(self.weights.copy(), self.means.copy(), self.variances.copy(),
                       self.ids.copy(), self.loglik)

    @property
    def k(self):
        return self.weights.size


@dataclass
class SegmentationResult:
    """Outcome of :func:`segment`: labels plus the whole merge history.

    Attributes
    ----------
    labels : (H, W) ndarray of int
        1..K, 0 where unclassified.
    n_segments : int
        K of ``labels`` (found automatically unless given).
    history : list of Mixture
        Mixtures from ``K_ini`` components down to 1, one per merge.
    probability : (H, W) ndarray
        Neighbourhood-weighted posterior probability of each pixel's label.
    """

    labels: np.ndarray
    n_segments: int
    history: list
    probability: np.ndarray
    features: np.ndarray = field(repr=False)
    smoothing: float = 2.0
    min_area: int = 0
    threshold: float = 0.0
    mask: np.ndarray | None = field(default=None, repr=False)

    def mixture_at(self, k):
        ks = [mx.k for mx in self.history]
        if not ks:
            raise ValueError("the merge history is empty.")
        k = int(np.clip(k, min(ks), max(ks)))
        # the last mixture with at least k components (weak ones may be dropped)
        best = min((mx for mx in self.history if mx.k >= k), key=lambda mx: mx.k)
        return best

    def labels_at(self, k, *, threshold=None):
        """Labelling with ``k`` segments from the stored history (no new
        features, no new EM): instant enough for a slider."""
        mix = self.mixture_at(k)
        labels, _ = label_pixels(
            self.features, mix, smoothing=self.smoothing,
            threshold=self.threshold if threshold is None else threshold,
            min_area=self.min_area,
        )
        if self.mask is not None:
            labels[~self.mask] = 0
        return _renumber(labels)


def pseudo_colour(grey, gammas=(0.5, 2.0)):
    """``[Y, Y^g1, Y^g2]`` from a grey image scaled to [0, 1] (SPEC 3.1)."""
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
    """Spectral Karhunen-Loeve transform with unit-variance factors (SPEC 1.2).

    The 3DCAR parameters transform as ``A -> B A B^{-1}`` under a channel
    mixing ``B`` (SPEC 2), so this changes no model, only how well the
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
    progress=None,
):
    """Per-pixel texture features ``Theta_r`` of SPEC 3.4 at full resolution.

    On each level of a Gaussian pyramid (colour first decorrelated by a
    spectral Karhunen-Loeve transform), the adaptive parameters of the four
    directional models (re-centred on the pixel, robustly standardised) are
    each reduced by PCA to ``components`` values, stacked, smoothed
    (Gaussian, ``smoothing`` pixels), reduced by PCA again to
    ``components + 1`` values, and joined by the log prediction-error energy
    of the local models and the local mean spectrum; coarse levels are
    interpolated to full resolution. Every feature is standardised.

    Returns
    -------
    features : (H, W, D) ndarray of float32
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
            if progress is not None:
                progress(done / steps)
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
        if progress is not None:
            progress(done / steps)
    theta = np.concatenate(blocks, axis=2)
    theta -= theta.mean(axis=(0, 1))
    std = theta.std(axis=(0, 1))
    theta /= np.where(std > 0, std, 1.0)
    return theta.astype(np.float32)


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


# --- Gaussian mixture with diagonal covariances -----------------------------


def _log_densities(X, mix):
    """log(w_j N(x | mu_j, diag var_j)) for every row x and component j."""
    inv = 1.0 / mix.variances  # (K, D)
    const = -0.5 * (np.log(2 * np.pi * mix.variances).sum(axis=1)) + np.log(mix.weights)
    quad = (X**2) @ inv.T - 2.0 * X @ (mix.means * inv).T + ((mix.means**2) * inv).sum(axis=1)
    return const - 0.5 * quad


def _posteriors(X, mix):
    logd = _log_densities(X, mix)
    top = logd.max(axis=1, keepdims=True)
    dens = np.exp(logd - top)
    total = dens.sum(axis=1, keepdims=True)
    loglik = float(np.mean(np.log(total[:, 0]) + top[:, 0]))
    return dens / total, loglik


def _em_steps(X, mix, steps, var_floor):
    for _ in range(steps):
        post, loglik = _posteriors(X, mix)
        nk = post.sum(axis=0) + 1e-12
        mix.weights = nk / nk.sum()
        mix.means = (post.T @ X) / nk[:, None]
        mix.variances = np.maximum((post.T @ X**2) / nk[:, None] - mix.means**2, var_floor)
        mix.loglik = loglik
    _, mix.loglik = _posteriors(X, mix)
    return mix


def _block_init(features, n_init, var_floor):
    """Components from a regular division of the image into ~n_init blocks."""
    h, w, D = features.shape
    rows = max(1, int(round(np.sqrt(n_init * h / w))))
    cols = max(1, int(round(n_init / rows)))
    means, variances = [], []
    for bi in np.array_split(np.arange(h), rows):
        for bj in np.array_split(np.arange(w), cols):
            block = features[bi[0] : bi[-1] + 1, bj[0] : bj[-1] + 1].reshape(-1, D)
            means.append(block.mean(axis=0))
            variances.append(np.maximum(block.var(axis=0), var_floor))
    k = len(means)
    return Mixture(np.full(k, 1.0 / k), np.array(means), np.array(variances), np.arange(1, k + 1))


def _kl_matrix(mix):
    """Symmetric KL divergence between every pair of diagonal Gaussians."""
    m, v = mix.means, mix.variances
    diff2 = (m[:, None, :] - m[None, :, :]) ** 2
    ratio = v[:, None, :] / v[None, :, :]
    kl = 0.5 * (ratio + diff2 / v[None, :, :] - 1.0 - np.log(ratio)).sum(axis=2)
    sym = kl + kl.T
    np.fill_diagonal(sym, np.inf)
    return sym


def _merge(mix, i, j):
    """Merge the weaker of (i, j) into the stronger by moment matching."""
    if mix.weights[i] < mix.weights[j]:
        i, j = j, i
    wi, wj = mix.weights[i], mix.weights[j]
    w = wi + wj
    mean = (wi * mix.means[i] + wj * mix.means[j]) / w
    var = (wi * (mix.variances[i] + mix.means[i] ** 2)
           + wj * (mix.variances[j] + mix.means[j] ** 2)) / w - mean**2
    mix.weights[i], mix.means[i], mix.variances[i] = w, mean, var
    keep = np.arange(mix.k) != j
    return Mixture(mix.weights[keep], mix.means[keep], mix.variances[keep], mix.ids[keep])


def label_pixels(features, mix, *, smoothing=2.0, threshold=0.0, min_area=0):
    """Neighbourhood-weighted labelling (SPEC 3.7) and small-blob clean-up (3.8).

    The posterior of every component is averaged over a Gaussian window
    (``smoothing`` pixels: the distance-weighted neighbourhood ``I_r``), each
    pixel takes the best component (labels are the component ids, 1..), a
    pixel whose best averaged posterior is below ``threshold`` is 0, and
    blobs smaller than ``min_area`` pixels join the nearest larger segment.
    """
    from scipy import ndimage

    h, w, D = features.shape
    post, _ = _posteriors(features.reshape(-1, D).astype(np.float64), mix)
    post = post.reshape(h, w, mix.k)
    if smoothing > 0:
        post = ndimage.gaussian_filter(post, sigma=(smoothing, smoothing, 0))
    best = post.argmax(axis=2)
    prob = np.take_along_axis(post, best[..., None], axis=2)[..., 0]
    labels = mix.ids[best].astype(np.int32)
    if min_area > 0:
        labels = _absorb_small_blobs(labels, min_area)
    if threshold > 0:
        labels[prob < threshold] = 0
    return labels, prob


def _absorb_small_blobs(labels, min_area):
    from skimage.measure import label as connected
    from skimage.segmentation import expand_labels

    regions = connected(labels, connectivity=1, background=-1)
    sizes = np.bincount(regions.ravel())
    small = sizes[regions] < min_area
    if not small.any() or small.all():
        return labels
    out = labels.copy()
    out[small] = 0
    return expand_labels(out, distance=max(labels.shape))


def iter_segment(
    image,
    *,
    n_segments=None,
    levels=3,
    neighbourhood=2,
    forgetting=0.99,
    n_init=16,
    smoothing=2.0,
    threshold=0.0,
    min_area=None,
    merge_threshold=1.5,
    grey="pseudo_colour",
    mask=None,
    channel_axis=-1,
    seed=0,
    features=None,
    feature_options=None,
    var_floor=0.1,
    merge_em_steps=3,
):
    """Segment a texture image, yielding progress and intermediate states.

    Yields :class:`SegmentationState` objects (stage 'features', 'initialised',
    'merged') and finally a :class:`SegmentationResult`. See :func:`segment`
    for the parameters.
    """
    if n_segments is not None and (not isinstance(n_segments, (int, np.integer))
                                   or n_segments < 1):
        raise ValueError(f"n_segments must be a positive int or None; got {n_segments!r}.")
    if not isinstance(n_init, (int, np.integer)) or n_init < 2:
        raise ValueError(f"n_init must be an int >= 2; got {n_init!r}.")
    if n_segments is not None and n_segments > n_init:
        raise ValueError(f"n_segments ({n_segments}) must not exceed n_init ({n_init}).")
    if not 0.0 <= threshold < 1.0:
        raise ValueError(f"threshold must be in [0, 1); got {threshold}.")
    arr = np.asarray(image) if image is not None else None
    if arr is not None and arr.ndim == 2 or channel_axis is None:
        if grey == "pseudo_colour":
            data = as_channel_last_float(image, channel_axis=None)
            check_not_constant(data)
            image, channel_axis = pseudo_colour(data[..., 0]), -1
        elif grey != "grey":
            raise ValueError(f"grey must be 'pseudo_colour' or 'grey'; got {grey!r}.")
    yield SegmentationState("features", 0.0, None, 0)
    if features is None:
        features = local_features(
            image, levels=levels, neighbourhood=neighbourhood, forgetting=forgetting,
            channel_axis=channel_axis, seed=seed, **(feature_options or {}),
        )
    else:
        features = np.asarray(features, dtype=np.float32)
    h, w, D = features.shape
    if min_area is None:
        min_area = max(16, (h * w) // 2000)
    yield SegmentationState("features", 0.3, None, 0)

    rng = np.random.default_rng(seed)
    flat = features.reshape(-1, D).astype(np.float64)
    sel = np.ones(h * w, bool) if mask is None else np.asarray(mask, bool).ravel()
    if mask is not None and (sel.size != h * w or not sel.any()):
        raise ValueError("mask must be (H, W) like the image and select at least one pixel.")
    idx = np.flatnonzero(sel)
    sample = flat[rng.choice(idx, size=min(idx.size, 40000), replace=False)]
    mix = _block_init(features, n_init, var_floor)
    mix = _em_steps(sample, mix, 10, var_floor)
    history = [mix.copy()]
    labels, _ = label_pixels(features, mix, smoothing=smoothing, min_area=0)
    yield SegmentationState("initialised", 0.35, labels, mix.k)

    k_ini = mix.k
    while mix.k > 1:
        mix = _em_steps(sample, mix, 2, var_floor)
        weak = mix.weights < 0.01 / k_ini
        if weak.any() and not weak.all():
            mix = Mixture(mix.weights[~weak] / mix.weights[~weak].sum(), mix.means[~weak],
                          mix.variances[~weak], mix.ids[~weak])
        if mix.k == 1:
            break
        kl = _kl_matrix(mix)
        i, j = np.unravel_index(np.argmin(kl), kl.shape)
        kl_value = float(kl[i, j])
        mix = _merge(mix, i, j)
        mix = _em_steps(sample, mix, merge_em_steps, var_floor)
        history.append(mix.copy())
        labels, _ = label_pixels(features, mix, smoothing=smoothing, min_area=0)
        yield SegmentationState("merged", 0.35 + 0.6 * (1 - (mix.k - 1) / max(k_ini - 1, 1)),
                                labels, mix.k, kl_value)

    if n_segments is None:
        n_segments = _choose_k(history, merge_threshold)
    result = SegmentationResult(
        labels=None, n_segments=n_segments, history=history, probability=None,
        features=features, smoothing=smoothing, min_area=min_area, threshold=threshold,
        mask=None if mask is None else np.asarray(mask, bool),
    )
    mix = result.mixture_at(n_segments)
    labels, prob = label_pixels(features, mix, smoothing=smoothing, threshold=threshold,
                                min_area=min_area)
    if mask is not None:
        labels[~np.asarray(mask, bool)] = 0
    result.labels, result.probability = _renumber(labels), prob
    result.n_segments = int(result.labels.max())
    yield result


def _renumber(labels):
    """Labels 1..K (in order of the old values), 0 kept."""
    values, inverse = np.unique(labels, return_inverse=True)
    new = np.arange(values.size) + (0 if values[0] == 0 else 1)
    return new[inverse].reshape(labels.shape).astype(labels.dtype)


def _choose_k(history, threshold):
    """Automatic number of segments: keep merging while a merge costs less
    than ``threshold`` nats of mean log-likelihood per pixel (SPEC 3.6's
    likelihood-gain stop); the first costlier merge stops it."""
    for prev, nxt in zip(history, history[1:]):
        if prev.loglik - nxt.loglik > threshold:
            return prev.k
    return history[-1].k


def segment(image, **kwargs):
    """Unsupervised texture segmentation (SPEC section 3).

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Grey images are turned into pseudo-colour ``[Y, Y^0.5, Y^2]`` unless
        ``grey='grey'``.
    n_segments : int or None, optional
        Stop merging at this many segments; None finds it automatically.
    levels : int, optional
        Resolutions (each halves the image).
    neighbourhood : int or (eta, 2) array, optional
    forgetting : float, optional
        Forgetting factor of the adaptive models.
    n_init : int, optional
        ``K_ini``: components of the initial regular block division.
    smoothing : float, optional
        Width (pixels) of the neighbourhood weighting in the labelling.
    threshold : float, optional
        Pixels whose neighbourhood-weighted posterior is below this are 0.
    min_area : int, optional
        Blobs smaller than this join their neighbour (default: 1/2000 of
        the image, at least 16 pixels).
    merge_threshold : float, optional
        Automatic stop: the largest loss of mean log-likelihood per pixel a
        merge may cost (1.5 was best among 0.75-2.5 on 5-texture VisTex and
        Brodatz mosaics of tuning seeds 101-102 with the default features).
    mask : (H, W) bool array, optional
        Pixels to segment (the mixture is fitted on them; others are 0).
    channel_axis : int or None, optional
    seed : int, optional
    features : (H, W, D) array, optional
        Precomputed :func:`local_features` (skips the scans: re-clustering
        with other mixture options is then fast).
    feature_options : dict, optional
        Extra keyword options for :func:`local_features` (``smoothing``,
        ``components``, ``decorrelate``, ``centre``, ``clip``, ``energy``...).
    var_floor : float, optional
        Floor of every component's variance, in units of the standardised
        features' variance: stops EM from making narrow components that
        split one texture (0.1 lifted ARI from 0.44 to 0.57 on VisTex
        tuning mosaics told K = 5).
    merge_em_steps : int, optional
        EM steps after each KL merge.

    Returns
    -------
    SegmentationResult
        ``.labels`` (H, W) int, 0 = unclassified, and ``.labels_at(k)``.
    """
    result = None
    for result in iter_segment(image, **kwargs):
        pass
    return result
