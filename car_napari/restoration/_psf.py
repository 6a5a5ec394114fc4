"""The point-spread function relating a restored image to the observed one
(14.46)-(14.47), section 14.5, docs/restoration.md."""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float, check_size


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
        The PSF support in pixels (default 7).
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

    Examples
    --------
    >>> import numpy as np
    >>> from scipy import ndimage
    >>> from car_napari.restoration import estimate_psf, psf_width
    >>> sharp = np.random.default_rng(0).random((64, 64))
    >>> psf = estimate_psf(ndimage.gaussian_filter(sharp, 1.0), sharp, size=9)
    >>> psf.shape, round(psf_width(psf), 1)
    ((9, 9), 1.0)
    """
    obs = as_channel_last_float(observed, channel_axis=channel_axis, name="observed")
    res = as_channel_last_float(restored, channel_axis=channel_axis, name="restored")
    if obs.shape != res.shape:
        raise ValueError(f"observed {obs.shape} and restored {res.shape} must have one shape.")
    if int(size) != size or size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer; got {size}.")
    size = int(size)
    half = size // 2
    H, W, _ = obs.shape
    if window is None:
        tiles = [(slice(0, H), slice(0, W))]
        grid = None
    else:
        if int(window) != window or window < size + 2 * half:
            raise ValueError(f"window must be an integer of at least {size + 2 * half} "
                             f"(size + 2 * (size // 2)); got {window}.")
        window = int(window)
        grid = (H // window, W // window)
        if 0 in grid:
            raise ValueError(f"window {window} is larger than the image {obs.shape[:2]}.")
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
        If the PSF has no positive mass.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.restoration import psf_width
    >>> i, j = np.indices((15, 15)) - 7
    >>> round(psf_width(np.exp(-(i**2 + j**2) / (2 * 1.5**2))), 2)
    1.5
    """
    psf = np.clip(np.asarray(psf, float), 0, None)
    total = psf.sum()
    if total <= 0:
        raise ValueError("the PSF has no positive mass.")
    r, c = np.indices(psf.shape)
    mr, mc = (psf * r).sum() / total, (psf * c).sum() / total
    var = ((psf * (r - mr) ** 2).sum() + (psf * (c - mc) ** 2).sum()) / (2 * total)
    return float(np.sqrt(var))
