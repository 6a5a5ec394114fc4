"""Docstring sections written once for the texture models (put in by
:func:`car_napari._docstrings.shared_sections`)."""

RAISES_SYNTHESIS = """
Raises
------
ValueError
    If ``shape`` is not two positive sizes (before the first record).
"""
