"""The model's Numba kernels (``cache=True``, ``nogil=True``): the recursive
square-root estimator and synthesis."""

from .recursive import recursive_scan
from .synthesis import synthesize_field

__all__ = ["recursive_scan", "synthesize_field"]
