"""``car-napari inpaint``: fill the masked pixels of one frame."""

from __future__ import annotations

import sys
import time

import numpy as np

from ..io.images import read_image, write_image
from ._common import add_output, channel_axis, one_image, print_note


def add_parser(sub):
    p = sub.add_parser("inpaint", help="fill the masked pixels of a frame (section 14.7, "
                                       "docs/inpainting.md)")
    p.add_argument("image", help="damaged frame")
    p.add_argument("-m", "--mask", required=True,
                   help="mask image, white (nonzero) = damaged; resized to the frame if needed")
    add_output(p, "output image file")
    p.set_defaults(run=run)


def read_mask(path, shape):
    """A drawn mask as (H, W) bool of ``shape``: bright = damaged."""
    from skimage.transform import resize

    mask = read_image(path)
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2)
    mask = mask > (127 if mask.dtype == np.uint8 else 0.5 * mask.max())
    if mask.shape != shape:  # masks are often drawn at another resolution
        mask = resize(mask, shape, order=0, anti_aliasing=False).astype(bool)
    return mask


def run(args):
    from ..inpainting import inpaint

    image = one_image(read_image(args.image, on_note=print_note), args.image)
    mask = read_mask(args.mask, image.shape[:2])
    t0 = time.perf_counter()
    out = inpaint(image, mask, channel_axis=channel_axis(image))
    write_image(args.output, out)
    print(f"wrote {args.output}: {int(mask.sum())} pixels restored "
          f"({100 * mask.mean():.1f} %), {time.perf_counter() - t0:.1f} s", file=sys.stderr)
