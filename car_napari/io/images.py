"""Reading and writing image files: common formats through scikit-image,
DICOM through :func:`~car_napari.io.dicom.read_dicom`.

The one list of the file suffixes car-napari treats as images
(:data:`IMAGE_SUFFIXES`) lives here, for the command line and the widgets
alike.
"""

from __future__ import annotations

from pathlib import Path

from .dicom import DICOM_SUFFIXES, read_dicom

__all__ = ["DICOM_SUFFIXES", "IMAGE_SUFFIXES", "read_image", "write_image"]

#: Suffixes (lower case) of the image files car-napari reads, DICOM included.
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm",
                            ".gif", *DICOM_SUFFIXES})


def read_image(path):
    """Read an image file as an array.

    Parameters
    ----------
    path : str or path-like
        An image file. DICOM files (``.dcm``, ``.dicom``) are read with
        :func:`~car_napari.io.dicom.read_dicom` (needs ``pydicom``); any other
        file with :func:`skimage.io.imread`.

    Returns
    -------
    image : ndarray
        The pixels as stored: ``(H, W)`` grey, ``(H, W, 3)`` colour (an alpha
        channel is dropped), or a stack as a multi-page TIFF holds it. A DICOM
        file gives its display-ready ``(H, W)`` float32 image in [0, 1].

    Raises
    ------
    ValueError
        If the file does not exist or cannot be read as an image.
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
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no such file: {path}")
    if path.suffix.lower() in DICOM_SUFFIXES:
        return read_dicom(path)[0]
    from skimage import io

    try:
        image = io.imread(str(path))
    except Exception as exc:
        raise ValueError(f"cannot read {path} as an image: {exc}") from None
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]  # drop alpha: the models see colour only
    return image


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

    io.imsave(str(path), image, check_contrast=False)
