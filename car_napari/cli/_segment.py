"""``car-napari segment``: unsupervised texture segmentation of many images
into label PNGs."""

from __future__ import annotations

import time

from ..io.images import read_image
from ._common import add_inputs, add_quiet, channel_axis, each_input, output_folder, write_labels


def add_parser(sub):
    p = sub.add_parser("segment", help="unsupervised texture segmentation; label PNGs")
    add_inputs(p, "images, folders or glob patterns")
    p.add_argument("--segments", type=int, default=None,
                   help="number of segments (default: found automatically)")
    p.add_argument("--levels", type=int, default=3, help="resolutions (default 3)")
    add_quiet(p)
    p.set_defaults(run=run)


def run(args):
    from ..segmentation import segment

    out = output_folder(args.output)
    for path, bar in each_input(args.inputs):
        image = read_image(path)
        t0 = time.perf_counter()
        result = segment(image, n_segments=args.segments, levels=args.levels,
                         channel_axis=channel_axis(image))
        write_labels(out / f"{path.stem}_segments.png", result.labels)
        bar.write(f"{path.name}: {result.n_segments} segments, "
                  f"{time.perf_counter() - t0:.1f} s", err=args.quiet)
