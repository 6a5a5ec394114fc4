"""Candidate regions of interest on a segmentation of the breast, the
grey-level filter that keeps mass-like ones (section 14.4,
docs/mammography.md), and their outlines."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._progress import Progress, drain
from .._validation import check_flag, check_real
from ._candidates import _centre_and_compactness, _crop, _generate, _ring
from ._images import _as_grey, _block_mean, _grey01, _upsample_mask

__all__ = [
    "DEFAULT_MAX_REGIONS",
    "MASS_RADIUS_RANGE",
    "REFERENCE_GREY",
    "REFERENCE_TOLERANCE",
    "TABLE_COLUMNS",
    "MammogramROIs",
    "filter_regions",
    "region_outlines",
]

# Learned by ``benchmarks/bench_mammography.py`` on mini-MIAS, 2026-11-22:
# learning split = even positions in refnum order (mdb001, mdb009, ...; its 6
# mass findings); the median, over the ground-truth mass circles, of the mean
# grey level (8-bit / 255) inside the circle. (All 13 masses: 0.636.)
REFERENCE_GREY = 0.660
# Half-width of the accepted band around REFERENCE_GREY and the number of
# regions kept per image (best score first), chosen by the same script on the
# learning split only (its 41 images, 6 mass findings; 2026-11-22, pooled
# 512-pixel segmentation with the local-contrast split): highest sensitivity
# with at most 3 false regions per image, ties to fewer false regions.
REFERENCE_TOLERANCE = 0.15
DEFAULT_MAX_REGIONS = 3
# Prior on a mass's equivalent radius, in full-resolution pixels of a
# 1024x1024 mini-MIAS image: log-normal centred on sqrt(20*130) ~ 51 px, one
# standard deviation = half the log range (ground-truth mass radii: 26-197).
# Set by hand from the radii, not tuned; scale it for other pixel sizes.
MASS_RADIUS_RANGE = (20.0, 130.0)
# Local-contrast split of segments: pixels brighter than a Gaussian background
# of these widths (full-resolution pixels, one candidate set per width) by
# ``SPLIT_DELTA`` (grey / 255) form the sub-regions.
SPLIT_SIGMAS = (16.0, 64.0)
SPLIT_DELTA = 0.01
# Candidates of one finding whose scores are within this fraction of the
# finding's score are equally good descriptions of it: the region is their
# union (:func:`_select`), so a near tie in the ranking does not decide it.
_TIE = 0.1
_ANALYSIS_SIDE = 256  # region analysis resolution (longest side, pixels)

TABLE_COLUMNS = ("label", "area", "mean_grey", "contrast", "bbox_min_row", "bbox_min_col",
                 "bbox_max_row", "bbox_max_col", "centroid_row", "centroid_col", "score")


def _empty_table():
    return {k: np.zeros(0, np.int64 if k.startswith(("label", "area", "bbox")) else np.float64)
            for k in TABLE_COLUMNS}


def _size_prior(radius, lo, hi):
    """Log-normal weight of an equivalent radius: 1 at sqrt(lo*hi)."""
    centre, spread = np.log(np.sqrt(lo * hi)), 0.5 * np.log(hi / lo)
    return float(np.exp(-0.5 * ((np.log(radius) - centre) / spread) ** 2))


class MammogramROIs(NamedTuple):
    """Regions of interest of a mammogram; unpacks as ``labels, table``.

    Parameters
    ----------
    labels : (H, W) ndarray of int32
        Kept regions numbered 1..n by decreasing score, 0 elsewhere.
    table : dict of equal-length 1-D arrays
        One row per region, columns :data:`TABLE_COLUMNS` (see
        :func:`filter_regions`).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import filter_regions
    >>> segments = np.ones((64, 64), np.int32)
    >>> image = np.full((64, 64), 0.3)
    >>> image[20:40, 20:40], segments[20:40, 20:40] = 0.66, 2
    >>> labels, table = filter_regions(image, segments, max_regions=None)
    >>> int(labels.max()), table["label"].tolist()
    (1, [1])
    """

    labels: np.ndarray
    table: dict


def _candidates(grey, labellings, breast, *, split, sigmas, delta, min_area):
    """Candidate regions on the analysis grid: ``(cc, i, slices, area)``
    tuples, those of :func:`._candidates._generate` without the labelling."""
    return [(cc, i, sl, area) for cc, i, sl, area, _ in _generate(
        grey, labellings, breast, split=split, sigmas=sigmas, delta=delta, min_area=min_area)]


def _select(rows, max_regions):
    """The findings among scored candidates: (score, contrast, mask) best first.

    ``rows`` are ``(score, contrast, cc, i, (r0, r1, c0, c1), row, col)``,
    sorted best first: candidate ``cc == i`` inside the box, its centroid.
    A candidate is the same finding as a kept one when its centroid lies in
    it or it holds the finding's centroid. Within :data:`_TIE` of that
    finding's score it joins it (the finding's mask grows to the union, so
    which of two nearly equal candidates ranks first does not change the
    region); otherwise it is skipped. Once ``max_regions`` findings are
    kept, only near ties may still join.
    """
    findings = []  # [score, contrast, mask on the analysis grid, centroid row, col]
    for score, contrast, cc, i, (r0, r1, c0, c1), cr, ccol in rows:
        full = max_regions is not None and len(findings) >= int(max_regions)
        if full and score < (1.0 - _TIE) * findings[-1][0]:
            break
        box = (slice(r0, r1), slice(c0, c1))
        inside = cc[box] == i
        same = None
        for fnd in findings:
            if fnd[2][cr, ccol] or (r0 <= fnd[3] < r1 and c0 <= fnd[4] < c1
                                    and cc[fnd[3], fnd[4]] == i):
                same = fnd
                break
        if same is not None:
            if score >= (1.0 - _TIE) * same[0]:
                same[2][box] |= inside
            continue
        if full:
            continue
        mask = np.zeros(cc.shape, bool)
        mask[box] = inside
        findings.append([score, contrast, mask, cr, ccol])
    return [(fnd[0], fnd[1], fnd[2]) for fnd in findings]


def filter_regions(image, segments, *, reference=None, tolerance=None, max_regions=None,
                   min_area=None, split=True, radius_range=MASS_RADIUS_RANGE,
                   split_sigmas=SPLIT_SIGMAS, split_delta=SPLIT_DELTA, channel_axis=-1):
    """Mass-like regions of a segmentation of the breast: the grey-level filter.

    The filter of section 14.4, docs/mammography.md, with candidate
    splitting and ranking. ``segments`` is one (H, W) labelling (0 outside
    the breast) or a list of them (e.g. several states of one merge history,
    pooled). The analysis runs on a grid of about 256 pixels on the long
    side (block mean).

    Candidates: every 4-connected component (after a one-pixel opening) of
    every segment; with ``split`` (default) also the components of each
    segment restricted to its locally bright pixels (brighter than a
    Gaussian background of width ``split_sigmas`` full-resolution pixels
    by ``split_delta``): CAR segments of mammograms are density bands much
    larger than most masses, and this cuts them into mass-sized pieces.
    Candidates smaller than ``min_area`` full-resolution pixels are dropped,
    and so are those whose mean grey (the image scaled to [0, 1] like
    ``img_as_float``) is further than ``tolerance`` from ``reference``.

    Score: ``contrast`` (mean grey minus the mean of the breast in a ring
    half the equivalent radius wide; candidates not brighter than their ring
    are dropped) times ``1 - |mean - reference| / tolerance`` times the
    compactness (fraction of the candidate inside the equal-area disc at
    its centroid) times a log-normal size prior on the equivalent radius.
    Candidates are taken best first. One whose centroid lies in an already
    kept region or that holds a kept region's centroid is the same finding:
    it joins that region (the region grows to their union) when its score
    is within 10 % of the region's, so that which of two nearly equal
    candidates ranks first does not decide the region, and is skipped
    otherwise. With
    ``max_regions`` only that many regions are kept. With ``split=False,
    radius_range=None`` and a single labelling this is close to the former
    behaviour (plus the opening and the compactness factor).

    Parameters
    ----------
    image : (H, W) array_like
        Grey mammogram (bright = dense), any numeric dtype; an RGB(A) export
        of one, with ``channel_axis``, is reduced to its luminance. One within
        a tenth of a grey level of an 8-bit image is read as that image.
    segments : (H, W) array_like of int, or a sequence of them
        Segmentation(s) of the breast, 0 outside it (the first one's non-zero
        pixels are the breast).
    reference : float, optional
        Reference grey level on [0, 1]; default :data:`REFERENCE_GREY`.
    tolerance : float, optional
        Accepted distance from ``reference`` (> 0); default
        :data:`REFERENCE_TOLERANCE`.
    max_regions : int or None, optional
        Keep only this many regions, best score first; None keeps all.
    min_area : int, optional
        Smallest candidate, full-resolution pixels (default: 1/4000 of the
        image, at least 16).
    split : bool, optional
        Also cut segments into their locally bright parts.
    radius_range : (float, float) or None, optional
        The size prior's equivalent radii (full-resolution pixels) one log
        standard deviation either side of its centre; None: no prior.
    split_sigmas : sequence of float, optional
        Widths (full-resolution pixels) of the Gaussian backgrounds of the
        split, one candidate set per width.
    split_delta : float, optional
        How much brighter than the background a split pixel is (grey / 255).
    channel_axis : int or None, optional
        The colour axis of an RGB(A) export; a 2-D image is grey, None forces
        grey.

    Returns
    -------
    MammogramROIs
        ``labels`` (H, W) int32: kept regions numbered 1..n by decreasing
        score, 0 elsewhere (a pixel claimed by two kept regions goes to the
        better one). ``table``: dict of equal-length 1-D arrays, columns
        :data:`TABLE_COLUMNS`, measured on ``labels`` at full resolution
        (``label`` matches ``labels``; bounding box ``max`` ends are
        exclusive; areas in pixels; centroid as (row, col)); ``contrast``
        and ``score`` come from the analysis grid. A napari features table
        and ``csv.writer`` take it.

    Raises
    ------
    ValueError
        If ``tolerance``, ``max_regions``, ``radius_range``, ``split_sigmas``
        or ``split_delta`` is out of range, the image is constant, or a
        labelling's shape differs from the image's.
    TypeError
        If an option is not a number (or a sequence of them where one is
        asked), or ``split`` is not a bool.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import filter_regions
    >>> image = np.full((200, 200), 0.3)
    >>> segments = np.ones((200, 200), np.int32)
    >>> image[50:90, 50:90], segments[50:90, 50:90] = 0.66, 2  # a mass-like block
    >>> image[120:160, 120:160], segments[120:160, 120:160] = 0.95, 3  # too bright
    >>> rois = filter_regions(image, segments, reference=0.66, tolerance=0.1)
    >>> int(rois.labels.max()), rois.table["area"].tolist()
    (1, [1596])
    """
    _check_filter_options(reference, tolerance, max_regions, min_area, split=split,
                          radius_range=radius_range, split_sigmas=split_sigmas,
                          split_delta=split_delta)
    grey_full = _grey01(_as_grey(image, channel_axis), name="mammogram")
    return drain(_iter_filter(
        grey_full, segments, reference=reference, tolerance=tolerance,
        max_regions=max_regions, min_area=min_area, split=split, radius_range=radius_range,
        split_sigmas=split_sigmas, split_delta=split_delta))


def _check_filter_options(reference, tolerance, max_regions, min_area=None, *, split=True,
                          radius_range=None, split_sigmas=SPLIT_SIGMAS,
                          split_delta=SPLIT_DELTA):
    """The region filter's options, checked before any work."""
    check_flag(split, "split")
    if radius_range is not None:
        if isinstance(radius_range, (str, bytes)) or not hasattr(radius_range, "__len__") \
                or len(radius_range) != 2:
            raise TypeError(f"radius_range must be None or two radii (pixels), e.g. (20, 130); "
                            f"got {radius_range!r}.")
        low, high = (check_real(r, "radius_range (pixels)", low=0.0, low_open=True)
                     for r in radius_range)
        if not low < high:
            raise ValueError(f"radius_range must be (smaller, larger); got {radius_range!r}.")
    if isinstance(split_sigmas, (str, bytes)) or not hasattr(split_sigmas, "__len__") \
            or not 1 <= len(split_sigmas) <= 16:
        raise TypeError(f"split_sigmas must be a sequence of 1 to 16 widths (pixels), e.g. "
                        f"(16, 64); got {split_sigmas!r}.")
    for sigma in split_sigmas:
        check_real(sigma, "split_sigmas (pixels)", low=0.0, high=1 << 20, low_open=True)
    check_real(split_delta, "split_delta (grey / 255)", low=0.0)
    reference = (REFERENCE_GREY if reference is None
                 else check_real(reference, "reference", low=0.0, high=1.0))
    tolerance = (REFERENCE_TOLERANCE if tolerance is None
                 else check_real(tolerance, "tolerance", low=0.0, low_open=True))
    if max_regions is not None:
        check_real(max_regions, "max_regions (a positive int or None)", low=1, integer=True)
    if min_area is not None:
        check_real(min_area, "min_area (pixels, or None)", low=0.0)
    return reference, tolerance


