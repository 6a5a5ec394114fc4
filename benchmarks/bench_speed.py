"""End-to-end seconds and peak memory of the applications, run by hand.

    PYTHONPATH=. python benchmarks/bench_speed.py [--repeat 2] [--only 512]
                                                  [--options '{"prior": 1.0}']

Each case runs in a fresh Python process (Numba cache warm: one untimed
small run first), so that its peak resident memory (``ru_maxrss``) is its
own. Cases:

* segmentation: a 512x512 RGB mosaic of five VisTex textures (the segmentation
  benchmark's first, seed 0), ``segment`` with the number of segments found
  automatically; and a 1024x1024 mosaic of the first five VisTex textures
  (mirror-tiled from 640x640); ``--options`` adds keyword options of
  ``segment`` (JSON). ``cpu_s`` is the process's CPU time of the
  run: on a machine shared with other work it is the figure to compare (the
  job runs in one thread, so on a quiet machine it is about the seconds);
* mammogram: ``detect_mammogram_rois`` on mini-MIAS mdb001 (1024x1024,
  shipped sample) and on the CBIS-DDSM film 00001_LEFT_CC (800x800, from
  ``../shared/data``); ``segment_tissue`` and ``analyse_mammogram`` (ROIs
  and tissue from one segmentation) on mdb001;
* restoration: ``restore`` on scikit-image's astronaut resized to
  1024x1024x3, blurred by 1 px, noise 0.05; and, in the same process,
  ``scipy.ndimage.median_filter(size=(5, 5, 1))`` on the same image.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = {
    "segmentation 512x512 RGB": """
sys.path.insert(0, {root!r} + "/benchmarks")
from mosaics import mosaic_set
from car_napari.segmentation import segment
image, truth = next(mosaic_set("vistex", count=1, seed=0))
segment(image[:64, :64], levels=1)
c0 = time.process_time()
t0 = time.perf_counter(); result = segment(image, **OPTIONS); seconds = time.perf_counter() - t0
extra = {"segments": int(result.n_segments), "cpu_s": round(time.process_time() - c0, 2)}
""",
    "segmentation 1024x1024 RGB": """
sys.path.insert(0, {root!r} + "/benchmarks")
from mosaics import DATA, make_mosaic
from car_napari.segmentation import segment
files = sorted((DATA / "vistex").glob("*.png"))[:5]
image, truth = make_mosaic(files, shape=(1024, 1024), seed=0)
segment(image[:64, :64], levels=1)
c0 = time.process_time()
t0 = time.perf_counter(); result = segment(image, **OPTIONS); seconds = time.perf_counter() - t0
extra = {"segments": int(result.n_segments), "cpu_s": round(time.process_time() - c0, 2)}
""",
    "mammogram 1024x1024": """
from car_napari.io.sample_data import mammogram
from car_napari.mammography import detect_mammogram_rois
(image, _, _), = mammogram()
t0 = time.perf_counter(); labels, table = detect_mammogram_rois(image)
seconds = time.perf_counter() - t0
extra = {"regions": int(len(table["label"]))}
""",
    "mammogram film 800x800": """
from skimage import io
from car_napari.mammography import detect_mammogram_rois
image = io.imread({root!r} + "/../shared/data/mammograms/cbis-ddsm-masses/00001_LEFT_CC.jpg")
t0 = time.perf_counter(); labels, table = detect_mammogram_rois(image)
seconds = time.perf_counter() - t0
extra = {"regions": int(len(table["label"]))}
""",
    "mammogram tissue 1024x1024": """
from car_napari.io.sample_data import mammogram
from car_napari.mammography import segment_tissue
(image, _, _), = mammogram()
t0 = time.perf_counter(); tissue = segment_tissue(image)
seconds = time.perf_counter() - t0
extra = {"density": round(float(tissue.density), 1), "class": tissue.tissue_class}
""",
    "mammogram ROIs and tissue 1024x1024": """
from car_napari.io.sample_data import mammogram
from car_napari.mammography import analyse_mammogram
(image, _, _), = mammogram()
t0 = time.perf_counter(); rois, tissue = analyse_mammogram(image)
seconds = time.perf_counter() - t0
extra = {"regions": int(len(rois.table["label"])), "density": round(float(tissue.density), 1)}
""",
    "restore 1024x1024x3": """
import numpy as np
from scipy import ndimage
from skimage import data
from skimage.transform import resize
from car_napari.restoration import restore
image = resize(data.astronaut() / 255.0, (1024, 1024), order=1)
noisy = ndimage.gaussian_filter(image, (1, 1, 0))
noisy += np.random.default_rng(0).normal(0, 0.05, image.shape)
restore(noisy[:64, :64])
t0 = time.perf_counter(); restore(noisy); seconds = time.perf_counter() - t0
t0 = time.perf_counter(); ndimage.median_filter(noisy, size=(5, 5, 1))
median = time.perf_counter() - t0
extra = {"median_5x5_s": round(median, 2), "median/ours": round(median / seconds, 2)}
""",
}

RUNNER = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
OPTIONS = json.loads({options!r})
{body}
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({{"seconds": round(seconds, 3), "peak_mb": peak, **extra}}))
"""


def run(body, options="{}"):
    code = RUNNER.format(root=str(ROOT), options=options,
                         body=body.replace("{root!r}", repr(str(ROOT))))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--only", default=None, help="substring of a case name")
    ap.add_argument("--options", default="{}",
                    help="extra keyword options of segment (JSON), segmentation cases")
    args = ap.parse_args()
    print("| case | seconds (runs) | peak memory (MB) | notes |")
    print("|---|---|---|---|")
    for name, body in CASES.items():
        if args.only and args.only not in name:
            continue
        runs = [run(body, args.options) for _ in range(args.repeat)]
        seconds = ", ".join(f"{r['seconds']:.2f}" for r in runs)
        peak = max(r["peak_mb"] for r in runs)
        notes = {k: [r[k] for r in runs] for k in runs[-1] if k not in ("seconds", "peak_mb")}
        print(f"| {name} | {seconds} | {peak:.0f} | {notes} |", flush=True)


if __name__ == "__main__":
    main()
