"""Command line: fit prints JSON, synthesize writes an image, errors are clear."""

import io as io_module
import json
import re
import subprocess
import sys

import numpy as np
import pytest
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


def test_segment_merge_regions(tmp_path, capsys):
    """--merge-regions is segment's region_threshold: never more segments
    than without it; with --segments it is refused before any work."""
    a, b = skdata.brick()[:96, :48], skdata.grass()[:96, :48]
    io.imsave(tmp_path / "one.png", np.concatenate([a, b], axis=1))
    options = [str(tmp_path / "one.png"), "--levels", "2"]
    assert main(["segment", *options, "-o", str(tmp_path / "plain.png")]) == 0
    assert main(["segment", *options, "-o", str(tmp_path / "merged.png"),
                 "--merge-regions", "0.1"]) == 0
    plain, merged = (io.imread(tmp_path / f"{n}.png") for n in ("plain", "merged"))
    assert 1 <= len(np.unique(merged[merged > 0])) <= len(np.unique(plain[plain > 0]))
    capsys.readouterr()
    assert main(["segment", *options, "-o", str(tmp_path / "x.png"), "--segments", "2",
                 "--merge-regions", "0.1"]) == 2
    assert "drop --segments or --merge-regions" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_bad_order_is_a_usage_error(tmp_path, capsys):
    import pytest

    path = tmp_path / "gravel.png"
    io.imsave(path, skdata.gravel()[:48, :48])
    with pytest.raises(SystemExit) as exit_info:
        main(["fit", str(path), "--order", "abc"])
    assert exit_info.value.code == 2
    assert "'auto' or a positive integer" in capsys.readouterr().err


