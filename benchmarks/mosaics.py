"""Prague-style texture mosaics with exact ground truth, and their scores.

Mosaics: K textures in random Voronoi-like cells whose borders are made
smooth and irregular by a low-pass random displacement; fixed seeds.
Scores: the Prague criteria (Haindl and Mikes) at k = 0.75 (CS, OS, US, ME,
NE), pixel accuracy after Hungarian matching, adjusted Rand index, variation
of information.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "textures"


def voronoi_layout(shape, n_regions, seed, roughness=25.0, amplitude=40.0):
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    h, w = shape
    while True:
        pts = rng.uniform([0, 0], [h, w], size=(n_regions, 2))
        gaps = [np.linalg.norm(a - b) for i, a in enumerate(pts) for b in pts[i + 1:]]
        if min(gaps) > 0.25 * min(h, w):
            break
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    noise = [ndimage.gaussian_filter(rng.standard_normal(shape), roughness) for _ in range(2)]
    noise = [amplitude * n / n.std() for n in noise]
    yy, xx = yy + noise[0], xx + noise[1]
    dist = np.stack([(yy - y) ** 2 + (xx - x) ** 2 for y, x in pts])
    return dist.argmin(axis=0) + 1


def strips_layout(shape, n_regions, seed, min_share=0.5):
    """``n_regions`` straight strips, vertical or horizontal (by the seed),
    each at least ``min_share`` of an equal strip's width; labels 1..n."""
    rng = np.random.default_rng(seed)
    h, w = shape
    vertical = bool(rng.integers(2))
    side = w if vertical else h
    widths = min_share + (1 - min_share) * rng.dirichlet(np.ones(n_regions)) * n_regions
    edges = np.round(np.cumsum(widths) / widths.sum() * side).astype(int)
    strip = np.searchsorted(edges, np.arange(side), side="right") + 1
    return np.broadcast_to(strip[None, :] if vertical else strip[:, None], shape).copy()


LAYOUTS = {"voronoi": voronoi_layout, "strips": strips_layout}


def _read_texture(path):
    """A texture as (H, W, C) uint8-valued array, C = 1 or 3 (a grey image
    with an alpha channel keeps only its grey)."""
    from skimage import io

    tex = io.imread(path)
    if tex.ndim == 2:
        tex = tex[..., None]
    if tex.shape[2] == 2:  # grey + alpha
        tex = tex[..., :1]
    return tex[..., :3]


def make_mosaic(files, shape=(512, 512), seed=0, grey=False, layout="voronoi"):
    """A mosaic of the textures in ``files`` and its (H, W) ground truth 1..K.

    ``layout``: "voronoi" (irregular cells, the default) or "strips"
    (straight strips, :func:`strips_layout`).

    ``grey=True`` turns colour textures grey (the mean of R, G, B, as the
    grey Brodatz files stored as RGB are). A texture smaller than the mosaic
    is mirror-tiled to its size first."""
    layout = LAYOUTS[layout](shape, len(files), seed)
    rng = np.random.default_rng(seed + 1000)
    textures = [_read_texture(f) for f in files]
    # a set is grey unless one of its textures really has colour (some grey
    # Brodatz files are stored as RGB with three equal channels)
    def coloured(t):
        return t.shape[2] >= 3 and np.ptp(t[..., :3].astype(np.int16), axis=2).any()
    channels = 3 if not grey and any(coloured(t) for t in textures) else 1
    mosaic = np.zeros(shape + (channels,))
    for k, tex in enumerate(textures, start=1):
        tex = tex.mean(axis=2, keepdims=True) if channels == 1 else tex
        if tex.shape[2] != channels:
            tex = np.repeat(tex, channels, axis=2)
        pad = [(0, max(0, n - t)) for n, t in zip(shape, tex.shape[:2], strict=True)]
        if any(p[1] for p in pad):
            tex = np.pad(tex, pad + [(0, 0)], mode="symmetric")
        th, tw = tex.shape[:2]
        top, left = rng.integers(0, th - shape[0] + 1), rng.integers(0, tw - shape[1] + 1)
        crop = tex[top : top + shape[0], left : left + shape[1]] / 255.0
        mosaic[layout == k] = crop[layout == k]
    return (mosaic[..., 0] if channels == 1 else mosaic), layout


