"""Tiles of an image larger than memory: a grid aligned to a model's blocks,
each tile read with a halo wide enough for the model's window, the halo's
results dropped (issue 16, point 2).

Two ways to run a per-tile function over a large image, with the same
tiles and the same results:

* :func:`iter_map_tiles`: tile after tile from any sliceable array (a dask
  array, a zarr array, a memory map, a NumPy array), each core written into
  ``out`` (a zarr array or NumPy array) as it finishes, a Progress record
  after each: memory is one tile and its halo, whatever the image.
* :func:`lazy_map_tiles`: a dask array built with ``dask.array.map_overlap``
  (the tiles are its chunks), for callers that compose dask graphs.

The grid's tile starts are multiples of ``align`` (a model's block side), so
a tile's blocks are the image's blocks; the halo is a multiple of it too.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._progress import Progress, Span

__all__ = ["CLUSTER_HINT", "Tile", "aligned_chunks", "is_lazy", "iter_map_tiles", "read_array",
           "lazy_map_tiles", "require", "tile_grid"]

#: What to install for dask, zarr and the cluster options.
CLUSTER_HINT = "pip install 'car-napari[cluster]'"


def require(module, what):
    """Import ``module`` (``'dask.array'``, ``'zarr'``, ...) or raise an
    ImportError that says what needs it and what to install.

    Examples
    --------
    >>> require("numpy", "this example").__name__
    'numpy'
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"{what} needs {module.split('.')[0]}: {CLUSTER_HINT}.") from None


def is_lazy(image):
    """Whether ``image`` is a dask or zarr array (read by tiles, never whole).

    Examples
    --------
    >>> import numpy as np
    >>> is_lazy(np.zeros(3))
    False
    """
    module = type(image).__module__ or ""
    return module.startswith(("dask.", "zarr."))


class Tile(NamedTuple):
    """One tile: its core ``[r0, r1) x [c0, c1)`` (written to the output)
    and the part read ``[a0, a1) x [b0, b1)`` (the core and its halo, inside
    the image)."""

    r0: int
    r1: int
    c0: int
    c1: int
    a0: int
    a1: int
    b0: int
    b1: int

    @property
    def read(self):
        """The slices of the part read."""
        return slice(self.a0, self.a1), slice(self.b0, self.b1)

    @property
    def core(self):
        """The slices of the core in the image."""
        return slice(self.r0, self.r1), slice(self.c0, self.c1)

    @property
    def inner(self):
        """The slices of the core in the part read."""
        return (slice(self.r0 - self.a0, self.r1 - self.a0),
                slice(self.c0 - self.b0, self.c1 - self.b0))


