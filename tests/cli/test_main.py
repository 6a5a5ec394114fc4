"""``car-napari`` itself (car_napari/cli/__init__.py): --version, --quiet."""

import io as io_module
import subprocess
import sys
from importlib.metadata import version

import numpy as np
import pytest
from skimage import io

from car_napari.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"car-napari {version('car-napari')}"


def test_version_of_the_command():
    out = subprocess.run([sys.executable, "-m", "car_napari.cli", "--version"],
                         capture_output=True, text=True, check=True).stdout
    assert out.startswith("car-napari ")


def _grey_alpha(path, seed=0):
    """A grey+alpha PNG: reading it gives a note (alpha dropped)."""
    grey = (np.random.default_rng(seed).random((40, 40)) * 255).astype(np.uint8)
    io.imsave(path, np.dstack([grey, np.full_like(grey, 255)]))


def test_quiet_prints_nothing_but_errors(tmp_path, capsys, monkeypatch):
    _grey_alpha(tmp_path / "a.png")
    _grey_alpha(tmp_path / "b.png", seed=1)
    mask = np.zeros((20, 20), np.uint8)  # another size: a note
    mask[:, 9:11] = 255
    io.imsave(tmp_path / "m.png", mask, check_contrast=False)
    runs = [["restore", str(tmp_path / "a.png"), "-o", str(tmp_path / "r")],
            ["restore", str(tmp_path / "a.png"), "-o", str(tmp_path / "r")],  # skipped
            ["inpaint", str(tmp_path / "a.png"), "-m", str(tmp_path / "m.png"),
             "-o", str(tmp_path / "i.png")],
            ["inpaint", str(tmp_path / "[ab].png"), "-m", str(tmp_path / "m.png"),
             "-o", str(tmp_path / "i")],
            ["segment", str(tmp_path / "a.png"), "-o", str(tmp_path / "s"), "--levels", "1",
             "--segments", "2"]]
    for argv in runs:
        assert main(argv) == 0
        captured = capsys.readouterr()
        assert "note:" in captured.err or "skipped" in captured.err or captured.out, argv
        assert main([*argv, "--quiet", "--overwrite"]) == 0
        assert capsys.readouterr() == ("", ""), argv
    assert main(["restore", str(tmp_path / "none.png"), "-o", str(tmp_path / "r"),
                 "--quiet"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "none.png" in captured.err  # errors still said


class _Terminal(io_module.StringIO):
    def isatty(self):
        return True


def test_quiet_has_no_progress_bar_on_a_terminal(tmp_path, monkeypatch):
    _grey_alpha(tmp_path / "a.png")
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["restore", str(tmp_path / "a.png"), "-o", str(tmp_path / "r")]) == 0
    assert "100%" in err.getvalue()
    err.seek(0)
    err.truncate()
    assert main(["restore", str(tmp_path / "a.png"), "-o", str(tmp_path / "r"), "--quiet",
                 "--overwrite"]) == 0
    assert err.getvalue() == ""
