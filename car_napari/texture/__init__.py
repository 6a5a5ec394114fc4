"""Texture modelling on the CAR model: synthesis and compression
(:class:`TextureModel`), BTF subspaces, dynamic textures (section 14.8,
docs/texture.md) and illumination-invariant retrieval (section 14.3,
docs/model.md).

Every fit and the ranking also come as a job, ``iter_<name>``, that yields
:class:`~car_napari.Progress` records and returns the result.
"""

from ._btf import BTFModel, cumulative_histograms, fit_btf, iter_fit_btf
from ._dynamic import (
    DynamicTextureModel,
    fit_dynamic_texture,
    iter_fit_dynamic_texture,
    temporal_context,
)
from ._model import (
    FORMAT_NAME,
    FORMAT_VERSION,
    TextureModel,
    collapse_pyramid,
    fit_texture,
    iter_fit_texture,
    laplacian_pyramid,
)
from ._retrieval import Ranking, iter_rank, minimum_size, rank, texture_features

__all__ = [
    "BTFModel",
    "DynamicTextureModel",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "Ranking",
    "TextureModel",
    "collapse_pyramid",
    "cumulative_histograms",
    "fit_btf",
    "fit_dynamic_texture",
    "fit_texture",
    "iter_fit_btf",
    "iter_fit_dynamic_texture",
    "iter_fit_texture",
    "iter_rank",
    "laplacian_pyramid",
    "minimum_size",
    "rank",
    "temporal_context",
    "texture_features",
]
