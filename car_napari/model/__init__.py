"""The CAR model: causal neighbourhoods, sufficient statistics, whole-image
and recursive Bayesian estimation, the support decision rule, Student-t
prediction, synthesis and illumination invariants (sections 14.2-14.3,
docs/model.md).

:func:`fit_car`, :func:`select_support`, :func:`local_parameters` and
:func:`synthesize` are long on large images; their job forms
:func:`iter_fit_car`, :func:`iter_select_support`,
:func:`iter_local_parameters` and :func:`iter_synthesize` yield
:class:`~car_napari.Progress` records and return the same results. The
recursive scan behind the last runs in chunks of rows
(:class:`~car_napari.model.recursive.RecursiveScan`,
:func:`~car_napari.model.recursive.iter_scan`): other long scans (filling,
restoration) yield between its chunks the same way.
"""

from .adaptive import iter_local_parameters, local_parameters
from .estimation import (
    SupportSelection,
    fit_car,
    iter_fit_car,
    iter_select_support,
    select_support,
)
from .fitted import CARModel, Prediction, predict
from .invariants import illumination_invariants
from .neighbourhood import Context, as_offsets, causal_neighbourhood
from .synthesis import iter_synthesize, spectral_radius, synthesize

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
    "iter_local_parameters",
    "iter_select_support",
    "iter_synthesize",
    "local_parameters",
    "predict",
    "select_support",
    "spectral_radius",
    "synthesize",
]