def mosaic_set(kind="vistex", count=6, n_textures=5, seed=0, grey=False):
    """``count`` mosaics of ``n_textures`` textures of ``textures/<kind>``
    (every PNG or JPEG file there), as colour unless ``grey``; fixed seeds."""
    files = sorted(f for f in (DATA / kind).iterdir() if f.suffix in (".png", ".jpg"))
    rng = np.random.default_rng(seed)
    for i in range(count):
        chosen = [files[j] for j in rng.choice(len(files), n_textures, replace=False)]
        yield make_mosaic(chosen, seed=seed * 100 + i, grey=grey)


def prague_scores(gt, seg, k=0.75):
    """Prague criteria in % of image area: CS, OS, US, ME, NE (Haindl & Mikes)."""
    total = gt.size
    g_ids = [g for g in np.unique(gt) if g != 0]
    s_ids = [s for s in np.unique(seg) if s != 0]
    overlap = np.zeros((len(g_ids), len(s_ids)))
    for a, g in enumerate(g_ids):
        gmask = gt == g
        for b, s in enumerate(s_ids):
            overlap[a, b] = np.count_nonzero(gmask & (seg == s))
    g_area = np.array([np.count_nonzero(gt == g) for g in g_ids], float)
    s_area = np.array([np.count_nonzero(seg == s) for s in s_ids], float)
    cs = os_ = us = me = 0.0
    for a in range(len(g_ids)):
        b = overlap[a].argmax() if s_ids else None
        if b is not None and overlap[a, b] >= k * s_area[b] and overlap[a, b] >= k * g_area[a]:
            cs += g_area[a]
            continue
        # over-segmentation: GT region split into segments each mostly inside it
        parts = [bb for bb in range(len(s_ids)) if overlap[a, bb] >= k * s_area[bb]]
        if len(parts) > 1 and overlap[a, parts].sum() >= k * g_area[a]:
            os_ += g_area[a]
            continue
        me += g_area[a]
    for b in range(len(s_ids)):
        parts = [a for a in range(len(g_ids)) if overlap[a, b] >= k * g_area[a]]
        if len(parts) > 1 and overlap[parts, b].sum() >= k * s_area[b]:
            us += s_area[b]
    ne = 0.0
    for b in range(len(s_ids)):
        a = overlap[:, b].argmax()
        if not (overlap[a, b] >= k * s_area[b] and overlap[a, b] >= k * g_area[a]):
            ne += s_area[b]
    return {key: 100.0 * val / total for key, val in
            dict(CS=cs, OS=os_, US=us, ME=me, NE=ne).items()}


def matched_accuracy(gt, seg):
    from scipy.optimize import linear_sum_assignment

    g_ids, g_inv = np.unique(gt, return_inverse=True)
    s_ids, s_inv = np.unique(seg, return_inverse=True)
    table = np.zeros((g_ids.size, s_ids.size))
    np.add.at(table, (g_inv.ravel(), s_inv.ravel()), 1)
    r, c = linear_sum_assignment(-table)
    return table[r, c].sum() / gt.size


def variation_of_information(gt, seg):
    from skimage.metrics import variation_of_information as vi

    return float(sum(vi(gt, seg)))


def adjusted_rand(gt, seg):
    """Adjusted Rand index from the contingency table (skimage has none)."""
    g_ids, g_inv = np.unique(gt, return_inverse=True)
    s_ids, s_inv = np.unique(seg, return_inverse=True)
    table = np.zeros((g_ids.size, s_ids.size))
    np.add.at(table, (g_inv.ravel(), s_inv.ravel()), 1)

    def comb(x):
        return x * (x - 1) / 2.0

    n = gt.size
    sum_ij = comb(table).sum()
    a = comb(table.sum(axis=1)).sum()
    b = comb(table.sum(axis=0)).sum()
    expected = a * b / comb(n)
    return float((sum_ij - expected) / (0.5 * (a + b) - expected))


def all_scores(gt, seg):
    out = prague_scores(gt, seg)
    out.update(acc=100 * matched_accuracy(gt, seg), ARI=adjusted_rand(gt, seg),
               VI=variation_of_information(gt, seg), K=len(np.unique(seg[seg > 0])))
    return out
