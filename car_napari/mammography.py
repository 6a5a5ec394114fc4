"""Mammogram helpers for ROI detection (SPEC 3.1): the breast area first.

``detect_breast`` separates the breast from the background (film, labels,
markers), so that the segmentation of SPEC 3 runs on tissue only.
"""

from __future__ import annotations

import numpy as np

from ._validation import as_channel_last_float, summarize

__all__ = ["detect_breast"]


def _largest_component(mask):
    from skimage.measure import label

    lab = label(mask, connectivity=1)
    if lab.max() == 0:
        return mask
    sizes = np.bincount(lab.ravel())
    sizes[0] = 0
    return lab == sizes.argmax()


def detect_breast(image, *, work_size=256):
    """Breast area of a mammogram (grey, any dtype).

    The image is reduced to about ``work_size`` pixels across, smoothed and
    thresholded by Otsu's method; the largest connected component (film
    labels and markers are smaller and detached by an opening) with its
    holes filled is the breast. The pectoral muscle of MLO views is not
    removed yet (a first heuristic, Otsu within the breast in the top corner
    of the chest-wall side, did not find it on mini-MIAS).

    Returns
    -------
    mask : (H, W) ndarray of bool

    Raises
    ------
    ValueError
        For a constant (e.g. all-black) image or one without a large bright
        region.
    """
    from scipy import ndimage
    from skimage.filters import threshold_otsu
    from skimage.transform import resize

    data = as_channel_last_float(image, channel_axis=None, name="mammogram")[..., 0]
    summary = summarize(data[..., None])
    if summary.max[0] - summary.min[0] <= 1e-12 * max(abs(summary.max[0]), 1.0):
        raise ValueError(
            "the mammogram is constant (all black?): there is no breast to find. Check "
            "the file, its windowing, or the layer chosen."
        )
    h, w = data.shape
    factor = max(1, int(round(max(h, w) / work_size)))
    small = data[::factor, ::factor] if factor > 1 else data
    small = ndimage.gaussian_filter(small, 2.0)
    tissue = small > threshold_otsu(small)
    tissue = ndimage.binary_opening(tissue, iterations=2)
    breast = ndimage.binary_fill_holes(_largest_component(tissue))
    if breast.sum() < 0.01 * breast.size:
        raise ValueError("no breast area found: the image has no large bright region.")
    return resize(breast.astype(float), (h, w), order=0, anti_aliasing=False) > 0.5
