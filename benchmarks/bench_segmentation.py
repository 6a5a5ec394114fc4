"""Texture segmentation quality on Prague-style mosaics, run by hand.

    python benchmarks/bench_segmentation.py [--count 6] [--split report|tuning|both]
                                            [--kind vistex brodatz natural-grey vistex-grey]
                                            [--only "ours (auto K)" ...] [--grey grey|pseudo_colour]
                                            [--tuning-seeds 1 2 3]

Ours with the number of segments found automatically; baselines told the
true number: a Gabor filter bank (4 frequencies x 4 orientations, smoothed
magnitudes) + k-means, SLIC superpixels + k-means on their statistics, and
scikit-image's Felzenszwalb.

Sets (5-texture 512x512 mosaics of ``/work/shared/data/textures``):
``vistex`` (colour), ``brodatz`` (grey), ``natural-grey`` (``natural``
textures made grey) and ``vistex-grey`` (VisTex made grey).

The split, fixed: TUNING is what defaults and options are chosen on: the
``brodatz`` and ``vistex`` mosaics of seed 1, and the ``natural-grey``
mosaics of seed 1 (other mosaics of the same textures; ``--tuning-seeds``
adds more seeds, never 0). REPORT is what is reported: every set at seed 0;
``vistex-grey`` is never used for choosing anything, nor is any mosaic of
seed 0.

``--grey`` says how ours segments a grey mosaic (``segment(grey=...)``):
``grey`` (the single channel, d = 1: the default of the features since
issue 14) or ``pseudo_colour`` (the chapter's ``[Y, Y^0.5, Y^2]``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.cluster.vq import kmeans2

sys.path.insert(0, str(Path(__file__).parent))
from mosaics import all_scores, mosaic_set  # noqa: E402


def _kmeans(features, k, seed=0):
    h, w, D = features.shape
    f = features.reshape(-1, D)
    f = (f - f.mean(0)) / np.where(f.std(0) > 0, f.std(0), 1)
    _, lab = kmeans2(f, k, seed=seed, minit="++")
    return lab.reshape(h, w) + 1


def gabor_kmeans(image, k):
    from skimage.color import rgb2gray
    from skimage.filters import gabor

    grey = rgb2gray(image) if image.ndim == 3 else image
    feats = []
    for freq in (0.05, 0.1, 0.2, 0.4):
        for theta in np.arange(4) * np.pi / 4:
            real, imag = gabor(grey, frequency=freq, theta=theta)
            feats.append(ndimage.gaussian_filter(np.hypot(real, imag), 3.0 / freq))
    return _kmeans(np.stack(feats, axis=-1), k)


def slic_kmeans(image, k):
    from skimage.segmentation import slic

    channel_axis = -1 if image.ndim == 3 else None
    sp = slic(image, n_segments=400, compactness=10, channel_axis=channel_axis, start_label=0)
    img = image if image.ndim == 3 else image[..., None]
    n = sp.max() + 1
    stats = []
    for c in range(img.shape[2]):
        ch = img[..., c]
        mean = ndimage.mean(ch, sp, np.arange(n))
        std = ndimage.standard_deviation(ch, sp, np.arange(n))
        stats += [mean, std]
    lab = _kmeans(np.stack(stats, axis=-1)[None], k)[0]
    return lab[sp]


def felzenszwalb(image, k):
    from skimage.segmentation import felzenszwalb as fz

    channel_axis = -1 if image.ndim == 3 else None
    return fz(image, scale=500, sigma=0.8, min_size=2000, channel_axis=channel_axis) + 1


GREY = {"mode": None}  # segment(grey=...) of ours, None: segment's default


def ours(image, k):
    from car_napari.segmentation import segment

    options = {} if GREY["mode"] is None else {"grey": GREY["mode"]}
    return segment(image, channel_axis=-1 if image.ndim == 3 else None, **options).labels


METHODS = {"ours (auto K)": ours, "Gabor + k-means": gabor_kmeans,
           "SLIC + k-means": slic_kmeans, "Felzenszwalb": felzenszwalb}
KEYS = ("CS", "OS", "US", "ME", "NE", "acc", "ARI", "VI", "K")


SETS = {"vistex": ("vistex", False), "brodatz": ("brodatz", False),
        "natural-grey": ("natural", True), "vistex-grey": ("vistex", True)}
SPLITS = {"tuning": {"seeds": (1,), "kinds": ("brodatz", "vistex", "natural-grey")},
          "report": {"seeds": (0,), "kinds": tuple(SETS)}}


def run_set(kind, seed, count, methods):
    """Mean scores and seconds of every method on one set."""
    folder, grey = SETS[kind]
    rows = {name: [] for name in methods}
    secs = {name: [] for name in methods}
    for image, truth in mosaic_set(folder, count=count, seed=seed, grey=grey):
        k = len(np.unique(truth))
        for name, method in methods.items():
            t0 = time.perf_counter()
            labels = method(image, k)
            secs[name].append(time.perf_counter() - t0)
            rows[name].append(all_scores(truth, labels))
    return rows, secs


def print_table(title, methods, rows, secs):
    print(f"\n{title}\n")
    print("| method | " + " | ".join(KEYS) + " | s/image |")
    print("|---" * (len(KEYS) + 2) + "|")
    for name in methods:
        means = [np.mean([r[key] for r in rows[name]]) for key in KEYS]
        print(f"| {name} | " + " | ".join(f"{m:.3f}" if key in ("ARI", "VI") else f"{m:.2f}"
                                          for key, m in zip(KEYS, means, strict=True))
              + f" | {np.mean(secs[name]):.1f} |", flush=True)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--count", type=int, default=6)
    parser.add_argument("--split", choices=("report", "tuning", "both"), default="report")
    parser.add_argument("--kind", nargs="+", default=None, choices=tuple(SETS),
                        help="sets to run (default: all of the split's)")
    parser.add_argument("--only", nargs="+", default=None, help="method names to run")
    parser.add_argument("--grey", choices=("grey", "pseudo_colour"), default=None,
                        help="segment(grey=...) of ours on grey mosaics (default: segment's)")
    parser.add_argument("--tuning-seeds", nargs="+", type=int, default=None,
                        help="seeds of the TUNING mosaics (default 1; never 0)")
    args = parser.parse_args()
    if args.tuning_seeds and 0 in args.tuning_seeds:
        parser.error("seed 0 is the REPORT split; tuning seeds must not include it")
    GREY["mode"] = args.grey
    methods = {n: m for n, m in METHODS.items() if not args.only or n in args.only}
    splits = ("tuning", "report") if args.split == "both" else (args.split,)
    for split in splits:
        seeds = SPLITS[split]["seeds"]
        if split == "tuning" and args.tuning_seeds:
            seeds = tuple(args.tuning_seeds)
        kinds = [k for k in (args.kind or SPLITS[split]["kinds"]) if k in SPLITS[split]["kinds"]]
        for kind in kinds:
            for seed in seeds:
                rows, secs = run_set(kind, seed, args.count, methods)
                print_table(f"{split.upper()} {kind}: {args.count} mosaics 512x512, 5 "
                            f"textures each, seed {seed}", methods, rows, secs)


if __name__ == "__main__":
    main()
