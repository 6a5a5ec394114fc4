"""The breast area of a mammogram: background, labels, markers and film edges
removed, and the pectoral muscle of MLO views (section 14.4,
docs/mammography.md)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._progress import Progress, drain
from ._images import _as_grey, _block_mean, _grey01, _upsample_mask

__all__ = ["BreastDetection", "detect_breast"]

_WORK_SIDE = 256  # breast detection resolution (longest side, pixels)
_MIN_WORK_SIDE = 16  # a thinner strip has no breast shape to find
# Scanned films carry bright strips along the image's borders (the scanner's
# edge, the film's rim) that touch the breast: a band of this fraction of the
# long side along every border is never breast (about 12 pixels of an
# 800-pixel film; a mass there is cut off the film anyway).
_BORDER = 0.015
# The pectoral muscle (:func:`_pectoral`): its candidate pixels are brighter
# than the breast median by this fraction of the seed's excess, and it covers
# at most this share of the breast (written for mini-MIAS).
PECTORAL_LEVEL = 0.5
PECTORAL_MAX_SHARE = 0.35


class BreastDetection(NamedTuple):
    """The breast mask and how it was found; unpacks as ``mask, details``.

    What ``detect_breast(..., return_details=True)`` returns.

    Parameters
    ----------
    mask : (H, W) ndarray of bool
        True on the breast.
    details : dict
        ``side`` ('left' or 'right': the chest wall), ``pectoral`` (the
        full-resolution mask of the removed muscle, all False when none was
        found) and ``threshold`` (the background threshold, on [0, 1]).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import detect_breast
    >>> image = np.zeros((128, 128))
    >>> image[16:112, :60] = 0.7
    >>> mask, details = detect_breast(image, return_details=True)
    >>> details["side"]
    'left'
    """

    mask: np.ndarray
    details: dict


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


def _theil_sen(y, x):
    """Theil-Sen line ``y = a + b x``: the slope and intercept of
    ``scipy.stats.theilslopes(y, x)`` (its 'separate' intercept), without
    importing scipy.stats (seconds, holding the GIL, on a job's first run)."""
    dx = x[:, np.newaxis] - x
    dy = y[:, np.newaxis] - y
    slopes = dy[dx > 0] / dx[dx > 0]
    slopes.sort()
    b = np.median(slopes)
    return b, np.median(y) - b * np.median(x)


def _pectoral(grey, breast, *, level=PECTORAL_LEVEL, max_share=PECTORAL_MAX_SHARE):
    """Pectoral muscle mask on a breast whose chest wall is on the LEFT.

    Heuristic (mini-MIAS MLO views): the muscle is a bright, roughly
    triangular region in the top corner on the chest-wall side, bounded by a
    nearly straight edge.

    1. Seed level ``s``: median grey of the breast in its top rows (first 3 %
       of the breast height), leftmost 15 % of the breast width, ignoring
       pixels darker than the breast median (the film edge). Breast level
       ``m``: median grey of the whole breast. No muscle unless ``s > m``.
    2. Candidate: breast pixels brighter than ``m + level (s - m)``,
       connected to the seed (after a small opening).
    3. Each row's extent from the breast's left edge (skipping the dark film
       edge, up to 6 pixels) along the candidate is
       measured until the first row without one; a Theil-Sen line
       ``col = a + b row`` (robust to leaks into dense tissue) is fitted to
       those extents, and the muscle is the breast left of the line.
    4. Rejected (no muscle: CC view or an invisible muscle) unless the line
       slopes inwards (``b < -0.1``), the muscle is brighter than the breast
       band just right of the line, and it covers 1 % to ``max_share`` of
       the breast.

    ``level`` may be a sequence of levels: of their accepted cuts, the one
    whose edge has the largest step (:func:`_edge_step`) is kept.
    """
    from scipy import ndimage

    h, w = grey.shape
    none = np.zeros_like(breast)
    if np.ndim(level):
        cuts = [_pectoral(grey, breast, level=v, max_share=max_share) for v in level]
        cuts = [c for c in cuts if c.any()]
        return max(cuts, key=lambda c: _edge_step(grey, breast, c)) if cuts else none
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
    cand = breast & (grey > m + level * (s - m))
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
    b, a = _theil_sen(ext, rr)
    if b > -0.1:
        return none
    R, C = np.mgrid[0:h, 0:w]
    pect = breast & (C < a + b * R)
    frac = pect.sum() / max(breast.sum(), 1)
    if not 0.01 <= frac <= max_share:
        return none
    band = breast & ~pect & (C < a + b * R + 0.1 * w)
    if band.sum() < 10 or grey[pect].mean() <= grey[band].mean():
        return none
    return pect


def _edge_step(grey, breast, pect, width=3):
    """Mean grey of the muscle's pixels within ``width`` pixels left of its
    inner edge minus that of the breast's pixels within ``width`` pixels right
    of it (rows: the muscle's edge runs down and inwards from the top)."""
    inside = np.zeros_like(pect)
    outside = np.zeros_like(pect)
    rest = breast & ~pect
    for k in range(1, width + 1):
        outside[:, k:] |= pect[:, :-k]
        inside[:, :-k] |= rest[:, k:]
    inside &= pect
    outside &= rest
    if not (inside.any() and outside.any()):
        return -np.inf
    return float(grey[inside].mean() - grey[outside].mean())


def _background(grey):
    """The working-resolution factor, the smoothed image and the background
    threshold of a grey mammogram on [0, 1] (steps 1-2 of
    :func:`detect_breast`)."""
    from scipy import ndimage

    factor = max(1, round(max(grey.shape) / _WORK_SIDE))
    small = _block_mean(grey, factor)
    if min(small.shape) < _MIN_WORK_SIDE:
        h, w = grey.shape
        raise ValueError(
            f"image {h}x{w} is too thin for breast detection: at its working resolution "
            f"(1/{factor}) the short side is {min(small.shape)} pixels and at least "
            f"{_MIN_WORK_SIDE} are needed. Pass the whole mammogram (short side at least "
            f"{_MIN_WORK_SIDE * factor} pixels at this length)."
        )
    smooth = ndimage.gaussian_filter(small, 1.0)
    b, p99 = np.percentile(smooth, [5, 99])
    if p99 <= b:
        raise ValueError(
            "image has almost no contrast (5th and 99th percentiles are equal): "
            "no breast found. Pass a mammogram with visible tissue."
        )
    return factor, smooth, float(b + 0.08 * (p99 - b))


def detect_breast(image, *, pectoral=True, return_details=False, channel_axis=-1):
    """Mask of the breast in a mammogram.

    Heuristics (all at a working resolution of about 256 pixels on the long
    side, so the call takes a few tens of milliseconds):

    1. The image is scaled to [0, 1] and smoothed (Gaussian, 1 pixel).
    2. Background threshold ``t = b + 0.08 (p99 - b)`` where ``b`` is the
       5th percentile (the black film/pad) and ``p99`` the 99th percentile:
       low enough to keep the dim skin line, above film grain.
    3. A band of 1.5 % of the long side along every image border is never
       breast (scanned films carry bright edge strips there); a binary
       opening (3 iterations) cuts thin bridges to labels, tape and
       film-edge strips; the largest connected component is the breast;
       holes are filled.
    4. The chest-wall side is the side where the mask is widest
       (:func:`chest_wall_side`); the image is mirrored so it is on the left.
    5. Pectoral muscle (``pectoral=True``): a bright, nearly triangular
       region in the top corner on the chest-wall side, bounded by a nearly
       straight edge (a robust line fit); it is removed when found (MLO
       views), nothing is removed otherwise.

    Parameters
    ----------
    image : (H, W) array_like
        Grey mammogram (bright = dense), any numeric dtype; an RGB(A) export
        of one, with ``channel_axis``, is reduced to its luminance.
    pectoral : bool, optional
        Remove the pectoral muscle.
    return_details : bool, optional
        Return a :class:`BreastDetection` ``(mask, details)`` instead of the
        mask alone.
    channel_axis : int or None, optional
        The colour axis of an RGB(A) export; a 2-D image is grey, None forces
        grey.

    Returns
    -------
    (H, W) ndarray of bool
        The mask, True on the breast; with ``return_details``, a
        :class:`BreastDetection` that unpacks as ``mask, details``.

    Raises
    ------
    ValueError
        If the image is constant (e.g. all black), has NaN or infinite
        values, or no breast is found.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.mammography import detect_breast
    >>> image = np.zeros((128, 128), np.uint8)
    >>> image[16:112, 68:] = 180  # a bright breast against the right edge
    >>> mask = detect_breast(image)
    >>> bool(mask[64, 100]), bool(mask[64, 10])
    (True, False)
    """
    grey = _grey01(_as_grey(image, channel_axis))
    return drain(_iter_detect(grey, pectoral=pectoral, return_details=return_details))


def _iter_detect(grey, *, pectoral=True, return_details=False):
    """:func:`detect_breast` of a grey image on [0, 1] (:func:`_grey01`), as a
    job: "breast" records between the steps that scan the full image."""
    H, W = grey.shape
    factor, smooth, t = _background(grey)
    yield Progress("breast", 0.4, "background level")
    mask, side = _breast_with_muscle(smooth, t)
    pect = np.zeros_like(mask)
    if pectoral:
        pect = _chest_wall_left(_pectoral, smooth, mask, side)
        mask = mask & ~pect
        mask = _largest_component(mask)
    full = _upsample_mask(mask, (H, W), factor)
    if not return_details:
        return full
    yield Progress("breast", 0.8, "pectoral muscle")
    return BreastDetection(full, {
        "side": side,
        "pectoral": _upsample_mask(pect, (H, W), factor),
        "threshold": float(t),
    })


def _chest_wall_left(find, smooth, mask, side, **options):
    """``find(grey, breast, **options)``, a mask finder for a chest wall on
    the left, on a breast whose chest wall is on ``side``: mirrored there
    and back."""
    if side != "right":
        return find(smooth, mask, **options)
    return find(smooth[:, ::-1], mask[:, ::-1], **options)[:, ::-1]


def _breast_with_muscle(smooth, t):
    """The breast mask at the working resolution before the pectoral muscle
    is removed (steps 3-4 of :func:`detect_breast`) and its chest-wall side."""
    from scipy import ndimage

    mask = smooth > t
    band = max(1, round(_BORDER * max(mask.shape)))
    mask[:band], mask[-band:], mask[:, :band], mask[:, -band:] = False, False, False, False
    mask = ndimage.binary_opening(mask, iterations=3)
    mask = _largest_component(mask)
    mask = ndimage.binary_fill_holes(mask)
    if mask.sum() < 0.01 * mask.size:
        raise ValueError(
            "no breast found: the bright area is under 1 % of the image. "
            "Pass a mammogram (bright = dense tissue)."
        )
    return mask, chest_wall_side(mask)
