"""Reading and writing image files: common formats through scikit-image,
DICOM through :func:`~car_napari.io.dicom.read_dicom`.

The one list of the file suffixes car-napari treats as images
(:data:`IMAGE_SUFFIXES`) lives here, for the command line and the widgets
alike.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import check_path
from .dicom import DICOM_SUFFIXES, read_dicom

__all__ = ["DICOM_SUFFIXES", "IMAGE_SUFFIXES", "WRITE_SUFFIXES", "check_format", "is_colour",
           "read_image", "write_image"]

# colour samples a pixel (RGB and alpha): more on a TIFF's samples axis is a
# guess of tifffile's for an ambiguous shape, not colour
_MAX_SAMPLES = 4

# formats that hold 8-bit pixels only (PNG also 16-bit grey)
_EIGHT_BIT = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".gif"})

#: Suffixes (lower case) of the image files car-napari reads, DICOM included.
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm",
                            ".gif", *DICOM_SUFFIXES})


def read_image(path, *, on_note=None):
    """Read an image file as an array.

    Parameters
    ----------
    path : str or path-like
        An image file. DICOM files (``.dcm``, ``.dicom``) are read with
        :func:`~car_napari.io.dicom.read_dicom` (needs ``pydicom``); any other
        file with :func:`skimage.io.imread`.
    on_note : callable, optional
        Called with a one-line note when something was dropped (an alpha
        channel).

    Returns
    -------
    image : ndarray
        The pixels as stored: ``(H, W)`` grey, ``(H, W, 3)`` colour (an alpha
        channel is dropped, grey + alpha gives grey), or a stack as a
        multi-page TIFF holds it (pages first; see :func:`is_colour`). A DICOM
        file gives its display-ready ``(H, W)`` float32 image in [0, 1].

    Raises
    ------
    ValueError
        If the file does not exist or cannot be read as an image, or
        ``path`` is empty.
    TypeError
        If ``path`` is not a file name (a str or path-like object).
    ImportError
        If the file is DICOM and ``pydicom`` is not installed.

    See Also
    --------
    car_napari.io.dicom.read_dicom : DICOM with its display transforms and metadata.
    write_image : The reverse.

    Examples
    --------
    >>> import numpy as np
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "ramp.png")
    >>> write_image(path, np.tile(np.arange(0, 256, 4, dtype=np.uint8), (8, 1)))
    >>> image = read_image(path)
    >>> image.shape, image.dtype
    ((8, 64), dtype('uint8'))
    """
    path = Path(check_path(path))
    if not path.exists():
        raise ValueError(f"no such file: {path}")
    if path.suffix.lower() in DICOM_SUFFIXES:
        return read_dicom(path)[0]
    from skimage import io

    try:
        if path.suffix.lower() in (".tif", ".tiff"):
            image = _read_tiff(path)
        else:
            image = io.imread(str(path))
    except Exception as exc:
        # the first line only: imageio appends install hints for other formats
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if "backend" in reason:  # imageio: no plugin could decode the bytes
            reason = f"not a valid {path.suffix or 'image'} file"
        raise ValueError(f"cannot read {path} as an image ({reason}); is it an image file "
                         "with the right suffix?") from None
    if image.ndim == 3 and image.shape[2] in (2, 4) and not _is_stack(path):
        image = image[..., :-1]  # drop alpha: the models see grey or colour only
        if image.shape[2] == 1:
            image = image[..., 0]
        if on_note is not None:
            on_note(f"{path.name}: alpha channel dropped")
    return image


def _is_stack(path):
    """A TIFF of several pages or frames (its trailing 2 or 4 are not channels)."""
    if path.suffix.lower() not in (".tif", ".tiff"):
        return False
    import tifffile

    with tifffile.TiffFile(str(path)) as tif:
        return "S" not in tif.series[0].axes


def _read_tiff(path):
    """A TIFF's first series with its samples (colour) axis last: pages, or
    frames of an ImageJ/OME stack, stay first."""
    import tifffile

    with tifffile.TiffFile(str(path)) as tif:
        series = tif.series[0]
        image = series.asarray()
        if "S" in series.axes:
            s = series.axes.index("S")
            # a file written by tifffile keeps the shape it was given; its axes
            # are a guess, which for a stack of colour frames (T, 64, 64, 3) was
            # "64 planar samples" (QSYX): moving them last gave (T, 64, 3, 64)
            if not (tif.is_shaped and image.shape[s] > _MAX_SAMPLES):
                image = np.moveaxis(image, s, -1)
    return image


def _write_tiff(path, image):
    """A TIFF of ``image`` with its layout said, not guessed (read back by
    :func:`read_image` in the same shape): a last axis of 3 or 4 is colour
    (RGB, RGBA) interleaved, so (H, W, 3) is one colour image and
    (T, H, W, 3) a stack of them; any other array is grey, its leading axes
    pages ((T, H, W): a stack of grey frames, as :func:`is_colour` reads it).
    Left to guess, tifffile wrote (3, H, W) as one planar RGB image and
    (3, 64, 64, 3) as frames of 64 planar samples."""
    import tifffile

    if image.ndim >= 3 and image.shape[-1] in (3, 4):
        tifffile.imwrite(str(path), image, photometric="rgb", planarconfig="contig")
    else:
        tifffile.imwrite(str(path), image, photometric="minisblack")


def is_colour(image):
    """Whether an array from :func:`read_image` is one colour image (H, W, 3);
    any other 3-D array (a multi-page TIFF) is a stack of grey frames.

    Parameters
    ----------
    image : ndarray
        An image as :func:`read_image` returns it.

    Returns
    -------
    bool
        True for ``(H, W, 3)``.

    Examples
    --------
    >>> import numpy as np
    >>> is_colour(np.zeros((8, 8, 3))), is_colour(np.zeros((3, 8, 8))), is_colour(np.zeros((8, 8)))
    (True, False, False)
    """
    return image.ndim == 3 and image.shape[2] == 3


#: Suffixes (lower case) of the image files :func:`write_image` writes.
WRITE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".gif", ".pgm",
                            ".ppm"})


def check_format(path, dtype, ndim):
    """Check that the file format of ``path`` (by its suffix) holds such pixels.

    What :func:`write_image` checks before it writes; a command checks it
    before any work.

    Parameters
    ----------
    path : str or path-like
        The file to write.
    dtype : numpy dtype
        The pixels' type.
    ndim : int
        2 for a grey image, 3 for colour ``(H, W, C)``.

    Raises
    ------
    ValueError
        If ``path`` has no suffix, a suffix that is not an image format
        car-napari writes (:data:`WRITE_SUFFIXES`), or one whose format does
        not hold the pixels (PNG holds 8-bit and 16-bit grey, JPEG, BMP and
        GIF 8-bit; TIFF anything). The message says what to use instead.

    Examples
    --------
    >>> import numpy as np
    >>> check_format("out.tif", np.float32, 2)
    >>> check_format("out.png", np.float32, 2)
    Traceback (most recent call last):
    ...
    ValueError: cannot write float32 grey pixels to out.png: ... Write a .tif instead.
    """
    path = Path(path)
    dtype = np.dtype(dtype)
    suffix = path.suffix.lower()
    if not suffix:
        raise ValueError(f"cannot write {path}: its name has no suffix to choose the format; "
                         "end it in .png, .jpg or .tif.")
    if suffix not in WRITE_SUFFIXES:
        raise ValueError(f"cannot write an image to {path.name}: {path.suffix} is not an image "
                         f"format car-napari writes; use one of "
                         f"{', '.join(sorted(WRITE_SUFFIXES))}.")
    grey16_png = suffix == ".png" and dtype == np.uint16 and ndim == 2
    if suffix in _EIGHT_BIT and dtype not in (np.uint8, np.bool_) and not grey16_png:
        holds = "8-bit pixels (or 16-bit grey)" if suffix == ".png" else "8-bit pixels"
        kind = "colour" if ndim == 3 else "grey"
        raise ValueError(f"cannot write {dtype} {kind} pixels to {path.name}: "
                         f"{path.suffix} holds {holds}. Write a .tif instead.")


def write_image(path, image):
    """Write an array to an image file, its format chosen by the suffix.

    Parameters
    ----------
    path : str or path-like
        The file to write (``.png``, ``.jpg``, ``.tif``, ...).
    image : ndarray
        The pixels, written as they are: convert them to the file's type
        first (for example uint8 for PNG and JPEG, float32 for TIFF).

    Raises
    ------
    OSError
        If the file cannot be written.
    ValueError
        If the image is empty or not at least 2-D, the file's format cannot
        hold its pixels, or ``path`` is a folder or empty.
    TypeError
        If the image is not numeric, or ``path`` is not a file name.

    See Also
    --------
    read_image : The reverse.

    Examples
    --------
    >>> import numpy as np
    >>> from pathlib import Path
    >>> from tempfile import mkdtemp
    >>> path = Path(mkdtemp()) / "flat.png"
    >>> write_image(path, np.zeros((4, 4), np.uint8))  # no low-contrast warning
    >>> int(read_image(path).max())
    0
    """
    from skimage import io

    path = Path(check_path(path))
    if path.is_dir():
        raise ValueError(f"cannot write {path}: it is a folder; pass a file name.")
    image = np.asarray(image)
    if image.dtype.kind not in "biuf":
        raise TypeError(f"cannot write {image.dtype} pixels to {path.name}: pass a numeric "
                        "(bool, integer or float) image.")
    if image.ndim < 2 or image.size == 0:
        raise ValueError(f"cannot write an image of shape {image.shape} to {path.name}: pass "
                         "a non-empty (H, W) or (H, W, C) image.")
    check_format(path, image.dtype, image.ndim)
    suffix = path.suffix.lower()
    try:
        if suffix in (".tif", ".tiff"):
            _write_tiff(path, image)
        else:
            io.imsave(str(path), image, check_contrast=False)
    except (ValueError, TypeError, KeyError) as exc:
        raise ValueError(f"cannot write {path}: {exc}. Write a .tif instead.") from None
