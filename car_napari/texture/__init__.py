"""Texture modelling on the CAR model: synthesis and compression
(:class:`TextureModel`), BTF subspaces, dynamic textures and
illumination-invariant retrieval (chapter 14.7)."""

from ._model import FORMAT_NAME, FORMAT_VERSION, TextureModel, collapse_pyramid, laplacian_pyramid
from .btf import BTFModel, cumulative_histograms
from .dynamic import DynamicTextureModel, temporal_context
from .retrieval import minimum_size, rank, texture_features

__all__ = [
    "BTFModel",
    "DynamicTextureModel",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "TextureModel",
    "collapse_pyramid",
    "cumulative_histograms",
    "laplacian_pyramid",
    "minimum_size",
    "rank",
    "temporal_context",
    "texture_features",
]
