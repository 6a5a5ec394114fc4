"""The public face of the fill: :func:`inpaint` and :func:`iter_inpaint`
run a frame or clip in memory through :mod:`._filling` and a dask or zarr
one through :mod:`._tiled` (a clip a block of frames at a time, exactly; a
frame by tiles).
"""

from __future__ import annotations

from functools import partial

from .._docstrings import documents_job, shared_parameters
from .._progress import drain
from .._tiles import is_lazy
from . import _tiled
from ._filling import DEFAULT_INTERLEAVE, Tiling, iter_inpaint_in_memory
from ._tiled import iter_inpaint_large

__all__ = ["inpaint", "iter_inpaint"]


# the Parameters of both forms of the job, written once
_PARAMETERS = """
    image : ndarray
        A frame or a clip, any integer or float32/64 dtype (a dask or zarr
        array is read a frame at a time, a clip exactly as in memory, a
        frame by tiles: :func:`~car_napari.inpainting.iter_inpaint_large`;
        the result is a NumPy array; a frame larger than
        :data:`~car_napari.inpainting._tiled.DEFAULT_TILE` a side is filled
        by the same tiles in memory, so the two are equal). How
        ``channel_axis`` reads it: ``(H, W)`` is a grey frame; a 3-D array is
        a colour frame ``(H, W, C)`` when the channel axis has at most 4
        entries and a grey clip ``(T, H, W)`` otherwise; a 4-D array is a
        colour clip ``(T, H, W, C)``; ``channel_axis=None`` forces grey
        (``(H, W)`` or ``(T, H, W)``, e.g. for a grey clip of 4 frames or
        fewer).
    mask : (H, W) or (T, H, W) array_like of bool
        True (nonzero) where pixels are missing (in every channel); (H, W)
        applies to every frame of a clip.
    temporal : bool, optional
        Use the previous restored frame as context (clips only).
    motion : bool, optional
        With ``temporal``, move the previous frame onto this one by the
        estimated optical flow first (:func:`estimate_motion`), so that the
        context follows moving content.
    neighbourhood : int or None, optional
        ``method="conditional"``: the hierarchical order (1 to 8) of the
        local models (default :data:`CONDITIONAL_ORDER`, 3).
        ``method="scans"``: how many previous scan lines the models see
        (default 1; see :func:`line_offsets`): 5 pixels of each. One line
        measured best on composited real scratches (+1.6 dB over two lines
        of 3 pixels).
    forgetting : float in [0.5, 1], optional
        Forgetting factor of the adaptive models (``method="scans"``).
    interleave : float, optional
        Decay length (pixels) of each side's weight (``method="scans"``).
    halo : float <= 0, 'auto' or None, optional
        The edge test: known pixels next to the mask (4-neighbours) that the
        model finds improbable are treated as damaged (still returned
        unchanged). Soft-edged damage leaves such a halo just outside a mask
        drawn at its core. A log density ratio: ``"scans"`` tests each
        pixel's predictive density relative to its peak as a model reaches
        it; ``"conditional"`` tests the blend of the pixel towards the
        damage (half its chi-square statistic, with the blend pooled over
        the ring nearby; such a pixel is used less half its estimated blend;
        docs/inpainting.md). 'auto' (the default): :data:`CONDITIONAL_HALO`
        or ``EDGE_OUTLIER_LOGREL`` (-12); None disables the test.
    channel_axis : int or None, optional
        The colour axis (default -1, the last); None forces grey.
    method : {'conditional', 'scans'}, optional
        ``"conditional"`` (the default): the exact conditional mean of the
        missing pixels given the known ones under local 3DCAR models fitted
        around the damage (four scan directions, their densities
        multiplied), a sparse linear solve per batch of coupled holes.
        ``"scans"``: the chapter's four directional adaptive models with
        exponential interleaving, in chunks of rows.
"""