def _upsample_box(mask, shape, factor):
    """``_upsample_mask(mask, shape, factor)`` inside the bounding box of the
    mask only: (rows, cols) slices of the full image and the mask there."""
    h, w = mask.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return (slice(0, 0), slice(0, 0)), np.zeros((0, 0), bool)
    a, b, c, d = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # the last row and column of the grid also cover the image's uncovered edge
    R0, R1 = min(a * factor, shape[0]), (b * factor if b < h else shape[0])
    C0, C1 = min(c * factor, shape[1]), (d * factor if d < w else shape[1])
    R1, C1 = max(R0, min(R1, shape[0])), max(C0, min(C1, shape[1]))
    sub = mask[a:b, c:d]
    if R0 == R1 or C0 == C1:
        return (slice(R0, R1), slice(C0, C1)), np.zeros((R1 - R0, C1 - C0), bool)
    return (slice(R0, R1), slice(C0, C1)), _upsample_mask(sub, (R1 - R0, C1 - C0), factor)


def _iter_filter(grey_full, segments, *, reference=None, tolerance=None, max_regions=None,
                 min_area=None, split=True, radius_range=MASS_RADIUS_RANGE,
                 split_sigmas=SPLIT_SIGMAS, split_delta=SPLIT_DELTA):
    """:func:`filter_regions` of a grey image on [0, 1] as a job: "regions"
    records between the steps (a Cancel is seen soon on a large image)."""

    reference, tolerance = _check_filter_options(reference, tolerance, max_regions, min_area)
    H, W = grey_full.shape
    if isinstance(segments, (list, tuple)) and segments and np.ndim(segments[0]) == 2:
        labellings = [np.asarray(s) for s in segments]  # (np.ndim(segments) copies them all)
    else:
        segments = np.asarray(segments)
        labellings = [segments] if segments.ndim == 2 else list(segments)
    if not labellings or any(s.shape != grey_full.shape for s in labellings):
        raise ValueError(f"segments {[s.shape for s in labellings]} must match the image "
                         f"{grey_full.shape}.")
    if min_area is None:
        min_area = max(16, H * W // 4000)
    f = max(1, round(max(H, W) / _ANALYSIS_SIDE))
    grey = _block_mean(grey_full, f)
    h, w = grey.shape
    small = [s[f // 2 :: f, f // 2 :: f][:h, :w] for s in labellings]
    breast = small[0] > 0
    yield Progress("regions", 0.1, "candidate regions")
    cands = _candidates(grey, small, breast, split=split,
                        sigmas=[s / f for s in split_sigmas], delta=split_delta,
                        min_area=max(4, min_area // (f * f)))
    yield Progress("regions", 0.3, f"scoring {len(cands)} candidates")
    rows = []
    for n, (cc, i, sl, a) in enumerate(cands):
        if n % 64 == 63:
            yield Progress("regions", 0.3 + 0.3 * n / len(cands),
                           f"scoring candidates {n + 1}/{len(cands)}")
        req, (r0, r1, c0, c1), inside = _crop(cc, i, sl, a, (h, w))
        g = grey[r0:r1, c0:c1]
        mean = float(g[inside].mean())
        closeness = 1.0 - abs(mean - reference) / tolerance
        if closeness <= 0:
            continue
        ring = _ring(inside, req, breast[r0:r1, c0:c1])
        if ring.sum() < 4:
            continue
        contrast = mean - float(g[ring].mean())
        if contrast <= 0:
            continue
        (cr, ccol), compact = _centre_and_compactness(inside, req)
        score = contrast * closeness * compact
        if radius_range is not None:
            score *= _size_prior(req * f, *radius_range)
        rows.append((score, contrast, cc, i, (r0, r1, c0, c1), int(round(cr)) + r0,
                     int(round(ccol)) + c0))
    rows.sort(key=lambda t: -t[0])
    findings = _select(rows, max_regions)
    yield Progress("regions", 0.6, f"{len(findings)} regions at full resolution")
    # paint at full resolution, best first; measure there (inside each
    # region's box: the same pixels as on the whole image)
    labels = np.zeros((H, W), np.int32)
    first = labellings[0]
    out_rows = []
    for n, (score, contrast, mask) in enumerate(findings):
        box, sub = _upsample_box(mask, (H, W), f)
        m = sub & (first[box] > 0) & (labels[box] == 0)
        yield Progress("regions", 0.6 + 0.4 * (n + 1) / max(len(findings), 1),
                       f"region {n + 1}/{len(findings)}")
        if not m.any():
            continue
        mean = float(grey_full[box][m].mean())
        if abs(mean - reference) > tolerance:
            continue
        new = len(out_rows) + 1
        labels[box][m] = new
        rr, cl = np.nonzero(m)
        rr, cl = rr + box[0].start, cl + box[1].start
        out_rows.append((new, int(m.sum()), mean, float(contrast), int(rr.min()), int(cl.min()),
                         int(rr.max()) + 1, int(cl.max()) + 1, float(rr.mean()), float(cl.mean()),
                         float(score)))
    table = _empty_table()
    if out_rows:
        for k, col in zip(TABLE_COLUMNS, zip(*out_rows, strict=True), strict=True):
            table[k] = np.asarray(col, table[k].dtype)
    return MammogramROIs(labels, table)


def region_outlines(labels, *, tolerance=0.0):
    """Outline polygons of the regions of a label image.

    Parameters
    ----------
    labels : (H, W) array_like of int
        Regions 1..n (e.g. :func:`detect_mammogram_rois`'s labels), 0 elsewhere.
    tolerance : float, optional
        Simplify each outline (Douglas-Peucker,
        ``skimage.measure.approximate_polygon``) so that it stays within this
        many pixels of the contour; 0 keeps every vertex. A viewer draws a
        polygon of a few hundred vertices much faster than one of thousands
        (a 4096x4096 region's staircase contour).

    Returns
    -------
    list of (N, 2) ndarray
        One polygon of (row, col) vertices per region present, in label order:
        the longest contour of the region, on pixel centres, closed at the
        image edge; ready for a napari Shapes layer.

    Raises
    ------
    ValueError
        If ``tolerance`` is negative or not finite, or ``labels`` is not a
        non-empty 2-D array of labels >= 0.
    TypeError
        If ``labels`` is not integer (or bool), or ``tolerance`` not a number.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import region_outlines
    >>> labels = np.zeros((8, 8), int)
    >>> labels[2:5, 3:6] = 1
    >>> (outline,) = region_outlines(labels)
    >>> outline.min(axis=0).tolist(), outline.max(axis=0).tolist()
    ([1.5, 2.5], [4.5, 5.5])
    >>> (simple,) = region_outlines(labels, tolerance=1.0)
    >>> len(outline), len(simple)
    (13, 5)
    """
    from scipy import ndimage
    from skimage.measure import approximate_polygon, find_contours

    tolerance = check_real(tolerance, "tolerance (pixels)", low=0.0)
    labels = np.asarray(labels)
    if labels.dtype.kind not in "biu":
        raise TypeError(f"labels has dtype {labels.dtype}; pass integer labels (regions "
                        "1..n, 0 elsewhere).")
    if labels.ndim != 2 or labels.size == 0:
        raise ValueError(f"labels must be a non-empty (H, W) array; got shape {labels.shape}.")
    if labels.dtype.kind == "b":
        labels = labels.astype(np.int32)  # one region
    elif labels.size and labels.min() < 0:
        raise ValueError("labels must be >= 0 (regions 1..n, 0 elsewhere).")
    outlines = []
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        # one pixel of padding so regions touching the crop edge close
        inside = np.pad(labels[sl] == i, 1).astype(np.float32)
        contour = max(find_contours(inside, 0.5), key=len)
        if tolerance > 0:
            contour = approximate_polygon(contour, tolerance)
        outlines.append(contour + np.array([sl[0].start - 1, sl[1].start - 1]))
    return outlines


# Outline colours of the overlay, best region first (RGB): yellow, orange,
# magenta, cyan, then green for the rest.
_OVERLAY_COLOURS = ((255, 255, 0), (255, 140, 0), (255, 0, 255), (0, 255, 255), (0, 255, 0))


def roi_overlay(image, labels, *, width=None, channel_axis=-1):
    """The mammogram in grey with each region's outline drawn in colour, as an
    8-bit RGB image a person can open (a label image looks black in an image
    viewer).

    Parameters
    ----------
    image : (H, W) array_like
        The mammogram (any numeric dtype; read as :func:`detect_mammogram_rois`
        reads it: 12-bit in a 16-bit container scaled by 4095); an RGB(A)
        export of one, with ``channel_axis``, is shown as its luminance.
    labels : (H, W) array_like of int
        Regions 1..n best first (:func:`detect_mammogram_rois`'s labels).
    width : int, optional
        Outline width in pixels; default about 1/400 of the long side, at
        least 1.
    channel_axis : int or None, optional
        The colour axis of an RGB(A) export; a 2-D image is grey.

    Returns
    -------
    (H, W, 3) ndarray of uint8
        Region 1 in yellow, 2 orange, 3 magenta, 4 cyan, the rest green.

    Raises
    ------
    ValueError
        If ``labels`` is not the image's (H, W), or the image is constant.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import roi_overlay
    >>> image = np.linspace(0, 1, 64 * 64).reshape(64, 64)
    >>> labels = np.zeros((64, 64), np.int32)
    >>> labels[20:40, 20:40] = 1
    >>> rgb = roi_overlay(image, labels, width=1)
    >>> rgb.shape, rgb.dtype, rgb[20, 30].tolist(), bool(rgb[30, 30, 0] == rgb[30, 30, 2])
    ((64, 64, 3), dtype('uint8'), [255, 255, 0], True)
    """
    from scipy import ndimage

    grey = _grey01(_as_grey(image, channel_axis), name="mammogram")
    labels = np.asarray(labels)
    if labels.shape != grey.shape or labels.dtype.kind not in "biu":
        raise ValueError(f"labels must be an integer (H, W) image like the mammogram "
                         f"{grey.shape}; got {labels.dtype} {labels.shape}.")
    if width is None:
        width = max(1, round(max(grey.shape) / 400))
    width = int(check_real(width, "width (pixels)", low=1, high=1000, integer=True))
    lo, hi = float(grey.min()), float(grey.max())
    rgb = np.repeat(np.round(255.0 * (grey - lo) / (hi - lo)).astype(np.uint8)[..., None], 3, 2)
    # a region's edge: its pixels with a 4-neighbour outside it, grown inwards to ``width``
    edge = np.zeros(labels.shape, np.int64)
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        grow = [slice(max(0, s.start - 1), s.stop + 1) for s in sl]
        inside = labels[tuple(grow)] == i
        ring = inside & ~ndimage.binary_erosion(inside, iterations=width, border_value=0)
        target = edge[tuple(grow)]
        target[ring & (target == 0)] = i
    for i, colour in enumerate(_OVERLAY_COLOURS, start=1):
        last = i == len(_OVERLAY_COLOURS)
        rgb[(edge >= i) if last else (edge == i)] = colour
    return rgb