def test_mammo_writes_labels_and_one_table(tmp_path, capsys):
    import csv

    import pytest

    from car_napari.io.sample_data import mammogram
    from car_napari.mammography import TABLE_COLUMNS

    (image, _, _), = mammogram()
    small = image.reshape(256, 4, 256, 4).mean(axis=(1, 3)).astype(np.uint8)
    src = tmp_path / "in"
    src.mkdir()
    io.imsave(src / "mdb001.png", small)
    io.imsave(src / "black.png", np.zeros((64, 64), np.uint8), check_contrast=False)
    inputs = [str(src / "*.png")]
    pytest.importorskip("pydicom")
    from dicom_files import write_dicom

    write_dicom(src / "mdb001.dcm", small.astype(np.uint16) * 16, bits=12)
    inputs.append(str(src / "mdb001.dcm"))
    out = tmp_path / "out"
    assert main(["mammo", *inputs, "-o", str(out), "--max-regions", "0",
                 "--tolerance", "0.3"]) == 1  # some inputs failed (black.png)
    err = capsys.readouterr().err
    assert "black.png: failed" in err and "constant" in err
    labels = io.imread(out / "mdb001_rois.png")
    assert labels.shape == small.shape and labels.max() >= 1
    # the overlay a person opens: the mammogram in grey, region 1 outlined in yellow
    overlay = io.imread(out / "mdb001_overlay.png")
    assert overlay.shape == (*small.shape, 3) and overlay.dtype == np.uint8
    assert np.all(overlay[labels == 0][:, 0] == overlay[labels == 0][:, 2])
    assert (np.all(overlay == (255, 255, 0), axis=-1) & (labels == 1)).any()
    with open(out / "rois.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert set(rows[0]) == {"image", "bit_depth", *TABLE_COLUMNS}
    png = [r for r in rows if r["image"] == "mdb001.png"]
    assert len(png) == labels.max()
    assert {r["bit_depth"] for r in png} == {"8-bit"}
    assert {r["image"] for r in rows} == {"mdb001.png", "mdb001.dcm"}
    assert main(["mammo", str(src / "black.png"), "-o", str(out)]) == 2


def test_restore_single_and_stack(tmp_path, capsys):
    import tifffile

    rng = np.random.default_rng(0)
    clean = skdata.camera()[:64, :64] / 255.0
    noisy = np.clip(clean + rng.normal(0, 0.05, clean.shape), 0, 1)
    src = tmp_path / "in"
    src.mkdir()
    io.imsave(src / "noisy.png", np.round(noisy * 255).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["restore", str(src / "noisy.png"), "-o", str(out), "--probability"]) == 0
    restored = io.imread(out / "noisy_restored.png")
    assert restored.shape == (64, 64) and restored.dtype == np.uint8
    probability = tifffile.imread(out / "noisy_probability.tif")
    assert probability.shape == (64, 64) and 0 <= probability.min() <= probability.max() <= 1
    stack = np.stack([clean + rng.normal(0, 0.05, clean.shape) for _ in range(3)], axis=-1)
    tifffile.imwrite(src / "burst.tif", stack.astype(np.float32))
    assert main(["restore", str(src / "burst.tif"), "-o", str(out), "--stack-axis", "2",
                 "--kappa", "0.1"]) == 0
    restored = tifffile.imread(out / "burst_restored.tif")
    assert restored.shape == (64, 64) and restored.dtype == np.float32
    assert "reference version" in capsys.readouterr().out
    assert main(["restore", str(src / "noisy.png"), "-o", str(out), "--stack-axis", "0",
                 "--overwrite"]) == 2
    assert "stack" in capsys.readouterr().err


def test_restore_bad_kappa_is_a_usage_error(tmp_path, capsys):
    import pytest

    with pytest.raises(SystemExit):
        main(["restore", "x.png", "-o", str(tmp_path), "--kappa", "1.5"])
    assert "kappa must be in [0, 1)" in capsys.readouterr().err


def test_inpaint_and_descratch(tmp_path, capsys):
    frame = skdata.astronaut()[:96, :96].copy()
    frame[:, 40:43] = 255
    mask = np.zeros((48, 48), np.uint8)  # drawn at half resolution
    mask[:, 20:22] = 255
    io.imsave(tmp_path / "frame.png", frame)
    io.imsave(tmp_path / "mask.png", mask, check_contrast=False)
    out = tmp_path / "out.png"
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(tmp_path / "mask.png"),
                 "-o", str(out)]) == 0
    restored = io.imread(out)
    assert restored.shape == frame.shape and np.all(restored[:, 41] != 255)
    np.testing.assert_array_equal(restored[:, :38], frame[:, :38])
    frames = tmp_path / "frames"
    frames.mkdir()
    base = skdata.camera()[:80, :80]
    for t in range(4):
        f = base.copy()
        f[:, 30 + 5 * t : 32 + 5 * t] = 250
        io.imsave(frames / f"{t + 1:04d}.png", f)
    assert main(["descratch", str(frames), "-o", str(tmp_path / "clean"), "--masks"]) == 0
    cleaned = io.imread(tmp_path / "clean" / "0003.png")
    assert np.abs(cleaned[:, 40:42].astype(int) - base[:, 40:42]).mean() < 25
    assert (tmp_path / "clean" / "0004_mask.png").exists()
    assert main(["descratch", str(tmp_path / "nothing"), "-o", str(tmp_path / "x")]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_fit_texture_then_synthesize_from_the_model(tmp_path, capsys):
    src = tmp_path / "gravel.png"
    io.imsave(src, skdata.gravel()[:128, :128])
    model = tmp_path / "gravel.npz"
    assert main(["fit-texture", str(src), "-o", str(model)]) == 0
    assert "compression" in capsys.readouterr().err
    assert model.stat().st_size < 10_000
    out = tmp_path / "big.png"
    assert main(["synthesize", str(model), "-o", str(out), "--size", "200", "300",
                 "--seed", "2", "--tileable"]) == 0
    big = io.imread(out)
    assert big.shape == (200, 300) and big.dtype == np.uint8
    assert main(["synthesize", str(model), "-o", str(tmp_path / "x.gif2")]) == 2
    assert "use .png" in capsys.readouterr().err
    (tmp_path / "broken.npz").write_bytes(b"not a model")
    assert main(["synthesize", str(tmp_path / "broken.npz"), "-o", str(out)]) == 2
    assert "not a readable" in capsys.readouterr().err


def test_retrieve_ranks_a_folder(tmp_path, capsys):
    from car_napari.io.sample_data import colour_texture

    vistex = colour_texture()[0][0]
    gallery = tmp_path / "gallery"
    gallery.mkdir()
    io.imsave(gallery / "same.png", vistex[128:])
    io.imsave(gallery / "cells.png", skdata.immunohistochemistry()[:128, :256])
    io.imsave(gallery / "coffee.png", skdata.coffee()[:128, :256])
    io.imsave(gallery / "grey.png", skdata.camera()[:128, :256])
    io.imsave(tmp_path / "query.png", vistex[:128])
    assert main(["retrieve", str(tmp_path / "query.png"), str(gallery), "--top", "2"]) == 0
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert len(lines) == 2 and lines[0].endswith("same.png")
    assert "grey.png" in captured.err
    assert main(["retrieve", str(tmp_path / "query.png"), str(tmp_path / "nope")]) == 2


def test_no_inputs_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["mammo", str(tmp_path / "none*.png"), "-o", str(out)]) == 2
    assert "no input images" in capsys.readouterr().err
    assert not (out / "rois.csv").exists()


