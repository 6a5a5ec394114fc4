"""The work-bounded steps of the features (:mod:`._features`): progress in
proportion to the estimated work (:class:`_Work`), and the blocked forms of
the smoothing, pyramid reduction, channel whitening and upsampling, each
giving, bit for bit, what the one-call NumPy/SciPy form gives, with a
yield about every 0.1 s of work."""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from .._progress import Progress, row_blocks
from ..model.blocks import row_ranges

# values per block of the whole-image passes that make float64 temporaries
_SMALL_BLOCK = 1 << 20
# estimated work (about ns of one core) between two yields, and at most this
# much CPU time of the job's thread
_YIELD_WORK = 7.0e7
_YIELD_CPU = 0.1
# estimated ns per unit of work of each kind of step (see _Work)
_NS_GAUSS = 0.6  # per value and tap of a 1-D Gaussian pass
_NS_SCAN = 0.4  # per work unit of a scan (see recursive._pixel_cost)
_NS_VALUE = 4.0  # per value of an elementwise NumPy pass


class _Work:
    """Progress proportional to the estimated work: ``step`` adds work done
    and returns a record once ``_YIELD_WORK`` has piled up since the last, or
    ``_YIELD_CPU`` seconds of this thread's CPU time have passed (whichever
    is first: an estimate that is off cannot make a long stretch)."""

    def __init__(self, total):
        self.total = max(float(total), 1.0)
        self.done = 0.0
        self.pending = 0.0
        self._lock = threading.Lock()  # two scans side by side step it
        self._clocks = {}  # each thread's CPU time at its last record

    def step(self, work, message, force=False):
        thread = threading.get_ident()
        now = time.thread_time()  # this thread's
        with self._lock:
            self.done += work
            self.pending += work
            since = now - self._clocks.setdefault(thread, now)
            if force or self.pending >= _YIELD_WORK or since >= _YIELD_CPU:
                self.pending = 0.0
                self._clocks[thread] = now
                return Progress("features", min(self.done / self.total, 1.0), message)
            return None

    def progress(self, work, message):
        """:meth:`step` in a job: yields its record, if it makes one."""
        record = self.step(work, message)
        if record:
            yield record


# pixels (rows of the (N, d) view) per block of the whitening, centring and reduction
_LONG_ROWS = 1 << 16


def _taps(sigma):
    return 2 * int(4.0 * float(sigma) + 0.5) + 1


