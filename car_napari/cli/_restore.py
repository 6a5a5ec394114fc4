"""``car-napari restore``: CAR restoration of degraded images, or of stacks of
degraded versions (multichannel restoration)."""

from __future__ import annotations

import argparse
import time

import numpy as np

from .._progress import drain
from .._validation import from_unit, unit_dtype
from ..io.arrays import is_large_path
from ..io.images import check_format, read_image, write_image
from ._arguments import add_batch_options, add_inputs, add_tile
from ._batch import run_batch, run_large_job
from ._console import print_note
from ._files import batch_outputs, channel_axis, image_suffix, one_image


def add_parser(sub):
    p = sub.add_parser("restore", help="CAR restoration of degraded images or stacks")
    add_inputs(p, "images or stacks (e.g. multi-page TIFF), folders or globs; or one "
                  "large image (.zarr, .ome.zarr, .tif) with -o FILE.zarr or FILE.tif")
    p.add_argument("--stack-axis", type=int, default=None,
                   help="each input is a stack of degraded versions along this axis "
                        "(multichannel restoration of the sharpest)")
    p.add_argument("--kappa", type=kappa_type, default=None,
                   help="prediction-probability threshold in [0, 1) (default: 0.05 for "
                        "stacks, off for single images)")
    p.add_argument("--probability", action="store_true",
                   help="also write <name>_probability.tif (prediction probability)")
    add_tile(p, "large image")
    add_batch_options(p, run)


def kappa_type(text):
    """argparse type for --kappa: a number in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"kappa must be a number in [0, 1); got {text!r}") \
            from None
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"kappa must be in [0, 1); got {value}")
    return value


def run(args):
    from ..restoration import DEFAULT_KAPPA, iter_restore, iter_restore_multichannel

    if _large(args):
        return run_large(args)

    paths, target, out = batch_outputs(args.inputs, args.output)

    def restored_file(path, restored):
        return target or out / f"{path.stem}_restored{image_suffix(restored, path)}"

    def probability_file(path):
        stem = target.stem if target else path.stem
        return out / f"{stem}_probability.tif"

    def outputs(path):
        # the restored image's suffix depends on its dtype: either one counts
        done = [out / f"{path.stem}_restored{sfx}" for sfx in (".png", ".tif")]
        first = next((f for f in done if f.exists()), done[0])
        return [first] + ([probability_file(path)] if args.probability else [])

    def process(path, on_progress):
        t0 = time.perf_counter()
        image = read_image(path, on_note=print_note)
        if args.stack_axis is None:
            image = one_image(image, path)
            job = iter_restore(image, kappa=args.kappa or 0.0, channel_axis=channel_axis(image),
                               return_result=True)
            colour = image.ndim == 3
        else:
            kappa = DEFAULT_KAPPA if args.kappa is None else args.kappa
            job = iter_restore_multichannel(image, axis=args.stack_axis, kappa=kappa,
                                            channel_axis=channel_axis(image, stack=True),
                                            return_result=True)
            colour = image.ndim == 4
        if target:  # the file can hold the result: checked before the work
            check_format(target, unit_dtype(image.dtype), 3 if colour else 2)
        result = drain(job, on_progress)
        restored = result.restored()
        if restored.ndim == 3 and restored.shape[2] == 1:
            restored = restored[..., 0]
        restored = from_unit(restored, image.dtype)  # a stack's versions share its dtype
        write_image(restored_file(path, restored), restored)
        if args.probability:
            write_image(probability_file(path), result.probability.astype(np.float32))
        ref = "" if result.reference is None else f", reference version {result.reference}"
        return f"restored{ref}, {time.perf_counter() - t0:.1f} s"

    # a file named by -o is written (again) as asked; a folder's outputs are skipped if done
    return run_batch(paths, process, outputs=None if target else outputs, options=args,
                     quiet=args.quiet)


def _large(args):
    """A large image by tiles: a zarr in or out, or a TIFF from one zarr or TIFF."""
    if any(str(p).lower().rstrip("/").endswith(".zarr") for p in (args.output, *args.inputs)):
        return True
    return is_large_path(args.output) and len(args.inputs) == 1 and \
        is_large_path(args.inputs[0])


def run_large(args):
    """``restore big.zarr -o out.zarr``: one image larger than memory, by tiles."""
    from ..restoration import iter_restore_large

    if args.stack_axis is not None or args.probability:
        raise ValueError("--stack-axis and --probability are for images in memory; a large "
                         "image (-o FILE.zarr or FILE.tif) is restored alone.")

    def job(image, out):
        tile = {} if args.tile is None else {"tile": args.tile}
        return iter_restore_large(image, out=out, kappa=args.kappa or 0.0, **tile)

    return run_large_job(args.inputs, args.output, job, verb="restored")
