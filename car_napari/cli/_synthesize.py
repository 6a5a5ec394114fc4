"""``car-napari synthesize``: a texture of any size from a model file or an
example image."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import from_unit
from ..io.images import write_image
from ._arguments import add_order, add_output, add_quiet, non_negative_int, positive_int
from ._console import say
from ._fit_texture import texture_model


def add_parser(sub):
    p = sub.add_parser("synthesize", help="synthesise a texture of any size from a model "
                                          "file or an example image")
    p.add_argument("source", help="model file (.npz from fit-texture) or example texture")
    add_output(p, "output image (.png/.jpg: 8-bit; .tif: float)")
    p.add_argument("--size", nargs=2, type=positive_int, metavar=("H", "W"), default=(256, 256),
                   help="height and width of the texture in pixels (default 256 256)")
    p.add_argument("--seed", type=non_negative_int, default=None,
                   help="random seed: the same seed, the same texture (default: a new one "
                        "each run)")
    p.add_argument("--tileable", action="store_true", help="wrap seamlessly (toroidal)")
    p.add_argument("--levels", type=positive_int, default=None,
                   help="the most pyramid levels when fitting (default 5; fewer for a small "
                        "texture)")
    add_order(p, help="neighbourhood order when fitting, or 'auto' (default)")
    add_quiet(p)
    p.set_defaults(run=run)


def run(args):
    check_texture_file(args.output)  # before the fit and the synthesis
    model, image = texture_model(args)
    sample = model.synthesize(tuple(args.size), seed=args.seed, tileable=args.tileable)
    uint16 = image is not None and image.dtype == np.uint16
    write_texture(args.output, sample, uint16=uint16)
    say(f"wrote {args.output}: {sample.shape}, orders {list(model.orders)}")


#: The files a texture is written to: 8-bit (16-bit grey PNG), or float TIFF.
TEXTURE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"})


def check_texture_file(path):
    """The suffix of ``path`` (lower case), if a texture can be written
    there (:data:`TEXTURE_SUFFIXES`); else a ValueError that says what to use."""
    suffix = Path(path).suffix.lower()
    if suffix not in TEXTURE_SUFFIXES:
        raise ValueError(f"cannot write {path}: synthesize writes one image; use .png, .jpg, "
                         ".bmp (8-bit) or .tif (float).")
    return suffix


def write_texture(path, sample, *, uint16=False):
    """PNG/JPEG/BMP: 8-bit (16-bit grey PNG with ``uint16``) of values in
    [0, 1]; TIFF: float32 as is."""
    suffix = check_texture_file(path)
    if suffix in (".tif", ".tiff"):
        out = from_unit(sample, np.float32)
    else:
        grey16 = uint16 and suffix == ".png" and sample.ndim == 2  # PNG writers: 16-bit grey only
        out = from_unit(sample, np.uint16 if grey16 else np.uint8)
    write_image(path, out)
    return out
