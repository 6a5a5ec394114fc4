"""Mammogram regions of interest: the job (section 14.4, docs/mammography.md).

:func:`iter_segment_breast` runs the unsupervised CAR texture segmentation
(section 14.4, docs/segmentation.md) on the pseudo-colour mammogram
``[Y, Y^0.5, Y^2]`` restricted to the breast (:func:`detect_breast`);
:func:`iter_detect_mammogram_rois` then keeps the regions whose mean grey level
is close to the median mean grey level of ground-truth mass regions (the
learned ``reference``, :func:`filter_regions`). Both yield
:class:`~car_napari.Progress` records and return their result; the names
without ``iter_`` run them to their end.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._docstrings import shared_parameters
from .._progress import Progress, drain, stage
from .._validation import check_real
from ..segmentation import iter_segment, pseudo_colour
from ._breast import _iter_detect
from ._images import _STRIP, _block_mean, _iter_grey
from ._regions import DEFAULT_MAX_REGIONS, _check_filter_options, _iter_filter

__all__ = [
    "DEFAULT_POOL_SEGMENTS",
    "BreastSegmentation",
    "detect_mammogram_rois",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "segment_breast",
]

# Segmentations pooled by :func:`detect_mammogram_rois`: the merge history's
# states with these numbers of segments (one CAR segmentation, KL merging
# (14.36), section 14.4, docs/segmentation.md).
DEFAULT_POOL_SEGMENTS = (8, 10, 12)


def _work(n_pixels, n_outputs):
    """Relative work (seconds on 2 cores, measured on mdb001 at 1024x1024 and
    upsampled to 4096x4096) of the job's parts, so that the progress fraction
    follows the work: the full-resolution steps grow with the image, the
    segmentation (at ``work_side``) does not."""
    m = n_pixels / 1e6
    return {"reading": 0.04 * m, "breast": 0.03 * m, "segmentation": 8.0,
            "pooling": 0.008 * m * n_outputs, "regions": 0.3 + 0.01 * m}


def _spans(work, parts):
    """Consecutive [start, stop) fractions of ``parts`` in proportion to ``work``."""
    total = sum(work[p] for p in parts)
    out, at = {}, 0.0
    for p in parts:
        out[p] = (at, at + work[p] / total)
        at = out[p][1]
    return out


class BreastSegmentation(NamedTuple):
    """A texture segmentation of the breast (:func:`segment_breast`).

    Parameters
    ----------
    segments : (H, W) ndarray of int32
        Segments 1..K at full resolution, 0 outside the breast.
    breast : (H, W) ndarray of bool
        The breast mask used.
    factor : int
        The block-averaging factor of the working resolution.
    pooled : list of (H, W) ndarray of int32, or None
        One full-resolution labelling per number of segments of ``pool``,
        re-cut from the same merge history; None without ``pool``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import segment_breast
    >>> image = np.zeros((64, 64))
    >>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
    >>> seg = segment_breast(image, levels=1, n_init=4, pool=(2, 3))
    >>> seg.segments.shape, seg.factor, len(seg.pooled)
    ((64, 64), 1, 2)
    """

    segments: np.ndarray
    breast: np.ndarray
    factor: int
    pooled: list | None


def _crop_box(mask, need):
    """Bounding box of ``mask`` grown to at least ``need`` pixels a side."""
    h, w = mask.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    box = []
    for lo, hi, n in ((rows[0], rows[-1] + 1, h), (cols[0], cols[-1] + 1, w)):
        size = max(hi - lo, min(need, n))
        lo = int(max(0, min(lo - (size - (hi - lo)) // 2, n - size)))
        hi = lo + size
        box.append((lo, hi))
    return box


_SEGMENT_BREAST_PARAMETERS = """
image : (H, W) array_like
    Grey mammogram (bright = dense), any numeric dtype; an RGB(A) export of
    one, with ``channel_axis``, is reduced to its luminance.
breast : (H, W) array_like of bool, optional
    The breast mask; default :func:`detect_breast`.
