"""Candidate regions of a breast segmentation described by what the CAR model
knows about them, scored by a small logistic model, merged into findings and
painted (section 14.4, docs/mammography.md).

The candidates are those of :func:`~car_napari.mammography.filter_regions`
(the components of every segment of every pooled labelling, and of their
locally bright parts). Each is described, on the analysis grid (about 256
pixels on the long side), by

* texture: the segmentation's CAR features (local parameters and log
  prediction-error energy of the directional adaptive models, (14.33))
  inside the candidate against a ring of breast around it, and how much of
  that ring belongs to other segments;
* grey level: mean, contrast against the ring, spread;
* size and shape: equivalent radius (on a 1024-pixel scale), compactness;
* model surprise: a grey CAR model fitted on the ring predicts the
  candidate (:func:`_surprise`): how much worse than the ring itself, and
  how much brighter than predicted;
* host: contrast against the rest of the candidate's segment;
* breast: its CAR features against its own breast (z-scores against the
  breast's distribution) and the ranks of its CAR contrasts and surprise
  among the image's candidates.

The score is a logistic model or boosted trees of those descriptors, shipped
in ``roi_model.json`` (fitted by ``benchmarks/bench_froc.py``); plain NumPy.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._progress import Progress
from ._trees import TreeEnsemble

# Names of the candidate descriptors, in the order of the matrix
# :func:`_describe` returns, and their families (a model may use a subset).
DESCRIPTORS = (
    # grey level
    "mean_grey", "grey_above_breast", "contrast", "contrast_z", "grey_std",
    "contrast_rank", "contrast_z_rank",
    # size and shape
    "log_radius", "log_radius_sq", "compactness",
    # CAR texture
    "param_contrast", "param_spread", "energy", "energy_contrast", "segment_edge",
    # CAR model surprise: a CAR fitted on the candidate's ring predicts it
    "surprise", "surprise_bias",
    # contrast against the host segment (the rest of the candidate's segment)
    "host_contrast", "host_contrast_z",
    # where in the breast: film edges and the pectoral corner are not masses
    "border_distance", "skin_distance", "chest_distance", "height", "corner",
    # the candidate's CAR features against its own breast: z-scores against
    # the breast's distribution, and ranks among the image's candidates
    "param_breast_z", "energy_breast_z", "param_contrast_rank", "energy_contrast_rank",
    "surprise_rank",
)
FAMILIES = {
    "grey": ("mean_grey", "grey_above_breast", "contrast", "contrast_z", "grey_std",
             "contrast_rank", "contrast_z_rank"),
    "shape": ("log_radius", "log_radius_sq", "compactness"),
    "texture": ("param_contrast", "param_spread", "energy", "energy_contrast",
                "segment_edge"),
    "surprise": ("surprise", "surprise_bias"),
    "host": ("host_contrast", "host_contrast_z"),
    "location": ("border_distance", "skin_distance", "chest_distance", "height", "corner"),
    "breast": ("param_breast_z", "energy_breast_z", "param_contrast_rank",
               "energy_contrast_rank", "surprise_rank"),
}
# descriptors that need the surprise fits (:func:`_surprise`)
NEEDS_SURPRISE = frozenset(FAMILIES["surprise"] + ("surprise_rank",))
# The CAR feature vector's layout per resolution level
# (car_napari.segmentation.local_features with its defaults on a
# pseudo-colour image): 4 PCA components of the local parameters, the log
# prediction-error energy, the 3-channel local mean.
_PER_LEVEL = 8
_PARAMS = (0, 1, 2, 3)
_ENERGY = 4
# A mass of this equivalent radius (pixels of a 1024-pixel mini-MIAS image)
# is the centre of the log-radius descriptor (sqrt(20 * 130), see
# MASS_RADIUS_RANGE).
_RADIUS_CENTRE = np.log(51.0)
_MODEL_FILE = Path(__file__).with_name("roi_model.json")


def _texture_grid(features, box, factor, f, shape):
    """The segmentation's features (working-resolution crop ``box``) on the
    analysis grid of block size ``f`` (full-resolution pixels) and ``shape``:
    each analysis pixel takes the working pixel under its centre (the
    features are smooth); 0 outside the crop."""
    h, w = shape
    r0, r1, c0, c1 = box
    rows = (np.arange(h) * f + f // 2) // factor - r0
    cols = (np.arange(w) * f + f // 2) // factor - c0
    okr = (rows >= 0) & (rows < features.shape[0])
    okc = (cols >= 0) & (cols < features.shape[1])
    out = np.zeros((h, w, features.shape[2]), np.float32)
    out[np.ix_(okr, okc)] = features[np.ix_(rows[okr], cols[okc])]
    return out


def _texture_indices(n_features):
    """Parameter and energy columns of a CAR feature vector of ``n_features``."""
    if n_features % _PER_LEVEL:
        raise ValueError(f"CAR features of {n_features} values: expected a multiple of "
                         f"{_PER_LEVEL} (4 parameter components, the energy and the "
                         "3-channel local mean per level).")
    levels = range(n_features // _PER_LEVEL)
    params = [m * _PER_LEVEL + k for m in levels for k in _PARAMS]
    energy = [m * _PER_LEVEL + _ENERGY for m in levels]
    return params, energy


def linear_terms(spec):
    """``(mean, scale, coef, intercept)`` float arrays of a standardised
    linear model stored in a model file (``((x - mean) / scale) . coef +
    intercept``)."""
    return tuple(np.asarray(spec[k], float) for k in ("mean", "scale", "coef", "intercept"))


class Candidate:
    """One candidate region on the analysis grid: its box ``(r0, r1, c0,
    c1)``, the mask inside the box, and its centroid (analysis pixels)."""

    __slots__ = ("box", "centroid", "mask")

    def __init__(self, box, mask, centroid):
        self.box, self.mask, self.centroid = box, mask, centroid


def _generate(grey, labellings, breast, *, split, sigmas, delta, min_area):
    """Candidate regions on the analysis grid: ``(cc, i, slices, area,
    labelling)`` tuples (component ``i`` of the label image ``cc``, from
    labelling number ``labelling``).

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
    for li, lab in enumerate(labellings):
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
                        out.append((cc, i, sl, int(sizes[i]), li))
    return out