def iter_inpaint(image, mask, *, temporal=True, neighbourhood=None, forgetting=0.9995,
                 interleave=DEFAULT_INTERLEAVE, halo="auto", channel_axis=-1,
                 method="conditional", motion=True):
    """Fill damaged pixels, as a job: Progress records, then the result.

    ``method="conditional"`` works in short steps with a record
    after each (the local fits by bands of blocks, the rows by model, the
    sparse solves by batches of coupled holes, run in threads with a record
    every :data:`~car_napari.inpainting._solver.SOLVE_RECORD_SECONDS`).
    With ``method="scans"`` each frame is four scans, run side by side in
    chunks of rows
    (about :data:`SCAN_CHUNK_PIXELS` pixels each, a fraction of a second) with
    a record after each chunk, so that closing the job (a Cancel) stops it
    quickly even on a large frame; the last record of frame ``t`` carries
    that frame restored, for live display. The result does not depend on
    the chunks.

    {plain form}

    Yields
    ------
    Progress
        Stage ``"frames"``, with a fraction proportional to the damaged
        frames done. After frame ``t`` of ``T``: message ``"frame t+1/T"`` and
        preview ``(t, restored_frame)``, the frame in the layout of the
        input's frames (a read-only view of the result). In between, no
        preview: ``"frame t+1/T, fitting"``, ``", assembling"``,
        ``", solving"``, ``", edge test"`` (``"conditional"``); ``"frame
        t+1/T, scan k/4"`` (``k`` scans done; ``"scans"``), and on a large
        frame between the bands of the passes before and after the scans:
        ``"frame t+1/T, preparing"`` and ``"frame t+1/T, combining"``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> frame = np.random.default_rng(0).random((16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[:, 7] = True
    >>> job = iter_inpaint(frame, mask)
    >>> records = []
    >>> restored = drain(job, records.append)
    >>> records[-1].message, records[-1].preview[0]
    ('frame 1/1', 0)
    >>> bool(np.array_equal(restored[~mask], frame[~mask]))
    True
    """
    if is_lazy(image) or is_lazy(mask):  # larger than memory: a frame or tile at a time
        job = iter_inpaint_large
    else:  # a large frame by the same tiles (what defines its fill)
        job = partial(iter_inpaint_in_memory,
                      by_tiles=Tiling(_tiled.iter_inpaint_tiles, _tiled.DEFAULT_TILE))
    return (yield from job(image, mask, temporal=temporal, neighbourhood=neighbourhood,
                           forgetting=forgetting, interleave=interleave, halo=halo,
                           channel_axis=channel_axis, method=method, motion=motion))


@documents_job(iter_inpaint)
@shared_parameters(_PARAMETERS)
def inpaint(image, mask, *, temporal=True, neighbourhood=None, forgetting=0.9995,
            interleave=DEFAULT_INTERLEAVE, halo="auto", channel_axis=-1,
            method="conditional", motion=True):
    """Fill damaged pixels with the conditional mean of CAR models.

    The default, ``method="conditional"``, is the exact Gaussian
    conditional mean of the damaged pixels given the known ones under 3DCAR
    models fitted locally around the damage (docs/inpainting.md), with an
    edge test that treats known pixels blended towards the damage (the
    fringe of soft-edged damage) as damaged. ``method="scans"`` is section
    14.7 of the chapter: four models move towards the damage
    (downwards, upwards, rightwards and leftwards), filled pixels serving as
    neighbours of later ones (14.54); the four fills are combined by
    exponential interleaving. Known pixels bordering the damage that a model
    finds improbable (the halo of soft-edged damage) are not used as its
    neighbours. In a clip the previous restored frame is part of each
    pixel's context (3.5D model) when ``temporal`` is True.

    {parameters}

    Returns
    -------
    ndarray
        Like ``image`` (same shape and dtype); pixels outside the mask are
        bit-identical to the input.

    Raises
    ------
    TypeError
        If the image or the mask is not numeric.
    ValueError
        If the image is neither a frame nor a clip, holds NaN or infinite
        values, or is too small for the neighbourhood; if the mask has the
        wrong shape or covers a whole frame; if an option is out of range.

    Warns
    -----
    UserWarning
        When the mask is empty (the input is returned unchanged), or covers
        more than half of a frame (a mask that marks the damage black, the
        other convention, does: invert it, e.g. :func:`fit_mask` with
        ``invert=True``).

    See Also
    --------
    iter_inpaint : The same as a job, with progress and each restored frame.
    detect_scratches : Propose a mask.

    Notes
    -----
    A constant image is accepted: the masked pixels are filled with the
    constant (finite; the known pixels unchanged), as there is no texture
    to continue.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.random.default_rng(0).random((16, 16))
    >>> mask = np.zeros((16, 16), bool)
    >>> mask[4:8, 4:8] = True
    >>> restored = inpaint(frame, mask)
    >>> restored.shape, bool(np.array_equal(restored[~mask], frame[~mask]))
    ((16, 16), True)
    """
    return drain(iter_inpaint(image, mask, temporal=temporal, neighbourhood=neighbourhood,
                              forgetting=forgetting, interleave=interleave, halo=halo,
                              channel_axis=channel_axis, method=method, motion=motion))
