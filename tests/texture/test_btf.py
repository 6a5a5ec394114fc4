"""BTF subspace models (section 14.8, docs/texture.md) on a stack built from a real texture under
simulated illuminations: shading of a height map (the texture's own smoothed
grey) by a set of light directions, times its colour (albedo)."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata

from car_napari import Progress
from car_napari._progress import drain
from car_napari.texture import BTFModel, cumulative_histograms, iter_fit_btf


def _lit_stack(n_lights=8):
    albedo = skdata.astronaut()[300:428, 0:128] / 255.0  # grass
    height = ndimage.gaussian_filter(albedo.mean(axis=2), 2.0) * 20.0
    gy, gx = np.gradient(height)
    normal = np.dstack([-gx, -gy, np.ones_like(gx)])
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    stack, elevations = [], []
    for k in range(n_lights):
        azimuth = 2 * np.pi * k / n_lights
        elevation = np.deg2rad(20 if k % 2 else 70)  # two groups: grazing and steep
        light = np.array([np.cos(azimuth) * np.cos(elevation),
                          np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
        shading = np.clip(normal @ light, 0, None)
        stack.append(np.clip(albedo * shading[..., None], 0, 1))
        elevations.append(k % 2)
    return np.stack(stack), np.array(elevations)


def test_subspaces_follow_the_illumination_and_synthesis_keeps_each_image():
    stack, group = _lit_stack()
    btf = BTFModel.fit(stack, n_subspaces=2, levels=2)
    # the two illumination groups (grazing vs steep light) are the two subspaces
    same = btf.assignment[:, None] == btf.assignment[None, :]
    assert np.array_equal(same, group[:, None] == group[None, :])
    out = btf.synthesize((96, 80), seed=0)
    assert out.shape == (8, 96, 80, 3)
    np.testing.assert_allclose(out.mean(axis=(1, 2)), stack.mean(axis=(1, 2)), atol=0.01)
    assert btf.compression_ratio(stack.shape) > 100
    again = btf.synthesize((96, 80), seed=0)
    np.testing.assert_array_equal(out, again)


def test_cumulative_histograms_are_monotone_and_end_at_one():
    stack, _ = _lit_stack(2)
    f = cumulative_histograms(stack)
    assert f.shape == (2, 96)
    per_channel = f.reshape(2, 3, 32)
    assert np.all(np.diff(per_channel, axis=2) >= 0) and np.all(per_channel[..., -1] == 1)


def test_cumulative_histograms_count_the_values_at_or_below_each_upper_edge():
    """Against a plain count: per image and channel, the share of pixels <= k / bins
    for k = 1..bins (values on the edges themselves included)."""
    rng = np.random.default_rng(3)
    stack = rng.random((3, 20, 17, 2))
    stack[0, :4, :, 0] = 0.25  # on an edge
    stack[1, :, :3, 1] = 1.0
    stack[2, 5:9, :, :] = 0.0
    bins = 8
    f = cumulative_histograms(stack, bins=bins)
    edges = np.arange(1, bins + 1) / bins
    want = np.stack([np.concatenate([(image[..., c].ravel()[:, None] <= edges).mean(axis=0)
                                     for c in range(2)]) for image in stack])
    np.testing.assert_array_equal(f, want)

def test_bad_input():
    stack, _ = _lit_stack(2)
    with pytest.raises(ValueError, match="n_subspaces"):
        BTFModel.fit(stack, n_subspaces=3)
    with pytest.raises(ValueError, match="each image of the stack is 128x3"):
        BTFModel.fit(stack[0])  # one colour image is 128 grey images of 128x3
    with pytest.raises(ValueError, match="channel_axis=None"):
        BTFModel.fit(stack, channel_axis=None)
    with pytest.raises(ValueError, match="channel_axis"):
        BTFModel.fit(stack, channel_axis=0)
    with pytest.raises(ValueError, match="empty"):
        BTFModel.fit(stack[:0])


def _same_btf(a, b):
    np.testing.assert_array_equal(a.assignment, b.assignment)
    np.testing.assert_array_equal(a.representatives, b.representatives)
    assert a.grey == b.grey and a.nbytes == b.nbytes
    np.testing.assert_array_equal(a.synthesize((40, 36), seed=2), b.synthesize((40, 36), seed=2))


def test_iter_fit_btf_reports_progress_and_returns_the_fit():
    stack, _ = _lit_stack(4)
    stack = stack[:, :64, :64]
    records = []
    result = drain(iter_fit_btf(stack, n_subspaces=2, levels=2), records.append)
    assert all(isinstance(r, Progress) for r in records)
    assert [r.message for r in records if r.stage == "histograms"] == [
        f"histogram {i}/4" for i in (1, 2, 3, 4)]
    fits = [r.message for r in records if r.stage == "subspaces"]
    assert fits[0] == "subspace 1/2" and "subspace 2/2" in fits
    assert "subspace 2/2, 2 levels fitted" in fits
    assert any(m.startswith("subspace 1/2, level 2/2: ") for m in fits)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[0] == 0 and fractions[-1] == 1
    _same_btf(result, BTFModel.fit(stack, n_subspaces=2, levels=2))


def test_grey_stack_and_channel_axis():
    stack, _ = _lit_stack(2)
    stack = stack[:, :64, :64]
    grey = BTFModel.fit(stack[..., 0], n_subspaces=1, levels=2)  # (n, H, W) is grey
    assert grey.grey and grey.synthesize((32, 40), seed=0).shape == (2, 32, 40)
    _same_btf(grey, BTFModel.fit(stack[..., 0], n_subspaces=1, levels=2, channel_axis=None))
    first = BTFModel.fit(np.moveaxis(stack, -1, 1), n_subspaces=1, levels=2, channel_axis=1)
    _same_btf(first, BTFModel.fit(stack, n_subspaces=1, levels=2))
    np.testing.assert_array_equal(cumulative_histograms(stack[..., 0]),
                                  cumulative_histograms(stack[..., :1]))


def _reference_btf_synthesis(btf, shape, seed):
    """Today's (session 19's) one-call BTF synthesis, the reference of the job."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(btf.n_images):
        model = btf.models[btf.assignment[i]]
        sample = model.synthesize(shape, seed=rng.integers(2**63))
        sample = sample.reshape(shape[0], shape[1], -1)
        centred = sample - sample.mean(axis=(0, 1))
        spread = centred.std(axis=(0, 1))
        gain = np.where(spread > 0, btf.image_std[i] / np.where(spread > 0, spread, 1), 1)
        image = np.clip(btf.image_mean[i] + centred * gain, btf.image_range[i, 0],
                        btf.image_range[i, 1])
        out.append(image[..., 0] if btf.grey else image)
    return np.stack(out)