class _Terminal(io_module.StringIO):
    def isatty(self):
        return True


def test_progress_bar_on_a_terminal(monkeypatch):
    from car_napari._progress import Progress
    from car_napari.cli._console import ProgressBar

    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    with ProgressBar(4, unit="image") as bar:
        bar.begin(2, "c.png")
        bar.on_progress(Progress("rows", 0.5))
        bar.write("c.png: done", err=True)
    text = err.getvalue()
    assert " 62%" in text and "3/4 c.png" in text and "c.png: done\n" in text


def test_restore_drives_the_bar_to_the_end(tmp_path, monkeypatch):
    from car_napari.cli._console import ProgressBar

    noisy = np.random.default_rng(1).integers(0, 256, (40, 40)).astype(np.uint8)
    io.imsave(tmp_path / "noisy.png", noisy, check_contrast=False)
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    fractions = []
    on_progress = ProgressBar.on_progress

    def spy(bar, record):
        fractions.append(record.fraction)
        on_progress(bar, record)

    monkeypatch.setattr(ProgressBar, "on_progress", spy)
    assert main(["restore", str(tmp_path / "noisy.png"), "-o", str(tmp_path / "out")]) == 0
    assert any(0 < f < 1 for f in fractions)  # the bar moved within the image
    percents = [int(p) for p in re.findall(r"(\d+)%\|", err.getvalue())]
    assert percents[-1] == 100
    assert (tmp_path / "out" / "noisy_restored.png").exists()


# --- bad input: one line per failed file, the batch goes on (issue 15) -------------------

def _noise_png(path, seed=0, shape=(64, 64)):
    io.imsave(path, (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8))


def test_a_bad_file_is_reported_and_the_batch_goes_on(tmp_path, capsys):
    _noise_png(tmp_path / "a.png")
    (tmp_path / "b.png").write_text("not an image")
    _noise_png(tmp_path / "c.png", seed=1)
    out = tmp_path / "out"
    assert main(["segment", str(tmp_path / "*.png"), "-o", str(out), "--segments", "2",
                 "--levels", "1"]) == 1
    err = capsys.readouterr().err
    assert re.search(r"b\.png: failed: cannot read .*b\.png", err)
    assert "pip install" not in err  # imageio's install hints are not the user's problem
    assert sorted(p.name for p in out.iterdir()) == ["a_segments.png", "c_segments.png"]


