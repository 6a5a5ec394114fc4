"""The README's first quick-start command, ``bash .ci/demo``, runs
``python -m car_napari._widgets.demo``: napari with the samples and the CAR
model widget docked on the texture. Here without its event loop (``--no-run``)."""

from car_napari._widgets.car_model import CARModelWidget
from car_napari._widgets.demo import main


def test_the_demo_opens_the_samples_with_the_car_model_widget_on_the_texture(qtbot):
    viewer, widget = main(["--no-run"])
    try:
        assert [layer.name for layer in viewer.layers] == [
            "damaged film", "damaged film scratch mask", "mini-MIAS mdb001", "VisTex VS50"]
        assert all(layer.data.size > 0 for layer in viewer.layers)
        assert isinstance(widget, CARModelWidget)
        assert widget._image.value is viewer.layers["VisTex VS50"]
        assert "CAR model (car-napari)" in viewer.window.dock_widgets
    finally:
        viewer.close()
