"""Mammogram breast area and regions of interest (SPEC section 3.1).

:func:`detect_breast` finds the breast (background, labels, markers, film
edges and the pectoral muscle removed) with a few documented heuristics;
:func:`detect_mammogram_rois` runs the unsupervised CAR texture segmentation
(SPEC 3) on the pseudo-colour mammogram ``[Y, Y^0.5, Y^2]`` restricted to the
breast, then keeps the regions whose mean grey level is close to the median
mean grey level of ground-truth mass regions (the learned ``reference``).
:func:`iter_detect_mammogram_rois` does the same and yields progress.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float

__all__ = [
    "DEFAULT_MAX_REGIONS",
    "DEFAULT_POOL_SEGMENTS",
    "MASS_RADIUS_RANGE",
    "REFERENCE_GREY",
    "REFERENCE_TOLERANCE",
    "TABLE_COLUMNS",
    "detect_breast",
    "detect_mammogram_rois",
    "filter_regions",
    "iter_detect_mammogram_rois",
    "iter_segment_breast",
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
# Segmentations pooled by :func:`detect_mammogram_rois`: the merge history's
# states with these numbers of segments (one CAR segmentation, SPEC 3.6).
DEFAULT_POOL_SEGMENTS = (8, 10, 12)
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

_WORK_SIDE = 256  # breast detection resolution (longest side, pixels)


# --- breast area --------------------------------------------------------------


def _grey01(image, name="image"):
    """(H, W) float64 grey image scaled like img_as_float; clear errors."""
    data = as_channel_last_float(image, channel_axis=None, name=name)[..., 0]
    lo, hi = float(data.min()), float(data.max())
    if hi <= lo:
        raise ValueError(
            f"{name} is constant (every pixel is {lo:g}): there is no breast to find. "
            "Pass a mammogram with visible tissue."
        )
    return data


def _as_grey(image, channel_axis):
    """A colour export of a grey mammogram (``channel_axis`` given) as the
    luminance in [0, 1]; a grey image unchanged."""
    if channel_axis is None:
        return image
    from skimage.color import rgb2gray

    return rgb2gray(np.moveaxis(np.asarray(image), channel_axis, -1)[..., :3])


def _block_mean(data, factor):
    """Downsample by an integer factor (block mean, edges cropped)."""
    if factor <= 1:
        return data
    h, w = (data.shape[0] // factor) * factor, (data.shape[1] // factor) * factor
    return data[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


def _upsample_mask(small, shape, factor):
    """Nearest-neighbour upsampling of a mask to ``shape`` (edges padded)."""
    big = np.repeat(np.repeat(small, factor, axis=0), factor, axis=1)
    out = np.zeros(shape, bool)
    h, w = min(shape[0], big.shape[0]), min(shape[1], big.shape[1])
    out[:h, :w] = big[:h, :w]
    if h < shape[0]:
        out[h:, :w] = out[h - 1 : h, :w]
    if w < shape[1]:
        out[:, w:] = out[:, w - 1 : w]
    return out


def _largest_component(mask):
    from scipy import ndimage

    lab, n = ndimage.label(mask)
    if n == 0:
        return mask
    sizes = np.bincount(lab.ravel())
    sizes[0] = 0
    return lab == sizes.argmax()


def chest_wall_side(mask):
    """'left' or 'right': the side of the breast mask's straight chest wall.

    The breast is widest at the chest wall and tapers to the nipple, so the
    tenth of the mask's bounding box on the chest-wall side holds more mask
    pixels than the tenth on the nipple side.
    """
    cols = np.flatnonzero(mask.any(axis=0))
    if cols.size == 0:
        return "left"
    c0, c1 = cols[0], cols[-1] + 1
    band = max(1, (c1 - c0) // 10)
    left = mask[:, c0 : c0 + band].sum()
    right = mask[:, c1 - band : c1].sum()
    return "right" if right > left else "left"


def _pectoral(grey, breast):
    """Pectoral muscle mask on a breast whose chest wall is on the LEFT.

    Heuristic (mini-MIAS MLO views): the muscle is a bright, roughly
    triangular region in the top corner on the chest-wall side, bounded by a
    nearly straight edge.

    1. Seed level ``s``: median grey of the breast in its top rows (first 3 %
       of the breast height), leftmost 15 % of the breast width, ignoring
       pixels darker than the breast median (the film edge). Breast level
       ``m``: median grey of the whole breast. No muscle unless ``s > m``.
    2. Candidate: breast pixels brighter than ``m + 0.5 (s - m)``, connected
       to the seed (after a small opening).
    3. Each row's extent from the breast's left edge (skipping the dark film
       edge, up to 6 pixels) along the candidate is
       measured until the first row without one; a Theil-Sen line
       ``col = a + b row`` (robust to leaks into dense tissue) is fitted to
       those extents, and the muscle is the breast left of the line.
    4. Rejected (no muscle: CC view or an invisible muscle) unless the line
       slopes inwards (``b < -0.1``), the muscle is brighter than the breast
       band just right of the line, and it covers 1 % to 35 % of the breast.
    """
    from scipy import ndimage
    from scipy.stats import theilslopes

    h, w = grey.shape
    none = np.zeros_like(breast)
    rows = np.flatnonzero(breast.any(axis=1))
    if rows.size < 16:
        return none
    top, bottom = rows[0], rows[-1] + 1
    height = bottom - top
    lefts = np.full(h, -1)
    widths = np.zeros(h, int)
    for r in rows:
        cs = np.flatnonzero(breast[r])
        lefts[r], widths[r] = cs[0], cs[-1] + 1 - cs[0]
    seed = np.zeros_like(breast)
    for r in range(top, top + max(2, height * 3 // 100)):
        if lefts[r] >= 0:
            seed[r, lefts[r] : lefts[r] + max(2, widths[r] * 15 // 100)] = True
    seed &= breast & (grey > np.median(grey[breast]))  # not the dark film edge
    if seed.sum() < 3:
        return none
    s = float(np.median(grey[seed]))
    m = float(np.median(grey[breast]))
    if s <= m:
        return none
    cand = breast & (grey > m + 0.5 * (s - m))
    cand = ndimage.binary_opening(cand, iterations=1)
    lab, _n = ndimage.label(cand)
    ids = np.unique(lab[seed & cand])
    ids = ids[ids > 0]
    if ids.size == 0:
        return none
    comp = ndimage.binary_fill_holes(np.isin(lab, ids))
    rr, ext = [], []
    for r in range(top, bottom):
        left = lefts[r]
        # the film edge along the chest wall is a dark strip a few pixels wide
        start = np.flatnonzero(comp[r, left : left + 6]) if left >= 0 else []
        if len(start) == 0:
            if rr:
                break
            continue
        left += start[0]
        run = comp[r, left:]
        stop = np.flatnonzero(~run)
        rr.append(r)
        ext.append(left + (stop[0] if stop.size else run.size))
    if len(rr) < max(5, height // 20):
        return none
    rr, ext = np.array(rr, float), np.array(ext, float)
    b, a, _, _ = theilslopes(ext, rr)
    if b > -0.1:
        return none
    R, C = np.mgrid[0:h, 0:w]
    pect = breast & (C < a + b * R)
    frac = pect.sum() / max(breast.sum(), 1)
    if not 0.01 <= frac <= 0.35:
        return none
    band = breast & ~pect & (C < a + b * R + 0.1 * w)
    if band.sum() < 10 or grey[pect].mean() <= grey[band].mean():
        return none
    return pect


def detect_breast(image, *, pectoral=True, return_details=False):
    """Mask of the breast in a mammogram.

    Heuristics (all at a working resolution of about 256 pixels on the long
    side, so the call takes a few tens of milliseconds):

    1. The image is scaled to [0, 1] and smoothed (Gaussian, 1 pixel).
    2. Background threshold ``t = b + 0.08 (p99 - b)`` where ``b`` is the
       5th percentile (the black film/pad) and ``p99`` the 99th percentile:
       low enough to keep the dim skin line, above film grain.
    3. A binary opening (3 iterations) cuts thin bridges to labels, tape and
       film-edge strips; the largest connected component is the breast;
       holes are filled.
    4. The chest-wall side is the side where the mask is widest
       (:func:`chest_wall_side`); the image is mirrored so it is on the left.
    5. Pectoral muscle (``pectoral=True``): see :func:`_pectoral`; it is
       removed when found (MLO views), nothing is removed otherwise.

    Parameters
    ----------
    image : (H, W) array
        Grey mammogram, any numeric dtype.
    pectoral : bool, optional
        Remove the pectoral muscle.
    return_details : bool, optional
        Also return a dict with ``side`` ('left'/'right': the chest wall),
        ``pectoral`` (full-resolution mask of the removed muscle) and
        ``threshold``.

    Returns
    -------
    mask : (H, W) ndarray of bool
        True on the breast.

    Raises
    ------
    ValueError
        If the image is constant (e.g. all black) or no breast is found.
    """
    from scipy import ndimage

    grey = _grey01(image)
    H, W = grey.shape
    factor = max(1, round(max(H, W) / _WORK_SIDE))
    small = _block_mean(grey, factor)
    smooth = ndimage.gaussian_filter(small, 1.0)
    b, p99 = np.percentile(smooth, [5, 99])
    if p99 <= b:
        raise ValueError(
            "image has almost no contrast (5th and 99th percentiles are equal): "
            "no breast found. Pass a mammogram with visible tissue."
        )
    t = b + 0.08 * (p99 - b)
    mask = smooth > t
    mask = ndimage.binary_opening(mask, iterations=3)
    mask = _largest_component(mask)
    mask = ndimage.binary_fill_holes(mask)
    if mask.sum() < 0.01 * mask.size:
        raise ValueError(
            "no breast found: the bright area is under 1 % of the image. "
            "Pass a mammogram (bright = dense tissue)."
        )
    side = chest_wall_side(mask)
    pect = np.zeros_like(mask)
    if pectoral:
        flip = side == "right"
        g = smooth[:, ::-1] if flip else smooth
        m = mask[:, ::-1] if flip else mask
        pect = _pectoral(g, m)
        if flip:
            pect = pect[:, ::-1]
        mask = mask & ~pect
        mask = _largest_component(mask)
    full = _upsample_mask(mask, (H, W), factor)
    if return_details:
        return full, {
            "side": side,
            "pectoral": _upsample_mask(pect, (H, W), factor),
            "threshold": float(t),
        }
    return full


# --- regions of interest (SPEC 3.1) --------------------------------------------


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


def iter_segment_breast(image, *, breast=None, n_segments=None, levels=3, neighbourhood=2,
                        n_init=16, work_side=512, seed=0, pool=None, **segment_kwargs):
    """Texture segmentation of the breast only; yields progress, then labels.

    The mammogram is block-averaged to about ``work_side`` pixels on its long
    side, cropped to the breast's bounding box, turned into pseudo-colour
    ``[Y, Y^0.5, Y^2]`` and segmented by :func:`car_napari.segmentation.
    iter_segment` with ``mask`` = breast. Yields floats in [0, 1], then a
    dict with ``segments`` ((H, W) int32 at full resolution, 0 outside the
    breast), ``breast`` (full-resolution mask) and ``factor``. With ``pool``
    (numbers of segments), the dict also has ``pooled``: one full-resolution
    labelling per number, read from the same run's merge history
    (``SegmentationResult.labels_at``), no extra segmentation.
    """
    from ..segmentation import SegmentationResult, iter_segment, pseudo_colour

    grey = _grey01(image, name="mammogram")
    H, W = grey.shape
    if breast is None:
        breast = detect_breast(grey)
    breast = np.asarray(breast, bool)
    if breast.shape != (H, W) or not breast.any():
        raise ValueError("breast must be an (H, W) mask like the mammogram with some True pixels.")
    yield 0.02
    factor = max(1, round(max(H, W) / work_side))
    small = _block_mean(grey, factor)
    small_mask = _block_mean(breast.astype(float), factor) > 0.5
    if not small_mask.any():
        small_mask = _block_mean(breast.astype(float), factor) > 0
    need = (2 ** (levels - 1)) * 32
    (r0, r1), (c0, c1) = _crop_box(small_mask, need)
    crop, crop_mask = small[r0:r1, c0:c1], small_mask[r0:r1, c0:c1]
    result = None
    for state in iter_segment(pseudo_colour(crop), n_segments=n_segments, levels=levels,
                              neighbourhood=neighbourhood, n_init=n_init, mask=crop_mask,
                              seed=seed, **segment_kwargs):
        if isinstance(state, SegmentationResult):
            result = state
        else:
            yield 0.05 + 0.85 * float(state.fraction)

    def to_full(seg):
        seg = np.asarray(seg, np.int32)
        seg[~crop_mask] = 0
        big = np.repeat(np.repeat(seg, factor, axis=0), factor, axis=1)
        out = np.zeros((H, W), np.int32)
        R0, C0 = r0 * factor, c0 * factor
        hh, ww = min(big.shape[0], H - R0), min(big.shape[1], W - C0)
        out[R0 : R0 + hh, C0 : C0 + ww] = big[:hh, :ww]
        out[~breast] = 0
        return out

    segments = to_full(result.labels)
    out = {"segments": segments, "breast": breast, "factor": factor}
    if pool:
        out["pooled"] = [to_full(result.labels_at(int(k))) for k in pool]
    yield 0.9
    yield out


TABLE_COLUMNS = ("label", "area", "mean_grey", "contrast", "bbox_min_row", "bbox_min_col",
                 "bbox_max_row", "bbox_max_col", "centroid_row", "centroid_col", "score")


def _empty_table():
    return {k: np.zeros(0, np.int64 if k.startswith(("label", "area", "bbox")) else np.float64)
            for k in TABLE_COLUMNS}


def _size_prior(radius, lo, hi):
    """Log-normal weight of an equivalent radius: 1 at sqrt(lo*hi)."""
    centre, spread = np.log(np.sqrt(lo * hi)), 0.5 * np.log(hi / lo)
    return float(np.exp(-0.5 * ((np.log(radius) - centre) / spread) ** 2))


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
                   split_sigmas=SPLIT_SIGMAS, split_delta=SPLIT_DELTA):
    """SPEC 3.1's grey-level filter on a segmentation of the breast.

    ``segments`` is one (H, W) labelling (0 outside the breast) or a list of
    them (e.g. several states of one merge history, pooled). The analysis
    runs on a grid of about 256 pixels on the long side (block mean).

    Candidates: every 4-connected component (after a one-pixel opening) of
    every segment; with ``split`` (default) also the components of each
    segment restricted to its locally bright pixels (brighter than a
    Gaussian background of width ``split_sigmas`` full-resolution pixels
    by ``split_delta``): CAR segments of mammograms are density bands much
    larger than most masses, and this cuts them into mass-sized pieces.
    Candidates smaller than ``min_area`` full-resolution pixels (default
    1/4000 of the image) are dropped, and so are those whose mean grey (the
    image scaled to [0, 1] like ``img_as_float``) is further than
    ``tolerance`` from ``reference`` (SPEC 3.1).

    Score: ``contrast`` (mean grey minus the mean of the breast in a ring
    half the equivalent radius wide; candidates not brighter than their ring
    are dropped) times ``1 - |mean - reference| / tolerance`` times the
    compactness (fraction of the candidate inside the equal-area disc at
    its centroid) times a log-normal size prior on the equivalent radius
    (``radius_range`` full-resolution pixels, None: no prior). Candidates
    are taken best first, skipping any whose centroid lies in an already
    kept one or that holds a kept one's centroid; with ``max_regions`` only
    that many are kept. With ``split=False, radius_range=None`` and a single
    labelling this is close to the former behaviour (plus the opening and
    the compactness factor).

    Returns
    -------
    labels : (H, W) ndarray of int32
        Kept regions numbered 1..n by decreasing score, 0 elsewhere (a
        pixel claimed by two kept regions goes to the better one).
    table : dict of equal-length 1-D arrays
        Columns ``TABLE_COLUMNS``, measured on ``labels`` at full resolution
        (``label`` matches ``labels``; bounding box ``max`` ends are
        exclusive; areas in pixels; centroid as (row, col)); ``contrast``
        and ``score`` come from the analysis grid. A napari features table
        and ``csv.writer`` take it.
    """
    from scipy import ndimage

    reference = REFERENCE_GREY if reference is None else float(reference)
    tolerance = REFERENCE_TOLERANCE if tolerance is None else float(tolerance)
    if tolerance <= 0:
        raise ValueError(f"tolerance must be positive; got {tolerance}.")
    if max_regions is not None and (int(max_regions) != max_regions or max_regions < 1):
        raise ValueError(f"max_regions must be a positive int or None; got {max_regions!r}.")
    grey_full = _grey01(image, name="mammogram")
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
        for k, col in zip(TABLE_COLUMNS, zip(*out_rows)):
            table[k] = np.asarray(col, table[k].dtype)
    return labels, table


def region_outlines(labels):
    """Outline polygons of regions 1..n of ``labels``: a list of (N, 2)
    arrays of (row, col) vertices in label order (the longest contour of each
    region, on pixel centres, ready for a napari Shapes layer)."""
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


def iter_detect_mammogram_rois(image, *, reference=None, tolerance=None, levels=3,
                               n_segments=None, neighbourhood=2, n_init=16,
                               max_regions=DEFAULT_MAX_REGIONS, min_area=None, breast=None,
                               work_side=512, seed=0, pool=DEFAULT_POOL_SEGMENTS, split=True,
                               channel_axis=None):
    """:func:`detect_mammogram_rois` as a generator: yields progress floats in
    [0, 1], then the ``(labels, table)`` tuple."""
    image = _as_grey(image, channel_axis)
    out = None
    pool = None if n_segments is not None else pool
    for step in iter_segment_breast(image, breast=breast, n_segments=n_segments, levels=levels,
                                    neighbourhood=neighbourhood, n_init=n_init,
                                    work_side=work_side, seed=seed, pool=pool):
        if isinstance(step, dict):
            out = step
        else:
            yield step
    labels, table = filter_regions(image, out.get("pooled") or out["segments"],
                                   reference=reference, tolerance=tolerance,
                                   max_regions=max_regions, min_area=min_area, split=split)
    yield 1.0
    yield labels, table


def detect_mammogram_rois(image, *, reference=None, tolerance=None, levels=3, n_segments=None,
                          neighbourhood=2, n_init=16, max_regions=DEFAULT_MAX_REGIONS,
                          min_area=None, breast=None, work_side=512, seed=0,
                          pool=DEFAULT_POOL_SEGMENTS, split=True, channel_axis=None):
    """Regions of interest (candidate masses) in a mammogram (SPEC 3.1).

    1. Breast area: :func:`detect_breast` (or ``breast`` if given).
    2. The mammogram is block-averaged to about ``work_side`` pixels (512:
       factor 2 for mini-MIAS 1024x1024), cropped to the breast, and
       segmented (SPEC 3: multiresolution 3DCAR features, EM and KL merging)
       as pseudo-colour ``[Y, Y^0.5, Y^2]`` with the breast as mask. Unless
       ``n_segments`` is given, the merge-history states with ``pool``
       segments (default 8, 10 and 12) are all used; segments are mapped
       back to full resolution.
    3. :func:`filter_regions`: candidate regions (segment components, and
       with ``split`` their locally bright parts) whose mean grey is within
       ``tolerance`` of ``reference`` (learned: the median mean grey of
       ground-truth mass regions), ranked by contrast with their ring,
       closeness to ``reference``, compactness and a mass-size prior; the
       best ``max_regions`` are kept (None: all).

    See ``benchmarks/bench_mammography.py`` for the measured sensitivity on
    mini-MIAS; with 13 mass findings in all it is a rough figure.

    Parameters
    ----------
    image : (H, W) array
        Grey mammogram (bright = dense), any numeric dtype; integer images are
        scaled by their dtype range, so ``reference`` is on that [0, 1] scale.
    reference : float, optional
        Reference grey level; default :data:`REFERENCE_GREY`.
    tolerance : float, optional
        Accepted distance from ``reference``; default
        :data:`REFERENCE_TOLERANCE`.
    levels, n_segments, neighbourhood, n_init :
        Passed to :func:`car_napari.segmentation.segment`.
    pool : sequence of int, optional
        Numbers of segments read from the merge history and pooled (used
        when ``n_segments`` is None; None or () uses the automatic one).
    split : bool, optional
        Also cut segments into their locally bright parts
        (:func:`filter_regions`).
    channel_axis : int or None, optional
        The colour axis of an RGB export of a grey mammogram (its luminance
        is used); None (default) for a grey image.
    max_regions : int or None, optional
        Keep only the best-scoring regions (default
        :data:`DEFAULT_MAX_REGIONS`).
    min_area : int, optional
        Smallest region (full-resolution pixels).

    Returns
    -------
    labels : (H, W) ndarray of int32
        Regions 1..n by decreasing score, 0 elsewhere.
    table : dict of 1-D arrays
        See :func:`filter_regions`.
    """
    result = None
    for step in iter_detect_mammogram_rois(
        image, reference=reference, tolerance=tolerance, levels=levels, n_segments=n_segments,
        neighbourhood=neighbourhood, n_init=n_init, max_regions=max_regions, min_area=min_area,
        breast=breast, work_side=work_side, seed=seed, pool=pool, split=split,
        channel_axis=channel_axis,
    ):
        if isinstance(step, tuple):
            result = step
    return result
