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

from .._docstrings import shared_sections
from .._progress import Progress, drain, spans, stage
from .._validation import check_mask, check_real
from ..segmentation import iter_segment, pseudo_colour
from ._breast import _iter_detect
from ._candidates import (
    DESCRIPTORS,
    FAMILIES,
    NEEDS_SURPRISE,
    _describe,
    _findings,
    _generate,
    _texture_grid,
    shipped_model,
)
from ._doc_sections import EXAMPLES_MAMMOGRAM, RAISES_BREAST, RAISES_ROIS
from ._images import _STRIP, _block_mean, _iter_grey
from ._regions import (
    _ANALYSIS_SIDE,
    REFERENCE_GREY,
    SPLIT_DELTA,
    SPLIT_SIGMAS,
    TABLE_COLUMNS,
    MammogramROIs,
    _empty_table,
    _upsample_box,
)

# the segmentation's automatic stop (nats per pixel), variance floor and
# forgetting the breast pipeline and its shipped scoring model were built with (segment's
# defaults before issue 14 chose them on texture mosaics)
_SEGMENT_DEFAULTS = {"merge_threshold": 1.5, "var_floor": 0.1, "forgetting": 0.99}

__all__ = [
    "DEFAULT_MARKS_PER_IMAGE",
    "DEFAULT_POOL_SEGMENTS",
    "BreastSegmentation",
    "detect_mammogram_rois",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
    "operating_point",
    "score_threshold",
    "segment_breast",
    "select_marks",
]

# Segmentations pooled by :func:`detect_mammogram_rois`: the merge history's
# states with these numbers of segments (one CAR segmentation, KL merging
# (14.36), section 14.4, docs/segmentation.md).
DEFAULT_POOL_SEGMENTS = (8, 10, 12)


def _stage_spans(n_pixels, n_outputs, parts):
    """The progress spans of the job's ``parts`` (:func:`~car_napari._progress.spans`)
    in proportion to their work (seconds on 2 cores, measured on mdb001 at
    1024x1024 and upsampled to 4096x4096), so that the progress fraction
    follows the work: the full-resolution steps grow with the image, the
    segmentation (at ``work_side``) does not."""
    m = n_pixels / 1e6
    work = {"reading": 0.04 * m, "breast": 0.03 * m, "segmentation": 8.0,
            "pooling": 0.008 * m * n_outputs, "regions": 0.3 + 0.01 * m}
    return spans({part: work[part] for part in parts})


@shared_sections(examples=EXAMPLES_MAMMOGRAM)
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
    features : (h, w, D) ndarray of float32, or None
        The segmentation's per-pixel CAR features (local parameters,
        prediction-error energy, local mean; (14.33)) on the working-resolution
        crop of the breast, when asked for (``keep_features``); else None.
    box : (int, int, int, int) or None
        The crop ``(row0, row1, col0, col1)`` of ``features`` at the working
        resolution (full-resolution pixel = ``factor`` x working pixel).

    {examples}
    >>> from car_napari.mammography import segment_breast
    >>> seg = segment_breast(image, levels=1, n_init=4, pool=(2, 3))
    >>> seg.segments.shape, seg.factor, len(seg.pooled)
    ((64, 64), 1, 2)
    """

    segments: np.ndarray
    breast: np.ndarray
    factor: int
    pooled: list | None
    features: np.ndarray | None = None
    box: tuple | None = None


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
Parameters
----------
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
keep_features : bool, optional
    Keep the segmentation's CAR features (``features``, ``box``): what
    :func:`segment_tissue` needs to reuse the segmentation.
"""


@shared_sections(parameters=_SEGMENT_BREAST_PARAMETERS, raises=RAISES_BREAST,
                 examples=EXAMPLES_MAMMOGRAM)
