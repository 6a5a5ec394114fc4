"""Film scratch and blotch restoration: detection and filling from the
directional CAR models (section 14.7, docs/inpainting.md).

A frame or a clip is read by one rule, with the default ``channel_axis=-1``:
``(H, W)`` is a grey frame; a 3-D array is a colour frame ``(H, W, C)`` when
its channel axis has at most 4 entries and a grey clip ``(T, H, W)``
otherwise; a 4-D array is a colour clip ``(T, H, W, C)``. ``channel_axis=None``
forces grey. :func:`fit_mask` fits a mask drawn at another size to a frame;
:func:`estimate_motion` and :func:`compensate_motion` move neighbouring frames
onto each other (the detector's blotch test and the fill's temporal context
use them).
"""

from ._detection import detect_scratches, iter_detect_scratches
from ._filling import inpaint, iter_inpaint
from ._layout import fit_mask
from ._motion import (
    compensate_motion,
    estimate_motion,
    iter_compensate_motion,
    iter_estimate_motion,
    warp_frame,
)

__all__ = [
    "compensate_motion",
    "detect_scratches",
    "estimate_motion",
    "fit_mask",
    "inpaint",
    "iter_compensate_motion",
    "iter_detect_scratches",
    "iter_estimate_motion",
    "iter_inpaint",
    "warp_frame",
]
