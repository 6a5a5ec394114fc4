"""Filling damage in clips and frames larger than memory (issue 16, point 2;
docs/inpainting.md).

What :func:`~car_napari.inpainting.inpaint` computes is local in time and
global in space:

* In a clip, frame ``t`` is filled from itself, its mask and the previous
  frame *as restored* (the 3.5D model, moved by the optical flow). A clip
  read one frame at a time, carrying the last restored frame, is therefore
  the in-memory result exactly: :func:`~car_napari.inpainting.iter_inpaint_frames`
  (memory: a block of frames, whatever the clip's length).
* Within a frame it is not tile-local. Each of the four scans
  (``method='scans'``) carries one adaptive model through the whole frame in
  raster order, updated at every known pixel with forgetting 0.9995: a
  pixel's model depends on the ~1/(1 - 0.9995) = 2000 (to 1e-6: ~28000)
  known pixels scanned before it, i.e. on whole rows of the frame, and the
  frame's statistics (mean, variance, range of the known pixels) are
  global. ``method='conditional'`` solves each damaged region as one sparse
  system, so a region crossing a tile couples the tiles. A frame larger than
  memory is filled by tiles with a halo (:func:`iter_inpaint_tiles`), each
  tile as its own frame: close to the in-memory fill, not equal (the
  difference is measured in ``benchmarks/bench_large.py --inpaint``). The
  smallest change that makes the in-memory fill tile-local is to define it
  so: scans restarted on a fixed grid of tiles (each tile's models learnt
  from the tile and its halo), which is what the tiled fill does.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._progress import drain
from .._tiles import iter_map_tiles, read_tile, tile_grid
from ._filling import iter_inpaint_in_memory
from ._frames import iter_inpaint_frames

__all__ = ["DEFAULT_HALO", "DEFAULT_TILE", "inpaint_large", "iter_inpaint_large",
           "iter_inpaint_tiles"]

#: Side of a tile's core, and the halo each tile reads around it (pixels).
DEFAULT_TILE = 2048
DEFAULT_HALO = 256


def _is_clip(shape, channel_axis):
    """The module rule of :func:`inpaint` (see ``_layout``) on a shape alone."""
    if len(shape) == 2:
        return False
    if len(shape) == 3:
        return channel_axis is None or shape[-1] > 4
    if len(shape) == 4:
        return True
    raise ValueError(f"image must be a frame (H, W) or (H, W, C), or a clip (T, H, W) or "
                     f"(T, H, W, C); got shape {tuple(shape)}.")


def iter_inpaint_tiles(image, mask, *, out=None, tile=DEFAULT_TILE, halo=DEFAULT_HALO,
                       channel_axis=-1, **options):
    """Fill one frame larger than memory by tiles with a halo.

    Each tile whose core holds damage is filled as a frame of its own (its
    core and ``halo`` pixels around it, :func:`inpaint`), and its core
    kept; other tiles are copied. Not equal to the in-memory fill, which is
    not tile-local (see the module's notes): close to it when the halo is
    wide.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Any sliceable array; read a tile at a time.
    mask : (H, W) array
        True (nonzero) where pixels are missing.
    out : array, optional
        Where the result goes, tile by tile. Default: a NumPy array.
    tile : int, optional
        Side of a tile's core.
    halo : int, optional
        Pixels read around the core (the models learn there).
    channel_axis : -1 or None, optional
        A 3-D frame is (H, W, C).
    **options
        As :func:`inpaint` (``neighbourhood``, ``method``, ...).

    Returns
    -------
    out
        The restored frame; pixels outside the mask equal the input's.

    Yields
    ------
    Progress
        Stage ``'tiles'``, ``'tile k/n'``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> frame = np.random.default_rng(0).random((40, 40))
    >>> mask = np.zeros((40, 40), bool)
    >>> mask[5:9, 5:9] = True
    >>> restored = drain(iter_inpaint_tiles(frame, mask, tile=20, halo=10))
    >>> bool(np.array_equal(restored[~mask], frame[~mask]))
    True
    """
    shape = tuple(np.shape(image))
    if _is_clip(shape, channel_axis):
        raise ValueError(f"image {shape} reads as a clip: use iter_inpaint_frames.")
    if tuple(np.shape(mask)) != shape[:2]:
        raise ValueError(f"mask has shape {tuple(np.shape(mask))}; the frame needs "
                         f"{shape[:2]} (True where pixels are missing).")
    for name, value in (("tile", tile), ("halo", halo)):
        if isinstance(value, (bool, np.bool_)) or int(value) != value or int(value) < 0 \
                or (name == "tile" and int(value) < 1):
            raise ValueError(f"{name} must be a {'positive' if name == 'tile' else '>= 0'} "
                             f"number of pixels; got {value!r}.")
    if out is None:
        out = np.empty(shape, np.asarray(image[:1, :1]).dtype)
    tiles = tile_grid(shape[:2], tile, halo)

    def fill(part, t):
        part_mask = read_tile(mask, t) != 0
        if not part_mask[t.inner].any():
            return part
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "the mask is empty", UserWarning)
            return drain(iter_inpaint_in_memory(part, part_mask, channel_axis=channel_axis,
                                                **options))

    return (yield from iter_map_tiles(image, fill, out, tiles))


def iter_inpaint_large(image, mask, *, out=None, tile=DEFAULT_TILE, halo=DEFAULT_HALO,
                       temporal=True, channel_axis=-1, **options):
    """:func:`~car_napari.inpainting.iter_inpaint_frames` for a clip, :func:`iter_inpaint_tiles`
    for a frame (what ``inpaint`` of a dask or zarr array runs).

    Parameters
    ----------
    image : array
        A frame or a clip, sliceable (dask, zarr, NumPy).
    mask : array
        Its mask.
    out : array, optional
        Where the result goes.
    tile, halo : int, optional
        A frame's tiles (see :func:`iter_inpaint_tiles`).
    temporal : bool, optional
        A clip's temporal context.
    channel_axis : int or None, optional
        As :func:`inpaint`.
    **options
        As :func:`inpaint`.

    Returns
    -------
    out
        The restored frame or clip.

    Yields
    ------
    Progress
        As the two forms.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> clip = np.random.default_rng(0).random((2, 16, 16))
    >>> drain(iter_inpaint_large(clip, clip[0] > 0.9)).shape
    (2, 16, 16)
    """
    shape = tuple(np.shape(image))
    if _is_clip(shape, channel_axis):
        if out is None:
            out = np.empty(shape, np.asarray(image[:1]).dtype)
        yield from iter_inpaint_frames(image, mask, out, temporal=temporal,
                                       channel_axis=None if len(shape) == 3 else -1, **options)
        return out
    return (yield from iter_inpaint_tiles(image, mask, out=out, tile=tile, halo=halo,
                                          channel_axis=channel_axis, **options))


def inpaint_large(image, mask, **options):
    """``drain(iter_inpaint_large(image, mask, **options))``.

    Parameters
    ----------
    image : array
        A frame or a clip, sliceable.
    mask : array
        Its mask.
    **options
        As :func:`iter_inpaint_large`.

    Returns
    -------
    out
        The restored frame or clip.

    Examples
    --------
    >>> import numpy as np
    >>> clip = np.random.default_rng(0).random((2, 16, 16))
    >>> inpaint_large(clip, clip[0] > 0.9).shape
    (2, 16, 16)
    """
    return drain(iter_inpaint_large(image, mask, **options))
