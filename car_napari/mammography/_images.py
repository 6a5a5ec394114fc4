"""Grey conversion and integer resampling shared by the breast, region and job
modules of the mammogram pipeline."""

from __future__ import annotations

import numpy as np

from .._progress import Progress
from .._validation import as_channel_last_float, check_channel_axis

# Pixels converted, averaged or upsampled between two records of a job, so
# that a Cancel is seen soon on a 4096x4096 mammogram.
_STRIP = 1 << 20


def _as_grey(image, channel_axis):
    """A colour export of a grey mammogram as its luminance in [0, 1]; a grey
    image (2-D, or ``channel_axis=None``) unchanged."""
    check_channel_axis(channel_axis)
    arr = np.asarray(image)
    if channel_axis is None or arr.ndim != 3:
        return image  # grey, or not an image at all: _grey01 says why
    arr = np.moveaxis(arr, channel_axis, -1)
    if arr.shape[-1] == 1:
        return arr[..., 0]
    if arr.shape[-1] not in (3, 4):
        raise ValueError(
            f"image has {arr.shape[-1]} channels on axis {channel_axis}; a colour export of "
            "a mammogram has 3 (RGB) or 4 (RGBA). Pass a 2-D grey image, or "
            "channel_axis=None for a grey image."
        )
    from skimage.color import rgb2gray

    _warn_if_colour(arr[..., :3])
    return rgb2gray(arr[..., :3])


# A grey mammogram exported as RGB has (nearly) equal channels; channels that
# differ by more than this fraction of the image's range on average are a
# colour picture, not a mammogram.
_COLOUR_SPREAD = 0.02


def _warn_if_colour(rgb):
    """Warn when an RGB image is not a grey image in three equal channels."""
    step = max(1, int(np.sqrt(rgb.shape[0] * rgb.shape[1] / 65536)))
    sample = np.asarray(rgb[::step, ::step], np.float64)
    span = float(sample.max() - sample.min())
    if span <= 0:
        return
    spread = float(np.mean(sample.max(axis=-1) - sample.min(axis=-1))) / span
    if spread > _COLOUR_SPREAD:
        import warnings

        warnings.warn(
            f"the image is in colour (its channels differ by {spread:.0%} of its range on "
            "average), not a grey mammogram; its luminance is used. Regions found on a "
            "colour picture mean nothing.", UserWarning, stacklevel=4)


# A mammogram whose every value lies within this many grey levels of an
# 8-bit image's (k / 255) is that 8-bit image carried in floats (a PNG read
# as float, a DICOM made from one, float32 rounding, noise of 1e-4): it is
# read as the 8-bit image, so that such differences, which carry no
# information, cannot change the segmentation (whose EM and greedy merging
# amplify any difference) and so the regions.
_SNAP_LEVELS = 0.1