def iter_segment_breast(image, *, breast=None, n_segments=None, levels=3, neighbourhood=2,
                        n_init=16, work_side=512, seed=0, pool=None, segment_options=None,
                        channel_axis=-1, keep_features=False):
    """Texture segmentation of the breast only, as a job.

    The mammogram is block-averaged to about ``work_side`` pixels on its long
    side, cropped to the breast's bounding box, turned into pseudo-colour
    ``[Y, Y^0.5, Y^2]`` and segmented by
    :func:`car_napari.segmentation.iter_segment` with the breast as mask; the
    segments are mapped back to full resolution. With ``pool``, the
    labellings with those numbers of segments are read from the same run's
    merge history (``SegmentationResult.labels_at``), no extra segmentation.

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

    {raises}

    {examples}
    >>> from car_napari.mammography import iter_segment_breast
    >>> job = iter_segment_breast(image, levels=1, n_init=4)
    >>> next(job).stage
    'breast'
    >>> job.close()
    """
    _check_segment_options(levels, work_side, seed, pool, segment_options)
    if breast is not None:
        breast = check_mask(breast, "breast", meaning="True on the breast")
    span = _stage_spans(np.size(image), len(pool or ()) + 1,
                 ("reading", "breast", "segmentation", "pooling"))
    grey = yield from stage(_iter_grey(image, channel_axis), *span("reading"))
    return (yield from stage(_iter_segment_grey(
        grey, breast=breast, n_segments=n_segments, levels=levels, neighbourhood=neighbourhood,
        n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        segment_options=segment_options, keep_features=bool(keep_features)),
        span("reading").stop, 1.0))


def _block_fraction(mask, factor):
    """``_block_mean(mask.astype(float), factor)`` without the float copy."""
    if factor <= 1:
        return mask.astype(float)
    h, w = (mask.shape[0] // factor) * factor, (mask.shape[1] // factor) * factor
    counts = mask[:h, :w].reshape(h // factor, factor, w // factor, factor).sum(
        axis=(1, 3), dtype=np.int64)
    return counts / float(factor * factor)


# segment's options that the breast segmentation sets itself
_OWN_SEGMENT_OPTIONS = ("image", "n_segments", "levels", "neighbourhood", "n_init", "mask",
                        "seed")
_MAX_POOL = 64  # pooled segmentations: each costs a pass over the merge history


def _check_segment_options(levels, work_side, seed, pool=None, segment_options=None):
    """The breast segmentation's own options, checked before any work (the
    segmentation checks the rest)."""
    check_real(levels, "levels", low=1, high=6, integer=True)
    check_real(work_side, "work_side (pixels)", low=64, high=8192, integer=True)
    if seed is not None:
        check_real(seed, "seed", low=0, integer=True)
    if pool is not None:
        if isinstance(pool, (str, bytes)) or not hasattr(pool, "__len__"):
            raise TypeError(f"pool must be None or a sequence of numbers of segments, e.g. "
                            f"(8, 10, 12); got {pool!r}.")
        if len(pool) > _MAX_POOL:
            raise ValueError(f"pool has {len(pool)} entries; at most {_MAX_POOL}.")
        for k in pool:
            check_real(k, "pool (numbers of segments)", low=1, high=1 << 16, integer=True)
    if segment_options is not None:
        if not isinstance(segment_options, dict):
            raise TypeError(f"segment_options must be None or a dict of segment's options; "
                            f"got {type(segment_options).__name__}.")
        import inspect

        known = set(inspect.signature(iter_segment).parameters) - set(_OWN_SEGMENT_OPTIONS)
        unknown = sorted(map(str, set(segment_options) - known))
        if unknown:
            raise TypeError(f"segment_options has {unknown}, which segment_breast does not "
                            f"pass on; allowed: {sorted(known)}.")


def _iter_segment_grey(grey, *, breast, n_segments, levels, neighbourhood, n_init, work_side,
                       seed, pool, segment_options, keep_features=False):
    """:func:`iter_segment_breast` of a grey image on [0, 1] (:func:`_iter_grey`)."""
    H, W = grey.shape
    span = _stage_spans(H * W, len(pool or ()) + 1, ("breast", "segmentation", "pooling"))
    (b0, b1), (s0_, s1_), (p0, p1) = span("breast"), span("segmentation"), span("pooling")
    if breast is None:
        breast = yield from stage(_iter_detect(grey), b0, b0 + 0.6 * (b1 - b0))
        found = "found"
    else:
        found = "given"
    breast = check_mask(breast, "breast", meaning="True on the breast") != 0
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
                     **{**_SEGMENT_DEFAULTS, **(segment_options or {})}),
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
    features = result.features if keep_features else None
    return BreastSegmentation(full[-1], breast, factor, full[:-1] if pool else None, features,
                              (int(r0), int(r1), int(c0), int(c1)))