def aligned_chunks(n, tile, halo):
    """Chunk sizes along an axis of ``n``: ``tile`` each, a last one shorter
    than ``halo`` merged into the one before (dask's map_overlap wants every
    chunk at least as long as the halo).

    Examples
    --------
    >>> aligned_chunks(100, 32, 16)
    (32, 32, 36)
    >>> aligned_chunks(140, 32, 16)
    (32, 32, 32, 44)
    >>> aligned_chunks(20, 32, 16)
    (20,)
    """
    sizes = [tile] * (n // tile)
    if n % tile:
        sizes.append(n % tile)
    if len(sizes) > 1 and sizes[-1] < halo:
        last = sizes.pop()
        sizes[-1] += last
    return tuple(sizes) or (n,)


def tile_grid(shape, tile, halo, align=1):
    """The tiles covering an (H, W) image.

    Parameters
    ----------
    shape : (int, int)
        The image's height and width.
    tile : int
        Side of a tile's core (rounded up to a multiple of ``align``).
    halo : int
        Pixels read on each side of the core (rounded up to a multiple of
        ``align``), where the image has them.
    align : int, optional
        Tile starts are multiples of this.

    Returns
    -------
    list of Tile
        Row by row, the cores covering the image once.

    Examples
    --------
    >>> [t.core for t in tile_grid((40, 20), 32, 8)][1]
    (slice(32, 40, None), slice(0, 20, None))
    >>> tile_grid((40, 20), 32, 8)[1].read
    (slice(24, 40, None), slice(0, 20, None))
    """
    align = max(1, int(align))
    tile = -(-max(int(tile), 1) // align) * align
    halo = -(-max(int(halo), 0) // align) * align
    H, W = (int(s) for s in shape)
    rows = np.cumsum((0,) + aligned_chunks(H, tile, halo))
    cols = np.cumsum((0,) + aligned_chunks(W, tile, halo))
    return [Tile(int(r0), int(r1), int(c0), int(c1), max(0, int(r0) - halo),
                 min(H, int(r1) + halo), max(0, int(c0) - halo), min(W, int(c1) + halo))
            for r0, r1 in zip(rows[:-1], rows[1:], strict=True)
            for c0, c1 in zip(cols[:-1], cols[1:], strict=True)]


def read_array(part):
    """``np.asarray(part)`` of a slice of any array, a dask array computed
    without global callbacks.

    napari enters its opportunistic dask cache (a global dask callback)
    while it slices a layer, and a compute that uses the global callbacks
    swaps them out and back while it runs: a read in a worker thread at
    the same time races with napari's (a ``KeyError`` of a chunk in the
    viewer, seen in a real-viewer test). A read with ``callbacks=()``
    neither uses nor touches them.

    Examples
    --------
    >>> read_array(np.arange(3)[1:])
    array([1, 2])
    """
    compute = getattr(part, "compute", None)
    if compute is not None and type(part).__module__.split(".")[0] == "dask":
        return np.asarray(compute(callbacks=()))
    return np.asarray(part)


def read_tile(source, tile):
    """The part of ``source`` (any sliceable array, rows and columns first)
    that ``tile`` reads, as a NumPy array."""
    return read_array(source[tile.read])


def iter_map_tiles(source, function, out, tiles, *, stage="tiles", span=(0.0, 1.0)):
    """Run ``function`` tile by tile, writing each tile's core into ``out``.

    Parameters
    ----------
    source : array
        Sliceable (a dask, zarr or NumPy array), rows and columns first.
    function : callable
        ``function(part, tile)``: the result over ``part`` (the tile's read
        region of ``source`` as NumPy), rows and columns first, the shape of
        ``part``'s rows and columns.
    out : array
        Written at each tile's core (a zarr array, a NumPy array ...).
    tiles : list of Tile
        From :func:`tile_grid`.
    stage : str, optional
        The records' stage.
    span : (float, float), optional
        The part of the job's progress these tiles cover.

    Returns
    -------
    out
        ``out``, filled.

    Yields
    ------
    Progress
        After each tile: ``'tile k/n'``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> image = np.arange(24.0).reshape(4, 6)
    >>> out = drain(iter_map_tiles(image, lambda part, tile: 2 * part, np.empty((4, 6)),
    ...                            tile_grid((4, 6), 2, 1)))
    >>> bool(np.array_equal(out, 2 * image))
    True
    """
    span = Span(*span)
    for k, tile in enumerate(tiles, start=1):
        result = function(read_tile(source, tile), tile)
        out[tile.core] = result[tile.inner]
        yield Progress(stage, span.at(k, len(tiles)), f"tile {k}/{len(tiles)}")
    return out


def lazy_map_tiles(image, function, *, tile, halo, align=1, dtype=float):
    """``function`` over a dask array by aligned tiles with a halo, lazily.

    Parameters
    ----------
    image : dask.array.Array
        Rows and columns first; any further axis (channels) in one chunk.
    function : callable
        ``function(part)``: the result over a tile and its halo (NumPy), the
        same rows and columns.
    tile, halo, align : int
        As in :func:`tile_grid`.
    dtype : dtype, optional
        The result's dtype.

    Returns
    -------
    dask.array.Array
        The result; its chunks are the tiles' cores.
    """
    da = require("dask.array", "a dask image")
    align = max(1, int(align))
    tile = -(-max(int(tile), 1) // align) * align
    halo = -(-max(int(halo), 0) // align) * align
    chunks = (aligned_chunks(image.shape[0], tile, halo),
              aligned_chunks(image.shape[1], tile, halo), *[(s,) for s in image.shape[2:]])
    image = image.rechunk(chunks)
    depth = {0: halo, 1: halo, **{a: 0 for a in range(2, image.ndim)}}
    return da.map_overlap(function, image, depth=depth, boundary="none", trim=True,
                          dtype=dtype, meta=np.empty((0,) * image.ndim, dtype))
