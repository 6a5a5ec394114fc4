"""Packaging: the npe2 manifest, sample data, a Qt-free core import, the wheel, and the
plugin installed from the wheel into a fresh environment under a real napari viewer."""

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from importlib.resources import files
from importlib.util import find_spec
from pathlib import Path

import numpy as np
import pytest
import yaml

TOP = Path(__file__).resolve().parents[1]
MANIFEST_FILE = TOP / "car_napari" / "napari.yaml"  # in the package: no copy step
MANIFEST = yaml.safe_load(MANIFEST_FILE.read_text())
WIDGETS = [w["display_name"] for w in MANIFEST["contributions"]["widgets"]]
SAMPLES = [s["key"] for s in MANIFEST["contributions"]["sample_data"]]
# what setup.py copies from resources/ into car_napari/_resources
SHIPPED_SUFFIXES = (".png", ".jpg", ".txt")
UNSHIPPED = ("screenshot.png",)


def test_manifest_validates_and_is_the_package_one():
    from npe2 import PluginManifest

    installed = files("car_napari") / "napari.yaml"
    assert installed.read_text() == MANIFEST_FILE.read_text()
    manifest = PluginManifest.from_file(str(installed))
    assert manifest.name == "car-napari"
    assert {w.display_name for w in manifest.contributions.widgets} >= {"CAR model"}
    keys = {s.key for s in manifest.contributions.sample_data}
    assert keys == {"texture", "mammogram", "film", "burst"}


def test_the_manifest_is_package_data_and_shown_at_the_top():
    """napari.yaml is package data, as the napari plugin template has it (no
    copy step in setup.py, no git-ignored copy); the project's layout shows
    it at the top level too: a committed file, byte for byte the package's
    (no symlink: they break on Windows and in wheels)."""
    import tomllib

    top = TOP / "napari.yaml"
    assert MANIFEST_FILE.is_file() and top.is_file() and not top.is_symlink()
    assert top.read_bytes() == MANIFEST_FILE.read_bytes(), (
        "napari.yaml and car_napari/napari.yaml differ: edit both the same way")
    assert not [line for line in (TOP / "setup.py").read_text().splitlines()
                if "napari.yaml" in line and "copy" in line]
    assert "napari.yaml" not in (TOP / ".gitignore").read_text()
    project = tomllib.loads((TOP / "pyproject.toml").read_text())
    assert "napari.yaml" in project["tool"]["setuptools"]["package-data"]["car_napari"]
    assert project["project"]["entry-points"]["napari.manifest"] == {
        "car-napari": "car_napari:napari.yaml"}


def test_python_3_11_and_the_version_in_one_place():
    """requires-python >= 3.11 (napari 0.8 needs it; the README says so too)
    and the version written once, in pyproject.toml, read by
    ``car_napari.__version__`` through importlib.metadata."""
    import re
    import tomllib
    from importlib import metadata

    import car_napari

    project = tomllib.loads((TOP / "pyproject.toml").read_text())["project"]
    assert project["requires-python"] == ">=3.11"
    assert project["version"] == metadata.version("car-napari") == car_napari.__version__
    assert "Python 3.11+" in (TOP / "README.md").read_text()
    assert not re.search(r"Python 3\.10", (TOP / "README.md").read_text())
    init = (TOP / "car_napari" / "__init__.py").read_text()
    assert project["version"] not in init  # not written twice
    assert "metadata.version(" in init


def test_sample_data():
    from car_napari.io import sample_data

    (tex, meta, kind), = sample_data.colour_texture()
    assert tex.shape == (256, 256, 3) and meta["rgb"] and kind == "image"
    (mam, _, _), = sample_data.mammogram()
    assert mam.shape == (1024, 1024)
    (frame, _, _), (mask, _, kind) = sample_data.damaged_film()
    assert kind == "labels" and mask.shape == frame.shape[:2]
    assert 0 < mask.mean() < 0.05 and set(np.unique(mask)) == {0, 1}
    (burst, meta, _), = sample_data.degraded_stack()
    assert burst.shape == (8, 256, 256, 3) and burst.dtype == np.float32 and meta["rgb"]


