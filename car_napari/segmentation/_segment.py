"""Unsupervised multiresolution texture segmentation: the job (section 14.4,
docs/segmentation.md).

Four directional adaptive 3DCAR models at several resolutions give a feature
vector ``Theta_r`` per pixel (:mod:`._features`); a Gaussian mixture with
diagonal covariances is fitted by EM from a regular initialisation and shrunk
by Kullback-Leibler merging (:mod:`._mixture`); pixels are labelled by the
neighbourhood-weighted posterior (:mod:`._labelling`), optionally under a
Potts prior on the labels (mean field, :mod:`._prior`; ``prior=0`` by
default: on the tuning mosaics the posteriors are so confident that
strengths 0.5-10 changed at most 0.12 % of the pixels and no score).

:func:`iter_segment` is the job: it yields :class:`~car_napari.Progress`
records whose previews are the labels after initialisation and after every
merge (so a viewer can show the segments merging live) and returns the
:class:`SegmentationResult`; :func:`segment` runs it to its end.

Every option is checked before any work (:func:`_check_options`).

Memory: EM runs on a fixed random sample of pixels (its E step in one
pass, no (N, K) array); every merge state is
labelled in bands of rows (the posteriors of all components never exist for
the whole image) and its labels are kept compressed, so that re-cuts of the
history are look-ups. Besides the (H, W, D) float32 features (96 bytes per
pixel for D = 24) the mixture, merging and labelling hold about 25 bytes per
pixel at their peak, plus some 40 MB (one band of posteriors, the EM sample).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import Progress, drain, stage
from .._validation import (
    as_channel_last_float,
    channel_last_shape,
    channel_last_view,
    check_channel_axis,
    check_forgetting,
    check_mask,
    check_not_constant,
    check_real,
)
from ..model.neighbourhood import as_offsets
from ._features import iter_local_features, local_features, pseudo_colour
from ._labelling import _cut_labels, _iter_label
from ._mixture import (
    _block_grid,
    _choose_k,
    _drop_weak,
    _iter_block_init,
    _iter_em,
    _merge,
    _merge_closest,
    _stops,
)
from ._regions import iter_region_merge_order

__all__ = ["SegmentationResult", "iter_segment", "segment"]

# EM iterations of the initial mixture and before every merge
_INIT_EM_STEPS = 10
_PRE_MERGE_EM_STEPS = 2
# pixels the mixture is fitted on (a random sample of the masked image)
_EM_SAMPLE = 40000
# parts of the job's progress: features (about 3/4 of the time on 1024x1024
# RGB), then initialisation, then the labelling of every merge state (work
# proportional to K + _ABSORB_WORK each)
_FEATURES_END, _INIT_END, _MERGES_END = 0.7, 0.72, 1.0
_ABSORB_WORK = 3.0
# images at least this many pixels a side are labelled from the posteriors of
# every second row and column, interpolated (4x less work; the features vary
# over ~10 pixels)
_LABEL_STEP_SIDE = 256
# default stop of the merging, in nats of mean log-likelihood per pixel and
# per feature dimension: a merge's loss is a sum over the features' dimensions,
# so colour (24 features) stops later than grey (18): 1.08 / 1.44 nats for
# grey / colour. Chosen with the variance floor (0.2) on the TUNING mosaics of
# seeds 1-3 (docs/segmentation.md)
MERGE_NATS_PER_FEATURE = 0.06
# ... and, since issue 32, more than this fraction of the costliest merge of
# the history (the last merges, between textures): on mosaics of 2 or 3
# textures their regions are larger, so a merge inside one texture costs
# more nats per pixel than 0.06 per feature and stopped the merging too
# early. Chosen on the TUNING mosaics of benchmarks/bench_auto_k.py (the
# largest fraction that changed no 5-texture TUNING mosaic; docs/segmentation.md)
MERGE_RELATIVE = 0.22


@dataclass
class SegmentationResult:
    """Outcome of :func:`segment`: the labels plus the whole merge history.

    Parameters
    ----------
    labels : (H, W) ndarray of int
        Segments 1..K, 0 where unclassified.
    n_segments : int
        K of ``labels`` (found automatically unless given).
    history : list of Mixture
        Mixtures from ``K_ini`` components down to 1, one per merge.
    probability : (H, W) ndarray of float32
        Neighbourhood-weighted posterior probability of each pixel's label.
    features : (H, W, D) ndarray of float32
        The per-pixel features the mixtures were fitted on.
    smoothing, min_area, threshold : float, int, float
        The labelling options used (reused by :meth:`labels_at`).
    prior, prior_iterations : float, int
        The Potts prior on the labels used (reused by :meth:`labels_at`).
    label_step : int
        The posteriors are computed on every ``label_step``-th row and
        column and interpolated (1 on small images, else 2).
    mask : (H, W) ndarray of bool or None
        The segmented pixels (others are 0), or None for all.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import segment
    >>> image = np.random.default_rng(0).random((32, 32))
    >>> result = segment(image, levels=1, n_init=4)
    >>> result.labels.shape, result.history[0].k, result.history[-1].k
    ((32, 32), 4, 1)
    """

    labels: np.ndarray
    n_segments: int
    history: list
    probability: np.ndarray
    features: np.ndarray = field(repr=False)
    smoothing: float = 2.0
    min_area: int = 0
    threshold: float = 0.0
    mask: np.ndarray | None = field(default=None, repr=False)
    label_step: int = 1
    prior: float = 0.0
    prior_iterations: int = 0
    # the labels of every history state (compressed, before the threshold
    # and the mask) and a few states' probabilities: re-cuts are look-ups
    _cuts: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _probs: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _final: int | None = field(default=None, init=False, repr=False, compare=False)

    def mixture_at(self, k):
        """The mixture of the history with ``k`` components.

        Weak components may be dropped between merges, so some K are missing
        from the history: the mixture with the fewest components >= ``k`` is
        taken, after clipping ``k`` to the range of the history.

        Parameters
        ----------
        k : int
            The number of components wanted.

        Returns
        -------
        Mixture
            One state of :attr:`history` (not a copy).

        Raises
        ------
        ValueError
            If the history is empty.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.segmentation import segment
        >>> result = segment(np.random.default_rng(0).random((32, 32)), levels=1, n_init=4)
        >>> result.mixture_at(2).k, result.mixture_at(99).k
        (2, 4)
        """
        return self.history[self._index(k)]

    def _index(self, k):
        ks = [mx.k for mx in self.history]
        if not ks:
            raise ValueError("the merge history is empty.")
        k = check_real(k, "k (the number of segments)", low=1, integer=True)
        k = int(np.clip(k, min(ks), max(ks)))
        return min((i for i, kk in enumerate(ks) if kk >= k), key=lambda i: ks[i])

    def labels_at(self, k, *, threshold=None):
        """Labelling with ``k`` segments, re-cut from the stored history.

        No new features and no new EM; the labels of every merge state are
        stored, so this is a look-up unless ``threshold`` needs the
        probabilities of a state not labelled lately
        (see :meth:`cached_labels_at`).

        Parameters
        ----------
        k : int
            The number of segments (see :meth:`mixture_at`).
        threshold : float, optional
            Posterior threshold of the labelling (default: the segmentation's).

        Returns
        -------
        (H, W) ndarray of int32
            Segments 1..n (n <= k), 0 where unclassified or outside the mask.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.segmentation import segment
        >>> result = segment(np.random.default_rng(0).random((32, 32)), levels=1, n_init=4)
        >>> int(result.labels_at(1).max())
        1
        """
        return drain(self.iter_labels_at(k, threshold=threshold))

    def iter_labels_at(self, k, *, threshold=None):
        """:meth:`labels_at` as a job: yield progress, return the labels.

        It yields nothing when the re-cut is a look-up
        (:meth:`cached_labels_at`); otherwise it labels the state's pixels
        again, in bands of rows, and keeps the state's probabilities.

        Parameters
        ----------
        k : int
            The number of segments (see :meth:`mixture_at`).
        threshold : float, optional
            Posterior threshold of the labelling (default: the segmentation's).

        Returns
        -------
        (H, W) ndarray of int32
            What :meth:`labels_at` returns (the generator's return value).

        Yields
        ------
        Progress
            Stage "labelling", message ``"K = n: ..."``, after every band of
            rows.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari import drain
        >>> from car_napari.segmentation import segment
        >>> result = segment(np.random.default_rng(0).random((32, 32)), levels=1, n_init=4)
        >>> records = []
        >>> labels = drain(result.iter_labels_at(3, threshold=0.9), records.append)
        >>> labels.shape, {r.stage for r in records}
        ((32, 32), {'labelling'})
        >>> np.array_equal(result.cached_labels_at(3, threshold=0.9), labels)
        True
        """
        threshold = self._threshold(threshold)
        i = self._index(k)
        labels, prob = self._cut(i, writable=False), self._probs.get(i)
        if labels is None or (threshold > 0 and prob is None):
            mix = self.history[i]
            labels, prob = yield from stage(self._iter_labelling(mix), 0.0, 1.0,
                                            prefix=f"K = {mix.k}: ")
            self._store(i, None if i in self._cuts else labels, prob)
        return self._finish(labels, prob, threshold)

    def cached_labels_at(self, k, *, threshold=None):
        """:meth:`labels_at` when it is a look-up, else None (no labelling).

        Every state's labels are stored; the probabilities (needed for a
        threshold) are kept for the final state and the latest other state
        labelled again. A look-up still passes over every pixel (the state's
        labels decompressed, thresholded and renumbered: tens of ms on a
        4000x4000 image), so a viewer runs it, as :meth:`iter_labels_at`, in
        a worker.

        Parameters
        ----------
        k : int
            The number of segments (see :meth:`mixture_at`).
        threshold : float, optional
            Posterior threshold of the labelling (default: the segmentation's).

        Returns
        -------
        (H, W) ndarray of int32 or None
            What :meth:`labels_at` returns, or None when it would label the
            pixels again.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.segmentation import segment
        >>> result = segment(np.random.default_rng(0).random((32, 32)), levels=1, n_init=4)
        >>> int(result.cached_labels_at(3).max())  # a stored state of the history
        3
        >>> result.cached_labels_at(3, threshold=0.9) is None
        True
        """
        threshold = self._threshold(threshold)
        i = self._index(k)
        prob = self._probs.get(i)  # one look-up: another thread may drop it later
        if i not in self._cuts or (threshold > 0 and prob is None):
            return None
        return self._finish(self._cut(i, writable=False), prob, threshold)

    def _threshold(self, threshold):
        """A re-cut's threshold: the segmentation's, or this one checked."""
        return self.threshold if threshold is None else check_real(
            threshold, "threshold", low=0.0, high=1.0, high_open=True)

    def _iter_labelling(self, mix):
        """Every pixel labelled by ``mix`` with the segmentation's labelling
        options (in bands, yielding): (labels, probability)."""
        return _iter_label(self.features, mix, smoothing=self.smoothing,
                           min_area=self.min_area, step=self.label_step, prior=self.prior,
                           prior_iterations=self.prior_iterations)

    def _cut(self, i, *, writable=True):
        """The stored labels of state ``i`` (in their compact dtype), or None."""
        if i not in self._cuts:
            return None
        data, dtype = self._cuts[i]
        flat = np.frombuffer(zlib.decompress(data), dtype=dtype)
        if writable:
            flat = flat.copy()
        return flat.reshape(self.features.shape[:2])

    def _store(self, i, labels, prob=None):
        """Keep state ``i``'s labels (compressed) and, with those of the final
        state, its probabilities (the latest other state's only)."""
        if labels is not None:
            top = int(labels.max(initial=0))
            dtype = np.uint8 if top < 2**8 else np.uint16 if top < 2**16 else np.int32
            self._cuts[i] = zlib.compress(labels.astype(dtype).tobytes(), 1), dtype
        if prob is not None:
            for j in [j for j in self._probs if j not in (i, self._final)]:
                del self._probs[j]
            self._probs[i] = prob

    def _finish(self, labels, prob, threshold):
        """Threshold, mask and renumber state labels (not changed): a new
        (H, W) int32 array."""
        return _cut_labels(labels, prob if threshold > 0 else None, threshold, self.mask)


# bounds of the options that set the work: beyond them a call would run for
# minutes (a Gaussian window of 1e6 pixels) rather than fail
_MAX_SMOOTHING = 32.0
_MAX_PRIOR_ITERATIONS = 50
_MAX_EM_STEPS = 100
_MAX_N_INIT = 64  # the merging labels every state: work ~ n_init**2
# options of local_features that segment sets itself
_OWN_FEATURE_OPTIONS = ("levels", "neighbourhood", "forgetting", "channel_axis", "seed")


def _check_options(image, features, mask, channel_axis, options):
    """Every option of :func:`iter_segment` checked before any work (no pass
    over the image's values): a TypeError or ValueError naming the option
    and what is allowed. Returns the options normalised (ints, floats), the
    (H, W) shape and the mask as a bool array (or None)."""
    o = dict(options)
    if o["n_segments"] is not None:
        o["n_segments"] = check_real(o["n_segments"], "n_segments", low=1, integer=True,
                                     strict=True)
    o["n_init"] = check_real(o["n_init"], "n_init", low=2, high=_MAX_N_INIT, integer=True,
                             strict=True)
    if o["n_segments"] is not None and o["n_segments"] > o["n_init"]:
        raise ValueError(f"n_segments ({o['n_segments']}) must not exceed n_init "
                         f"({o['n_init']}).")
    o["levels"] = check_real(o["levels"], "levels", low=1, high=30, integer=True, strict=True)
    o["forgetting"] = check_forgetting(o["forgetting"])
    o["smoothing"] = check_real(o["smoothing"], "smoothing", low=0.0, high=_MAX_SMOOTHING)
    o["threshold"] = check_real(o["threshold"], "threshold", low=0.0, high=1.0,
                                high_open=True)
    if o["min_area"] is not None:
        o["min_area"] = check_real(o["min_area"], "min_area", low=0, integer=True, strict=True)
    if o["merge_threshold"] is not None:
        o["merge_threshold"] = check_real(o["merge_threshold"], "merge_threshold", low=0.0)
    if o["region_threshold"] is not None:
        o["region_threshold"] = check_real(o["region_threshold"], "region_threshold",
                                           low=0.0)
        if o["n_segments"] is not None:
            raise ValueError(
                f"region_threshold merges the segments of the automatic number of segments; "
                f"with n_segments={o['n_segments']} there is none. Pass n_segments=None or "
                "region_threshold=None.")
        if image is None:
            raise ValueError("region_threshold reads the image's pixels: pass the image "
                             "with the features, or region_threshold=None.")
    o["var_floor"] = check_real(o["var_floor"], "var_floor", low=0.0, low_open=True)
    o["merge_em_steps"] = check_real(o["merge_em_steps"], "merge_em_steps", low=0,
                                     high=_MAX_EM_STEPS, integer=True, strict=True)
    o["prior"] = check_real(o["prior"], "prior", low=0.0)
    o["prior_iterations"] = check_real(o["prior_iterations"], "prior_iterations", low=0,
                                       high=_MAX_PRIOR_ITERATIONS, integer=True, strict=True)
    o["seed"] = check_real(o["seed"], "seed", low=0, integer=True, strict=True)
    if o["grey"] not in ("pseudo_colour", "grey"):
        raise ValueError(f"grey must be 'pseudo_colour' or 'grey'; got {o['grey']!r}.")
    as_offsets(o["neighbourhood"])  # its own messages
    extra = o["feature_options"]
    if extra is not None:
        if not isinstance(extra, dict):
            raise TypeError(f"feature_options must be a dict or None; got {extra!r}.")
        import inspect

        known = set(inspect.signature(local_features).parameters) - {"image"}
        bad = sorted(set(extra) - (known - set(_OWN_FEATURE_OPTIONS)))
        if bad:
            raise TypeError(
                f"feature_options has unknown or reserved keys {bad}; allowed: "
                f"{sorted(known - set(_OWN_FEATURE_OPTIONS))} (levels, neighbourhood, "
                "forgetting, channel_axis and seed are segment's own options).")
    check_channel_axis(channel_axis)

    # the shape: the features' if given, else the image's
    if features is not None:
        shape = np.shape(features)
        if len(shape) != 3 or 0 in shape:
            raise ValueError(f"features must be a non-empty (H, W, D) array; got shape "
                             f"{shape}.")
        shape = shape[:2]
    elif image is None:
        raise TypeError("image is None: pass a 2-D grey or 3-D multichannel array "
                        "(or features).")
    else:
        grey = np.ndim(image) == 2 or channel_axis is None
        shape = channel_last_shape(image, channel_axis=None if grey else channel_axis)[:2]
    h, w = shape
    rows, cols = _block_grid(h, w, o["n_init"])
    if rows > h or cols > w:
        fits = (n for n in range(min(o["n_init"], h * w), 1, -1)
                if _block_grid(h, w, n)[0] <= h and _block_grid(h, w, n)[1] <= w)
        most = next(fits, None)
        allowed = "the image is too small" if most is None else f"use at most {most}"
        raise ValueError(f"n_init ({o['n_init']}) is too large for a {h}x{w} image: its "
                         f"regular division needs {rows}x{cols} blocks; {allowed}.")
    if mask is not None:
        mask = check_mask(mask, "mask", meaning="True where the image is segmented")
        if mask.shape != (h, w):
            raise ValueError(f"mask must be (H, W) like the image, {h}x{w}; got shape "
                             f"{mask.shape}.")
        mask = mask.astype(bool)
        if not mask.any():
            raise ValueError("mask must select at least one pixel; it is all False.")
    return o, (h, w), mask


_SEGMENT_PARAMETERS = """
image : (H, W) or (H, W, C) array_like
    The image, any numeric dtype. A grey image is modelled as it is
    (d = 1) unless ``grey='pseudo_colour'``.
n_segments : int or None, optional
    Labels with this many segments (at most ``n_init``); None finds the
    number automatically (``merge_threshold``).
levels : int, optional
    Resolutions of the features (each halves the image).
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the local models: an order or explicit
    offsets (causal neighbourhoods, docs/model.md).
forgetting : float, optional
    Forgetting factor of the adaptive models, in [0.5, 1] (0.98: an effective
    window of about 50 pixels along each scan; 0.97-0.98 was best on the
    TUNING mosaics, docs/segmentation.md).
n_init : int, optional
    ``K_ini``: components of the initial regular block division, 2 to 64
    (and no more blocks a side than the image has pixels).
smoothing : float, optional
    Width (pixels) of the neighbourhood weighting in the labelling, 0 to 32.
threshold : float, optional
    Pixels whose neighbourhood-weighted posterior is below this are 0;
    in [0, 1).
min_area : int, optional
    Blobs smaller than this (pixels) join their neighbour (default:
    1/2000 of the image, at least 16 pixels).
merge_threshold : float or None, optional
    Automatic stop: the largest loss of mean log-likelihood per pixel (nats)
    a merge may cost. None: 0.06 per feature dimension (1.08 for the 18
    features of a grey image, 1.44 for the 24 of a colour one) and 0.22 of
    the costliest merge of the history, whichever is larger; when the
    costliest merges stand apart (each at least 3.25 times any other merge),
    only they stop it (chosen on the TUNING mosaics, docs/segmentation.md).
region_threshold : float or None, optional
    After the automatic stop, merge its segments while the CAR model fitted
    on all of one segment's pixels predicts another's within this many nats
    per pixel and channel (symmetric; the parts of one texture); the
    history below that state then follows these merges. None: no such
    merging (the default). 0.1, chosen on the TUNING mosaics, raised the
    exact number of segments on REPORT mosaics of 2 and 3 textures from
    43.8 to 50.0 % but merged two textures on 3 of 24 REPORT mosaics of 5
    (docs/segmentation.md). Needs the image and ``n_segments=None``.
grey : {'grey', 'pseudo_colour'}, optional
    How a grey image is segmented: as it is (one channel, d = 1), or as
    the chapter's pseudo-colour ``[Y, Y^0.5, Y^2]`` (d = 3). 'grey'
    separates grey textures better (TUNING mosaics, Brodatz and
    natural-grey seed 1: mean CS 66.0 / ARI 0.708 against 58.3 / 0.640;
    docs/segmentation.md) in about half the feature time.
mask : (H, W) array_like of bool, optional
    Pixels to segment (the mixture is fitted on them; others are 0).
channel_axis : int or None, optional
    Axis of the channels; a 2-D image is grey, None forces grey.
seed : int, optional
    Seed of the random subsamples (PCA, EM sample).
features : (H, W, D) array_like, optional
    Precomputed :func:`local_features` (skips the scans: re-clustering
    with other mixture options is then fast).
feature_options : dict, optional
    Extra keyword options for :func:`local_features` (``smoothing``,
    ``components``, ``decorrelate``, ``centre``, ``clip``, ``energy``...).
var_floor : float, optional
    Floor of every component's variance, in units of the standardised
    features' variance: stops EM from making narrow components that
    split one texture (0.1 lifted ARI from 0.44 to 0.57 on VisTex
    tuning mosaics told K = 5; 0.2 with the automatic stop, chosen with
    it: docs/segmentation.md).
merge_em_steps : int, optional
    EM steps after each KL merge (at most 100).
prior : float, optional
    Strength ``beta`` >= 0 of the Potts prior on the labels: the
    neighbourhood-weighted posteriors become their mean-field marginals
    under it (8-neighbourhood, on the grid of the labelling) before each
    pixel takes the best; 0: no prior (the default: on the Brodatz and
    VisTex tuning mosaics of seed 1, strengths 0.5 to 10 changed at most
    0.12 % of the pixels and no score, at up to 20 % more time).
prior_iterations : int, optional
    Mean-field sweeps of the prior (its reach in pixels of that grid),
    0 to 50.
"""


@shared_sections(parameters=_SEGMENT_PARAMETERS,
                 raises=raises_as("segment", "ValueError"))
def iter_segment(
    image,
    *,
    n_segments=None,
    levels=3,
    neighbourhood=2,
    forgetting=0.98,
    n_init=16,
    smoothing=2.0,
    threshold=0.0,
    min_area=None,
    merge_threshold=None,
    region_threshold=None,
    grey="grey",
    mask=None,
    channel_axis=-1,
    seed=0,
    features=None,
    feature_options=None,
    var_floor=0.2,
    merge_em_steps=3,
    prior=0.0,
    prior_iterations=5,
):
    """Segment a texture image as a job: yield progress and live labels, return the result.

    See :func:`segment` for what is computed.

    {parameters}

    Returns
    -------
    SegmentationResult
        What :func:`segment` returns (the generator's return value).

    Yields
    ------
    Progress
        Stage "features" (the local features), then "mixture" (after the
        initial EM) and "merging" (after every merge); those have the
        message ``"K = n"`` and preview the (H, W) int labels of that mixture.

    {raises}

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import iter_segment
    >>> image = np.random.default_rng(0).random((32, 32))
    >>> [r.message for r in iter_segment(image, levels=1, n_init=4) if r.preview is not None]
    ['K = 4', 'K = 3', 'K = 2', 'K = 1']
    """
    options, _, mask = _check_options(image, features, mask, channel_axis, dict(
        n_segments=n_segments, levels=levels, neighbourhood=neighbourhood,
        forgetting=forgetting, n_init=n_init, smoothing=smoothing, threshold=threshold,
        min_area=min_area, merge_threshold=merge_threshold,
        region_threshold=region_threshold, grey=grey, seed=seed,
        feature_options=feature_options, var_floor=var_floor,
        merge_em_steps=merge_em_steps, prior=prior, prior_iterations=prior_iterations))
    n_segments, n_init, smoothing, threshold, min_area, merge_threshold, var_floor, \
        merge_em_steps, prior, prior_iterations, seed = (options[key] for key in (
            "n_segments", "n_init", "smoothing", "threshold", "min_area", "merge_threshold",
            "var_floor", "merge_em_steps", "prior", "prior_iterations", "seed"))
    arr = np.asarray(image) if image is not None else None
    region_threshold = options["region_threshold"]
    # the region merging reads the image, a band at a time (a view: no copy)
    region_image = (None if region_threshold is None else
                    channel_last_view(image, channel_axis=channel_axis))
    if (arr is not None and arr.ndim == 2 or channel_axis is None) and grey == "pseudo_colour":
        data = as_channel_last_float(image, channel_axis=None)
        check_not_constant(data)
        if features is None:  # given features need no image
            image, channel_axis = pseudo_colour(data[..., 0]), -1
        del data
    if features is None:
        features = yield from stage(iter_local_features(
            image, levels=options["levels"], neighbourhood=neighbourhood,
            forgetting=options["forgetting"], channel_axis=channel_axis, seed=seed,
            **(feature_options or {}),
        ), 0.0, _FEATURES_END)
    else:
        if np.asarray(features).dtype.kind not in "biuf":
            raise TypeError(f"features must be a numeric array; got dtype "
                            f"{np.asarray(features).dtype}.")
        features = np.asarray(features, dtype=np.float32)
        if not np.isfinite(features).all():
            raise ValueError("features has NaN or infinite values (or values beyond "
                             "float32); pass local_features' finite output.")
        yield Progress("features", _FEATURES_END, "features given")
    image = arr = None  # the rest needs the features only (a pseudo-colour copy goes)
    h, w, D = features.shape
    if min_area is None:
        min_area = max(16, (h * w) // 2000)
    relative = 0.0  # the relative stop is the default's only
    if merge_threshold is None:
        merge_threshold, relative = MERGE_NATS_PER_FEATURE * D, MERGE_RELATIVE

    # EM runs on a random sample of the (masked) pixels
    rng = np.random.default_rng(seed)
    if mask is None:
        pick = rng.choice(h * w, size=min(h * w, _EM_SAMPLE), replace=False)
    else:
        idx = np.flatnonzero(mask.ravel())
        pick = rng.choice(idx, size=min(idx.size, _EM_SAMPLE), replace=False)
        del idx
    sample = features[pick // w, pick % w].astype(np.float64)
    del pick

    middle = 0.5 * (_FEATURES_END + _INIT_END)
    mix = yield from stage(_iter_block_init(features, n_init, var_floor),
                           _FEATURES_END, middle, prefix=f"K = {n_init}: ")
    mix = yield from stage(_iter_em(sample, mix, _INIT_EM_STEPS, var_floor),
                           middle, _INIT_END, prefix=f"K = {mix.k}: ")
    k_ini = mix.k
    work = [0.0]  # the merge states' share of the work so far (K + _ABSORB_WORK each)
    total = sum(k + _ABSORB_WORK for k in range(1, k_ini + 1))

    def at(extra=0.0):
        return _INIT_END + (_MERGES_END - _INIT_END) * min(1.0, (work[0] + extra) / total)

    cache = {}  # the last EM's posteriors: the next EM on that mixture starts from them

    def em(mix, steps):
        return (yield from stage(_iter_em(sample, mix, steps, var_floor, cache), at(), at(),
                                 name="merging", prefix=f"K = {mix.k}: "))

    result = SegmentationResult(
        labels=None, n_segments=n_segments, history=[], probability=None,
        features=features, smoothing=smoothing, min_area=min_area, threshold=threshold,
        mask=mask, label_step=2 if min(h, w) >= _LABEL_STEP_SIDE else 1,
        prior=prior, prior_iterations=prior_iterations,
    )
    history = result.history

    def label(mix_i, start, stop, stage_name):
        """Label every pixel by this mixture (in bands, yielding): (labels, probability)."""
        return (yield from stage(result._iter_labelling(mix_i), start, stop, name=stage_name,
                                 prefix=f"K = {mix_i.k}: "))

    def label_state(stage_name):
        """Label the newest state (in bands, yielding); keep its labels, its
        probabilities while it may be the final state; preview it."""
        i = len(history) - 1
        mix_i = history[i]
        share = mix_i.k + _ABSORB_WORK
        labels, prob = yield from label(mix_i, at(), at(share), stage_name)
        if i > 0 and result._final is None and _is_final(history, i - 1, n_segments,
                                                         merge_threshold, relative):
            result._final = i - 1
        result._store(i, labels, prob if result._final is None else None)
        work[0] += share
        yield Progress(stage_name, at(), f"K = {mix_i.k}", labels)

    history.append(mix.copy())
    yield from label_state("mixture")
    while mix.k > 1:
        mix = _drop_weak((yield from em(mix, _PRE_MERGE_EM_STEPS)), 0.01 / k_ini)
        if mix.k == 1:
            break
        mix, _ = _merge_closest(mix)
        mix = yield from em(mix, merge_em_steps)
        history.append(mix.copy())
        yield from label_state("merging")

    if n_segments is None:
        n_segments = _choose_k(history, merge_threshold, relative)
    final = result._index(n_segments)
    if region_image is not None:
        final = yield from _iter_region_merges(result, final, region_image, region_threshold,
                                               em, label, merge_em_steps, at)
    labels, prob = result._cut(final, writable=False), result._probs.get(final)
    result._final = final
    if prob is None:  # not kept (_is_final was wrong, or n_segments missing): label again
        labels, prob = yield from label(history[final], at(), at(), "merging")
        result._store(final, None, prob)  # kept: thresholds on it stay look-ups
    for j in [j for j in result._probs if j != final]:
        del result._probs[j]
    result.labels = result._finish(labels, prob, threshold)
    result.probability = prob
    result.n_segments = int(result.labels.max())
    return result


def _iter_region_merges(result, final, image, limit, em, label, em_steps, at):
    """The region merging of the automatic K (:mod:`._regions`): merge the
    segments of state ``final`` whose region models predict each other
    within ``limit`` nats per pixel and channel. The history below
    ``final`` then follows the region models' order down to one component,
    every state labelled and stored as before (re-cuts stay look-ups).
    Returns the index of the new final state."""
    history = result.history
    labels = result._cut(final, writable=result.mask is not None)
    if result.mask is not None:  # the stored labels cover the whole image
        labels[~result.mask] = 0
    present = np.unique(labels)  # one pass, not one per component
    ids = [int(i) for i in history[final].ids if i in present]
    if len(ids) < 2:
        return final
    order = yield from stage(iter_region_merge_order(image, labels, ids), at(), at(),
                             name="merging", prefix=f"K = {history[final].k}: ")
    accepted = next((n for n, (loss, _, _) in enumerate(order) if loss > limit),
                    len(order))
    if accepted == 0:
        return final
    # the KL history below the state gives way to the region models' merges
    for i in range(final + 1, len(history)):
        result._cuts.pop(i, None)
        result._probs.pop(i, None)
    del history[final + 1:]
    group = {i: i for i in ids}  # a segment's id -> its group's component id
    mix = history[final]
    for n, (_, a, b) in enumerate(order, 1):
        ca, cb = group[a], group[b]
        mix = _merge(mix.copy(), *(int(np.flatnonzero(mix.ids == c)[0]) for c in (ca, cb)))
        mix = yield from em(mix, em_steps)
        kept = ca if ca in mix.ids else cb
        group = {i: kept if g in (ca, cb) else g for i, g in group.items()}
        history.append(mix.copy())
        labels, prob = yield from label(mix, at(), at(), "merging")
        result._store(len(history) - 1, labels, prob if n == accepted else None)
        # no preview: the viewer has shown the merging down to one segment
        yield Progress("merging", at(), f"K = {mix.k}: region merges")
    return final + accepted


def _is_final(history, i, n_segments, merge_threshold, relative=0.0):
    """Whether state ``i`` is likely the one
    :meth:`SegmentationResult.mixture_at` will pick, now that state ``i + 1``
    exists (its probabilities are then kept): automatic K (as
    :func:`_choose_k`), the first state whose merge costs more than
    ``merge_threshold`` and than ``relative`` times the costliest merge so
    far (a later, costlier merge may still move the stop: the state is then
    labelled again); else the last state with at least ``n_segments``
    components."""
    if n_segments is None:
        return _stops(history[:i + 2], i, merge_threshold, relative)
    return history[i + 1].k < min(n_segments, history[0].k)


@shared_parameters(_SEGMENT_PARAMETERS)
def segment(
    image,
    *,
    n_segments=None,
    levels=3,
    neighbourhood=2,
    forgetting=0.98,
    n_init=16,
    smoothing=2.0,
    threshold=0.0,
    min_area=None,
    merge_threshold=None,
    region_threshold=None,
    grey="grey",
    mask=None,
    channel_axis=-1,
    seed=0,
    features=None,
    feature_options=None,
    var_floor=0.2,
    merge_em_steps=3,
    prior=0.0,
    prior_iterations=5,
):
    """Unsupervised texture segmentation of an image.

    Multiresolution local CAR features (:func:`local_features`), a Gaussian
    mixture with diagonal covariances fitted by EM from a regular division
    of the image into ``n_init`` blocks, Kullback-Leibler merging down to
    one component, and the neighbourhood-weighted labelling with
    ``n_segments`` segments (found automatically unless given); section
    14.4, docs/segmentation.md.

    {parameters}

    Returns
    -------
    SegmentationResult
        ``.labels`` (H, W) int, 0 = unclassified; ``.labels_at(k)`` re-cuts
        the merge history for another number of segments.

    Raises
    ------
    ValueError
        If an option is out of range, the image is constant, has NaN or
        infinite values or is too small for ``levels``, or ``mask`` does not
        match the image or selects nothing.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import segment
    >>> image = np.random.default_rng(0).random((32, 32))
    >>> image[:, :16] *= 0.1  # a dark left half
    >>> result = segment(image, levels=1, n_segments=2, n_init=4)
    >>> result.labels.shape
    (32, 32)
    """
    return drain(iter_segment(
        image, n_segments=n_segments, levels=levels, neighbourhood=neighbourhood,
        forgetting=forgetting, n_init=n_init, smoothing=smoothing, threshold=threshold,
        min_area=min_area, merge_threshold=merge_threshold,
        region_threshold=region_threshold, grey=grey, mask=mask,
        channel_axis=channel_axis, seed=seed, features=features,
        feature_options=feature_options, var_floor=var_floor, merge_em_steps=merge_em_steps,
        prior=prior, prior_iterations=prior_iterations,
    ))