def test_a_batch_where_nothing_succeeds_exits_2(tmp_path, capsys):
    (tmp_path / "fake.dcm").write_bytes(b"not a dicom")
    (tmp_path / "empty.dcm").write_bytes(b"")
    assert main(["segment", str(tmp_path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "empty.dcm: failed: cannot read" in err and "the file is empty" in err
    assert "fake.dcm: failed: cannot read" in err and "no input could be processed" in err


def test_a_multipage_tiff_is_a_stack_not_colour(tmp_path, capsys):
    import tifffile

    from car_napari.io.images import read_image

    frames = (np.random.default_rng(0).random((3, 48, 40)) * 255).astype(np.uint8)
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, frames, photometric="minisblack")
    np.testing.assert_array_equal(read_image(path), frames)
    assert main(["segment", str(path), "-o", str(tmp_path / "out")]) == 2
    assert "holds a stack of shape (3, 48, 40)" in capsys.readouterr().err


def test_grey_plus_alpha_is_grey_with_a_note(tmp_path, capsys):
    from car_napari.io.images import read_image

    grey = (np.random.default_rng(0).random((32, 32)) * 255).astype(np.uint8)
    path = tmp_path / "ga.png"
    io.imsave(path, np.dstack([grey, np.full_like(grey, 255)]))
    notes = []
    np.testing.assert_array_equal(read_image(path, on_note=notes.append), grey)
    assert notes == ["ga.png: alpha channel dropped"]


def test_outputs_go_to_a_format_that_holds_them(tmp_path):
    from car_napari.cli._files import image_suffix
    from car_napari.io.images import read_image, write_image

    rgb16 = np.random.default_rng(0).integers(0, 65535, (8, 8, 3)).astype(np.uint16)
    assert image_suffix(rgb16, "x.png") == ".tif"
    assert image_suffix(rgb16[..., 0], "x.png") == ".png"
    with pytest.raises(ValueError, match="Write a .tif instead"):
        write_image(tmp_path / "x.png", rgb16)
    write_image(tmp_path / "x.tif", rgb16)
    np.testing.assert_array_equal(read_image(tmp_path / "x.tif"), rgb16)


@pytest.mark.parametrize("argv, match", [
    (["mammo", "{img}", "-o", "{out}", "--tolerance", "-1"], "--tolerance: must be"),
    (["mammo", "{img}", "-o", "{out}", "--max-regions", "-1"], "--max-regions: must be"),
    (["retrieve", "{img}", "{dir}", "--top", "-1"], "--top: must be a positive"),
    (["segment", "{img}", "-o", "{out}", "--levels", "0"], "--levels: must be a positive"),
    (["synthesize", "{img}", "-o", "{out}.png", "--size", "0", "5"], "--size: must be"),
])
def test_option_values_are_checked_before_any_work(tmp_path, capsys, argv, match):
    _noise_png(tmp_path / "q.png")
    args = [a.format(img=tmp_path / "q.png", out=tmp_path / "out", dir=tmp_path) for a in argv]
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    assert exit_info.value.code == 2 and match in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_fit_texture_of_a_model_file_says_what_to_do(tmp_path, capsys):
    (tmp_path / "m.npz").write_bytes(b"")
    assert main(["fit-texture", str(tmp_path / "m.npz"), "-o", str(tmp_path / "n.npz")]) == 2
    assert "is a model file" in capsys.readouterr().err


# --- batches on a dask cluster (issue 16) -------------------------------------------------

def _mosaics(folder, count=3):
    folder.mkdir()
    textures = [skdata.brick(), skdata.grass(), skdata.gravel()]
    for k in range(count):
        a, b = textures[k % 3], textures[(k + 1) % 3]
        io.imsave(folder / f"m{k}.png", np.concatenate([a[:64, :32], b[:64, :32]], axis=1))


def test_a_local_cluster_writes_what_the_serial_run_writes(tmp_path, capsys):
    pytest.importorskip("dask.distributed")
    _mosaics(tmp_path / "in")
    (tmp_path / "in" / "broken.png").write_text("not an image")
    options = ["--segments", "2", "--levels", "1"]
    assert main(["segment", str(tmp_path / "in"), "-o", str(tmp_path / "serial"), *options]) == 1
    assert main(["segment", str(tmp_path / "in"), "-o", str(tmp_path / "cluster"), *options,
                 "--workers", "2"]) == 1
    err = capsys.readouterr().err
    assert err.count("broken.png: failed: cannot read") == 2  # reported, the rest went on
    serial = sorted(p.name for p in (tmp_path / "serial").iterdir())
    assert serial == ["m0_segments.png", "m1_segments.png", "m2_segments.png"]
    for name in serial:
        np.testing.assert_array_equal(io.imread(tmp_path / "cluster" / name),
                                      io.imread(tmp_path / "serial" / name))


def test_a_rerun_skips_what_exists_unless_overwrite(tmp_path, capsys):
    _mosaics(tmp_path / "in", count=2)
    out = tmp_path / "out"
    options = ["segment", str(tmp_path / "in"), "-o", str(out), "--segments", "2", "--levels", "1"]
    assert main(options) == 0
    first = (out / "m0_segments.png").stat().st_mtime_ns
    capsys.readouterr()
    assert main(options) == 0
    assert "2 of 2 inputs skipped" in capsys.readouterr().err
    assert (out / "m0_segments.png").stat().st_mtime_ns == first
    assert main([*options, "--overwrite"]) == 0
    assert (out / "m0_segments.png").stat().st_mtime_ns > first


def test_cluster_options_without_dask_say_what_to_install(tmp_path, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.startswith("dask"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    _mosaics(tmp_path / "in", count=1)
    monkeypatch.setattr(builtins, "__import__", no_dask)
    assert main(["segment", str(tmp_path / "in"), "-o", str(tmp_path / "out"),
                 "--workers", "2"]) == 2
    assert "pip install 'car-napari[cluster]'" in capsys.readouterr().err


@pytest.mark.parametrize("command", [
    ["inpaint", "{missing}", "-m", "{mask}", "-o", "{out}.png"],
    ["inpaint", "{missing}", "-m", "{mask}", "-o", "{out}"],
    ["inpaint", "{frame}", "-m", "{missing}", "-o", "{out}"],
    ["restore", "{missing}", "-o", "{out}"],
    ["segment", "{missing}", "-o", "{out}"],
    ["mammo", "{missing}", "-o", "{out}"],
])
def test_missing_inputs_leave_no_output_folder(tmp_path, capsys, command):
    """`inpaint missing.png -o out.png` left an empty folder out.png."""
    frame, mask = tmp_path / "frame.png", tmp_path / "mask.png"
    io.imsave(frame, skdata.camera()[:32, :32])
    io.imsave(mask, np.zeros((32, 32), np.uint8), check_contrast=False)
    names = dict(missing=tmp_path / "missing.png", mask=mask, frame=frame,
                 out=tmp_path / "out")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main([part.format(**names) for part in command]) == 2
    assert "no such" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_mammo_tissue_writes_density_and_class(tmp_path):
    import csv

    from car_napari.io.sample_data import mammogram
    from car_napari.mammography import TISSUE_CLASSES, analyse_mammogram

    (image, _, _), = mammogram()
    small = image.reshape(256, 4, 256, 4).mean(axis=(1, 3)).astype(np.uint8)
    src = tmp_path / "in"
    src.mkdir()
    io.imsave(src / "mdb001.png", small)
    out = tmp_path / "out"
    assert main(["mammo", str(src / "mdb001.png"), "-o", str(out), "--tissue", "--quiet"]) == 0
    rois, tissue = analyse_mammogram(small)
    mask = io.imread(out / "mdb001_tissue.png")
    np.testing.assert_array_equal(mask > 0, tissue.fibroglandular)
    np.testing.assert_array_equal(io.imread(out / "mdb001_rois.png"), rois.labels)
    with open(out / "tissue.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1 and rows[0]["image"] == "mdb001.png"
    assert float(rows[0]["density_percent"]) == pytest.approx(
        100.0 * (mask > 0).sum() / tissue.breast.sum(), abs=0.01)
    assert rows[0]["tissue_class"] == tissue.tissue_class
    assert sum(float(rows[0][f"p_{c}"]) for c in TISSUE_CLASSES) == pytest.approx(1, abs=1e-3)
    # without the switch: no tissue outputs
    out2 = tmp_path / "out2"
    assert main(["mammo", str(src / "mdb001.png"), "-o", str(out2), "--quiet"]) == 0
    assert not (out2 / "tissue.csv").exists() and not (out2 / "mdb001_tissue.png").exists()


def test_fit_texture_levels_are_the_widgets(tmp_path):
    """No --levels: TextureModel.levels_for the texture (5, fewer when small),
    as the widget; --levels N is the most, fewer for a small texture."""
    from car_napari.texture import TextureModel

    small, large = tmp_path / "small.png", tmp_path / "in" / "large.png"
    large.parent.mkdir()
    io.imsave(small, skdata.gravel()[:128, :128])
    io.imsave(large, skdata.gravel()[:512, :512])
    assert TextureModel.levels_for((128, 128)) == 4
    for src, options, levels in ((small, [], 4), (small, ["--levels", "8"], 4),
                                 (small, ["--levels", "2"], 2), (large, [], 5)):
        out = tmp_path / f"{src.stem}{len(options)}{levels}.npz"
        assert main(["fit-texture", str(src), "-o", str(out), "--quiet", *options]) == 0
        assert TextureModel.load(out).levels == levels, (src, options)
    # several textures into a folder: the same rule
    assert main(["fit-texture", str(large.parent), "-o", str(tmp_path / "models"), "--quiet"]) == 0
    assert TextureModel.load(tmp_path / "models" / "large.npz").levels == 5
