"""The model's Numba kernels (``cache=True``, ``nogil=True``): the recursive
square-root estimator and synthesis."""

from .recursive import finish_factor, recursive_scan
from .synthesis import synthesize_field

__all__ = ["finish_factor", "recursive_scan", "synthesize_field"]