@shared_sections(parameters=_SEGMENT_BREAST_PARAMETERS, raises=RAISES_BREAST,
                 examples=EXAMPLES_MAMMOGRAM)
def segment_breast(image, *, breast=None, n_segments=None, levels=3, neighbourhood=2,
                   n_init=16, work_side=512, seed=0, pool=None, segment_options=None,
                   channel_axis=-1, keep_features=False):
    """Texture segmentation of the breast only.

    :func:`iter_segment_breast` run to its end (see it for the method).

    {parameters}

    Returns
    -------
    BreastSegmentation
        ``segments`` (full resolution, 0 outside the breast), ``breast``,
        ``factor`` and ``pooled``.

    {raises}

    {examples}
    >>> from car_napari.mammography import segment_breast
    >>> seg = segment_breast(image, levels=1, n_init=4, n_segments=2)
    >>> int(seg.segments.max()), bool(seg.segments[:, :16].any())
    (2, False)
    """
    return drain(iter_segment_breast(
        image, breast=breast, n_segments=n_segments, levels=levels,
        neighbourhood=neighbourhood, n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        segment_options=segment_options, channel_axis=channel_axis,
        keep_features=keep_features,
    ))


_ROI_PARAMETERS = """
Parameters
----------
image : (H, W) array_like
    Grey mammogram (bright = dense), any numeric dtype; integer images are
    scaled by their dtype range, except a uint16 image whose maximum is at
    most 4,095: a 12-bit mammogram, scaled by 4095. An RGB(A) export of a grey mammogram, with
    ``channel_axis``, is reduced to its luminance.
marks_per_image : float or None, optional
    The operating point: the score threshold at which the shipped model
    makes this many false marks per image on average, cross-validated by
    patient on CBIS-DDSM films (see :func:`operating_point` for the
    sensitivity there);
    default :data:`DEFAULT_MARKS_PER_IMAGE`. None keeps every finding, each
    with its score (:func:`select_marks` cuts such a result later).
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
    Advanced: also keep at most this many regions, best first; None: no cap.
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
    Also cut segments into their locally bright parts.
reference : float, optional
    Advanced, the chapter's grey-level filter: with ``tolerance``, drop
    candidates whose mean grey (on [0, 1]) is further than ``tolerance``
    from ``reference`` (default :data:`REFERENCE_GREY`). Off by default:
    the grey level is one of the scoring model's descriptors.
tolerance : float or None, optional
    Advanced: the width of that filter; None (default) turns it off.
channel_axis : int or None, optional
    The colour axis of an RGB(A) export of a grey mammogram; a 2-D image is
    grey, None forces grey.
"""

# The default operating point: false marks per image (cross-validated on CBIS-DDSM films).
DEFAULT_MARKS_PER_IMAGE = 2.0


def _check_roi_options(marks_per_image, reference, tolerance, max_regions, min_area):
    """The ROI job's own options, checked before any work."""
    if marks_per_image is not None:
        check_real(marks_per_image, "marks_per_image (false marks per image, or None)",
                   low=0.0, low_open=True, high=100.0)
    if reference is not None:
        check_real(reference, "reference", low=0.0, high=1.0)
    if tolerance is not None:
        check_real(tolerance, "tolerance", low=0.0, low_open=True)
    if max_regions is not None:
        check_real(max_regions, "max_regions (a positive int or None)", low=1, integer=True)
    if min_area is not None:
        check_real(min_area, "min_area (pixels, or None)", low=0.0)


