"""``car-napari mammo``: mammogram regions of interest, a label PNG and an
overlay PNG per image and one table for all."""

from __future__ import annotations

import csv
import time

import numpy as np

from .._progress import drain
from ..io.images import write_image
from ._arguments import add_batch_options, add_inputs, non_negative_float, non_negative_int
from ._batch import run_batch
from ._console import say
from ._files import LABEL_SUFFIXES, batch_outputs, channel_axis, read_one_image, write_labels


def add_parser(sub):
    p = sub.add_parser("mammo", help="mammogram regions of interest; label and overlay PNGs "
                                     "and rois.csv")
    add_inputs(p, "mammograms (PNG, TIFF, DICOM), folders or globs")
    p.add_argument("--marks-per-image", type=non_negative_float, default=None,
                   help="operating point: false marks per image on average, cross-validated "
                        "on CBIS-DDSM films (default 2; more marks find more masses); 0 keeps "
                        "every scored region")
    advanced = p.add_argument_group("advanced (the chapter's grey-level filter, a cap)")
    advanced.add_argument("--reference", type=non_negative_float, default=None,
                          help="reference grey of a mass in [0, 1] (default: the chapter's, "
                               "learned on mini-MIAS); used with --tolerance")
    advanced.add_argument("--tolerance", type=non_negative_float, default=None,
                          help="drop regions whose mean grey is further than this from the "
                               "reference (default: no grey filter)")
    advanced.add_argument("--max-regions", type=non_negative_int, default=None,
                          help="at most this many regions per image, best first (default "
                               "and 0: no cap)")
    p.add_argument("--tissue", action="store_true",
                   help="also the breast tissue from the same segmentation: percent density "
                        "and class (F/G/D) in tissue.csv, the fibroglandular mask as "
                        "<name>_tissue.png")
    add_batch_options(p, run)


def run(args):
    from ..mammography import (
        DEFAULT_MARKS_PER_IMAGE,
        TABLE_COLUMNS,
        TISSUE_CLASSES,
        bit_depth,
        iter_analyse_mammogram,
        iter_detect_mammogram_rois,
        roi_overlay,
    )

    paths, target, out = batch_outputs(args.inputs, args.output, suffixes=LABEL_SUFFIXES,
                                       what="a label image")
    # one input to a file: its table beside it, <name>.csv
    table_path = target.with_suffix(".csv") if target else out / "rois.csv"
    max_regions = args.max_regions or None
    marks = (DEFAULT_MARKS_PER_IMAGE if args.marks_per_image is None
             else args.marks_per_image or None)

    def process(path, on_progress):
        t0 = time.perf_counter()
        image = read_one_image(path)
        options = dict(marks_per_image=marks, reference=args.reference,
                       tolerance=args.tolerance or None, max_regions=max_regions,
                       channel_axis=channel_axis(image))
        if args.tissue:  # one segmentation for both
            (labels, table), tissue = drain(iter_analyse_mammogram(image, **options),
                                            on_progress)
        else:
            labels, table = drain(iter_detect_mammogram_rois(image, **options), on_progress)
        labels_path, overlay_path, *tissue_path = outputs(path)
        write_labels(labels_path, labels)
        tissue_row = []
        if args.tissue:
            write_labels(tissue_path[0], tissue.fibroglandular.astype(np.uint8))
            tissue_row = [(f"{tissue.density:.2f}", tissue.tissue_class,
                           *(f"{tissue.probabilities[c]:.4f}" for c in TISSUE_CLASSES))]
        write_image(overlay_path, roi_overlay(image, labels, channel_axis=channel_axis(image)))
        depth = bit_depth(image) if np.ndim(image) == 2 else None
        depth = f"{depth}-bit" if depth else "float"
        rows = [(depth, *row) for row in zip(
            *(np.asarray(table[k]).tolist() for k in TABLE_COLUMNS), strict=True)]
        note = (f", density {tissue.density:.0f} % ({tissue.tissue_class})"
                if args.tissue else "")
        return (f"{len(rows)} regions ({depth}){note}, {time.perf_counter() - t0:.1f} s",
                (rows, tissue_row))

    def outputs(path):
        # the label image, and beside it the overlay a person opens (labels look black)
        if target:
            found = [target, target.with_name(f"{target.stem}_overlay.png")]
            tissue = target.with_name(f"{target.stem}_tissue.png")
        else:
            found = [out / f"{path.stem}_rois.png", out / f"{path.stem}_overlay.png"]
            tissue = out / f"{path.stem}_tissue.png"
        return [*found, tissue] if args.tissue else found

    # one table for the whole batch, in input order whatever order the inputs finish
    # in; the rows of inputs skipped on a rerun come from the table already there
    rows = {} if args.overwrite or target else _table_rows(table_path, paths)
    tissue_path = table_path.with_name(
        f"{table_path.stem}_tissue.csv" if target else "tissue.csv")
    tissue_rows = ({} if args.overwrite or target or not args.tissue
                   else _table_rows(tissue_path, paths))
    try:
        return run_batch(paths, process, outputs=None if target else outputs,
                         on_done=lambda path, r: (rows.__setitem__(path, r[0]),
                                                  tissue_rows.__setitem__(path, r[1])),
                         options=args, quiet=args.quiet)
    finally:
        with open(table_path, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(("image", "bit_depth", *TABLE_COLUMNS))
            for path in paths:
                for row in rows.get(path, ()):
                    writer.writerow((path.name, *row))
        say(f"table: {table_path}")
        if args.tissue:
            with open(tissue_path, "w", newline="") as fh:
                writer = csv.writer(fh)
                writer.writerow(("image", "density_percent", "tissue_class",
                                 *(f"p_{c}" for c in TISSUE_CLASSES)))
                for path in paths:
                    for row in tissue_rows.get(path, ()):
                        writer.writerow((path.name, *row))
            say(f"tissue: {tissue_path}")


def _table_rows(table_path, paths):
    """The rows an earlier run wrote for ``paths`` (by file name), if any."""
    if not table_path.exists():
        return {}
    by_name = {}
    with open(table_path, newline="") as fh:
        for row in list(csv.reader(fh))[1:]:
            by_name.setdefault(row[0], []).append(row[1:])
    return {path: by_name[path.name] for path in paths if path.name in by_name}