def _crop(cc, i, sl, area, shape):
    """A candidate's crop: component ``i`` of ``cc`` (bounding slices
    ``sl``, ``area`` pixels) with a margin of half its equivalent radius
    (at least 2). Returns the equivalent radius, the crop ``(r0, r1, c0,
    c1)`` within ``shape`` and the candidate's mask in it."""
    req = np.sqrt(area / np.pi)
    width = _ring_width(req)
    r0, r1 = max(0, sl[0].start - width), min(shape[0], sl[0].stop + width)
    c0, c1 = max(0, sl[1].start - width), min(shape[1], sl[1].stop + width)
    return req, (r0, r1, c0, c1), cc[r0:r1, c0:c1] == i


def _ring_width(req):
    return max(2, round(0.5 * req))


def _ring(inside, req, breast):
    """The ring around a candidate (its crop's mask ``inside``): the breast
    pixels within the ring width of it, not in it."""
    from scipy import ndimage

    return ndimage.binary_dilation(inside, iterations=_ring_width(req)) & ~inside & breast


def _centre_and_compactness(inside, req):
    """The centroid of the mask ``inside`` and the share of its pixels within
    the equivalent radius ``req`` of it."""
    rr, cl = np.nonzero(inside)
    cr, ccol = rr.mean(), cl.mean()
    return (cr, ccol), float(np.mean((rr - cr) ** 2 + (cl - ccol) ** 2 <= req**2))


