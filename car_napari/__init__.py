"""car-napari: Haindl's causal autoregressive (CAR) random-field models.

The model (:mod:`car_napari.model`) and every application on it are reached
from here. Each long computation has a generator form ``iter_<name>`` that
yields :class:`Progress` records and returns what ``<name>`` returns
(``<name>(...)`` is ``drain(iter_<name>(...))``). The core is NumPy + Numba and
imports neither Qt nor napari; the napari dock widgets live in
:mod:`car_napari._widgets`, the command line in :mod:`car_napari.cli`.
"""

from importlib import metadata as _metadata

from ._progress import Progress, drain
from ._threads import limited_blas
from .inpainting import (
    compensate_motion,
    descratch_frames,
    detect_scratches,
    estimate_motion,
    fit_mask,
    inpaint,
    inpaint_frames,
    inpaint_large,
    iter_compensate_motion,
    iter_descratch_frames,
    iter_detect_scratches,
    iter_estimate_motion,
    iter_inpaint,
    iter_inpaint_frames,
    iter_inpaint_large,
    warp_frame,
)
from .mammography import (
    MammogramROIs,
    TissueResult,
    detect_breast,
    detect_mammogram_rois,
    iter_detect_mammogram_rois,
    iter_segment_breast,
    iter_segment_tissue,
    segment_breast,
    segment_tissue,
)
from .model import (
    CARModel,
    Context,
    Prediction,
    SupportSelection,
    causal_neighbourhood,
    fit_car,
    illumination_invariants,
    iter_fit_car,
    iter_local_parameters,
    iter_select_support,
    iter_synthesize,
    local_parameters,
    predict,
    select_support,
    spectral_radius,
    synthesize,
)
from .restoration import (
    MultichannelRestoration,
    RestorationResult,
    estimate_noise,
    estimate_psf,
    iter_restore,
    iter_restore_frames,
    iter_restore_large,
    iter_restore_multichannel,
    restore,
    restore_frames,
    restore_large,
    restore_multichannel,
)
from .segmentation import (
    SegmentationResult,
    iter_local_features,
    iter_segment,
    local_features,
    segment,
)
from .texture import (
    BTFModel,
    DynamicTextureModel,
    Ranking,
    TextureModel,
    fit_btf,
    fit_dynamic_texture,
    fit_texture,
    iter_fit_btf,
    iter_fit_dynamic_texture,
    iter_fit_texture,
    iter_rank,
    rank,
    texture_features,
)

try:  # the version is pyproject.toml's, read from the installed distribution
    __version__ = _metadata.version("car-napari")
except _metadata.PackageNotFoundError:  # the source tree on sys.path, not installed
    __version__ = "0+unknown"

__all__ = [
    # the model
    "CARModel",
    "Context",
    "Prediction",
    "SupportSelection",
    "causal_neighbourhood",
    "fit_btf",
    "fit_car",
    "fit_dynamic_texture",
    "fit_texture",
    "illumination_invariants",
    "iter_fit_car",
    "iter_local_parameters",
    "iter_select_support",
    "iter_synthesize",
    "local_parameters",
    "predict",
    "select_support",
    "spectral_radius",
    "synthesize",
    # segmentation and mammograms
    "SegmentationResult",
    "iter_local_features",
    "iter_segment",
    "local_features",
    "segment",
    "MammogramROIs",
    "detect_breast",
    "detect_mammogram_rois",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "segment_breast",
    "TissueResult",
    "iter_segment_tissue",
    "segment_tissue",
    # restoration
    "MultichannelRestoration",
    "RestorationResult",
    "estimate_noise",
    "estimate_psf",
    "iter_restore",
    "iter_restore_multichannel",
    "restore",
    "restore_multichannel",
    # scratches and blotches
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
    # larger than memory: an image by tiles, a clip by blocks of frames
    "descratch_frames",
    "inpaint_frames",
    "inpaint_large",
    "iter_descratch_frames",
    "iter_inpaint_frames",
    "iter_inpaint_large",
    "iter_restore_frames",
    "iter_restore_large",
    "restore_frames",
    "restore_large",
    # textures
    "BTFModel",
    "DynamicTextureModel",
    "Ranking",
    "TextureModel",
    "iter_fit_btf",
    "iter_fit_dynamic_texture",
    "iter_fit_texture",
    "iter_rank",
    "rank",
    "texture_features",
    # the job protocol
    "Progress",
    "drain",
    "limited_blas",
]
