"""Filling damage in clips and frames larger than memory (issue 16, point 2;
docs/inpainting.md).

What :func:`~car_napari.inpainting.inpaint` computes is local in time and
global in space:

* In a clip, frame ``t`` is filled from itself, its mask and the previous
  frame *as restored* (the 3.5D model, moved by the optical flow). A clip
  read one frame at a time, carrying the last restored frame, is therefore
  the in-memory result exactly: :func:`~car_napari.inpainting.iter_inpaint_frames`
  (memory: a block of frames, whatever the clip's length).
* Within a frame the fill is defined by tiles: a frame larger than
  :data:`DEFAULT_TILE` a side is filled tile by tile, each tile whose core
  holds damage as a frame of its own (its core and :data:`DEFAULT_HALO`
  pixels around it; the local fits, the known range and variance, the edge
  test and the sparse solves all within it), its core kept. The in-memory
  fill and :func:`iter_inpaint_tiles` (a dask or zarr frame) run the same
  tiles through the same code, so they are equal. Against one solve over
  the whole frame (the definition before issue 16) the tiles differ only
  near a tile's edge, where a hole crossing it is solved from each side's
  halo (``benchmarks/bench_large.py --inpaint``: 54.6 dB PSNR between the
  two at a 128-pixel halo).
"""

from __future__ import annotations

import warnings

import numpy as np

from .._docstrings import documents_job, shared_parameters
from .._progress import Progress, drain, stage
from .._tiles import read_tile, tile_grid
from ._filling import DEFAULT_INTERLEAVE, iter_inpaint_in_memory
from ._frames import iter_inpaint_frames

__all__ = ["DEFAULT_HALO", "DEFAULT_TILE", "inpaint_large", "iter_inpaint_large",
           "iter_inpaint_tiles"]

#: Side of a tile's core, and the halo each tile reads around it (pixels):
#: a frame larger than DEFAULT_TILE a side is filled by these tiles, in
#: memory or not.
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


def iter_inpaint_tiles(image, mask, *, out=None, tile=None, tile_halo=None,
                       channel_axis=-1, **options):
    """Fill one frame by tiles with a halo: what :func:`iter_inpaint_large`
    runs for a frame, and ``inpaint`` for a frame in memory larger than
    :data:`DEFAULT_TILE` a side (the same tiles: see the module's notes).
    The parameters, records and result are :func:`iter_inpaint_large`'s;
    ``**options`` are the fill's (:func:`~car_napari.inpainting.inpaint`'s).

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> frame = np.random.default_rng(0).random((40, 40))
    >>> mask = np.zeros((40, 40), bool)
    >>> mask[5:9, 5:9] = True
    >>> restored = drain(iter_inpaint_tiles(frame, mask, tile=20, tile_halo=10))
    >>> bool(np.array_equal(restored[~mask], frame[~mask]))
    True
    """
    shape = tuple(np.shape(image))
    if _is_clip(shape, channel_axis):
        raise ValueError(f"image {shape} reads as a clip: use iter_inpaint_frames.")
    if tuple(np.shape(mask)) != shape[:2]:
        raise ValueError(f"mask has shape {tuple(np.shape(mask))}; the frame needs "
                         f"{shape[:2]} (True where pixels are missing).")
    tile = DEFAULT_TILE if tile is None else tile
    tile_halo = DEFAULT_HALO if tile_halo is None else tile_halo
    for name, value in (("tile", tile), ("tile_halo", tile_halo)):
        if isinstance(value, (bool, np.bool_, str)) or int(value) != value or int(value) < 0 \
                or (name == "tile" and int(value) < 1):
            raise ValueError(f"{name} must be a {'positive' if name == 'tile' else '>= 0'} "
                             f"number of pixels; got {value!r}.")
    if out is None:
        out = np.empty(shape, np.asarray(image[:1, :1]).dtype)
    tiles = tile_grid(shape[:2], int(tile), int(tile_halo))
    for k, t in enumerate(tiles, start=1):
        part = read_tile(image, t)
        part_mask = read_tile(mask, t) != 0
        done = f"tile {k}/{len(tiles)}"
        if part_mask[t.inner].any():
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", "the mask is empty", UserWarning)
                job = iter_inpaint_in_memory(part, part_mask, channel_axis=channel_axis,
                                             **options)
                span = (k - 1) / len(tiles), k / len(tiles)
                # a tile's frame is not the frame: no previews
                part = yield from stage(job, *span, name="tiles", prefix=f"{done}: ",
                                        previews=False)
        out[t.core] = part[t.inner]
        yield Progress("tiles", k / len(tiles), done)
    return out