def test_core_import_is_qt_free():
    code = ("import sys, car_napari, car_napari.cli, car_napari.io.sample_data; "
            "bad = [m for m in sys.modules if m.split('.')[0] in "
            "('napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6', 'magicgui', 'vispy')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """A regular (non-editable) wheel of the working tree, built once."""
    out = tmp_path_factory.mktemp("wheel")
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(TOP)],
        capture_output=True, text=True,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    (path,) = out.glob("car_napari-*.whl")
    return path


def test_wheel_ships_manifest_and_resources(wheel):
    """A regular install gets the real manifest and the samples, and nothing else from the
    repository's top level."""
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        assert z.read("car_napari/napari.yaml").decode() == MANIFEST_FILE.read_text()
        entry = next(n for n in names if n.endswith("entry_points.txt"))
        assert "car-napari = car_napari:napari.yaml" in z.read(entry).decode()
    expected = {
        f"car_napari/_resources/{p.name}" for p in (TOP / "resources").iterdir()
        if (p.suffix in SHIPPED_SUFFIXES or p.name == "README.md") and p.name not in UNSHIPPED
    }
    shipped = {n for n in names if n.startswith("car_napari/_resources/")}
    assert shipped == expected
    for name in ("texture_vistex_VS50.png", "mammogram_mdb001.png",
                 "film_cinestill50d_damaged.jpg", "film_cinestill50d_mask.png",
                 "LICENCE-mini-MIAS.txt"):
        assert f"car_napari/_resources/{name}" in names
    assert "car_napari/mammography/roi_model.json" in names  # read on import
    assert "car_napari/mammography/tissue_model.json" in names
    assert "car_napari/mammography/tissue_unet.npz" in names  # the tissue U-Net's weights
    packages = {n.split("/")[0] for n in names if ".dist-info/" not in n}
    assert packages == {"car_napari"}  # no tests/, benchmarks/ or top-level modules
    modules = {n for n in names if n.endswith(".py")}
    sources = {p.relative_to(TOP).as_posix() for p in (TOP / "car_napari").rglob("*.py")}
    assert modules == sources  # every module, and none left over in build/ from an old layout


def test_manifest_reads_dicom():
    from npe2 import PluginManifest

    manifest = PluginManifest.from_file(str(MANIFEST_FILE))
    (reader,) = manifest.contributions.readers
    assert "*.dcm" in reader.filename_patterns


def test_napari_uses_the_qt_binding_asked_for():
    """napari (through qtpy) and pytest-qt share one binding: $QT_API, else PyQt5 (the
    README's); CI runs the widget tests under PyQt5 and again with QT_API=pyqt6."""
    pytest.importorskip("napari")
    import napari._qt  # noqa: F401  (napari's Qt layer; fails without a usable binding)
    import qtpy
    from pytestqt.qt_compat import qt_api

    default = "pyqt5" if find_spec("PyQt5") else qtpy.API_NAME.lower()
    wanted = os.environ.get("QT_API", default).lower()
    assert qtpy.API_NAME.lower() == wanted
    assert qt_api.pytest_qt_api == wanted
    bindings = {name.split(".")[0] for name in sys.modules} & {"PyQt5", "PyQt6", "PySide6"}
    assert bindings == {qtpy.API_NAME}
    print(f"napari {napari.__version__} on {qtpy.API_NAME} {qtpy.QT_VERSION}")


@pytest.fixture(scope="module")
def wheel_venv(wheel, tmp_path_factory):
    """A fresh venv with car-napari installed from the wheel alone; the dependencies come from
    the development venv through a path line in a .pth file (its own .pth files, which serve the
    editable car_napari, stay inert there), so nothing is downloaded."""
    venv = tmp_path_factory.mktemp("fresh") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    # install before the .pth exists, so pip sees no car-napari installed already
    res = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
         "--no-index", "-q", str(wheel)],
        capture_output=True, text=True,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    purelib = subprocess.check_output(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], text=True
    ).strip()
    (Path(purelib) / "development-venv.pth").write_text(sysconfig.get_path("purelib") + "\n")
    return python


VIEWER_SCRIPT = """
import json, sys
from pathlib import Path

import car_napari, napari, qtpy
from npe2 import PluginManager

assert Path(car_napari.__file__).is_relative_to(sys.prefix), car_napari.__file__
viewer = napari.Viewer()  # discovers the installed plugins
manifest = PluginManager.instance().get_manifest("car-napari")
widgets = [w.display_name for w in manifest.contributions.widgets]
docked = []
for name in widgets:
    viewer.window.add_plugin_dock_widget("car-napari", name)
    docked.append(name)
samples = {}
for key in [s.key for s in manifest.contributions.sample_data]:
    before = len(viewer.layers)
    added = viewer.open_sample("car-napari", key)
    samples[key] = [len(viewer.layers) - before, [type(layer).__name__.lower() for layer in added]]
viewer.close()
print("RESULT", json.dumps({"qt": qtpy.API_NAME, "widgets": widgets, "docked": docked,
                            "samples": samples, "package": car_napari.__file__}))
"""


def _needs_display():
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        if os.environ.get("CI"):
            pytest.fail("no display in CI: run the tests under xvfb-run (bash .ci/test does)")
        pytest.skip("needs a display (bash .ci/test starts Xvfb)")


@pytest.mark.parametrize("binding", ["pyqt5", "pyqt6"])
def test_plugin_from_the_wheel_in_a_real_viewer(wheel_venv, tmp_path, binding):
    """Installed from the wheel (not the source tree), napari lists the plugin's widgets, docks
    each of them and opens each sample as layers, under both Qt bindings."""
    _needs_display()
    if not find_spec({"pyqt5": "PyQt5", "pyqt6": "PyQt6"}[binding]):
        if os.environ.get("CI"):
            pytest.fail(f"{binding} is not installed (bash .ci/setup installs both bindings)")
        pytest.skip(f"{binding} is not installed")
    env = {**os.environ, "QT_API": binding}
    env.pop("PYTHONPATH", None)
    res = subprocess.run(
        [str(wheel_venv), "-c", VIEWER_SCRIPT], capture_output=True, text=True, cwd=tmp_path,
        env=env, timeout=600,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    line = next(x for x in res.stdout.splitlines() if x.startswith("RESULT "))
    result = json.loads(line.removeprefix("RESULT "))
    assert result["qt"].lower() == binding
    assert Path(result["package"]).is_relative_to(wheel_venv.parent.parent)
    assert result["widgets"] == WIDGETS and len(WIDGETS) == 7
    assert result["docked"] == WIDGETS
    assert sorted(result["samples"]) == sorted(SAMPLES) and len(SAMPLES) == 4
    for key, (added, kinds) in result["samples"].items():
        assert added >= 1 and added == len(kinds), (key, added, kinds)
    assert result["samples"]["film"][1] == ["image", "labels"]