def _describe(grey, labellings, breast, texture, cands, *, f, side, work=None, surprise=True):
    """Descriptors (:data:`DESCRIPTORS`) of ``cands`` (``(cc, i, slices,
    area, labelling)`` from :func:`_generate`) on the analysis grid.

    Returns the kept :class:`Candidate` list and the (n, len(DESCRIPTORS))
    float64 matrix; candidates not brighter than their ring, or with too
    small a ring, are dropped. ``texture`` (h, w, D) or None (its columns
    are then 0); without ``surprise`` the surprise columns are 0 (a model
    that does not use them skips the fits). ``side``: the full-resolution long side (the radius is
    measured on a 1024-pixel scale). With ``work``, a generator: yields
    Progress records now and then and returns the same.
    """

    h, w = grey.shape
    scale = f * 1024.0 / side
    med = float(np.median(grey[breast])) if breast.any() else 0.0
    if texture is not None:
        params, energy = _texture_indices(texture.shape[2])
        # the breast's distribution of the CAR features (a mass is unusual
        # for its own breast, whatever the film's scale)
        in_breast = texture[breast] if breast.any() else texture.reshape(-1, texture.shape[2])
        breast_mean = in_breast.mean(axis=0, dtype=np.float64)
        breast_sd = in_breast.std(axis=0, dtype=np.float64) + 1e-6
    # per labelling: grey sum, sum of squares and count of every segment
    # (the host statistics are those less the candidate's own pixels)
    sums = []
    for lab in labellings:
        n_lab = int(lab.max()) + 1
        sums.append([np.bincount(lab.ravel(), weights=w_, minlength=n_lab)
                     for w_ in (grey.ravel(), grey.ravel() ** 2, None)])
    where = _Location(breast)
    kept, rows = [], []
    for n, (cc, i, sl, a, li) in enumerate(cands):
        if work is not None and n % 64 == 63:
            yield Progress("regions", work[0] + (work[1] - work[0]) * n / len(cands),
                           f"describing candidates {n + 1}/{len(cands)}")
        req, (r0, r1, c0, c1), inside = _crop(cc, i, sl, a, (h, w))
        ring = _ring(inside, req, breast[r0:r1, c0:c1])
        if ring.sum() < 4:
            continue
        g = grey[r0:r1, c0:c1]
        gi, gr = g[inside], g[ring]
        mean = float(gi.mean())
        contrast = mean - float(gr.mean())
        if contrast <= 0:
            continue
        (cr, ccol), compact = _centre_and_compactness(inside, req)
        log_r = np.log(max(req * scale, 1e-3)) - _RADIUS_CENTRE
        desc = [mean, mean - med, contrast, contrast / (float(gr.std()) + 0.01),
                float(gi.std()), 0.0, 0.0, log_r, log_r**2, compact]
        if texture is not None:
            t = texture[r0:r1, c0:c1]
            ti, tr = t[inside], t[ring]
            mi, mr = ti.mean(axis=0), tr.mean(axis=0)
            # the segments of the labelling the candidate comes from, in its ring
            seg = labellings[li][r0:r1, c0:c1]
            own = np.bincount(seg[inside]).argmax()
            desc += [float(np.sqrt(np.mean((mi[params] - mr[params]) ** 2))),
                     float(ti[:, params].std(axis=0).mean()),
                     float(mi[energy].mean()), float((mi[energy] - mr[energy]).mean()),
                     float(np.mean(seg[ring] != own))]
            z = (mi - breast_mean) / breast_sd
            breast_z = [float(np.sqrt(np.mean(z[params] ** 2))), float(z[energy].mean())]
        else:
            desc += [0.0] * len(FAMILIES["texture"])
            breast_z = [0.0, 0.0]
        desc += _surprise(g, inside, ring) if surprise else [0.0, 0.0]
        desc += _host(g, inside, labellings[li][r0:r1, c0:c1], sums[li])
        desc += where(cr + r0, ccol + c0)
        desc += breast_z + [0.0, 0.0, 0.0]  # the ranks, filled in below
        rows.append(desc)
        kept.append(Candidate((r0, r1, c0, c1), inside, (cr + r0, ccol + c0)))
    X = np.asarray(rows, float).reshape(len(rows), len(DESCRIPTORS))
    # the image's own scale: the rank of the contrast among its candidates
    # (a mass stands out in its own breast more than on an absolute scale)
    for src, dst in (("contrast", "contrast_rank"), ("contrast_z", "contrast_z_rank"),
                     ("param_contrast", "param_contrast_rank"),
                     ("energy_contrast", "energy_contrast_rank"), ("surprise", "surprise_rank")):
        col = X[:, DESCRIPTORS.index(src)]
        X[:, DESCRIPTORS.index(dst)] = _ranks(col)
    return kept, X