def _iter_gaussian(plane, sigma, work, message, out=None):
    """``ndimage.gaussian_filter(plane, sigma)`` into ``out`` (default: in
    place), by blocks: the pass along axis 0 by blocks of columns, then the
    pass along axis 1 by blocks of rows, as gaussian_filter runs them. Yields
    the work's records."""
    from scipy import ndimage

    out = plane if out is None else out
    h, w = plane.shape
    taps = _taps(sigma)
    per_value = _NS_GAUSS * taps
    cols = max(1, int(_YIELD_WORK // (per_value * h)))
    for start in range(0, w, cols):
        stop = min(start + cols, w)
        ndimage.gaussian_filter1d(plane[:, start:stop], sigma, axis=0,
                                  output=out[:, start:stop])
        yield from work.progress(per_value * h * (stop - start), message)
    rows = max(1, int(_YIELD_WORK // (per_value * w)))
    for start in range(0, h, rows):
        block = out[start : start + rows]
        ndimage.gaussian_filter1d(block, sigma, axis=1, output=block)
        yield from work.progress(per_value * block.size, message)


def _iter_pyramid_reduce(level, work, message):
    """``skimage.transform.pyramid_reduce(level, downscale=2, channel_axis=-1)``
    channel by channel, its smoothing by blocks: Progress, then the level."""
    from scipy import ndimage

    h, w, d = level.shape
    out_shape = (math.ceil(h / 2.0), math.ceil(w / 2.0))
    sigma = 2 * 2 / 6.0
    zoom = [1 / f for f in np.divide((h, w), out_shape)]
    out = np.empty(out_shape + (d,))
    plane = np.empty((h, w))
    lo, hi = np.inf, -np.inf
    for c in range(d):
        plane[...] = level[..., c]
        yield from _iter_gaussian(plane, sigma, work, message)
        lo, hi = min(lo, plane.min()), max(hi, plane.max())
        # resize(order=1, mode='reflect', anti_aliasing=False) is this zoom
        out[..., c] = ndimage.zoom(plane, zoom, order=1, mode="mirror", grid_mode=True)
        yield from work.progress(_NS_VALUE * 4 * out_shape[0] * out_shape[1], message)
    np.clip(out, lo, hi, out=out)  # resize's clip to the input's range
    return out


def _iter_whiten_channels(level, work, message):
    """Spectral Karhunen-Loeve transform with unit-variance factors, by blocks.

    The 3DCAR parameters ((14.1)-(14.4), docs/model.md) transform as
    ``A -> B A B^{-1}`` under a channel mixing ``B`` (section 14.3,
    docs/model.md), so this changes no model, only how well the
    cross-spectral terms are conditioned (RGB channels are nearly collinear)
    and puts every parameter on a comparable scale. The same arithmetic as
    the one-call form (NumPy's mean, covariance and products).
    """
    h, w, d = level.shape
    flat = level.reshape(-1, d)
    n = flat.shape[0]
    mean = flat.mean(axis=0)
    out = np.empty_like(level)
    out_flat = out.reshape(-1, d)
    blocks = row_blocks(n, _LONG_ROWS, merge_tail=True)
    step = _NS_VALUE * d
    if d == 1:
        std = flat.std()
        scale = std if std > 0 else 1.0
        for start, stop in blocks:
            np.subtract(flat[start:stop], mean, out=out_flat[start:stop])
            out_flat[start:stop] /= scale
            yield from work.progress(step * (stop - start), message)
        return out
    # np.cov((flat - mean).T): its mean of the centred data, its centred copy
    for start, stop in blocks:
        np.subtract(flat[start:stop], mean, out=out_flat[start:stop])
        yield from work.progress(step * (stop - start), message)
    avg = out_flat.mean(axis=0)
    for start, stop in blocks:
        out_flat[start:stop] -= avg
        yield from work.progress(step * (stop - start), message)
    cov = np.dot(out_flat.T, out_flat) * (1.0 / (n - 1))
    ev, vec = np.linalg.eigh(cov)
    ev = np.maximum(ev, 1e-6 * max(ev.max(), 1e-300))
    transform = vec / np.sqrt(ev)
    for start, stop in blocks:
        out_flat[start:stop] = (flat[start:stop] - mean) @ transform
        yield from work.progress(step * (stop - start), message)
    return out


def _iter_upsample(coarse, out, work, message):
    """Bilinear interpolation of (hm, wm, c) features to ``out`` (h, w, c), as
    ``skimage.transform.resize(order=1, mode='edge', anti_aliasing=False)``
    (pixel centres aligned, edges repeated), by blocks of rows."""
    hm, wm, c = coarse.shape
    h, w = out.shape[:2]

    def axis(n_out, n_in):
        pos = np.clip((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0, n_in - 1)
        lo = np.minimum(pos.astype(np.int64), n_in - 1)
        hi = np.minimum(lo + 1, n_in - 1)
        return lo, hi, (pos - lo)

    y0, y1, fy = axis(h, hm)
    x0, x1, fx = axis(w, wm)
    fx = fx[None, :, None]
    for start, stop in row_ranges(h, w * c * 4, _SMALL_BLOCK):
        wy = fy[start:stop, None, None]
        rows = coarse[y0[start:stop]] * (1 - wy) + coarse[y1[start:stop]] * wy
        out[start:stop] = rows[:, x0] * (1 - fx) + rows[:, x1] * fx
        yield from work.progress(_NS_VALUE * 4 * (stop - start) * w * c, message)
