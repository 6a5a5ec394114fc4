"""The colours a synthesis may use: a palette of the input's colours.

A CAR band model is Gaussian in the colour channels jointly, and the
histogram restore maps every channel on its own; together they can make
colours that occur nowhere in the input (the dark blue-green blobs in a brown
stone, issue 34). The palette keeps ``k`` colours of the input (k-means
centres of a fixed sample of its pixels) and, per colour, the radius that
holds 95 % of the sampled pixels nearest to it. After the histogram restore
every synthesised pixel farther from its nearest palette colour than that
colour's radius is moved along the line to it onto the radius; pixels within
it are left alone. The move is per pixel, so a tileable texture stays
periodic; the new colour lies between two colours within the input's range,
so the value range holds.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["fit_palette", "snap"]

PALETTE_COLOURS = 32  # colours kept (chosen on the TUNING textures)
_SAMPLE = 20000  # pixels the k-means sees
_ITERATIONS = 15  # Lloyd iterations
_COVER = 0.95  # share of a colour's nearest sampled pixels within its radius


def _nearest(values, centres):
    """Index of and squared distance to the nearest centre, per row."""
    dist = (values * values).sum(1)[:, None] - 2 * values @ centres.T \
        + (centres * centres).sum(1)[None, :]
    index = np.argmin(dist, axis=1)
    return index, np.maximum(dist[np.arange(len(values)), index], 0.0)


def fit_palette(image, k=PALETTE_COLOURS, *, seed=0):
    """Palette of a channel-last (h, w, d) image.

    Parameters
    ----------
    image : (h, w, d) ndarray
        The texture.
    k : int, optional
        Number of colours.
    seed : int, optional
        Seed of the pixel sample and of the k-means++ start (fixed: the same
        image gives the same palette).

    Returns
    -------
    centres : (k2, d) ndarray
        The colours (``k2 <= k``: fewer when the image has fewer distinct
        colours).
    radius : (k2,) ndarray
        Per colour, the distance within which lie 95 % of the sampled
        pixels nearest to it.
    """
    rng = np.random.default_rng(seed)
    pixels = image.reshape(-1, image.shape[-1])
    n = len(pixels)
    sample = pixels[np.sort(rng.choice(n, _SAMPLE, replace=False))] if n > _SAMPLE else pixels
    centres = sample[[int(rng.integers(len(sample)))]]
    d2 = None
    for _ in range(k - 1):  # k-means++: the distances to the nearest centre so far
        _, new = _nearest(sample, centres[-1:])
        d2 = new if d2 is None else np.minimum(d2, new)
        total = d2.sum()
        if total <= 0:
            break
        centres = np.vstack([centres, sample[rng.choice(len(sample), p=d2 / total)]])
    for _ in range(_ITERATIONS):
        index, _ = _nearest(sample, centres)
        counts = np.bincount(index, minlength=len(centres))
        # the sums of each centre's pixels, in pixel order (as np.add.at adds)
        sums = np.stack([np.bincount(index, weights=sample[:, j], minlength=len(centres))
                         for j in range(sample.shape[1])], axis=1)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled, None]
    index, d2 = _nearest(sample, centres)
    radius = np.zeros(len(centres))
    for c in range(len(centres)):
        mine = d2[index == c]
        if mine.size:
            radius[c] = np.sqrt(np.quantile(mine, _COVER))
    return centres, radius


# pixels whose nearest colours are sought together (their coordinates as
# planes, their best distances so far: a few kB, in the L1 cache)
_SNAP_BLOCK = 256


@numba.njit(cache=True, nogil=True)
def _squared_distances(planes, centre, n, out):
    """Into ``out[:n]``: the squared distance of each of the first ``n``
    pixels of (d, block) ``planes`` to ``centre``, summed over the channels
    in order from 0.0 (as a pixel-by-pixel loop sums it); a loop over the
    pixels, which the compiler runs on several at once."""
    d = planes.shape[0]
    if d == 3:
        r0, r1, r2 = planes[0], planes[1], planes[2]
        c0, c1, c2 = centre[0], centre[1], centre[2]
        for p in range(n):
            t0, t1, t2 = r0[p] - c0, r1[p] - c1, r2[p] - c2
            out[p] = ((0.0 + t0 * t0) + t1 * t1) + t2 * t2
        return
    out[:n] = 0.0
    for j in range(d):
        row, cj = planes[j], centre[j]
        for p in range(n):
            t = row[p] - cj
            out[p] += t * t


@numba.njit(cache=True, nogil=True)
def _snap_kernel(values, centres, radius, out):
    """:func:`snap` of (n, d) ``values`` into (n, d) ``out`` (may be
    ``values``: a block is read before it is written). The nearest colour
    of a pixel is the first of the smallest squared distances, the colours
    taken in order, as a scan of the colours per pixel finds it; the scan
    runs a colour at a time over a block of pixels."""
    n, d = values.shape
    block = _SNAP_BLOCK
    planes = np.empty((d, block))
    distance = np.empty(block)
    best = np.empty(block)
    which = np.zeros(block, np.int64)
    for start in range(0, n, block):
        m = min(block, n - start)
        for p in range(m):
            for j in range(d):
                planes[j, p] = values[start + p, j]
            best[p] = np.inf
            which[p] = 0
        for c in range(centres.shape[0]):
            _squared_distances(planes, centres[c], m, distance)
            for p in range(m):  # (selects, not branches: vectorised)
                closer = distance[p] < best[p]
                best[p] = distance[p] if closer else best[p]
                which[p] = c if closer else which[p]
        for p in range(m):
            i, w = start + p, which[p]
            r = radius[w]
            if best[p] > r * r:
                f = r / np.sqrt(best[p])
                for j in range(d):
                    out[i, j] = centres[w, j] + (planes[j, p] - centres[w, j]) * f
            else:
                for j in range(d):
                    out[i, j] = planes[j, p]


def snap(values, centres, radius, *, out=None):
    """Move every pixel of (h, w, d) ``values`` that lies farther from its
    nearest palette colour than that colour's radius onto the radius, along
    the line to the colour (see the module); into ``out`` (may be
    ``values``)."""
    h, w, d = values.shape
    out = np.empty_like(values) if out is None else out
    flat = np.ascontiguousarray(values.reshape(h * w, d), dtype=np.float64)
    # the kernel reads a pixel before it writes it: it may write into
    # ``out`` directly, even when that is ``values`` (no copies)
    direct = out.dtype == np.float64 and out.flags.c_contiguous
    result = out.reshape(h * w, d) if direct else np.empty_like(flat)
    _snap_kernel(flat, np.ascontiguousarray(centres, np.float64),
                 np.ascontiguousarray(radius, np.float64), result)
    if not direct:
        out[...] = result.reshape(h, w, d)
    return out
