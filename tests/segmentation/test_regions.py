"""The region test of the automatic K (issue 32, item 13; _regions.py),
against plain NumPy on explicit pixel lists."""

import numpy as np
import pytest

from car_napari.segmentation import segment
from car_napari.segmentation._regions import (
    _OFFSETS,
    cross_prediction_loss,
    region_merge_order,
    region_moments,
)


def _design_rows(image, labels, segment_id):
    """(X, Y) of a segment's pixels whose causal neighbours are all inside
    the image and in the segment, built pixel by pixel."""
    h, w, _ = image.shape
    xs, ys = [], []
    for r in range(h):
        for c in range(w):
            if labels[r, c] != segment_id:
                continue
            near = [(r + dr, c + dc) for dr, dc in _OFFSETS]
            if all(0 <= rr < h and 0 <= cc < w and labels[rr, cc] == segment_id
                   for rr, cc in near):
                xs.append(np.concatenate([image[rr, cc] for rr, cc in near] + [[1.0]]))
                ys.append(image[r, c])
    return np.array(xs), np.array(ys)


def _mean_log_density(theta, residual, x, y):
    error = y - x @ theta
    inverse = np.linalg.inv(residual)
    quad = np.einsum("ni,ij,nj->n", error, inverse, error)
    return np.mean(-0.5 * (y.shape[1] * np.log(2 * np.pi)
                           + np.log(np.linalg.det(residual)) + quad))


def _image_and_labels(channels, seed=0):
    rng = np.random.default_rng(seed)
    image = rng.random((20, 26, channels))
    other = rng.random((20, 14, channels))
    image[:, 13:] = 0.2 + 0.5 * (other[:, 1:] + other[:, :-1])  # another texture
    labels = np.ones((20, 26), int)
    labels[:, 13:] = 2
    labels[15:, :6] = 3  # a corner: pixels on its edges have mixed neighbours
    labels[0, 0] = 0
    return image, labels


@pytest.mark.parametrize("channels", [1, 3])
def test_moments_are_those_of_the_pixel_by_pixel_design(channels):
    image, labels = _image_and_labels(channels)
    moments, counts = region_moments(image, labels, [1, 2, 3])
    for a, segment_id in enumerate([1, 2, 3]):
        x, y = _design_rows(image, labels, segment_id)
        z = np.hstack([y, x])
        assert counts[a] == len(z)
        np.testing.assert_allclose(moments[a], z.T @ z, rtol=1e-12)


@pytest.mark.parametrize("channels", [1, 3])
def test_cross_prediction_loss_is_the_least_squares_models_cross_log_densities(
        channels, monkeypatch):
    from car_napari.segmentation import _regions

    monkeypatch.setattr(_regions, "_RIDGE", 0.0)  # the plain least squares below
    image, labels = _image_and_labels(channels, seed=1)
    moments, counts = region_moments(image, labels, [1, 2])
    (xa, ya), (xb, yb) = (_design_rows(image, labels, i) for i in (1, 2))

    def fit(x, y):
        theta = np.linalg.lstsq(x, y, rcond=None)[0]
        error = y - x @ theta
        return theta, error.T @ error / len(y)

    model_a, model_b = fit(xa, ya), fit(xb, yb)
    expected = (_mean_log_density(*model_b, xb, yb) - _mean_log_density(*model_a, xb, yb)
                + _mean_log_density(*model_a, xa, ya)
                - _mean_log_density(*model_b, xa, ya)) / channels
    loss = cross_prediction_loss(moments[0], counts[0], moments[1], counts[1], channels)
    assert loss > 0.1
    np.testing.assert_allclose(loss, expected, rtol=1e-8)


def test_the_parts_of_one_texture_merge_before_two_textures():
    """Four strips, two of white noise and two of a smooth ramp texture
    (other realisations): the parts of each merge first, at a small loss;
    the last merge joins the two textures at a large one."""
    rng = np.random.default_rng(3)
    strips = [rng.random((64, 32)), np.cumsum(rng.random((64, 32)), axis=1) / 16,
              rng.random((64, 32)), np.cumsum(rng.random((64, 32)), axis=1) / 16]
    image = np.hstack(strips)[..., None]
    labels = np.repeat([1, 2, 3, 4], 32)[None, :].repeat(64, 0)
    order = region_merge_order(image, labels, [1, 2, 3, 4])
    assert sorted(tuple(sorted((a, b))) for _, a, b in order[:2]) == [(1, 3), (2, 4)]
    losses = [loss for loss, _, _ in order]
    assert max(losses[:2]) < 0.05 < 1.0 < losses[2]


def test_tiny_segments_are_merged_last():
    image, labels = _image_and_labels(1)
    labels[5, 5] = 4  # one pixel: no model
    order = region_merge_order(image, labels, [1, 2, 3, 4])
    assert np.isinf(order[-1][0]) and 4 in order[-1][1:]


