"""Mammogram regions of interest on the CAR texture segmentation of the breast
(section 14.4, docs/mammography.md).

:func:`detect_breast` finds the breast; :func:`segment_breast` segments it;
:func:`filter_regions` keeps the mass-like regions of a segmentation;
:func:`detect_mammogram_rois` does all three and returns
:class:`MammogramROIs` ``(labels, table)``. The ``iter_`` forms are the same
jobs as generators of :class:`~car_napari.Progress` records that return the
result. A research tool, never a screening aid.
"""

from ._breast import BreastDetection, detect_breast
from ._regions import (
    DEFAULT_MAX_REGIONS,
    MASS_RADIUS_RANGE,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    TABLE_COLUMNS,
    MammogramROIs,
    filter_regions,
    region_outlines,
)
from ._rois import (
    DEFAULT_POOL_SEGMENTS,
    BreastSegmentation,
    detect_mammogram_rois,
    iter_detect_mammogram_rois,
    iter_segment_breast,
    segment_breast,
)

__all__ = [
    "DEFAULT_MAX_REGIONS",
    "DEFAULT_POOL_SEGMENTS",
    "MASS_RADIUS_RANGE",
    "REFERENCE_GREY",
    "REFERENCE_TOLERANCE",
    "TABLE_COLUMNS",
    "BreastDetection",
    "BreastSegmentation",
    "MammogramROIs",
    "detect_breast",
    "detect_mammogram_rois",
    "filter_regions",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "region_outlines",
    "segment_breast",
]
