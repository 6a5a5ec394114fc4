"""Candidate regions of interest on a segmentation of the breast, the
grey-level filter that keeps mass-like ones (section 14.4,
docs/mammography.md), and their outlines."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

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
    >>> image = np.full((64, 64), 0.3)
    >>> segments = np.ones((64, 64), np.int32)
    >>> image[20:40, 20:40], segments[20:40, 20:40] = 0.66, 2
    >>> labels, table = filter_regions(image, segments, max_regions=None)
    >>> int(labels.max()), table["label"].tolist()
    (1, [1])
    """

    labels: np.ndarray
    table: dict


def _candidates(grey, labellings, breast, *, split, sigmas, delta, min_area):
    """Candidate regions on the analysis grid: (mask, area) pairs.

    For every labelling and every segment value: the 4-connected components
    of the segment after a one-pixel opening; with ``split``, also the
    components of (segment AND locally bright), locally bright meaning
    brighter than a breast-normalised Gaussian background of width ``sigma``
    by ``delta``, for each ``sigma``.
    """
    from scipy import ndimage

    cross = ndimage.generate_binary_structure(2, 1)
    brights = []
    if split:
        b = breast.astype(float)
        fine = ndimage.gaussian_filter(grey, 1.0)
        for sigma in sigmas:
            bg = ndimage.gaussian_filter(grey * b, sigma) / np.maximum(
                ndimage.gaussian_filter(b, sigma), 1e-6)
            brights.append(fine - bg > delta)
    out = []
    for lab in labellings:
        for v in np.unique(lab):
            if v == 0:
                continue
            seg = lab == v
            for extra in [None] + brights:
                m = seg if extra is None else seg & extra
                m = ndimage.binary_opening(m, structure=cross, iterations=1)
                cc, k = ndimage.label(m)
                if k == 0:
                    continue
                sizes = np.bincount(cc.ravel())
                for i, sl in enumerate(ndimage.find_objects(cc), start=1):
                    if sizes[i] >= min_area:
                        out.append((cc, i, sl, int(sizes[i])))
    return out


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
    Candidates are taken best first, skipping any whose centroid lies in an
    already kept one or that holds a kept one's centroid; with
    ``max_regions`` only that many are kept. With ``split=False,
    radius_range=None`` and a single labelling this is close to the former
    behaviour (plus the opening and the compactness factor).

    Parameters
    ----------
    image : (H, W) array_like
        Grey mammogram (bright = dense), any numeric dtype; an RGB(A) export
        of one, with ``channel_axis``, is reduced to its luminance.
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
        If ``tolerance`` or ``max_regions`` is out of range, the image is
        constant, or a labelling's shape differs from the image's.

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
    from scipy import ndimage

    reference = REFERENCE_GREY if reference is None else float(reference)
    tolerance = REFERENCE_TOLERANCE if tolerance is None else float(tolerance)
    if tolerance <= 0:
        raise ValueError(f"tolerance must be positive; got {tolerance}.")
    if max_regions is not None and (int(max_regions) != max_regions or max_regions < 1):
        raise ValueError(f"max_regions must be a positive int or None; got {max_regions!r}.")
    grey_full = _grey01(_as_grey(image, channel_axis), name="mammogram")
    H, W = grey_full.shape
    labellings = [np.asarray(segments)] if np.ndim(segments) == 2 else [
        np.asarray(s) for s in segments]
    if not labellings or any(s.shape != grey_full.shape for s in labellings):
        raise ValueError(f"segments {[s.shape for s in labellings]} must match the image "
                         f"{grey_full.shape}.")
    if min_area is None:
        min_area = max(16, H * W // 4000)
    f = max(1, round(max(H, W) / _ANALYSIS_SIDE))
    grey = _block_mean(grey_full, f)
    h, w = grey.shape
    small = [s[f // 2 :: f, f // 2 :: f][:h, :w] for s in labellings]
    breast_full = labellings[0] > 0
    breast = small[0] > 0
    cands = _candidates(grey, small, breast, split=split,
                        sigmas=[s / f for s in split_sigmas], delta=split_delta,
                        min_area=max(4, min_area // (f * f)))
    rows = []
    for cc, i, sl, a in cands:
        req = np.sqrt(a / np.pi)
        width = max(2, round(0.5 * req))
        r0, r1 = max(0, sl[0].start - width), min(h, sl[0].stop + width)
        c0, c1 = max(0, sl[1].start - width), min(w, sl[1].stop + width)
        inside = cc[r0:r1, c0:c1] == i
        g = grey[r0:r1, c0:c1]
        mean = float(g[inside].mean())
        closeness = 1.0 - abs(mean - reference) / tolerance
        if closeness <= 0:
            continue
        ring = ndimage.binary_dilation(inside, iterations=width) & ~inside & breast[r0:r1, c0:c1]
        if ring.sum() < 4:
            continue
        contrast = mean - float(g[ring].mean())
        if contrast <= 0:
            continue
        rr, cl = np.nonzero(inside)
        cr, ccol = rr.mean(), cl.mean()
        compact = float(np.mean((rr - cr) ** 2 + (cl - ccol) ** 2 <= req**2))
        score = contrast * closeness * compact
        if radius_range is not None:
            score *= _size_prior(req * f, *radius_range)
        rows.append((score, contrast, cc, i, (r0, r1, c0, c1), int(round(cr)) + r0,
                     int(round(ccol)) + c0))
    rows.sort(key=lambda t: -t[0])
    kept = []
    for t in rows:
        _, _, cc, i, (r0, r1, c0, c1), cr, ccol = t
        clash = False
        for k in kept:
            kc, ki, (k0, k1, kc0, kc1) = k[2], k[3], k[4]
            if k0 <= cr < k1 and kc0 <= ccol < kc1 and kc[cr, ccol] == ki:
                clash = True
                break
            if r0 <= k[5] < r1 and c0 <= k[6] < c1 and cc[k[5], k[6]] == i:
                clash = True
                break
        if clash:
            continue
        kept.append(t)
        if max_regions is not None and len(kept) >= int(max_regions):
            break
    # paint at full resolution, best first; measure there
    labels = np.zeros((H, W), np.int32)
    out_rows = []
    for t in kept:
        score, contrast, cc, i = t[:4]
        m = _upsample_mask(cc == i, (H, W), f) & breast_full & (labels == 0)
        if not m.any():
            continue
        mean = float(grey_full[m].mean())
        if abs(mean - reference) > tolerance:
            continue
        new = len(out_rows) + 1
        labels[m] = new
        rr, cl = np.nonzero(m)
        out_rows.append((new, int(m.sum()), mean, float(contrast), int(rr.min()), int(cl.min()),
                         int(rr.max()) + 1, int(cl.max()) + 1, float(rr.mean()), float(cl.mean()),
                         float(score)))
    table = _empty_table()
    if out_rows:
        for k, col in zip(TABLE_COLUMNS, zip(*out_rows, strict=True), strict=True):
            table[k] = np.asarray(col, table[k].dtype)
    return MammogramROIs(labels, table)


def region_outlines(labels):
    """Outline polygons of the regions of a label image.

    Parameters
    ----------
    labels : (H, W) array_like of int
        Regions 1..n (e.g. :func:`detect_mammogram_rois`'s labels), 0 elsewhere.

    Returns
    -------
    list of (N, 2) ndarray
        One polygon of (row, col) vertices per region present, in label order:
        the longest contour of the region, on pixel centres, closed at the
        image edge; ready for a napari Shapes layer.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import region_outlines
    >>> labels = np.zeros((8, 8), int)
    >>> labels[2:5, 3:6] = 1
    >>> (outline,) = region_outlines(labels)
    >>> outline.min(axis=0).tolist(), outline.max(axis=0).tolist()
    ([1.5, 2.5], [4.5, 5.5])
    """
    from scipy import ndimage
    from skimage.measure import find_contours

    labels = np.asarray(labels)
    outlines = []
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        # one pixel of padding so regions touching the crop edge close
        inside = np.pad(labels[sl] == i, 1).astype(np.float32)
        contour = max(find_contours(inside, 0.5), key=len)
        outlines.append(contour + np.array([sl[0].start - 1, sl[1].start - 1]))
    return outlines
