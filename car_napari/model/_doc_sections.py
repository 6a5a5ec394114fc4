"""Docstring sections written once for the model's modules (put in by
:func:`car_napari._docstrings.shared_sections`)."""

# the examples of the statistics and scans start from this field
EXAMPLES_FIELD = """
Examples
--------
>>> import numpy as np
>>> from car_napari._progress import drain
>>> from car_napari.model import Context
>>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
"""

# the examples of the jobs that record their progress start so
EXAMPLES_RECORDS = """
Examples
--------
>>> import numpy as np
>>> from car_napari._progress import drain
>>> records = []
>>> image = np.random.default_rng(0).random((32, 32))
"""

RAISES_DIRECTION = """
Raises
------
ValueError
    If ``direction`` is not one of the four.
"""
