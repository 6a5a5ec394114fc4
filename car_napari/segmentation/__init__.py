"""Unsupervised texture segmentation: local CAR features, a Gaussian mixture
and Kullback-Leibler merging (chapter 14.4)."""

from ._segment import (
    iter_segment,
    pseudo_colour,
    segment,
    SegmentationResult,
    SegmentationState,
    local_features,
)

__all__ = [
    "segment",
    "iter_segment",
    "local_features",
    "SegmentationState",
    "SegmentationResult",
    "pseudo_colour",
]
