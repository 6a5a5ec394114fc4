"""Illumination-invariant texture retrieval (section 14.3, docs/model.md): features and
ranking."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari import Progress
from car_napari._progress import drain
from car_napari.texture import Ranking, iter_rank, minimum_size, rank, texture_features


def _patch():
    return skdata.astronaut()[256:384, 0:128] / 255.0


def _illuminate(image, rng, noise=0.0):
    """Y -> B Y with B positive (entries in [0.2, 1]), scaled so the result
    stays in [0, 1], plus Gaussian noise."""
    B = rng.uniform(0.2, 1.0, (3, 3))
    B /= B.sum(axis=1).max()
    out = image @ B.T
    if noise:
        out = out + rng.normal(0.0, noise, out.shape)
    return out


@pytest.mark.parametrize("seed", range(3))
def test_invariant_under_random_positive_B(seed):
    rng = np.random.default_rng(seed)
    img = _patch()
    f = texture_features(img)
    g = texture_features(_illuminate(img, rng))
    assert f.shape == (3 * (4 + 1),)
    np.testing.assert_allclose(g, f, rtol=1e-6, atol=1e-6 * np.abs(f).max())


def test_invariant_grey_gain_and_other_options():
    img = skdata.camera()[100:228, 100:228] / 255.0
    f = texture_features(img, channel_axis=None, levels=2, neighbourhood=3)
    g = texture_features(0.3 * img, channel_axis=None, levels=2, neighbourhood=3)
    assert f.shape == (2 * (6 + 1),)
    np.testing.assert_allclose(g, f, rtol=1e-6, atol=1e-6 * np.abs(f).max())


def test_channel_axis_first():
    img = _patch()
    np.testing.assert_allclose(
        texture_features(np.moveaxis(img, -1, 0), channel_axis=0), texture_features(img)
    )


def _textures(shared_root):
    """Colour textures of 192 x 192 (a 2 x 2 grid of 96 x 96 tiles each): four
    VisTex images when present, otherwise scikit-image's grey brick, grass
    and gravel made colour by putting shifted copies in the other channels
    (scikit-image has no homogeneous colour texture: its colour photographs'
    patches are not stationary enough at this size)."""
    vistex = shared_root / "textures" / "vistex"
    names = ["VS1.png", "VS10.png", "VS100.png", "VS104.png"]
    if vistex.is_dir() and all((vistex / n).is_file() for n in names):
        from skimage import io

        return [io.imread(vistex / n)[..., :3][128:320, 128:320] / 255.0 for n in names]
    out = []
    for name in ("brick", "grass", "gravel"):
        g = getattr(skdata, name)() / 255.0
        rgb = np.stack([g, np.roll(g, 3, axis=0), np.roll(g, 3, axis=1)], axis=-1)
        out.append(rgb[100:292, 100:292])
    return out


def test_ranking_finds_same_texture_first():
    from car_fields import SHARED_DATA

    rng = np.random.default_rng(0)
    tiles, labels = [], []
    for k, tex in enumerate(_textures(SHARED_DATA)):
        for i in (0, 96):
            for j in (0, 96):
                tiles.append(_illuminate(tex[i:i + 96, j:j + 96], rng, noise=0.03))
                labels.append(k)
    labels = np.array(labels)
    feats = [texture_features(t) for t in tiles]
    hits = 0
    for q in range(len(tiles)):
        others = [f for i, f in enumerate(feats) if i != q]
        idx, dist = rank(feats[q], others)
        assert np.all(np.diff(dist) >= 0)
        hits += labels[np.delete(np.arange(len(tiles)), q)][idx[0]] == labels[q]
    # every query's nearest neighbour is another tile of its own texture
    assert hits == len(tiles)


def test_rank_accepts_images_and_vectors_alike():
    rng = np.random.default_rng(1)
    img = _patch()
    gallery = [img[:64, :64], img[64:, 64:], skdata.coffee()[:64, :64] / 255.0]
    idx_img, d_img = rank(_illuminate(img[:64, 64:], rng), gallery)
    idx_vec, d_vec = rank(texture_features(_illuminate(img[:64, 64:], np.random.default_rng(1))),
                          np.array([texture_features(g) for g in gallery]))
    np.testing.assert_array_equal(idx_img, idx_vec)
    np.testing.assert_allclose(d_img, d_vec, rtol=1e-6)
    assert set(idx_img.tolist()) == {0, 1, 2}


def test_single_entry_gallery():
    img = _patch()
    idx, dist = rank(img, [img[::-1]])
    assert idx.tolist() == [0] and np.isfinite(dist[0])


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda img: rank(img, []), "gallery is empty"),
        (lambda img: rank(img, [img[..., 0]]), "grey"),
        (lambda img: rank(img[..., 0], [img]), "grey"),
        (lambda img: rank(img, [np.ones(7)]), "length 7"),
        (lambda img: rank(np.ones(15), [np.ones(15), np.ones(12)]), r"gallery\[1\].*length 12"),
        (lambda img: texture_features(img[:20, :20]), "at least 24 pixels"),
        (lambda img: rank(img, [img, img[:16, :16]]), r"gallery\[1\].*at least 24"),
        (lambda img: texture_features(img, levels=0), "levels"),
        (lambda img: texture_features(np.repeat(img[..., :1], 3, axis=2)), "dependent"),
        (lambda img: texture_features(np.zeros((64, 64))), "constant"),
        (lambda img: rank(img, np.ones(3)), "gallery array"),
    ],
)
def test_bad_input_is_a_clear_error(call, match):
    with pytest.raises(ValueError, match=match):
        call(_patch())


def test_bad_types():
    with pytest.raises(TypeError, match="gallery"):
        rank(_patch(), None)
    with pytest.raises(TypeError, match="dtype"):
        rank(_patch(), [np.array(["a", "b"])])


def test_minimum_size_grows_with_levels_and_order():
    assert minimum_size() == 24
    assert minimum_size(levels=4, neighbourhood=3) > minimum_size()
    n = minimum_size(levels=2, neighbourhood=1)
    texture_features(np.random.default_rng(0).random((n, n, 3)), levels=2, neighbourhood=1)


def test_iter_rank_reports_every_gallery_entry_and_returns_the_ranking():
    img = _patch()
    gallery = [img[:64, :64], texture_features(img[64:, 64:]), skdata.coffee()[:32, :32] / 255.0]
    records = []
    result = drain(iter_rank(img[:64, 64:], gallery), records.append)
    assert all(isinstance(r, Progress) for r in records)
    assert [r.message for r in records] == ["query", "gallery 1/3", "gallery 2/3",
                                            "gallery 3/3", "3 ranked"]
    assert [r.stage for r in records] == ["features"] * 4 + ["ranking"]
    # by pixels: query 64x64, gallery[0] 64x64, gallery[1] a vector (free), gallery[2] 32x32
    np.testing.assert_allclose([r.fraction for r in records], [0, 4 / 9, 8 / 9, 8 / 9, 1])
    assert isinstance(result, Ranking)
    expected = rank(img[:64, 64:], gallery)
    assert isinstance(expected, Ranking)
    np.testing.assert_array_equal(result.indices, expected.indices)
    np.testing.assert_array_equal(result.distances, expected.distances)
    indices, distances = expected  # still unpacks like a pair
    assert indices is expected.indices and distances is expected.distances


def test_iter_rank_of_vectors_advances_by_entries_and_validates_first():
    vectors = np.random.default_rng(0).random((4, 15))
    records = []
    drain(iter_rank(vectors[0], vectors[1:]), records.append)
    np.testing.assert_allclose([r.fraction for r in records], [0, 0.25, 0.5, 0.75, 1])
    job = iter_rank(_patch(), [_patch(), np.ones(7)])
    with pytest.raises(ValueError, match="length 7"):
        next(job)  # every entry is checked before any features are computed


def test_grey_image_needs_no_channel_axis():
    img = skdata.camera()[100:228, 100:228] / 255.0
    np.testing.assert_array_equal(texture_features(img), texture_features(img, channel_axis=None))


# --- the features by bands of rows (issue 12: cancellable, bounded memory) ----------------

def _reference_features(image, levels, neighbourhood, channel_axis):
    """The traces and alpha_3 of every level, from illumination_invariants
    (the whole-image computation the band-by-band one replaces)."""
    from car_napari.model import as_offsets, illumination_invariants

    eta = len(as_offsets(neighbourhood)[0])
    d = 1 if image.ndim == 2 else image.shape[channel_axis]
    raw = illumination_invariants(image, neighbourhood, levels=levels,
                                  channel_axis=channel_axis).reshape(levels, -1)
    assert raw.shape[1] == eta + 2 * eta * d + 3
    return np.concatenate([raw[:, :eta], raw[:, -1:]], axis=1).ravel()


@pytest.mark.parametrize("band_pixels", [1 << 17, 700])
@pytest.mark.parametrize(
    "make, levels, neighbourhood, channel_axis",
    [
        (lambda: skdata.astronaut()[100:301, 50:223], 3, 2, -1),  # uint8, odd sizes
        (lambda: skdata.camera()[50:200, 100:251] / 255.0, 2, 3, None),  # float grey
        (lambda: skdata.coffee()[:120, :160].astype(np.uint16) * 257, 1, 1, -1),  # no pyramid
        (lambda: np.moveaxis(skdata.chelsea()[:99, :77], -1, 0).astype(np.float32), 3, 1, 0),
    ],
)
def test_features_by_bands_match_the_whole_image_computation(monkeypatch, band_pixels, make,
                                                            levels, neighbourhood,
                                                            channel_axis):
    from car_napari.texture import _retrieval as retrieval

    image = make()
    before = image.copy()
    monkeypatch.setattr(retrieval, "BAND_PIXELS", band_pixels)  # 700: many bands a level
    got = texture_features(image, levels=levels, neighbourhood=neighbourhood,
                           channel_axis=channel_axis)
    want = _reference_features(image, levels, neighbourhood, channel_axis)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(image, before)  # the input is read, never written


def test_ranking_by_bands_matches_plain_numpy(monkeypatch):
    """Same ranking and distances (float tolerance) as the normalised L1 of
    the whole-image features, computed here with plain NumPy."""
    from car_napari.texture import _retrieval as retrieval

    astro = skdata.astronaut()
    gallery = [astro[i:i + 96, j:j + 96] for i in (0, 200, 400) for j in (0, 150, 300)]
    query = astro[210:330, 160:290]
    feats = np.array([_reference_features(g, 3, 2, -1) for g in gallery])
    q = _reference_features(query, 3, 2, -1)
    spread = feats.std(axis=0)
    want = (np.abs(feats - q) / np.where(spread > 0, spread, 1.0)).sum(axis=1)
    monkeypatch.setattr(retrieval, "BAND_PIXELS", 1000)
    indices, distances = rank(query, gallery)
    np.testing.assert_array_equal(indices, np.argsort(want, kind="stable"))
    np.testing.assert_allclose(distances, want[indices], rtol=1e-9)


def test_a_large_image_reports_between_bands_and_stops_when_closed(monkeypatch):
    from car_napari.texture import _retrieval as retrieval

    monkeypatch.setattr(retrieval, "BAND_PIXELS", 2048)
    image = np.tile(skdata.astronaut()[:128, :128], (2, 2, 1))  # 256 x 256: 32 bands a pass
    records = []
    drain(iter_rank(image, [image[::-1], image[:, ::-1]]), records.append)
    messages = [r.message for r in records]
    assert messages[0] == "query" and "query, level 1/3" in messages
    assert "gallery 2/2, level 3/3" in messages and messages[-1] == "2 ranked"
    fractions = [r.fraction for r in records]
    assert np.all(np.diff(fractions) >= 0) and len(records) > 40
    job = iter_rank(image, [image[::-1]])
    for _ in range(5):
        next(job)
    job.close()  # a Cancel: the generator stops between two bands
    with pytest.raises(StopIteration):
        next(job)


def test_values_are_checked_as_the_image_is_described():
    img = _patch()
    bad = img.copy()
    bad[3, 4, 1] = np.nan
    bad[60:62, 7, 0] = np.inf
    with pytest.raises(ValueError, match=r"gallery\[1\] contains 3 NaN or infinite"):
        rank(img, [img[::-1], bad])
    with pytest.raises(ValueError, match=r"query: image is constant in channel\(s\) \[2\]"):
        flat = img.copy()
        flat[..., 2] = 0.5
        rank(flat, [img])
