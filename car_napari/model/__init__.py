"""The CAR model: causal neighbourhoods, sufficient statistics, whole-image
and recursive Bayesian estimation, the support decision rule, Student-t
prediction, synthesis and illumination invariants (sections 14.2-14.3,
docs/model.md).

:func:`fit_car` and :func:`select_support` are long on large images; their
job forms :func:`iter_fit_car` and :func:`iter_select_support` yield
:class:`~car_napari.Progress` records and return the same results.
"""

from .estimation import (
    CARModel,
    Prediction,
    SupportSelection,
    fit_car,
    iter_fit_car,
    iter_select_support,
    predict,
    select_support,
)
from .invariants import illumination_invariants
from .neighbourhood import Context, as_offsets, causal_neighbourhood
from .recursive import local_parameters
from .synthesis import spectral_radius, synthesize

__all__ = [
    "CARModel",
    "Context",
    "Prediction",
    "SupportSelection",
    "as_offsets",
    "causal_neighbourhood",
    "fit_car",
    "illumination_invariants",
    "iter_fit_car",
    "iter_select_support",
    "local_parameters",
    "predict",
    "select_support",
    "spectral_radius",
    "synthesize",
]
