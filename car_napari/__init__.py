"""car-napari: Haindl's causal autoregressive (CAR) random-field models.

The model (:mod:`car_napari.model`) and every application on it are reached
from here; each long computation also has a generator form ``iter_<name>``
that yields :class:`Progress` records and returns the result. The core is
NumPy + Numba and imports neither Qt nor napari; the napari dock widgets live
in :mod:`car_napari._widgets`.
"""

from ._progress import Progress
from .inpainting import detect_scratches, inpaint, iter_inpaint
from .mammography import detect_breast, detect_mammogram_rois, iter_detect_mammogram_rois
from .model import (
    CARModel,
    Context,
    causal_neighbourhood,
    fit_car,
    illumination_invariants,
    local_parameters,
    predict,
    select_support,
    spectral_radius,
    synthesize,
)
from .restoration import (
    RestorationResult,
    estimate_noise,
    estimate_psf,
    iter_restore,
    iter_restore_multichannel,
    restore,
    restore_multichannel,
)
from .segmentation import SegmentationResult, iter_segment, local_features, segment
from .texture import BTFModel, DynamicTextureModel, TextureModel, rank, texture_features

__version__ = "0.1.0"

__all__ = [
    # the model
    "CARModel",
    "Context",
    "causal_neighbourhood",
    "fit_car",
    "illumination_invariants",
    "local_parameters",
    "predict",
    "select_support",
    "spectral_radius",
    "synthesize",
    # segmentation and mammograms
    "SegmentationResult",
    "iter_segment",
    "local_features",
    "segment",
    "detect_breast",
    "detect_mammogram_rois",
    "iter_detect_mammogram_rois",
    # restoration
    "RestorationResult",
    "estimate_noise",
    "estimate_psf",
    "iter_restore",
    "iter_restore_multichannel",
    "restore",
    "restore_multichannel",
    # scratches and blotches
    "detect_scratches",
    "inpaint",
    "iter_inpaint",
    # textures
    "BTFModel",
    "DynamicTextureModel",
    "TextureModel",
    "rank",
    "texture_features",
    # the job protocol
    "Progress",
]
