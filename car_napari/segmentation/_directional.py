"""The four directional scans of one level of the features (:mod:`._features`):
each an adaptive scan streamed twice, its local parameters reduced on the fly
(samples for the robust scaling and the PCA, then every pixel projected), so
no image-sized array of them ever exists."""

from __future__ import annotations

import numpy as np

from ..model.adaptive import adaptive_scanner, adaptive_start
from ..model.directions import DIRECTIONS, scan_view
from ._blocked import _NS_SCAN, _NS_VALUE

# pixels each PCA is fitted on, and the robust scaling (medians) before it
_SAMPLE = 20000
_ROBUST_SAMPLE = 20000


def _scan_coords(index, shape, direction):
    """Scan coordinates (a, b) of raster pixel indices of an (h, w) image."""
    h, w = shape
    i, j = np.divmod(index, w)
    if direction == "down":
        return i, j
    if direction == "up":
        return h - 1 - i, j
    if direction == "right":
        return j, i
    return w - 1 - j, i  # left


class _Gather:
    """Rows of a streamed scan output at given raster pixels (in their order),
    collected chunk by chunk."""

    def __init__(self, index, shape, direction, shift, width):
        a, b = _scan_coords(np.asarray(index), shape, direction)
        ws = shape[1] if direction in ("down", "up") else shape[0]
        self.order = np.argsort(a, kind="stable")
        self.a = a[self.order]
        self.b = np.minimum(b[self.order] + shift, ws - 1)  # the re-centring
        self.values = np.empty((len(index), width))

    def take(self, start, stop, chunk):
        lo, hi = np.searchsorted(self.a, [start, stop])
        if hi > lo:
            self.values[self.order[lo:hi]] = chunk[self.a[lo:hi] - start, self.b[lo:hi]]


def _robust_fit(sample):
    """Median and spread (MAD, else the std) of the columns of a sample: a
    few ill-conditioned local fits must not dominate the PCA. (The medians
    run on the contiguous transpose: the same values, faster.)"""
    cols = np.ascontiguousarray(sample.T)
    med = np.median(cols, axis=1)
    mad = np.median(np.abs(cols - med[:, None]), axis=1) * 1.4826
    spread = np.where(mad > 0, mad, np.maximum(sample.std(axis=0), 1e-12))
    return med, spread


def _robust_apply(x, med, spread, clip, out=None):
    """Columns centred on the median, scaled by the spread and clipped."""
    out = np.subtract(x, med, out=out)
    out /= spread
    return np.clip(out, -clip, clip, out=out)


def _pca_fit(S, n_components):
    """Mean and principal axes of the rows of a sample: the leading
    eigenvectors of the scatter matrix (what the SVD of the centred sample
    gives, ~50x faster on 20000 x 36 samples), each signed so that its
    largest entry is positive (the SVD's signs are arbitrary)."""
    mean = S.mean(axis=0)
    centred = S - mean
    _, vec = np.linalg.eigh(centred.T @ centred)
    axes = vec[:, ::-1][:, :n_components]
    top = np.abs(axes).argmax(axis=0)
    return mean, axes * np.sign(axes[top, np.arange(axes.shape[1])])


def _iter_direction(centred, ctx, var, *, forgetting, direction, lag, clip, components,
                    pca_index, reduced, err, work, message):
    """One directional scan's reduced parameters into ``reduced`` (hm, wm, c)
    and, with ``err``, its share of the prediction-error energy added: two
    streamed passes (samples, the PCA's at ``pca_index``, then projection).
    Yields the work's records."""
    hm, wm = centred.shape[:2]
    n = hm * wm
    ws = wm if direction in ("down", "up") else hm
    shift = min(lag, ws // 4) if lag > 0 else 0
    cols = np.minimum(np.arange(ws) + shift, ws - 1)
    robust_index = np.arange(0, n, max(1, n // _ROBUST_SAMPLE))
    view_err = None if err is None else scan_view(err, direction)
    view_centred = scan_view(centred, direction)
    view_reduced = scan_view(reduced, direction)

    # pass 1: the samples, and the energy
    outputs = ("gamma", "mean") if err is not None else ("gamma",)
    warm = adaptive_start(centred, ctx, var, forgetting=forgetting, direction=direction)
    scanner = adaptive_scanner(centred, ctx, var, forgetting=forgetting, direction=direction,
                               outputs=outputs, stream=True, start=warm)
    width = ctx.n_targets * ctx.n_regressors
    rows = scanner.rows
    per_row = _NS_SCAN * scanner.pixel_work * ws
    samples = [_Gather(index, (hm, wm), direction, shift, width)
               for index in (robust_index, pca_index)]
    while not scanner.done:
        start, stop, out = scanner.advance()
        gamma = out["gamma"].reshape(stop - start, ws, width)
        for sample in samples:
            sample.take(start, stop, gamma)
        if err is not None:
            err2 = np.nan_to_num(((view_centred[start:stop] - out["mean"]) ** 2).sum(axis=2))
            view_err[start:stop] += err2 / len(DIRECTIONS)
        yield from work.progress(per_row * (stop - start), f"{message} (1/2), rows {stop}/{rows}")
    robust, pca_sample = (sample.values for sample in samples)
    if clip:
        med, spread = _robust_fit(robust)
        pca_sample = _robust_apply(pca_sample, med, spread, clip)
    mean, axes = _pca_fit(pca_sample, components)

    # pass 2: the same scan again, every pixel projected on the axes
    scanner = adaptive_scanner(centred, ctx, var, forgetting=forgetting, direction=direction,
                               outputs=("gamma",), stream=True, start=warm)  # as pass 1
    per_row = (_NS_SCAN * scanner.pixel_work + _NS_VALUE * width) * ws
    while not scanner.done:
        start, stop, out = scanner.advance()
        x = out["gamma"].reshape(stop - start, ws, width)[:, cols]  # a copy
        if clip:
            _robust_apply(x, med, spread, clip, out=x)
        x -= mean
        view_reduced[start:stop] = x @ axes
        yield from work.progress(per_row * (stop - start), f"{message} (2/2), rows {stop}/{rows}")
    yield work.step(0.0, message, force=True)  # one record after each scan


def _direction_groups(pool):
    """The directions' indices, run a group at a time: pairs on a pool, else one by one."""
    k = range(len(DIRECTIONS))
    return [k[:2], k[2:]] if pool is not None else [[i] for i in k]