class _Location:
    """Where a point lies in the image and in its breast (the ``location``
    descriptors): the distance to the nearest image border over the long side
    (film edges and scanner strips lie there), the distance to the skin line
    over the breast's equivalent radius, the distance from the chest wall
    and from the breast's top as fractions of its width and height, and
    closeness to the top chest-wall corner (the pectoral muscle of MLO views),
    ``max(0, 1 - hypot(chest, height))``."""

    def __init__(self, breast):
        from scipy import ndimage

        from ._breast import chest_wall_side

        self.shape = breast.shape
        self.inside = ndimage.distance_transform_edt(np.pad(breast, 1))[1:-1, 1:-1]
        self.radius = max(np.sqrt(breast.sum() / np.pi), 1.0)
        rows = np.flatnonzero(breast.any(axis=1))
        cols = np.flatnonzero(breast.any(axis=0))
        self.top, self.height = (rows[0], max(rows[-1] - rows[0], 1)) if rows.size else (0, 1)
        left, right = (cols[0], cols[-1]) if cols.size else (0, self.shape[1] - 1)
        self.wall = left if chest_wall_side(breast) == "left" else right
        self.width = max(right - left, 1)

    def __call__(self, r, c):
        h, w = self.shape
        border = min(r, c, h - 1 - r, w - 1 - c) / max(h, w)
        ri, ci = min(max(int(round(r)), 0), h - 1), min(max(int(round(c)), 0), w - 1)
        chest = abs(c - self.wall) / self.width
        height = (r - self.top) / self.height
        return [border, self.inside[ri, ci] / self.radius, chest, height,
                max(0.0, 1.0 - float(np.hypot(chest, height)))]


def _host(g, inside, seg, sums):
    """Contrast of a candidate against its host segment (the segment most of
    it lies in, less the candidate's own pixels): ``[mean difference, that
    over the host's grey deviation]``; zeros when the host is (almost) only
    the candidate."""
    own = int(np.bincount(seg[inside]).argmax())
    mine = inside & (seg == own)
    s1, s2, n = (t[own] for t in sums)
    n -= mine.sum()
    if n < 4:
        return [0.0, 0.0]
    mean = (s1 - g[mine].sum()) / n
    var = max((s2 - (g[mine] ** 2).sum()) / n - mean**2, 0.0)
    diff = float(g[inside].mean() - mean)
    return [diff, diff / (np.sqrt(var) + 0.01)]


# The surprise model: a grey 2DCAR of this hierarchical order (4 causal
# neighbours), fixed a priori like the segmentation's neighbourhood.
_SURPRISE_ORDER = 2


