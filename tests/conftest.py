import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from car_fields import SHARED_DATA  # noqa: E402


@pytest.fixture
def shared_data():
    """The real data beside the repository; skip where a clone lacks it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone with ../shared beside it)")
    return SHARED_DATA
