"""Unsupervised texture segmentation: local CAR features, a Gaussian mixture
and Kullback-Leibler merging (section 14.4, docs/segmentation.md).

:func:`segment` labels an image; :func:`iter_segment` is the same job as a
generator of :class:`~car_napari.Progress` records (previews: the labels after
initialisation and after every merge) that returns the
:class:`SegmentationResult`, whose merge history (:class:`Mixture` states)
re-cuts to any number of segments.
"""

from ._features import iter_local_features, local_features, pseudo_colour
from ._mixture import Mixture
from ._segment import SegmentationResult, iter_segment, segment

__all__ = [
    "Mixture",
    "SegmentationResult",
    "iter_local_features",
    "iter_segment",
    "local_features",
    "pseudo_colour",
    "segment",
]
