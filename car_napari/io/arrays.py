"""Images larger than memory: zarr (OME-Zarr too) and TIFF, opened as arrays
read a tile at a time, and outputs created to be written a tile at a time
(issue 16, point 2).

zarr needs the ``cluster`` extra (``pip install 'car-napari[cluster]'``);
TIFF needs only tifffile (a base dependency).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._tiles import require

__all__ = ["LARGE_SUFFIXES", "create_array", "is_large_path", "open_array"]

#: Suffixes of the files opened as arrays (not read whole).
LARGE_SUFFIXES = (".zarr", ".tif", ".tiff")


def is_large_path(path):
    """Whether ``path`` names a zarr store or a TIFF file (by its suffix).

    Examples
    --------
    >>> is_large_path("scan.ome.zarr"), is_large_path("a.png")
    (True, False)
    """
    return str(path).lower().rstrip("/").endswith(LARGE_SUFFIXES)


def _is_zarr(path):
    return str(path).lower().rstrip("/").endswith(".zarr")


def open_array(path):
    """Open a large image without reading it: a zarr array or a TIFF's pixels.

    Parameters
    ----------
    path : str or path-like
        A zarr array (``.zarr``), an OME-Zarr image (its full-resolution
        level; channels moved last), or a TIFF file (memory-mapped when
        uncompressed, else read through tifffile's zarr store).

    Returns
    -------
    array
        Sliceable, with ``shape`` and ``dtype``: ``(H, W)`` grey or
        ``(H, W, C)`` colour (a zarr array, a memory map, or for OME-Zarr
        with channels first a dask array).

    Raises
    ------
    ValueError
        If the path does not exist or holds no image.
    ImportError
        For zarr without the ``cluster`` extra.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "big.tif")
    >>> out = create_array(path, (64, 48), np.uint8)
    >>> out[:32] = 7
    >>> del out
    >>> image = open_array(path)
    >>> image.shape, int(image[0, 0]), int(image[40, 0])
    ((64, 48), 7, 0)
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no such file or store: {path}")
    if _is_zarr(path):
        zarr = require("zarr", f"reading {path.name}")
        try:
            node = zarr.open(str(path), mode="r")
        except Exception as exc:
            raise ValueError(f"cannot open {path} as zarr: {exc}") from None
        if hasattr(node, "shape"):
            return node
        return _ome_image(node, path)
    import tifffile

    try:
        return tifffile.memmap(str(path), mode="r")
    except (ValueError, OSError, tifffile.TiffFileError):
        pass
    try:
        with tifffile.TiffFile(str(path)) as tif:
            axes = tif.series[0].axes
        zarr = require("zarr", f"reading the compressed TIFF {path.name} by tiles")
        array = zarr.open(tifffile.imread(str(path), aszarr=True), mode="r")
    except tifffile.TiffFileError as exc:
        raise ValueError(f"cannot read {path} as TIFF: {exc}") from None
    if "S" in axes and axes.index("S") != len(axes) - 1:
        da = require("dask.array", f"reading {path.name}")
        return da.moveaxis(da.from_zarr(array), axes.index("S"), -1)
    return array


def _ome_image(group, path):
    """The full-resolution level of an OME-Zarr group, channels last."""
    attrs = dict(group.attrs)
    ome = attrs.get("ome", attrs)  # NGFF 0.5 nests the metadata under "ome"
    scales = ome.get("multiscales")
    if not scales:
        raise ValueError(f"{path} is a zarr group without an image (no 'multiscales' "
                         "metadata); pass the path of its array.")
    level = scales[0]["datasets"][0]["path"]
    array = group[level]
    axes = [a["name"] if isinstance(a, dict) else a for a in scales[0].get("axes", [])]
    if not axes:
        return array
    # keep y, x and the channels; other axes (t, z) must have one entry
    da = require("dask.array", f"reading {path.name}")
    lazy = da.from_zarr(array)
    for k in reversed(range(len(axes))):
        if axes[k] not in ("y", "x", "c"):
            if lazy.shape[k] != 1:
                raise ValueError(f"{path} has {lazy.shape[k]} entries on axis {axes[k]!r}; "
                                 "pass one image (a single t and z).")
            lazy = lazy[(slice(None),) * k + (0,)]
            axes.pop(k)
    if "c" in axes:
        lazy = da.moveaxis(lazy, axes.index("c"), -1)
        if lazy.shape[-1] == 1:
            lazy = lazy[..., 0]
    return lazy


