"""The commands' shared rules (car_napari/cli/_files.py): where -o puts the outputs."""

from pathlib import Path

import numpy as np
import pytest
from skimage import io

from car_napari.cli import main
from car_napari.cli._files import LABEL_SUFFIXES, names_a_folder, output_file


def _noise_png(path, seed=0, shape=(40, 40)):
    io.imsave(path, (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8))


def test_output_file_or_folder_by_one_rule(tmp_path):
    one, two = [Path("a.png")], [Path("a.png"), Path("b.png")]
    assert names_a_folder(tmp_path) and names_a_folder("out/") and names_a_folder("out")
    assert not names_a_folder("out/y.png")
    assert output_file(tmp_path / "out", two) is None
    assert output_file(str(tmp_path / "out.v2") + "/", one) is None
    (tmp_path / "dotted.d").mkdir()
    assert output_file(tmp_path / "dotted.d", one) is None  # an existing folder
    target = output_file(tmp_path / "new" / "y.png", one)
    assert target == tmp_path / "new" / "y.png" and target.parent.is_dir()
    with pytest.raises(ValueError, match=r"\.xyz is not a file type of an image; use .*\.png"):
        output_file(tmp_path / "i.xyz", one)
    with pytest.raises(ValueError, match="names one file, but there are 2 inputs"):
        output_file(tmp_path / "y.png", two)
    with pytest.raises(ValueError, match="not a file type of a label image"):
        output_file(tmp_path / "y.jpg", one, suffixes=LABEL_SUFFIXES, what="a label image")


def test_restore_to_a_file_writes_that_file(tmp_path, capsys):
    _noise_png(tmp_path / "x.png")
    assert main(["restore", str(tmp_path / "x.png"), "-o", str(tmp_path / "out" / "y.png"),
                 "--probability"]) == 0
    assert (tmp_path / "out" / "y.png").is_file()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["y.png",
                                                                   "y_probability.tif"]
    assert io.imread(tmp_path / "out" / "y.png").dtype == np.uint8


@pytest.mark.parametrize("command", [
    ["inpaint", "{x}", "-m", "{x}", "-o", "{out}/i.xyz"],
    ["restore", "{x}", "-o", "{out}/y.xyz"],
    ["segment", "{x}", "-o", "{out}/s.jpg"],
    ["mammo", "{x}", "-o", "{out}/m.gif"],
    ["fit-texture", "{x}", "-o", "{out}/t.png"],
    ["restore", "{x}", "{x}", "-o", "{out}/y.png"],
    ["descratch", "{dir}", "-o", "{out}/y.png"],
    ["synthesize", "{x}", "-o", "{out}/folder"],
])
def test_an_output_that_cannot_hold_the_result_is_refused_before_any_work(
        tmp_path, capsys, command):
    _noise_png(tmp_path / "x_0001.png")
    args = [a.format(x=tmp_path / "x_0001.png", out=tmp_path / "out", dir=tmp_path)
            for a in command]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("car-napari: ") and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_a_file_that_cannot_hold_the_pixels_is_refused_before_the_work(tmp_path, capsys):
    import tifffile

    tifffile.imwrite(tmp_path / "f.tif", np.random.default_rng(0).random((40, 40))
                     .astype(np.float32))
    io.imsave(tmp_path / "m.png", np.zeros((40, 40), np.uint8), check_contrast=False)
    assert main(["inpaint", str(tmp_path / "f.tif"), "-m", str(tmp_path / "m.png"),
                 "-o", str(tmp_path / "out.png")]) == 2
    assert "cannot write float32 grey pixels to out.png" in capsys.readouterr().err
    assert main(["restore", str(tmp_path / "f.tif"), "-o", str(tmp_path / "r.jpg")]) == 2
    assert "cannot write float32 grey pixels to r.jpg" in capsys.readouterr().err
    assert not (tmp_path / "out.png").exists() and not (tmp_path / "r.jpg").exists()


def test_segment_one_input_to_a_file(tmp_path):
    _noise_png(tmp_path / "x.png")
    assert main(["segment", str(tmp_path / "x.png"), "-o", str(tmp_path / "labels.png"),
                 "--segments", "2", "--levels", "1"]) == 0
    assert io.imread(tmp_path / "labels.png").shape == (40, 40)


def test_mammo_one_input_to_a_file_writes_its_table_beside_it(tmp_path):
    from car_napari.io.sample_data import mammogram

    (image, _, _), = mammogram()
    io.imsave(tmp_path / "mdb.png", image.reshape(256, 4, 256, 4).mean(axis=(1, 3))
              .astype(np.uint8))
    assert main(["mammo", str(tmp_path / "mdb.png"), "-o", str(tmp_path / "out" / "r.png")]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "r.csv", "r.png", "r_overlay.png"]
    assert (tmp_path / "out" / "r.csv").read_text().startswith("image,bit_depth,label,")
