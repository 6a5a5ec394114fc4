"""``car-napari descratch``: reruns, frames without a number, the progress bar (issue 32)."""

import io as io_module
import re
import sys

from skimage import data as skdata
from skimage import io

from car_napari.cli import main


def _frames(folder, count=4):
    folder.mkdir()
    base = skdata.camera()[:48, :48]
    for t in range(count):
        f = base.copy()
        f[:, 10 + 5 * t : 12 + 5 * t] = 250
        io.imsave(folder / f"{t + 1:04d}.png", f)
    return folder


def test_a_rerun_skips_the_clip_unless_overwrite(tmp_path, capsys):
    args = ["descratch", str(_frames(tmp_path / "in")), "-o", str(tmp_path / "out")]
    assert main(args) == 0
    first = (tmp_path / "out" / "0001.png").stat().st_mtime_ns
    capsys.readouterr()
    assert main(args) == 0
    assert "4 of 4 frames skipped: their outputs exist" in capsys.readouterr().err
    assert (tmp_path / "out" / "0001.png").stat().st_mtime_ns == first
    assert main([*args, "--overwrite"]) == 0
    assert (tmp_path / "out" / "0001.png").stat().st_mtime_ns > first


def test_a_rerun_over_some_outputs_is_refused(tmp_path, capsys):
    _frames(tmp_path / "in")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "0002.png").write_bytes(b"")  # a run stopped early
    args = ["descratch", str(tmp_path / "in"), "-o", str(tmp_path / "out")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "holds 1 of the clip's 4 output files (e.g. 0002.png)" in err and "--overwrite" in err
    assert main([*args, "--masks"]) == 2  # the masks count too: 1 of 8
    assert "1 of the clip's 8" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    assert io.imread(tmp_path / "out" / "0002.png").shape == (48, 48)


def test_frames_without_a_number_are_named(tmp_path, capsys):
    folder = _frames(tmp_path / "in", count=3)
    io.imsave(folder / "title.png", skdata.camera()[:48, :48])
    assert main(["descratch", str(folder), "-o", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "1 image(s) of" in err and "skipped, no frame number in the name: title.png" in err
    assert not (tmp_path / "out" / "title.png").exists()


class _Terminal(io_module.StringIO):
    def isatty(self):
        return True


def test_the_bar_counts_the_frame_its_percentage_is_at(tmp_path, monkeypatch):
    from car_napari._progress import Progress
    from car_napari.cli._console import ProgressBar

    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    with ProgressBar(55, unit="frame") as bar:
        bar.begin(0, "frames", span=55)
        bar.on_progress(Progress("frames", 0.5))
    assert " 50%" in err.getvalue() and "28/55 frames" in err.getvalue()

    folder = _frames(tmp_path / "in")
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["descratch", str(folder), "-o", str(tmp_path / "out")]) == 0
    states = re.findall(r"(\d+)%\|[^\r\n]*? (\d)/4 frames", err.getvalue())
    assert states and states[-1] == ("100", "4")
    for percent, frame in states:  # the frame shown holds the percentage
        assert (int(frame) - 1) * 25 <= int(percent) <= int(frame) * 25