n_segments : int or None, optional
    Number of segments; None finds it automatically.
levels : int, optional
    Resolutions of the segmentation's features.
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the local models.
n_init : int, optional
    Components of the initial block division.
work_side : int, optional
    The working resolution: the mammogram is block-averaged to about this
    many pixels on its long side.
seed : int, optional
    Seed of the segmentation's random subsamples.
pool : sequence of int, optional
    Numbers of segments re-cut from the merge history (``pooled``).
segment_options : dict, optional
    Further keyword options of :func:`car_napari.segmentation.segment`
    (``smoothing``, ``merge_threshold``, ``forgetting``...).
channel_axis : int or None, optional
    The colour axis of an RGB(A) export; a 2-D image is grey, None forces
    grey.
"""


@shared_parameters(_SEGMENT_BREAST_PARAMETERS)
def iter_segment_breast(image, *, breast=None, n_segments=None, levels=3, neighbourhood=2,
                        n_init=16, work_side=512, seed=0, pool=None, segment_options=None,
                        channel_axis=-1):
    """Texture segmentation of the breast only, as a job.

    The mammogram is block-averaged to about ``work_side`` pixels on its long
    side, cropped to the breast's bounding box, turned into pseudo-colour
    ``[Y, Y^0.5, Y^2]`` and segmented by
    :func:`car_napari.segmentation.iter_segment` with the breast as mask; the
    segments are mapped back to full resolution. With ``pool``, the
    labellings with those numbers of segments are read from the same run's
    merge history (``SegmentationResult.labels_at``), no extra segmentation.

    Parameters
    ----------
    {parameters}

    Returns
    -------
    BreastSegmentation
        What :func:`segment_breast` returns (the generator's return value).

    Yields
    ------
    Progress
        Stage "reading" (a large image is converted in strips), "breast",
        then the segmentation's records ("features", "mixture", "merging";
        their previews are the labels of the working-resolution crop of the
        breast, not of the mammogram), then "pooling" (the segments mapped
        back to full resolution, in strips). On a 4096x4096 mammogram a
        record comes at least every half second or so (2 cores), so closing
        the job stops it soon; the fractions follow the work (the
        full-resolution steps grow with the image, the segmentation does not).

    Raises
    ------
    ValueError
        If the image is constant or has no breast, or ``breast`` does not
        match the image or is empty.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import iter_segment_breast
    >>> image = np.zeros((64, 64))
    >>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
    >>> job = iter_segment_breast(image, levels=1, n_init=4)
    >>> next(job).stage
    'breast'
    >>> job.close()
    """
    _check_segment_options(levels, work_side, seed)
    work = _work(np.size(image), len(pool or ()) + 1)
    spans = _spans(work, ("reading", "breast", "segmentation", "pooling"))
    grey = yield from stage(_iter_grey(image, channel_axis), *spans["reading"])
    return (yield from stage(_iter_segment_grey(
        grey, breast=breast, n_segments=n_segments, levels=levels, neighbourhood=neighbourhood,
        n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        segment_options=segment_options), spans["reading"][1], 1.0))


def _block_fraction(mask, factor):
    """``_block_mean(mask.astype(float), factor)`` without the float copy."""
    if factor <= 1:
        return mask.astype(float)
    h, w = (mask.shape[0] // factor) * factor, (mask.shape[1] // factor) * factor
    counts = mask[:h, :w].reshape(h // factor, factor, w // factor, factor).sum(
        axis=(1, 3), dtype=np.int64)
    return counts / float(factor * factor)


def _check_segment_options(levels, work_side, seed):
    """The breast segmentation's own options, checked before any work (the
    segmentation checks the rest)."""
    check_real(levels, "levels", low=1, high=6, integer=True)
    check_real(work_side, "work_side (pixels)", low=64, high=8192, integer=True)
    if seed is not None:
        check_real(seed, "seed", low=0, integer=True)


def _iter_segment_grey(grey, *, breast, n_segments, levels, neighbourhood, n_init, work_side,
                       seed, pool, segment_options):
    """:func:`iter_segment_breast` of a grey image on [0, 1] (:func:`_iter_grey`)."""
    H, W = grey.shape
    span = _spans(_work(H * W, len(pool or ()) + 1), ("breast", "segmentation", "pooling"))
    (b0, b1), (s0_, s1_), (p0, p1) = span["breast"], span["segmentation"], span["pooling"]
    if breast is None:
        breast = yield from stage(_iter_detect(grey), b0, b0 + 0.6 * (b1 - b0))
        found = "found"
    else:
        found = "given"
    breast = np.asarray(breast, bool)
    if breast.shape != (H, W) or not breast.any():
        raise ValueError("breast must be an (H, W) mask like the mammogram with some True pixels.")
    yield Progress("breast", b0 + 0.6 * (b1 - b0),
                   f"breast {found}: {breast.mean():.0%} of the image")
    factor = max(1, round(max(H, W) / work_side))
    small = _block_mean(grey, factor)
    yield Progress("breast", b0 + 0.8 * (b1 - b0), "working resolution")
    fraction = _block_fraction(breast, factor)
    small_mask = fraction > 0.5
    if not small_mask.any():
        small_mask = fraction > 0
    need = (2 ** (levels - 1)) * 32
    (r0, r1), (c0, c1) = _crop_box(small_mask, need)
    crop, crop_mask = small[r0:r1, c0:c1], small_mask[r0:r1, c0:c1]
    yield Progress("breast", b1, "breast cropped")
    result = yield from stage(
        iter_segment(pseudo_colour(crop), n_segments=n_segments, levels=levels,
                     neighbourhood=neighbourhood, n_init=n_init, mask=crop_mask, seed=seed,
                     **(segment_options or {})),
        s0_, s1_,
    )
    R0, C0 = r0 * factor, c0 * factor
    hh, ww = min((r1 - r0) * factor, H - R0), min((c1 - c0) * factor, W - C0)
    step = max(1, _STRIP // max(1, ww * factor))  # working-resolution rows per strip
    outputs = [(int(k), f"{k} segments") for k in pool] if pool else []
    outputs.append((None, "the segments"))
    full = []
    for j, (k, what) in enumerate(outputs):
        # the crop's segments, block-upsampled into the mammogram, 0 off the breast
        seg = np.array(result.labels if k is None else result.labels_at(k), np.int32)
        seg[~crop_mask] = 0
        out = np.zeros((H, W), np.int32)
        for s0 in range(0, r1 - r0, step):
            a, b = R0 + s0 * factor, min(R0 + (s0 + step) * factor, R0 + hh)
            if a >= b:
                break
            part = np.repeat(np.repeat(seg[s0 : s0 + step], factor, axis=0), factor, axis=1)
            part = part[: b - a, :ww]
            part[~breast[a:b, C0 : C0 + ww]] = 0
            out[a:b, C0 : C0 + ww] = part
            yield Progress("pooling", p0 + (p1 - p0) * (j + (b - R0) / max(hh, 1)) / len(outputs),
                           f"{what} at full resolution")
        full.append(out)
    return BreastSegmentation(full[-1], breast, factor, full[:-1] if pool else None)


@shared_parameters(_SEGMENT_BREAST_PARAMETERS)
def segment_breast(image, *, breast=None, n_segments=None, levels=3, neighbourhood=2,
                   n_init=16, work_side=512, seed=0, pool=None, segment_options=None,
                   channel_axis=-1):
    """Texture segmentation of the breast only.

    :func:`iter_segment_breast` run to its end (see it for the method).

    Parameters
    ----------
    {parameters}

    Returns
    -------
    BreastSegmentation
        ``segments`` (full resolution, 0 outside the breast), ``breast``,
        ``factor`` and ``pooled``.

    Raises
    ------
    ValueError
        If the image is constant or has no breast, or ``breast`` does not
        match the image or is empty.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import segment_breast
    >>> image = np.zeros((64, 64))
    >>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
    >>> seg = segment_breast(image, levels=1, n_init=4, n_segments=2)
    >>> int(seg.segments.max()), bool(seg.segments[:, :16].any())
    (2, False)
    """
    return drain(iter_segment_breast(
        image, breast=breast, n_segments=n_segments, levels=levels,
        neighbourhood=neighbourhood, n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        segment_options=segment_options, channel_axis=channel_axis,
    ))


_ROI_PARAMETERS = """
image : (H, W) array_like
    Grey mammogram (bright = dense), any numeric dtype; integer images are
    scaled by their dtype range, so ``reference`` is on that [0, 1] scale.
    An RGB(A) export of a grey mammogram, with ``channel_axis``, is reduced
    to its luminance.
