"""``python -m car_napari._widgets.demo``: napari with the CAR model widget and samples."""

from __future__ import annotations

import sys


def main(argv=None):
    import napari

    viewer = napari.Viewer(title="car-napari")
    for key in ("film", "mammogram", "texture"):
        viewer.open_sample("car-napari", key)
    _, widget = viewer.window.add_plugin_dock_widget("car-napari", "CAR model")
    widget._image.value = viewer.layers["VisTex VS50"]
    if "--no-run" not in (sys.argv[1:] if argv is None else argv):
        napari.run()
    return viewer, widget


if __name__ == "__main__":
    main()
