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
    assert keys == {"texture", "mammogram", "film"}


def test_sample_data():
    from car_napari import sample_data

    (tex, meta, kind), = sample_data.colour_texture()
    assert tex.shape == (256, 256, 3) and meta["rgb"] and kind == "image"
    (mam, _, _), = sample_data.mammogram()
    assert mam.shape == (1024, 1024)
    (frame, _, _), (mask, _, kind) = sample_data.damaged_film()
    assert kind == "labels" and mask.shape == frame.shape[:2]
    assert 0 < mask.mean() < 0.05 and set(np.unique(mask)) == {0, 1}


def test_core_import_is_qt_free():
    code = ("import sys, car_napari, car_napari.cli, car_napari.sample_data; "
            "bad = [m for m in sys.modules if m.split('.')[0] in "
            "('napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6', 'magicgui', 'vispy')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
