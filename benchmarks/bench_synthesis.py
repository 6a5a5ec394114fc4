"""Texture synthesis against random-phase noise, on a fixed TUNING / REPORT split.

    python benchmarks/bench_synthesis.py [--split report] [--repeats 5]
        [--grid docs/synthesis_grid.png] [--levels N] [--pyramid spectral]

Textures: the colour textures of ``textures/vistex`` (central 512 x 512 crop of
the 640 x 640 images) and ``textures/natural`` (the 512 x 512 RGB ones;
``camo_large`` is 384 x 384 with two channels and is left out). The split is
fixed by the file name: ``zlib.crc32(stem) % 2 == 1`` is REPORT, the rest
TUNING. Every constant of the texture model is chosen on TUNING; figures are
reported on REPORT.

Per texture: ``TextureModel.fit(crop)`` (the defaults) and one synthesis of
512 x 512 with seed 0; the baseline is random-phase noise (Galerne, Gousseau
and Morel 2011, as ``bench_texture.random_phase_noise``: the input's exact
power spectrum with random phases), and for reference the previous model (a
Gaussian-Laplacian pyramid of 3 levels, ``pyramid="gaussian", levels=3``).
Distances to the input (lower is better), as in ``bench_texture``:

- colour histogram L1 (32 bins per channel, averaged over the channels);
- autocorrelation L1 (normalised grey autocorrelation, lags dy 0..15,
  dx -15..15, mean absolute difference);
- LBP L1 (uniform LBP, P = 8, R = 1, 2, 3, averaged over R);
- spurious colours: the share of synthesised pixels whose CIELAB colour
  lies more than 10 units from every input pixel's colour (exact nearest
  neighbour over all input pixels, ``scipy.spatial.cKDTree``);
  the table marks the textures where ours exceeds random-phase noise's share
  (one pixel in 262,144 is 0.0004 %) and counts them;
- compression ratio: raw float32 bytes of the 512 x 512 x 3 input over
  the model's stored bytes.

Times: after one warm-up fit and synthesis, every texture is fitted
``--repeats`` times and synthesised ``--repeats`` times; the table gives the
median and the range (min-max over all textures and repeats), and random-phase
noise's time measured in the same run as the baseline for the machine's load.

Variants declared before their REPORT run (session 39, issue 34): the
palette's radii cut to the balls the input's colours cover
(``texture/_palette.py``, ``_TOLERANCE = 0.08`` of the largest channel span,
chosen on TUNING as the largest of 0.04 / 0.06 / 0.08 / 0.1 / 0.12 / 0.15 /
0.2 with no spurious pixel on the 34 TUNING syntheses of seeds 0 and 1).

The PNG grid (``--grid``) has one row per texture: input, ours, random-phase
noise (each downscaled to 128 x 128).
"""

from __future__ import annotations

import argparse
import sys
import time
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
DATA = ROOT.parent / "shared" / "data" / "textures"

from bench_texture import distances, random_phase_noise  # noqa: E402

KEYS = ("autocorr", "colour hist", "LBP", "spurious")


def part_of(stem):
    """'report' or 'tuning', fixed by the file name."""
    return "report" if zlib.crc32(stem.encode()) % 2 == 1 else "tuning"


def load_textures(split):
    from skimage import io

    files = sorted((DATA / "vistex").glob("*.png")) + sorted((DATA / "natural").glob("*"))
    out = []
    for f in files:
        if part_of(f.stem) != split:
            continue
        img = io.imread(f)
        if img.ndim != 3 or img.shape[2] < 3 or min(img.shape[:2]) < 512:
            continue
        img = img[..., :3].astype(np.float64) / 255.0
        h, w = img.shape[:2]
        i, j = (h - 512) // 2, (w - 512) // 2
        out.append((f.stem, np.ascontiguousarray(img[i:i + 512, j:j + 512])))
    if not out:
        raise SystemExit(f"no textures found in {DATA}")
    return out


def spurious_share(original, synthesis, radius=10.0):
    """Share of ``synthesis`` pixels whose CIELAB colour is more than
    ``radius`` from every pixel colour of ``original``."""
    from scipy.spatial import cKDTree
    from skimage.color import rgb2lab

    ref = np.unique(np.round(rgb2lab(np.clip(original, 0, 1)).reshape(-1, 3), 3), axis=0)
    query = rgb2lab(np.clip(synthesis, 0, 1)).reshape(-1, 3)
    dist, _ = cKDTree(ref).query(query, distance_upper_bound=radius)
    return float(np.mean(~np.isfinite(dist)))


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, times


def measure(textures, repeats, fit_kwargs):
    from car_napari import TextureModel

    # warm-up: the Numba kernels compile (or load from the cache) once
    TextureModel.fit(textures[0][1], **fit_kwargs).synthesize((64, 64), seed=0)
    rows, times = [], {"fit": [], "synthesis": [], "random phase": [], "old fit": [],
                       "old synthesis": []}
    for name, img in textures:
        model, t = timed(lambda img=img: TextureModel.fit(img, **fit_kwargs), repeats)
        times["fit"] += t
        ours, t = timed(lambda m=model: m.synthesize((512, 512), seed=0), repeats)
        times["synthesis"] += t
        synthesis_times = t
        noise, t = timed(lambda img=img: random_phase_noise(img, seed=0), repeats)
        times["random phase"] += t
        old_model, t = timed(
            lambda img=img: TextureModel.fit(img, levels=3, pyramid="gaussian"), 1)
        times["old fit"] += t
        old, t = timed(lambda m=old_model: m.synthesize((512, 512), seed=0), repeats)
        times["old synthesis"] += t
        row = {"name": name, "ratio": model.compression_ratio(img.shape),
               "old ratio": old_model.compression_ratio(img.shape),
               "levels": model.levels, "orders": model.orders, "synthesis": synthesis_times}
        for label, out in (("ours", ours), ("rpn", noise), ("old", old)):
            d = distances(img, out)
            d["spurious"] = spurious_share(img, out)
            row[label] = d
        row["images"] = (img, ours, noise)
        rows.append(row)
        print(f"  {name}: " + " | ".join(
            f"{label} " + " ".join(f"{row[label][k]:.4f}" for k in KEYS)
            for label in ("ours", "rpn", "old")) + f" | {row['ratio']:.0f}:1", file=sys.stderr,
            flush=True)
    return rows, times


