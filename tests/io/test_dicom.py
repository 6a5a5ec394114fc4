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


def test_napari_opens_dicom(make_napari_viewer_proxy, tmp_path, ramp):
    viewer = make_napari_viewer_proxy()
    path = str(_write(tmp_path / "f.dcm", ramp, photometric="MONOCHROME1"))
    (layer,) = viewer.open(path, plugin="car-napari")
    np.testing.assert_allclose(layer.data, 1.0 - ramp / 4095.0, atol=1e-6)
    assert tuple(layer.scale) == (0.1, 0.1)


# --- how napari names the reader (defect j of issue 12) --------------------------------


def test_manifest_names_the_reader_for_what_it_reads():
    from pathlib import Path

    from npe2 import PluginManifest

    manifest = PluginManifest.from_file(
        str(Path(__file__).parents[2] / "car_napari" / "napari.yaml"))
    # napari's reader chooser lists a reader by its plugin's display name
    assert manifest.display_name == "car-napari"
    (reader,) = manifest.contributions.readers
    command = {c.id: c for c in manifest.contributions.commands}[reader.command]
    assert command.title.startswith("DICOM")
    assert set(reader.filename_patterns) >= {"*.dcm", "*.DCM", "*.dicom"}


def test_reader_chooser_shows_the_plugin_not_a_model(make_napari_viewer, tmp_path, ramp):
    """What napari's "Choose reader" dialog shows for a .dcm file."""
    from napari._qt.dialogs.qt_reader_dialog import QtReaderDialog
    from napari.plugins import _npe2
    from qtpy.QtWidgets import QRadioButton

    viewer = make_napari_viewer()
    path = str(_write(tmp_path / "g.dcm", ramp))
    readers = _npe2.get_readers(path)
    assert readers.get("car-napari") == "car-napari"
    dialog = QtReaderDialog(pth=path, parent=viewer.window._qt_viewer, readers=readers)
    shown = [b.text() for b in dialog.findChildren(QRadioButton)]
    assert "car-napari" in shown and "CAR models" not in shown
    dialog.close()
    # and choosing it opens the file with the DICOM reader
    (layer,) = viewer.open(path, plugin="car-napari")
    assert layer.metadata["modality"] == "MG"


@pytest.mark.parametrize("function", ["LINEAR_EXACT", "SIGMOID"])
def test_voi_functions_are_the_standards_formulas(tmp_path, ramp, function):
    """The VOI LUT functions of PS3.3 C.11.2.1.3, onto [0, 1]: LINEAR_EXACT
    ``(x - c) / w + 0.5`` clipped, SIGMOID ``1 / (1 + exp(-4 (x - c) / w))``."""
    path = _write(tmp_path / "e.dcm", ramp, WindowCenter=2000, WindowWidth=1500,
                  VOILUTFunction=function)
    image, meta = read_dicom(path)
    x = ramp.astype(float)
    if function == "LINEAR_EXACT":
        expect = np.clip((x - 2000) / 1500 + 0.5, 0, 1)
    else:
        expect = 1 / (1 + np.exp(-4 * (x - 2000) / 1500))
    np.testing.assert_allclose(image, expect, atol=1e-6)
    assert "VOI window" in meta["applied"]


@pytest.mark.parametrize("function", ["LINEAR_EXACT", "SIGMOID"])
def test_voi_functions_take_widths_below_one(tmp_path, function):
    """LINEAR_EXACT and SIGMOID with a window width of 0.5 on modality
    values within a pixel of the centre, against the formulas of the
    test above."""
    stored = np.tile(np.arange(1990, 2011).astype(np.uint16), (2, 1))
    x = 0.1 * stored  # 199.0 .. 201.0
    path = _write(tmp_path / "n.dcm", stored, WindowCenter=200, WindowWidth=0.5,
                  RescaleSlope=0.1, RescaleIntercept=0, VOILUTFunction=function)
    image, _ = read_dicom(path)
    if function == "LINEAR_EXACT":
        expect = np.clip((x - 200) / 0.5 + 0.5, 0, 1)
    else:
        expect = 1 / (1 + np.exp(-4 * (x - 200) / 0.5))
    np.testing.assert_allclose(image, expect, atol=1e-6)


def _linear_window(x, center, width):
    """PS3.3 C.11.2.1.2.1 (the default LINEAR function), its pseudo-code as
    written, onto [0, 1]."""
    out = []
    for v in x.ravel().tolist():
        if v <= center - 0.5 - (width - 1) / 2:
            out.append(0.0)
        elif v > center - 0.5 + (width - 1) / 2:
            out.append(1.0)
        else:
            out.append((v - (center - 0.5)) / (width - 1) + 0.5)
    return np.array(out).reshape(x.shape)


@pytest.mark.parametrize("width", [1, 1.25, 2, 3])
def test_linear_window_of_width_one_or_more_is_the_standards_pseudo_code(tmp_path, width):
    """The LINEAR window down to its smallest width, 1 (a threshold: 1 above
    ``c - 0.5``, 0 at or below), against the pseudo-code of PS3.3
    C.11.2.1.2.1 on modality values (rescaled by 0.5, less 0.5) landing on
    ``c - 0.5`` and the window's other ends; with integer values a width of
    2 thresholds as a width of 1 does (its Note 5)."""
    stored = np.concatenate([np.arange(1990, 2011), [0, 4095, 2001, 2002]])
    stored = np.tile(stored.astype(np.uint16), (2, 1))
    values = 0.5 * stored - 0.5  # 999.5 = c - 0.5 at stored 2000
    path = _write(tmp_path / f"w{width}.dcm", stored, WindowCenter=1000, WindowWidth=width,
                  RescaleSlope=0.5, RescaleIntercept=-0.5)
    image, meta = read_dicom(path)
    assert "VOI window" in meta["applied"]
    np.testing.assert_allclose(image, _linear_window(values, 1000, width), atol=1e-6)
    if width == 1:
        np.testing.assert_array_equal(image, values > 999.5)
    if width in (1, 2):  # integer input values: a threshold at the centre
        path = _write(tmp_path / f"i{width}.dcm", stored, WindowCenter=2000, WindowWidth=width)
        image, _ = read_dicom(path)
        np.testing.assert_array_equal(image, stored >= 2000)
        np.testing.assert_allclose(image, _linear_window(stored.astype(float), 2000, width))
