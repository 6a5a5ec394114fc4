"""Texture segmentation core (section 14.4, docs/segmentation.md): the job,
the merge history, bad input."""

import inspect
import time

import numpy as np
import pytest
from skimage import data as skdata

from car_napari import Progress
from car_napari._progress import drain
from car_napari.segmentation import (
    Mixture,
    SegmentationResult,
    iter_local_features,
    iter_segment,
    local_features,
    segment,
)


def _two_textures():
    a = skdata.brick()[:128, :64] / 255.0
    b = skdata.grass()[:128, :64] / 255.0
    truth = np.zeros((128, 128), int)
    truth[:, 64:] = 1
    return np.concatenate([a, b], axis=1), truth


def _matched_accuracy(truth, labels):
    best = 0.0
    for flip in (False, True):
        pred = labels == labels[64, 96] if not flip else labels != labels[64, 32]
        best = max(best, np.mean(pred == truth.astype(bool)))
    return best


def test_two_textures_are_separated():
    image, truth = _two_textures()
    result = segment(image, n_segments=2, levels=2, n_init=8)
    assert isinstance(result, SegmentationResult)
    assert result.labels.shape == truth.shape and result.n_segments == 2
    assert _matched_accuracy(truth, result.labels) > 0.85


def test_job_yields_progress_with_label_previews_and_returns_the_result():
    image, truth = _two_textures()
    records = []
    result = drain(iter_segment(image, levels=2, n_init=8), records.append)
    assert isinstance(result, SegmentationResult)
    assert all(isinstance(r, Progress) for r in records)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and 0.0 <= fractions[0] and fractions[-1] <= 1.0
    assert records[0].stage == "features" and records[0].preview is None
    shown = [r for r in records if r.preview is not None]
    assert [r.stage for r in shown] == ["mixture"] + ["merging"] * (len(shown) - 1)
    # one preview after the initialisation and one after every merge, K falling to 1
    ks = [int(r.message.removeprefix("K = ")) for r in shown]
    assert ks[0] == result.history[0].k and ks[-1] == 1 == result.history[-1].k
    assert ks == sorted(ks, reverse=True) and len(shown) == len(result.history)
    for r, mix in zip(shown, result.history, strict=True):
        assert r.preview.shape == truth.shape and r.preview.dtype.kind == "i"
        assert set(np.unique(r.preview)) <= set(mix.ids.tolist())
    # the job returns exactly what segment returns
    again = segment(image, levels=2, n_init=8)
    np.testing.assert_array_equal(again.labels, result.labels)
    assert again.n_segments == result.n_segments


def test_closing_the_job_early_stops_it():
    image, _ = _two_textures()
    job = iter_segment(image, levels=2, n_init=8)
    first = next(job)
    assert first.stage == "features" and first.fraction == 0.0
    t0 = time.perf_counter()
    job.close()
    assert time.perf_counter() - t0 < 0.5
    with pytest.raises(StopIteration):
        next(job)
    # closed during the merges too: no result, nothing more yielded
    job = iter_segment(image, levels=2, n_init=8)
    for record in job:
        if record.stage == "merging":
            break
    job.close()
    assert list(job) == []


def test_iter_local_features_yields_per_scan_and_level():
    image, _ = _two_textures()
    records = []
    features = drain(iter_local_features(image, levels=2), records.append)
    assert len(records) == 1 + 2 * (4 + 1)
    assert [r.fraction for r in records] == sorted(r.fraction for r in records)
    assert records[-1].fraction == 1.0 and all(r.stage == "features" for r in records)
    np.testing.assert_array_equal(features, local_features(image, levels=2))
    assert features.dtype == np.float32 and features.shape[:2] == image.shape


def test_segment_lists_its_options_like_iter_segment():
    params = inspect.signature(segment).parameters
    assert list(params) == list(inspect.signature(iter_segment).parameters)
    kinds = {p.kind for name, p in params.items() if name != "image"}
    assert kinds == {inspect.Parameter.KEYWORD_ONLY}
    assert params["channel_axis"].default == -1
    for name in params:
        assert f"{name} :" in segment.__doc__ and f"{name} :" in iter_segment.__doc__


def test_history_is_mixtures():
    image, _ = _two_textures()
    result = segment(image, n_segments=2, levels=2, n_init=8)
    assert all(isinstance(m, Mixture) for m in result.history)
    assert all(np.isclose(m.weights.sum(), 1.0) for m in result.history)


def test_labels_at_recuts_the_history():
    image, _ = _two_textures()
    result = segment(image, levels=2, n_init=8)
    ks = sorted({m.k for m in result.history})
    assert ks[0] == 1 and ks[-1] >= 6
    for k in (1, 2, 3, ks[-1]):
        labels = result.labels_at(k)
        assert labels.shape == image.shape
        assert 1 <= len(np.unique(labels[labels > 0])) <= k
    assert (result.labels_at(2, threshold=0.999) == 0).any()


def test_grey_modes():
    image, truth = _two_textures()
    for grey in ("pseudo_colour", "grey"):
        result = segment(image, n_segments=2, levels=2, n_init=8, grey=grey)
        assert result.labels.shape == truth.shape


@pytest.mark.parametrize(
    "image, match",
    [
        (np.full((128, 128), 0.3), "constant"),
        (np.random.default_rng(0).random((20, 20)), "too small"),
        (np.where(np.eye(128) > 0, np.nan, 0.5) + np.random.default_rng(1).random((128, 128)),
         "NaN"),
    ],
)
def test_bad_input(image, match):
    with pytest.raises(ValueError, match=match):
        segment(image, levels=3)


@pytest.mark.parametrize(
    "options, match",
    [
        ({"mask": np.zeros((128, 128), bool)}, "mask"),
        ({"mask": np.ones((64, 128), bool)}, "mask"),
        ({"grey": "gray"}, "grey must be"),
        ({"n_segments": 9, "n_init": 8}, "must not exceed"),
        ({"threshold": 1.0}, "threshold"),
    ],
)
def test_bad_options_fail_before_the_features(options, match):
    image, _ = _two_textures()
    job = iter_segment(image, levels=2, **options)
    with pytest.raises(ValueError, match=match):
        next(job)


def test_n_segments_stops_at_k_and_features_can_be_reused():
    image, _ = _two_textures()
    result = segment(image, n_segments=3, levels=2, n_init=8)
    assert len(np.unique(result.labels[result.labels > 0])) <= 3
    again = segment(image, n_segments=3, levels=2, n_init=8, features=result.features)
    np.testing.assert_array_equal(again.labels, result.labels)


def test_labels_at_is_fast():
    image, _ = _two_textures()
    result = segment(image, levels=2, n_init=8)
    t0 = time.perf_counter()
    result.labels_at(2)
    assert time.perf_counter() - t0 < 1.0
