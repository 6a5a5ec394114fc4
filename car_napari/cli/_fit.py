"""``car-napari fit``: fit a CAR model and print it as JSON."""

from __future__ import annotations

import json
import sys

from ..io.images import read_image
from ._arguments import add_order
from ._console import print_note
from ._files import channel_axis, one_image


def add_parser(sub):
    p = sub.add_parser("fit", help="fit a CAR model and print it as JSON")
    p.add_argument("image", help="image file (grey or RGB)")
    add_order(p)
    p.set_defaults(run=run)


def run(args):
    from ..model import fit_car

    image = one_image(read_image(args.image, on_note=print_note), args.image)
    model = fit_car(image, args.order, channel_axis=channel_axis(image))
    json.dump(model.to_dict(), sys.stdout, indent=2)
    sys.stdout.write("\n")