def create_array(path, shape, dtype, *, chunks=1024):
    """Create an output image to be written a tile at a time.

    Parameters
    ----------
    path : str or path-like
        ``.zarr`` (a zarr array), ``.ome.zarr`` (an OME-Zarr image of one
        level, see Notes) or ``.tif``/``.tiff`` (an uncompressed BigTIFF,
        memory-mapped). Replaced if it exists.
    shape : tuple of int
        ``(H, W)`` or ``(H, W, C)``.
    dtype : dtype
        The pixels' type.
    chunks : int, optional
        Side of the zarr chunks (rows and columns).

    Returns
    -------
    array
        Writable by slices (``out[r0:r1, c0:c1] = values``).

    Notes
    -----
    An ``.ome.zarr`` output follows NGFF 0.4 (zarr format 2): axes ``y, x``
    or ``c, y, x`` (channels first on disk, as the specification orders
    them); the returned array takes channel-last values and moves them, and
    :func:`open_array` moves them back.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> out = create_array(os.path.join(tempfile.mkdtemp(), "a.tif"), (8, 8), np.float32)
    >>> out.shape, out.dtype
    ((8, 8), dtype('float32'))
    """
    path = Path(path)
    shape = tuple(int(s) for s in shape)
    dtype = np.dtype(dtype)
    if _is_zarr(path):
        zarr = require("zarr", f"writing {path.name}")
        import shutil

        if path.exists():
            shutil.rmtree(path)
        chunk_shape = (min(chunks, shape[0]), min(chunks, shape[1]), *shape[2:])
        if str(path).lower().rstrip("/").endswith(".ome.zarr"):
            try:  # zarr 3 writes NGFF 0.4's format 2 when asked; zarr 2 always does
                group = zarr.open_group(str(path), mode="w", zarr_format=2)
            except TypeError:
                group = zarr.open_group(str(path), mode="w")
            create = getattr(group, "create_array", None) or group.create_dataset
            axes = [{"name": "y", "type": "space"}, {"name": "x", "type": "space"}]
            if len(shape) == 3:
                axes.insert(0, {"name": "c", "type": "channel"})
                stored = create("0", shape=(shape[2], *shape[:2]),
                                chunks=(shape[2], *chunk_shape[:2]), dtype=dtype)
                array = _ChannelsFirst(stored)
            else:
                array = create("0", shape=shape, chunks=chunk_shape, dtype=dtype)
            group.attrs["multiscales"] = [{
                "version": "0.4", "name": path.stem, "axes": axes,
                "datasets": [{"path": "0", "coordinateTransformations": [
                    {"type": "scale", "scale": [1.0] * len(shape)}]}]}]
            return array
        return zarr.open_array(str(path), mode="w", shape=shape, chunks=chunk_shape,
                               dtype=dtype)
    if str(path).lower().endswith((".tif", ".tiff")):
        import tifffile

        if path.exists():
            path.unlink()
        return tifffile.memmap(str(path), shape=shape, dtype=dtype, bigtiff=True,
                               photometric="rgb" if len(shape) == 3 and shape[2] == 3
                               else "minisblack")
    raise ValueError(f"cannot write a large image to {path.name}: use .zarr, .ome.zarr or "
                     ".tif.")


class _ChannelsFirst:
    """A (C, H, W) zarr array written with (H, W, C) values."""

    def __init__(self, stored):
        self.stored = stored
        self.shape = (*stored.shape[1:], stored.shape[0])
        self.dtype = stored.dtype

    def __setitem__(self, key, values):
        key = key if isinstance(key, tuple) else (key,)
        self.stored[(slice(None), *key[:2])] = np.moveaxis(np.asarray(values), -1, 0)
