"""``car-napari fit``: fit a CAR model and print it as JSON."""

from __future__ import annotations

import json
import sys

from ._arguments import add_order
from ._files import channel_axis, read_one_image


def add_parser(sub):
    p = sub.add_parser("fit", help="fit a CAR model and print it as JSON")
    p.add_argument("image", help="image file (grey or RGB)")
    add_order(p)
    p.set_defaults(run=run)


def run(args):
    from ..model import fit_car

    image = read_one_image(args.image)
    model = fit_car(image, args.order, channel_axis=channel_axis(image))
    json.dump(model.to_dict(), sys.stdout, indent=2)
    sys.stdout.write("\n")
