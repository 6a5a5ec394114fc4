"""Inputs and outputs on disk: the input walk (files, folders, globs), where
-o puts the outputs, and the conversion of results back to file types."""

from __future__ import annotations

import glob
import os
from pathlib import Path

import numpy as np

from ..io.images import IMAGE_SUFFIXES, WRITE_SUFFIXES, is_colour, read_image, write_image
from ._console import print_note


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
        If there is no file at all, or none of the files named exists (a
        command then stops before it creates its output folder; when only
        some are missing, the batch reports each on its line).

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
    if not any(p.is_file() for p in paths):
        shown = ", ".join(str(p) for p in paths[:3]) + (", ..." if len(paths) > 3 else "")
        raise ValueError(f"no such input file: {shown}")
    return paths


def output_file(output, paths, *, suffixes=WRITE_SUFFIXES, what="an image"):
    """The file ``-o`` names, or None when it names a folder: the one rule of
    every command's output.

    A path that is a folder, ends in a slash or has no suffix names a folder
    (the outputs go there, named after the inputs: :func:`output_folder`).
    A path with a suffix names one file, which the single input's result
    is written to; a suffix the command does not write is refused, and so is
    a file for several inputs, before any work.

    Parameters
    ----------
    output : str or path-like
        The ``-o`` argument.
    paths : list of pathlib.Path
        The inputs (from :func:`expand_inputs`).
    suffixes : collection of str, optional
        The file suffixes (lower case) the command writes.
    what : str, optional
        What the command writes, for the messages.

    Returns
    -------
    path : pathlib.Path or None
        The file (its folder created), or None for a folder.

    Raises
    ------
    ValueError
        If the suffix is not one of ``suffixes``, or a file is named for
        several inputs.

    Examples
    --------
    >>> output_file("out/", [Path("a.png")]) is None
    True
    >>> output_file("out/b.xyz", [Path("a.png")])
    Traceback (most recent call last):
    ...
    ValueError: -o out/b.xyz: .xyz is not a file type of an image; ...
    """
    if names_a_folder(output):
        return None
    path = Path(output)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"-o {output}: {path.suffix} is not a file type of {what}; use "
                         f"{', '.join(sorted(suffixes))} for one file, or a folder (a name "
                         "without a suffix, or ending in /).")
    if len(paths) != 1:
        raise ValueError(f"-o {output} names one file, but there are {len(paths)} inputs: "
                         "name a folder (without a suffix, or ending in /) for several.")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def batch_outputs(inputs, output, *, suffixes=WRITE_SUFFIXES, what="an image"):
    """A batch command's inputs and outputs: ``(paths, target, folder)``, the
    input files (:func:`expand_inputs`), the file ``-o`` names or None
    (:func:`output_file`), and the folder the outputs go to (the file's, or
    ``-o`` created: :func:`output_folder`)."""
    paths = expand_inputs(inputs)
    target = output_file(output, paths, suffixes=suffixes, what=what)
    return paths, target, target.parent if target else output_folder(output)


def names_a_folder(output):
    """Whether ``-o output`` names a folder: one that exists, a path ending
    in a slash or one without a suffix (else it names a file;
    :func:`output_file`)."""
    path = Path(output)
    return path.is_dir() or str(output).endswith(("/", os.sep)) or not path.suffix


def output_folder(path):
    """The output folder, created if needed: call it once the inputs are
    checked (:func:`expand_inputs`, the command's own files), so that a
    failed command leaves no empty folder behind."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def one_image(image, path):
    """``image`` if it is one grey or colour image; a stack (a multi-page
    TIFF) is a ValueError that says what to do."""
    if image.ndim == 2 or is_colour(image):
        return image
    raise ValueError(
        f"{Path(path).name} holds a stack of shape {image.shape}, not one image; this "
        "command takes one image per file (split the stack into files, or for versions "
        "of one scene use 'car-napari restore --stack-axis 0').")


def read_one_image(path):
    """The one grey or colour image in the file ``path`` (:func:`one_image`),
    the reader's notes printed."""
    return one_image(read_image(path, on_note=print_note), path)


def image_suffix(image, source):
    """The file suffix of a batch's output ``image`` made from the file
    ``source``: .png for 8-bit; 16-bit stays in its container kind, .png
    from a 16-bit grey PNG and .tif from anything else (a TIFF, DICOM, a
    16-bit colour image, which PNG writers do not take); .tif for floats.

    Examples
    --------
    >>> import numpy as np
    >>> grey16 = np.zeros((2, 2), np.uint16)
    >>> image_suffix(grey16, Path("a.png")), image_suffix(grey16, Path("a.tif"))
    ('.png', '.tif')
    """
    if image.dtype == np.uint8:
        return ".png"
    if image.dtype == np.uint16 and image.ndim == 2 and Path(source).suffix.lower() == ".png":
        return ".png"
    return ".tif"


def channel_axis(image, *, stack=False):
    """-1 for colour (a trailing channel axis), None for grey."""
    if not stack:
        return -1 if is_colour(image) else None
    return -1 if image.ndim == 4 else None


#: The files a label image is written to (lossless, 8 or 16-bit).
LABEL_SUFFIXES = frozenset({".png", ".tif", ".tiff"})


def write_labels(path, labels):
    """A label image as an 8-bit PNG (16-bit beyond 255 labels)."""
    write_image(path, labels.astype(np.uint8 if labels.max() < 256 else np.uint16))
