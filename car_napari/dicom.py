"""Reading mammograms (and other greyscale images) from DICOM files.

Clinics store mammograms as DICOM. Correct grey values need the modality
rescale (RescaleSlope/RescaleIntercept), the VOI window (WindowCenter /
WindowWidth or a VOI LUT) when the file has one, and inversion of
MONOCHROME1 images (where larger stored values are darker). The result is a
float32 image in [0, 1], bright = dense, as the rest of car-napari expects.
``pydicom`` is an optional dependency (``pip install car-napari[dicom]``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["read_dicom", "get_reader"]


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

    Returns
    -------
    image : (H, W) ndarray of float32 in [0, 1]
        Modality rescale, then the first VOI window or LUT if present
        (scaled from its output range), otherwise the stored bit range;
        MONOCHROME1 is inverted so that bright means dense.
    metadata : dict
        Photometric interpretation, modality, view, laterality, pixel spacing
        (mm) and what was applied. No patient data.
    """
    pydicom = _pydicom()
    from pydicom.pixels import apply_modality_lut, apply_voi_lut

    ds = pydicom.dcmread(str(path))
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
    if "RescaleSlope" in ds or "RescaleIntercept" in ds:
        applied.append("modality rescale")
    bits = int(ds.get("BitsStored", 16))
    has_voi = "WindowCenter" in ds or "VOILUTSequence" in ds
    if has_voi:
        windowed = apply_voi_lut(values, ds, index=0).astype(np.float64)
        lo, hi = 0.0, float(2**bits - 1)
        if "WindowCenter" in ds and "VOILUTSequence" not in ds:
            applied.append("VOI window")
            # pydicom maps the window linearly onto [y_min, y_max] of the stored range
            y_max = float(2**bits - 1)
            signed = int(ds.get("PixelRepresentation", 0)) == 1
            lo, hi = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0.0, y_max)
        else:
            applied.append("VOI LUT")
            lo, hi = float(np.min(windowed)), float(np.max(windowed))
        image = (windowed - lo) / max(hi - lo, 1e-12)
    else:
        slope = float(ds.get("RescaleSlope", 1.0))
        intercept = float(ds.get("RescaleIntercept", 0.0))
        ends = sorted([intercept, intercept + slope * (2**bits - 1)])
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


def get_reader(path):
    """napari reader hook: a reader function for .dcm files, else None."""
    paths = [path] if isinstance(path, (str, bytes)) or not hasattr(path, "__iter__") else path
    if not all(str(p).lower().endswith((".dcm", ".dicom")) for p in paths):
        return None
    return _read_layers


def _read_layers(path):
    paths = [path] if isinstance(path, (str, bytes)) or not hasattr(path, "__iter__") else path
    layers = []
    for p in paths:
        image, metadata = read_dicom(p)
        name = str(p).replace("\\", "/").rsplit("/", 1)[-1]
        scale = metadata["pixel_spacing_mm"]
        kwargs = {"name": name, "colormap": "gray", "metadata": metadata,
                  "contrast_limits": (0.0, 1.0)}
        if scale:
            kwargs["scale"] = tuple(scale)
        layers.append((image, kwargs, "image"))
    return layers
