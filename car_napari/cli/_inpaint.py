"""``car-napari inpaint``: fill the masked pixels of a frame, of a batch of
frames (on a dask cluster with --workers), or of a zarr frame or clip larger
than memory."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..io.arrays import is_large_path
from ..io.images import IMAGE_SUFFIXES, read_image, write_image
from ._common import (
    add_cluster,
    add_output,
    add_quiet,
    channel_axis,
    expand_inputs,
    image_suffix,
    one_image,
    output_folder,
    positive_int,
    print_note,
    run_batch,
    run_large_job,
)


def add_parser(sub):
    p = sub.add_parser("inpaint", help="fill the masked pixels of frames (section 14.7, "
                                       "docs/inpainting.md)")
    p.add_argument("inputs", nargs="+",
                   help="damaged frame(s), folders or globs; or one zarr frame or clip "
                        "(.zarr) with -o FILE.zarr")
    p.add_argument("-m", "--mask", required=True,
                   help="mask image, white (nonzero) = damaged, resized to the frame if "
                        "needed; for a batch, one mask for all or a folder holding "
                        "<name>_mask.* or <name>.* per frame; for a zarr input, a zarr or "
                        "image mask")
    add_output(p, "output image file (one frame), folder (a batch) or .zarr (a zarr input)")
    p.add_argument("--tile", type=positive_int, default=None,
                   help="a zarr frame: side of a tile in pixels (default 2048)")
    add_quiet(p)
    add_cluster(p)
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


def _single(args):
    """One frame to one file: the form before batches."""
    return len(args.inputs) == 1 and Path(args.inputs[0]).is_file() and \
        Path(args.output).suffix.lower() in IMAGE_SUFFIXES


def run(args):
    if str(args.inputs[0]).lower().rstrip("/").endswith(".zarr") or \
            str(args.output).lower().rstrip("/").endswith(".zarr"):
        return run_large(args)
    if _single(args):
        return run_one(args)
    return run_many(args)


def run_one(args):
    from ..inpainting import inpaint

    image = one_image(read_image(args.inputs[0], on_note=print_note), args.inputs[0])
    mask = read_mask(args.mask, image.shape[:2])
    t0 = time.perf_counter()
    out = inpaint(image, mask, channel_axis=channel_axis(image))
    write_image(args.output, out)
    print(f"wrote {args.output}: {int(mask.sum())} pixels restored "
          f"({100 * mask.mean():.1f} %), {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def mask_for(mask_arg, path):
    """The mask file of input ``path``: ``mask_arg`` itself, or in the folder
    ``mask_arg`` the file ``<stem>_mask.*`` (else ``<stem>.*``)."""
    folder = Path(mask_arg)
    if not folder.is_dir():
        return folder
    for pattern in (f"{path.stem}_mask.*", f"{path.stem}.*"):
        found = sorted(p for p in folder.glob(pattern) if p.suffix.lower() in IMAGE_SUFFIXES)
        if found:
            return found[0]
    raise ValueError(f"no mask for {path.name} in {folder} (looked for {path.stem}_mask.* "
                     f"and {path.stem}.*)")


def run_many(args):
    """A batch: one task per frame, on a dask cluster with --workers."""
    from .._progress import drain
    from ..inpainting import iter_inpaint

    paths = expand_inputs(args.inputs)
    mask_arg = args.mask
    if not Path(mask_arg).exists():  # before the output folder is made
        raise ValueError(f"no such mask file or folder: {mask_arg}")
    out = output_folder(args.output)

    def outputs(path):
        done = [out / f"{path.stem}_inpainted{sfx}" for sfx in (".png", ".tif")]
        return [next((f for f in done if f.exists()), done[0])]

    def process(path, on_progress):
        t0 = time.perf_counter()
        image = one_image(read_image(path, on_note=print_note), path)
        mask = read_mask(mask_for(mask_arg, path), image.shape[:2])
        restored = drain(iter_inpaint(image, mask, channel_axis=channel_axis(image)),
                         on_progress)
        write_image(out / f"{path.stem}_inpainted{image_suffix(restored)}", restored)
        return (f"{int(mask.sum())} pixels restored ({100 * mask.mean():.1f} %), "
                f"{time.perf_counter() - t0:.1f} s")

    return run_batch(paths, process, outputs=outputs, options=args, quiet=args.quiet)


def run_large(args):
    """``inpaint clip.zarr -m mask.zarr -o out.zarr``: a frame or clip larger than
    memory, a frame (or a tile of a frame) at a time."""
    from ..inpainting import iter_inpaint_large
    from ..io.arrays import open_array

    if len(args.inputs) != 1:
        raise ValueError("a zarr input is one frame or clip: give one input.")
    image = open_array(args.inputs[0])
    frame_shape = image.shape[1:3] if _is_clip_shape(image.shape) else image.shape[:2]
    if is_large_path(args.mask):
        mask = open_array(args.mask)
    else:
        mask = read_mask(args.mask, tuple(frame_shape))

    def job(image, out):
        tile = {} if args.tile is None else {"tile": args.tile}
        return iter_inpaint_large(image, mask, out=out, channel_axis=-1, **tile)

    return run_large_job(args.inputs, args.output, _Raw(job), verb="inpainted")


def _is_clip_shape(shape):
    return len(shape) == 4 or (len(shape) == 3 and shape[-1] > 4)


class _Raw:
    """The fill returns pixels in the input's dtype: written as they are
    (not scaled from [0, 1])."""

    raw = True

    def __init__(self, job):
        self.job = job

    def __call__(self, image, out):
        return self.job(image, getattr(out, "out", out))
