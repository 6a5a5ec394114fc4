"""Breast tissue: fibroglandular mask, percent density and tissue class
(issue 35; car_napari.mammography.segment_tissue)."""

import json

import numpy as np
import pytest
from skimage import io
from skimage.filters import threshold_otsu

import car_napari as car
from car_napari import Progress
from car_napari import mammography as mm
from car_napari._progress import drain
from car_napari.io.sample_data import resource_path
from car_napari.mammography import _tissue


@pytest.fixture(scope="module")
def half():
    """mini-MIAS mdb001 at 512x512 (block mean 2)."""
    sample = io.imread(str(resource_path("mammogram_mdb001.png")))
    return sample.reshape(512, 2, 512, 2).mean(axis=(1, 3)).astype(np.uint8)


@pytest.fixture(scope="module")
def job(half):
    records = []
    result = drain(mm.iter_segment_tissue(half), records.append)
    return result, records


def test_result_against_independent_computations(half, job):
    tissue, _ = job
    assert isinstance(tissue, mm.TissueResult)
    fg, breast = tissue.fibroglandular, tissue.breast
    assert fg.shape == breast.shape == half.shape and fg.dtype == bool == breast.dtype
    # the breast is detect_breast's (pectoral muscle removed), the mask inside it
    np.testing.assert_array_equal(breast, mm.detect_breast(half))
    assert not (fg & ~breast).any()
    assert 0 < fg.sum() < breast.sum()
    # percent density, computed here
    assert tissue.density == pytest.approx(100.0 * fg.sum() / breast.sum())
    # a probability per class, summing to 1; the class is the most probable
    assert set(tissue.probabilities) == set(mm.TISSUE_CLASSES) == {"F", "G", "D"}
    assert sum(tissue.probabilities.values()) == pytest.approx(1.0)
    assert all(0.0 <= p <= 1.0 for p in tissue.probabilities.values())
    assert tissue.tissue_class == max(tissue.probabilities, key=tissue.probabilities.get)
    # the fibroglandular tissue is the breast's brighter part on average
    assert half[fg].mean() > half[breast & ~fg].mean()


def test_job_records(job):
    _, records = job
    assert records and all(isinstance(r, Progress) for r in records)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert records[-1].stage == "tissue" and "density" in records[-1].message
    assert {"breast", "features", "tissue"} <= {r.stage for r in records}


def test_plain_function_drains_the_job(half, job):
    tissue = car.segment_tissue(half)
    np.testing.assert_array_equal(tissue.fibroglandular, job[0].fibroglandular)
    assert tissue.density == job[0].density
    assert tissue.probabilities == job[0].probabilities


def test_input_unchanged_and_dtype_free(half, job):
    before = half.copy()
    as_float = half.astype(np.float64) / 255.0
    tissue = mm.segment_tissue(as_float)
    np.testing.assert_array_equal(half, before)
    np.testing.assert_array_equal(tissue.fibroglandular, job[0].fibroglandular)


def test_a_given_segmentation_is_reused(half, job):
    seg = mm.segment_breast(half, pool=mm.DEFAULT_POOL_SEGMENTS, keep_features=True)
    records = []
    tissue = drain(mm.iter_segment_tissue(half, segmentation=seg), records.append)
    np.testing.assert_array_equal(tissue.fibroglandular, job[0].fibroglandular)
    assert tissue.density == job[0].density
    assert not {"features", "mixture", "merging"} & {r.stage for r in records}


def test_rois_and_tissue_from_one_segmentation(half, job):
    rois, tissue = mm.analyse_mammogram(half)
    alone = mm.detect_mammogram_rois(half)
    np.testing.assert_array_equal(rois.labels, alone.labels)
    for k in alone.table:
        np.testing.assert_array_equal(rois.table[k], alone.table[k])
    np.testing.assert_array_equal(tissue.fibroglandular, job[0].fibroglandular)
    assert tissue.tissue_class == job[0].tissue_class