def _off_grid(data):
    """The largest distance of a value of ``data`` from the 8-bit grid k / 255,
    in grey levels (strips of rows: no full-size temporaries)."""
    worst = 0.0
    rows = max(1, _STRIP // max(1, data.shape[1]))
    for r0 in range(0, data.shape[0], rows):
        levels = data[r0 : r0 + rows] * 255.0
        worst = max(worst, float(np.abs(levels - np.round(levels)).max()))
        if worst > _SNAP_LEVELS:
            break
    return worst


def _snap(data, r0=0, r1=None):
    """Rows ``r0:r1`` of ``data`` onto the 8-bit grid, in place."""
    part = data[r0:r1]
    np.round(part * 255.0, out=part)
    part /= 255.0


# Digital mammograms store 12 bits in a 16-bit container: a uint16 image
# whose maximum is at most this is read as 12-bit (0..4095 -> [0, 1]), so that
# it gives the regions of the same image scaled; a DICOM's BitsStored is
# honoured by the reader (car_napari.io).
_TWELVE_BIT_MAX = 4095


def bit_depth(image):
    """The bit depth a mammogram is read with.

    Integer images are scaled to [0, 1] by their range: 255 for 8 bits,
    4095 for 12 bits (a wider unsigned image whose maximum is at most 4,095:
    a digital mammogram's 12 bits in a 16-bit container), else the dtype's
    maximum.

    Parameters
    ----------
    image : array_like
        The mammogram.

    Returns
    -------
    int or None
        8, 12, or the dtype's width in bits; None for float and bool images
        (their values are kept as they are).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import bit_depth
    >>> bit_depth(np.full((4, 4), 3501, np.uint16)), bit_depth(np.zeros((4, 4), np.uint8))
    (12, 8)
    """
    arr = np.asarray(image)
    if arr.dtype.kind != "u" or arr.dtype.itemsize < 2:
        return 8 if arr.dtype == np.uint8 else (
            arr.dtype.itemsize * 8 if arr.dtype.kind == "i" else None)
    if arr.size and int(arr.max()) <= _TWELVE_BIT_MAX:
        return 12
    return arr.dtype.itemsize * 8


def _to_float(part, depth, name):
    """``as_channel_last_float`` of a grey (part of an) image, a 12-bit one
    scaled by 4095 (exactly ``part / 4095``)."""
    if depth == 12:
        part = np.asarray(part)
        out = part.astype(np.float64) / float(_TWELVE_BIT_MAX)
        return as_channel_last_float(out, channel_axis=None, name=name, copy=False)[..., 0]
    return as_channel_last_float(part, channel_axis=None, name=name)[..., 0]


def _exact(arr):
    """True for dtypes whose values are already on the 8-bit grid or need no snap."""
    return arr.dtype in (np.uint8, np.bool_)


def _grey01(image, name="image"):
    """(H, W) float64 grey image scaled like img_as_float (an 8-bit image
    carried in floats is read as the 8-bit image, :data:`_SNAP_LEVELS`);
    clear errors."""
    depth = bit_depth(image) if isinstance(image, np.ndarray) and image.ndim == 2 else None
    data = _to_float(image, depth, name)
    _check_contrast(data, name)
    if not _exact(np.asarray(image)) and _off_grid(data) <= _SNAP_LEVELS:
        _snap(data)
    return data


def _iter_grey(image, channel_axis, name="mammogram"):
    """``_grey01(_as_grey(image, channel_axis), name)`` as a job: a large
    image is converted in strips of rows with a "reading" record after each
    (the same values; a bad image gets the same error)."""
    arr = np.asarray(image) if image is not None else None
    colour = arr is not None and channel_axis is not None and arr.ndim == 3
    plain = (arr is None or arr.dtype.kind not in "biuf" or arr.ndim not in (2, 3)
             or (arr.ndim == 3 and not colour))
    if not plain and colour:
        arr = np.moveaxis(arr, channel_axis, -1)
    if (plain or arr.shape[0] * arr.shape[1] <= _STRIP
            or (colour and arr.shape[-1] not in (1, 3, 4))):
        return _grey01(_as_grey(image, channel_axis), name=name)
    H, W = arr.shape[:2]
    rows = max(1, _STRIP // W)
    out = np.empty((H, W))
    depth = None if colour else bit_depth(arr)
    for r0 in range(0, H, rows):
        part = arr[r0 : r0 + rows]
        try:
            part = _as_grey(part, -1 if colour else None)
            out[r0 : r0 + rows] = _to_float(part, depth, name)
        except (ValueError, TypeError):
            return _grey01(_as_grey(image, channel_axis), name=name)  # the whole image's error
        r1 = min(r0 + rows, H)
        yield Progress("reading", 0.8 * r1 / H, f"rows {r1}/{H}")
    _check_contrast(out, name)
    if not (_exact(arr) and not colour) and _off_grid(out) <= _SNAP_LEVELS:
        for r0 in range(0, H, rows):
            _snap(out, r0, r0 + rows)
            yield Progress("reading", 0.8 + 0.2 * min(r0 + rows, H) / H, "8-bit grey levels")
    return out


def _check_contrast(data, name):
    lo, hi = float(data.min()), float(data.max())
    if hi <= lo:
        raise ValueError(
            f"{name} is constant (every pixel is {lo:g}): there is no breast to find. "
            "Pass a mammogram with visible tissue."
        )


def _block_mean(data, factor):
    """Downsample by an integer factor (block mean, edges cropped)."""
    if factor <= 1:
        return data
    h, w = (data.shape[0] // factor) * factor, (data.shape[1] // factor) * factor
    return data[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


def _upsample_mask(small, shape, factor):
    """Nearest-neighbour upsampling of a mask to ``shape`` (edges padded)."""
    big = np.repeat(np.repeat(small, factor, axis=0), factor, axis=1)
    out = np.zeros(shape, bool)
    h, w = min(shape[0], big.shape[0]), min(shape[1], big.shape[1])
    out[:h, :w] = big[:h, :w]
    if h < shape[0]:
        out[h:, :w] = out[h - 1 : h, :w]
    if w < shape[1]:
        out[:, w:] = out[:, w - 1 : w]
    return out
