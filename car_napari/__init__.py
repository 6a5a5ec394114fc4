"""car-napari: Haindl's causal autoregressive (CAR) random-field models.

The core is pure NumPy + Numba and imports neither Qt nor napari; the napari
widgets live in :mod:`car_napari._widgets`.
"""

from .estimation import CARModel, fit_car, predict, select_support
from .invariants import illumination_invariants
from .neighbourhood import Context, causal_neighbourhood
from .recursive import local_parameters
from .synthesis import spectral_radius, synthesize
from .texture import TextureModel

__version__ = "0.1.0"

__all__ = [
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
    "TextureModel",
]
