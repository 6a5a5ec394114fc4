"""Bidirectional texture functions: a stack of images of one material under
many illuminations (or views) compressed into a few subspace models
(section 14.8, docs/texture.md).

The stack's images are clustered by K-means on their colour cumulative
histograms; each cluster (subspace) gets one :class:`TextureModel`, fitted to
its most central image (the medoid); every image is then synthesised from its
subspace's model, with that image's own mean, contrast and range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._docstrings import constructor_sections, shared_parameters, shared_sections
from .._progress import Progress, drain, stage
from .._validation import check_memory, check_real, check_seed, check_shape, output_shape
from ._doc_sections import RAISES_SYNTHESIS
from ._fit import _check_options, _check_texture_size
from ._histogram import _iter_clip, _iter_restore
from ._model import iter_fit_texture
from ._stack import as_stack
from ._synthesis import _SYNTHESIS_COPIES

__all__ = ["BTFModel", "cumulative_histograms", "iter_fit_btf"]

HISTOGRAM_BINS = 32
# the examples' shared start (docstring sections written once)
EXAMPLES_STACK = """
Examples
--------
>>> import numpy as np
>>> texture = np.random.default_rng(0).random((32, 32))
>>> stack = np.stack([texture * gain for gain in (0.2, 0.25, 0.8, 0.9)])
"""
EXAMPLES_BTF = """
Examples
--------
>>> import numpy as np
>>> from car_napari.texture import BTFModel
>>> stack = np.random.default_rng(0).random((3, 32, 32))
"""


_HISTOGRAM_SHARE = 0.1  # of the progress range: the histograms, before the fits


def _cumulative_histogram(image, bins):
    """(bins * d,) cumulative histograms of the channels of one (H, W, d) image."""
    edges = np.linspace(0.0, 1.0, bins + 1)[1:-1]
    d = image.shape[2]
    out = np.empty(bins * d)
    for c in range(d):
        values = np.sort(image[..., c].ravel())
        below = np.searchsorted(values, edges, side="right") / values.size
        out[c * bins : (c + 1) * bins] = np.r_[below, 1.0]
    return out


def cumulative_histograms(stack, *, bins=HISTOGRAM_BINS, channel_axis=-1):
    """Colour cumulative histograms of every image of a stack.

    The clustering features of the BTF subspaces (section 14.8,
    docs/texture.md): robust to the texture's layout, sensitive to its
    illumination.

    Parameters
    ----------
    stack : (n, H, W) or (n, H, W, C) array
        Images along axis 0, values in [0, 1] (integer images are scaled to
        [0, 1]). A 3-D stack is grey.
    bins : int, optional
        Equal bins over [0, 1] per channel.
    channel_axis : int or None, optional
        Axis of the channels of a 4-D stack (default the last; not 0).

    Returns
    -------
    features : (n, bins * C) ndarray of float64
        Per image, for every channel in turn, the fraction of its pixels at
        or below the upper edge of each bin (the last value is 1).

    Raises
    ------
    ValueError
        If the stack is not 3-D or 4-D, is empty or not finite, or ``bins``
        is not a positive int.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import cumulative_histograms
    >>> stack = np.stack([np.full((4, 4), 0.1), np.full((4, 4), 0.9)])
    >>> cumulative_histograms(stack, bins=4)
    array([[1., 1., 1., 1.],
           [0., 0., 0., 1.]])
    """
    bins = check_real(bins, "bins (a positive int)", low=1, high=1 << 16, integer=True)
    images, _ = as_stack(stack, channel_axis)
    return np.stack([_cumulative_histogram(image, bins) for image in images])


def _kmeans(features, k, seed):
    from scipy.cluster.vq import kmeans2

    distinct = len(np.unique(features, axis=0))
    if min(k, distinct) == 1:  # kmeans2 would divide by zero and warn of empty clusters
        return np.zeros(len(features), int)
    _, labels = kmeans2(features, min(k, distinct), seed=seed, minit="++")
    # empty clusters: renumber to 0..k'-1 in order of first appearance
    _, labels = np.unique(labels, return_inverse=True)
    return labels


_FIT_PARAMETERS = """
stack : (n, H, W) or (n, H, W, C) array
    Images along axis 0 (a 3-D stack is grey); any dtype (integer
    images are scaled to [0, 1]). Every side must be at least
    ``16 * 2**(levels - 1)`` pixels.
n_subspaces : int, optional
    Number of K-means clusters (at most ``n``; empty clusters are
    dropped).
levels : int, optional
    Pyramid levels of every subspace model (see :meth:`TextureModel.fit`).
