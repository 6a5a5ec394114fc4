"""Mammogram regions of interest (docs/mammography.md) on mini-MIAS, run by hand:
the chapter's plain grey-level filter (``filter_regions``) on a half split.

Superseded for the shipped pipeline by ``benchmarks/bench_froc.py`` (issue 17:
cross-validated FROC of the scored candidates, strict and lenient rules, the
no-CAR control and the DoG baseline); kept for the grey-level filter alone.

    PYTHONPATH=. python benchmarks/bench_mammography.py [--limit N] [--cache DIR]

(about 10-30 s per image for the segmentation, cached: the first full run
takes 15-40 minutes on 2 cores.)

1. Split: the 81 images in refnum order, even positions learn (mdb001,
   mdb009, ...), odd positions are held out (mdb005, mdb013, ...); each side
   has 6 mass images (6 and 7 mass findings).
2. Learns the reference grey (docs/mammography.md): the median, over the learning split's
   mass findings (CIRC, SPIC, MISC), of the mean grey level (8-bit / 255)
   inside the ground-truth circle. ``car_napari.mammography.REFERENCE_GREY``
   must be the printed value.
3. Segments every breast once (``segment_breast`` at ``work_side`` 512,
   keeping the merge-history states with ``DEFAULT_POOL_SEGMENTS`` segments;
   cached in ``--cache`` so re-runs only redo the cheap filtering), tunes
   ``tolerance`` and
   ``max_regions`` (top-N by score per image) on the learning split only:
   the highest sensitivity with at most 3 false regions per image (ties: fewer
   false regions), and evaluates on the held-out split and on all images.
4. Control: the same filter on the breast as one segment (no CAR
   segmentation), to show what the segmentation adds.
5. Baseline: ``skimage.feature.blob_dog`` on the mammogram (block-averaged
   by 4 for speed, like ours), the 5 strongest blobs inside the breast, each
   a disc of radius sqrt(2) sigma.

Scoring: a mass finding is detected when a region's centroid lies within its
radius or its centre lies in a region; a region that matches no mass finding
is a false region (counted over all images of the split, NORM ones too).
The second rule rewards big regions (a density band holding the mass centre
counts), so the table also gives the "strict" sensitivity (centroid within
the radius only) and the median equivalent radius of the kept regions.
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

import numpy as np
from skimage import io

from car_napari import mammography as mm
from car_napari.mammography._images import _block_mean

# the data next to the checkout, or where CAR_NAPARI_MINI_MIAS says (a worktree elsewhere)
DATA = Path(os.environ.get("CAR_NAPARI_MINI_MIAS", Path(__file__).resolve().parents[1].parent
                           / "shared" / "data" / "mammograms" / "mini-mias"))
MASSES = ("CIRC", "SPIC", "MISC")


def load_truth():
    with open(DATA / "ground_truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    names = sorted({r["refnum"] for r in rows})
    masses = {n: [] for n in names}
    for r in rows:
        if r["class"] in MASSES and r["col"]:
            masses[r["refnum"]].append((int(r["row"]), int(r["col"]), int(r["radius"])))
    return names, masses


def read(name):
    return io.imread(DATA / f"{name}.png")


def disc(shape, row, col, radius):
    yy, xx = np.ogrid[: shape[0], : shape[1]]
    return (yy - row) ** 2 + (xx - col) ** 2 <= radius**2


def learn_reference(names, masses):
    greys = []
    for n in names:
        if masses[n]:
            image = read(n) / 255.0
            greys += [image[disc(image.shape, *m)].mean() for m in masses[n]]
    return np.array(greys)


def score_image(labels, table, findings, strict=False):
    """(detected flags per finding, false regions) for one image; ``strict``:
    only a centroid within the radius counts."""
    cents = np.stack([table["centroid_row"], table["centroid_col"]], axis=1) if len(
        table["label"]) else np.zeros((0, 2))
    matched = np.zeros(len(cents), bool)
    hit = []
    for row, col, radius in findings:
        near = np.hypot(cents[:, 0] - row, cents[:, 1] - col) <= radius
        inside = labels[min(row, labels.shape[0] - 1), min(col, labels.shape[1] - 1)]
        if inside > 0 and not strict:
            near[table["label"] == inside] = True
        matched |= near
        hit.append(bool(near.any()))
    return hit, int((~matched).sum())


def summarise(per_image, names):
    hits = [h for n in names for h in per_image[n][0]]
    fp = sum(per_image[n][1] for n in names)
    secs = [per_image[n][2] for n in names]
    strict = [h for n in names for h in per_image[n][3]]
    radii = [r for n in names for r in per_image[n][4]]
    return (np.mean(hits) if hits else float("nan"), len(hits), fp / len(names),
            float(np.mean(secs)), np.mean(strict) if strict else float("nan"),
            float(np.median(radii)) if radii else float("nan"))


def evaluate(labels, table, findings, secs):
    hit, fp = score_image(labels, table, findings)
    strict, _ = score_image(labels, table, findings, strict=True)
    radii = np.sqrt(np.asarray(table["area"], float) / np.pi) if "area" in table else (
        np.sqrt(np.bincount(labels.ravel())[1:] / np.pi))
    return hit, fp, secs, strict, list(radii)


def segments_for(name, cache):
    """Pooled labellings (list of (H, W)) and segmentation seconds."""
    path = cache / f"{name}.npz"
    if path.exists():
        z = np.load(path)
        return list(z["pooled"]), float(z["seconds"])
    image = read(name)
    t = time.perf_counter()
    out = mm.segment_breast(image, pool=mm.DEFAULT_POOL_SEGMENTS)
    seconds = time.perf_counter() - t
    pooled = np.array(out.pooled, np.uint8)
    np.savez_compressed(path, pooled=pooled, seconds=seconds)
    return list(pooled), seconds


def blob_baseline(image, top=5, factor=4):
    from scipy import ndimage
    from skimage.feature import blob_dog

    grey = image / 255.0
    breast = mm.detect_breast(grey)
    small = _block_mean(grey, factor)
    blobs = blob_dog(small, min_sigma=2, max_sigma=24, threshold=0.02)
    keep = []
    for r, c, s in blobs:
        R, C = int(r) * factor, int(c) * factor
        if breast[min(R, breast.shape[0] - 1), min(C, breast.shape[1] - 1)]:
            # normalised DoG response at the blob centre ranks the blobs
            resp = s * (ndimage.gaussian_filter(small, s)[int(r), int(c)]
                        - ndimage.gaussian_filter(small, 1.6 * s)[int(r), int(c)])
            keep.append((resp, R, C, np.sqrt(2) * s * factor))
    keep.sort(key=lambda t: -t[0])
    labels = np.zeros(image.shape, np.int32)
    table = {k: [] for k in ("label", "centroid_row", "centroid_col")}
    for i, (_, R, C, rad) in enumerate(keep[:top], start=1):
        labels[disc(image.shape, R, C, rad) & (labels == 0)] = i
        table["label"].append(i)
        table["centroid_row"].append(R)
        table["centroid_col"].append(C)
    return labels, {k: np.asarray(v) for k, v in table.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=None,
                    help="development: every mass image plus only the first N images "
                         "without a mass, per split")
    ap.add_argument("--cache", default="/tmp/car_napari_mammo_cache_pool512")
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    names, masses = load_truth()
    learn, held = names[0::2], names[1::2]
    if args.limit is not None:
        # every mass image, plus the first N images without a mass, per split
        def pick(ns):
            return [n for n in ns if masses[n]] + [n for n in ns if not masses[n]][: args.limit]

        learn, held = sorted(pick(learn)), sorted(pick(held))
    everything = sorted(learn + held)

    # (a) reference grey
    g_learn = learn_reference(learn, masses)
    g_held = learn_reference(held, masses)
    ref = float(np.median(g_learn))
    print(f"mass findings: {len(g_learn)} learning, {len(g_held)} held out")
    print(f"learned reference grey (median mean grey of learning masses): {ref:.3f}")
    print(f"  held-out median {np.median(g_held):.3f}, all-image median "
          f"{np.median(np.r_[g_learn, g_held]):.3f}; learning masses: "
          f"{np.round(np.sort(g_learn), 3).tolist()}")
    if abs(ref - mm.REFERENCE_GREY) > 5e-4:
        print(f"  NOTE: car_napari.mammography.REFERENCE_GREY is {mm.REFERENCE_GREY}; "
              "update it to the learned value.")

    # segmentation once per image
    segs = {}
    # mass images first, so a partial (interrupted) run still caches them all
    order = sorted(everything, key=lambda n: (not masses[n], n))
    for i, n in enumerate(order):
        segs[n] = segments_for(n, cache)
        print(f"\rsegmented {i + 1}/{len(everything)}", end="", flush=True)
    print()

    def run(names_, tol, top, control=False):
        out = {}
        for n in names_:
            image = read(n)
            t = time.perf_counter()
            # control: no CAR segmentation, the whole breast as one segment
            seg = (segs[n][0][0] > 0).astype(np.int32) if control else segs[n][0]
            labels, table = mm.filter_regions(image, seg, reference=ref, tolerance=tol,
                                              max_regions=top)
            secs = segs[n][1] + time.perf_counter() - t
            out[n] = evaluate(labels, table, masses[n], secs)
        return out

    # (b) tune tolerance and top-N on the learning split
    print("\ntuning on the learning split (sensitivity, false regions/image):")
    best = None
    for tol in (0.1, 0.15, 0.2, 0.3):
        res = run(learn, tol, None)
        line = [f"tol {tol:5.3f}:"]
        for top in (1, 2, 3, 5, None):
            res_top = run(learn, tol, top) if top is not None else res
            sens, _, fpi, _, _, _ = summarise(res_top, learn)
            line.append(f"top {top}: {sens:.2f}/{fpi:.2f}")
            key = (fpi <= 3.0, sens, -fpi)
            if best is None or key > best[0]:
                best = (key, tol, top)
        print("  " + "  ".join(line))
    _, tol, top = best
    print(f"chosen: tolerance {tol}, max_regions {top}")
    if (tol, top) != (mm.REFERENCE_TOLERANCE, mm.DEFAULT_MAX_REGIONS):
        print(f"  NOTE: shipped defaults are tolerance {mm.REFERENCE_TOLERANCE}, "
              f"max_regions {mm.DEFAULT_MAX_REGIONS}.")

    # evaluation
    ours = run(everything, tol, top)
    control = run(everything, tol, top, control=True)
    blobs = {}
    for n in everything:
        image = read(n)
        t = time.perf_counter()
        labels, table = blob_baseline(image)
        secs = time.perf_counter() - t
        blobs[n] = evaluate(labels, table, masses[n], secs)
    print("\n| method | split | images | mass findings | sensitivity | strict sensitivity "
          "| false regions/image | median region radius (px) | s/image |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, res in ((f"CAR ROIs (tol {tol}, top {top})", ours),
                       ("control: breast as one segment, same filter", control),
                       ("DoG blobs (top 5)", blobs)):
        for split, ns in (("learn", learn), ("held out", held), ("all", everything)):
            sens, nf, fpi, secs, strict, rad = summarise(res, ns)
            print(f"| {label} | {split} | {len(ns)} | {nf} | {sens:.2f} | {strict:.2f} | "
                  f"{fpi:.2f} | {rad:.0f} | {secs:.1f} |")
    missed = [(n, m) for n in everything
              for m, h in zip(masses[n], ours[n][0], strict=True) if not h]
    print(f"\nmissed by ours: {missed}")


if __name__ == "__main__":
    main()
