"""Bidirectional texture functions: a stack of images of one material under
many illuminations (or views) compressed into a few subspace models (SPEC 7).

The stack's images are clustered by K-means on their colour cumulative
histograms; each cluster (subspace) gets one :class:`TextureModel`, fitted to
its most central image (the medoid); every image is then synthesised from its
subspace's model, with that image's own mean, contrast and range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_channel_last_float
from ._model import TextureModel

__all__ = ["BTFModel", "cumulative_histograms"]

HISTOGRAM_BINS = 32


def cumulative_histograms(stack, *, bins=HISTOGRAM_BINS):
    """(n, bins * C) colour cumulative histograms of a (n, H, W, C) stack in
    [0, 1] units: the clustering features of SPEC 7 (robust to the texture's
    layout, sensitive to its illumination)."""
    n, _, _, C = stack.shape
    edges = np.linspace(0.0, 1.0, bins + 1)[1:-1]
    features = np.empty((n, bins * C))
    for i in range(n):
        for c in range(C):
            values = np.sort(stack[i, ..., c].ravel())
            below = np.searchsorted(values, edges, side="right") / values.size
            features[i, c * bins : (c + 1) * bins] = np.r_[below, 1.0]
    return features


def _kmeans(features, k, seed):
    from scipy.cluster.vq import kmeans2

    _, labels = kmeans2(features, k, seed=seed, minit="++")
    # empty clusters: renumber to 0..k'-1 in order of first appearance
    _, labels = np.unique(labels, return_inverse=True)
    return labels


@dataclass(eq=False)
class BTFModel:
    """Subspace models of a stack of images of one material.

    Attributes
    ----------
    models : tuple of TextureModel, one per subspace.
    assignment : (n,) int array, the subspace of each image of the stack.
    representatives : (k,) int array, the image each subspace model was fitted to.
    image_mean, image_std : (n, C) arrays, each image's mean and standard
        deviation; image_range : (n, 2, C) its minimum and maximum. Synthesis
        restores them, so one subspace model serves several illuminations.
    grey : bool, True when the images have no colour axis.
    """

    models: tuple
    assignment: np.ndarray
    representatives: np.ndarray
    image_mean: np.ndarray
    image_std: np.ndarray
    image_range: np.ndarray
    grey: bool

    @classmethod
    def fit(cls, stack, *, n_subspaces=4, levels=3, neighbourhood="auto", channel_axis=-1,
            seed=0):
        """Cluster a (n, H, W[, C]) stack into subspaces and fit one texture
        model per subspace.

        Parameters
        ----------
        stack : (n, H, W) or (n, H, W, C) array, images along axis 0.
        n_subspaces : int, optional
            Number of K-means clusters (at most ``n``; empty clusters are dropped).
        levels, neighbourhood : see :meth:`TextureModel.fit`.
        channel_axis : int or None, optional
            Colour axis of each image (-1: the last axis of the stack); None for grey.
        seed : int, optional
            K-means initialisation.
        """
        arr = np.asarray(stack)
        grey = channel_axis is None
        if arr.ndim != (3 if grey else 4):
            raise ValueError(
                f"stack must be (n, H, W{'' if grey else ', C'}) with the images along axis 0; "
                f"got shape {arr.shape}." + ("" if grey else " For grey images pass "
                                             "channel_axis=None."))
        n = arr.shape[0]
        if n < 1:
            raise ValueError("the stack is empty.")
        if int(n_subspaces) != n_subspaces or not 1 <= n_subspaces <= n:
            raise ValueError(f"n_subspaces must be an int from 1 to the number of images "
                             f"({n}); got {n_subspaces!r}.")
        images = np.stack([as_channel_last_float(a, channel_axis=None if grey else -1,
                                                 name=f"image {i}")
                           for i, a in enumerate(arr)])
        features = cumulative_histograms(images)
        assignment = _kmeans(features, int(n_subspaces), seed) if n_subspaces > 1 \
            else np.zeros(n, int)
        models, representatives = [], []
        for k in range(assignment.max() + 1):
            members = np.flatnonzero(assignment == k)
            centre = features[members].mean(axis=0)
            medoid = members[np.argmin(np.abs(features[members] - centre).sum(axis=1))]
            representatives.append(int(medoid))
            models.append(TextureModel.fit(images[medoid], levels=levels,
                                           neighbourhood=neighbourhood, channel_axis=-1))
        return cls(tuple(models), assignment, np.array(representatives),
                   images.mean(axis=(1, 2)), images.std(axis=(1, 2)),
                   np.stack([images.min(axis=(1, 2)), images.max(axis=(1, 2))], axis=1),
                   grey)

    @property
    def n_images(self):
        return int(self.assignment.size)

    @property
    def nbytes(self):
        """Stored bytes: the subspace models, the assignment (1 byte an image)
        and the per-image mean, std and range (float32)."""
        per_image = self.image_mean.size + self.image_std.size + self.image_range.size
        return sum(m.nbytes for m in self.models) + self.n_images + 4 * per_image

    def compression_ratio(self, stack_shape):
        """Raw float32 bytes of the stack over :attr:`nbytes`."""
        return 4.0 * float(np.prod(stack_shape)) / self.nbytes

    def synthesize(self, shape, *, seed=None):
        """(n, H, W[, C]) synthesised stack: image ``i`` from its subspace's
        model, with image ``i``'s own mean, contrast and value range."""
        rng = np.random.default_rng(seed)
        out = []
        for i in range(self.n_images):
            model = self.models[self.assignment[i]]
            sample = model.synthesize(shape, seed=rng.integers(2**63))
            sample = sample.reshape(shape[0], shape[1], -1)
            centred = sample - sample.mean(axis=(0, 1))
            spread = centred.std(axis=(0, 1))
            gain = np.where(spread > 0, self.image_std[i] / np.where(spread > 0, spread, 1), 1)
            image = np.clip(self.image_mean[i] + centred * gain, self.image_range[i, 0],
                            self.image_range[i, 1])
            out.append(image[..., 0] if self.grey else image)
        return np.stack(out)
