"""``python -m car_napari.demo``: napari with the CAR model widget and samples."""

from __future__ import annotations

import sys


def main(argv=None):
    import napari

    viewer = napari.Viewer(title="car-napari")
    for key in ("film", "mammogram", "texture"):
        viewer.open_sample("car-napari", key)
    viewer.window.add_plugin_dock_widget("car-napari", "CAR model")
    if "--no-run" not in (argv or sys.argv[1:]):
        napari.run()
    return viewer


if __name__ == "__main__":
    main()
