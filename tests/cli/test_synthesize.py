"""``car-napari synthesize``: its help, a missing model file."""

import pytest

from car_napari.cli import main


def test_help_says_size_and_seed(capsys):
    with pytest.raises(SystemExit):
        main(["synthesize", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "height and width of the texture in pixels (default 256 256)" in text
    assert "random seed" in text


def test_a_missing_model_file_says_no_such_file(tmp_path, capsys):
    missing = tmp_path / "gone.npz"
    assert main(["synthesize", str(missing), "-o", str(tmp_path / "t.png")]) == 2
    err = capsys.readouterr().err
    assert f"no such file: {missing}" in err and "Errno" not in err