def report(rows, times, split):
    n = len(rows)
    print(f"\n{split.upper()} part: {n} textures, 512x512 RGB, one synthesis each (seed 0); "
          "distances to the input, lower is better\n")
    head = "| texture | " + " | ".join(
        f"{k} ours / RPN" for k in ("autocorr L1", "colour-hist L1", "LBP L1")) + \
        " | spurious % ours / RPN | ours above RPN | compression | s synthesis median / max |"
    print(head)
    print("|" + "---|" * 8)
    for r in rows:
        o, p = r["ours"], r["rpn"]
        print(f"| {r['name']} | " + " | ".join(
            f"{o[k]:.4f} / {p[k]:.4f}" for k in ("autocorr", "colour hist", "LBP"))
            + f" | {100 * o['spurious']:.4f} / {100 * p['spurious']:.4f} | "
            f"{'YES' if o['spurious'] > p['spurious'] else 'no'} | {r['ratio']:.0f}:1 | "
            f"{np.median(r['synthesis']):.3f} / {np.max(r['synthesis']):.3f} |")
    mean = {label: {k: float(np.mean([r[label][k] for r in rows])) for k in KEYS}
            for label in ("ours", "rpn", "old")}
    print("| **mean** | " + " | ".join(
        f"{mean['ours'][k]:.4f} / {mean['rpn'][k]:.4f}" for k in ("autocorr", "colour hist",
                                                                  "LBP"))
          + f" | {100 * mean['ours']['spurious']:.4f} / {100 * mean['rpn']['spurious']:.4f} | "
          f"{sum(r['ours']['spurious'] > r['rpn']['spurious'] for r in rows)}/{n} | "
          f"{np.mean([r['ratio'] for r in rows]):.0f}:1 | |")
    print("\n| method | autocorr L1 | colour-hist L1 | LBP L1 | spurious % (mean, worst) "
          "| compression (min) | s fit median [range] | s synthesis median [range] |")
    print("|---|---|---|---|---|---|---|---|")

    def span(t):
        return f"{np.median(t):.3f} [{np.min(t):.3f}-{np.max(t):.3f}]" if t else "-"

    for label, name, fit, syn, ratio in (
            ("ours", "ours (spectral pyramid, defaults)", times["fit"], times["synthesis"],
             min(r["ratio"] for r in rows)),
            ("old", "previous (Gaussian pyramid, 3 levels)", times["old fit"],
             times["old synthesis"], min(r["old ratio"] for r in rows)),
            ("rpn", "random-phase noise", [], times["random phase"], 1.0)):
        m = mean[label]
        worst = max(r[label]["spurious"] for r in rows)
        print(f"| {name} | {m['autocorr']:.4f} | {m['colour hist']:.4f} | {m['LBP']:.4f} | "
              f"{100 * m['spurious']:.3f}, {100 * worst:.3f} | {ratio:.0f}:1 | {span(fit)} | "
              f"{span(syn)} |")
    ratio = mean["ours"]["autocorr"] / mean["rpn"]["autocorr"]
    beaten = sum(r["ours"]["spurious"] > r["rpn"]["spurious"] for r in rows)
    print(f"\nautocorrelation: ours / RPN = {ratio:.2f} (must be <= 4); colour-hist "
          f"{'below' if mean['ours']['colour hist'] < mean['rpn']['colour hist'] else 'NOT below'}"
          f" RPN; LBP {'below' if mean['ours']['LBP'] < mean['rpn']['LBP'] else 'NOT below'} "
          f"RPN; spurious colours above RPN's on {beaten}/{n} textures; synthesis median above "
          f"0.1 s on {sum(np.median(r['synthesis']) > 0.1 for r in rows)}/{n} textures")


def write_grid(rows, path, side=128):
    from skimage.io import imsave
    from skimage.transform import resize

    tiles = []
    for r in rows:
        tiles.append(np.concatenate(
            [resize(np.clip(a, 0, 1), (side, side), anti_aliasing=True) for a in r["images"]],
            axis=1))
    grid = np.concatenate(tiles, axis=0)
    imsave(path, np.round(grid * 255).astype(np.uint8), check_contrast=False)
    print(f"\ngrid (rows: {', '.join(r['name'] for r in rows)}; columns: input, ours, "
          f"random-phase noise) written to {path}")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--split", choices=["report", "tuning"], default="report")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--grid", default=None, help="PNG path of the image grid")
    parser.add_argument("--levels", type=int, default=None, help="fit option (tuning)")
    parser.add_argument("--pyramid", default="spectral", help="fit option (tuning)")
    parser.add_argument("--count", type=int, default=None, help="first N textures only")
    args = parser.parse_args()
    textures = load_textures(args.split)[: args.count]
    rows, times = measure(textures, args.repeats,
                          {"levels": args.levels, "pyramid": args.pyramid})
    report(rows, times, args.split)
    if args.grid:
        write_grid(rows, args.grid)


if __name__ == "__main__":
    main()
