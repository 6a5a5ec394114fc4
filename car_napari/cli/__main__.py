"""``python -m car_napari.cli``: the car-napari command."""

import sys

from . import main

sys.exit(main())
