"""``car-napari fit-texture``: fit a multiresolution texture model and write
it (a few kB)."""

from __future__ import annotations

import sys

from ..io.images import read_image
from ._common import add_order, add_output, channel_axis, one_image, positive_int, print_note


def add_parser(sub):
    p = sub.add_parser("fit-texture", help="fit a multiresolution texture model; write it "
                                           "(.npz, a few kB)")
    p.add_argument("source", help="example texture (grey or RGB)")
    add_output(p, "model file (.npz)")
    p.add_argument("--levels", type=positive_int, default=3, help="pyramid levels (default 3)")
    add_order(p)
    p.set_defaults(run=run)


def texture_model(args):
    """(model, example image): a TextureModel loaded from a saved model
    (.npz; no image) or fitted to an example image (``args.levels``,
    ``args.order``)."""
    from ..texture import TextureModel

    if str(args.source).lower().endswith(".npz"):
        return TextureModel.load(args.source), None
    image = one_image(read_image(args.source, on_note=print_note), args.source)
    model = TextureModel.fit(image, levels=args.levels, neighbourhood=args.order,
                             channel_axis=channel_axis(image))
    return model, image


def run(args):
    if str(args.source).lower().endswith(".npz"):
        raise ValueError(f"{args.source} is a model file; fit-texture fits a model to an "
                         "example image (PNG, TIFF, ...). To synthesise from a saved model, "
                         "use 'car-napari synthesize MODEL.npz'.")
    model, image = texture_model(args)
    model.save(args.output)
    print(f"wrote {args.output}: orders {list(model.orders)} per band, {model.nbytes} bytes "
          f"of parameters, compression {model.compression_ratio(image.shape):.0f}:1 at "
          f"{'x'.join(map(str, image.shape))}", file=sys.stderr)
