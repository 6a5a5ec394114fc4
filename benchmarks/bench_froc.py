"""Mammogram ROIs on mini-MIAS: cross-validated FROC (issue 17), run by hand.

    PYTHONPATH=. nice -n 10 python benchmarks/bench_froc.py [--prepare-only]
        [--cache DIR] [--nested] [--png docs/froc_mammography.png] [--write-model]

(``CAR_NAPARI_MINI_MIAS``: the data folder, when the checkout is not next to
``shared/``.)

1. Segments every breast of ``../shared/data/mammograms/mini-mias`` once
   (the package's pipeline: ``segment_breast`` at work side 512, the merge
   history's 8, 10 and 12 segment states, with the CAR features kept) and
   caches, per image, the labellings and the CAR features on the analysis
   grid (``--cache``, .npz): re-runs only redo the cheap part.
2. Candidates and their descriptors (``car_napari.mammography._candidates``)
   for the CAR pipeline, for the no-CAR control (the breast as one
   segment, the same bright-region cutting, grey and shape descriptors only:
   nothing of the CAR model) and for both pooled (the CAR segments plus the
   breast as one more segment, so the CAR can only add candidates). Every
   candidate also carries the CAR "surprise" (a grey CAR model fitted on its
   ring predicts it: ``_candidates._surprise``) and its contrast against
   its host segment (``_candidates._host``).
3. 5-fold cross-validation by image (fold = md5 of the name mod 5): a
   logistic regression (scikit-learn, C=1, balanced classes; positives: the
   candidates whose centroid lies within a mass radius, at least 10 px) is
   fitted on 4 folds and scores the 5th; findings are merged from the
   scored candidates exactly as the package does. No constant is chosen on
   the images it is scored on. The variants of the table were declared
   before they were measured. ``--nested``: also the whole procedure with
   the candidate set, the descriptor families and C (0.01, 0.1, 1) chosen
   inside each outer training part by an inner CV over its 4 folds
   (``nested_choices``: 33 choices).
4. FROC (sensitivity against false regions per image over all thresholds),
   strict rule (a region's centroid within the mass radius, at least 10 px)
   and lenient rule (or the mass centre inside the region), for the CAR
   pipeline, the no-CAR control and a difference-of-Gaussians blob baseline
   (``skimage.feature.blob_dog``, blobs in the breast ranked by their
   normalised DoG response). Writes the plot (``--png``) and prints the
   table at 1, 2 and 3 false regions per image.
5. ``--write-model``: fits the model on all images and writes
   ``car_napari/mammography/roi_model.json`` (coefficients, standardisation,
   the operating points: score threshold per false marks per image on all
   images, with the cross-validated sensitivity there).

Masses: classes CIRC, SPIC, MISC of ``ground_truth.csv`` (13 findings in 12
images); every other region is a false one (also on CALC, ARCH, ASYM
images).
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from bench_mammography import load_truth
from skimage import io

from car_napari._progress import drain
from car_napari.mammography import _candidates as C
from car_napari.mammography._images import _block_mean, _grey01
from car_napari.mammography._regions import (
    _ANALYSIS_SIDE,
    SPLIT_DELTA,
    SPLIT_SIGMAS,
)
from car_napari.mammography._rois import DEFAULT_POOL_SEGMENTS, _iter_segment_grey

# the data next to the checkout, or where CAR_NAPARI_MINI_MIAS says (a worktree elsewhere)
DATA = Path(os.environ.get("CAR_NAPARI_MINI_MIAS", Path(__file__).resolve().parents[1].parent
                           / "shared" / "data" / "mammograms" / "mini-mias"))
MASSES = ("CIRC", "SPIC", "MISC")
FOLDS = 5
RATES = (1.0, 2.0, 3.0)
MODES = ("car", "pooled", "control")
SHIPPED = "CAR: grey + shape"
NESTED = "CAR, chosen inside each training part (nested CV)"
# the regularisations the nested CV chooses among (inverse strength)
CS = (0.01, 0.1, 1.0)
MIN_RADIUS = 10.0


_FOLDS = {}


def _hash(name):
    return int(hashlib.md5(name.encode()).hexdigest(), 16)


def make_folds(names, masses):
    """Fixed folds, stratified: the mass images in the order of the md5 of
    their names dealt round-robin into the 5 folds, then the others the same
    way (so every fold has 2 or 3 mass images)."""
    _FOLDS.clear()
    k = 0
    for group in ([n for n in names if masses[n]], [n for n in names if not masses[n]]):
        for n in sorted(group, key=_hash):
            _FOLDS[n] = k % FOLDS
            k += 1


def fold_of(name):
    return _FOLDS[name]


def read(name):
    return io.imread(DATA / f"{name}.png")


def analysis_grid(grey_full):
    H, W = grey_full.shape
    f = max(1, round(max(H, W) / _ANALYSIS_SIDE))
    return f, _block_mean(grey_full, f)


def segmentation(name, cache):
    """Cached: small labellings (P, h, w) uint8, texture grid (h, w, D) float16,
    seconds of the segmentation."""
    path = cache / f"{name}.npz"
    if path.exists():
        z = np.load(path)
        return z["labellings"], z["texture"].astype(np.float32), float(z["seconds"])
    grey = _grey01(read(name))
    t = time.perf_counter()
    seg = drain(_iter_segment_grey(grey, breast=None, n_segments=None, levels=3,
                                   neighbourhood=2, n_init=16, work_side=512, seed=0,
                                   pool=DEFAULT_POOL_SEGMENTS, segment_options=None,
                                   keep_features=True))
    seconds = time.perf_counter() - t
    f, small = analysis_grid(grey)
    h, w = small.shape
    labs = np.array([s[f // 2 :: f, f // 2 :: f][:h, :w] for s in seg.pooled], np.uint8)
    tex = C._texture_grid(seg.features, seg.box, seg.factor, f, (h, w))
    np.savez(path, labellings=labs, texture=tex.astype(np.float16), seconds=seconds)
    return labs, tex, seconds


def candidates(name, cache, mode):
    """(Candidate list, descriptor matrix, f) of one image, ``mode`` "car",
    "control" or "pooled" (the CAR segments' candidates and the control's
    together) (cached as a pickle next to the segmentation, keyed by the
    descriptor code's version)."""
    import pickle

    key = hashlib.md5(Path(C.__file__).read_bytes()).hexdigest()[:8]
    path = cache / f"{name}_{mode}_{key}.pkl"
    if path.exists():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    out = _candidates(name, cache, mode)
    with open(path, "wb") as fh:
        pickle.dump(out, fh)
    return out


def _candidates(name, cache, mode):
    grey = _grey01(read(name))
    f, small = analysis_grid(grey)
    labs, tex, _ = segmentation(name, cache)
    breast = labs[0] > 0
    if mode == "control":
        labs, tex = breast[None].astype(np.uint8), None
    elif mode == "pooled":
        # the breast as one more "segment": the control's candidates join in
        labs = np.concatenate([labs, breast[None].astype(np.uint8)])
    H, W = grey.shape
    min_area = max(16, H * W // 4000)
    cands = C._generate(small, list(labs), breast, split=True,
                        sigmas=[s / f for s in SPLIT_SIGMAS], delta=SPLIT_DELTA,
                        min_area=max(4, min_area // (f * f)))
    kept, X = drain(C._describe(small, list(labs), breast, tex, cands, f=f, side=max(H, W)))
    return kept, X, f


def labels_for(kept, f, findings):
    """Strict positives: the mass (index in ``findings``) whose max(r, 10)
    holds the candidate's centroid (full res), -1 for none."""
    y = np.full(len(kept), -1)
    for k, c in enumerate(kept):
        r, col = (c.centroid[0] + 0.5) * f - 0.5, (c.centroid[1] + 0.5) * f - 0.5
        for j, (R, Cc, rad) in enumerate(findings):
            if np.hypot(r - R, col - Cc) <= max(rad, MIN_RADIUS):
                y[k] = j
                break
    return y


def training_set(d, names, cols):
    """X, y (bool), mass groups (-1: negative) of the images ``names``."""
    X = np.vstack([d[n][1] for n in names])[:, cols]
    ids = [np.where(d[n][3] >= 0, 100 * i + d[n][3], -1) for i, n in enumerate(names)]
    groups = np.concatenate(ids)
    return X, groups >= 0, groups


def marks_of(findings_merged, f):
    """(score, centroid row, col (full res), mask, box) per merged finding."""
    out = []
    for score, mask, (r0, _r1, c0, _c1), _best in findings_merged:
        rr, cc = np.nonzero(mask)
        out.append((score, (rr.mean() + r0 + 0.5) * f - 0.5, (cc.mean() + c0 + 0.5) * f - 0.5,
                    mask, (r0, c0)))
    return out


def match(marks, masses, f, lenient):
    """Per mark: index of the first mass it hits (or -1)."""
    hit = []
    for _s, r, c, mask, (r0, c0) in marks:
        j = -1
        for k, (R, Cc, rad) in enumerate(masses):
            if np.hypot(r - R, c - Cc) <= max(rad, MIN_RADIUS):
                j = k
                break
            if lenient:
                a, b = R // f - r0, Cc // f - c0
                if 0 <= a < mask.shape[0] and 0 <= b < mask.shape[1] and mask[a, b]:
                    j = k
                    break
        hit.append(j)
    return hit


def froc(per_image, n_masses, n_images):
    """per_image: list of (scores, hit mass ids (per mark, -1 = false), image
    id). Returns arrays (false per image, sensitivity, threshold) over all
    thresholds, best first."""
    rows = [(s, h, i) for scores, hits, i in per_image for s, h in zip(scores, hits, strict=True)]
    rows.sort(key=lambda t: -t[0])
    seen, fp = set(), 0
    fpi, sens, thr = [0.0], [0.0], [np.inf]
    for s, h, i in rows:
        if h < 0:
            fp += 1
        else:
            seen.add((i, h))
        fpi.append(fp / n_images)
        sens.append(len(seen) / n_masses)
        thr.append(s)
    return np.array(fpi), np.array(sens), np.array(thr)


def found_at(res, rate):
    """Names of the masses found (strict) at the best threshold with at most
    ``rate`` false regions per image."""
    names = sorted(res)
    marks = sorted(((s, h, n) for n in names for s, h in zip(res[n][0], res[n][1],
                                                             strict=True)), key=lambda t: -t[0])
    fp, seen, best = 0, set(), set()
    for _s, h, n in marks:
        if h < 0:
            fp += 1
            if fp > rate * len(names) + 1e-9:
                break
        else:
            seen.add(f"{n}#{h}")
        best = set(seen)
    return sorted(best)


def at_rate(curve, rate):
    """Best sensitivity with at most ``rate`` false regions per image, and
    the masses found there."""
    fpi, sens, _ = curve
    ok = fpi <= rate + 1e-12
    return float(sens[ok].max())


def fit_lr(X, y, groups=None, c=1.0):
    """Logistic regression (inverse regularisation ``c``); weights: every mass counts once (its
    positive candidates share a weight of 1), the negatives together weigh
    as much as the positives."""
    from sklearn.linear_model import LogisticRegression

    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale[scale == 0] = 1.0
    y = np.asarray(y, bool)
    w = np.ones(len(y))
    if groups is not None:
        pos = groups >= 0
        for g in np.unique(groups[pos]):
            w[groups == g] = 1.0 / np.sum(groups == g)
        w[~pos] = w[pos].sum() / max(1, np.sum(~pos))
    lr = LogisticRegression(C=c, max_iter=2000)
    lr.fit((X - mean) / scale, y, sample_weight=w)
    return mean, scale, lr.coef_[0], float(lr.intercept_[0])


def model_of(cols, params):
    mean, scale, coef, intercept = params
    return C.RoiModel({"descriptors": [C.DESCRIPTORS[c] for c in cols], "mean": mean.tolist(),
                       "scale": scale.tolist(), "coef": coef.tolist(), "intercept": intercept})


def cross_validate(data, names, masses, cols, c=1.0):
    """CV FROC marks: per image (scores, strict hits, lenient hits)."""
    out = {}
    for k in range(FOLDS):
        train = [n for n in names if fold_of(n) != k]
        test = [n for n in names if fold_of(n) == k]
        model = model_of(cols, fit_lr(*training_set(data, train, cols), c=c))
        for n in test:
            kept, Xn, f, _ = data[n]
            out[n] = evaluate_image(model, kept, Xn, f, masses[n])
    return out


def nested_choices(idx):
    """What the nested CV chooses among: label -> (mode, descriptor columns,
    C): the CAR or the pooled candidates with four descriptor sets, the
    control's candidates with the CAR surprise, three regularisations
    (fewest descriptors and strongest regularisation first: ties go to
    them)."""
    gs = idx["grey"] + idx["shape"]
    sets = {"grey + shape": gs, "+ surprise": gs + idx["surprise"],
            "+ texture": gs + idx["texture"],
            "+ texture + surprise": gs + idx["texture"] + idx["surprise"],
            "+ host": gs + idx["host"]}
    out = {f"{mode}: {name}, C={c:g}": (mode, cols, c)
           for mode in ("car", "pooled") for name, cols in sets.items() for c in CS}
    # the bright-region cutting of the whole breast, described with the CAR
    # surprise (its candidates carry no CAR texture features)
    out.update({f"control: + surprise, C={c:g}": ("control", sets["+ surprise"], c)
                for c in CS})
    return out


def select(data, names, masses, choices):
    """The choice with the best mean strict sensitivity at 1, 2, 3 false
    regions per image in a leave-one-fold-out CV over the folds of
    ``names``; returns (label, value)."""
    best = None
    for label, (mode, cols, c) in choices.items():
        d = data[mode]
        inner = {}
        for j in sorted(set(fold_of(n) for n in names)):
            fit_on = [n for n in names if fold_of(n) != j]
            model = model_of(cols, fit_lr(*training_set(d, fit_on, cols), c=c))
            for n in names:
                if fold_of(n) == j:
                    kept, Xn, f, _ = d[n]
                    inner[n] = evaluate_image(model, kept, Xn, f, masses[n])
        cv = curves(inner, names, masses)["strict"]
        value = float(np.mean([at_rate(cv, r) for r in RATES]))
        # ties: the first (the fewest descriptors, the strongest regularisation)
        if best is None or value > best[1] + 1e-12:
            best = (label, value)
    return best


def nested(data, names, masses, choices):
    """CV FROC marks where the candidate set, the descriptor set and the
    regularisation (``choices``: label -> (mode, cols, C); ``data``: mode ->
    per-image data) are chosen inside each training part by :func:`select`
    (an inner CV over its 4 folds): the honest figure of the whole
    procedure, selection included. Returns the marks and the choice per
    outer fold."""
    out, chosen = {}, {}
    for k in range(FOLDS):
        train = [n for n in names if fold_of(n) != k]
        test = [n for n in names if fold_of(n) == k]
        label, _ = select(data, train, masses, choices)
        chosen[k] = label
        mode, cols, c = choices[label]
        model = model_of(cols, fit_lr(*training_set(data[mode], train, cols), c=c))
        for n in test:
            kept, Xn, f, _ = data[mode][n]
            out[n] = evaluate_image(model, kept, Xn, f, masses[n])
    return out, chosen


def evaluate_image(model, kept, X, f, findings):
    scores = model.score(X) if len(kept) else np.zeros(0)
    shape = (1024 // f + 1, 1024 // f + 1)  # covers every box of the grid
    merged = C._visible(C._merge(kept, scores), shape)
    marks = marks_of(merged, f)
    return ([m[0] for m in marks], match(marks, findings, f, False),
            match(marks, findings, f, True))


def curves(results, names, masses):
    n_masses = sum(len(masses[n]) for n in names)
    out = {}
    for j, rule in ((1, "strict"), (2, "lenient")):
        per = [(results[n][0], results[n][j], i) for i, n in enumerate(names)]
        out[rule] = froc(per, n_masses, len(names))
    return out


def cached(path, make):
    import pickle

    if path.exists():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    out = make()
    with open(path, "wb") as fh:
        pickle.dump(out, fh)
    return out


def dog_baseline(name):
    """DoG blobs in the breast, scored by the normalised DoG response."""
    from scipy import ndimage
    from skimage.feature import blob_dog

    from car_napari.mammography import detect_breast

    grey = read(name) / 255.0
    breast = detect_breast(grey)
    factor = 4
    small = _block_mean(grey, factor)
    blobs = blob_dog(small, min_sigma=2, max_sigma=24, threshold=0.005)
    marks = []
    dogs = {}
    for r, c, s in blobs:
        R, Cc = int(r) * factor + factor // 2, int(c) * factor + factor // 2
        if breast[min(R, breast.shape[0] - 1), min(Cc, breast.shape[1] - 1)]:
            if s not in dogs:  # blob sigmas come from a few scales
                dogs[s] = s * (ndimage.gaussian_filter(small, s)
                               - ndimage.gaussian_filter(small, 1.6 * s))
            resp = dogs[s][int(r), int(c)]
            rad = np.sqrt(2) * s  # analysis pixels of the factor-4 grid
            yy, xx = np.ogrid[-int(rad) - 1 : int(rad) + 2, -int(rad) - 1 : int(rad) + 2]
            mask = yy**2 + xx**2 <= rad**2
            marks.append((float(resp), float(R), float(Cc), mask,
                          (int(r) - int(rad) - 1, int(c) - int(rad) - 1)))
    return marks


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="/tmp/car_napari_froc_cache")
    ap.add_argument("--prepare-only", action="store_true")
    ap.add_argument("--png", default=None)
    ap.add_argument("--write-model", action="store_true")
    ap.add_argument("--nested", action="store_true",
                    help="also choose the descriptor families inside each training part")
    ap.add_argument("--limit", type=int, default=None, help="development: first N images")
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    names, masses = load_truth()
    make_folds(names, masses)
    order = sorted(names, key=lambda n: (not masses[n], n))
    if args.limit:
        order = order[: args.limit]
        names = sorted(order)
    secs = []
    for i, n in enumerate(order):
        secs.append(segmentation(n, cache)[2])
        print(f"\rsegmented {i + 1}/{len(order)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    if args.prepare_only:
        return
    n_masses = sum(len(masses[n]) for n in names)
    print(f"{len(names)} images, {n_masses} mass findings in "
          f"{sum(bool(masses[n]) for n in names)} images; folds: "
          f"{[sum(fold_of(n) == k for n in names) for k in range(FOLDS)]} images, "
          f"{[sum(len(masses[n]) for n in names if fold_of(n) == k) for k in range(FOLDS)]} "
          "masses")
    print(f"segmentation (cached, as first run): median {np.median(secs):.1f} s/image")

    data = {}
    for mode in MODES:
        d = {}
        for n in names:
            kept, X, f = candidates(n, cache, mode)
            d[n] = (kept, X, f, labels_for(kept, f, masses[n]))
        data[mode] = d
        print(f"{mode}: candidates per image median "
              f"{np.median([len(d[n][0]) for n in names]):.0f}, positives "
              f"{sum(int((d[n][3] >= 0).sum()) for n in names)}")

    idx = {fam: [C.DESCRIPTORS.index(x) for x in C.FAMILIES[fam]] for fam in C.FAMILIES}
    gs = idx["grey"] + idx["shape"]
    # the variants, declared before any was measured (see the README)
    variants = {
        "CAR: grey + shape": ("car", gs),
        "CAR: grey + shape + texture": ("car", gs + idx["texture"]),
        "CAR: grey + shape + surprise": ("car", gs + idx["surprise"]),
        "CAR + control pooled: grey + shape": ("pooled", gs),
        "CAR + control pooled: grey + shape + surprise": ("pooled", gs + idx["surprise"]),
        "CAR + control pooled: grey + shape + texture + surprise":
            ("pooled", gs + idx["texture"] + idx["surprise"]),
        "control (no CAR): grey + shape": ("control", gs),
        "control's candidates + CAR surprise": ("control", gs + idx["surprise"]),
        # added after the first runs (the brief's "contrast against the host
        # CAR segment instead of a ring")
        "CAR: grey + shape + host segment": ("car", gs + idx["host"]),
        "CAR + control pooled: grey + shape + host segment": ("pooled", gs + idx["host"]),
    }
    results = {}
    t0 = time.perf_counter()
    raw = {}
    for label, (mode, cols) in variants.items():
        raw[label] = res = cross_validate(data[mode], names, masses, cols)
        results[label] = curves(res, names, masses)
    print(f"cross-validation of {len(variants)} variants: {time.perf_counter() - t0:.0f} s")
    choices = nested_choices(idx)
    if args.nested:
        t0 = time.perf_counter()
        res, chosen = nested(data, names, masses, choices)
        results[NESTED] = curves(res, names, masses)
        raw[NESTED] = res
        print(f"nested CV over {len(choices)} choices: {time.perf_counter() - t0:.0f} s; "
              f"inner-CV choice per outer fold: {chosen}")
    dog = {}
    for n in names:
        marks = cached(cache / f"{n}_dog.pkl", lambda n=n: dog_baseline(n))
        dog[n] = ([m[0] for m in marks], match(marks, masses[n], 4, False),
                  match(marks, masses[n], 4, True))
    results["DoG blobs"] = curves(dog, names, masses)

    print("\n| method | rule | " + " | ".join(f"sens. at {r:g} FP/image" for r in RATES) + " |")
    print("| --- | --- |" + " --- |" * len(RATES))
    for label, cv in results.items():
        for rule in ("strict", "lenient"):
            vals = [at_rate(cv[rule], r) for r in RATES]
            cells = " | ".join(f"{v:.2f} ({round(v * n_masses)}/{n_masses})" for v in vals)
            print(f"| {label} | {rule} | {cells} |")

    for label in raw:
        print(f"{label}: masses found (strict) at 2 FP/image: {found_at(raw[label], 2.0)}")

    if args.png:
        shown = [k for k in (NESTED, "CAR: grey + shape", "control (no CAR): grey + shape",
                             "DoG blobs") if k in results]
        plot({k: results[k] for k in shown}, args.png, n_masses, len(names))
    if args.write_model:
        # the shipped descriptors: the best CAR variant of this CV, set when
        # the texture family was first compared (issue 17); neither the
        # surprise or host families nor the pooled candidates raised the CV
        # figures,
        # and the nested choice among them is lower still: all left out
        mode, cols = variants[SHIPPED]
        write_model(data[mode], names, masses, cols, results[SHIPPED])


def plot(results, png, n_masses, n_images):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=110)
    styles = {"strict": "-", "lenient": ":"}
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (label, cv) in enumerate(results.items()):
        for rule in ("strict", "lenient"):
            fpi, sens, _ = cv[rule]
            ax.step(fpi, sens, where="post", ls=styles[rule], color=colours[k % len(colours)],
                    label=f"{label} ({rule})" if rule == "strict" else None, lw=1.4)
    ax.set_xlim(0, 8)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("false regions per image")
    ax.set_ylabel("sensitivity (masses found)")
    ax.set_title(f"mini-MIAS, 5-fold CV by image: {n_masses} masses, {n_images} images\n"
                 "solid: strict (centroid within radius), dotted: lenient", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(png)
    print(f"plot: {png}")


def write_model(d, names, masses, cols, cv):
    params = fit_lr(*training_set(d, names, cols))
    model = model_of(cols, params)
    res = {n: evaluate_image(model, d[n][0], d[n][1], d[n][2], masses[n]) for n in names}
    fpi, sens, thr = curves(res, names, masses)["strict"]
    points = []
    for rate in (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0):
        ok = np.flatnonzero(fpi <= rate + 1e-12)
        j = ok[-1]  # the lowest threshold with at most ``rate`` false marks per image
        points.append({"marks_per_image": rate, "threshold": float(thr[j]) if j else 1.0,
                       "cv_sensitivity_strict": at_rate(cv["strict"], rate),
                       "cv_sensitivity_lenient": at_rate(cv["lenient"], rate)})
    mean, scale, coef, intercept = params
    spec = {
        "what": "logistic score of mammogram ROI candidates (car_napari.mammography)",
        "made_by": "PYTHONPATH=. nice -n 10 python benchmarks/bench_froc.py --write-model",
        "date": datetime.date.today().isoformat(),
        "data": f"mini-MIAS, all {len(names)} images, "
                f"{sum(len(masses[n]) for n in names)} mass findings (CIRC, SPIC, MISC)",
        "fit": "sklearn LogisticRegression(C=1) on standardised descriptors; positive = "
               "candidate centroid within the mass radius (>= 10 px); weights: each mass's "
               "positives share 1, the negatives together weigh as much as the positives",
        "descriptors": [C.DESCRIPTORS[c] for c in cols],
        "mean": mean.tolist(), "scale": scale.tolist(), "coef": coef.tolist(),
        "intercept": intercept,
        "operating_points_note": "threshold: the lowest score with at most marks_per_image "
                                 "false marks per image on the training images (all 81); "
                                 "cv_sensitivity_*: 5-fold cross-validated sensitivity there",
        "operating_points": points,
    }
    with open(C._MODEL_FILE, "w") as fh:
        json.dump(spec, fh, indent=1)
        fh.write("\n")
    print(f"model: {C._MODEL_FILE}")


if __name__ == "__main__":
    main()
