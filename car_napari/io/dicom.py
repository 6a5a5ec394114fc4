"""Reading mammograms (and other greyscale images) from DICOM files.

Clinics store mammograms as DICOM. Correct grey values need the modality
rescale (RescaleSlope/RescaleIntercept), the VOI window (WindowCenter /
WindowWidth or a VOI LUT) when the file has one, and inversion of
MONOCHROME1 images (where larger stored values are darker). The result is a
float32 image in [0, 1], bright = dense, as the rest of car-napari expects.
``pydicom`` is an optional dependency (``pip install car-napari[dicom]``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import check_path

#: Suffixes (lower case) of DICOM files.
DICOM_SUFFIXES = frozenset({".dcm", ".dicom"})

__all__ = ["DICOM_SUFFIXES", "dicom_reader", "get_reader", "read_dicom"]


def _pydicom():
    try:
        import pydicom
    except ImportError:
        raise ImportError(
            "reading DICOM needs pydicom: pip install pydicom (or car-napari[dicom])"
        ) from None
    return pydicom


def read_dicom(path):
    """Read a greyscale DICOM image with its display transforms applied.

    Parameters
    ----------
    path : str or path-like
        A DICOM file holding one greyscale (MONOCHROME1 or MONOCHROME2) frame.

    Returns
    -------
    image : (H, W) ndarray of float32 in [0, 1]
        Modality rescale, then the first VOI window or LUT if present
        (scaled from its output range), otherwise the stored bit range;
        MONOCHROME1 is inverted so that bright means dense.
    metadata : dict
        Photometric interpretation, modality, view, laterality, pixel spacing
        (mm) and what was applied. No patient data.

    Raises
    ------
    ValueError
        If the file has no pixel data, is not greyscale, or holds more than
        one frame.
    ImportError
        If ``pydicom`` is not installed.

    See Also
    --------
    car_napari.io.images.read_image : Any image file, DICOM included.

    Examples
    --------
    >>> from pydicom.data import get_testdata_file
    >>> image, metadata = read_dicom(get_testdata_file("MR_small.dcm"))
    >>> image.shape, image.dtype, metadata["applied"]
    ((64, 64), dtype('float32'), ['VOI window'])
    >>> bool(0.0 <= image.min() and image.max() <= 1.0)
    True
    """
    check_path(path)
    pydicom = _pydicom()
    from pydicom.pixels import apply_modality_lut, apply_voi_lut

    try:
        ds = pydicom.dcmread(str(path))
    except (pydicom.errors.InvalidDicomError, EOFError, OSError) as exc:
        empty = Path(path).stat().st_size == 0 if Path(path).exists() else False
        reason = "the file is empty" if empty else f"{type(exc).__name__}: no DICOM header"
        raise ValueError(f"cannot read {path} as DICOM ({reason}). Check that it is a DICOM "
                         "file (a 128-byte preamble and 'DICM'), not another file renamed.") \
            from None
    if "PixelData" not in ds:
        raise ValueError(f"{path} has no pixel data.")
    photometric = str(ds.get("PhotometricInterpretation", "MONOCHROME2"))
    if photometric not in ("MONOCHROME1", "MONOCHROME2"):
        raise ValueError(
            f"{path} is {photometric}; only greyscale (MONOCHROME1/2) DICOM is supported."
        )
    stored = ds.pixel_array
    if stored.ndim != 2:
        raise ValueError(f"{path} holds {stored.ndim}-D pixel data {stored.shape}; "
                         "pass a single 2-D image (one frame).")
    values = apply_modality_lut(stored, ds).astype(np.float64)
    applied = []
    if "RescaleSlope" in ds or "RescaleIntercept" in ds or "ModalityLUTSequence" in ds:
        applied.append("modality rescale")
    bits = int(ds.get("BitsStored", 16))
    if "VOILUTSequence" in ds and len(ds.VOILUTSequence):
        # the LUT's own output range (LUTDescriptor's third value: its bit depth)
        image = apply_voi_lut(values, ds, index=0, prefer_lut=True).astype(np.float64)
        lut_bits = int(ds.VOILUTSequence[0].LUTDescriptor[2]) or 16
        image = image / float(2**lut_bits - 1)
        applied.append("VOI LUT")
    elif "WindowCenter" in ds and "WindowWidth" in ds:
        image = _window(values, _first(ds.WindowCenter), _first(ds.WindowWidth),
                        str(ds.get("VOILUTFunction", "LINEAR")).upper())
        applied.append("VOI window")
    else:
        # no VOI: the modality-rescaled range of the stored bits
        slope = float(ds.get("RescaleSlope", 1.0))
        intercept = float(ds.get("RescaleIntercept", 0.0))
        signed = int(ds.get("PixelRepresentation", 0)) == 1
        s_lo, s_hi = ((-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed
                      else (0, 2**bits - 1))
        ends = sorted([intercept + slope * s_lo, intercept + slope * s_hi])
        image = (values - ends[0]) / max(ends[1] - ends[0], 1e-12)
    image = np.clip(image, 0.0, 1.0)
    if photometric == "MONOCHROME1":
        image = 1.0 - image
        applied.append("MONOCHROME1 inverted")
    spacing = ds.get("PixelSpacing", ds.get("ImagerPixelSpacing", None))
    metadata = {
        "photometric": photometric,
        "modality": str(ds.get("Modality", "")),
        "view": str(ds.get("ViewPosition", "")),
        "laterality": str(ds.get("ImageLaterality", ds.get("Laterality", ""))),
        "pixel_spacing_mm": [float(v) for v in spacing] if spacing is not None else None,
        "applied": applied,
    }
    return image.astype(np.float32), metadata


def _first(value):
    """First value of a possibly multi-valued DICOM element."""
    try:
        return float(value[0])
    except TypeError:
        return float(value)


def _window(x, center, width, function="LINEAR"):
    """DICOM VOI window (PS3.3 C.11.2.1.2) onto [0, 1]."""
    width = float(width)
    if function in ("SIGMOID", "LINEAR_EXACT"):
        # any width > 0 (C.11.2.1.3); a file's 0 or less is read as LINEAR's least, 1
        width = width if width > 0 else 1.0
        if function == "SIGMOID":
            return 1.0 / (1.0 + np.exp(-4.0 * (x - center) / width))
        return np.clip((x - center) / width + 0.5, 0.0, 1.0)
    width = max(width, 1.0)  # LINEAR's width is at least 1 (C.11.2.1.2.1)
    if width <= 1.0:
        return (x > center - 0.5).astype(np.float64)
    return np.clip((x - (center - 0.5)) / (width - 1.0) + 0.5, 0.0, 1.0)


def get_reader(path):
    """The napari reader hook: a reader for DICOM paths, else None.

    Parameters
    ----------
    path : str or list of str
        What napari asks to open: one path or several.

    Returns
    -------
    reader : callable or None
        :func:`dicom_reader` when every path ends in ``.dcm`` or ``.dicom``
        (any case), otherwise None (napari then asks another plugin).

    Examples
    --------
    >>> get_reader("scan.dcm") is dicom_reader
    True
    >>> get_reader(["scan.dcm", "photo.png"]) is None
    True
    """
    paths = _as_paths(path)
    if not all(str(p).lower().endswith(tuple(DICOM_SUFFIXES)) for p in paths):
        return None
    return dicom_reader


def dicom_reader(path):
    """The napari reader: one image layer per DICOM path.

    Parameters
    ----------
    path : str or list of str
        One or more DICOM files.

    Returns
    -------
    layers : list of tuple
        napari ``LayerData`` tuples ``(image, kwargs, "image")``: the grey
        image of :func:`read_dicom` in [0, 1], named after the file, with a
        grey colour map, the DICOM metadata, and the pixel spacing (mm) as
        the layer scale when the file has one.

    Raises
    ------
    ValueError
        If a file cannot be read (see :func:`read_dicom`).

    Examples
    --------
    >>> from pydicom.data import get_testdata_file
    >>> (image, kwargs, kind), = dicom_reader(get_testdata_file("MR_small.dcm"))
    >>> kind, kwargs["name"], kwargs["scale"]
    ('image', 'MR_small.dcm', (0.3125, 0.3125))
    """
    layers = []
    for p in _as_paths(path):
        image, metadata = read_dicom(p)
        name = str(p).replace("\\", "/").rsplit("/", 1)[-1]
        scale = metadata["pixel_spacing_mm"]
        kwargs = {"name": name, "colormap": "gray", "metadata": metadata,
                  "contrast_limits": (0.0, 1.0)}
        if scale:
            kwargs["scale"] = tuple(scale)
        layers.append((image, kwargs, "image"))
    return layers


def _as_paths(path):
    """napari passes one path or a list of them."""
    return [path] if isinstance(path, (str, bytes)) or not hasattr(path, "__iter__") else path
