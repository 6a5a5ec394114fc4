"""Learn the mammogram ROI reference grey value (SPEC 3.1), run by hand.

    python benchmarks/bench_mammography.py

SPEC 3.1 keeps regions whose mean grey level is close to the median mean
grey level of cancerous ground-truth regions. Here: the mean grey (8-bit
scaled to [0, 1]) inside every mini-MIAS mass circle (CIRC, SPIC, MISC),
learned on every other finding (mini-MIAS here holds only odd-numbered images)
and checked on the rest, and the
spread of that value (for the tolerance); plus the same for the breast
tissue around the masses, to see how well grey alone separates them.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from skimage import io

from car_napari.mammography import detect_breast

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mammograms" / "mini-mias"


def mass_greys():
    rows = list(csv.DictReader(open(DATA / "ground_truth.csv")))
    out = []
    for r in rows:
        if r["class"] not in ("CIRC", "SPIC", "MISC") or not r["col"]:
            continue
        image = io.imread(DATA / f"{r['refnum']}.png") / 255.0
        yy, xx = np.mgrid[: image.shape[0], : image.shape[1]]
        disc = (yy - int(r["row"])) ** 2 + (xx - int(r["col"])) ** 2 <= int(r["radius"]) ** 2
        breast = detect_breast(image)
        ring = breast & ~disc & ((yy - int(r["row"])) ** 2 + (xx - int(r["col"])) ** 2
                                 <= (2 * int(r["radius"])) ** 2)
        out.append((int(r["refnum"][3:]), image[disc].mean(), image[ring].mean()))
    return np.array(out)


def main():
    table = mass_greys()
    learn, check = table[0::2], table[1::2]
    ref = float(np.median(learn[:, 1]))
    spread = float(np.percentile(np.abs(learn[:, 1] - ref), 80))
    print(f"mass findings: {len(table)} (learn on {len(learn)}, check on {len(check)})")
    print(f"reference grey (median over the learning masses): {ref:.3f}")
    print(f"80th percentile of |mass grey - reference| (learning): {spread:.3f}")
    covered = np.mean(np.abs(check[:, 1] - ref) <= spread)
    print(f"held-out masses within that tolerance: {100 * covered:.0f} %")
    print(f"reference over all masses: {np.median(table[:, 1]):.3f}")
    print(f"median grey of the tissue ring around masses (all): {np.median(table[:, 2]):.3f}")
    print(f"masses brighter than their surrounding ring: "
          f"{100 * np.mean(table[:, 1] > table[:, 2]):.0f} %")


if __name__ == "__main__":
    main()
