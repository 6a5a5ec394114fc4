"""``car-napari descratch``: detect and restore scratches and blotches in a
folder of numbered frames, a block of frames at a time (memory independent of
the number of frames; the result equals that of the whole clip in memory)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._frames import DEFAULT_BLOCK
from .._progress import drain
from ..inpainting import iter_descratch_frames
from ..io.images import IMAGE_SUFFIXES, read_image, write_image
from ._arguments import add_output, add_quiet, positive_int
from ._console import ProgressBar, print_note, say
from ._files import names_a_folder, output_folder


def add_parser(sub):
    p = sub.add_parser("descratch", help="detect and restore scratches and blotches in a "
                                         "folder of numbered frames")
    p.add_argument("input", help="folder of numbered frames (0001.png, 0002.png, ...)")
    add_output(p, "output folder (same file names)")
    p.add_argument("--masks", action="store_true", help="also write <frame>_mask.png")
    p.add_argument("--block", type=positive_int, default=DEFAULT_BLOCK,
                   help=f"frames read and restored at a time (default {DEFAULT_BLOCK}); the "
                        "result does not depend on it")
    p.add_argument("--overwrite", action="store_true",
                   help="redo the clip when its outputs exist (default: skip it when all "
                        "exist, refuse when some do)")
    add_quiet(p)
    p.set_defaults(run=run)


def numbered_frames(folder, *, on_note=None):
    """The images of ``folder`` whose names hold a number, in the order of
    their last number; ``on_note(text)`` is told of the images skipped (no
    number in the name)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of numbered frames.")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    paths = [p for p in images if re.search(r"\d+", p.stem)]
    others = [p.name for p in images if not re.search(r"\d+", p.stem)]
    if not paths:
        raise ValueError(f"no numbered frames (like 0001.png) in {folder}.")
    if others and on_note is not None:
        shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
        on_note(f"{len(others)} image(s) of {folder} skipped, no frame number in the name: "
                f"{shown}")
    return sorted(paths, key=lambda p: (int(re.findall(r"\d+", p.stem)[-1]), p.name))


def existing_outputs(paths, out, *, masks=False):
    """The output files of the clip that exist in the folder ``out``, and
    how many there are in all."""
    files = [out / p.name for p in paths]
    if masks:
        files += [out / f"{p.stem}_mask.png" for p in paths]
    return [f for f in files if f.exists()], len(files)


class FrameFiles:
    """Numbered frame files as a lazy clip: ``clip[a:b]`` reads those frames
    (what :func:`~car_napari._frames.iter_frame_blocks` slices).

    Parameters
    ----------
    paths : list of pathlib.Path
        The frames, in order; the first one sets the shape and dtype.
    """

    def __init__(self, paths):
        self.paths = list(paths)
        first = read_image(self.paths[0])
        self.shape = (len(self.paths), *first.shape)
        self.dtype = first.dtype
        self.ndim = len(self.shape)

    def __len__(self):
        return len(self.paths)

    def __getitem__(self, index):
        frames = [read_image(p) for p in self.paths[index]]
        for path, frame in zip(self.paths[index], frames, strict=True):
            if frame.shape != self.shape[1:]:
                raise ValueError(f"{path.name} is {frame.shape}, the first frame "
                                 f"{self.shape[1:]}: the frames must have one size.")
        return np.stack(frames).astype(self.dtype, copy=False)


class FrameWriter:
    """``write(start, frames)``: frames written to files named after the
    inputs' (the masks as ``<stem>_mask.png``); counts the damaged pixels."""

    def __init__(self, paths, out, *, masks=False):
        self.paths, self.out, self.masks = paths, out, masks
        self.damaged = 0

    def frames(self, start, frames):
        for path, frame in zip(self.paths[start:start + len(frames)], frames, strict=True):
            write_image(self.out / path.name, frame)

    def mask(self, start, masks):
        self.damaged += int(np.count_nonzero(masks))
        if self.masks:
            for path, mask in zip(self.paths[start:start + len(masks)], masks, strict=True):
                write_image(self.out / f"{path.stem}_mask.png", mask.astype(np.uint8) * 255)


def run(args):
    if not names_a_folder(args.output):
        raise ValueError(f"-o {args.output}: descratch writes a folder of frames (named as the "
                         "inputs); name a folder (without a suffix, or ending in /).")
    paths = numbered_frames(args.input, on_note=print_note)
    done, total = existing_outputs(paths, Path(args.output), masks=args.masks)
    if done and not args.overwrite:
        if len(done) == total:
            say(f"{len(paths)} of {len(paths)} frames skipped: their outputs exist "
                "(--overwrite to redo them).")
            return 0
        raise ValueError(
            f"{args.output} holds {len(done)} of the clip's {total} output files (e.g. "
            f"{done[0].name}): a clip is restored as a whole, each frame from its "
            "neighbours, so it is not resumed. Pass --overwrite to redo it, or another -o "
            "folder.")
    clip = FrameFiles(paths)
    colour = clip.ndim == 4
    out = output_folder(args.output)
    writer = FrameWriter(paths, out, masks=args.masks)
    kinds = ("line", "blotch") if len(paths) >= 3 else ("line",)
    with ProgressBar(len(paths), unit="frame") as bar:
        bar.begin(0, "frames", span=len(paths))
        drain(iter_descratch_frames(clip, writer.frames, writer.mask, block=args.block,
                                    kinds=kinds, channel_axis=-1 if colour else None),
              bar.on_progress)
    pixels = len(paths) * clip.shape[1] * clip.shape[2]
    say(f"{len(paths)} frames, {100 * writer.damaged / pixels:.2f} % of pixels restored "
        f"-> {out}")
