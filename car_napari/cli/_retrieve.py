"""``car-napari retrieve``: rank a folder of textures by their
illumination-invariant distance to a query."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from ..io.images import DICOM_SUFFIXES, IMAGE_SUFFIXES, is_colour, read_image
from ._common import (
    BatchFailed,
    add_cluster,
    channel_axis,
    one_image,
    positive_int,
    print_note,
    run_batch,
)


def add_parser(sub):
    p = sub.add_parser("retrieve", help="rank a folder of textures by illumination-invariant "
                                        "distance to a query")
    p.add_argument("query", help="query texture")
    p.add_argument("gallery", help="folder of images")
    p.add_argument("--top", type=positive_int, default=None, help="print only the N nearest")
    add_cluster(p, overwrite=False)
    p.set_defaults(run=run)


#: The core's advice in Python words, and what a command-line user does instead.
_PYTHON_ADVICE = ("Pass one channel (channel_axis=None on a 2-D image) or a true colour image.",
                  "Save it as a grey (one-channel) image, or use a true colour one.")


@contextlib.contextmanager
def cli_words(what=None):
    """The core's ValueErrors with their Python advice (a ``channel_axis``
    argument) said the command line's way; ``what`` names the image."""
    try:
        yield
    except ValueError as exc:
        text = str(exc)
        if _PYTHON_ADVICE[0] not in text:
            raise
        text = text.replace(*_PYTHON_ADVICE)
        if what:
            text = f"{what}: {text}"
        raise ValueError(text) from None


def run(args):
    from ..texture.retrieval import rank, texture_features

    query = one_image(read_image(args.query, on_note=print_note), args.query)
    folder = Path(args.gallery)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of images.")
    colour = is_colour(query)
    paths = [p for p in sorted(folder.iterdir())
             if p.suffix.lower() in IMAGE_SUFFIXES - DICOM_SUFFIXES]
    if not paths:
        raise ValueError(f"no images in {folder}.")

    def process(path, on_progress):
        # one task per gallery image (on a cluster with --workers): its features
        image = one_image(read_image(path, on_note=print_note), path)
        if is_colour(image) != colour:
            return "", None
        with cli_words():
            return "", texture_features(image, channel_axis=channel_axis(image))

    features = {}
    try:
        status = run_batch(paths, process, on_done=features.__setitem__, options=args,
                           quiet=True, unit="image")
    except BatchFailed:
        status = 2
    kept = [p for p in paths if features.get(p) is not None]
    skipped = [p.name for p in paths if p in features and features[p] is None]
    if not kept:
        raise ValueError(f"no {'colour' if colour else 'grey'} images in {folder}.")
    with cli_words(f"the query {Path(args.query).name}"):
        indices, distances = rank(query, [features[p] for p in kept],
                                  channel_axis=channel_axis(query))
    top = len(kept) if args.top is None else args.top
    for k, (i, dist) in enumerate(zip(indices[:top], distances[:top], strict=True), start=1):
        print(f"{k}\t{dist:.4g}\t{kept[i]}")
    if skipped:
        print(f"skipped ({'grey' if colour else 'colour'}, the query is "
              f"{'colour' if colour else 'grey'}): {', '.join(skipped)}", file=sys.stderr)
    return 1 if status else 0
