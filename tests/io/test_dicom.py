"""DICOM reading: rescale, VOI window, MONOCHROME1 inversion; napari reader hook."""

import numpy as np
import pytest

pydicom = pytest.importorskip("pydicom")

from car_napari.io.dicom import get_reader, read_dicom  # noqa: E402
from dicom_files import write_dicom  # noqa: E402


def _write(path, pixels, photometric="MONOCHROME2", bits=12, **attrs):
    attrs.setdefault("PixelSpacing", [0.1, 0.1])
    return write_dicom(path, pixels, photometric, bits, **attrs)


@pytest.fixture
def ramp():
    return np.tile(np.linspace(0, 4095, 64).round().astype(np.uint16), (32, 1))


def test_monochrome2_plain(tmp_path, ramp):
    image, meta = read_dicom(_write(tmp_path / "a.dcm", ramp))
    assert image.dtype == np.float32 and image.shape == ramp.shape
    np.testing.assert_allclose(image, ramp / 4095.0, atol=1e-6)
    assert meta["pixel_spacing_mm"] == [0.1, 0.1] and meta["modality"] == "MG"


def test_monochrome1_is_inverted(tmp_path, ramp):
    image, meta = read_dicom(_write(tmp_path / "b.dcm", ramp, photometric="MONOCHROME1"))
    np.testing.assert_allclose(image, 1.0 - ramp / 4095.0, atol=1e-6)
    assert "MONOCHROME1 inverted" in meta["applied"]


def test_window_is_applied(tmp_path, ramp):
    path = _write(tmp_path / "c.dcm", ramp, WindowCenter=2048, WindowWidth=1024)
    image, meta = read_dicom(path)
    assert "VOI window" in meta["applied"]
    row = image[0]
    assert row[ramp[0] < 1500].max() == 0.0 and row[ramp[0] > 2600].min() == 1.0
    inside = (ramp[0] > 1700) & (ramp[0] < 2400)
    assert np.all(np.diff(row[inside]) > 0)


def test_rescale_without_window(tmp_path, ramp):
    path = _write(tmp_path / "d.dcm", ramp, RescaleSlope=2, RescaleIntercept=-100)
    image, meta = read_dicom(path)
    assert "modality rescale" in meta["applied"]
    np.testing.assert_allclose(image, ramp / 4095.0, atol=1e-6)  # linear: same display


def test_reader_hook(tmp_path, ramp):
    path = str(_write(tmp_path / "e.dcm", ramp))
    assert get_reader(str(tmp_path / "x.png")) is None
    reader = get_reader(path)
    (data, kwargs, kind), = reader(path)
    assert kind == "image" and data.shape == ramp.shape and kwargs["scale"] == (0.1, 0.1)


def test_napari_opens_dicom(make_napari_viewer, tmp_path, ramp):
    viewer = make_napari_viewer()
    path = str(_write(tmp_path / "f.dcm", ramp, photometric="MONOCHROME1"))
    (layer,) = viewer.open(path, plugin="car-napari")
    np.testing.assert_allclose(layer.data, 1.0 - ramp / 4095.0, atol=1e-6)
    assert tuple(layer.scale) == (0.1, 0.1)