def test_dense_blob_on_fat_is_found():
    """A synthetic breast: smooth dark fat with a bright, mottled disc in its
    middle. The disc is the fibroglandular tissue."""
    rng = np.random.default_rng(1)
    h, w = 400, 240
    rr, cc = np.mgrid[:h, :w]
    breast = ((rr - h / 2) / (h / 2 - 10)) ** 2 + (cc / (w - 10)) ** 2 < 1
    from scipy import ndimage

    image = np.where(breast, 0.35, 0.02) + 0.01 * rng.standard_normal((h, w))
    disc = ((rr - h / 2) / 90) ** 2 + ((cc - 80) / 60) ** 2 < 1
    mottle = ndimage.gaussian_filter(rng.standard_normal((h, w)), 2)
    image[disc] += 0.3 + 0.6 * mottle[disc]
    image = np.clip(image, 0, 1)
    tissue = mm.segment_tissue(image)
    fg = tissue.fibroglandular
    d = 2 * (fg & disc).sum() / (fg.sum() + disc.sum())
    assert d > 0.6, d


def test_bad_input(half):
    with pytest.raises(ValueError, match="constant"):
        mm.segment_tissue(np.zeros((64, 64)))
    with pytest.raises(TypeError, match="BreastSegmentation"):
        mm.segment_tissue(half, segmentation=np.zeros((512, 512)))
    seg = mm.segment_breast(half[::2, ::2], levels=1, n_init=4)
    with pytest.raises(ValueError, match="CAR features"):
        mm.segment_tissue(half[::2, ::2], segmentation=seg)
    seg = mm.segment_breast(half[::2, ::2], levels=1, n_init=4, keep_features=True)
    with pytest.raises(ValueError, match="mammogram is"):
        mm.segment_tissue(half, segmentation=seg)
    with pytest.raises(ValueError, match="levels"):
        mm.segment_tissue(half, levels=0)
    with pytest.raises(ValueError, match="at least 3"):  # the model's resolutions
        mm.segment_tissue(half, levels=2)
    small = half[::2, ::2]
    seg = mm.segment_breast(small, levels=1, n_init=4, keep_features=True)
    with pytest.raises(ValueError, match="fewer than 3"):
        mm.segment_tissue(small, segmentation=seg)
    with pytest.raises(TypeError, match="pool"):
        mm.segment_tissue(half, pool="8")
    with pytest.raises(ValueError, match="breast"):
        mm.segment_tissue(half, breast=np.zeros((512, 512), bool))


def test_shipped_model_has_its_provenance():
    with open(_tissue._MODEL_FILE) as fh:
        spec = json.load(fh)
    assert {"made_by", "date", "data", "fit", "cross_validation"} <= set(spec)
    assert "bench_tissue.py" in spec["made_by"]
    assert tuple(spec["segment"]["descriptors"]) == mm._tissue.SEGMENT_DESCRIPTORS
    assert sorted(spec["tissue"]["classes"]) == sorted(mm.TISSUE_CLASSES)
    cv = spec["cross_validation"]
    assert {"ddsm_tissue", "mini_mias"} <= set(cv)
    # the spatial model, when shipped, makes the mask; else the pixel model, when shipped;
    # each says how it was chosen
    threshold = _tissue.shipped_tissue_model().threshold
    if "spatial" in spec:
        assert threshold == spec["spatial"]["threshold"]
        assert "train_tissue_unet.py" in spec["spatial"]["made_by"]
    if "pixel" in spec:
        assert set(spec["pixel"]["descriptors"]) <= set(mm._tissue.PIXEL_DESCRIPTORS)
        assert "spatial" in spec or threshold == spec["pixel"]["threshold"]
        assert "pixel trees, nested choice (CAR)" in cv["ddsm_tissue"]


