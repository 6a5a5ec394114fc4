"""``car-napari segment``: unsupervised texture segmentation of many images
into label PNGs."""

from __future__ import annotations

import time

from .._progress import drain
from ._arguments import add_batch_options, add_inputs, non_negative_float, positive_int
from ._batch import run_batch
from ._files import LABEL_SUFFIXES, batch_outputs, channel_axis, read_one_image, write_labels


def add_parser(sub):
    p = sub.add_parser("segment", help="unsupervised texture segmentation; label PNGs")
    add_inputs(p, "images, folders or glob patterns")
    p.add_argument("--segments", type=positive_int, default=None,
                   help="number of segments (default: found automatically)")
    p.add_argument("--levels", type=positive_int, default=3, help="resolutions (default 3)")
    p.add_argument("--merge-regions", type=non_negative_float, default=None, metavar="NATS",
                   help="with the automatic number of segments, also merge segments whose "
                        "whole-segment CAR models predict each other within NATS per pixel "
                        "(0.1: fewer segments on images of 2-3 textures, but it can join "
                        "similar textures; default: off)")
    add_batch_options(p, run)


def run(args):
    from ..segmentation import iter_segment

    if args.segments is not None and args.merge_regions is not None:
        raise ValueError("--merge-regions merges the segments of the automatic number of "
                         "segments; drop --segments or --merge-regions.")
    paths, target, out = batch_outputs(args.inputs, args.output, suffixes=LABEL_SUFFIXES,
                                       what="a label image")

    def outputs(path):
        return [target or out / f"{path.stem}_segments.png"]

    def process(path, on_progress):
        image = read_one_image(path)
        t0 = time.perf_counter()
        result = drain(iter_segment(image, n_segments=args.segments, levels=args.levels,
                                    region_threshold=args.merge_regions,
                                    channel_axis=channel_axis(image)), on_progress)
        write_labels(outputs(path)[0], result.labels)
        return f"{result.n_segments} segments, {time.perf_counter() - t0:.1f} s"

    # a file named by -o is written (again) as asked; a folder's outputs are skipped if done
    return run_batch(paths, process, outputs=None if target else outputs, options=args,
                     quiet=args.quiet)