@shared_sections(parameters=_ROI_PARAMETERS, raises=RAISES_ROIS,
                 examples=EXAMPLES_MAMMOGRAM)
def iter_detect_mammogram_rois(image, *, marks_per_image=DEFAULT_MARKS_PER_IMAGE, levels=3,
                               n_segments=None, neighbourhood=2, n_init=16, max_regions=None,
                               min_area=None, breast=None, work_side=512, seed=0,
                               pool=DEFAULT_POOL_SEGMENTS, split=True, reference=None,
                               tolerance=None, channel_axis=-1):
    """Find regions of interest (candidate masses) in a mammogram, as a job.

    See :func:`detect_mammogram_rois` for the method.

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
        then stage "regions" while the candidates are described, scored and
        the findings painted at full resolution.

    {raises}

    {examples}
    >>> from car_napari.mammography import iter_detect_mammogram_rois
    >>> records = list(iter_detect_mammogram_rois(image, levels=1, n_init=4, pool=(2, 3)))
    >>> records[0].stage, records[-1].stage, records[-1].fraction
    ('breast', 'regions', 1.0)
    """
    _check_roi_options(marks_per_image, reference, tolerance, max_regions, min_area)
    _check_segment_options(levels, work_side, seed, pool)
    if breast is not None:
        breast = check_mask(breast, "breast", meaning="True on the breast")
    model = shipped_model()
    pool = None if n_segments is not None else pool
    grey, segmentation, (r0, r1) = yield from _iter_breast_stages(
        image, breast=breast, n_segments=n_segments, levels=levels,
        neighbourhood=neighbourhood, n_init=n_init, work_side=work_side, seed=seed, pool=pool,
        channel_axis=channel_axis)
    yield Progress("regions", r0, "candidate regions")
    threshold = None if marks_per_image is None else model.threshold(marks_per_image)
    rois = yield from stage(
        _iter_rank(grey, segmentation, model, threshold=threshold, max_regions=max_regions,
                   min_area=min_area, split=split, band=_band(reference, tolerance)),
        r0, r1,
    )
    n = len(rois.table["label"])
    yield Progress("regions", 1.0, f"{n} region{'' if n == 1 else 's'}")
    return rois


def _iter_breast_stages(image, *, breast, n_segments, levels, neighbourhood, n_init, work_side,
                        seed, pool, channel_axis):
    """The first stages of every mammogram job: the image read as grey and
    its breast segmented (features kept). Returns (grey, segmentation, the
    (start, stop) fractions left for the job's own stages)."""
    span = _stage_spans(np.size(image), len(pool or ()) + 1,
                 ("reading", "breast", "segmentation", "pooling", "regions"))
    grey = yield from stage(_iter_grey(image, channel_axis), *span("reading"))
    segmentation = yield from stage(
        _iter_segment_grey(grey, breast=breast, n_segments=n_segments, levels=levels,
                           neighbourhood=neighbourhood, n_init=n_init, work_side=work_side,
                           seed=seed, pool=pool, segment_options=None, keep_features=True),
        span("breast").start, span("pooling").stop,
    )
    return grey, segmentation, tuple(span("regions"))


def _iter_default_segmentation(grey):
    """The mammogram jobs' breast segmentation of a grey image on [0, 1]
    with their default options, the CAR features kept: what the benchmarks
    segment once and cache (bench_froc.py, bench_tissue.py)."""
    return _iter_segment_grey(grey, breast=None, n_segments=None, levels=3, neighbourhood=2,
                              n_init=16, work_side=512, seed=0, pool=DEFAULT_POOL_SEGMENTS,
                              segment_options=None, keep_features=True)


def _band(reference, tolerance):
    """The chapter's grey-level filter as (centre, half width), or None."""
    if tolerance is None:
        return None
    return REFERENCE_GREY if reference is None else float(reference), float(tolerance)


