import os
import sys
from importlib.util import find_spec
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

# pytest-qt tries PyQt6 before PyQt5 and qtpy (so napari) then follows whatever is imported; with
# both bindings installed (CI) tell pytest-qt qtpy's choice: $QT_API, else PyQt5 first. This file
# is loaded before pytest-qt configures itself.
_BINDINGS = {"pyqt5": "PyQt5", "pyqt6": "PyQt6", "pyside6": "PySide6"}
if "PYTEST_QT_API" not in os.environ:
    _wanted = os.environ.get("QT_API", "").lower()
    _api = _wanted or next((api for api, mod in _BINDINGS.items() if find_spec(mod)), None)
    if _api in _BINDINGS:
        os.environ["PYTEST_QT_API"] = _api

from car_fields import SHARED_DATA  # noqa: E402


@pytest.fixture
def shared_data():
    """The real data beside the repository; skip where a clone lacks it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone with ../shared beside it)")
    return SHARED_DATA
