"""Command line: fit prints JSON, synthesize writes an image, errors are clear."""

import json
import subprocess
import sys

import numpy as np
from skimage import data as skdata
from skimage import io

from car_napari.cli import main


def test_fit_prints_json(tmp_path, capsys):
    path = tmp_path / "gravel.png"
    io.imsave(path, skdata.gravel()[:96, :96])
    assert main(["fit", str(path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["order"] in range(1, 6)
    assert set(out["scores"]) == {"1", "2", "3", "4", "5"}
    assert np.array(out["gamma"]).shape == (1, len(out["offsets"]))
    assert np.array(out["sigma"]).shape == (1, 1)


def test_synthesize_writes_image(tmp_path):
    src, dst = tmp_path / "astro.png", tmp_path / "out.png"
    io.imsave(src, skdata.astronaut()[300:400, 0:100])
    assert main(["synthesize", str(src), "-o", str(dst), "--size", "50", "60",
                 "--seed", "1"]) == 0
    out = io.imread(dst)
    assert out.shape == (50, 60, 3) and out.dtype == np.uint8


def test_errors(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "missing.png")]) == 2
    assert "no such file" in capsys.readouterr().err
    flat = tmp_path / "flat.png"
    io.imsave(flat, np.full((32, 32), 9, np.uint8), check_contrast=False)
    assert main(["fit", str(flat)]) == 2
    assert "constant" in capsys.readouterr().err


def test_entry_point_help():
    out = subprocess.run([sys.executable, "-m", "car_napari.cli", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "fit" in out and "synthesize" in out


def test_segment_folder_and_glob(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    a, b = skdata.brick()[:96, :48], skdata.grass()[:96, :48]
    io.imsave(src / "one.png", np.concatenate([a, b], axis=1))
    io.imsave(src / "two.png", np.concatenate([b, a], axis=1))
    out = tmp_path / "out"
    assert main(["segment", str(src), "-o", str(out), "--segments", "2", "--levels", "2"]) == 0
    labels = io.imread(out / "one_segments.png")
    assert labels.shape == (96, 96) and set(np.unique(labels)) <= {0, 1, 2}
    assert (out / "two_segments.png").exists()
    assert main(["segment", str(src / "*.png"), "-o", str(out), "--levels", "2"]) == 0
    assert main(["segment", str(tmp_path / "none*.png"), "-o", str(out)]) == 2
    assert "no input images" in capsys.readouterr().err


def test_bad_order_is_a_usage_error(tmp_path, capsys):
    import pytest

    path = tmp_path / "gravel.png"
    io.imsave(path, skdata.gravel()[:48, :48])
    with pytest.raises(SystemExit) as exit_info:
        main(["fit", str(path), "--order", "abc"])
    assert exit_info.value.code == 2
    assert "'auto' or a positive integer" in capsys.readouterr().err