def _iter_rank(grey, segmentation, model, *, threshold, max_regions, min_area, split, band):
    """Candidates of a breast segmentation, described, scored by ``model``,
    merged into findings and painted (``_candidates``), as a job."""
    H, W = grey.shape
    if min_area is None:
        min_area = max(16, H * W // 4000)
    f = max(1, round(max(H, W) / _ANALYSIS_SIDE))
    small = _block_mean(grey, f)
    h, w = small.shape
    labellings = segmentation.pooled or [segmentation.segments]
    labs = [s[f // 2 :: f, f // 2 :: f][:h, :w] for s in labellings]
    breast = labs[0] > 0
    texture = None
    # the breast-relative family reads the CAR features too
    uses_texture = bool(set(model.names) & set(FAMILIES["texture"] + FAMILIES["breast"]))
    if segmentation.features is not None and uses_texture:
        texture = _texture_grid(segmentation.features, segmentation.box, segmentation.factor, f,
                                (h, w))
    cands = _generate(small, labs, breast, split=split, sigmas=[s / f for s in SPLIT_SIGMAS],
                      delta=SPLIT_DELTA, min_area=max(4, min_area // (f * f)))
    yield Progress("regions", 0.2, f"describing {len(cands)} candidates")
    kept, X = yield from _describe(small, labs, breast, texture, cands, f=f, side=max(H, W),
                                   work=(0.2, 0.6),
                                   surprise=bool(set(model.names) & NEEDS_SURPRISE))
    scores = model.score(X) if kept else np.zeros(0)
    if band is not None:
        ok = np.abs(X[:, DESCRIPTORS.index("mean_grey")] - band[0]) <= band[1]
        kept, X, scores = [c for c, k in zip(kept, ok, strict=True) if k], X[ok], scores[ok]
    findings = _findings(kept, scores, small, model)
    if threshold is not None:
        findings = [fnd for fnd in findings if fnd[0] >= threshold]
    if max_regions is not None:
        findings = findings[: int(max_regions)]
    yield Progress("regions", 0.6, f"{len(findings)} regions at full resolution")
    contrast = X[:, DESCRIPTORS.index("contrast")] if kept else np.zeros(0)
    return (yield from _iter_paint(grey, labellings[0], findings, contrast, f, band, (h, w)))


def _iter_paint(grey_full, first, findings, contrast, f, band, shape):
    """Findings (``_merge``'s ``(score, mask, box, best)``, best first; the
    analysis grid of ``shape`` and block ``f``) painted at full resolution
    and measured there, as :class:`MammogramROIs`."""
    H, W = grey_full.shape
    labels = np.zeros((H, W), np.int32)
    out_rows = []
    for n, (score, mask, (r0, r1, c0, c1), best) in enumerate(findings):
        grid = np.zeros(shape, bool)  # the analysis grid
        grid[r0:r1, c0:c1] = mask
        box, sub = _upsample_box(grid, (H, W), f)
        m = sub & (first[box] > 0) & (labels[box] == 0)
        if n % 16 == 15:
            yield Progress("regions", 0.6 + 0.4 * (n + 1) / max(len(findings), 1),
                           f"region {n + 1}/{len(findings)}")
        if not m.any():
            continue
        mean = float(grey_full[box][m].mean())
        if band is not None and abs(mean - band[0]) > band[1]:
            continue
        new = len(out_rows) + 1
        labels[box][m] = new
        rr, cl = np.nonzero(m)
        rr, cl = rr + box[0].start, cl + box[1].start
        out_rows.append((new, int(m.sum()), mean, float(contrast[best]), int(rr.min()),
                         int(cl.min()), int(rr.max()) + 1, int(cl.max()) + 1, float(rr.mean()),
                         float(cl.mean()), float(score)))
    table = _empty_table()
    if out_rows:
        for k, col in zip(TABLE_COLUMNS, zip(*out_rows, strict=True), strict=True):
            table[k] = np.asarray(col, table[k].dtype)
    return MammogramROIs(labels, table)


def select_marks(rois, marks_per_image=DEFAULT_MARKS_PER_IMAGE, *, threshold=None):
    """The marks of an operating point, cut from a result with every finding.

    Parameters
    ----------
    rois : MammogramROIs
        A result of :func:`detect_mammogram_rois` (typically with
        ``marks_per_image=None``: every finding); regions are numbered by
        decreasing score.
    marks_per_image : float, optional
        The operating point, as in :func:`detect_mammogram_rois`.
    threshold : float, optional
        A score threshold instead of ``marks_per_image``.

    Returns
    -------
    MammogramROIs
        The regions whose score is at least the threshold: labels 1..m (the
        same numbers), the table's first m rows. Nothing is recomputed:
        regions were painted best first, so the first m are those the
        detection at this operating point paints.

    Raises
    ------
    TypeError
        If ``rois`` is not a MammogramROIs, or ``threshold`` not a number.
    ValueError
        If ``threshold`` is not finite, or ``marks_per_image`` is out of
        range.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import MammogramROIs, select_marks
    >>> labels = np.array([[1, 1, 2, 3]], np.int32)
    >>> table = {"label": np.array([1, 2, 3]), "score": np.array([0.9, 0.5, 0.1])}
    >>> cut = select_marks(MammogramROIs(labels, table), threshold=0.4)
    >>> cut.labels.tolist(), cut.table["score"].tolist()
    ([[1, 1, 2, 0]], [0.9, 0.5])
    """
    if threshold is None:
        check_real(marks_per_image, "marks_per_image (false marks per image)", low=0.0,
                   low_open=True, high=100.0)
        threshold = shipped_model().threshold(marks_per_image)
    else:
        threshold = check_real(threshold, "threshold (a score)")
    if not isinstance(rois, MammogramROIs):
        raise TypeError(f"rois must be a MammogramROIs (from detect_mammogram_rois); got "
                        f"{type(rois).__name__}.")
    labels, table = rois
    m = int(np.sum(np.asarray(table["score"]) >= threshold))
    cut = {k: np.asarray(v)[:m] for k, v in table.items()}
    kept = labels.copy()  # one copy, zeroed in place: no temporaries of the image's size
    kept[kept > m] = 0  # (a viewer re-cuts this on its main thread)
    return MammogramROIs(kept, cut)


def score_threshold(marks_per_image=DEFAULT_MARKS_PER_IMAGE):
    """The score threshold of an operating point of the shipped model.

    Parameters
    ----------
    marks_per_image : float, optional
        False marks per image on average (cross-validated by patient on
        the model's training films, CBIS-DDSM).

    Returns
    -------
    float
        Regions scoring at least this are marked.

    Examples
    --------
    >>> from car_napari.mammography import score_threshold
    >>> score_threshold(1.0) >= score_threshold(3.0)
    True
    """
    check_real(marks_per_image, "marks_per_image (false marks per image)", low=0.0,
               low_open=True, high=100.0)
    return shipped_model().threshold(marks_per_image)


def operating_point(marks_per_image=DEFAULT_MARKS_PER_IMAGE):
    """What the shipped model's cross-validation says of an operating point.

    Parameters
    ----------
    marks_per_image : float, optional
        False marks per image on average (on the model's cross-validated
        training films).

    Returns
    -------
    dict
        ``marks_per_image``; ``threshold`` (the score threshold);
        ``sensitivity`` (the share of masses found there, strict rule: a
        mark's centroid inside the mass's box), ``interval`` (its 95 %
        bootstrap interval over patients, or None) and ``control`` (the no-CAR
        control's sensitivity at the same rate), each read from
        :data:`OPERATING_POINTS` at the nearest tabled rate at or below
        ``marks_per_image`` (the first row below the table).

    Examples
    --------
    >>> from car_napari.mammography import operating_point
    >>> point = operating_point(1.0)
    >>> sorted(point)
    ['control', 'interval', 'marks_per_image', 'sensitivity', 'threshold']
    """
    check_real(marks_per_image, "marks_per_image (false marks per image)", low=0.0,
               low_open=True, high=100.0)
    model = shipped_model()
    points = sorted(model.spec.get("operating_points", []), key=lambda p: p["marks_per_image"])
    below = [p for p in points if p["marks_per_image"] <= marks_per_image + 1e-9]
    row = below[-1] if below else (points[0] if points else {})
    return {"marks_per_image": float(marks_per_image),
            "threshold": model.threshold(marks_per_image),
            "sensitivity": row.get("cv_sensitivity_strict"),
            "interval": row.get("cv_interval_strict"),
            "control": row.get("control_cv_sensitivity_strict")}


@shared_sections(parameters=_ROI_PARAMETERS, raises=RAISES_ROIS,
                 examples=EXAMPLES_MAMMOGRAM)
def detect_mammogram_rois(image, *, marks_per_image=DEFAULT_MARKS_PER_IMAGE, levels=3,
                          n_segments=None, neighbourhood=2, n_init=16, max_regions=None,
                          min_area=None, breast=None, work_side=512, seed=0,
                          pool=DEFAULT_POOL_SEGMENTS, split=True, reference=None,
                          tolerance=None, channel_axis=-1):
    """Find regions of interest (candidate masses) in a mammogram.

    The method of section 14.4, docs/mammography.md:

    0. The image is scaled to [0, 1]; one within a tenth of a grey level of
       an 8-bit image (a PNG read as float, a DICOM made from one) is read
       as that 8-bit image, so that such differences cannot change the
       regions.
    1. Breast area: :func:`detect_breast` (or ``breast`` if given).
    2. The mammogram is block-averaged to about ``work_side`` pixels (512:
       factor 2 for mini-MIAS 1024x1024), cropped to the breast, and
       segmented (multiresolution 3DCAR features, EM and KL merging; section
       14.4, docs/segmentation.md) as pseudo-colour ``[Y, Y^0.5, Y^2]`` with
       the breast as mask. Unless ``n_segments`` is given, the merge-history
       states with ``pool`` segments (default 8, 10 and 12) are all used.
    3. Candidates: the components of every segment and, with ``split``, of
       their locally bright parts, on a grid of about 256 pixels.
    4. Each candidate is described by the segmentation's CAR features
       (local parameters and prediction-error energy inside against a ring
       of breast around it, how much of the ring is other segments), its
       grey level and contrast against the ring, its size and shape, and
       where it lies in the breast; a model of those descriptors (boosted
       trees), fitted on 1,231 CBIS-DDSM films and shipped
       (``roi_model.json``), scores it in (0, 1).
    5. Findings, best score first: a candidate whose centroid lies in a
       kept finding or that holds its centroid is that finding (it joins it
       within the model's ``merge_tie`` of its score; the shipped model's
       is 0: never). Those scoring at least the threshold of
       ``marks_per_image`` are painted at full resolution.

    The sensitivity at each operating point, cross-validated by patient on
    the CBIS-DDSM films, is in :data:`OPERATING_POINTS` and
    :func:`operating_point` (``benchmarks/bench_froc.py``). A research tool,
    never a screening aid.

    {parameters}

    Returns
    -------
    MammogramROIs
        ``labels`` (H, W) int32, regions 1..n by decreasing score, 0
        elsewhere, and ``table``, a dict of 1-D arrays (columns
        :data:`TABLE_COLUMNS`; ``score`` is the model's, ``contrast`` the
        best candidate's on the analysis grid); unpacks as ``labels, table``.

    {raises}

    {examples}
    >>> from car_napari.mammography import TABLE_COLUMNS, detect_mammogram_rois
    >>> labels, table = detect_mammogram_rois(image, levels=1, n_init=4, pool=(2, 3),
    ...                                       marks_per_image=None)
    >>> labels.shape, tuple(table) == TABLE_COLUMNS
    ((64, 64), True)
    """
    return drain(iter_detect_mammogram_rois(
        image, marks_per_image=marks_per_image, levels=levels, n_segments=n_segments,
        neighbourhood=neighbourhood, n_init=n_init, max_regions=max_regions, min_area=min_area,
        breast=breast, work_side=work_side, seed=seed, pool=pool, split=split,
        reference=reference, tolerance=tolerance, channel_axis=channel_axis,
    ))
