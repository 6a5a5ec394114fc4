"""Mammograms as they come: screening films with edge strips, labels and the
pectoral muscle, 12- and 16-bit images, colour pictures (issue 31)."""

import warnings

import numpy as np
import pytest
from skimage import io

from car_fields import SHARED_DATA
from car_napari.io.sample_data import resource_path
from car_napari.mammography import bit_depth, detect_breast, detect_mammogram_rois

# Named films of ../shared/data/mammograms, each showing what the breast area
# must leave out (rows and columns of the file's own pixels, read off the
# images by eye):
#   01744_LEFT_MLO (CBIS-DDSM): a white scanner strip along the bottom border
#     (rows 788-799 are 255), the film's edge along the right border, and the
#     pectoral muscle in the top right corner;
#   00148_RIGHT_MLO (CBIS-DDSM): an "RMLO" label at the top left, the bottom
#     strip, and the pectoral muscle on the right;
#   01887_LEFT_CC (CBIS-DDSM): an "LCC" label near the right border;
#   mdb005 (mini-MIAS): a "JM" marker at the top left and the muscle at the
#     top right.
FILMS = {
    "01744_LEFT_MLO": {"strip": (slice(786, 800), slice(None)),
                       "muscle": [(60, 740), (150, 770)], "tissue": [(500, 500), (400, 300)]},
    "00148_RIGHT_MLO": {"label": (slice(50, 110), slice(0, 120)),
                        "strip": (slice(788, 800), slice(None)),
                        "muscle": [(100, 720), (300, 760)], "tissue": [(450, 300), (600, 450)]},
    "01887_LEFT_CC": {"label": (slice(180, 340), slice(715, 800)),
                      "tissue": [(400, 300), (300, 500)]},
    "mdb005": {"label": (slice(0, 110), slice(90, 180)), "muscle": [(100, 750), (250, 820)],
               "tissue": [(800, 500), (600, 700)]},
}


def _film(name):
    folder = SHARED_DATA / "mammograms"
    path = (folder / "mini-mias" / f"{name}.png" if name.startswith("mdb")
            else folder / "cbis-ddsm-masses" / f"{name}.jpg")
    if not path.exists():
        pytest.skip(f"real data not found at {path} (clone with ../shared beside it)")
    return io.imread(path)


@pytest.fixture(scope="module")
def films():
    """The named films with their breast masks, and their ROIs with every
    finding kept (one run each for the module)."""
    out = {}
    for name in FILMS:
        image = _film(name)
        out[name] = (image, detect_breast(image),
                     detect_mammogram_rois(image, marks_per_image=None).labels)
    return out


@pytest.mark.parametrize("name", list(FILMS))
def test_breast_area_leaves_out_strips_labels_and_muscle(films, name):
    image, mask, _ = films[name]
    where = FILMS[name]
    for part in ("strip", "label"):
        if part in where:
            assert not mask[where[part]].any(), part
    for r, c in where.get("muscle", []):
        assert not mask[r, c], ("muscle", r, c)
    for r, c in where["tissue"]:
        assert mask[r, c], ("tissue", r, c)
    # no breast within 1.5 % of the long side of any border
    band = round(0.015 * max(image.shape))
    assert not (mask[:band].any() or mask[-band:].any() or mask[:, :band].any()
                or mask[:, -band:].any())


@pytest.mark.parametrize("name", list(FILMS))
def test_no_region_on_strips_labels_or_muscle(films, name):
    """Every scored region, not only those of an operating point."""
    _, mask, labels = films[name]
    where = FILMS[name]
    assert labels.max() > 0
    assert not labels[~mask].any()
    for part in ("strip", "label"):
        if part in where:
            assert not labels[where[part]].any(), part
    for r, c in where.get("muscle", []):
        assert labels[r, c] == 0, ("muscle", r, c)


def test_bit_depth_of_integer_images():
    assert bit_depth(np.zeros((4, 4), np.uint8)) == 8
    assert bit_depth(np.full((4, 4), 4095, np.uint16)) == 12
    assert bit_depth(np.full((4, 4), 4096, np.uint16)) == 16
    assert bit_depth(np.full((4, 4), 70000, np.uint32)) == 32
    assert bit_depth(np.zeros((4, 4), np.float32)) is None


@pytest.fixture(scope="module")
def twelve_bit():
    """The sample mammogram at half size as a 12-bit image in a uint16
    container (values up to 3,501, as a digital mammogram's)."""
    sample = io.imread(str(resource_path("mammogram_mdb001.png")))
    half = sample.reshape(512, 2, 512, 2).mean(axis=(1, 3))
    return np.round(half * 3501.0 / 255.0).astype(np.uint16)


def test_twelve_bit_gives_the_regions_of_the_scaled_image(twelve_bit):
    a = twelve_bit
    assert a.max() <= 4095
    direct = detect_mammogram_rois(a, marks_per_image=None)
    scaled = detect_mammogram_rois(a / 4095, marks_per_image=None)
    assert direct.labels.max() > 0
    np.testing.assert_array_equal(direct.labels, scaled.labels)
    np.testing.assert_array_equal(direct.table["score"], scaled.table["score"])
    # a full 16-bit image is read on its own range
    sixteen = a.astype(np.uint16) * 16
    assert bit_depth(sixteen) == 16
    np.testing.assert_array_equal(detect_breast(sixteen), detect_breast(sixteen / 65535))


def test_twelve_bit_input_is_not_modified(twelve_bit):
    a = twelve_bit.copy()
    detect_breast(a)
    np.testing.assert_array_equal(a, twelve_bit)


def test_a_colour_picture_gets_a_warning():
    sample = io.imread(str(resource_path("mammogram_mdb001.png")))[::4, ::4]
    colour = np.dstack([sample, sample // 2, 255 - sample])
    with pytest.warns(UserWarning, match="colour"):
        detect_breast(colour)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a grey export in three channels: no warning
        detect_breast(np.dstack([sample] * 3))


def test_location_descriptors_against_direct_measurements():
    """Border, skin-line, chest-wall and height distances of a point in a
    rectangular breast against the formulas."""
    from car_napari.mammography._candidates import _Location

    breast = np.zeros((100, 80), bool)
    breast[10:90, 0:50] = True  # chest wall on the left: the nipple side tapers
    breast[10:30, 40:], breast[70:90, 40:] = False, False
    where = _Location(breast)
    border, skin, chest, height, corner = where(50.0, 20.0)
    assert border == pytest.approx(20 / 100)
    # the nearest non-breast pixel: the padding left of column 0, 21 pixels away
    assert skin == pytest.approx(21 / np.sqrt(breast.sum() / np.pi))
    assert chest == pytest.approx(20 / 49)
    assert height == pytest.approx((50 - 10) / 79)
    assert corner == pytest.approx(max(0.0, 1 - np.hypot(20 / 49, 40 / 79)))
    mirrored = _Location(breast[:, ::-1])
    assert mirrored(50.0, 79 - 20.0)[2] == pytest.approx(chest)
