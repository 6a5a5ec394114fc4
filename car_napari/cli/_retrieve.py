"""``car-napari retrieve``: rank a folder of textures by their
illumination-invariant distance to a query."""

from __future__ import annotations

import sys
from pathlib import Path

from ..io.images import DICOM_SUFFIXES, IMAGE_SUFFIXES, is_colour, read_image
from ._common import INPUT_ERRORS, channel_axis, one_image, positive_int, print_note


def add_parser(sub):
    p = sub.add_parser("retrieve", help="rank a folder of textures by illumination-invariant "
                                        "distance to a query")
    p.add_argument("query", help="query texture")
    p.add_argument("gallery", help="folder of images")
    p.add_argument("--top", type=positive_int, default=None, help="print only the N nearest")
    p.set_defaults(run=run)


def run(args):
    from ..texture.retrieval import rank

    query = one_image(read_image(args.query, on_note=print_note), args.query)
    folder = Path(args.gallery)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of images.")
    colour = is_colour(query)
    paths, images, skipped, failed = [], [], [], 0
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in IMAGE_SUFFIXES - DICOM_SUFFIXES:
            continue
        try:
            image = one_image(read_image(path, on_note=print_note), path)
        except INPUT_ERRORS as exc:  # one bad file must not lose the others
            failed += 1
            print(f"{path.name}: failed: {exc}", file=sys.stderr)
            continue
        if is_colour(image) != colour:
            skipped.append(path.name)
            continue
        paths.append(path)
        images.append(image)
    if not images:
        raise ValueError(f"no {'colour' if colour else 'grey'} images in {folder}.")
    indices, distances = rank(query, images, channel_axis=channel_axis(query))
    top = len(paths) if args.top is None else args.top
    for k, (i, dist) in enumerate(zip(indices[:top], distances[:top], strict=True), start=1):
        print(f"{k}\t{dist:.4g}\t{paths[i]}")
    if skipped:
        print(f"skipped ({'grey' if colour else 'colour'}, the query is "
              f"{'colour' if colour else 'grey'}): {', '.join(skipped)}", file=sys.stderr)
    return 1 if failed else 0
