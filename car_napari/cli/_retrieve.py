"""``car-napari retrieve``: rank a folder of textures by their
illumination-invariant distance to a query."""

from __future__ import annotations

import contextlib
import functools
import sys
from pathlib import Path

import numpy as np

from ..io.images import DICOM_SUFFIXES, IMAGE_SUFFIXES, is_colour
from ._arguments import add_cluster, positive_int
from ._batch import BatchFailed, run_batch
from ._console import print_note
from ._files import channel_axis, read_one_image


def add_parser(sub):
    p = sub.add_parser("retrieve", help="rank a folder of textures by illumination-invariant "
                                        "distance to a query")
    p.add_argument("query", help="query texture")
    p.add_argument("gallery", help="folder of images, compared with the query in its kind "
                                   "(colour or grey; grey saved as RGB is grey), all in grey "
                                   "when none is of the query's kind")
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


def as_kind(image):
    """``(image, colour)`` by the retrieval's one rule: a colour file whose
    three channels are equal (grey saved as RGB) is a grey image (its first
    channel); only a true colour image is colour.

    Examples
    --------
    >>> import numpy as np
    >>> grey = np.arange(16, dtype=np.uint8).reshape(4, 4)
    >>> image, colour = as_kind(np.dstack([grey] * 3))
    >>> image.shape, colour
    ((4, 4), False)
    >>> as_kind(np.dstack([grey, grey, 255 - grey]))[1]
    True
    """
    if not is_colour(image):
        return image, False
    first = image[..., 0]
    if all(np.array_equal(first, image[..., c]) for c in (1, 2)):
        return first, False
    return image, True


def luminance(image):
    """The grey version of a colour image, as compared when the query and
    the gallery differ in kind (skimage's ``rgb2gray``: [0, 1] floats)."""
    from skimage.color import rgb2gray

    return rgb2gray(image)


def run(args):
    from ..texture import rank, texture_features

    query, colour = as_kind(read_one_image(args.query))
    folder = Path(args.gallery)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of images.")
    paths = [p for p in sorted(folder.iterdir())
             if p.suffix.lower() in IMAGE_SUFFIXES - DICOM_SUFFIXES]
    if not paths:
        raise ValueError(f"no images in {folder}.")

    def process(path, on_progress, grey=False):
        # one task per gallery image (on a cluster with --workers): its features,
        # None for an image of the other kind (grey: every image compared in grey)
        image, kind = as_kind(read_one_image(path))
        if grey:
            image = luminance(image) if kind else image
        elif kind != colour:
            return "", None
        with cli_words():
            return "", texture_features(image, channel_axis=channel_axis(image))

    def run_all(process, paths):
        features = {}
        try:
            status = run_batch(paths, process, on_done=features.__setitem__, options=args,
                               quiet=True, unit="image")
        except BatchFailed:
            status = 2
        return features, status

    features, status = run_all(process, paths)
    kept = [p for p in paths if features.get(p) is not None]
    skipped = [p.name for p in paths if p in features and features[p] is None]
    name = Path(args.query).name
    if not kept and skipped:
        # nothing of the query's kind: compare everything in grey (one rule both ways)
        other = [p for p in paths if p.name in skipped]
        print_note(f"the gallery holds no colour image: the query {name} is compared in "
                   "grey (as its luminance)." if colour else "the gallery holds no grey "
                   "image: its colour images are compared in grey (as their luminance).")
        more, again = run_all(functools.partial(process, grey=True), other)
        features.update(more)
        status = status or again
        if colour:
            query, colour = luminance(query), False
        kept = [p for p in paths if features.get(p) is not None]
        skipped = []
    if not kept:
        raise ValueError(f"no {'colour' if colour else 'grey'} images in {folder}.")
    with cli_words(f"the query {name}"):
        indices, distances = rank(query, [features[p] for p in kept],
                                  channel_axis=channel_axis(query))
    top = len(kept) if args.top is None else args.top
    for k, (i, dist) in enumerate(zip(indices[:top], distances[:top], strict=True), start=1):
        print(f"{k}\t{dist:.4g}\t{kept[i]}")
    if skipped:
        print(f"skipped ({'grey' if colour else 'colour'}, the query is "
              f"{'colour' if colour else 'grey'}): {', '.join(skipped)}", file=sys.stderr)
    return 1 if status else 0
