"""``car-napari inpaint``: fill the masked pixels of a frame, of a batch of
frames (on a dask cluster with --workers), or of a zarr frame or clip larger
than memory."""

from __future__ import annotations

import contextlib
import time
import warnings
from pathlib import Path

import numpy as np

from ..inpainting import MOSTLY_MASKED, fit_mask
from ..io.arrays import is_large_path
from ..io.images import IMAGE_SUFFIXES, check_format, read_image, write_image
from ._arguments import add_batch_options, add_output, add_tile
from ._batch import run_batch, run_large_job
from ._console import print_note, say
from ._files import (
    channel_axis,
    expand_inputs,
    image_suffix,
    one_image,
    output_file,
    output_folder,
    read_one_image,
)


def add_parser(sub):
    p = sub.add_parser("inpaint", help="fill the masked pixels of frames (section 14.7, "
                                       "docs/inpainting.md)")
    p.add_argument("inputs", nargs="+",
                   help="damaged frame(s), folders or globs; or one zarr frame or clip "
                        "(.zarr) with -o FILE.zarr")
    p.add_argument("-m", "--mask", required=True,
                   help="mask image: damaged where brighter than mid-grey (above 127 in an "
                        "8-bit mask, above half its brightest value in any other; in colour, "
                        "the brightest channel), so white on black; resized to the frame if "
                        "needed (a note says so; refused when the aspect ratios differ by "
                        "more than 2 %%); for a batch, one mask for all or a folder holding "
                        "<name>_mask.*, <name>-mask.* or <name>.* per frame; for a zarr "
                        "input, a zarr (nonzero = damaged) or image mask")
    p.add_argument("--invert-mask", action="store_true",
                   help="the mask marks the damage black (dark = damaged)")
    p.add_argument("--force", action="store_true",
                   help="fill a frame even when the mask covers more than half of it "
                        "(refused by default: such a mask usually has the other convention, "
                        "see --invert-mask)")
    add_output(p, "output image file (one frame), folder (a batch) or .zarr (a zarr input)")
    add_tile(p, "a zarr frame")
    add_batch_options(p, run)


def damaged_pixels(mask):
    """A mask image's damaged pixels at its own size: True where brighter
    than mid-grey.

    Parameters
    ----------
    mask : ndarray
        A grey ``(h, w)`` or colour ``(h, w, C)`` mask image, as read.

    Returns
    -------
    ndarray of bool
        ``(h, w)``: True above 127 in a uint8 mask, above half the mask's
        brightest value in any other (a 0/1 mask, a 16-bit one); in colour,
        by the brightest of the first three channels.

    Examples
    --------
    >>> import numpy as np
    >>> damaged_pixels(np.array([[0, 127, 128, 255]], np.uint8)).astype(int)
    array([[0, 0, 1, 1]])
    >>> damaged_pixels(np.array([[0, 1]], np.uint16)).astype(int)
    array([[0, 1]])
    """
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2)
    if mask.dtype == np.bool_:
        return mask.copy()
    return mask > (127 if mask.dtype == np.uint8 else 0.5 * mask.max())


def read_mask(path, shape, *, invert=False, force=False):
    """A mask file as (H, W) bool of ``shape``: True where damaged
    (:func:`load_mask`, then :func:`fit_to_frame`)."""
    return fit_to_frame(load_mask(path, invert=invert, force=force), shape, path)


def load_mask(path, *, invert=False, force=False):
    """A mask file's damaged pixels at its own size: brighter than mid-grey
    (:func:`damaged_pixels`), darker with ``invert``; refused (ValueError)
    when they cover more than half of it, unless ``force``
    (:func:`check_coverage`)."""
    damaged = damaged_pixels(one_image(read_image(path), path))  # a stack is refused
    if invert:
        damaged = ~damaged
    check_coverage(damaged, path, force=force)
    return damaged


#: The most a mask's aspect ratio may differ from its frame's (relative) for
#: it to be resized to the frame; beyond, it would be stretched.
MAX_ASPECT_CHANGE = 0.02


def fit_to_frame(damaged, shape, path):
    """``damaged`` (a mask's pixels, from the file ``path``) resized to the
    frame ``shape`` (H, W) by nearest neighbour
    (:func:`~car_napari.inpainting.fit_mask`), with a note on stderr.

    Raises
    ------
    ValueError
        If the aspect ratios of the mask and the frame differ by more than
        :data:`MAX_ASPECT_CHANGE`: the mask would be stretched.
    """
    (h, w), (H, W) = damaged.shape, tuple(shape)
    if (h, w) != (H, W):
        change = abs((w / h) / (W / H) - 1.0)
        sizes = f"{w}x{h}, the frame {W}x{H} (width x height)"
        if change > MAX_ASPECT_CHANGE:
            raise ValueError(
                f"the mask {Path(path).name} is {sizes}: their aspect ratios differ by "
                f"{100 * change:.1f} % (more than {100 * MAX_ASPECT_CHANGE:.0f} %), so the mask "
                "would be stretched onto the frame. Draw the mask on this frame, or at a "
                "scale of it.")
        print_note(f"mask {Path(path).name} resized from {w}x{h} to {W}x{H} (width x height)")
    return fit_mask(damaged, shape)


