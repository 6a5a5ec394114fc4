"""Pixel labelling by the neighbourhood-weighted posterior and small-blob
clean-up (labelling and post-processing, section 14.4, docs/segmentation.md)."""

from __future__ import annotations

import numpy as np

from ._mixture import _posteriors

__all__ = ["label_pixels"]


def label_pixels(features, mix, *, smoothing=2.0, threshold=0.0, min_area=0):
    """Label every pixel by its neighbourhood-weighted posterior.

    The posterior of every component is averaged over a Gaussian window
    (``smoothing`` pixels: the distance-weighted neighbourhood ``I_r``), each
    pixel takes the best component (labels are the component ids, 1..), a
    pixel whose best averaged posterior is below ``threshold`` is 0, and
    blobs smaller than ``min_area`` pixels join the nearest larger segment.

    Parameters
    ----------
    features : (H, W, D) ndarray
        Per-pixel features (:func:`local_features`).
    mix : Mixture
        The mixture whose components are the segments.
    smoothing : float, optional
        Width (pixels) of the Gaussian neighbourhood weighting; 0: none.
    threshold : float, optional
        Pixels whose best averaged posterior is below this are 0.
    min_area : int, optional
        Connected blobs smaller than this (pixels) join their neighbours.

    Returns
    -------
    labels : (H, W) ndarray of int32
        Component ids, 0 where unclassified.
    probability : (H, W) ndarray
        The best averaged posterior of every pixel.
    """
    from scipy import ndimage

    h, w, D = features.shape
    post, _ = _posteriors(features.reshape(-1, D).astype(np.float64), mix)
    post = post.reshape(h, w, mix.k)
    if smoothing > 0:
        post = ndimage.gaussian_filter(post, sigma=(smoothing, smoothing, 0))
    best = post.argmax(axis=2)
    prob = np.take_along_axis(post, best[..., None], axis=2)[..., 0]
    labels = mix.ids[best].astype(np.int32)
    if min_area > 0:
        labels = _absorb_small_blobs(labels, min_area)
    if threshold > 0:
        labels[prob < threshold] = 0
    return labels, prob


def _absorb_small_blobs(labels, min_area):
    """Blobs (4-connected) under ``min_area`` pixels take their nearest
    larger neighbour's label."""
    from skimage.measure import label as connected
    from skimage.segmentation import expand_labels

    regions = connected(labels, connectivity=1, background=-1)
    sizes = np.bincount(regions.ravel())
    small = sizes[regions] < min_area
    if not small.any() or small.all():
        return labels
    out = labels.copy()
    out[small] = 0
    return expand_labels(out, distance=max(labels.shape))


def _renumber(labels):
    """Labels 1..K (in order of the old values), 0 kept."""
    values, inverse = np.unique(labels, return_inverse=True)
    new = np.arange(values.size) + (0 if values[0] == 0 else 1)
    return new[inverse].reshape(labels.shape).astype(labels.dtype)