@pytest.mark.parametrize("grey", [False, True])
def test_synthesis_job_is_bit_identical_and_reports_every_image(grey):
    stack, _ = _lit_stack(4)
    stack = stack[:, :64, :64].mean(axis=3) if grey else stack[:, :64, :64]
    btf = BTFModel.fit(stack, n_subspaces=2, levels=2)
    want = _reference_btf_synthesis(btf, (35, 47), 4)
    np.testing.assert_array_equal(btf.synthesize((35, 47), seed=4), want)
    records = []
    got = drain(btf.iter_synthesize((35, 47), seed=4), records.append)
    np.testing.assert_array_equal(got, want)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    for i in range(4):  # an equal share per image
        mine = [r.fraction for r in records if r.message.startswith(f"image {i + 1}/4, ")]
        assert i / 4 <= min(mine) and max(mine) <= (i + 1) / 4 + 1e-12
    assert [r.preview for r in records if r.preview is not None][-1] is got
    with pytest.raises(ValueError, match="positive"):
        next(btf.iter_synthesize((0, 5)))


def test_a_stack_beyond_0_1_clusters_as_the_stack_scaled_to_it():
    # found by tests/test_properties_entry_points.py: the histograms' bins
    # were fixed on [0, 1], so radiances (say 3 x + 1) fell in one bin: one
    # subspace for every illumination, and K-means warned of empty clusters
    import warnings

    stack, group = _lit_stack()
    stack = stack[:, :48, :48]
    want = BTFModel.fit(stack, n_subspaces=2, levels=1).assignment
    assert len(set(want.tolist())) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = BTFModel.fit(3 * stack + 1, n_subspaces=2, levels=1).assignment
        np.testing.assert_array_equal(got, want)
        # identical images: one subspace, without a word from K-means
        same = BTFModel.fit(np.stack([stack[0]] * 3), n_subspaces=2, levels=1)
    assert same.assignment.tolist() == [0, 0, 0] and len(same.models) == 1
