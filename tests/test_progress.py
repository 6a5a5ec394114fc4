"""The job protocol's helpers (car_napari._progress), each against a plain loop."""

from __future__ import annotations

import numpy as np
import pytest

from car_napari._progress import Progress, drain, map_previews


def _job(n, closed=None):
    """n records, every other one with an image preview; returns n."""
    try:
        for k in range(n):
            preview = np.full((2, 3), k, float) if k % 2 == 0 else None
            yield Progress("rows", (k + 1) / n, f"rows {k + 1}/{n}", preview)
        return n
    finally:
        if closed is not None:
            closed.append(True)


def _plain_loop(job, transform):
    """The records and the result as a widget mapped them by hand before."""
    records = []
    while True:
        try:
            record = next(job)
        except StopIteration as stop:
            return records, stop.value
        if record.preview is not None:
            record = Progress(record.stage, record.fraction, record.message,
                              transform(record.preview))
        records.append(record)


@pytest.mark.parametrize("n", [0, 1, 5])
def test_map_previews_is_the_plain_loop(n):
    def transform(preview):
        return (preview[::2] * 2.0).astype(np.float32)

    expected, expected_result = _plain_loop(_job(n), transform)
    records = []
    result = drain(map_previews(_job(n), transform), records.append)
    assert result == expected_result == n
    assert len(records) == len(expected) == n
    for got, want in zip(records, expected, strict=True):
        assert (got.stage, got.fraction, got.message) == (want.stage, want.fraction,
                                                          want.message)
        if want.preview is None:
            assert got.preview is None
        else:
            assert got.preview.dtype == want.preview.dtype
            np.testing.assert_array_equal(got.preview, want.preview)


def test_map_previews_closes_the_job_when_closed():
    closed = []
    mapped = map_previews(_job(5, closed), lambda preview: preview)
    next(mapped)
    mapped.close()  # a Cancel
    assert closed == [True]


def test_map_previews_passes_the_job_s_error_on():
    def failing():
        yield Progress("rows", 0.5, preview=1)
        raise ValueError("bad input")

    mapped = map_previews(failing(), lambda preview: preview + 1)
    assert next(mapped).preview == 2
    with pytest.raises(ValueError, match="bad input"):
        next(mapped)
