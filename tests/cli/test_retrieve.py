"""``car-napari retrieve``: the core's advice said the command line's way;
one rule for grey saved as RGB; a query and a gallery of different kinds
compared in grey."""

import numpy as np
from skimage import data as skdata
from skimage import io
from skimage.color import rgb2gray

from car_napari.cli import main
from car_napari.texture import rank


def test_dependent_channels_are_told_the_cli_way(tmp_path, capsys):
    gallery = tmp_path / "gallery"
    gallery.mkdir()
    io.imsave(gallery / "colour.png", skdata.astronaut()[:96, :96])
    grey = skdata.camera()[:96, :96]
    # channels that are not equal but linearly dependent: not a grey file
    io.imsave(tmp_path / "q.png", np.dstack([grey, grey, 255 - grey]))
    assert main(["retrieve", str(tmp_path / "q.png"), str(gallery)]) == 2
    err = capsys.readouterr().err
    assert "the query q.png: " in err and "linearly dependent" in err
    assert "Save it as a grey (one-channel) image" in err and "channel_axis" not in err


def _ranked(out):
    """The file names of retrieve's output lines, nearest first."""
    return [line.split("\t")[2].rsplit("/", 1)[-1] for line in out.strip().splitlines()]


def test_grey_saved_as_rgb_is_grey_for_every_query(tmp_path, capsys):
    # issue 32, point 7: such files were `failed` for a colour query, `skipped` for a grey one
    gallery = tmp_path / "gallery"
    gallery.mkdir()
    io.imsave(gallery / "colour.png", skdata.astronaut()[:96, :96])
    io.imsave(gallery / "rgb_grey.png", np.dstack([skdata.camera()[:96, :96]] * 3))
    io.imsave(gallery / "grey.png", skdata.moon()[:96, :96])
    io.imsave(tmp_path / "grey_q.png", skdata.camera()[100:196, 100:196])
    io.imsave(tmp_path / "colour_q.png", skdata.astronaut()[100:196, 100:196])
    # a grey query: the file is compared as the grey image it holds
    assert main(["retrieve", str(tmp_path / "grey_q.png"), str(gallery)]) == 0
    captured = capsys.readouterr()
    assert sorted(_ranked(captured.out)) == ["grey.png", "rgb_grey.png"]
    assert "skipped (colour, the query is grey): colour.png" in captured.err
    assert "failed" not in captured.err
    # a colour query: the same file is skipped as grey, like grey.png
    assert main(["retrieve", str(tmp_path / "colour_q.png"), str(gallery)]) == 0
    captured = capsys.readouterr()
    assert _ranked(captured.out) == ["colour.png"]
    assert "skipped (grey, the query is colour): grey.png, rgb_grey.png" in captured.err
    assert "failed" not in captured.err
    # a grey query saved as RGB is a grey query: the same ranking as the grey file's
    io.imsave(tmp_path / "rgb_q.png", np.dstack([skdata.camera()[100:196, 100:196]] * 3))
    outputs = []
    for query in ("grey_q.png", "rgb_q.png"):
        assert main(["retrieve", str(tmp_path / query), str(gallery)]) == 0
        outputs.append(capsys.readouterr().out)
    assert outputs[0] == outputs[1]


def test_a_query_against_a_gallery_of_the_other_kind_is_compared_in_grey(tmp_path, capsys):
    # issue 32, point 7: a colour query against a grey gallery exited 2
    gallery = tmp_path / "gallery"
    gallery.mkdir()
    greys = {"camera.png": skdata.camera()[:96, :96], "moon.png": skdata.moon()[:96, :96],
             "rgb_text.png": np.dstack([skdata.text()[:96, :96]] * 3)}
    for name, image in greys.items():
        io.imsave(gallery / name, image)
    query = skdata.astronaut()[100:196, 100:196]
    io.imsave(tmp_path / "q.png", query)
    assert main(["retrieve", str(tmp_path / "q.png"), str(gallery)]) == 0
    captured = capsys.readouterr()
    assert "the gallery holds no colour image: the query q.png is compared in grey" \
        in captured.err
    names = sorted(greys)
    order, _ = rank(rgb2gray(query), [greys[n] if greys[n].ndim == 2 else greys[n][..., 0]
                                      for n in names])
    assert _ranked(captured.out) == [names[i] for i in order]
    # and a grey query against a colour gallery: the gallery in grey
    colours = tmp_path / "colours"
    colours.mkdir()
    io.imsave(colours / "astronaut.png", skdata.astronaut()[:96, :96])
    io.imsave(colours / "coffee.png", skdata.coffee()[:96, :96])
    io.imsave(tmp_path / "g.png", skdata.camera()[100:196, 100:196])
    assert main(["retrieve", str(tmp_path / "g.png"), str(colours)]) == 0
    captured = capsys.readouterr()
    assert "its colour images are compared in grey" in captured.err
    assert sorted(_ranked(captured.out)) == ["astronaut.png", "coffee.png"]