def _history_is_consistent(result):
    ks = [mix.k for mix in result.history]
    assert ks == sorted(ks, reverse=True) and len(set(ks)) == len(ks) and ks[-1] == 1
    for mix in result.history:  # every state's labels are stored: re-cuts are look-ups
        assert result.cached_labels_at(mix.k) is not None


def test_segment_merges_the_regions_below_the_limit():
    """The region merging runs on the automatic K's state: with no limit it
    merges down to one segment and the history below follows it; with a
    zero limit (two distinct textures) nothing changes."""
    from skimage import data as skdata

    image = np.concatenate([skdata.brick()[:96, :48], skdata.grass()[:96, :48]],
                           axis=1) / 255.0
    plain = segment(image, levels=2, n_init=8)
    none_merged = segment(image, levels=2, n_init=8, region_threshold=0.0)
    np.testing.assert_array_equal(none_merged.labels, plain.labels)
    assert [m.k for m in none_merged.history] == [m.k for m in plain.history]
    merged = segment(image, levels=2, n_init=8, region_threshold=1e300)
    assert merged.n_segments == 1 and merged.labels.max() == 1
    _history_is_consistent(merged)
    above = [m.k for m in plain.history if m.k >= plain.n_segments]
    assert [m.k for m in merged.history][:len(above)] == above  # the KL merges kept
    np.testing.assert_array_equal(merged.labels_at(plain.n_segments),
                                  plain.labels_at(plain.n_segments))


@pytest.mark.parametrize("options, match", [
    (dict(region_threshold=0.1, n_segments=3), "automatic number of segments"),
    (dict(region_threshold=-0.1), "region_threshold"),
    (dict(region_threshold="0.1"), "region_threshold"),
])
def test_region_threshold_is_checked_before_any_work(options, match):
    with pytest.raises((TypeError, ValueError), match=match):
        segment(np.zeros((16, 16)), n_init=4, **options)


def test_region_threshold_needs_the_image():
    features = np.random.default_rng(0).random((16, 16, 4)).astype(np.float32)
    with pytest.raises(ValueError, match="reads the image"):
        segment(None, features=features, n_init=4, region_threshold=0.1)


def test_segment_result_is_the_states_labelling():
    from skimage import data as skdata

    image = np.concatenate([skdata.grass()[:96, :64], skdata.gravel()[:96, :64]],
                           axis=1) / 255.0
    plain = segment(image, levels=2, n_init=8)
    result = segment(image, levels=2, n_init=8, region_threshold=0.1)
    assert result.n_segments <= plain.n_segments
    _history_is_consistent(result)
    np.testing.assert_array_equal(result.labels, result.labels_at(result.n_segments))


def test_region_merging_reads_only_the_masked_pixels():
    """With a mask, the region models see only its pixels: an image that
    differs outside it (same features) gives the same segmentation."""
    from skimage import data as skdata

    image = np.concatenate([skdata.brick()[:96, :48], skdata.grass()[:96, :48]],
                           axis=1) / 255.0
    mask = np.zeros(image.shape, bool)
    mask[:, 8:88] = True
    features = segment(image, levels=2, n_init=8).features
    other = image.copy()
    other[~mask] = np.random.default_rng(0).random((~mask).sum())
    results = [segment(im, features=features, n_init=8, mask=mask, region_threshold=0.1)
               for im in (image, other)]
    np.testing.assert_array_equal(results[0].labels, results[1].labels)
    assert [m.k for m in results[0].history] == [m.k for m in results[1].history]
    assert (results[0].labels[~mask] == 0).all()


def test_the_region_jobs_yield_in_bands_and_return_the_plain_results(monkeypatch):
    """Cancel needs records often: the moments come in bands of rows (here
    of 64 pixels: 3 rows), every merge yields too; the results are the
    plain functions'."""
    from car_napari import Progress
    from car_napari._progress import drain
    from car_napari.segmentation import _regions

    image, labels = _image_and_labels(3, seed=2)
    expected = region_merge_order(image, labels, [1, 2, 3])
    monkeypatch.setattr(_regions, "_BAND_PIXELS", 64)
    records = []
    order = drain(_regions.iter_region_merge_order(image, labels, [1, 2, 3]), records.append)
    # the same merges; the losses up to the bands' summation order
    assert [m[1:] for m in order] == [m[1:] for m in expected]
    np.testing.assert_allclose([m[0] for m in order], [m[0] for m in expected], rtol=1e-10)
    assert all(isinstance(r, Progress) for r in records)
    assert len(records) >= 18 // 3 + 2  # 18 modelled rows in bands of 3, then 2 merges
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