def _surprise(g, inside, ring):
    """How badly the CAR model of a candidate's surroundings predicts it.

    A grey CAR model (:data:`_SURPRISE_ORDER`, the model core's Bayesian
    estimate, centred on the ring's mean) is fitted on the ring pixels none of
    whose neighbours is the candidate's; :func:`~car_napari.model.predict` then
    gives the log predictive density (Student t) of every pixel of the crop
    ``g``. A mass is where the surrounding tissue's texture model fails.

    Returns
    -------
    list of float
        ``[surprise, surprise_bias]``: the mean negative log predictive
        density of the candidate less that of the ring (0: predicted as
        well as the ring itself), and the candidate's mean prediction error
        in units of the model's noise deviation (positive: brighter than
        the surrounding texture predicts). Zeros when the ring is too small
        to fit the model.
    """
    from ..model import CARModel, Context, causal_neighbourhood, predict
    from ..model.statistics import estimate_parameters

    offsets = causal_neighbourhood(_SURPRISE_ORDER)
    eta = len(offsets)
    if ring.sum() < 4 * (eta + 1):
        return [0.0, 0.0]
    mean = float(g[ring].mean())
    y = g.astype(np.float64) - mean
    h, w = y.shape
    (up, down), (left, right) = Context.spatial(offsets, 1).reach
    if h <= up + down or w <= left + right:
        return [0.0, 0.0]
    # rows [X_r, Y_r] of the ring pixels none of whose neighbours is the
    # candidate's (the ring alone is too thin to hold whole neighbourhoods)
    r0, r1, c0, c1 = up, h - down, left, w - right
    use = ring[r0:r1, c0:c1].copy()
    taps = []
    for di, dj in offsets:
        use &= ~inside[r0 - di : r1 - di, c0 - dj : c1 - dj]
        taps.append(y[r0 - di : r1 - di, c0 - dj : c1 - dj])
    if use.sum() < 4 * (eta + 1):
        return [0.0, 0.0]
    Z = np.stack(taps + [y[r0:r1, c0:c1]], axis=-1)[use]
    var = float(Z[:, -1].var()) + 1e-12
    # an almost uninformative prior on the scale of the ring's variance
    est = estimate_parameters(Z.T @ Z, len(Z), eta, np.full(eta + 1, 1e-6 * var))
    model = CARModel(gamma=est.gamma, sigma=est.lam / est.beta, mean=np.array([mean]),
                     offsets=np.asarray(offsets), lam=est.lam, vx=est.vx, beta=est.beta,
                     n_pixels=len(Z), order=_SURPRISE_ORDER)
    pred, logp = predict(model, g.astype(np.float64), channel_axis=None)
    ok = np.isfinite(logp)
    a, b = inside & ok, ring & ok
    if not a.any() or not b.any():
        return [0.0, 0.0]
    sd = float(np.sqrt(model.sigma[0, 0]))
    return [float(logp[b].mean() - logp[a].mean()),
            float(np.mean(g[a] - pred[a])) / sd]


def _ranks(values):
    """Ranks of ``values`` scaled to [0, 1] (1: the largest; ties share)."""
    n = values.size
    if n < 2:
        return np.ones(n)
    order = np.argsort(values, kind="stable")
    ranks = np.empty(n)
    ranks[order] = np.arange(n)
    # ties take their mean rank
    uniq, inv = np.unique(values, return_inverse=True)
    if uniq.size < n:
        ranks = (np.bincount(inv, ranks) / np.bincount(inv))[inv]
    return ranks / (n - 1)


# Two candidates overlapping by at least this intersection over union are
# one finding (the usual non-maximum suppression of detectors; set a priori,
# not tuned), and so are two that each hold the other's centroid. A small
# candidate inside a large one is a finding of its own (a mass in a density
# band).
_SAME_IOU = 0.5


def _overlap(box_a, mask_a, box_b, mask_b):
    """Pixels common to two box masks."""
    r0, r1 = max(box_a[0], box_b[0]), min(box_a[1], box_b[1])
    c0, c1 = max(box_a[2], box_b[2]), min(box_a[3], box_b[3])
    if r0 >= r1 or c0 >= c1:
        return 0
    a = mask_a[r0 - box_a[0] : r1 - box_a[0], c0 - box_a[2] : c1 - box_a[2]]
    b = mask_b[r0 - box_b[0] : r1 - box_b[0], c0 - box_b[2] : c1 - box_b[2]]
    return int(np.count_nonzero(a & b))


def _holds(box, mask, point):
    r, c = point
    return box[0] <= r < box[1] and box[2] <= c < box[3] and bool(mask[r - box[0], c - box[2]])


