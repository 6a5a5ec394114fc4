"""``car-napari retrieve``: the core's advice said the command line's way."""

import numpy as np
from skimage import data as skdata
from skimage import io

from car_napari.cli import main


def test_grey_stored_as_rgb_is_told_the_cli_way(tmp_path, capsys):
    gallery = tmp_path / "gallery"
    gallery.mkdir()
    io.imsave(gallery / "colour.png", skdata.astronaut()[:96, :96])
    grey = skdata.camera()[:96, :96]
    io.imsave(tmp_path / "q.png", np.dstack([grey] * 3))
    assert main(["retrieve", str(tmp_path / "q.png"), str(gallery)]) == 2
    err = capsys.readouterr().err
    assert "the query q.png: " in err and "linearly dependent" in err
    assert "Save it as a grey (one-channel) image" in err and "channel_axis" not in err
