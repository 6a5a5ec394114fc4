"""Mammogram regions of interest on the CAR texture segmentation of the breast
(section 14.4, docs/mammography.md).

:func:`detect_breast` finds the breast; :func:`segment_breast` segments it;
:func:`detect_mammogram_rois` does both, then describes every candidate
region by its CAR texture, grey level, contrast, size and shape, scores it
with the shipped logistic model and returns the marks of an operating point
(``marks_per_image``) as :class:`MammogramROIs` ``(labels, table)``;
:func:`select_marks` re-cuts a result at another operating point
(:data:`OPERATING_POINTS`: the shipped cross-validated FROC table).
:func:`filter_regions` is the chapter's plain grey-level filter.
:func:`segment_tissue` finds the fibroglandular tissue on the same
segmentation and gives the percent density and tissue class
(:class:`TissueResult`); :func:`analyse_mammogram` does both from one
segmentation. The ``iter_`` forms are the same
jobs as generators of :class:`~car_napari.Progress` records that return the
result. A research tool, never a screening aid.
"""

from ._breast import BreastDetection, detect_breast
from ._candidates import shipped_model as _shipped_model
from ._images import bit_depth
from ._regions import (
    DEFAULT_MAX_REGIONS,
    MASS_RADIUS_RANGE,
    REFERENCE_GREY,
    REFERENCE_TOLERANCE,
    TABLE_COLUMNS,
    MammogramROIs,
    filter_regions,
    region_outlines,
    roi_overlay,
)
from ._rois import (
    DEFAULT_MARKS_PER_IMAGE,
    DEFAULT_POOL_SEGMENTS,
    BreastSegmentation,
    detect_mammogram_rois,
    iter_detect_mammogram_rois,
    iter_segment_breast,
    operating_point,
    score_threshold,
    segment_breast,
    select_marks,
)
from ._tissue import (
    TISSUE_CLASSES,
    MammogramAnalysis,
    TissueResult,
    analyse_mammogram,
    iter_analyse_mammogram,
    iter_segment_tissue,
    segment_tissue,
)

# The shipped model's operating points (benchmarks/bench_froc.py): per
# ``marks_per_image`` (false marks per image, cross-validated by patient on
# CBIS-DDSM films), the score threshold and the cross-validated sensitivity
# there, with the no-CAR control's (operating_point reads one).
OPERATING_POINTS = tuple(dict(p) for p in _shipped_model().spec["operating_points"])

__all__ = [
    "DEFAULT_MARKS_PER_IMAGE",
    "DEFAULT_MAX_REGIONS",
    "DEFAULT_POOL_SEGMENTS",
    "MASS_RADIUS_RANGE",
    "OPERATING_POINTS",
    "REFERENCE_GREY",
    "REFERENCE_TOLERANCE",
    "TABLE_COLUMNS",
    "TISSUE_CLASSES",
    "BreastDetection",
    "BreastSegmentation",
    "MammogramAnalysis",
    "MammogramROIs",
    "TissueResult",
    "analyse_mammogram",
    "bit_depth",
    "detect_breast",
    "detect_mammogram_rois",
    "filter_regions",
    "iter_analyse_mammogram",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "iter_segment_tissue",
    "operating_point",
    "region_outlines",
    "roi_overlay",
    "score_threshold",
    "segment_breast",
    "segment_tissue",
    "select_marks",
]