def test_tree_evaluator_against_scikit_learn():
    """Our boosted-tree evaluation (the pixel model's and the ROI model's)
    against scikit-learn's predict_proba on a small fitted model."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    from car_napari.mammography._trees import TreeEnsemble, exported_trees

    rng = np.random.default_rng(5)
    X = rng.standard_normal((600, 3))
    y = X[:, 0] + 0.5 * X[:, 1] ** 2 + 0.3 * rng.standard_normal(600) > 0.4
    clf = HistGradientBoostingClassifier(max_iter=20, max_leaf_nodes=7,
                                         random_state=0).fit(X, y)
    baseline, trees = exported_trees(clf)
    test = rng.standard_normal((300, 3))
    raw = TreeEnsemble(baseline, trees).log_odds(test)
    np.testing.assert_allclose(1 / (1 + np.exp(-raw)), clf.predict_proba(test)[:, 1],
                               rtol=0, atol=1e-12)
    # the pixel model reads its own descriptor columns out of the full rows
    names = ["grey_flat", "skin", "segment_probability"]
    model = _tissue.PixelModel({"descriptors": names, "baseline": baseline, "trees": trees,
                                "threshold": 0.4})
    full = np.zeros((300, len(mm._tissue.PIXEL_DESCRIPTORS)))
    full[:, [mm._tissue.PIXEL_DESCRIPTORS.index(n) for n in names]] = test
    np.testing.assert_allclose(model.probability(full), clf.predict_proba(test)[:, 1],
                               rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="unknown pixel descriptors"):
        _tissue.PixelModel({"descriptors": ["nope"], "baseline": 0.0, "trees": trees,
                            "threshold": 0.5})


def test_pixel_rows_against_direct_computations(half):
    """Each working pixel's descriptors: its flattened grey, place, CAR
    features and segment probability as computed here, and the context means
    as Gaussian-weighted sums over the breast written out pixel by pixel."""
    seg = mm.segment_breast(half, pool=mm.DEFAULT_POOL_SEGMENTS, keep_features=True)
    grey = half / 255.0
    work = _tissue._working(grey, seg)
    b = work.breast
    z, _ = _tissue._standardised(work.features, b)
    places = _tissue._places(b)
    seg_prob = np.random.default_rng(6).random(b.shape).astype(np.float32)
    rows = _tissue._pixel_rows(work, z, places, seg_prob)
    names = mm._tissue.PIXEL_DESCRIPTORS
    assert rows.shape == (b.sum(), len(names)) and rows.dtype == np.float32
    flat = _tissue._flattened(work.grey[b], places[0])
    np.testing.assert_allclose(rows[:, 0], flat, rtol=1e-6, atol=1e-6)
    for k, name in enumerate(("skin", "chest", "height")):
        np.testing.assert_allclose(rows[:, names.index(name)], places[k], rtol=1e-6)
    car_cols = [names.index(n) for n in mm._tissue.CAR_SEGMENT_DESCRIPTORS]
    np.testing.assert_allclose(rows[:, car_cols], z, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(rows[:, -1], seg_prob[b])
    # the grey level against the whole breast's, pixel by pixel
    g = work.grey[b].astype(np.float64)
    sd = g.std()
    otsu = threshold_otsu(g, nbins=256)
    p10, p90 = np.percentile(g, 10), np.percentile(g, 90)
    picks = np.random.default_rng(7).choice(g.size, 200, replace=False)
    for i in picks:
        want = [np.count_nonzero(g < g[i]) / g.size, (g[i] - g.mean()) / sd,
                (g[i] - otsu) / sd, (g[i] - p10) / (p90 - p10)]
        got = [rows[i, names.index(n)] for n in mm._tissue.BREAST_GREY_PIXEL_DESCRIPTORS]
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    # context means away from the image's edge (scipy's kernel: radius 4 sigma)
    flat_map = np.zeros(b.shape)
    flat_map[b] = flat
    rr, cc = np.nonzero(b)
    for sigma in (2, 6):
        r = int(4 * sigma + 0.5)
        inside = np.flatnonzero((rr >= r) & (rr < b.shape[0] - r) & (cc >= r)
                                & (cc < b.shape[1] - r))[::997]
        d = np.arange(-r, r + 1)
        w = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2.0 * sigma**2))
        got = rows[inside, names.index(f"grey_flat_mean_{sigma}")]
        for i, value in zip(inside, got, strict=True):
            win = (slice(rr[i] - r, rr[i] + r + 1), slice(cc[i] - r, cc[i] + r + 1))
            want = (w * flat_map[win]).sum() / (w * b[win]).sum()
            assert value == pytest.approx(want, rel=1e-4, abs=1e-4)


def test_shipped_mask_is_its_probability_over_threshold(half, job):
    """The mask is the working probability over the shipped model's
    threshold, block-upsampled onto the breast."""
    tissue, _ = job
    model = _tissue.shipped_tissue_model()
    seg = mm.segment_breast(half, pool=mm.DEFAULT_POOL_SEGMENTS, keep_features=True)
    want = _tissue._full_mask(tissue.probability > model.threshold, seg, half.shape)
    np.testing.assert_array_equal(tissue.fibroglandular, want)
    assert tissue.density == pytest.approx(100.0 * want.sum() / seg.breast.sum())


def test_image_row_against_direct_computations():
    """Each breast descriptor (:data:`IMAGE_DESCRIPTORS`) by name, computed
    here pixel list by pixel list from a small random breast."""
    rng = np.random.default_rng(7)
    h, w = 40, 30
    breast = np.zeros((h, w), bool)
    breast[3:37, 2:25] = True
    grey = rng.random((h, w))
    prob = np.where(breast, rng.random((h, w)), 0.0).astype(np.float32)
    n = int(breast.sum())
    vals = rng.standard_normal((n, 15))
    work = _tissue._Working(grey, np.zeros((1, h, w), np.int32), breast, None)
    row = _tissue._image_row(work, vals, prob, 0.4)
    names = mm._tissue.IMAGE_DESCRIPTORS
    assert row.shape == (len(names),)
    got = dict(zip(names, row, strict=True))
    g, p = grey[breast], prob[breast]
    fg = p > 0.4
    assert got["density"] == pytest.approx(fg.sum() / n)
    assert got["fg_contrast"] == pytest.approx((g[fg].mean() - g[~fg].mean()) / g.std())
    assert got["probability_mean"] == pytest.approx(p.mean())
    assert got["probability_above_75"] == pytest.approx(np.mean(p > 0.75))
    for m in range(3):
        energy = vals[:, 12 + m]
        assert got[f"energy_mean_{m}"] == pytest.approx(energy.mean())
        assert got[f"energy_q25_{m}"] == pytest.approx(np.percentile(energy, 25))
        assert got[f"energy_fg_minus_fat_{m}"] == pytest.approx(
            energy[fg].mean() - energy[~fg].mean())
        for k in range(4):
            assert got[f"param{k}_q90_{m}"] == pytest.approx(np.percentile(vals[:, 4 * m + k], 90))
    # the darker quarter: the sorted greys up to numpy's 25th percentile
    # (linear interpolation; random greys have no ties)
    fat = np.sort(g)[: int(np.floor(0.25 * (n - 1))) + 1].mean()
    assert got["fat_reference"] == pytest.approx(fat)
    assert got["above_fat_q50"] == pytest.approx(np.median(g) - fat)
    assert got["above_fat_15"] == pytest.approx(np.mean(g > fat + 0.15))
    assert got["grey_p75"] == pytest.approx(np.percentile(g, 75))


@pytest.mark.parametrize("classifier", ["multinomial", "ordinal logistic", "ordinal trees"])
def test_class_model_against_scikit_learn(classifier):
    """The class probabilities of every kind of class model as scikit-learn
    computes them (the multinomial softmax; the ordinal steps' differences)."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression

    from car_napari.mammography._trees import exported_trees

    rng = np.random.default_rng(8)
    names = ["density", "grey_mean", "energy_q50_1"]
    rows = rng.standard_normal((150, len(mm._tissue.IMAGE_DESCRIPTORS)))
    cols = [mm._tissue.IMAGE_DESCRIPTORS.index(n) for n in names]
    X = rows[:, cols]
    index = np.digitize(X[:, 0] + 0.5 * X[:, 1] + 0.3 * rng.standard_normal(150), [-0.5, 0.5])
    y = np.array(["F", "G", "D"])[index]
    mean, scale = X.mean(axis=0), X.std(axis=0)
    z = (X - mean) / scale
    terms = {"descriptors": names, "mean": mean.tolist(), "scale": scale.tolist()}
    if classifier == "multinomial":
        lr = LogisticRegression(max_iter=1000).fit(z, y)
        spec = {**terms, "classes": list(lr.classes_), "coef": lr.coef_.tolist(),
                "intercept": lr.intercept_.tolist()}
        want = lr.predict_proba(z)[:, [list(lr.classes_).index(c) for c in "FGD"]]
    else:
        steps, above = [], []
        for step in (1, 2):
            if classifier == "ordinal logistic":
                lr = LogisticRegression(max_iter=1000).fit(z, index >= step)
                steps.append({"mean": mean.tolist(), "scale": scale.tolist(),
                              "coef": lr.coef_[0].tolist(), "intercept": float(lr.intercept_[0])})
                above.append(lr.predict_proba(z)[:, 1])
            else:
                clf = HistGradientBoostingClassifier(max_iter=30, max_leaf_nodes=4,
                                                     random_state=0).fit(X, index >= step)
                baseline, trees = exported_trees(clf)
                steps.append({"baseline": baseline, "trees": trees})
                above.append(clf.predict_proba(X)[:, 1])
        spec = {"descriptors": names, "kind": "ordinal", "steps": steps}
        a, g = above
        want = np.column_stack([1 - a, np.clip(a - g, 0, None), g])
        want /= want.sum(axis=1, keepdims=True)
    model = _tissue.ClassModel(spec)
    np.testing.assert_allclose(model.probabilities(rows), want, rtol=0, atol=1e-12)
    tissue_model = _tissue.TissueModel({**_tissue.shipped_tissue_model().spec, "tissue": spec})
    got = tissue_model.class_probabilities(rows[0])
    assert list(got) == ["F", "G", "D"]
    np.testing.assert_allclose(list(got.values()), want[0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="unknown descriptors"):
        _tissue.ClassModel({**spec, "descriptors": ["nope"]})
    with pytest.raises(ValueError, match="unknown kind"):
        _tissue.ClassModel({**spec, "kind": "nope"})


def test_class_is_the_shipped_class_model_of_the_breast_row(half, job):
    """segment_tissue's class probabilities are the shipped class model's of
    the breast's descriptor row (as the benchmark computes it: the working
    probability map and the model's threshold, the full-resolution density)."""
    tissue, _ = job
    model = _tissue.shipped_tissue_model()
    seg = mm.segment_breast(half, pool=mm.DEFAULT_POOL_SEGMENTS, keep_features=True)
    work = _tissue._working(half / 255.0, seg)
    _, vals = _tissue._standardised(work.features, work.breast)
    row = _tissue._image_row(work, vals, tissue.probability, model.threshold)
    row[0] = tissue.density / 100.0
    want = model.tissue.probabilities(row[None])[0]
    np.testing.assert_allclose([tissue.probabilities[c] for c in "FGD"], want, rtol=0,
                               atol=1e-12)


def _density_benchmark():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_density_cbis.py"
    spec = importlib.util.spec_from_file_location("bench_density_cbis_under_test", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_cbis_density_labels_name_the_shared_films(shared_data):
    """benchmarks/data/cbis_ddsm_density.csv: one BI-RADS density (1-4) for
    each film of cbis-ddsm-masses, and one per patient (the two breasts and
    views of a woman share it in CBIS-DDSM)."""
    import csv
    from pathlib import Path

    labels = Path(__file__).resolve().parents[2] / "benchmarks" / "data" / "cbis_ddsm_density.csv"
    with open(labels) as fh:
        rows = list(csv.DictReader(fh))
    films = sorted(p.name for p in (shared_data / "mammograms" / "cbis-ddsm-masses").glob("*.jpg"))
    assert sorted(r["file"] for r in rows) == films and len(films) == 1231
    assert {r["breast_density"] for r in rows} == {"1", "2", "3", "4"}
    per_patient = {}
    for r in rows:
        per_patient.setdefault(r["file"].split("_")[0], set()).add(r["breast_density"])
    assert all(len(d) == 1 for d in per_patient.values())


def test_density_benchmark_describes_films_as_segment_tissue(shared_data, monkeypatch):
    """The rows bench_density_cbis.py evaluates are segment_tissue's: its
    density, and the shipped class model's probabilities of the row."""
    monkeypatch.setenv("CAR_NAPARI_MAMMOGRAMS", str(shared_data / "mammograms"))
    bench = _density_benchmark()
    path = shared_data / "mammograms" / "cbis-ddsm-masses" / "00001_LEFT_CC.jpg"
    row = bench.image_row(path)
    tissue = mm.segment_tissue(io.imread(path))
    assert row[0] * 100.0 == pytest.approx(tissue.density, abs=1e-9)
    probabilities = _tissue.shipped_tissue_model().class_probabilities(row)
    for c in _tissue.TISSUE_CLASSES:
        assert probabilities[c] == pytest.approx(tissue.probabilities[c], abs=1e-12)


def test_standardised_flattened_and_places_against_their_definitions():
    """The pixel descriptors' pieces written out from their docstrings:
    ``_standardised`` the first three levels' four CAR parameters, then
    their energies (8 values a level), over the breast less their mean over
    their standard deviation (a constant one: 0); ``_flattened`` the grey
    less the median grey of its band of distance from the skin (16 bands
    between the linear-interpolation quantiles), over the grey's standard
    deviation; ``_places`` on a half disc against either chest wall: the
    distance to the nearest pixel out of the breast (the breast continued
    beyond the chest wall, which is not skin) over its largest, the
    distance from the chest-wall column over the breast's width in
    columns, and the distance off the middle row over half the height."""
    rng = np.random.default_rng(8)
    H, W = 41, 37
    rr, cc = np.mgrid[:H, :W]
    for side in ("left", "right"):
        breast = ((rr - 20) ** 2 + cc**2 <= 30**2) & (rr >= 3) & (rr < 36)
        breast = breast if side == "left" else breast[:, ::-1]
        # standardised
        features = rng.normal(size=(H, W, 32)).astype(np.float32)
        features[..., 12] = 2.5  # level 1's energy: constant
        z, raw = _tissue._standardised(features, breast)
        cols = [0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 4, 12, 20]
        values = np.array([[float(features[i, j, c]) for c in cols]
                           for i, j in zip(*np.nonzero(breast), strict=True)])
        np.testing.assert_array_equal(raw, values)
        for k in range(len(cols)):
            v = values[:, k]
            mu = sum(v) / len(v)
            sd = (sum((v - mu) ** 2) / len(v)) ** 0.5
            want = np.zeros(len(v)) if sd == 0 else (v - mu) / sd
            np.testing.assert_allclose(z[:, k], want, rtol=1e-9, atol=1e-12)
        # places
        skin, chest, height = _tissue._places(breast)
        bi, bj = np.nonzero(breast)
        wall = 0 if side == "left" else W - 1
        out = [(i, j) for i in range(H) for j in range(W) if not breast[i, j]]
        out += [(i, wall - 1 if side == "left" else wall + 1) for i in range(H)
                if not breast[i, wall]]
        oi, oj = np.array(out).T
        d = np.sqrt((bi[:, None] - oi[None]) ** 2 + (bj[:, None] - oj[None]) ** 2).min(axis=1)
        np.testing.assert_allclose(skin, d / d.max(), rtol=1e-12)
        width = bj.max() - bj.min() + 1
        from_wall = bj - bj.min() if side == "left" else bj.max() - bj
        np.testing.assert_allclose(chest, from_wall / width, rtol=1e-12)
        middle, half = (bi.min() + bi.max()) / 2, (bi.max() - bi.min() + 1) / 2
        np.testing.assert_allclose(height, np.abs(bi - middle) / half, rtol=1e-12)
    # flattened
    skin = rng.random(3000)
    g = 0.3 * skin + rng.normal(0, 0.1, 3000)
    s = np.sort(skin)
    edges = []
    for k in range(1, 16):
        at = (len(s) - 1) * k / 16
        lo = int(at)
        edges.append(s[lo] + (at - lo) * (s[lo + 1] - s[lo]))
    band = np.array([sum(e < v for e in edges) for v in skin])
    sd = (np.mean((g - g.mean()) ** 2)) ** 0.5
    want = [(g[n] - np.median(g[band == band[n]])) / sd for n in range(len(g))]
    np.testing.assert_allclose(_tissue._flattened(g, skin), want, rtol=1e-10, atol=1e-12)
