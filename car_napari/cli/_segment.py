"""``car-napari segment``: unsupervised texture segmentation of many images
into label PNGs."""

from __future__ import annotations

import time

from .._progress import drain
from ..io.images import read_image
from ._arguments import add_cluster, add_inputs, add_quiet, positive_int
from ._batch import run_batch
from ._console import print_note
from ._files import (
    LABEL_SUFFIXES,
    channel_axis,
    expand_inputs,
    one_image,
    output_file,
    output_folder,
    write_labels,
)


def add_parser(sub):
    p = sub.add_parser("segment", help="unsupervised texture segmentation; label PNGs")
    add_inputs(p, "images, folders or glob patterns")
    p.add_argument("--segments", type=positive_int, default=None,
                   help="number of segments (default: found automatically)")
    p.add_argument("--levels", type=positive_int, default=3, help="resolutions (default 3)")
    add_quiet(p)
    add_cluster(p)
    p.set_defaults(run=run)


def run(args):
    from ..segmentation import iter_segment

    paths = expand_inputs(args.inputs)
    target = output_file(args.output, paths, suffixes=LABEL_SUFFIXES, what="a label image")
    out = None if target else output_folder(args.output)

    def outputs(path):
        return [target or out / f"{path.stem}_segments.png"]

    def process(path, on_progress):
        image = one_image(read_image(path, on_note=print_note), path)
        t0 = time.perf_counter()
        result = drain(iter_segment(image, n_segments=args.segments, levels=args.levels,
                                    channel_axis=channel_axis(image)), on_progress)
        write_labels(outputs(path)[0], result.labels)
        return f"{result.n_segments} segments, {time.perf_counter() - t0:.1f} s"

    # a file named by -o is written (again) as asked; a folder's outputs are skipped if done
    return run_batch(paths, process, outputs=None if target else outputs, options=args,
                     quiet=args.quiet)
