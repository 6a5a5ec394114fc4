"""Mammograms: breast area, regions of interest (section 14.4.1,
docs/mammography.md), DICOM reading."""

import sys

import numpy as np
import pytest
from skimage import io

from car_napari import Progress
from car_napari import mammography as mm
from car_napari._progress import drain
from car_napari.io.sample_data import resource_path
from car_napari.mammography import detect_breast, detect_mammogram_rois
from dicom_files import write_dicom as _write_dicom

# mdb001's ground-truth mass (mini-MIAS): centre (col 535, row 599), radius 197
MASS_ROW, MASS_COL, MASS_RADIUS = 599, 535, 197


@pytest.fixture(scope="module")
def sample():
    return io.imread(str(resource_path("mammogram_mdb001.png")))


@pytest.fixture(scope="module")
def rois(sample):
    """ROIs of the sample downsampled by 2 (512x512) at the default operating
    point: one run for the tests."""
    half = sample.reshape(512, 2, 512, 2).mean(axis=(1, 3)).astype(np.uint8)
    records = []
    result = drain(mm.iter_detect_mammogram_rois(half), records.append)
    assert isinstance(result, mm.MammogramROIs)
    labels, table = result
    return half, labels, table, records


@pytest.fixture(scope="module")
def every_finding(rois):
    """The same image with every finding kept (``marks_per_image=None``)."""
    return mm.detect_mammogram_rois(rois[0], marks_per_image=None)


# --- breast area ---------------------------------------------------------------


def test_breast_of_the_sample(sample):
    mask, details = detect_breast(sample, return_details=True)
    assert mask.shape == sample.shape and mask.dtype == bool
    assert details["side"] == "right"  # mdb001: chest wall on the right
    # the mass and the bulk of the tissue are inside, background corners are not
    assert mask[MASS_ROW, MASS_COL]
    assert not mask[:40, :40].any() and not mask[-40:, :40].any()
    assert sample[mask].mean() > 3 * sample[~mask].mean()
    # the pectoral muscle (bright triangle at the top right) is removed
    pect = details["pectoral"]
    assert pect.sum() > 0.02 * mask.sum() and not (pect & mask).any()
    assert not mask[30, 700] and pect[30, 700]
    assert not mask[:15].any()  # the border band (1.5 % of the long side)
    assert mask[700, 700]
    # nearly all clearly bright pixels other than the muscle are breast
    bright = (sample > 0.3 * sample.max()) & ~pect
    assert (bright & mask).sum() > 0.95 * bright.sum()


