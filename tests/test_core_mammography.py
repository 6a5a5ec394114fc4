"""Breast-area detection on the shipped mini-MIAS sample and on real data."""

import numpy as np
import pytest
from skimage import io

from car_napari.mammography import detect_breast
from car_napari.sample_data import resource_path


def test_breast_of_the_sample():
    image = io.imread(str(resource_path("mammogram_mdb001.png")))
    mask = detect_breast(image)
    assert mask.shape == image.shape and mask.dtype == bool
    # the ground-truth mass of mdb001 (col 535, row 599) is inside, the film corners are not
    assert mask[599, 535]
    assert not mask[:40, :40].any() and not mask[-40:, :40].any()
    # tissue is brighter than what is left out
    assert image[mask].mean() > 3 * image[~mask].mean()


def test_every_mass_centre_is_inside(shared_data):
    import csv

    folder = shared_data / "mammograms" / "mini-mias"
    rows = list(csv.DictReader(open(folder / "ground_truth.csv")))
    masses = [r for r in rows if r["class"] in ("CIRC", "SPIC", "MISC") and r["col"]]
    inside = 0
    for r in masses:
        mask = detect_breast(io.imread(folder / f"{r['refnum']}.png"))
        inside += bool(mask[int(r["row"]), int(r["col"])])
    assert inside == len(masses)


@pytest.mark.parametrize("image", [np.zeros((64, 64), np.uint8), np.full((64, 64), 200, np.uint8)])
def test_constant_mammogram_is_a_clear_error(image):
    with pytest.raises(ValueError, match="constant"):
        detect_breast(image)
