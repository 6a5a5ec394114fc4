"""Blocks of rows: how the long passes of a texture fit and synthesis are
cut, with a :class:`~car_napari.Progress` record between blocks; and the
float32 rounding of the stored numbers."""

from __future__ import annotations

import numpy as np

_CHUNK_PIXELS = 1 << 19  # pixels per block of a long pass (a record between blocks)


def _row_chunks(n_rows, width, pixels=None):
    """``(start, stop)`` row ranges of about ``pixels`` pixels each (at least
    one row): the pieces a long pass over an image is cut into, with a
    record between them."""
    step = max(1, (pixels or _CHUNK_PIXELS) // max(int(width), 1))
    return [(a, min(a + step, n_rows)) for a in range(0, n_rows, step)]


def _f32(values):
    """float64 array holding exactly float32-representable values."""
    return np.asarray(values, dtype=np.float64).astype(np.float32).astype(np.float64)