reference : float, optional
    Reference grey level; default :data:`REFERENCE_GREY`.
tolerance : float, optional
    Accepted distance from ``reference``; default :data:`REFERENCE_TOLERANCE`.
levels : int, optional
    Resolutions of the segmentation's features.
n_segments : int or None, optional
    Segment into this many segments (and use only that labelling); None
    pools the merge-history states of ``pool``.
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the segmentation's local models.
n_init : int, optional
    Components of the segmentation's initial block division.
max_regions : int or None, optional
    Keep only the best-scoring regions (default :data:`DEFAULT_MAX_REGIONS`);
    None keeps all.
min_area : int, optional
    Smallest region (full-resolution pixels; default 1/4000 of the image).
breast : (H, W) array_like of bool, optional
    The breast mask; default :func:`detect_breast`.
work_side : int, optional
    Working resolution of the segmentation (long side, pixels).
seed : int, optional
    Seed of the segmentation's random subsamples.
pool : sequence of int, optional
    Numbers of segments read from the merge history and pooled (used when
    ``n_segments`` is None; None or () uses the automatic one).
split : bool, optional
    Also cut segments into their locally bright parts (:func:`filter_regions`).
channel_axis : int or None, optional
    The colour axis of an RGB(A) export of a grey mammogram; a 2-D image is
    grey, None forces grey.
