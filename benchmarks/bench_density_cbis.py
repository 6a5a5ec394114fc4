"""Breast-density class on 1,231 CBIS-DDSM films (issue 35): does the CAR
texture tell the density class better than the grey histogram, on a set
eight times mini-MIAS's, and does it help mini-MIAS as training data?

    PYTHONPATH=. nice -n 5 python benchmarks/bench_density_cbis.py [--jobs 2]
        [--boot 1000] [--cache DIR] [--only e1,e2,e3,e4]

**Labels.** ``benchmarks/data/cbis_ddsm_density.csv``: the BI-RADS breast
density (1 almost entirely fat, 2 scattered fibroglandular, 3 heterogeneously
dense, 4 extremely dense) of each film of ``cbis-ddsm-masses`` (the mass
training split), from CBIS-DDSM's ``mass_case_description_train_set.csv``
(Lee et al., Scientific Data 4:170177, 2017; The Cancer Imaging Archive,
CC BY 3.0). It was transcribed twice, independently, from two public copies
of that file; the two transcriptions were identical, name exactly the 1,231
films of the shared folder, give each film as many masses as ``boxes.csv``,
and give each patient one density. Mapped to mini-MIAS's classes: 1 -> F,
2 -> G, 3 and 4 -> D.

**Rows.** Each film's whole-breast descriptors (the class model's: CAR and
grey histogram, ``T.IMAGE_DESCRIPTORS``' first 21) by the package's
segmentation and shipped tissue model, the density at full resolution, as
``segment_tissue`` computes them; cached per image under ``--cache``, in a
folder named after the shipped model's files (a new model, new rows).
Single-threaded processes (``--jobs``); about 2.5 s a film.

**Evaluations** (declared before any CBIS row was seen, in stop 43;
multinomial logistic on standardised descriptors, as ``bench_tissue``;
the descriptor sets are ``bench_tissue.CLASS_VARIANTS``):

- E1, mini-MIAS 5-fold CV by image (``bench_tissue``'s folds), with the
  CBIS films added to every training fold. The pooling ("plain", "indicator":
  a column saying which set, "per-dataset z": each set standardised by its own
  training images) and C (0.1, 1) are chosen per outer fold by an inner
  stratified 5-fold CV on the mini-MIAS training images. Against mini-MIAS
  alone (C = 1, the shipped procedure) in the same run. Rule: the pooled
  CAR + histogram model would replace the shipped class model if it beat
  mini-MIAS alone by at least 0.02 without a lower kappa.
- E2, transfer: fitted on CBIS alone (per-dataset z, C = 1), tested on all
  161 mini-MIAS images.
- E3, CBIS 5-fold CV by patient (md5 of the patient number), 3 classes and
  the 4 BI-RADS grades; 95 % intervals by bootstrap over patients, paired
  differences against the histogram control.
- E4 (declared after E1-E3 were seen; no model, nothing chosen): the shipped
  mask's percent density per BI-RADS grade (mean, 95 % over women) and
  Spearman's rho between density and grade; the same per F/G/D on mini-MIAS
  (over images). Does the density ``segment_tissue`` reports follow the
  radiologists' grades on films it was never trained on?
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_tissue as B  # noqa: E402

from car_napari.mammography import _tissue as T  # noqa: E402

LABELS = Path(__file__).resolve().parent / "data" / "cbis_ddsm_density.csv"
CBIS = B.ROOT / "cbis-ddsm-masses"
BIRADS_TO_CLASS = {"1": "F", "2": "G", "3": "D", "4": "D"}
CONTROL = "histogram (control)"
MODES = ("plain", "indicator", "per-dataset z")
INNER_CS = (0.1, 1.0)


def cbis_labels():
    """{film name without .jpg: BI-RADS density '1'-'4'}."""
    with open(LABELS) as fh:
        return {r["file"].removesuffix(".jpg"): r["breast_density"] for r in csv.DictReader(fh)}


def model_key():
    """The shipped tissue model's files, hashed: the rows' cache folder."""
    digest = hashlib.md5()
    for name in ("tissue_model.json", "tissue_unet.npz"):
        digest.update((Path(T.__file__).with_name(name)).read_bytes())
    return digest.hexdigest()[:10]


def image_row(path):
    """The class model's descriptors of one mammogram, as ``segment_tissue``
    computes them (the density at full resolution)."""
    from skimage import io

    from car_napari._progress import drain
    from car_napari.mammography._images import _grey01
    from car_napari.mammography._rois import _iter_default_segmentation

    grey = _grey01(io.imread(path))
    seg = drain(_iter_default_segmentation(grey))
    model = T.shipped_tissue_model()
    _work, prob, row = T._describe_breast(grey, seg, model)
    fg = T._full_mask(prob > model.threshold, seg, grey.shape)
    row = row[: len(T.CAR_IMAGE_DESCRIPTORS + T.HISTOGRAM_DESCRIPTORS)].copy()
    row[0] = float(fg.sum()) / float(seg.breast.sum())
    return row


def _row_job(job):
    path, out = job
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        np.save(out, image_row(path))
    return out


def rows(cache, jobs):
    """(mini-MIAS names, rows, classes), (CBIS names, rows, BI-RADS)."""
    folder = cache / model_key()
    mias = B.mias_names()
    m_names = sorted(mias)
    dens = cbis_labels()
    c_names = sorted(dens)
    todo = [(B.MIAS / f"{n}.png", folder / "mias" / f"{n}.npy") for n in m_names]
    todo += [(CBIS / f"{n}.jpg", folder / "cbis" / f"{n}.npy") for n in c_names]
    todo = [t for t in todo if not t[1].exists()]
    if todo:
        import multiprocessing as mp

        t0 = time.perf_counter()
        with mp.get_context("spawn").Pool(jobs, initializer=B._single_threaded) as pool:
            for i, _ in enumerate(pool.imap_unordered(_row_job, todo, chunksize=4)):
                print(f"\rdescribed {i + 1}/{len(todo)}", end="", file=sys.stderr, flush=True)
        print(f" ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    Xm = np.array([np.load(folder / "mias" / f"{n}.npy") for n in m_names])
    Xc = np.array([np.load(folder / "cbis" / f"{n}.npy") for n in c_names])
    return ((m_names, Xm, np.array([mias[n] for n in m_names])),
            (c_names, Xc, np.array([dens[n] for n in c_names])))


def columns(variant):
    return [T.IMAGE_DESCRIPTORS.index(n) for n in B.CLASS_VARIANTS[variant]]


def standardised(X, reference):
    mean, scale = reference.mean(axis=0), reference.std(axis=0)
    scale[scale <= 0] = 1.0
    return (X - mean) / scale


def pooled_predictions(Xm_train, ym_train, Xc, yc, Xm_test, mode, c):
    """Classes of ``Xm_test`` by a model fitted on both sets, pooled by ``mode``."""
    if mode == "plain":
        X, test = np.vstack([Xm_train, Xc]), Xm_test
    elif mode == "indicator":
        which = np.r_[np.zeros(len(Xm_train)), np.ones(len(Xc))]
        X = np.column_stack([np.vstack([Xm_train, Xc]), which])
        test = np.column_stack([Xm_test, np.zeros(len(Xm_test))])
    else:
        X = np.vstack([standardised(Xm_train, Xm_train), standardised(Xc, Xc)])
        test = standardised(Xm_test, Xm_train)
    lr, mean, scale = B.fit_classes(X, np.r_[ym_train, yc], c)
    return lr.predict((test - mean) / scale).astype(str)


def choose_pooling(Xm, ym, Xc, yc):
    """(mode, C) of best inner-CV accuracy on these mini-MIAS images (the
    first declared on a tie)."""
    from sklearn.model_selection import StratifiedKFold

    scores = {}
    for mode in MODES:
        for c in INNER_CS:
            right = []
            for a, b in StratifiedKFold(5, shuffle=True, random_state=0).split(Xm, ym):
                right.extend(pooled_predictions(Xm[a], ym[a], Xc, yc, Xm[b], mode, c) == ym[b])
            scores[mode, c] = float(np.mean(right))
    return max(scores, key=scores.get)


def _summary(y, p, n_boot):
    right = (p == y).astype(float)
    lo, hi = B.bootstrap(right, n_boot)
    return f"accuracy {right.mean():.3f} [{lo:.3f}, {hi:.3f}], kappa {B.kappa(y, p):.3f}"


def _paired(a, b, y, n_boot):
    a, b = (a == y).astype(float), (b == y).astype(float)
    lo, hi = B.bootstrap((a, b), n_boot, stat=lambda u, v: np.mean(u - v))
    return f"{a.mean() - b.mean():+.3f} [{lo:+.3f}, {hi:+.3f}]"


def evaluate_pooled(mias, cbis, n_boot):
    """E1: mini-MIAS CV, alone and with the CBIS films in every training fold."""
    m_names, Xm, ym = mias
    yc = np.array([BIRADS_TO_CLASS[d] for d in cbis[2]])
    folds = np.array([B.fold_of(n) for n in m_names])
    preds = {}
    print(f"\nE1: mini-MIAS, 5-fold CV by image ({len(ym)} images), "
          f"CBIS ({len(yc)} films) in every training fold")
    for variant in B.CLASS_VARIANTS:
        cols = columns(variant)
        alone, pooled = np.empty(len(ym), object), np.empty(len(ym), object)
        chosen = []
        for k in range(B.FOLDS):
            train = folds != k
            lr, mean, scale = B.fit_classes(Xm[train][:, cols], ym[train], 1.0)
            alone[~train] = lr.predict((Xm[~train][:, cols] - mean) / scale)
            best = choose_pooling(Xm[train][:, cols], ym[train], cbis[1][:, cols], yc)
            chosen.append(best)
            pooled[~train] = pooled_predictions(Xm[train][:, cols], ym[train],
                                                cbis[1][:, cols], yc, Xm[~train][:, cols], *best)
        preds[variant] = alone.astype(str), pooled.astype(str)
        print(f"  {variant:22s} mini-MIAS alone: {_summary(ym, preds[variant][0], n_boot)}")
        print(f"  {variant:22s} pooled, nested:  {_summary(ym, preds[variant][1], n_boot)}")
        print(f"  {'':22s} chosen per fold: "
              + ", ".join(f"{mode} C={c:g}" for mode, c in chosen))
    shipped = "CAR+histogram"
    print(f"  paired, {shipped} pooled minus alone: "
          f"{_paired(preds[shipped][1], preds[shipped][0], ym, n_boot)}")
    for how, i in (("alone", 0), ("pooled", 1)):
        print(f"  paired, {how}, {shipped} minus histogram: "
              f"{_paired(preds[shipped][i], preds[CONTROL][i], ym, n_boot)}")


def evaluate_transfer(mias, cbis, n_boot):
    """E2: fitted on CBIS alone, tested on every mini-MIAS image."""
    _, Xm, ym = mias
    yc = np.array([BIRADS_TO_CLASS[d] for d in cbis[2]])
    print(f"\nE2: fitted on CBIS alone (per-dataset z, C=1), tested on all {len(ym)} "
          "mini-MIAS images")
    for variant in B.CLASS_VARIANTS:
        cols = columns(variant)
        lr, mean, scale = B.fit_classes(standardised(cbis[1][:, cols], cbis[1][:, cols]), yc)
        p = lr.predict((standardised(Xm[:, cols], Xm[:, cols]) - mean) / scale).astype(str)
        print(f"  {variant:22s} {_summary(ym, p, n_boot)}")


def _resampled(units, n_boot, seed=0):
    """Bootstrap samples over ``units`` (a woman, an image): each the
    indices of the units drawn with replacement, with all their items."""
    groups = [np.flatnonzero(units == u) for u in np.unique(units)]
    rng = np.random.default_rng(seed)
    for _ in range(n_boot):
        yield np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])


def _by_patient_interval(right, other, patients, n_boot, seed=0):
    """95 % interval of the mean of ``right`` (minus ``other``'s, paired)
    over patients resampled with their films."""
    stats = [right[idx].mean() - (0.0 if other is None else other[idx].mean())
             for idx in _resampled(patients, n_boot, seed)]
    return np.percentile(stats, [2.5, 97.5])


def evaluate_cbis(cbis, n_boot):
    """E3: CBIS 5-fold CV by patient, 3 classes and 4 BI-RADS grades."""
    names, Xc, birads = cbis
    patients = np.array([n.split("_")[0] for n in names])
    folds = np.array([int(hashlib.md5(p.encode()).hexdigest(), 16) % B.FOLDS for p in patients])
    print(f"\nE3: CBIS, 5-fold CV by patient ({len(np.unique(patients))} patients, "
          f"{len(names)} films), C=1; 95 % over patients")
    targets = {"3 classes F/G/D": np.array([BIRADS_TO_CLASS[d] for d in birads]),
               "4 BI-RADS grades": birads}
    for target_name, y in targets.items():
        right = {}
        for variant in B.CLASS_VARIANTS:
            cols = columns(variant)
            p = np.empty(len(y), object)
            for k in range(B.FOLDS):
                train = folds != k
                lr, mean, scale = B.fit_classes(Xc[train][:, cols], y[train])
                p[~train] = lr.predict((Xc[~train][:, cols] - mean) / scale)
            p = p.astype(str)
            right[variant] = (p == y).astype(float)
            lo, hi = _by_patient_interval(right[variant], None, patients, n_boot)
            print(f"  {target_name}, {variant:22s} accuracy {right[variant].mean():.3f} "
                  f"[{lo:.3f}, {hi:.3f}], kappa {B.kappa(y, p):.3f}")
        for variant in ("CAR", "CAR+histogram"):
            lo, hi = _by_patient_interval(right[variant], right[CONTROL], patients, n_boot)
            d = right[variant].mean() - right[CONTROL].mean()
            print(f"  {target_name}, paired {variant} minus histogram: "
                  f"{d:+.3f} [{lo:+.3f}, {hi:+.3f}]")


def evaluate_density(mias, cbis, n_boot, seed=0):
    """E4: the mask's percent density against the readers' grades."""
    from scipy.stats import spearmanr

    print("\nE4: the shipped mask's percent density by the readers' grade "
          "(mean [95 %]); Spearman's rho")
    order = {"F": 0, "G": 1, "D": 2}
    sets = (("CBIS, BI-RADS", cbis[1][:, 0] * 100, cbis[2].astype(int),
             np.array([n.split("_")[0] for n in cbis[0]])),
            ("mini-MIAS, F/G/D", mias[1][:, 0] * 100,
             np.array([order[c] for c in mias[2]]), np.array(mias[0])))
    for name, density, grade, unit in sets:
        means, rhos = [], []
        for idx in _resampled(unit, n_boot, seed):
            means.append([density[idx][grade[idx] == g].mean() for g in np.unique(grade)])
            rhos.append(spearmanr(density[idx], grade[idx])[0])
        lo, hi = np.percentile(means, [2.5, 97.5], axis=0)
        labels = [str(g) if "BI-RADS" in name else "FGD"[g] for g in np.unique(grade)]
        cells = ", ".join(f"{lab} {density[grade == g].mean():.1f} [{a:.1f}, {b:.1f}] "
                          f"(n {np.sum(grade == g)})"
                          for lab, g, a, b in zip(labels, np.unique(grade), lo, hi, strict=True))
        r_lo, r_hi = np.percentile(rhos, [2.5, 97.5])
        print(f"  {name}: {cells}; rho {spearmanr(density, grade)[0]:.3f} "
              f"[{r_lo:.3f}, {r_hi:.3f}]")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--boot", type=int, default=1000)
    ap.add_argument("--cache", default="/tmp/car_napari_density_cache")
    ap.add_argument("--only", default="e1,e2,e3,e4")
    args = ap.parse_args(argv)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if not CBIS.is_dir() or not B.MIAS.is_dir():
        sys.exit(f"no mammograms at {B.ROOT} (set CAR_NAPARI_MAMMOGRAMS)")
    mias, cbis = rows(Path(args.cache), args.jobs)
    only = {s.strip() for s in args.only.split(",")}
    if "e1" in only:
        evaluate_pooled(mias, cbis, args.boot)
    if "e2" in only:
        evaluate_transfer(mias, cbis, args.boot)
    if "e3" in only:
        evaluate_cbis(cbis, args.boot)
    if "e4" in only:
        evaluate_density(mias, cbis, args.boot)


if __name__ == "__main__":
    main()