# the Parameters of both forms of the job, written once; the fill's own options
# are inpaint's (their text stays there)
_PARAMETERS = """
    image : array
        A frame ``(H, W)`` / ``(H, W, C)`` or a clip ``(T, H, W)`` /
        ``(T, H, W, C)`` (read by :func:`~car_napari.inpainting.inpaint`'s
        rule), any sliceable array (dask, zarr, a memory map, NumPy): a clip
        is read a block of frames at a time, a frame a tile at a time.
    mask : array
        True (nonzero) where pixels are missing: ``(H, W)``, or for a clip
        ``(T, H, W)`` one per frame (read by blocks too).
    out : array, optional
        Where the result goes (a zarr array, a memory map...), like
        ``image``. Default: a NumPy array.
    tile : int, optional
        Side of a frame's tile core (default :data:`DEFAULT_TILE`).
    tile_halo : int, optional
        Pixels read around a tile's core (the models learn there; default
        :data:`DEFAULT_HALO`).
    temporal : bool, optional
        A clip's temporal context, as :func:`~car_napari.inpainting.inpaint`
        (a frame has none).
    neighbourhood, forgetting, interleave, halo, method, motion : optional
        As :func:`~car_napari.inpainting.inpaint`.
    channel_axis : -1 or None, optional
        A 3-D frame is (H, W, C) with -1 (the default), a grey clip with None.
"""


def iter_inpaint_large(image, mask, *, out=None, tile=None, tile_halo=None, temporal=True,
                       neighbourhood=None, forgetting=0.9995, interleave=DEFAULT_INTERLEAVE,
                       halo="auto", channel_axis=-1, method="conditional", motion=True):
    """Fill damaged pixels of a frame or clip larger than memory, as a job.

    {plain form}

    Yields
    ------
    Progress
        As :func:`~car_napari.inpainting.iter_inpaint_frames` for a clip;
        stage ``'tiles'`` for a frame: ``'tile k/n'`` after each tile, and
        the fill's own records within a damaged tile
        (``'tile k/n: frame 1/1, ...'``, no previews).

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> clip = np.random.default_rng(0).random((2, 16, 16))
    >>> drain(iter_inpaint_large(clip, clip[0] > 0.9)).shape
    (2, 16, 16)
    """
    options = dict(neighbourhood=neighbourhood, forgetting=forgetting, interleave=interleave,
                   halo=halo, method=method, motion=motion)
    shape = tuple(np.shape(image))
    if _is_clip(shape, channel_axis):
        if out is None:
            out = np.empty(shape, np.asarray(image[:1]).dtype)
        yield from iter_inpaint_frames(image, mask, out, temporal=temporal,
                                       channel_axis=None if len(shape) == 3 else -1, **options)
        return out
    return (yield from iter_inpaint_tiles(image, mask, out=out, tile=tile, tile_halo=tile_halo,
                                          channel_axis=channel_axis, **options))


@documents_job(iter_inpaint_large)
@shared_parameters(_PARAMETERS)
def inpaint_large(image, mask, *, out=None, tile=None, tile_halo=None, temporal=True,
                  neighbourhood=None, forgetting=0.9995, interleave=DEFAULT_INTERLEAVE,
                  halo="auto", channel_axis=-1, method="conditional", motion=True):
    """Fill damaged pixels of a frame or clip larger than memory.

    What :func:`~car_napari.inpainting.inpaint` of a dask or zarr array
    runs, into any array: a clip a block of frames at a time
    (:func:`~car_napari.inpainting.inpaint_frames`, exactly the in-memory
    result), a frame by tiles with a halo: each tile whose core holds damage
    is filled as a frame of its own (its core and ``tile_halo`` pixels
    around it) and its core kept, other tiles copied. With the default
    tiles this is what ``inpaint`` computes for a frame larger than
    :data:`DEFAULT_TILE` a side in memory (see the module's notes).

    {parameters}

    Returns
    -------
    out : array
        The restored frame or clip; pixels outside the mask equal the
        input's.

    Raises
    ------
    ValueError
        If the image is neither a frame nor a clip, the mask has another
        shape, ``tile`` or ``tile_halo`` is not a number of pixels, or an
        option of the fill is out of range.
    TypeError
        If the image or the mask is not numeric.

    Examples
    --------
    >>> clip = np.random.default_rng(0).random((2, 16, 16))
    >>> inpaint_large(clip, clip[0] > 0.9).shape
    (2, 16, 16)
    """
    return drain(iter_inpaint_large(
        image, mask, out=out, tile=tile, tile_halo=tile_halo, temporal=temporal,
        neighbourhood=neighbourhood, forgetting=forgetting, interleave=interleave, halo=halo,
        channel_axis=channel_axis, method=method, motion=motion))