"""


@shared_parameters(_ROI_PARAMETERS)
def iter_detect_mammogram_rois(image, *, reference=None, tolerance=None, levels=3,
                               n_segments=None, neighbourhood=2, n_init=16,
                               max_regions=DEFAULT_MAX_REGIONS, min_area=None, breast=None,
                               work_side=512, seed=0, pool=DEFAULT_POOL_SEGMENTS, split=True,
                               channel_axis=-1):
    """Find regions of interest (candidate masses) in a mammogram, as a job.

    See :func:`detect_mammogram_rois` for the method.

    Parameters
    ----------
    {parameters}

    Returns
    -------
    MammogramROIs
        What :func:`detect_mammogram_rois` returns (the generator's return
        value).

    Yields
    ------
    Progress
        The breast segmentation's records (:func:`iter_segment_breast`),
        then stage "regions" while the candidates are scored and the kept
        regions painted at full resolution.

    Raises
    ------
    ValueError
        If the image is constant or has no breast, or an option is out of
        range.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import iter_detect_mammogram_rois
    >>> image = np.zeros((64, 64))
    >>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
    >>> records = list(iter_detect_mammogram_rois(image, levels=1, n_init=4, pool=(2, 3)))
    >>> records[0].stage, records[-1].stage, records[-1].fraction
    ('breast', 'regions', 1.0)
    """
    _check_filter_options(reference, tolerance, max_regions, min_area)
    _check_segment_options(levels, work_side, seed)
    pool = None if n_segments is not None else pool
    spans = _spans(_work(np.size(image), len(pool or ()) + 1),
                   ("reading", "breast", "segmentation", "pooling", "regions"))
    grey = yield from stage(_iter_grey(image, channel_axis), *spans["reading"])
    segmentation = yield from stage(
        _iter_segment_grey(grey, breast=breast, n_segments=n_segments, levels=levels,
                           neighbourhood=neighbourhood, n_init=n_init, work_side=work_side,
                           seed=seed, pool=pool, segment_options=None),
        spans["breast"][0], spans["pooling"][1],
    )
    r0, r1 = spans["regions"]
    yield Progress("regions", r0, "filtering candidate regions")
    rois = yield from stage(
        _iter_filter(grey, segmentation.pooled or segmentation.segments, reference=reference,
                     tolerance=tolerance, max_regions=max_regions, min_area=min_area,
                     split=split),
        r0, r1,
    )
    n = len(rois.table["label"])
    yield Progress("regions", 1.0, f"{n} region{'' if n == 1 else 's'}")
    return rois


@shared_parameters(_ROI_PARAMETERS)
def detect_mammogram_rois(image, *, reference=None, tolerance=None, levels=3, n_segments=None,
                          neighbourhood=2, n_init=16, max_regions=DEFAULT_MAX_REGIONS,
                          min_area=None, breast=None, work_side=512, seed=0,
                          pool=DEFAULT_POOL_SEGMENTS, split=True, channel_axis=-1):
    """Find regions of interest (candidate masses) in a mammogram.

    The method of section 14.4, docs/mammography.md:

    0. The image is scaled to [0, 1]; one within a tenth of a grey level of
       an 8-bit image (a PNG read as float, a DICOM made from one) is read
       as that 8-bit image, so that such differences cannot change the
       regions (the segmentation's EM and greedy merging amplify any
       difference).
    1. Breast area: :func:`detect_breast` (or ``breast`` if given).
    2. The mammogram is block-averaged to about ``work_side`` pixels (512:
       factor 2 for mini-MIAS 1024x1024), cropped to the breast, and
       segmented (multiresolution 3DCAR features, EM and KL merging; section
       14.4, docs/segmentation.md) as pseudo-colour ``[Y, Y^0.5, Y^2]`` with
       the breast as mask. Unless ``n_segments`` is given, the merge-history
       states with ``pool`` segments (default 8, 10 and 12) are all used;
       segments are mapped back to full resolution.
    3. :func:`filter_regions`: candidate regions (segment components, and
       with ``split`` their locally bright parts) whose mean grey is within
       ``tolerance`` of ``reference`` (learned: the median mean grey of
       ground-truth mass regions), ranked by contrast with their ring,
       closeness to ``reference``, compactness and a mass-size prior; the
       best ``max_regions`` are kept (None: all). Candidates of one finding
       whose scores are within 10 % of each other make one region, their
       union, so a near tie in the ranking does not decide its shape.

    See ``benchmarks/bench_mammography.py`` for the measured sensitivity on
    mini-MIAS; with 13 mass findings in all it is a rough figure. A research
    tool, never a screening aid.

    Parameters
    ----------
    {parameters}

    Returns
    -------
    MammogramROIs
        ``labels`` (H, W) int32, regions 1..n by decreasing score, 0
        elsewhere, and ``table``, a dict of 1-D arrays (columns
        :data:`TABLE_COLUMNS`, see :func:`filter_regions`); unpacks as
        ``labels, table``.

    Raises
    ------
    ValueError
        If the image is constant or has no breast, or an option is out of
        range.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import TABLE_COLUMNS, detect_mammogram_rois
    >>> image = np.zeros((64, 64))
    >>> image[4:60, 20:] = np.random.default_rng(0).uniform(0.5, 0.9, (56, 44))
    >>> labels, table = detect_mammogram_rois(image, levels=1, n_init=4, pool=(2, 3))
    >>> labels.shape, tuple(table) == TABLE_COLUMNS
    ((64, 64), True)
    """
    return drain(iter_detect_mammogram_rois(
        image, reference=reference, tolerance=tolerance, levels=levels, n_segments=n_segments,
        neighbourhood=neighbourhood, n_init=n_init, max_regions=max_regions, min_area=min_area,
        breast=breast, work_side=work_side, seed=seed, pool=pool, split=split,
        channel_axis=channel_axis,
    ))
