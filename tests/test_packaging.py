"""Packaging: the npe2 manifest, sample data, and a Qt-free core import."""

import subprocess
import sys
from importlib.resources import files
from pathlib import Path

import numpy as np

TOP = Path(__file__).resolve().parents[1]


def test_manifest_validates_and_is_the_top_level_one():
    from npe2 import PluginManifest

    installed = files("car_napari") / "napari.yaml"
    assert installed.read_text() == (TOP / "napari.yaml").read_text()
    manifest = PluginManifest.from_file(str(installed))
    assert manifest.name == "car-napari"
    assert {w.display_name for w in manifest.contributions.widgets} >= {"CAR model"}
    keys = {s.key for s in manifest.contributions.sample_data}
    assert keys == {"texture", "mammogram", "film", "burst"}


def test_sample_data():
    from car_napari.io import sample_data

    (tex, meta, kind), = sample_data.colour_texture()
    assert tex.shape == (256, 256, 3) and meta["rgb"] and kind == "image"
    (mam, _, _), = sample_data.mammogram()
    assert mam.shape == (1024, 1024)
    (frame, _, _), (mask, _, kind) = sample_data.damaged_film()
    assert kind == "labels" and mask.shape == frame.shape[:2]
    assert 0 < mask.mean() < 0.05 and set(np.unique(mask)) == {0, 1}


def test_core_import_is_qt_free():
    code = ("import sys, car_napari, car_napari.cli, car_napari.io.sample_data; "
            "bad = [m for m in sys.modules if m.split('.')[0] in "
            "('napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6', 'magicgui', 'vispy')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


def test_wheel_ships_manifest_and_resources(tmp_path):
    """A regular (non-editable) install gets the real manifest and the samples."""
    import zipfile

    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(TOP)],
        capture_output=True, text=True,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    (wheel,) = tmp_path.glob("car_napari-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        assert z.read("car_napari/napari.yaml").decode() == (TOP / "napari.yaml").read_text()
        entry = next(n for n in names if n.endswith("entry_points.txt"))
        assert "car-napari = car_napari:napari.yaml" in z.read(entry).decode()
    for name in ("texture_vistex_VS50.png", "mammogram_mdb001.png",
                 "film_cinestill50d_damaged.jpg", "film_cinestill50d_mask.png",
                 "LICENCE-mini-MIAS.txt"):
        assert f"car_napari/_resources/{name}" in names


def test_manifest_reads_dicom():
    from npe2 import PluginManifest

    manifest = PluginManifest.from_file(str(TOP / "napari.yaml"))
    (reader,) = manifest.contributions.readers
    assert "*.dcm" in reader.filename_patterns
