"""``car-napari descratch``: detect and restore scratches and blotches in a
folder of numbered frames."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from .._progress import drain
from ..io.images import IMAGE_SUFFIXES, read_image, write_image
from ._common import ProgressBar, add_output, channel_axis, output_folder


def add_parser(sub):
    p = sub.add_parser("descratch", help="detect and restore scratches and blotches in a "
                                         "folder of numbered frames")
    p.add_argument("input", help="folder of numbered frames (0001.png, 0002.png, ...)")
    add_output(p, "output folder (same file names)")
    p.add_argument("--masks", action="store_true", help="also write <frame>_mask.png")
    p.set_defaults(run=run)


def numbered_frames(folder):
    """The images of ``folder`` whose names hold a number, in the order of
    their last number."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of numbered frames.")
    paths = [p for p in folder.iterdir()
             if p.suffix.lower() in IMAGE_SUFFIXES and re.search(r"\d+", p.stem)]
    if not paths:
        raise ValueError(f"no numbered frames (like 0001.png) in {folder}.")
    return sorted(paths, key=lambda p: (int(re.findall(r"\d+", p.stem)[-1]), p.name))


def run(args):
    from ..inpainting import detect_scratches, iter_inpaint

    paths = numbered_frames(args.input)
    frames = np.stack([read_image(p) for p in paths])
    colour_axis = channel_axis(frames, stack=True)
    kinds = ("line", "blotch") if len(frames) >= 3 else ("line",)
    masks = detect_scratches(frames, kinds=kinds, channel_axis=colour_axis)
    out = output_folder(args.output)
    with ProgressBar(len(paths), unit="frame") as bar:
        bar.begin(0, "frames", span=len(paths))
        restored = drain(iter_inpaint(frames, masks, channel_axis=colour_axis), bar.on_progress)
    for path, frame, mask in zip(paths, restored, masks, strict=True):
        write_image(out / path.name, frame)
        if args.masks:
            write_image(out / f"{path.stem}_mask.png", (mask * 255).astype(np.uint8))
    print(f"{len(paths)} frames, {100 * masks.mean():.2f} % of pixels restored -> {out}",
          file=sys.stderr)
