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

A cluster of the input's colours is seldom round: a ball that holds 95 % of
an elongated one also holds colours far from every input colour (on the
TUNING textures of ``benchmarks/bench_synthesis.py`` 0.19 % of the pixels on
average, 3 % on VS69). So each radius is also cut to the largest one whose
ball the input's colours cover: every probe of the ball (a ring of
directions at steps of a grid cell) that lies in the colour's Voronoi cell
and within the value range must lie in a grid cell beside one holding an
input colour, that is within :data:`_TOLERANCE` of the largest channel span
of an input colour.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["fit_palette", "snap"]

PALETTE_COLOURS = 32  # colours kept (chosen on the TUNING textures)
_SAMPLE = 20000  # pixels the k-means sees
_ITERATIONS = 15  # Lloyd iterations
_COVER = 0.95  # share of a colour's nearest sampled pixels within its radius
# how far (a share of the largest channel span) a colour within a radius may
# lie from every input colour. Chosen on the 17 TUNING textures (seeds 0 and
# 1) among 0.04 / 0.06 / 0.08 / 0.1 / 0.12 / 0.15 / 0.2: the largest with no
# spurious pixel (CIELAB > 10 from every input pixel) on any of the 34
# syntheses (0.12: 1 pixel; 0.15: 1.1 % on VS69); colour-histogram L1 (seed
# 0) 0.0652 / 0.0546 / 0.0500 / 0.0480 for the first four (0.0443 without)
_TOLERANCE = 0.08
_DIRECTIONS = 256  # probe directions of a colour's ball
_MAX_CELLS = 1 << 22  # cells of the grid of input colours (4 MB of flags)
_GRID_BLOCK = 1 << 16  # pixels placed on the grid at a time


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
        pixels nearest to it, cut to the ball the input's colours cover
        (see the module).
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
    return centres, _covered_radius(pixels, centres, radius)


def _directions(d, n=_DIRECTIONS):
    """(n, d) unit vectors spread over the sphere: a Fibonacci lattice for
    d = 3, evenly spaced angles for d = 2, fixed Gaussian draws otherwise."""
    if d == 2:
        angle = 2 * np.pi * np.arange(n) / n
        return np.stack([np.cos(angle), np.sin(angle)], axis=1)
    if d == 3:
        i = np.arange(n) + 0.5
        polar = np.arccos(1 - 2 * i / n)
        turn = np.pi * (1 + 5 ** 0.5) * i
        return np.stack([np.cos(turn) * np.sin(polar), np.sin(turn) * np.sin(polar),
                         np.cos(polar)], axis=1)
    draws = np.random.default_rng(0).normal(size=(n, d))
    return draws / np.linalg.norm(draws, axis=1, keepdims=True)


def _colour_grid(pixels, tolerance):
    """The input's colours on a grid, dilated by one cell: a point whose cell
    is flagged lies within ``tolerance`` of an input colour.

    Returns ``(flags, low, cell)``: the (n_1, ..., n_d) flags, the grid's
    corner and its cell side. Two neighbouring cells span at most
    ``2 cell sqrt(d)``, which the side ``tolerance / (2 sqrt(d))`` keeps
    within the tolerance (a grid of more than :data:`_MAX_CELLS` cells is
    made coarser, and then only approximately so).
    """
    d = pixels.shape[1]
    low, high = pixels.min(axis=0), pixels.max(axis=0)
    span = np.maximum(high - low, 0.0)
    cell = tolerance / (2 * np.sqrt(d))
    cell = max(cell, float(np.prod(span) / _MAX_CELLS) ** (1 / d))
    sides = np.maximum(np.ceil(span / cell).astype(np.int64), 1)
    flags = np.zeros(tuple(sides.tolist()), bool)
    for start in range(0, len(pixels), _GRID_BLOCK):  # (no image-sized temporaries)
        part = pixels[start:start + _GRID_BLOCK]
        index = np.minimum(((part - low) / cell).astype(np.int64), sides - 1)
        flags[tuple(index.T)] = True
    for axis in range(d):  # the 3^d neighbourhood, an axis at a time
        grown = flags.copy()
        lead = [slice(None)] * d
        lag = [slice(None)] * d
        lead[axis], lag[axis] = slice(1, None), slice(None, -1)
        grown[tuple(lead)] |= flags[tuple(lag)]
        grown[tuple(lag)] |= flags[tuple(lead)]
        flags = grown
    return flags, low, cell


def _covered_radius(pixels, centres, radius, tolerance=_TOLERANCE):
    """Each of ``radius`` cut to the largest ball around its centre that the
    (n, d) input ``pixels`` cover (see the module): the probes at ``cell``,
    ``2 cell``, ... up to the radius along :func:`_directions`, kept where
    they fall in the centre's Voronoi cell and within the pixels' range,
    must fall in flagged cells of :func:`_colour_grid`; the radius becomes
    that of the last ring of probes that all do (0 if the first does not).
    ``tolerance`` is a share of the largest channel span."""
    pixels = np.asarray(pixels, np.float64)
    d = pixels.shape[1]
    low, high = pixels.min(axis=0), pixels.max(axis=0)
    width = float((high - low).max())
    if width <= 0:
        return radius
    flags, low, cell = _colour_grid(pixels, tolerance * width)
    sides = np.array(flags.shape)
    directions = _directions(d)
    squares = (centres * centres).sum(1)
    out = np.array(radius, np.float64)
    for c in range(len(centres)):
        steps = int(np.ceil(radius[c] / cell))
        if steps == 0:
            continue
        rings = np.minimum(np.arange(1, steps + 1) * cell, radius[c])
        probes = (centres[c] + rings[:, None, None] * directions[None]).reshape(-1, d)
        # the probes whose nearest centre is this one (the squared distances
        # less the probe's own square, which every centre shares)
        own = np.argmin(squares[None] - 2 * probes @ centres.T, axis=1) == c
        within = np.all((probes >= low) & (probes <= high), axis=1)
        index = np.minimum(((np.clip(probes, low, high) - low) / cell).astype(np.int64),
                           sides - 1)
        bare = (own & within & ~flags[tuple(index.T)]).reshape(steps, -1).any(axis=1)
        if bare.any():
            first = int(np.argmax(bare))
            out[c] = rings[first - 1] if first > 0 else 0.0
    return out


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
