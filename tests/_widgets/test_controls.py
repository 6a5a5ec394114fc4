"""Every dock widget's controls speak the user's words and explain themselves."""

import re

import pytest
from magicgui.widgets import Container, Label, ProgressBar

from car_napari._widgets.car_model import CARModelWidget
from car_napari._widgets.inpainting import InpaintingWidget
from car_napari._widgets.mammography import MammogramWidget
from car_napari._widgets.restoration import RestorationWidget
from car_napari._widgets.retrieval import TextureRetrievalWidget
from car_napari._widgets.segmentation import SegmentationWidget
from car_napari._widgets.texture import TextureSynthesisWidget

DOCK_WIDGETS = [CARModelWidget, SegmentationWidget, MammogramWidget, RestorationWidget,
                InpaintingWidget, TextureSynthesisWidget, TextureRetrievalWidget]

# an equation or section number of the book: "(14.40)", "(14.", "section 14.5", "eq. 3"
NUMBERED = re.compile(r"\(\s*\d+\.|\bsection\s+\d|\beq(uation)?\.?\s*\d|\b\d+\.\d+\)", re.I)


def controls(container):
    """The controls of a magicgui container, nested ones too (not the
    read-only labels and the progress bar)."""
    for widget in container:
        if isinstance(widget, Container):
            yield from controls(widget)
        elif not isinstance(widget, (Label, ProgressBar)):
            yield widget


def test_manifest_lists_every_dock_widget():
    from pathlib import Path

    manifest = (Path(__file__).parents[2] / "car_napari" / "napari.yaml").read_text()
    listed = set(re.findall(r"python_name: car_napari\._widgets\.\w+:(\w+)", manifest))
    assert listed == {cls.__name__ for cls in DOCK_WIDGETS}


@pytest.mark.parametrize("widget_class", DOCK_WIDGETS, ids=lambda cls: cls.__name__)
def test_controls_have_user_words_and_a_tooltip(docked, widget_class):
    """Issue 32 item 12: no label carries an equation or section number (it
    goes in the tooltip), and every visible control has a tooltip."""
    _, w = docked(widget_class, widget_class.__name__)
    found = list(controls(w))
    assert len(found) >= 3
    problems = []
    for control in found:
        words = " ".join(str(text) for text in (control.label, getattr(control, "text", ""))
                         if text)
        if NUMBERED.search(words):
            problems.append(f"{words!r} carries a number of the book")
        if not control.native.isHidden() and not (control.tooltip or "").strip():
            problems.append(f"{words!r} has no tooltip")
    assert not problems, f"{widget_class.__name__}: " + "; ".join(problems)
