"""io.images: reading PNG (grey, RGB, RGBA) and DICOM, writing, the suffix list."""

import numpy as np
import pytest
from PIL import Image

from car_napari.io.images import DICOM_SUFFIXES, IMAGE_SUFFIXES, read_image, write_image


def _ramp(h=16, w=24):
    return np.add.outer(np.arange(h) * 5, np.arange(w) * 3).astype(np.uint8)


def test_grey_png(tmp_path):
    grey = _ramp()
    Image.fromarray(grey).save(tmp_path / "grey.png")  # written by another library
    image = read_image(tmp_path / "grey.png")
    assert image.dtype == np.uint8
    np.testing.assert_array_equal(image, grey)


def test_rgb_and_rgba_png(tmp_path):
    rgb = np.stack([_ramp(), 255 - _ramp(), np.full((16, 24), 7, np.uint8)], axis=-1)
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    np.testing.assert_array_equal(read_image(str(tmp_path / "rgb.png")), rgb)
    rgba = np.concatenate([rgb, np.full((16, 24, 1), 128, np.uint8)], axis=-1)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "rgba.png")
    np.testing.assert_array_equal(read_image(tmp_path / "rgba.png"), rgb)  # alpha dropped


def test_write_then_read_round_trip(tmp_path):
    labels = np.zeros((8, 8), np.uint16)
    labels[2:5, 3:7] = 300
    write_image(tmp_path / "labels.png", labels)
    back = read_image(tmp_path / "labels.png")
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, labels)
    values = np.linspace(0, 1, 48, dtype=np.float32).reshape(6, 8)
    write_image(tmp_path / "values.tif", values)
    np.testing.assert_array_equal(read_image(tmp_path / "values.tif"), values)


def test_dicom(tmp_path):
    pytest.importorskip("pydicom")
    from dicom_files import write_dicom

    stored = np.tile(np.arange(0, 4096, 64, dtype=np.uint16), (8, 1))
    path = write_dicom(tmp_path / "scan.DCM", stored, bits=12)  # the suffix in any case
    image = read_image(path)
    assert image.shape == stored.shape and image.dtype == np.float32
    np.testing.assert_allclose(image, stored / 4095.0, atol=1e-6)


def test_errors_say_what_is_wrong(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        read_image(tmp_path / "missing.png")
    with pytest.raises(ValueError, match="no such file"):
        read_image(tmp_path / "missing.dcm")
    (tmp_path / "broken.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="cannot read .*broken.png as an image"):
        read_image(tmp_path / "broken.png")


def test_suffixes():
    assert DICOM_SUFFIXES < IMAGE_SUFFIXES
    assert {".png", ".jpg", ".tif", ".tiff"} <= IMAGE_SUFFIXES
    assert all(s == s.lower() and s.startswith(".") for s in IMAGE_SUFFIXES)
