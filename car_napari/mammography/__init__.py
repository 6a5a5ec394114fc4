"""Mammogram regions of interest on the CAR texture segmentation of the
breast (chapter 14.4.1)."""

from ._rois import (
    DEFAULT_MAX_REGIONS,
    DEFAULT_POOL_SEGMENTS,
    detect_breast,
    detect_mammogram_rois,
    filter_regions,
    iter_detect_mammogram_rois,
    iter_segment_breast,
    MASS_RADIUS_RANGE,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    region_outlines,
    TABLE_COLUMNS,
)

__all__ = [
    "DEFAULT_MAX_REGIONS",
    "DEFAULT_POOL_SEGMENTS",
    "MASS_RADIUS_RANGE",
    "REFERENCE_GREY",
    "REFERENCE_TOLERANCE",
    "TABLE_COLUMNS",
    "detect_breast",
    "detect_mammogram_rois",
    "filter_regions",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "region_outlines",
]
