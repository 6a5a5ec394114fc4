"""io.images: reading PNG (grey, RGB, RGBA) and DICOM, writing, the suffix list."""

import numpy as np
import pytest
from PIL import Image

from car_napari.io.images import (
    DICOM_SUFFIXES,
    IMAGE_SUFFIXES,
    is_colour,
    read_image,
    write_image,
)


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


@pytest.mark.parametrize("shape", [(3, 64, 64, 3), (4, 32, 32, 3), (5, 16, 16, 3),
                                   (3, 16, 16, 4), (3, 64, 64), (64, 64, 3), (64, 64),
                                   (2, 3, 8, 8)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_tiff_stacks_read_back_in_the_shape_written(tmp_path, shape, dtype):
    """(3, 64, 64, 3) was written as frames of 64 planar samples and read as
    (3, 64, 3, 64); (3, 64, 64) as one planar RGB image, read as (64, 64, 3)."""
    image = (np.random.default_rng(0).random(shape) * 200).astype(dtype)
    write_image(tmp_path / "stack.tif", image)
    back = read_image(tmp_path / "stack.tif")
    assert back.shape == image.shape
    np.testing.assert_array_equal(back, image)
    assert is_colour(back) == (image.ndim == 3 and shape[-1] == 3)


def test_tiff_stacks_written_by_the_old_guess_read_right(tmp_path):
    """Files already written with tifffile's guess (QSYX, 64 'samples') keep
    the shape stored with them; a real planar RGB file still reads as colour."""
    import tifffile
    from skimage import io

    stack = (np.random.default_rng(1).random((3, 64, 64, 3)) * 255).astype(np.uint8)
    io.imsave(tmp_path / "old.tif", stack, check_contrast=False)  # how write_image wrote it
    with tifffile.TiffFile(tmp_path / "old.tif") as tif:
        if tif.series[0].axes != "QSYX":  # the ambiguous guess this reads right
            pytest.skip(f"this scikit-image and tifffile write {tif.series[0].axes}")
    np.testing.assert_array_equal(read_image(tmp_path / "old.tif"), stack)
    planar = stack[0].transpose(2, 0, 1).copy()
    tifffile.imwrite(tmp_path / "planar.tif", planar, photometric="rgb",
                     planarconfig="separate")
    np.testing.assert_array_equal(read_image(tmp_path / "planar.tif"), stack[0])