def check_coverage(damaged, path, *, force=False):
    """Refuse (a ValueError naming --invert-mask and --force) a mask that
    covers more than half of the frame; with ``force``, say so on stderr."""
    share = float(np.mean(damaged))
    if share <= MOSTLY_MASKED:
        return
    text = (f"the mask {Path(path).name} marks {100 * share:.1f} % of the frame as damaged, "
            "more than half")
    if force:
        print_note(f"{text}; filling it (--force).")
        return
    raise ValueError(f"{text}: damaged is white (bright) on black. If the mask marks the "
                     "damage black, pass --invert-mask; if the frame really is that damaged, "
                     "pass --force.")


def run(args):
    if str(args.inputs[0]).lower().rstrip("/").endswith(".zarr") or \
            str(args.output).lower().rstrip("/").endswith(".zarr"):
        return run_large(args)
    paths = expand_inputs(args.inputs)
    target = output_file(args.output, paths)
    if target:
        return run_one(args, paths[0], target)
    return run_many(args, paths)


def run_one(args, path, target):
    """One frame to the file ``target``: the form before batches."""
    from ..inpainting import inpaint

    image = read_one_image(path)
    check_format(target, image.dtype, image.ndim)  # the file holds the frame: before the work
    mask = read_mask(args.mask, image.shape[:2], invert=args.invert_mask, force=args.force)
    t0 = time.perf_counter()
    with _checked_coverage():
        out = inpaint(image, mask, channel_axis=channel_axis(image))
    write_image(target, out)
    say(f"wrote {target}: {int(mask.sum())} pixels restored ({100 * mask.mean():.1f} %), "
        f"{time.perf_counter() - t0:.1f} s")
    return 0


def mask_for(mask_arg, path):
    """The mask file of input ``path``: ``mask_arg`` itself, or in the folder
    ``mask_arg`` the file ``<stem>_mask.*`` or ``<stem>-mask.*`` (else
    ``<stem>.*``)."""
    folder = Path(mask_arg)
    if not folder.is_dir():
        return folder
    patterns = (f"{path.stem}_mask.*", f"{path.stem}-mask.*", f"{path.stem}.*")
    for pattern in patterns:
        found = sorted(p for p in folder.glob(pattern) if p.suffix.lower() in IMAGE_SUFFIXES)
        if found:
            return found[0]
    raise ValueError(f"no mask for {path.name} in {folder} (looked for "
                     f"{', '.join(patterns[:-1])} and {patterns[-1]})")


def run_many(args, paths):
    """A batch: one task per frame, on a dask cluster with --workers."""
    from .._progress import drain
    from ..inpainting import iter_inpaint

    mask_arg, invert, force = args.mask, args.invert_mask, args.force
    # one mask for all: checked once, before any work
    shared = None if Path(mask_arg).is_dir() else load_mask(mask_arg, invert=invert,
                                                            force=force)
    out = output_folder(args.output)

    def outputs(path):
        done = [out / f"{path.stem}_inpainted{sfx}" for sfx in (".png", ".tif")]
        return [next((f for f in done if f.exists()), done[0])]

    def process(path, on_progress):
        t0 = time.perf_counter()
        image = read_one_image(path)
        if shared is None:
            mask = read_mask(mask_for(mask_arg, path), image.shape[:2], invert=invert,
                             force=force)
        else:
            mask = fit_to_frame(shared, image.shape[:2], mask_arg)
        with _checked_coverage():
            restored = drain(iter_inpaint(image, mask, channel_axis=channel_axis(image)),
                             on_progress)
        write_image(out / f"{path.stem}_inpainted{image_suffix(restored, path)}", restored)
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
        mask = open_array(args.mask)  # not checked: read a frame at a time
        if args.invert_mask:
            import dask.array as da

            mask = da.from_array(mask) == 0
    else:
        mask = read_mask(args.mask, tuple(frame_shape), invert=args.invert_mask,
                         force=args.force)

    def job(image, out):
        tile = {} if args.tile is None else {"tile": args.tile}
        return iter_inpaint_large(image, mask, out=out, channel_axis=-1, **tile)

    return run_large_job(args.inputs, args.output, _Raw(job), verb="inpainted")


@contextlib.contextmanager
def _checked_coverage():
    """The core's warning on a mask covering more than half of a frame,
    silenced: :func:`check_coverage` has refused such a mask or said so."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the mask covers", UserWarning)
        yield


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
