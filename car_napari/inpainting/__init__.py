"""Film scratch and blotch restoration: detection and filling from the
directional CAR models (section 14.7, docs/inpainting.md).

A frame or a clip is read by one rule, with the default ``channel_axis=-1``:
``(H, W)`` is a grey frame; a 3-D array is a colour frame ``(H, W, C)`` when
its channel axis has at most 4 entries and a grey clip ``(T, H, W)``
otherwise; a 4-D array is a colour clip ``(T, H, W, C)``. ``channel_axis=None``
forces grey. :func:`fit_mask` fits a mask drawn at another size to a frame.
"""

from ._detection import detect_scratches, iter_detect_scratches
from ._filling import inpaint, iter_inpaint
from ._layout import fit_mask

__all__ = [
    "detect_scratches",
    "fit_mask",
    "inpaint",
    "iter_detect_scratches",
    "iter_inpaint",
]
