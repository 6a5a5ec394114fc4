"""Texture segmentation core (SPEC 3): generator, merge history, bad input."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari.segmentation import SegmentationResult, SegmentationState, iter_segment, segment


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


def test_generator_yields_live_states_then_result():
    image, _ = _two_textures()
    items = list(iter_segment(image, levels=2, n_init=8))
    states, result = items[:-1], items[-1]
    assert isinstance(result, SegmentationResult)
    assert all(isinstance(s, SegmentationState) for s in states)
    shown = [s for s in states if s.labels is not None]
    assert len(shown) >= 3
    ks = [s.n_components for s in shown]
    assert ks == sorted(ks, reverse=True) and ks[-1] < ks[0]
    fractions = [s.fraction for s in states]
    assert fractions == sorted(fractions)
    merged = [s for s in states if s.stage == "merged"]
    assert all(s.kl is not None and s.kl >= 0 for s in merged)


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


def test_n_segments_stops_at_k_and_features_can_be_reused():
    image, _ = _two_textures()
    result = segment(image, n_segments=3, levels=2, n_init=8)
    assert len(np.unique(result.labels[result.labels > 0])) <= 3
    again = segment(image, n_segments=3, levels=2, n_init=8, features=result.features)
    np.testing.assert_array_equal(again.labels, result.labels)


def test_labels_at_is_fast():
    import time

    image, _ = _two_textures()
    result = segment(image, levels=2, n_init=8)
    t0 = time.perf_counter()
    result.labels_at(2)
    assert time.perf_counter() - t0 < 1.0
