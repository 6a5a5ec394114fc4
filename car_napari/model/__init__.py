"""The CAR model: causal neighbourhoods, sufficient statistics, whole-image
and recursive Bayesian estimation, the support decision rule, Student-t
prediction, synthesis and illumination invariants (chapter 14.2-14.3)."""

from .estimation import CARModel, fit_car, predict, select_support
from .invariants import illumination_invariants
from .neighbourhood import Context, as_offsets, causal_neighbourhood
from .recursive import local_parameters
from .synthesis import spectral_radius, synthesize

__all__ = [
    "CARModel",
    "Context",
    "as_offsets",
    "causal_neighbourhood",
    "fit_car",
    "illumination_invariants",
    "local_parameters",
    "predict",
    "select_support",
    "spectral_radius",
    "synthesize",
]
