"""Film scratch and blotch restoration: detection and filling from the
directional CAR models (chapter 14.6)."""

from ._inpaint import (
    detect_scratches,
    inpaint,
    InpaintState,
    iter_inpaint,
)

__all__ = [
    "InpaintState",
    "detect_scratches",
    "inpaint",
    "iter_inpaint",
]
