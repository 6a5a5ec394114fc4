"""Film scratch and blotch restoration: detection and filling from the
directional CAR models (section 14.7, docs/inpainting.md).

A frame or a clip is read by one rule, with the default ``channel_axis=-1``:
``(H, W)`` is a grey frame; a 3-D array is a colour frame ``(H, W, C)`` when
its channel axis has at most 4 entries and a grey clip ``(T, H, W)``
otherwise; a 4-D array is a colour clip ``(T, H, W, C)``. ``channel_axis=None``
forces grey. :func:`fit_mask` fits a mask drawn at another size to a frame;
:func:`estimate_motion` and :func:`compensate_motion` move neighbouring frames
onto each other (the detector's blotch test and the fill's temporal context
use them). :func:`inpaint_frames` and
:func:`descratch_frames` (detection and fill) run a clip longer than memory a
block of frames at a time into any array or writer, exactly as in memory;
``inpaint`` of a dask or zarr array does it for you
(:func:`inpaint_large`: a clip by frames, one large frame by tiles).
"""

from ._detection import detect_scratches, iter_detect_scratches
from ._filling import MOSTLY_MASKED
from ._frames import descratch_frames, inpaint_frames, iter_descratch_frames, iter_inpaint_frames
from ._inpaint import inpaint, iter_inpaint
from ._layout import fit_mask
from ._motion import (
    compensate_motion,
    estimate_motion,
    iter_compensate_motion,
    iter_estimate_motion,
    warp_frame,
)
from ._tiled import inpaint_large, iter_inpaint_large

__all__ = [
    "MOSTLY_MASKED",
    "compensate_motion",
    "descratch_frames",
    "detect_scratches",
    "estimate_motion",
    "fit_mask",
    "inpaint",
    "inpaint_frames",
    "inpaint_large",
    "iter_compensate_motion",
    "iter_descratch_frames",
    "iter_detect_scratches",
    "iter_estimate_motion",
    "iter_inpaint",
    "iter_inpaint_frames",
    "iter_inpaint_large",
    "warp_frame",
]
