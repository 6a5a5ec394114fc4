"""What the commands share: the input walk, the progress bar, argument types
and the conversion of results back to file types."""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

import numpy as np

from ..io.images import IMAGE_SUFFIXES, write_image


def expand_inputs(items):
    """The image files named by files, folders and glob patterns, in order.

    Parameters
    ----------
    items : list of str
        File paths (taken as they are), folders (their files with a suffix
        in :data:`~car_napari.io.images.IMAGE_SUFFIXES`, sorted) and glob
        patterns (their matches, sorted).

    Returns
    -------
    paths : list of pathlib.Path
        Every item's files, in the order of the items.

    Raises
    ------
    ValueError
        If there is no file at all.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for name in ("b.png", "a.tif", "notes.txt"):
    ...     _ = (folder / name).write_bytes(b"")
    >>> [p.name for p in expand_inputs([str(folder), str(folder / "*.txt")])]
    ['a.tif', 'b.png', 'notes.txt']
    """
    paths = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            paths += sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        elif any(ch in item for ch in "*?["):
            paths += sorted(Path(f) for f in glob.glob(item))
        else:
            paths.append(p)
    if not paths:
        raise ValueError(f"no input images found in {list(items)}")
    return paths


def output_folder(path):
    """The output folder, created if needed."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def each_input(inputs):
    """(input path, progress bar) for every input image of :func:`expand_inputs`.

    The inputs are expanded at once (so that a command fails before it
    writes anything when there are none); the bar on stderr advances by one
    input per image, and within one through ``bar.on_progress``.
    """
    paths = expand_inputs(inputs)

    def walk():
        with ProgressBar(len(paths), unit="image") as bar:
            for i, path in enumerate(paths):
                bar.begin(i, path.name)
                yield path, bar
            bar.begin(len(paths), "done")

    return walk()


class ProgressBar:
    """A tqdm bar on stderr, silent when stderr is not a terminal.

    ``begin(i, label)`` starts item ``i`` of ``total``; ``on_progress`` (the
    ``drain`` callback) moves the bar within ``span`` items from there by the
    job's fraction done.
    """

    def __init__(self, total, *, unit):
        from tqdm import tqdm

        self._tqdm = tqdm
        self._bar = tqdm(total=total, unit=unit, file=sys.stderr, disable=None,
                         dynamic_ncols=True, bar_format="{percentage:3.0f}%|{bar}| {postfix}")
        self._total = total
        self._start, self._span = 0, 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._bar.close()

    def begin(self, index, label, *, span=1):
        """Start the work on items ``index`` to ``index + span``."""
        self._start, self._span = index, span
        self._bar.set_postfix_str(f"{min(index + 1, self._total)}/{self._total} {label[:40]}",
                                  refresh=False)
        self._move(index)

    def on_progress(self, record):
        """:func:`car_napari._progress.drain`'s callback: a job's Progress record."""
        self._move(self._start + self._span * min(max(float(record.fraction), 0.0), 1.0))

    def write(self, text, *, err=False):
        """Print a line to stdout (stderr with ``err``) without breaking the bar."""
        self._tqdm.write(text, file=sys.stderr if err else sys.stdout)

    def _move(self, position):
        self._bar.update(position - self._bar.n)  # tqdm redraws at most every 0.1 s


def channel_axis(image, *, stack=False):
    """-1 for colour (a trailing channel axis), None for grey."""
    return -1 if image.ndim == (4 if stack else 3) else None


def order_type(text):
    """argparse type for --order: 'auto' or a positive integer (the core's
    ``neighbourhood`` argument)."""
    if text == "auto":
        return text
    try:
        order = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"order must be 'auto' or a positive integer; got {text!r}") from None
    if order < 1:
        raise argparse.ArgumentTypeError(f"order must be 'auto' or a positive integer; got {order}")
    return order


def add_order(parser, help="neighbourhood order, or 'auto' for the decision rule (default)"):
    """The --order option."""
    parser.add_argument("--order", default="auto", type=order_type, help=help)


def add_inputs(parser, help):
    """The inputs (files, folders, globs) and -o folder of a batch command."""
    parser.add_argument("inputs", nargs="+", help=help)
    add_output(parser, "output folder")


def add_output(parser, help):
    """The required -o/--output option."""
    parser.add_argument("-o", "--output", required=True, help=help)


def add_quiet(parser):
    """The --quiet option of a batch command."""
    parser.add_argument("--quiet", action="store_true", help="per-image lines to stderr")


def from_unit(values, dtype):
    """Float values on the core's [0, 1] scale as ``dtype``: uint8 and uint16
    scaled and rounded, anything else float32."""
    if dtype in (np.uint8, np.uint16):
        return np.round(np.clip(values, 0.0, 1.0) * np.iinfo(dtype).max).astype(dtype)
    return np.asarray(values).astype(np.float32)


def write_labels(path, labels):
    """A label image as an 8-bit PNG (16-bit beyond 255 labels)."""
    write_image(path, labels.astype(np.uint8 if labels.max() < 256 else np.uint16))
