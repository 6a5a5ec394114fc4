"""``car-napari mammo``: mammogram regions of interest, a label PNG per
image and one table for all."""

from __future__ import annotations

import csv
import sys
import time

import numpy as np

from ..io.images import read_image
from ._common import add_inputs, add_quiet, channel_axis, each_input, output_folder, write_labels


def add_parser(sub):
    p = sub.add_parser("mammo", help="mammogram regions of interest; label PNGs and rois.csv")
    add_inputs(p, "mammograms (PNG, TIFF, DICOM), folders or globs")
    p.add_argument("--reference", type=float, default=None,
                   help="reference grey of a mass in [0, 1] (default: learned on mini-MIAS)")
    p.add_argument("--tolerance", type=float, default=None,
                   help="accepted distance from the reference (default: learned)")
    p.add_argument("--max-regions", type=int, default=None,
                   help="regions kept per image, best first (default: learned; 0: all)")
    add_quiet(p)
    p.set_defaults(run=run)


def run(args):
    from ..mammography import DEFAULT_MAX_REGIONS, TABLE_COLUMNS, detect_mammogram_rois

    out = output_folder(args.output)
    inputs = each_input(args.inputs)
    table_path = out / "rois.csv"
    n_images = failed = 0
    max_regions = DEFAULT_MAX_REGIONS if args.max_regions is None else args.max_regions or None
    with open(table_path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(("image", *TABLE_COLUMNS))
        for path, bar in inputs:
            n_images += 1
            t0 = time.perf_counter()
            try:
                image = read_image(path)
                labels, table = detect_mammogram_rois(
                    image, reference=args.reference, tolerance=args.tolerance,
                    max_regions=max_regions, channel_axis=channel_axis(image))
            except ValueError as exc:  # one bad file must not lose the others
                failed += 1
                bar.write(f"{path.name}: skipped: {exc}", err=True)
                continue
            write_labels(out / f"{path.stem}_rois.png", labels)
            for row in zip(*(np.asarray(table[k]).tolist() for k in TABLE_COLUMNS), strict=True):
                writer.writerow((path.name, *row))
            fh.flush()
            bar.write(f"{path.name}: {len(table['label'])} regions, "
                      f"{time.perf_counter() - t0:.1f} s", err=args.quiet)
    print(f"table: {table_path}", file=sys.stderr)
    if failed == n_images:
        raise ValueError("no mammogram could be processed (see the messages above).")