def _merge(cands, scores, tie=0.1):
    """Findings of scored candidates, best first: ``(score, mask, box, j)``
    with the mask on the analysis grid inside ``box`` and ``j`` the index of
    the finding's best candidate.

    Greedy, best score first: a candidate that overlaps a kept finding by an
    intersection over union of at least :data:`_SAME_IOU`, or that holds the
    finding's centroid while the finding holds its own, is that finding; it
    joins it (the mask grows to the union) when its score is within ``tie``
    of the finding's, and is dropped otherwise. Since the order is by score,
    the findings above any threshold are those this gives from the
    candidates above it (up to the joins).
    """
    order = np.argsort(-np.asarray(scores), kind="stable")
    found = []  # [score, mask, centroid of the best candidate, box, j, area]
    for j in order:
        c, s = cands[j], float(scores[j])
        r0, r1, c0, c1 = c.box
        cen = (int(round(c.centroid[0])), int(round(c.centroid[1])))
        area = int(np.count_nonzero(c.mask))
        same = None
        for fnd in found:
            if not (fnd[3][0] < r1 and r0 < fnd[3][1] and fnd[3][2] < c1 and c0 < fnd[3][3]):
                continue
            common = _overlap(c.box, c.mask, fnd[3], fnd[1])
            if common >= _SAME_IOU * (area + fnd[5] - common) or (
                    _holds(fnd[3], fnd[1], cen) and _holds(c.box, c.mask, fnd[2])):
                same = fnd
                break
        if same is None:
            found.append([s, c.mask.copy(), cen, c.box, int(j), area])
        elif s >= (1.0 - tie) * same[0]:
            # grow the finding's box to hold the union
            fr0, fr1, fc0, fc1 = same[3]
            nr0, nr1, nc0, nc1 = min(fr0, r0), max(fr1, r1), min(fc0, c0), max(fc1, c1)
            m = np.zeros((nr1 - nr0, nc1 - nc0), bool)
            m[fr0 - nr0 : fr1 - nr0, fc0 - nc0 : fc1 - nc0] = same[1]
            m[r0 - nr0 : r1 - nr0, c0 - nc0 : c1 - nc0] |= c.mask
            same[1], same[3], same[5] = m, (nr0, nr1, nc0, nc1), int(np.count_nonzero(m))
    return [(fnd[0], fnd[1], fnd[3], fnd[4]) for fnd in found]


def _visible(findings, shape, min_visible=0.0):
    """The part of each finding not claimed by a better one (``_merge``'s
    output, best first, on the analysis grid of ``shape``): what a label
    image painted best first shows. Findings with nothing left, or with less
    than ``min_visible`` of their own mask left (a duplicate of better ones;
    its pixels stay claimed), are dropped; the rest keep their order, score
    and best candidate."""
    claimed = np.zeros(shape, bool)
    out = []
    for score, mask, (r0, r1, c0, c1), best in findings:
        mine = mask & ~claimed[r0:r1, c0:c1]
        n_mine = np.count_nonzero(mine)
        if not n_mine:
            continue
        claimed[r0:r1, c0:c1] |= mine
        if n_mine < min_visible * np.count_nonzero(mask):
            continue
        out.append((score, mine, (r0, r1, c0, c1), best))
    return out


# The grey level is smoothed by this Gaussian (analysis-grid pixels) before a
# finding's bright core is cut (:func:`_cores`); fixed with the core rule on
# CBIS-DDSM folds 0-1 scored by a model of folds 2-4 (benchmarks/bench_froc.py).
_CORE_SIGMA = 2.0


def _cores(findings, grey, quantile):
    """Each finding cut to its bright core: the pixels of its mask where the
    smoothed grey level is at least its ``quantile`` inside the mask, and of
    those the connected part (4-neighbours) holding the brightest. A mass is
    a bright blob; a segment holding one is often much larger, and its
    centroid then lies off the mass."""
    from scipy import ndimage

    smooth = ndimage.gaussian_filter(np.asarray(grey, float), _CORE_SIGMA)
    out = []
    for score, mask, (r0, r1, c0, c1), best in findings:
        sub = smooth[r0:r1, c0:c1]
        core = mask & (sub >= np.quantile(sub[mask], quantile))
        parts, n = ndimage.label(core)
        if n > 1:
            core = parts == parts.flat[np.argmax(np.where(core, sub, -np.inf))]
        out.append((score, core, (r0, r1, c0, c1), best))
    return out