def test_every_mass_centre_is_inside(shared_data):
    import csv

    folder = shared_data / "mammograms" / "mini-mias"
    with open(folder / "ground_truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    masses = [r for r in rows if r["class"] in ("CIRC", "SPIC", "MISC") and r["col"]]
    inside = 0
    for r in masses:
        mask = detect_breast(io.imread(folder / f"{r['refnum']}.png"))
        inside += bool(mask[int(r["row"]), int(r["col"])])
    assert inside == len(masses)


def test_breast_is_fast(sample):
    import time

    detect_breast(sample)
    t = time.perf_counter()
    detect_breast(sample)
    assert time.perf_counter() - t < 1.0


@pytest.mark.parametrize("image", [np.zeros((64, 64), np.uint8), np.full((64, 64), 200, np.uint8)])
def test_constant_mammogram_is_a_clear_error(image):
    with pytest.raises(ValueError, match="constant"):
        detect_breast(image)
    with pytest.raises(ValueError, match="constant"):
        detect_mammogram_rois(image)


# --- regions of interest ---------------------------------------------------------


def test_rois_shape_and_table(rois):
    half, labels, table, _ = rois
    assert labels.shape == half.shape and labels.dtype == np.int32
    n = int(labels.max())
    assert n >= 1
    assert set(table) == set(mm.TABLE_COLUMNS)
    assert all(len(v) == n for v in table.values())
    np.testing.assert_array_equal(table["label"], np.arange(1, n + 1))
    assert np.all(np.diff(table["score"]) <= 0)  # best first
    breast = detect_breast(half)
    assert not labels[~breast].any()
    for i in range(n):
        region = labels == table["label"][i]
        assert region.sum() == table["area"][i]
        np.testing.assert_allclose(half[region].mean() / 255.0, table["mean_grey"][i], rtol=1e-9)
        assert table["score"][i] >= mm.score_threshold(mm.DEFAULT_MARKS_PER_IMAGE)
        rows, cols = np.nonzero(region)
        assert (rows.min(), cols.min()) == (table["bbox_min_row"][i], table["bbox_min_col"][i])
        assert (rows.max() + 1, cols.max() + 1) == (table["bbox_max_row"][i],
                                                    table["bbox_max_col"][i])
        np.testing.assert_allclose([rows.mean(), cols.mean()],
                                   [table["centroid_row"][i], table["centroid_col"][i]])


def test_mass_of_mdb001_is_detected(rois):
    _, labels, table, _ = rois
    row, col, radius = MASS_ROW / 2, MASS_COL / 2, MASS_RADIUS / 2
    near = np.hypot(table["centroid_row"] - row, table["centroid_col"] - col) <= radius
    assert near.any() or labels[int(row), int(col)] > 0


def test_filter_regions_on_a_synthetic_segmentation():
    image = np.full((200, 200), 0.3)
    segments = np.ones((200, 200), np.int32)
    image[50:90, 50:90], segments[50:90, 50:90] = 0.66, 2  # a bright "mass"
    image[120:160, 120:160], segments[120:160, 120:160] = 0.95, 3  # too bright
    rois = mm.filter_regions(image, segments, reference=0.66, tolerance=0.1, max_regions=None)
    assert isinstance(rois, mm.MammogramROIs)
    labels, table = rois
    # the one-pixel opening of the candidates takes the block's 4 corners
    assert labels.max() == 1 and table["area"].tolist() == [1596]
    assert table["centroid_row"][0] == pytest.approx(69.5)
    assert table["contrast"][0] == pytest.approx(0.36, abs=0.005)
    # pooled labellings: the same block found twice is kept once
    labels2, table2 = mm.filter_regions(image, [segments, segments], reference=0.66,
                                        tolerance=0.1, max_regions=None)
    assert labels2.max() == 1 and table2["area"].tolist() == [1596]
    with pytest.raises(ValueError, match="tolerance"):
        mm.filter_regions(image, segments, tolerance=0)


def test_iter_yields_progress_then_returns_the_rois(rois):
    half, labels, _, records = rois
    assert all(isinstance(r, Progress) for r in records) and len(records) > 3
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    stages = [r.stage for r in records]
    assert stages[0] == "breast" and stages[-1] == "regions"
    assert {"features", "mixture", "merging"} <= set(stages)
    n = labels.max()
    assert records[-1].message == f"{n} region{'' if n == 1 else 's'}"


def test_closing_the_job_early_stops_it(sample):
    job = mm.iter_detect_mammogram_rois(sample)
    assert next(job).stage == "breast"
    job.close()
    assert list(job) == []


def test_colour_export_is_read_as_its_luminance(sample):
    rgb = np.stack([sample] * 3, axis=-1)
    np.testing.assert_array_equal(detect_breast(rgb), detect_breast(sample))
    np.testing.assert_array_equal(detect_breast(np.moveaxis(rgb, -1, 0), channel_axis=0),
                                  detect_breast(sample))
    with pytest.raises(ValueError, match="3-D"):
        detect_breast(rgb, channel_axis=None)
    with pytest.raises(ValueError, match="2 channels"):
        detect_breast(rgb[..., :2])


def test_segment_breast_pools_one_history(sample):
    small = sample[::8, ::8]
    records = []
    seg = drain(mm.iter_segment_breast(small, levels=1, n_init=8, pool=(2, 4)), records.append)
    assert isinstance(seg, mm.BreastSegmentation) and seg.factor == 1
    assert records[0].stage == "breast" and records[-1].fraction <= 1.0
    np.testing.assert_array_equal(seg.breast, detect_breast(small))
    assert not seg.segments[~seg.breast].any() and seg.segments[seg.breast].min() >= 1
    assert [len(np.unique(p[seg.breast])) for p in seg.pooled] == [2, 4]
    again = mm.segment_breast(small, levels=1, n_init=8, n_segments=3)
    assert again.pooled is None and again.segments.max() <= 3


def _matched_ious(a, b):
    """For every region of labels ``a``, its best IoU with a region of ``b``."""
    out = []
    for i in range(1, int(a.max()) + 1):
        m = a == i
        ious = [(m & (b == j)).sum() / (m | (b == j)).sum() for j in range(1, int(b.max()) + 1)]
        out.append(max(ious, default=0.0))
    return out


@pytest.fixture(scope="module")
def stability(sample):
    """ROIs of mdb001 as uint8, as float in [0, 1] and with +-1e-4 noise
    (issue 12, defect l: the DICOM and the PNG of one mammogram differ so)."""
    noise = np.random.default_rng(12).uniform(-1e-4, 1e-4, sample.shape)
    inputs = {"uint8": sample, "float": sample / 255.0,
              "noise": np.clip(sample / 255.0 + noise, 0.0, 1.0)}
    return {name: detect_mammogram_rois(image) for name, image in inputs.items()}


@pytest.mark.parametrize("variant", ["float", "noise"])
def test_rois_do_not_follow_quantisation_or_tiny_noise(stability, variant):
    labels, table = stability["uint8"]
    other, other_table = stability[variant]
    assert len(other_table["label"]) == len(table["label"]) >= 1
    assert min(_matched_ious(labels, other)) >= 0.9
    assert min(_matched_ious(other, labels)) >= 0.9


def test_an_8_bit_image_carried_in_floats_is_read_as_it(sample):
    """The cause of defect l: the segmentation's EM and greedy KL merging
    amplify any difference, and the ROIs followed. A mammogram within a tenth
    of a grey level of an 8-bit image (a PNG read as float, a DICOM made from
    one, float32, noise of 1e-4) is read as that 8-bit image."""
    from car_napari.mammography._images import _grey01

    exact = sample / 255.0
    rng = np.random.default_rng(0)
    for variant in (exact, exact.astype(np.float32), sample.astype(np.uint16) * 257,
                    np.clip(exact + rng.uniform(-3e-4, 3e-4, sample.shape), 0, 1)):
        np.testing.assert_array_equal(_grey01(variant), exact)
    # so is its 12-bit copy; a true 12-bit or a continuous image is left as it is
    np.testing.assert_array_equal(_grey01(np.round(exact * 4095) / 4095), exact)
    twelve = rng.integers(0, 4096, (256, 256)) / 4095
    np.testing.assert_array_equal(_grey01(twelve), twelve)
    smooth = rng.random((256, 256))
    np.testing.assert_array_equal(_grey01(smooth), smooth)


def test_near_ties_of_one_finding_make_one_region():
    """Two candidates of one finding (each holds the other's centroid) with
    nearly the same score are one region, their union, whichever ranks
    first: a near tie no longer decides the region's shape."""
    from car_napari.mammography._regions import _select

    cc = np.zeros((40, 40), np.int32)
    cc[5:25, 5:25] = 1
    other = np.zeros((40, 40), np.int32)
    other[15:30, 15:30] = 1
    a = (0.0205, 0.07, cc, 1, (0, 40, 0, 40), 15, 15)
    b = (0.0204, 0.04, other, 1, (0, 40, 0, 40), 22, 22)
    for rows in ([a, b], [b, a]):
        (score, _, mask), = _select(rows, max_regions=1)
        np.testing.assert_array_equal(mask, (cc == 1) | (other == 1))
    # far apart in score: the better one alone
    weak = (0.01, 0.04, other, 1, (0, 40, 0, 40), 22, 22)
    (_, _, mask), = _select([a, weak], max_regions=None)
    np.testing.assert_array_equal(mask, cc == 1)


def test_the_job_yields_while_it_reads_a_large_mammogram(sample):
    """A 4096x4096 mammogram is converted in strips, with a record after each
    (so that a Cancel is seen soon), to the same values."""
    from car_napari.mammography._images import _grey01, _iter_grey

    big = np.kron(sample, np.ones((2, 2), np.uint8))
    records = []
    grey = drain(_iter_grey(big, None), records.append)
    assert len(records) >= 4 and {r.stage for r in records} == {"reading"}
    np.testing.assert_array_equal(grey, _grey01(big))
    with pytest.raises(ValueError, match="NaN"):
        bad = big / 255.0
        bad[-1, -1] = np.nan
        drain(_iter_grey(bad, None))


# --- DICOM ----------------------------------------------------------------------




RAMP = np.tile(np.linspace(0, 4095, 64).round().astype(np.uint16), (8, 1))


@pytest.mark.parametrize("photometric", ["MONOCHROME2", "MONOCHROME1"])
def test_dicom_rescale_and_window(tmp_path, photometric):
    pytest.importorskip("pydicom")
    from car_napari.io.dicom import read_dicom

    # value = 2 s - 100; window [3000, 5000] in rescaled units
    path = _write_dicom(tmp_path / "w.dcm", RAMP, photometric, RescaleSlope=2,
                        RescaleIntercept=-100, WindowCenter=4000, WindowWidth=2000)
    image, meta = read_dicom(path)
    expect = np.clip((2.0 * RAMP - 100 - 3999.5) / 1999 + 0.5, 0, 1)
    if photometric == "MONOCHROME1":
        expect = 1 - expect
    np.testing.assert_allclose(image, expect, atol=1e-6)
    assert image.dtype == np.float32
    assert meta["applied"][:2] == ["modality rescale", "VOI window"]


@pytest.mark.parametrize("photometric", ["MONOCHROME2", "MONOCHROME1"])
def test_dicom_plain_and_rescale_only(tmp_path, photometric):
    pytest.importorskip("pydicom")
    from car_napari.io.dicom import read_dicom

    flip = (lambda x: 1 - x) if photometric == "MONOCHROME1" else (lambda x: x)
    image, meta = read_dicom(_write_dicom(tmp_path / "p.dcm", RAMP, photometric))
    np.testing.assert_allclose(image, flip(RAMP / 4095.0), atol=1e-6)
    image, meta = read_dicom(_write_dicom(tmp_path / "r.dcm", RAMP, photometric,
                                          RescaleSlope=0.5, RescaleIntercept=10))
    np.testing.assert_allclose(image, flip(RAMP / 4095.0), atol=1e-6)
    assert "modality rescale" in meta["applied"]


def test_dicom_voi_lut(tmp_path):
    pytest.importorskip("pydicom")
    from pydicom.dataset import Dataset

    from car_napari.io.dicom import read_dicom

    item = Dataset()
    item.add_new((0x0028, 0x3002), "US", [4096, 0, 16])  # LUT Descriptor: 16-bit output
    lut = np.minimum(np.arange(4096) * 32, 65535)  # a steeper display curve, clipped
    item.add_new((0x0028, 0x3006), "US", lut.tolist())  # LUT Data
    path = _write_dicom(tmp_path / "l.dcm", RAMP, VOILUTSequence=[item])
    image, meta = read_dicom(path)
    assert "VOI LUT" in meta["applied"]
    np.testing.assert_allclose(image, lut[RAMP] / 65535.0, atol=1e-6)


def test_dicom_reader_layer_data(tmp_path):
    pytest.importorskip("pydicom")
    from car_napari.io.dicom import dicom_reader, get_reader

    path = _write_dicom(tmp_path / "n.dcm", RAMP, PixelSpacing=[0.2, 0.1])
    assert get_reader(str(tmp_path / "x.png")) is None
    assert get_reader(path) is dicom_reader
    (data, kwargs, kind), = dicom_reader(path)
    assert kind == "image" and data.shape == RAMP.shape and kwargs["scale"] == (0.2, 0.1)


def test_dicom_without_pydicom_is_a_clear_error(monkeypatch, tmp_path):
    from car_napari.io.dicom import read_dicom

    monkeypatch.setitem(sys.modules, "pydicom", None)
    with pytest.raises(ImportError, match="pip install pydicom"):
        read_dicom(tmp_path / "missing.dcm")


@pytest.mark.parametrize("shape", [(3, 2000), (2000, 3), (30, 2000)])
def test_thin_image_is_a_clear_error(shape):
    image = np.random.default_rng(0).random(shape)
    with pytest.raises(ValueError, match="too thin for breast detection"):
        detect_mammogram_rois(image)
    with pytest.raises(ValueError, match="too thin"):
        detect_breast(image)


@pytest.mark.parametrize("option, value, error", [
    ("marks_per_image", 0.0, ValueError), ("marks_per_image", np.nan, ValueError),
    ("marks_per_image", "2", TypeError),
    ("reference", np.nan, ValueError), ("reference", 2.5, ValueError),
    ("tolerance", np.inf, ValueError), ("tolerance", 0.0, ValueError),
    ("max_regions", np.inf, ValueError), ("max_regions", 2.5, ValueError),
    ("min_area", -1, ValueError), ("min_area", "a", TypeError),
    ("levels", 10**9, ValueError), ("work_side", 0, ValueError), ("seed", -1, ValueError),
])
def test_options_are_checked_before_any_work(option, value, error):
    image = np.zeros((4096, 4096), np.uint8)  # would take seconds to read: not read at all
    job = mm.iter_detect_mammogram_rois(image, **{option: value})
    with pytest.raises(error, match=option):
        next(job)


# --- scoring, operating points (issue 17) ---------------------------------------


def test_every_finding_carries_its_score_and_cuts_to_the_operating_point(rois, every_finding):
    """The result with every finding, cut at the default operating point, is
    the default result: same regions, same numbers, no recomputation."""
    half, labels, table, _ = rois
    all_labels, all_table = every_finding
    n = len(all_table["label"])
    assert n > len(table["label"]) >= 1
    assert np.all(np.diff(all_table["score"]) <= 0)
    assert np.all((all_table["score"] > 0) & (all_table["score"] < 1))
    cut_labels, cut = mm.select_marks(every_finding, mm.DEFAULT_MARKS_PER_IMAGE)
    np.testing.assert_array_equal(cut_labels, labels)
    for k in mm.TABLE_COLUMNS:
        np.testing.assert_array_equal(cut[k], table[k])
    # more marks per image: a lower threshold, at least as many marks
    assert mm.score_threshold(1.0) >= mm.score_threshold(2.0) >= mm.score_threshold(3.0)
    counts = [len(mm.select_marks(every_finding, r).table["label"]) for r in (0.5, 2, 8)]
    assert counts == sorted(counts)


def test_shipped_model_says_how_it_was_made():
    import json

    from car_napari.mammography._candidates import _MODEL_FILE, DESCRIPTORS

    spec = json.loads(_MODEL_FILE.read_text())
    for key in ("made_by", "date", "data", "fit", "descriptors", "operating_points"):
        assert key in spec, key
    assert set(spec["descriptors"]) <= set(DESCRIPTORS)
    if spec.get("kind") == "trees":
        assert spec["trees"] and isinstance(spec["baseline"], float)
    else:
        assert len(spec["mean"]) == len(spec["scale"]) == len(spec["coef"]) == len(
            spec["descriptors"])
    rates = [p["marks_per_image"] for p in spec["operating_points"]]
    thresholds = [p["threshold"] for p in spec["operating_points"]]
    assert rates == sorted(rates) and thresholds == sorted(thresholds, reverse=True)
    assert mm.OPERATING_POINTS[0]["marks_per_image"] == rates[0]


def test_model_score_and_threshold_against_plain_formulas():
    from car_napari.mammography._candidates import DESCRIPTORS, RoiModel

    spec = {"descriptors": ["contrast", "compactness"], "mean": [0.1, 0.5],
            "scale": [0.2, 0.25], "coef": [2.0, -1.0], "intercept": 0.5,
            "operating_points": [{"marks_per_image": 1.0, "threshold": 0.8},
                                 {"marks_per_image": 4.0, "threshold": 0.4}]}
    model = RoiModel(spec)
    X = np.random.default_rng(3).random((6, len(DESCRIPTORS)))
    a, b = DESCRIPTORS.index("contrast"), DESCRIPTORS.index("compactness")
    for row, got in zip(X, model.score(X), strict=True):
        z = 2.0 * (row[a] - 0.1) / 0.2 - 1.0 * (row[b] - 0.5) / 0.25 + 0.5
        assert got == pytest.approx(1.0 / (1.0 + np.e ** -z), rel=1e-12)
    assert model.threshold(1.0) == pytest.approx(0.8)
    assert model.threshold(4.0) == pytest.approx(0.4)
    assert model.threshold(2.0) == pytest.approx(0.6)  # halfway on the log scale
    assert model.threshold(0.1) == pytest.approx(0.8) and model.threshold(99) == 0.4
    with pytest.raises(ValueError, match="unknown descriptors"):
        RoiModel({**spec, "descriptors": ["nope", "contrast"]})


def test_tree_model_against_a_plain_walk_of_its_trees():
    """Boosted trees: the baseline plus each tree's leaf, found by walking the
    nodes one sample at a time in plain Python."""
    from car_napari.mammography._candidates import DESCRIPTORS, RoiModel

    trees = [  # node 0 splits on descriptor 0 ("contrast"), node 1 on 1 ("compactness")
        {"feature": [0, 1, 0, 0, 0], "threshold": [0.5, 0.2, 0, 0, 0],
         "left": [1, 3, 0, 0, 0], "right": [2, 4, 0, 0, 0], "leaf": [0, 0, 1, 1, 1],
         "value": [0, 0, 0.7, -0.3, 0.4]},
        {"feature": [1, 0, 0], "threshold": [0.6, 0, 0], "left": [1, 0, 0],
         "right": [2, 0, 0], "leaf": [0, 1, 1], "value": [0, 0.25, -0.5]},
    ]
    model = RoiModel({"kind": "trees", "descriptors": ["contrast", "compactness"],
                      "baseline": -0.1, "trees": trees, "operating_points": []})
    X = np.random.default_rng(4).random((50, len(DESCRIPTORS)))
    a, b = DESCRIPTORS.index("contrast"), DESCRIPTORS.index("compactness")
    for row, got in zip(X, model.score(X), strict=True):
        total = -0.1
        for t in trees:
            node = 0
            while not t["leaf"][node]:
                value = (row[a], row[b])[t["feature"][node]]
                node = t["left"][node] if value <= t["threshold"][node] else t["right"][node]
            total += t["value"][node]
        assert got == pytest.approx(1.0 / (1.0 + np.exp(-total)), rel=1e-12)


def test_descriptors_of_a_disc_against_direct_measurements():
    """A bright disc (radius 12 analysis pixels) on a two-level background,
    one segment each: the grey, contrast, radius and compactness descriptors
    against NumPy measurements of the disc and its ring."""
    from scipy import ndimage

    from car_napari.mammography._candidates import DESCRIPTORS, _describe, _generate

    h = w = 96
    yy, xx = np.mgrid[:h, :w]
    disc = (yy - 48) ** 2 + (xx - 40) ** 2 <= 12**2
    grey = np.where(xx < 60, 0.4, 0.5) + 0.01 * np.sin(yy / 3.0)
    grey[disc] += 0.2
    seg = np.where(disc, 2, 1).astype(np.int32)
    breast = np.ones((h, w), bool)
    cands = _generate(grey, [seg], breast, split=False, sigmas=(), delta=0.0, min_area=20)
    texture = np.random.default_rng(0).normal(size=(h, w, 24)).astype(np.float32)
    kept, X = drain(_describe(grey, [seg], breast, texture, cands, f=4, side=384))
    j = [k for k, c in enumerate(kept) if abs(c.centroid[0] - 48) < 1][0]
    row = dict(zip(DESCRIPTORS, X[j], strict=True))
    # the candidate is the disc after a one-pixel opening (a 4-connected cross)
    inside = ndimage.binary_opening(disc, ndimage.generate_binary_structure(2, 1))
    width = max(2, round(0.5 * np.sqrt(inside.sum() / np.pi)))
    dist = ndimage.distance_transform_cdt(~inside, metric="taxicab")
    ring = (dist > 0) & (dist <= width)
    assert row["mean_grey"] == pytest.approx(grey[inside].mean())
    assert row["contrast"] == pytest.approx(grey[inside].mean() - grey[ring].mean())
    assert row["grey_std"] == pytest.approx(grey[inside].std())
    radius_1024 = np.sqrt(inside.sum() / np.pi) * 4 * 1024 / 384
    assert row["log_radius"] == pytest.approx(np.log(radius_1024) - np.log(51.0))
    assert row["compactness"] > 0.95
    params = [m * 8 + k for m in range(3) for k in range(4)]
    diff = texture[inside][:, params].mean(0) - texture[ring][:, params].mean(0)
    assert row["param_contrast"] == pytest.approx(np.sqrt(np.mean(diff**2)), rel=1e-5)
    assert row["segment_edge"] == pytest.approx(1.0)  # the ring is all the other segment
    # the breast-relative family: z-scores against the whole breast's features
    energy = [m * 8 + 4 for m in range(3)]
    t64 = texture.astype(np.float64)
    z = (t64[inside].mean(0) - t64.reshape(-1, 24).mean(0)) / (t64.reshape(-1, 24).std(0) + 1e-6)
    assert row["param_breast_z"] == pytest.approx(np.sqrt(np.mean(z[params] ** 2)), rel=1e-4)
    assert row["energy_breast_z"] == pytest.approx(z[energy].mean(), rel=1e-4, abs=1e-6)
    # and ranks among the image's candidates (1 for the largest, or a lone one)
    for src in ("param_contrast", "energy_contrast", "surprise"):
        col = X[:, DESCRIPTORS.index(src)]
        want = (np.ones(1) if len(col) == 1 else
                np.argsort(np.argsort(col, kind="stable"), kind="stable") / (len(col) - 1))
        np.testing.assert_allclose(X[:, DESCRIPTORS.index(src + "_rank")], want)


def test_texture_grid_takes_the_working_pixel_under_each_centre():
    from car_napari.mammography._candidates import _texture_grid

    feats = np.random.default_rng(1).random((30, 20, 2)).astype(np.float32)
    box, factor, f, shape = (5, 35, 3, 23), 2, 4, (20, 16)
    grid = _texture_grid(feats, box, factor, f, shape)
    for i in range(shape[0]):
        for j in range(shape[1]):
            r, c = (i * f + f // 2) // factor - box[0], (j * f + f // 2) // factor - box[2]
            want = feats[r, c] if 0 <= r < 30 and 0 <= c < 20 else np.zeros(2)
            np.testing.assert_array_equal(grid[i, j], want)


def test_merge_keeps_one_finding_per_place_best_first():
    from car_napari.mammography._candidates import Candidate, _merge

    def cand(r0, c0, size):
        return Candidate((r0, r0 + size, c0, c0 + size), np.ones((size, size), bool),
                         (r0 + (size - 1) / 2, c0 + (size - 1) / 2))

    cands = [cand(10, 10, 8), cand(11, 11, 8), cand(40, 40, 6)]
    found = _merge(cands, np.array([0.5, 0.9, 0.7]))
    assert [round(f_[0], 2) for f_ in found] == [0.9, 0.7]
    # the near-equal twin (0.5 is not within 10 % of 0.9) is dropped, not joined
    assert found[0][1].shape == (8, 8) and found[0][3] == 1
    joined = _merge(cands, np.array([0.85, 0.9, 0.7]))
    assert joined[0][1].shape == (9, 9) and joined[0][1].sum() == 64 + 64 - 49


def test_surprise_of_the_ring_model_on_like_and_unlike_candidates():
    """The CAR model of the ring predicts a candidate of the ring's own
    texture about as well as the ring (surprise near 0), a rougher one much
    worse (surprise > 0), and a brighter one with a positive bias."""
    from scipy import ndimage

    from car_napari.mammography._candidates import _surprise

    rng = np.random.default_rng(5)
    h = w = 64
    smooth = ndimage.gaussian_filter(rng.standard_normal((h, w)), 1.5)
    yy, xx = np.mgrid[:h, :w]
    inside = (yy - 32) ** 2 + (xx - 32) ** 2 <= 12**2
    ring = ~inside & ((yy - 32) ** 2 + (xx - 32) ** 2 <= 20**2)
    same = _surprise(0.5 + smooth, inside, ring)
    rough = 0.5 + np.where(inside, 3 * smooth.std() * rng.standard_normal((h, w)), smooth)
    other = _surprise(rough, inside, ring)
    bright = _surprise(0.5 + smooth + np.where(inside, 4 * smooth.std(), 0.0), inside, ring)
    assert abs(same[0]) < 0.5 < other[0]
    assert bright[1] > 0.5 > abs(same[1])
    # too small a ring to fit the model: zeros
    assert _surprise(0.5 + smooth, inside, ring & (yy < 14)) == [0.0, 0.0]
    assert _surprise(0.5 + smooth, inside, ring & (yy < 0)) == [0.0, 0.0]


def test_host_contrast_against_the_rest_of_the_segment():
    """The host of a candidate is its segment less its own pixels: the
    contrast and its z-score against NumPy on that set."""
    from car_napari.mammography._candidates import _host

    rng = np.random.default_rng(2)
    grey = rng.random((40, 50))
    seg = np.where(np.arange(50)[None, :] < 30, 1, 2).repeat(40, axis=0).astype(np.uint8)
    inside = np.zeros_like(seg, bool)
    inside[10:20, 5:15] = True
    sums = [np.bincount(seg.ravel(), weights=w, minlength=3)
            for w in (grey.ravel(), grey.ravel() ** 2, None)]
    got = _host(grey, inside, seg, sums)
    host = (seg == 1) & ~inside
    diff = grey[inside].mean() - grey[host].mean()
    assert got[0] == pytest.approx(diff)
    assert got[1] == pytest.approx(diff / (grey[host].std() + 0.01))
    # a candidate that is its whole segment has no host
    assert _host(grey, seg == 2, seg, sums) == [0.0, 0.0]


def test_visible_drops_findings_mostly_hidden_by_better_ones():
    from car_napari.mammography._candidates import _visible

    a = np.zeros((6, 6), bool)
    a[:4, :4] = True
    b = np.zeros((6, 6), bool)
    b[1:5, 1:5] = True  # 9 of its 16 pixels under a: 7/16 visible
    c = np.zeros((6, 6), bool)
    c[4:, :] = True
    found = [(0.9, a, (0, 6, 0, 6), 0), (0.8, b, (0, 6, 0, 6), 1), (0.7, c, (0, 6, 0, 6), 2)]
    assert [f_[3] for f_ in _visible(found, (6, 6))] == [0, 1, 2]
    kept = _visible(found, (6, 6), min_visible=0.5)
    assert [f_[3] for f_ in kept] == [0, 2]
    # b's 7 visible pixels stay claimed: c keeps 12 - 4 (row 4 under b)
    assert kept[1][1].sum() == 8 and not kept[1][1][4, 1:5].any()


def test_cores_keep_the_bright_connected_part_of_each_finding():
    from scipy import ndimage

    from car_napari.mammography._candidates import _CORE_SIGMA, _cores

    rng = np.random.default_rng(3)
    grey = rng.random((40, 50))
    grey[10:16, 30:36] += 3.0  # a bright blob inside a big finding
    grey[30:33, 5:8] += 2.0  # a second, dimmer blob in it
    mask = np.zeros((36, 46), bool)
    mask[2:34, 2:44] = True
    [(score, core, box, best)] = _cores([(0.5, mask, (2, 38, 2, 48), 7)], grey, 0.9)
    assert (score, box, best) == (0.5, (2, 38, 2, 48), 7)
    # independently: threshold the smoothed image at the mask's 90th percentile,
    # keep the 4-connected part holding the brightest pixel
    smooth = ndimage.gaussian_filter(grey, _CORE_SIGMA)[2:38, 2:48]
    above = mask & (smooth >= np.percentile(smooth[mask], 90))
    seen = np.zeros_like(above)
    stack = [np.unravel_index(np.argmax(np.where(above, smooth, -1)), smooth.shape)]
    while stack:
        r, c = stack.pop()
        if 0 <= r < above.shape[0] and 0 <= c < above.shape[1] and above[r, c] and not seen[r, c]:
            seen[r, c] = True
            stack += [(r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)]
    np.testing.assert_array_equal(core, seen)
    rr, cc = np.nonzero(core)
    assert 8 <= rr.mean() + 2 <= 18 and 28 <= cc.mean() + 2 <= 38


def test_ranks_among_an_images_candidates_against_scipy():
    """``_ranks`` (the within-image rank descriptors): scipy's average ranks
    scaled to [0, 1], ties sharing theirs."""
    from scipy.stats import rankdata

    from car_napari.mammography._candidates import _ranks

    values = np.array([0.3, -1.0, 0.3, 2.0, 0.0, 0.3, 5.0])
    np.testing.assert_allclose(_ranks(values), (rankdata(values) - 1) / (len(values) - 1))
    np.testing.assert_array_equal(_ranks(np.array([4.0])), [1.0])


def test_package_describes_candidates_as_the_froc_benchmark(shared_data, tmp_path, monkeypatch):
    """The package's candidates and descriptors of a CBIS-DDSM film are
    those ``benchmarks/bench_froc.py`` trains the shipped model on: the same
    candidates, the same grey, shape, location and surprise descriptors,
    and the CAR-feature ones up to the benchmark cache's float16 rounding."""
    import importlib.util
    from pathlib import Path

    from car_napari.mammography import _rois
    from car_napari.mammography._candidates import DESCRIPTORS, FAMILIES, shipped_model

    monkeypatch.setenv("CAR_NAPARI_MAMMOGRAMS", str(shared_data / "mammograms"))
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_froc.py"
    spec = importlib.util.spec_from_file_location("bench_froc_under_test", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    ds, name = bench.cbis(), "00001_LEFT_CC"
    (tmp_path / ds.key).mkdir()
    kept_b, X_b, _f, _secs = bench.candidates(ds, name, tmp_path, "car")

    seen = {}
    describe = _rois._describe

    def spy(*args, **kwargs):
        seen["kept"], seen["X"] = yield from describe(*args, **kwargs)
        return seen["kept"], seen["X"]

    monkeypatch.setattr(_rois, "_describe", spy)
    detect_mammogram_rois(ds.read(name), marks_per_image=None)
    assert [c.box for c in seen["kept"]] == [c.box for c in kept_b]
    used = set(shipped_model().names)
    from_features = set(FAMILIES["texture"] + FAMILIES["breast"])
    for j, d in enumerate(DESCRIPTORS):
        if d not in used:
            continue
        if d in from_features:  # the benchmark caches the CAR features as float16
            np.testing.assert_allclose(seen["X"][:, j], X_b[:, j], rtol=0.05, atol=0.05,
                                       err_msg=d)
        else:
            np.testing.assert_allclose(seen["X"][:, j], X_b[:, j], rtol=1e-9, atol=1e-12,
                                       err_msg=d)


def test_select_marks_keeps_the_best_regions_pixel_by_pixel():
    """The marked labels against a plain comparison: regions 1..m (those
    scoring at least the threshold; the table is sorted by score) kept,
    the others 0; the input, even read-only, is not changed."""
    rng = np.random.default_rng(5)
    for dtype in (np.uint8, np.uint16, np.int32):
        labels = rng.integers(0, 13, (40, 60)).astype(dtype)
        labels.flags.writeable = False
        scores = np.sort(rng.random(12))[::-1]
        table = {"label": np.arange(1, 13), "score": scores}
        before = labels.copy()
        for threshold in (2.0, scores[4], scores[0], -1.0):
            m = int(np.sum(scores >= threshold))
            cut_labels, cut = mm.select_marks(mm.MammogramROIs(labels, table),
                                              threshold=threshold)
            want = np.array([[v if v <= m else 0 for v in row] for row in labels.tolist()])
            assert cut_labels.dtype == dtype
            np.testing.assert_array_equal(cut_labels, want)
            np.testing.assert_array_equal(cut["label"], np.arange(1, m + 1))
        np.testing.assert_array_equal(labels, before)


def test_block_means_and_fractions_are_plain_block_averages_with_ragged_edges_cropped():
    """``_block_mean`` (the working image) and ``_block_fraction`` (of a
    mask) against a loop over the whole ``factor`` x ``factor`` blocks: the
    mean of each block; the last rows and columns that do not fill one are
    left out; a factor of 1 or less keeps the image."""
    from car_napari.mammography._images import _block_mean
    from car_napari.mammography._rois import _block_fraction

    rng = np.random.default_rng(6)
    grey = rng.random((23, 17))
    mask = rng.random((23, 17)) < 0.4
    for factor in (2, 3, 4, 5, 17):
        rows, cols = 23 // factor, 17 // factor
        want = np.zeros((rows, cols))
        part = np.zeros((rows, cols))
        for a in range(rows):
            for b in range(cols):
                block = (slice(a * factor, (a + 1) * factor), slice(b * factor, (b + 1) * factor))
                want[a, b] = sum(grey[block].ravel().tolist()) / factor**2
                part[a, b] = np.count_nonzero(mask[block]) / factor**2
        np.testing.assert_allclose(_block_mean(grey, factor), want, rtol=1e-13)
        np.testing.assert_array_equal(_block_fraction(mask, factor), part)
    for factor in (1, 0):
        np.testing.assert_array_equal(_block_mean(grey, factor), grey)
        np.testing.assert_array_equal(_block_fraction(mask, factor), mask.astype(float))
