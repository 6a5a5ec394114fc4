"""Docstring sections written once for the mammography jobs and results
(put in by :func:`car_napari._docstrings.shared_sections`)."""

# the examples start from this mammogram: a dark background and a bright
# textured breast on the right (the chest wall there)
EXAMPLES_MAMMOGRAM = """
Examples
--------
>>> import numpy as np
>>> image = np.zeros((64, 64))
>>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
"""

RAISES_BREAST = """
Raises
------
ValueError
    If the image is constant or has no breast, or ``breast`` does not
    match the image or is empty.
"""

RAISES_ROIS = """
Raises
------
ValueError
    If the image is constant or has no breast, or an option is out of
    range.
"""
