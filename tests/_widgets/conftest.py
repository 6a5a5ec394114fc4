import pytest


@pytest.fixture
def docked(make_napari_viewer):
    """Factory: a real viewer with ``widget_class`` docked; returns both."""

    def make(widget_class, name):
        viewer = make_napari_viewer()
        widget = widget_class(viewer)
        viewer.window.add_dock_widget(widget, name=name)
        return viewer, widget

    return make


@pytest.fixture
def last_notification():
    """The message of napari's latest notification (errors the user sees)."""
    from napari.utils.notifications import notification_manager

    return lambda: str(notification_manager.records[-1].message)