neighbourhood : 'auto', int or (eta, 2) array, optional
    Support of every subspace model (see :meth:`TextureModel.fit`).
channel_axis : int or None, optional
    Axis of the channels of a 4-D stack (default the last; not 0, which
    holds the images). None requires a 3-D grey stack.
seed : int, optional
    K-means initialisation.
"""


@shared_parameters(_FIT_PARAMETERS)
@shared_sections(examples_stack=EXAMPLES_STACK)
def iter_fit_btf(stack, *, n_subspaces=4, levels=3, neighbourhood="auto", channel_axis=-1,
                 seed=0):
    """Fit a BTF subspace model, as a job reporting progress.

    The generator form of :func:`fit_btf` (same arguments, same
    result): it yields :class:`~car_napari.Progress` records while the
    histograms are computed (one per image) and while every subspace model
    is fitted (``"subspace 2/4"``, then that fit's ``"level 1/3"`` records),
    and returns the :class:`BTFModel`. Closing the generator stops the fit
    at the next record.

    {parameters}

    Returns
    -------
    BTFModel
        The fitted model (the generator's return value).

    Yields
    ------
    Progress
        Stage ``"histograms"`` (the first tenth of the range), then
        ``"subspaces"`` (an equal share per subspace).

    Raises
    ------
    ValueError
        As :func:`fit_btf`, before the first record.
    TypeError
        As :func:`fit_btf`, before the first record.

    {examples_stack}
    >>> from car_napari.texture import iter_fit_btf
    >>> records = list(iter_fit_btf(stack, n_subspaces=2, levels=1))
    >>> [r.message for r in records if r.message.endswith("fitted")]
    ['subspace 1/2, 1 level fitted', 'subspace 2/2, 1 level fitted']
    >>> records[-1].fraction
    1.0
    """
    levels = _check_options(levels, "3d", neighbourhood)
    if not isinstance(seed, (np.random.Generator, np.random.RandomState)):
        check_real(seed, "seed (a non-negative int or a numpy Generator)", low=0,
                   high=2**32 - 1, integer=True)
    images, grey = as_stack(stack, channel_axis)
    n = images.shape[0]
    n_subspaces = check_real(n_subspaces, f"n_subspaces (an int from 1 to the number of "
                             f"images, {n})", low=1, high=n, integer=True)
    _check_texture_size(images.shape[1:3], levels, name="each image of the stack")
    # the histograms' bins span the stack's range (per channel): one subspace per
    # illumination however the stack is scaled (floats beyond [0, 1], radiances)
    low, high = images.min(axis=(0, 1, 2)), images.max(axis=(0, 1, 2))
    span = np.where(high > low, high - low, 1.0)
    features = []
    for i, image in enumerate(images):
        yield Progress("histograms", _HISTOGRAM_SHARE * i / n, f"histogram {i + 1}/{n}")
        features.append(_cumulative_histogram((image - low) / span, HISTOGRAM_BINS))
    features = np.stack(features)
    assignment = _kmeans(features, int(n_subspaces), seed) if n_subspaces > 1 \
        else np.zeros(n, int)
    models, representatives = [], []
    n_found = int(assignment.max()) + 1
    share = (1.0 - _HISTOGRAM_SHARE) / n_found
    for k in range(n_found):
        members = np.flatnonzero(assignment == k)
        centre = features[members].mean(axis=0)
        medoid = members[np.argmin(np.abs(features[members] - centre).sum(axis=1))]
        representatives.append(int(medoid))
        start = _HISTOGRAM_SHARE + k * share
        yield Progress("subspaces", start, f"subspace {k + 1}/{n_found}")
        job = iter_fit_texture(images[medoid], levels=levels, neighbourhood=neighbourhood,
                               channel_axis=-1)
        models.append((yield from stage(job, start, start + share, name="subspaces",
                                        prefix=f"subspace {k + 1}/{n_found}, ")))
    return BTFModel(tuple(models), assignment, np.array(representatives),
                    images.mean(axis=(1, 2)), images.std(axis=(1, 2)),
                    np.stack([images.min(axis=(1, 2)), images.max(axis=(1, 2))], axis=1),
                    grey)


@shared_parameters(_FIT_PARAMETERS)
@shared_sections(examples_stack=EXAMPLES_STACK)
def fit_btf(stack, *, n_subspaces=4, levels=3, neighbourhood="auto", channel_axis=-1, seed=0):
    """Cluster a stack into subspaces and fit one texture model per subspace.

    The same as running :func:`iter_fit_btf` to its end. The images are
    clustered by K-means on their cumulative histograms, binned over the
    stack's range per channel: the subspaces do not change when the whole
    stack is scaled by a positive gain and an offset (float radiances
    cluster as the stack scaled to [0, 1] does).

    {parameters}

    Returns
    -------
    BTFModel
        The fitted model.

    Raises
    ------
    ValueError
        If the stack is not (n, H, W) or (n, H, W, C), is empty, constant or
        not finite, its images are too small for ``levels``, or
        ``n_subspaces`` is not from 1 to ``n``.
    TypeError
        If ``levels`` is not an int, or the stack is not numeric.

    See Also
    --------
    iter_fit_btf : The same fit as a job that reports its progress.
    BTFModel.fit : The same, as the model's constructor.

    {examples_stack}
    >>> from car_napari.texture import fit_btf
    >>> fit_btf(stack, n_subspaces=2, levels=1).assignment.tolist()
    [0, 0, 1, 1]
    """
    return drain(iter_fit_btf(stack, n_subspaces=n_subspaces, levels=levels,
                              neighbourhood=neighbourhood, channel_axis=channel_axis, seed=seed))


_SYNTHESIZE_PARAMETERS = """
shape : tuple of 2 ints
    (height, width) of every image.
seed : int, numpy Generator or None, optional
    The same seed gives the same stack.
"""


@dataclass(eq=False)
@shared_sections(examples_stack=EXAMPLES_STACK)
class BTFModel:
    """Subspace models of a stack of images of one material.

    The BTF model of section 14.8 (docs/texture.md): the images are
    clustered into subspaces, each with one :class:`TextureModel`. Build
    one with :meth:`fit` (or :func:`iter_fit_btf`). The fields below are
    also the constructor's parameters.

    Parameters
    ----------
    models : tuple of TextureModel
        One per subspace.
    assignment : (n,) ndarray of int
        The subspace of each image of the stack.
    representatives : (k,) ndarray of int
        The image each subspace model was fitted to (its medoid).
    image_mean : (n, C) ndarray
        Each image's mean; synthesis restores it.
    image_std : (n, C) ndarray
        Each image's standard deviation; synthesis restores it.
    image_range : (n, 2, C) ndarray
        Each image's minimum and maximum; synthesis clips to them, so one
        subspace model serves several illuminations.
    grey : bool
        True when the images have no colour axis.

    {examples_stack}
    >>> from car_napari.texture import BTFModel
    >>> btf = BTFModel.fit(stack, n_subspaces=2, levels=1)
    >>> btf.n_images, len(btf.models), btf.synthesize((20, 24), seed=0).shape
    (4, 2, (4, 20, 24))
    """

    models: tuple
    assignment: np.ndarray
    representatives: np.ndarray
    image_mean: np.ndarray
    image_std: np.ndarray
    image_range: np.ndarray
    grey: bool

    @classmethod
    @shared_sections(parameters=_FIT_PARAMETERS,
                     constructor=constructor_sections("BTFModel", "fit_btf"))
    def fit(cls, stack, *, n_subspaces=4, levels=3, neighbourhood="auto", channel_axis=-1,
            seed=0):
        """Cluster a stack into subspaces and fit one texture model per subspace.

        The model's constructor: the same as :func:`fit_btf`.

        {parameters}

        {constructor}

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import BTFModel
        >>> stack = np.random.default_rng(0).random((2, 32, 32))
        >>> BTFModel.fit(stack, n_subspaces=1, levels=1).assignment.tolist()
        [0, 0]
        """
        return fit_btf(stack, n_subspaces=n_subspaces, levels=levels, neighbourhood=neighbourhood,
                       channel_axis=channel_axis, seed=seed)

    @property
    @shared_sections(examples_btf=EXAMPLES_BTF)
    def n_images(self):
        """Number of images of the fitted stack (int).

        {examples_btf}
        >>> BTFModel.fit(stack, n_subspaces=1, levels=1).n_images
        3
        """
        return int(self.assignment.size)

    @property
    @shared_sections(examples_btf=EXAMPLES_BTF)
    def nbytes(self):
        """Stored bytes (int): the compressed size.

        The subspace models, the assignment (1 byte an image) and the
        per-image mean, std and range (float32).

        {examples_btf}
        >>> btf = BTFModel.fit(stack, n_subspaces=1, levels=1)
        >>> btf.nbytes == btf.models[0].nbytes + 3 + 4 * 3 * 4
        True
        """
        per_image = self.image_mean.size + self.image_std.size + self.image_range.size
        return sum(m.nbytes for m in self.models) + self.n_images + 4 * per_image

    @shared_sections(examples_btf=EXAMPLES_BTF)
    def compression_ratio(self, stack_shape):
        """Raw float32 bytes of a stack of ``stack_shape`` over :attr:`nbytes`.

        Parameters
        ----------
        stack_shape : tuple of int
            (n, H, W) or (n, H, W, C); the model synthesises any size.

        Returns
        -------
        float
            ``4 * prod(stack_shape) / nbytes``.

        {examples_btf}
        >>> btf = BTFModel.fit(stack, n_subspaces=1, levels=1)
        >>> btf.compression_ratio(stack.shape) == 4 * stack.size / btf.nbytes
        True
        """
        shape = check_shape(stack_shape, "stack_shape ((n, H, W) or (n, H, W, C))",
                            lengths=(3, 4))
        return 4.0 * float(math.prod(shape)) / self.nbytes

    @shared_parameters(_SYNTHESIZE_PARAMETERS)
    def synthesize(self, shape, *, seed=None):
        """Synthesise every image of the stack at any size.

        Image ``i`` comes from its subspace's model, with image ``i``'s own
        mean, contrast and value range.

        {parameters}

        Returns
        -------
        stack : (n, H, W) or (n, H, W, C) ndarray of float64
            Grey when the fitted stack was, channel-last otherwise.

        Raises
        ------
        ValueError
            If ``shape`` is not two positive sizes.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import BTFModel
        >>> stack = np.random.default_rng(0).random((2, 32, 32, 3))
        >>> btf = BTFModel.fit(stack, n_subspaces=1, levels=1)
        >>> btf.synthesize((16, 20), seed=0).shape
        (2, 16, 20, 3)
        """
        return drain(self.iter_synthesize(shape, seed=seed))

    @shared_parameters(_SYNTHESIZE_PARAMETERS)
    @shared_sections(raises_synthesis=RAISES_SYNTHESIS)
    def iter_synthesize(self, shape, *, seed=None):
        """Synthesise every image of the stack, as a job: Progress, then the stack.

        The generator form of :meth:`synthesize`, with the same parameters
        and, bit for bit, the same result: image after image, each by
        :meth:`TextureModel.iter_synthesize` and a restore of its own mean,
        contrast and range by blocks of rows, with a
        :class:`~car_napari.Progress` record between blocks (closing the
        generator stops it within a fraction of a second).

        {parameters}

        Returns
        -------
        stack : (n, H, W) or (n, H, W, C) ndarray of float64
            What :meth:`synthesize` returns.

        Yields
        ------
        Progress
            Stage ``"synthesis"``, message ``"image 2/8, band 1/3, rows
            512/1024"``; an equal share of the range per image. The records
            of each image's last pass carry a preview: the stack filling in
            (images not yet done are 0; it is the array returned, do not
            modify it).

        {raises_synthesis}

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari._progress import drain
        >>> from car_napari.texture import BTFModel
        >>> stack = np.random.default_rng(0).random((2, 32, 32))
        >>> btf = BTFModel.fit(stack, n_subspaces=1, levels=1)
        >>> records = []
        >>> out = drain(btf.iter_synthesize((16, 20), seed=0), records.append)
        >>> records[-1].message, records[-1].fraction
        ('image 2/2, rows 16/16', 1.0)
        >>> np.array_equal(out, btf.synthesize((16, 20), seed=0))
        True
        """
        h, w = output_shape(shape)
        n = self.n_images
        d = self.image_mean.shape[1]
        check_memory(8 * d * h * w * (n + _SYNTHESIS_COPIES), f"shape {(h, w)}")
        rng = check_seed(seed)
        out = np.zeros((n, h, w, d))
        shown = out[..., 0] if self.grey else out
        for i in range(n):
            model = self.models[self.assignment[i]]
            part = f"image {i + 1}/{n}, "
            a, b = i / n, (i + 1) / n
            sample = yield from stage(model.iter_synthesize((h, w), seed=rng.integers(2**63)),
                                      a, a + 0.9 * (b - a), name="synthesis", prefix=part)
            sample = yield from stage(
                _iter_restore(sample.reshape(h, w, -1), self.image_mean[i], self.image_std[i]),
                a + 0.9 * (b - a), a + 0.95 * (b - a), name="synthesis", prefix=part)
            yield from stage(_iter_clip(sample, self.image_range[i], out=out[i], preview=shown),
                             a + 0.95 * (b - a), b, name="synthesis", prefix=part)
        return shown
