"""Breast tissue: the fibroglandular mask, percent density and tissue class
from the CAR texture segmentation of the breast (section 14.4, issue 35).

The breast is segmented exactly as for the mammogram ROIs
(:func:`~car_napari.mammography.iter_segment_breast`'s pipeline with the
merge history's 8, 10 and 12 segment states and the CAR features kept), so
one segmentation serves both (:func:`analyse_mammogram`). Every segment of
every pooled labelling is described by what the CAR model knows of it (its
local parameters and prediction-error energy against the breast's) and by its
grey level relative to the breast; a logistic model gives the probability
that it is fibroglandular; a pixel's probability is the mean over the pooled
labellings. Boosted trees of each working pixel's descriptors (its grey
level, against its surroundings and the whole breast's, its place and its
CAR features) refine it pixel by pixel (the segments are coarser than the
tissue). The shipped model decides the mask by neither: a small U-Net of
the working crop's grey and place maps (``_unet.py``, run in NumPy; stop
42) won on films it was not tuned on, and with the CAR features as more
input maps it did worse; the segment and pixel models remain for models
without one. The percent
density is the fibroglandular area over the breast area (the pectoral
muscle, removed by :func:`detect_breast`, is not breast);
the tissue class (F fatty, G fatty-glandular, D dense-glandular) comes from
the density, the CAR texture and the grey histogram of the whole breast by
a multinomial logistic model. The models are shipped in ``tissue_model.json`` with their
provenance (``benchmarks/bench_tissue.py --write-model``; the U-Net's weights
in ``tissue_unet.npz``, ``benchmarks/train_tissue_unet.py --write``).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .._docstrings import shared_sections
from .._progress import Progress, drain, stage
from .._validation import check_mask
from ._candidates import _texture_indices, linear_terms
from ._candidates import shipped_model as _roi_model
from ._doc_sections import EXAMPLES_MAMMOGRAM, RAISES_ROIS
from ._images import _block_mean, _iter_grey
from ._rois import (
    DEFAULT_MARKS_PER_IMAGE,
    DEFAULT_POOL_SEGMENTS,
    BreastSegmentation,
    MammogramROIs,
    _band,
    _check_roi_options,
    _iter_breast_stages,
    _iter_rank,
)
from ._trees import TreeEnsemble

__all__ = [
    "IMAGE_DESCRIPTORS",
    "SEGMENT_DESCRIPTORS",
    "TISSUE_CLASSES",
    "MammogramAnalysis",
    "TissueResult",
    "analyse_mammogram",
    "iter_analyse_mammogram",
    "iter_segment_tissue",
    "segment_tissue",
]

# The tissue classes of mini-MIAS: fatty, fatty-glandular, dense-glandular.
TISSUE_CLASSES = ("F", "G", "D")

_LEVELS = 3  # resolutions of the segmentation's CAR features
# A segment's descriptors: its grey level relative to the breast (z score,
# rank among the breast's pixels, spread, and the z score of the grey level
# less the breast's median at the same distance from the skin: the breast
# thins towards the skin), its share of the breast, where it lies (distance
# from the skin and from the chest wall, height off the breast's middle), and
# its mean CAR features (4 principal components of the local parameters and
# the log prediction-error energy per level), each standardised over the
# breast.
GREY_SEGMENT_DESCRIPTORS = ("grey_z", "grey_rank", "grey_spread", "grey_flat")
PLACE_SEGMENT_DESCRIPTORS = ("area", "skin", "chest", "height")
CAR_SEGMENT_DESCRIPTORS = (
    tuple(f"param{k}_z_{m}" for m in range(_LEVELS) for k in range(4))
    + tuple(f"energy_z_{m}" for m in range(_LEVELS))
)
SEGMENT_DESCRIPTORS = GREY_SEGMENT_DESCRIPTORS + PLACE_SEGMENT_DESCRIPTORS + CAR_SEGMENT_DESCRIPTORS
# A working pixel's descriptors: its grey level less the breast's median at
# its distance from the skin, where it lies, the Gaussian means over the
# breast of that grey level at 2, 6 and 18 working pixels (its
# surroundings), its CAR features standardised over the breast, and the
# segment model's smoothed probability.
CONTEXT_SIGMAS = (2, 6, 18)
GREY_PLACE_PIXEL_DESCRIPTORS = (("grey_flat", "skin", "chest", "height")
                                + tuple(f"grey_flat_mean_{s}" for s in CONTEXT_SIGMAS))
# Its grey level against the whole breast's (its rank, z score, distance
# above Otsu's threshold, place between the 10th and 90th percentiles): the
# flattened grey level hides a dense breast, whose median is fibroglandular
# at every distance from the skin; these let the trees read each film's own
# grey scale (stop 41).
BREAST_GREY_PIXEL_DESCRIPTORS = ("grey_breast_rank", "grey_breast_z", "grey_above_otsu",
                                 "grey_in_p10_p90")
PIXEL_DESCRIPTORS = (GREY_PLACE_PIXEL_DESCRIPTORS + CAR_SEGMENT_DESCRIPTORS
                     + BREAST_GREY_PIXEL_DESCRIPTORS + ("segment_probability",))
# The spatial model's input maps (stop 42): the working crop's grey level
# against the breast's, flattened, the pixel's place, its grey level against
# the whole breast's (``grey_breast_z`` twice: the network was trained so),
# and the breast mask; each at half the working resolution.
SPATIAL_CHANNELS = (("grey_breast_z", "grey_flat", "skin", "chest", "height")
                    + BREAST_GREY_PIXEL_DESCRIPTORS + ("breast",))
# A breast's descriptors: the CAR ones (the density and the texture of the
# whole breast: prediction-error energy and parameter spread per level, the
# fibroglandular-fat grey contrast) and the grey-level histogram ones (the
# benchmark's control).
CAR_IMAGE_DESCRIPTORS = (
    ("density", "fg_contrast")
    + tuple(f"energy_mean_{m}" for m in range(_LEVELS))
    + tuple(f"energy_std_{m}" for m in range(_LEVELS))
    + tuple(f"param_std_{m}" for m in range(_LEVELS))
)
HISTOGRAM_DESCRIPTORS = ("grey_mean", "grey_std", "grey_skew", "grey_kurtosis", "grey_p05",
                         "grey_p25", "grey_p50", "grey_p75", "grey_p95", "otsu_fraction")
# The whole breast's density and texture: the pixel model's probability
# (its mean and the breast's fractions above 0.25, 0.5, 0.75) and per
# resolution the quantiles over the breast of the log prediction-error
# energy and of each local parameter, and the energy's mean on the
# fibroglandular mask less that on the fat.
_QUANTILES = (10, 25, 50, 75, 90)
_PARAM_QUANTILES = (10, 50, 90)
_PROBABILITY_STEPS = (0.25, 0.5, 0.75)
DENSITY_DESCRIPTORS = ("probability_mean",) + tuple(
    f"probability_above_{int(100 * t)}" for t in _PROBABILITY_STEPS)
TEXTURE_DESCRIPTORS = (
    tuple(f"energy_q{q}_{m}" for m in range(_LEVELS) for q in _QUANTILES)
    + tuple(f"param{k}_q{q}_{m}" for m in range(_LEVELS) for k in range(4)
            for q in _PARAM_QUANTILES)
    + tuple(f"energy_fg_minus_fat_{m}" for m in range(_LEVELS))
)
# The grey histogram normalised to the breast's fat: the fat reference is the
# mean grey of the breast's darker quarter (film exposure moves it, the
# tissue's contrast above it stays); quantiles of the grey above it and the
# breast's fractions above it by fixed grey steps.
_FAT_STEPS = (0.05, 0.1, 0.15, 0.2, 0.3)
FAT_HISTOGRAM_DESCRIPTORS = (
    ("fat_reference",) + tuple(f"above_fat_q{q}" for q in _QUANTILES)
    + tuple(f"above_fat_{int(100 * t):02d}" for t in _FAT_STEPS)
)
IMAGE_DESCRIPTORS = (CAR_IMAGE_DESCRIPTORS + HISTOGRAM_DESCRIPTORS + DENSITY_DESCRIPTORS
                     + TEXTURE_DESCRIPTORS + FAT_HISTOGRAM_DESCRIPTORS)

_MODEL_FILE = Path(__file__).with_name("tissue_model.json")


@shared_sections(examples=EXAMPLES_MAMMOGRAM)
class TissueResult(NamedTuple):
    """Breast tissue of a mammogram (:func:`segment_tissue`).

    Parameters
    ----------
    fibroglandular : (H, W) ndarray of bool
        True on the fibroglandular (dense) tissue of the breast.
    density : float
        Percent density: the fibroglandular area over the breast area, in
        percent (0-100; the pectoral muscle is not breast).
    tissue_class : str
        'F' (fatty), 'G' (fatty-glandular) or 'D' (dense-glandular), the most
        probable.
    probabilities : dict
        The probability of each class of :data:`TISSUE_CLASSES`.
    breast : (H, W) ndarray of bool
        The breast area the density is over.
    probability : (h, w) ndarray of float32
        Advanced: the fibroglandular probability at the segmentation's working
        resolution (crop ``box`` of the block-averaged mammogram, block
        ``factor``), 0 off the breast.

    {examples}
    >>> from car_napari.mammography import segment_tissue
    >>> tissue = segment_tissue(image, n_init=4)
    >>> tissue.tissue_class in ("F", "G", "D"), 0.0 <= tissue.density <= 100.0
    (True, True)
    """

    fibroglandular: np.ndarray
    density: float
    tissue_class: str
    probabilities: dict
    breast: np.ndarray
    probability: np.ndarray


@shared_sections(examples=EXAMPLES_MAMMOGRAM)
class MammogramAnalysis(NamedTuple):
    """Regions of interest and breast tissue of one mammogram from one
    segmentation (:func:`analyse_mammogram`); unpacks as ``rois, tissue``.

    Parameters
    ----------
    rois : MammogramROIs
        What :func:`detect_mammogram_rois` returns.
    tissue : TissueResult
        What :func:`segment_tissue` returns.

    {examples}
    >>> from car_napari.mammography import analyse_mammogram
    >>> rois, tissue = analyse_mammogram(image, n_init=4, pool=(2, 3))
    >>> rois.labels.shape == tissue.fibroglandular.shape
    True
    """

    rois: MammogramROIs
    tissue: TissueResult


# --- the model ------------------------------------------------------------------


class TissueModel:
    """The shipped segment, pixel and tissue-class models (``tissue_model.json``).

    ``segment``: a logistic model of :data:`SEGMENT_DESCRIPTORS` (``mean``,
    ``scale``, ``coef``, ``intercept``), the ``smoothing`` of the pixel
    probabilities (a Gaussian mean over the breast, its sigma a fraction of
    the working crop's long side) and the probability ``threshold`` of a
    fibroglandular pixel; ``pixel`` (optional; when present it makes the
    mask): gradient-boosted trees of the working pixels' ``descriptors``
    (of :data:`PIXEL_DESCRIPTORS`; ``baseline`` and ``trees`` as
    :class:`TreeEnsemble` reads them), with its own ``smoothing`` and
    ``threshold``; ``tissue``: the class model of the breast's descriptors
    (:class:`ClassModel`).
    """

    def __init__(self, spec):
        self.spec = spec
        seg = spec["segment"]
        if tuple(seg["descriptors"]) != SEGMENT_DESCRIPTORS:
            raise ValueError("tissue model: its segment descriptors are not this code's.")
        self.seg_mean, self.seg_scale, self.seg_coef, self.seg_intercept = linear_terms(seg)
        self.threshold = float(seg.get("threshold", 0.5))
        self.smoothing = float(seg.get("smoothing", 0.0))
        pix = spec.get("pixel")
        self.pixel = None if pix is None else PixelModel(pix)
        if self.pixel is not None:  # the mask is the pixel model's
            self.threshold = self.pixel.threshold
        spatial = spec.get("spatial")
        self.spatial = None if spatial is None else SpatialModel(spatial)
        if self.spatial is not None:  # unless there is a spatial model
            self.threshold = self.spatial.threshold
        self.tissue = ClassModel(spec["tissue"])

    def segment_probability(self, X):
        """Fibroglandular probability of segment descriptor rows ``X``."""
        z = (np.asarray(X, float) - self.seg_mean) / self.seg_scale
        return 1.0 / (1.0 + np.exp(-(z @ self.seg_coef + self.seg_intercept)))

    def class_probabilities(self, x):
        """{class: probability} of one breast's descriptor row ``x``
        (:data:`IMAGE_DESCRIPTORS`)."""
        p = self.tissue.probabilities(np.asarray(x, float)[None])[0]
        return {c: float(v) for c, v in zip(TISSUE_CLASSES, p, strict=True)}


class ClassModel:
    """The tissue class of a breast from its ``descriptors`` (names of
    :data:`IMAGE_DESCRIPTORS`; the ``tissue`` part of :class:`TissueModel`'s
    spec).

    ``kind`` "multinomial" (the default): a multinomial logistic model with
    ``classes``, ``mean``, ``scale``, ``coef`` (classes x descriptors) and
    ``intercept``. ``kind`` "ordinal" (F < G < D): two binary ``steps``, the
    probability of a class above F and of one above G, each a logistic model
    (``mean``, ``scale``, ``coef``, ``intercept``) or boosted trees
    (``baseline``, ``trees`` as :class:`TreeEnsemble` reads them); the class
    probabilities are their differences (a negative one, where the two
    disagree, counts 0; then all are rescaled to sum to 1).
    """

    def __init__(self, spec):
        self.spec = spec
        self.columns = _descriptor_columns(spec["descriptors"], IMAGE_DESCRIPTORS, "descriptors")
        self.kind = spec.get("kind", "multinomial")
        if self.kind == "multinomial":
            classes = list(spec["classes"])
            self.order = [classes.index(c) for c in TISSUE_CLASSES]
            self.linear = linear_terms(spec)
        elif self.kind == "ordinal":
            self.steps = [_binary_step(step) for step in spec["steps"]]
        else:
            raise ValueError(f"tissue model of unknown kind {self.kind!r}.")

    def probabilities(self, X):
        """(n, 3) probabilities of :data:`TISSUE_CLASSES` of descriptor rows
        ``X`` (n, len(IMAGE_DESCRIPTORS))."""
        X = np.asarray(X, float)[:, self.columns]
        if self.kind == "multinomial":
            mean, scale, coef, intercept = self.linear
            raw = ((X - mean) / scale) @ coef.T + intercept
            p = np.exp(raw - raw.max(axis=1, keepdims=True))
            return (p / p.sum(axis=1, keepdims=True))[:, self.order]
        above_f, above_g = (step(X) for step in self.steps)
        p = np.column_stack([1.0 - above_f, np.maximum(above_f - above_g, 0.0), above_g])
        return p / p.sum(axis=1, keepdims=True)


def _descriptor_columns(names, known, what):
    """The columns of the descriptors ``names`` among ``known``; a
    ValueError naming the unknown ones (``what`` they are)."""
    unknown = set(names) - set(known)
    if unknown:
        raise ValueError(f"tissue model uses unknown {what} {sorted(unknown)}.")
    return [known.index(n) for n in names]


def _binary_step(spec):
    """The probability function of one binary step of an ordinal class
    model: logistic (``coef``) or boosted trees (``trees``)."""
    if "trees" in spec:
        trees = TreeEnsemble(spec["baseline"], spec["trees"])
        return lambda X: 1.0 / (1.0 + np.exp(-trees.log_odds(X)))
    mean, scale, coef, intercept = linear_terms(spec)
    return lambda X: 1.0 / (1.0 + np.exp(-(((X - mean) / scale) @ coef + intercept)))


class PixelModel:
    """Fibroglandular probability of working pixels by boosted trees of a
    subset of :data:`PIXEL_DESCRIPTORS` (the ``pixel`` part of
    :class:`TissueModel`'s spec)."""

    def __init__(self, spec):
        self.spec = spec
        self.columns = _descriptor_columns(spec["descriptors"], PIXEL_DESCRIPTORS,
                                           "pixel descriptors")
        self.trees = TreeEnsemble(spec["baseline"], spec["trees"])
        self.threshold = float(spec["threshold"])
        self.smoothing = float(spec.get("smoothing", 0.0))

    def probability(self, X):
        """Fibroglandular probability of pixel descriptor rows ``X`` (n,
        len(PIXEL_DESCRIPTORS))."""
        raw = self.trees.log_odds(np.asarray(X)[:, self.columns])
        return 1.0 / (1.0 + np.exp(-raw))


class SpatialModel:
    """Fibroglandular probability of a whole working crop by a small U-Net
    of its :data:`SPATIAL_CHANNELS` (the ``spatial`` part of
    :class:`TissueModel`'s spec: the ``weights`` file beside the model file,
    the ``channels``, the ``threshold``)."""

    def __init__(self, spec, folder=None):
        self.spec = spec
        if tuple(spec["channels"]) != SPATIAL_CHANNELS:
            raise ValueError("tissue model: its spatial channels are not this code's.")
        self.threshold = float(spec["threshold"])
        path = Path(folder or _MODEL_FILE.parent) / spec["weights"]
        with np.load(path) as weights:
            self.weights = {k: weights[k].astype(np.float32) for k in weights.files}

    def probability(self, work, places=None):
        """The fibroglandular probability (h, w) of the working crop ``work``
        (0 off the breast); ``places``: its breast's :func:`_places`, when
        already computed."""
        from ._unet import bilinear2, unet_logits

        b = work.breast
        h, w = b.shape
        logits = unet_logits(_spatial_input(work, places), self.weights)
        p = bilinear2(1.0 / (1.0 + np.exp(-logits)))[:h, :w]
        p[~b] = 0.0
        return p


# The network was trained on crops padded with zeros to 240x128 (at least 8
# rows and 24 columns of zeros): its border pixels expect zeros beyond.
_SPATIAL_MARGIN = 16


def _spatial_input(work, places=None):
    """The U-Net's input: :data:`SPATIAL_CHANNELS` of the working crop, each
    the mean of 2x2 blocks (an odd side padded with zeros), then padded with
    zeros at the bottom and right by at least :data:`_SPATIAL_MARGIN`, to
    multiples of 8: (C, H, W) float32."""
    from ._unet import MULTIPLE

    b = work.breast
    g = work.grey[b]
    places = _places(b) if places is None else places
    columns = [(g - g.mean()) / max(float(g.std()), 1e-6), _flattened(g, places[0]),
               *places, *_breast_grey(g)]
    h, w = b.shape
    maps = np.zeros((len(columns) + 1, h + h % 2, w + w % 2), np.float32)
    for k, values in enumerate(columns):
        maps[k, :h, :w][b] = values
    maps[-1, :h, :w] = b
    c, h2, w2 = maps.shape
    half = maps.reshape(c, h2 // 2, 2, w2 // 2, 2).mean(axis=(2, 4))
    side = [-(-(n // 2 + _SPATIAL_MARGIN) // MULTIPLE) * MULTIPLE for n in (h2, w2)]
    out = np.zeros((c, *side), np.float32)
    out[:, : h2 // 2, : w2 // 2] = half
    return out


@lru_cache(maxsize=1)
def shipped_tissue_model():
    """The :class:`TissueModel` shipped with the package (``tissue_model.json``)."""
    with open(_MODEL_FILE) as fh:
        return TissueModel(json.load(fh))


# --- descriptors ----------------------------------------------------------------


class _Working(NamedTuple):
    """A segmentation on its working-resolution crop: grey (h, w), the pooled
    labellings (P, h, w), the breast (h, w), CAR features (h, w, D)."""

    grey: np.ndarray
    labellings: np.ndarray
    breast: np.ndarray
    features: np.ndarray


def _working(grey, segmentation):
    """The working-resolution view of a full-resolution segmentation: each
    working pixel reads the full-resolution labels at its block's centre."""
    H, W = grey.shape
    f = segmentation.factor
    r0, r1, c0, c1 = segmentation.box
    feats = segmentation.features
    h, w = feats.shape[:2]
    small = _block_mean(grey, f)[r0 : r0 + h, c0 : c0 + w]
    rows = np.minimum((r0 + np.arange(h)) * f + f // 2, H - 1)
    cols = np.minimum((c0 + np.arange(w)) * f + f // 2, W - 1)
    labs = segmentation.pooled or [segmentation.segments]
    labs = np.array([s[np.ix_(rows, cols)] for s in labs], np.int32)
    return _Working(small, labs, labs[0] > 0, feats)


def _standardised(features, breast):
    """The CAR parameter and energy features (h, w, 4L + L), standardised
    over the breast, and their raw breast values (n, 4L + L)."""
    params, energy = _texture_indices(features.shape[2])
    cols = params[: 4 * _LEVELS] + energy[:_LEVELS]
    vals = features[breast][:, cols].astype(np.float64)
    mu, sd = vals.mean(axis=0), vals.std(axis=0)
    sd[sd <= 0] = 1.0
    return (vals - mu) / sd, vals


def _places(breast):
    """Per breast pixel: distance from the skin over its largest (the chest
    wall, the image's edge on the breast's straight side, is not skin),
    distance from the chest wall over the breast's width, and height off
    the breast's middle row over its half height (absolute)."""
    from scipy import ndimage

    from ._breast import chest_wall_side

    h, w = breast.shape
    left = chest_wall_side(breast) == "left"
    grown = np.pad(breast, ((1, 1), (w, 0) if left else (0, w)), mode="edge")
    grown[0] = grown[-1] = False
    d = ndimage.distance_transform_edt(grown)[1:-1, w:] if left else \
        ndimage.distance_transform_edt(grown)[1:-1, :w]
    skin = d[breast] / max(float(d[breast].max()), 1.0)
    rr, cc = np.nonzero(breast)
    c0, c1 = cc.min(), cc.max() + 1
    chest = ((cc - c0) if left else (c1 - 1 - cc)) / max(c1 - c0, 1)
    r0, r1 = rr.min(), rr.max() + 1
    height = np.abs(rr - (r0 + r1 - 1) / 2) / max((r1 - r0) / 2, 1.0)
    return skin, chest, height


def _flattened(g, skin, bins=16):
    """Grey levels ``g`` less the median of those at the same distance from
    the skin (``bins`` quantile bands), over the breast's grey spread."""
    edges = np.quantile(skin, np.linspace(0, 1, bins + 1)[1:-1])
    band = np.searchsorted(edges, skin)
    med = np.array([np.median(g[band == k]) if np.any(band == k) else 0.0
                    for k in range(bins)])
    return (g - med[band]) / max(float(g.std()), 1e-6)


def _segment_rows(work, z, places):
    """Descriptor rows (:data:`SEGMENT_DESCRIPTORS`) of every segment of
    every labelling: a list of (labels present, rows) per labelling."""
    b = work.breast
    g = work.grey[b]
    gm, gs = float(g.mean()), max(float(g.std()), 1e-6)
    flat = _flattened(g, places[0])
    per_pixel = [flat, *places, *z.T]
    order = np.sort(g)
    n = float(g.size)
    out = []
    for lab in work.labellings:
        s = lab[b]
        k = int(s.max()) + 1
        cnt = np.bincount(s, minlength=k).astype(float)
        present = np.flatnonzero(cnt)
        present = present[present > 0]
        c = cnt[present]
        mean = np.bincount(s, g, k)[present] / c
        var = np.bincount(s, g * g, k)[present] / c - mean**2
        cols = [(mean - gm) / gs, np.searchsorted(order, mean) / n,
                np.sqrt(np.maximum(var, 0.0)) / gs]
        means = [np.bincount(s, v, k)[present] / c for v in per_pixel]
        cols += [means[0], c / n, *means[1:]]
        out.append((present, np.column_stack(cols)))
    return out


def _probability(work, segment_rows, model):
    """Fibroglandular probability (h, w) of the working crop: the mean over
    the labellings of each pixel's segment's probability."""
    b = work.breast
    acc = np.zeros(int(b.sum()))
    for lab, (present, rows) in zip(work.labellings, segment_rows, strict=True):
        table = np.zeros(int(lab.max()) + 1)
        table[present] = model.segment_probability(rows)
        acc += table[lab[b]]
    return _breast_mean(acc / len(segment_rows), b, model.smoothing * max(b.shape))


def _breast_mean(values, breast, sigma):
    """The breast pixels' ``values`` as an (h, w) float32 map, 0 off the
    breast, their Gaussian mean over the breast only when ``sigma`` > 0."""
    out = np.zeros(breast.shape, np.float32)
    out[breast] = values
    if sigma > 0:
        from scipy import ndimage

        weight = ndimage.gaussian_filter(breast.astype(np.float32), sigma)
        out = ndimage.gaussian_filter(out, sigma) / np.maximum(weight, 1e-6)
        out[~breast] = 0.0
    return out


def _pixel_rows(work, z, places, segment_probability):
    """Descriptor rows (:data:`PIXEL_DESCRIPTORS`, float32) of the breast's
    working pixels; ``segment_probability``: the segment model's (h, w) map."""
    b = work.breast
    flat = _flattened(work.grey[b], places[0])
    context = [_breast_mean(flat, b, s)[b] for s in CONTEXT_SIGMAS]
    return np.column_stack([flat, *places, *context, z, *_breast_grey(work.grey[b]),
                            segment_probability[b]]).astype(np.float32)


def _breast_grey(g):
    """:data:`BREAST_GREY_PIXEL_DESCRIPTORS` of the breast's grey levels ``g``
    (n,): four (n,) float64 columns."""
    g = np.asarray(g, np.float64)
    sd = max(float(g.std()), 1e-6)
    p10, p90 = np.percentile(g, [10, 90])
    rank = np.searchsorted(np.sort(g), g) / g.size  # the share of the breast darker
    return [rank, (g - g.mean()) / sd, (g - _otsu(g)) / sd, (g - p10) / max(p90 - p10, 1e-6)]


def _pixel_probability(work, z, places, segment_probability, pixel):
    """The pixel model's smoothed fibroglandular probability (h, w)."""
    b = work.breast
    p = pixel.probability(_pixel_rows(work, z, places, segment_probability))
    return _breast_mean(p, b, pixel.smoothing * max(b.shape))


def _histogram_row(g):
    """:data:`HISTOGRAM_DESCRIPTORS` of the breast's grey levels ``g``."""
    mean, std = float(g.mean()), float(g.std())
    d = (g - mean) / max(std, 1e-6)
    p = np.percentile(g, [5, 25, 50, 75, 95])
    return [mean, std, float(np.mean(d**3)), float(np.mean(d**4)), *map(float, p),
            float(np.mean(g > _otsu(g)))]


def _otsu(g):
    """Otsu's threshold of the values ``g`` (256 bins)."""
    from skimage.filters import threshold_otsu

    return float(threshold_otsu(g, nbins=256)) if g.max() > g.min() else float(g.max())


def _image_row(work, vals, prob, threshold, needed=None):
    """:data:`IMAGE_DESCRIPTORS` of a breast from its working view, the raw
    breast features ``vals`` and the fibroglandular probability map ``prob``
    on the crop (the mask is where it exceeds ``threshold``): the first
    ``needed`` of them at least (a class model reading only the first ones
    need not pay for the whole-breast quantiles)."""
    b = work.breast
    g = work.grey[b]
    p = prob[b]
    f = p > threshold
    gs = max(float(g.std()), 1e-6)
    has_both = 0 < f.sum() < f.size
    contrast = (float(g[f].mean() - g[~f].mean()) / gs) if has_both else 0.0
    energy = vals[:, 4 * _LEVELS :]
    params = vals[:, : 4 * _LEVELS].reshape(len(vals), _LEVELS, 4)
    row = [float(f.mean()), contrast, *energy.mean(axis=0), *energy.std(axis=0),
           *np.sqrt((params.var(axis=0)).sum(axis=1))]
    row += _histogram_row(g)
    if needed is not None and len(row) >= needed:
        return np.array(row, float)
    row += [float(p.mean()), *(float(np.mean(p > t)) for t in _PROBABILITY_STEPS)]
    row += [*np.percentile(energy, _QUANTILES, axis=0).T.ravel()]
    row += [*np.percentile(params, _PARAM_QUANTILES, axis=0).transpose(1, 2, 0).ravel()]
    row += [*(energy[f].mean(axis=0) - energy[~f].mean(axis=0) if has_both
              else np.zeros(_LEVELS))]
    fat = float(g[g <= np.percentile(g, 25)].mean())
    row += [fat, *np.percentile(g - fat, _QUANTILES),
            *(float(np.mean(g - fat > t)) for t in _FAT_STEPS)]
    return np.array(row, float)


def _describe_breast(grey, segmentation, model):
    """Everything the tissue models see of one segmented breast:
    (working view, probability map, image row)."""
    work = _working(grey, segmentation)
    if not work.breast.any():
        raise ValueError("the segmentation has no breast pixel at its working resolution.")
    z, vals = _standardised(work.features, work.breast)
    places = _places(work.breast)
    if model.spatial is not None:  # the segment rows are not read
        prob = model.spatial.probability(work, places)
    else:
        prob = _probability(work, _segment_rows(work, z, places), model)
        if model.pixel is not None:
            prob = _pixel_probability(work, z, places, prob, model.pixel)
    needed = max(model.tissue.columns) + 1
    return work, prob, _image_row(work, vals, prob, model.threshold, needed)


def _full_mask(small, segmentation, shape):
    """A working-crop mask block-upsampled into the mammogram, on the breast."""
    H, W = shape
    f = segmentation.factor
    r0, _, c0, _ = segmentation.box
    R0, C0 = r0 * f, c0 * f
    big = np.repeat(np.repeat(small, f, axis=0), f, axis=1)[: H - R0, : W - C0]
    out = np.zeros((H, W), bool)
    out[R0 : R0 + big.shape[0], C0 : C0 + big.shape[1]] = big
    # the pixels of a side not divisible by f (cut off by the block mean)
    # take the last working block's value
    r_end, c_end = R0 + big.shape[0], C0 + big.shape[1]
    if r_end < H and big.shape[0]:
        out[r_end : r_end + f, C0:c_end] = big[-1]
    if c_end < W and big.shape[1]:
        out[R0 : r_end + f, c_end : c_end + f] = out[R0 : r_end + f, c_end - 1 : c_end]
    return out & segmentation.breast


def _tissue_of(grey, segmentation, model):
    """:class:`TissueResult` of a segmented breast."""
    work, prob, row = _describe_breast(grey, segmentation, model)
    fg = _full_mask(prob > model.threshold, segmentation, grey.shape)
    breast = segmentation.breast
    density = 100.0 * float(fg.sum()) / float(breast.sum())
    row = row.copy()
    row[0] = density / 100.0  # the density at full resolution
    probs = model.class_probabilities(row)
    best = max(TISSUE_CLASSES, key=probs.get)
    return TissueResult(fg, density, best, probs, breast.copy(), prob)


def _check_segmentation(segmentation, shape):
    if not isinstance(segmentation, BreastSegmentation):
        raise TypeError(f"segmentation must be a BreastSegmentation (segment_breast(..., "
                        f"keep_features=True)); got {type(segmentation).__name__}.")
    if segmentation.features is None or segmentation.box is None:
        raise ValueError("segmentation has no CAR features: make it with "
                         "segment_breast(..., keep_features=True).")
    if segmentation.segments.shape != tuple(shape):
        raise ValueError(f"segmentation is of a {segmentation.segments.shape} image; the "
                         f"mammogram is {tuple(shape)}.")
    if segmentation.features.shape[-1] < 8 * _LEVELS:
        raise ValueError(f"segmentation has CAR features of fewer than {_LEVELS} resolutions; "
                         f"the tissue model needs {_LEVELS} (segment_breast(..., levels="
                         f"{_LEVELS}, keep_features=True)).")


# the breast segmentation's options, shared by the tissue and combined jobs
_SEGMENTATION_PARAMETERS = """levels : int, optional
    Resolutions of the segmentation's features (at least 3: the tissue
    model's).
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the segmentation's local models.
n_init : int, optional
    Components of the segmentation's initial block division.
work_side : int, optional
    Working resolution of the segmentation (long side, pixels). The tissue
    models were fitted at the default, 512: at another the U-Net sees its
    textures at another scale.
seed : int, optional
    Seed of the segmentation's random subsamples.
"""

_TISSUE_PARAMETERS = """
Parameters
----------
image : (H, W) array_like
    Grey mammogram (bright = dense), any numeric dtype (integer images are
    scaled by their range; a uint16 image whose maximum is at most 4,095 is
    12-bit); an RGB(A) export of one, with ``channel_axis``, is reduced to
    its luminance.
breast : (H, W) array_like of bool, optional
    The breast mask (pectoral muscle excluded); default :func:`detect_breast`.
""" + _SEGMENTATION_PARAMETERS + """pool : sequence of int, optional
    Numbers of segments read from the merge history; each labelling's
    segments are classified and a pixel's probability is their mean.
segmentation : BreastSegmentation, optional
    A segmentation of this mammogram with its CAR features
    (``segment_breast(image, keep_features=True)``, the same ``pool``):
    used instead of segmenting again (``breast`` and the segmentation
    options are then ignored).
channel_axis : int or None, optional
    The colour axis of an RGB(A) export; a 2-D image is grey, None forces
    grey.
"""


def _check_tissue_options(levels, work_side, seed, pool):
    from ._rois import _check_segment_options

    _check_segment_options(levels, work_side, seed, pool)
    if levels < _LEVELS:
        raise ValueError(f"levels must be at least {_LEVELS} for the tissue model (fitted on "
                         f"{_LEVELS} resolutions of CAR features); got {levels}.")


@shared_sections(parameters=_TISSUE_PARAMETERS, examples=EXAMPLES_MAMMOGRAM)
def iter_segment_tissue(image, *, breast=None, levels=3, neighbourhood=2, n_init=16,
                        work_side=512, seed=0, pool=DEFAULT_POOL_SEGMENTS, segmentation=None,
                        channel_axis=-1):
    """Fibroglandular tissue, percent density and tissue class, as a job.

    See :func:`segment_tissue` for the method.

    {parameters}

    Returns
    -------
    TissueResult
        What :func:`segment_tissue` returns (the generator's return value).

    Yields
    ------
    Progress
        The breast segmentation's records (:func:`iter_segment_breast`;
        none with ``segmentation``), then stage "tissue".

    Raises
    ------
    ValueError, TypeError
        As :func:`segment_tissue`, before any work.

    {examples}
    >>> from car_napari.mammography import iter_segment_tissue
    >>> records = list(iter_segment_tissue(image, n_init=4))
    >>> records[0].stage, records[-1].stage, records[-1].fraction
    ('breast', 'tissue', 1.0)
    """
    _check_tissue_options(levels, work_side, seed, pool)
    if breast is not None:
        breast = check_mask(breast, "breast", meaning="True on the breast")
    model = shipped_tissue_model()
    if segmentation is not None:
        if not isinstance(segmentation, BreastSegmentation):
            _check_segmentation(segmentation, ())
        grey = yield from stage(_iter_grey(image, channel_axis), 0.0, 0.5)
        _check_segmentation(segmentation, grey.shape)
        t0 = 0.5
    else:
        grey, segmentation, (t0, _) = yield from _iter_breast_stages(
            image, breast=breast, n_segments=None, levels=levels, neighbourhood=neighbourhood,
            n_init=n_init, work_side=work_side, seed=seed, pool=pool or None,
            channel_axis=channel_axis)
    yield Progress("tissue", t0, "fibroglandular segments")
    tissue = _tissue_of(grey, segmentation, model)
    yield Progress("tissue", 1.0, f"density {tissue.density:.0f} %, class {tissue.tissue_class}")
    return tissue


@shared_sections(parameters=_TISSUE_PARAMETERS, examples=EXAMPLES_MAMMOGRAM)
def segment_tissue(image, *, breast=None, levels=3, neighbourhood=2, n_init=16, work_side=512,
                   seed=0, pool=DEFAULT_POOL_SEGMENTS, segmentation=None, channel_axis=-1):
    """Fibroglandular tissue, percent density and tissue class of a mammogram.

    1. The breast (pectoral muscle excluded) is found and segmented by its CAR
       texture exactly as for :func:`detect_mammogram_rois` (the merge
       history's states with ``pool`` segments, the CAR features kept).
    2. Every segment of every pooled labelling is described by its mean CAR
       features (local parameters and log prediction-error energy per
       resolution, each standardised over the breast), its grey level
       relative to the breast (z score, rank, spread), its share of the
       breast and how deep in it it lies; the shipped logistic model
       (``tissue_model.json``, fitted on the DDSM films with pixel labels of
       Tiryaki and Kaplanoglu) gives its fibroglandular probability; a
       pixel's is the mean over the labellings.
    3. The shipped boosted trees (fitted on the same films) give each
       working pixel's fibroglandular probability from its grey level less
       the breast's median at its distance from the skin, its place, that
       grey level's Gaussian means over the breast around it, its grey level
       against the whole breast's (rank, z score, above Otsu's threshold,
       between the 10th and 90th percentiles) and its CAR features; smoothed
       over the breast, the mask is where it exceeds the model's threshold.
    4. Percent density: the mask's area over the breast's, in percent.
    5. Tissue class: a multinomial logistic model (fitted on mini-MIAS) of
       the density and the whole breast's CAR texture (prediction-error
       energy and parameter spread per resolution, the fibroglandular-fat
       grey contrast) and grey histogram.

    The cross-validated accuracy of each step is in the model file and
    ``benchmarks/bench_tissue.py``. A research tool, never a diagnostic aid.

    {parameters}

    Returns
    -------
    TissueResult
        ``fibroglandular`` (H, W) bool, ``density`` (percent),
        ``tissue_class`` ('F', 'G' or 'D'), ``probabilities`` ({class:
        probability}), ``breast`` (H, W) bool and the working-resolution
        ``probability`` map.

    Raises
    ------
    ValueError
        If the image is constant or has no breast, ``breast`` does not match
        it, an option is out of range or ``segmentation`` is not of this
        image.
    TypeError
        If ``segmentation`` is not a BreastSegmentation.

    {examples}
    >>> from car_napari.mammography import segment_tissue
    >>> tissue = segment_tissue(image, n_init=4)
    >>> tissue.fibroglandular.shape, bool((tissue.fibroglandular & ~tissue.breast).any())
    ((64, 64), False)
    """
    return drain(iter_segment_tissue(
        image, breast=breast, levels=levels, neighbourhood=neighbourhood, n_init=n_init,
        work_side=work_side, seed=seed, pool=pool, segmentation=segmentation,
        channel_axis=channel_axis))


_ANALYSE_PARAMETERS = """
Parameters
----------
image : (H, W) array_like
    Grey mammogram, as for :func:`detect_mammogram_rois`.
marks_per_image : float or None, optional
    The ROI operating point (false marks per image), as for
    :func:`detect_mammogram_rois`; None keeps every finding.
max_regions : int or None, optional
    Advanced: at most this many regions, best first.
reference : float, optional
    Advanced: the chapter's grey-level filter's reference, with
    ``tolerance`` (as for :func:`detect_mammogram_rois`).
tolerance : float or None, optional
    Advanced: the width of that filter; None turns it off.
breast : (H, W) array_like of bool, optional
    The breast mask; default :func:`detect_breast`.
""" + _SEGMENTATION_PARAMETERS + """pool : sequence of int, optional
    Numbers of segments read from the merge history (both analyses use them).
channel_axis : int or None, optional
    The colour axis of an RGB(A) export; a 2-D image is grey, None forces
    grey.
"""


@shared_sections(parameters=_ANALYSE_PARAMETERS, examples=EXAMPLES_MAMMOGRAM)
def iter_analyse_mammogram(image, *, marks_per_image=DEFAULT_MARKS_PER_IMAGE, max_regions=None,
                           reference=None, tolerance=None, breast=None, levels=3,
                           neighbourhood=2, n_init=16, work_side=512, seed=0,
                           pool=DEFAULT_POOL_SEGMENTS, channel_axis=-1):
    """Regions of interest and breast tissue from one segmentation, as a job.

    See :func:`analyse_mammogram`.

    {parameters}

    Returns
    -------
    MammogramAnalysis
        What :func:`analyse_mammogram` returns (the generator's return value).

    Yields
    ------
    Progress
        The breast segmentation's records (:func:`iter_segment_breast`), then
        stage "regions" (:func:`iter_detect_mammogram_rois`'s), then "tissue".

    Raises
    ------
    ValueError
        As :func:`analyse_mammogram`, before any work.

    {examples}
    >>> from car_napari.mammography import iter_analyse_mammogram
    >>> records = list(iter_analyse_mammogram(image, n_init=4, pool=(2, 3)))
    >>> records[-1].stage, records[-1].fraction
    ('tissue', 1.0)
    """
    _check_roi_options(marks_per_image, reference, tolerance, max_regions, None)
    _check_tissue_options(levels, work_side, seed, pool)
    if breast is not None:
        breast = check_mask(breast, "breast", meaning="True on the breast")
    roi_model, model = _roi_model(), shipped_tissue_model()
    grey, segmentation, (r0, r1) = yield from _iter_breast_stages(
        image, breast=breast, n_segments=None, levels=levels, neighbourhood=neighbourhood,
        n_init=n_init, work_side=work_side, seed=seed, pool=pool or None,
        channel_axis=channel_axis)
    mid = r0 + 0.8 * (r1 - r0)
    yield Progress("regions", r0, "candidate regions")
    threshold = None if marks_per_image is None else roi_model.threshold(marks_per_image)
    rois = yield from stage(
        _iter_rank(grey, segmentation, roi_model, threshold=threshold, max_regions=max_regions,
                   min_area=None, split=True, band=_band(reference, tolerance)), r0, mid)
    yield Progress("tissue", mid, "fibroglandular segments")
    tissue = _tissue_of(grey, segmentation, model)
    yield Progress("tissue", 1.0, f"density {tissue.density:.0f} %, class {tissue.tissue_class}")
    return MammogramAnalysis(rois, tissue)


@shared_sections(parameters=_ANALYSE_PARAMETERS, raises=RAISES_ROIS,
                 examples=EXAMPLES_MAMMOGRAM)
def analyse_mammogram(image, *, marks_per_image=DEFAULT_MARKS_PER_IMAGE, max_regions=None,
                      reference=None, tolerance=None, breast=None, levels=3, neighbourhood=2,
                      n_init=16, work_side=512, seed=0, pool=DEFAULT_POOL_SEGMENTS,
                      channel_axis=-1):
    """Regions of interest and breast tissue of a mammogram from one segmentation.

    The breast is segmented once; its regions of interest are those of
    :func:`detect_mammogram_rois` and its tissue that of
    :func:`segment_tissue` with the same options (the same results as the
    two calls, in about the time of one).

    {parameters}

    Returns
    -------
    MammogramAnalysis
        ``rois`` (:class:`MammogramROIs`) and ``tissue``
        (:class:`TissueResult`); unpacks as ``rois, tissue``.

    {raises}

    {examples}
    >>> from car_napari.mammography import analyse_mammogram
    >>> rois, tissue = analyse_mammogram(image, n_init=4, pool=(2, 3))
    >>> tissue.tissue_class in ("F", "G", "D")
    True
    """
    return drain(iter_analyse_mammogram(
        image, marks_per_image=marks_per_image, max_regions=max_regions, reference=reference,
        tolerance=tolerance, breast=breast, levels=levels,
        neighbourhood=neighbourhood, n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        channel_axis=channel_axis))
