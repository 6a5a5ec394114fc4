"""``car-napari fit-texture``: fit a multiresolution texture model and write
it (a few kB)."""

from __future__ import annotations

import time
from pathlib import Path

from ._arguments import add_batch_options, add_inputs, add_order, positive_int
from ._batch import run_batch
from ._console import say
from ._files import channel_axis, expand_inputs, output_file, output_folder, read_one_image


def add_parser(sub):
    p = sub.add_parser("fit-texture", help="fit a multiresolution texture model; write it "
                                           "(.npz, a few kB)")
    add_inputs(p, "example texture (grey or RGB); or several, folders or globs with -o "
                  "FOLDER (a model <name>.npz each)", name="sources",
               output="model file (.npz), or a folder for several textures")
    p.add_argument("--levels", type=positive_int, default=None,
                   help="the most pyramid levels (default 5, as the widget); fewer for a "
                        "small texture (TextureModel.levels_for)")
    add_order(p)
    add_batch_options(p, run)


def fit_levels(image, levels):
    """The pyramid levels of a fit to ``image``, as the widget chooses them:
    :meth:`TextureModel.levels_for` its size, with at most ``levels`` (None:
    the default most, 5)."""
    from ..texture import TextureModel

    if levels is None:
        return TextureModel.levels_for(image.shape[:2])
    return TextureModel.levels_for(image.shape[:2], levels)


def texture_model(args):
    """(model, example image): a TextureModel loaded from a saved model
    (.npz; no image) or fitted to an example image (at most ``args.levels``
    levels, see :func:`fit_levels`; ``args.order``)."""
    from ..texture import TextureModel

    if str(args.source).lower().endswith(".npz"):
        if not Path(args.source).is_file():
            raise ValueError(f"no such file: {args.source}")
        return TextureModel.load(args.source), None
    image = read_one_image(args.source)
    model = TextureModel.fit(image, levels=fit_levels(image, args.levels),
                             neighbourhood=args.order, channel_axis=channel_axis(image))
    return model, image


def run(args):
    paths = expand_inputs(args.sources)
    target = output_file(args.output, paths, suffixes={".npz"}, what="a model")
    if not target:
        return run_many(args, paths)
    args.source, args.output = paths[0], target
    if str(args.source).lower().endswith(".npz"):
        raise ValueError(f"{args.source} is a model file; fit-texture fits a model to an "
                         "example image (PNG, TIFF, ...). To synthesise from a saved model, "
                         "use 'car-napari synthesize MODEL.npz'.")
    model, image = texture_model(args)
    model.save(args.output)
    say(f"wrote {args.output}: orders {list(model.orders)} per band, {model.nbytes} bytes "
          f"of parameters, compression {model.compression_ratio(image.shape):.0f}:1 at "
        f"{'x'.join(map(str, image.shape))}")


def run_many(args, paths):
    """Several textures, a model file each in the folder ``args.output``
    (one task per texture, on a dask cluster with --workers)."""
    from ..texture import TextureModel

    out = output_folder(args.output)
    levels, order = args.levels, args.order

    def outputs(path):
        return [out / f"{path.stem}.npz"]

    def process(path, on_progress):
        t0 = time.perf_counter()
        if path.suffix.lower() == ".npz":
            raise ValueError("a model file, not an example image")
        image = read_one_image(path)
        model = TextureModel.fit(image, levels=fit_levels(image, levels), neighbourhood=order,
                                 channel_axis=channel_axis(image))
        model.save(outputs(path)[0])
        return (f"orders {list(model.orders)}, {model.nbytes} bytes, "
                f"{time.perf_counter() - t0:.1f} s")

    return run_batch([Path(p) for p in paths], process, outputs=outputs, options=args,
                     quiet=args.quiet, unit="texture")