def _findings(cands, scores, grey, model):
    """The findings of scored candidates as ``model`` makes them (merged,
    visible part, bright core when the model asks for it) on the analysis
    grid ``grey``: ``(score, mask, box, best)``, best first."""
    return _refined(_merge(cands, scores, tie=model.tie), grey, model)


def _refined(merged, grey, model):
    """Merged findings (:func:`_merge`'s) cleaned as ``model`` asks: the
    visible part, the bright core (:func:`_findings`)."""
    found = _visible(merged, grey.shape, min_visible=model.min_visible)
    if model.core is not None:
        found = _cores(found, grey, model.core)
    return found


# --- the scoring model --------------------------------------------------------


class RoiModel:
    """The scoring model of candidates and its operating points.

    Parameters
    ----------
    spec : dict
        The parsed ``roi_model.json``: ``descriptors`` (the names used) and
        ``operating_points`` (rows of ``marks_per_image``, ``threshold``...),
        and either a logistic model (``mean``, ``scale``: standardisation;
        ``coef``, ``intercept``) or, with ``"kind": "trees"``, gradient-boosted
        trees (``baseline`` and ``trees``: per tree the node arrays
        ``feature``, ``threshold``, ``left``, ``right``, ``leaf``, ``value``;
        a sample goes left where its descriptor is at most the threshold; the
        score is the logistic of the baseline plus the leaves' values);
        ``merge_tie`` (default 0.1): how close to a finding's score a
        candidate joins it (:func:`_merge`); ``min_visible`` (default 0)
        and ``core_quantile`` (default none): how findings are cleaned and
        cut to their bright core (:func:`_findings`).
    """

    def __init__(self, spec):
        self.spec = spec
        self.kind = spec.get("kind", "logistic")
        self.names = tuple(spec["descriptors"])
        unknown = set(self.names) - set(DESCRIPTORS)
        if unknown:
            raise ValueError(f"ROI model uses unknown descriptors {sorted(unknown)}.")
        self.columns = [DESCRIPTORS.index(n) for n in self.names]
        if self.kind == "trees":
            self.ensemble = TreeEnsemble(spec["baseline"], spec["trees"])
        else:
            self.mean, self.scale, self.coef, self.intercept = linear_terms(spec)
        # candidates within this fraction of a finding's score join it (:func:`_merge`)
        self.tie = float(spec.get("merge_tie", 0.1))
        # findings less visible than this are dropped, and each is cut to its
        # bright core at this quantile when set (:func:`_findings`)
        self.min_visible = float(spec.get("min_visible", 0.0))
        core = spec.get("core_quantile")
        self.core = None if core is None else float(core)
        points = sorted(spec.get("operating_points", []), key=lambda p: p["marks_per_image"])
        self.rates = np.array([p["marks_per_image"] for p in points], float)
        self.thresholds = np.array([p["threshold"] for p in points], float)

    def raw(self, X):
        """The model's log-odds of descriptor rows ``X`` (n, len(DESCRIPTORS))."""
        X = np.asarray(X, float).reshape(-1, len(DESCRIPTORS))[:, self.columns]
        if self.kind != "trees":
            return ((X - self.mean) / self.scale) @ self.coef + self.intercept
        return self.ensemble.log_odds(X)

    def score(self, X):
        """Scores in (0, 1) of descriptor rows ``X`` (n, len(DESCRIPTORS))."""
        return 1.0 / (1.0 + np.exp(-self.raw(X)))

    def threshold(self, marks_per_image):
        """The score threshold of an operating point: on the model's training
        images, ``marks_per_image`` false marks per image on average
        (interpolated in the stored table, log scale; clipped to its ends)."""
        if self.rates.size == 0:
            return 0.0
        x = np.log(max(float(marks_per_image), 1e-6))
        return float(np.interp(x, np.log(self.rates), self.thresholds))


@lru_cache(maxsize=1)
def shipped_model():
    """The :class:`RoiModel` shipped with the package (``roi_model.json``)."""
    with open(_MODEL_FILE) as fh:
        return RoiModel(json.load(fh))
