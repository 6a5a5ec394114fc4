"""Breast tissue: fibroglandular mask, percent density and tissue class
(issue 35; car_napari.mammography.segment_tissue)."""

import json

import numpy as np
import pytest
from skimage import io

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
