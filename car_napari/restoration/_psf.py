"""The point-spread function relating a restored image to the observed one
(14.46)-(14.47), section 14.5, docs/restoration.md."""

from __future__ import annotations

import numpy as np

from .._validation import (
    as_channel_last_float,
    channel_last_shape,
    check_memory,
    check_real,
    check_size,
)

# the largest PSF support: 31 x 31 = 961 unknowns, a 7 MB normal system (the
# design matrix has one column per tap and a row per pixel and channel)
MAX_PSF_SIZE = 31


def _largest_size(h, w, d):
    """The largest odd size whose taps an h x w x d region determines."""
    best = 1
    for size in range(1, MAX_PSF_SIZE + 1, 2):
        half = size // 2
        if max(h - 2 * half, 0) * max(w - 2 * half, 0) * d >= size * size:
            best = size
    return best


def estimate_psf(observed, restored, *, size=7, window=None, channel_axis=-1):
    """Estimate the point-spread function from a restored to an observed image.

    The least-squares fit (14.46)-(14.47): ``psi = V_W^{-1} V_WX`` where
    ``W_r`` is the ``size x size`` neighbourhood of the restored image around
    ``r`` and ``X_r`` the observed pixel, summed over the image (or over each
    window). Colour channels share one PSF. Means are removed first, so a
    brightness offset does not bias it.

    Parameters
    ----------
    observed : (H, W) or (H, W, C) array
        The observed (degraded) image.
    restored : (H, W) or (H, W, C) array
        The restored (or sharp) image, of the shape of ``observed``.
    size : odd int, optional
        The PSF support in pixels (default 7), at most 31, and small enough
        that the image (or a window) has as many interior pixels as the
        PSF has taps.
    window : int or None, optional
        None: one global PSF. An int: PSFs of non-overlapping
        ``window x window`` tiles (the local PSFs of a slowly varying blur);
        at least ``size + 2 * (size // 2)``.
    channel_axis : int or None, optional
        The colour axis of 3-D images (default -1); None for grey images.
        2-D images are always grey.

    Returns
    -------
    psf : (size, size) ndarray, or (H // window, W // window, size, size)
        ``observed ~ convolve(restored, psf)``.

    Raises
    ------
    ValueError
        If the images differ in shape, ``size`` is not a positive odd
        integer, ``window`` is too small or larger than the image, or the
        restored image is too flat to determine the PSF.

    Notes
    -----
    A constant ``observed`` image is accepted: none of the restored image's
    texture is seen in it, so the PSF is zero (finite). A constant (or too
    flat) ``restored`` image determines no PSF and is refused.

    Examples
    --------
    >>> from scipy import ndimage
    >>> from car_napari.restoration import estimate_psf, psf_width
    >>> sharp = np.random.default_rng(0).random((64, 64))
    >>> psf = estimate_psf(ndimage.gaussian_filter(sharp, 1.0), sharp, size=9)
    >>> psf.shape, round(psf_width(psf), 1)
    ((9, 9), 1.0)
    """
    size = check_real(size, "size (a positive odd integer)", low=1, high=MAX_PSF_SIZE,
                      integer=True)
    if size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer; got {size}.")
    half = size // 2
    if window is not None:
        window = check_real(window, f"window (an integer of at least {size + 2 * half}, "
                            "size + 2 * (size // 2), or None)", low=size + 2 * half,
                            integer=True)
    # the layout before any pass over the values
    shape = channel_last_shape(observed, channel_axis=channel_axis, name="observed")
    other = channel_last_shape(restored, channel_axis=channel_axis, name="restored")
    if shape != other:
        raise ValueError(f"observed {shape} and restored {other} must have one shape.")
    H, W, d = shape
    if window is not None and window > min(H, W):
        raise ValueError(f"window {window} is larger than the image {(H, W)}.")
    side_h, side_w = (H, W) if window is None else (window, window)
    equations = max(side_h - 2 * half, 0) * max(side_w - 2 * half, 0) * d
    if equations < size * size:
        largest = _largest_size(side_h, side_w, d)
        raise ValueError(
            f"size {size} is too large for {'the image' if window is None else 'a window'} "
            f"of {side_h}x{side_w}: its {size * size} taps need at least as many interior "
            f"pixels, there are {equations}. Use size <= {largest}"
            + (" or a larger window." if window is not None else ".")
        )
    n_rows = max(H - 2 * half, 0) * max(W - 2 * half, 0) * d
    check_memory(8 * n_rows * (size * size + 2), f"size={size} on an image of {H}x{W}x{d}")
    obs = as_channel_last_float(observed, channel_axis=channel_axis, name="observed")
    res = as_channel_last_float(restored, channel_axis=channel_axis, name="restored")
    if window is None:
        tiles = [(slice(0, H), slice(0, W))]
        grid = None
    else:
        grid = (H // window, W // window)
        tiles = [(slice(i * window, (i + 1) * window), slice(j * window, (j + 1) * window))
                 for i in range(grid[0]) for j in range(grid[1])]
    check_size(res, ((half, half), (half, half)), name="restored")
    psfs = []
    for rows, cols in tiles:
        o = obs[rows, cols] - obs[rows, cols].mean(axis=(0, 1))
        r = res[rows, cols] - res[rows, cols].mean(axis=(0, 1))
        h, w = o.shape[:2]
        # design matrix: one column per PSF tap, rows = interior pixels x channels
        cols_ = [r[half + di : h - half + di, half + dj : w - half + dj].ravel()
                 for di in range(-half, half + 1) for dj in range(-half, half + 1)]
        A = np.stack(cols_, axis=1)
        b = o[half : h - half, half : w - half].ravel()
        gram = A.T @ A
        if not np.isfinite(gram).all() or np.linalg.matrix_rank(gram) < gram.shape[0]:
            raise ValueError("the restored image is too flat to estimate a PSF of this size "
                             "(its neighbourhoods are linearly dependent); use a smaller size "
                             "or a more textured region.")
        psi = np.linalg.solve(gram, A.T @ b)
        # (14.46) fits X_r on W_r = restored[r + s]; convolution flips the taps
        psfs.append(psi.reshape(size, size)[::-1, ::-1])
    if grid is None:
        return psfs[0]
    return np.array(psfs).reshape(grid[0], grid[1], size, size)


def psf_width(psf):
    """Measure the Gaussian-equivalent standard deviation of a PSF, in pixels.

    The root mean of its second moments about its centroid along rows and
    columns, negative taps clipped.

    Parameters
    ----------
    psf : (h, w) array
        A point-spread function, e.g. from :func:`estimate_psf`.

    Returns
    -------
    width : float
        The standard deviation, in pixels, of the Gaussian with the same
        second moments.

    Raises
    ------
    ValueError
        If the PSF is not a non-empty finite 2-D array, or has no positive
        mass.
    TypeError
        If the PSF is not numeric.

    Examples
    --------
    >>> from car_napari.restoration import psf_width
    >>> i, j = np.indices((15, 15)) - 7
    >>> round(psf_width(np.exp(-(i**2 + j**2) / (2 * 1.5**2))), 2)
    1.5
    """
    arr = np.asarray(psf)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"psf has dtype {arr.dtype}; pass a numeric 2-D array.")
    if arr.ndim != 2 or arr.size == 0:
        raise ValueError(f"psf must be a non-empty 2-D array; got shape {arr.shape}.")
    if not np.isfinite(arr).all():
        raise ValueError("psf contains NaN or infinite values.")
    psf = np.clip(arr.astype(float), 0, None)
    total = psf.sum()
    if total <= 0:
        raise ValueError("the PSF has no positive mass.")
    r, c = np.indices(psf.shape)
    mr, mc = (psf * r).sum() / total, (psf * c).sum() / total
    var = ((psf * (r - mr) ** 2).sum() + (psf * (c - mc) ** 2).sum()) / (2 * total)
    return float(np.sqrt(var))
