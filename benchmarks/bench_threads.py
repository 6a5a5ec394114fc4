"""Seconds of restore, inpaint and segment on 1 and 2 job threads, run by hand.

    PYTHONPATH=. nice -n 5 python benchmarks/bench_threads.py [--repeat 3]
                                                              [--threads 1 2]

``CAR_NAPARI_JOB_THREADS`` sizes the one pool of every application's
side-by-side kernels (:func:`car_napari._threads.job_pool`). Each run is a
fresh Python process with the setting in its environment (the Numba cache
warm: one untimed small run first), the settings taking turns repeat by
repeat so that a busy machine's load falls on both alike. Printed per case
and setting: the range (min-max) of the wall seconds and of the process's
CPU seconds over the repeats, and a hash of the output: the same hash on
every setting is the bit-for-bit claim. Cases (scikit-image's images, no
download):

* restore: ``restore`` (windowed) on the astronaut at 1024x1024x3, noise 0.05;
* restore recursive: ``restore(estimator='recursive')`` on its 512x512x3 crop;
* inpaint: ``inpaint`` (conditional) of 640x640x3 with five scratches
  3 px wide and a 40x40 blotch;
* segment: ``segment`` (2 segments, 2 levels) of a 512x512 mosaic of
  brick and grass.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PRELUDE = """
import hashlib, json, time
import numpy as np
from skimage import data as skdata, transform
"""

CASES = {
    "restore": """
from car_napari.restoration import restore
rng = np.random.default_rng(0)
clean = transform.resize(skdata.astronaut() / 255.0, (1024, 1024), anti_aliasing=True)
image = clean + rng.normal(0, 0.05, clean.shape)
restore(image[:64, :64])
run = lambda: restore(image)
""",
    "restore recursive": """
from car_napari.restoration import restore
rng = np.random.default_rng(0)
clean = skdata.astronaut()[:512, :512] / 255.0
image = clean + rng.normal(0, 0.05, clean.shape)
restore(image[:64, :64], estimator="recursive")
run = lambda: restore(image, estimator="recursive")
""",
    "inpaint": """
from car_napari.inpainting import inpaint
frame = transform.resize(skdata.astronaut(), (640, 640), anti_aliasing=True,
                         preserve_range=True).astype(np.uint8)
mask = np.zeros(frame.shape[:2], bool)
for c in (60, 170, 300, 420, 555):
    mask[:, c : c + 3] = True
mask[300:340, 200:240] = True
damaged = frame.copy()
damaged[mask] = 255
inpaint(damaged[:96, :96], mask[:96, :96])
run = lambda: inpaint(damaged, mask)
""",
    "segment": """
from car_napari.segmentation import segment
image = np.concatenate([skdata.brick()[:512, :256], skdata.grass()[:512, :256]], axis=1)
segment(image[:64, :64], levels=1)
run = lambda: segment(image, n_segments=2, levels=2).labels
""",
}

TIMED = """
c0 = time.process_time()
t0 = time.perf_counter()
out = run()
seconds = time.perf_counter() - t0
cpu = time.process_time() - c0
out = np.ascontiguousarray(out)
print(json.dumps({"seconds": seconds, "cpu": cpu,
                  "hash": hashlib.sha256(out.tobytes()).hexdigest()[:12]}))
"""


def run_case(name, threads):
    """One timed run of case ``name`` in a fresh process on ``threads`` job threads."""
    env = dict(os.environ, CAR_NAPARI_JOB_THREADS=str(threads),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", PRELUDE + CASES[name] + TIMED], env=env,
                          capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{name} on {threads} threads failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None):
    """Run the cases and print their ranges.

    Parameters
    ----------
    argv : list of str, optional
        The command line (default ``sys.argv[1:]``).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--only", nargs="+", choices=list(CASES), default=list(CASES))
    args = parser.parse_args(argv)
    print(f"load before: {os.getloadavg()[0]:.1f}, cpus {os.cpu_count()}")
    for name in args.only:
        runs = {t: [] for t in args.threads}
        for k in range(args.repeat):
            order = args.threads if k % 2 == 0 else args.threads[::-1]
            for threads in order:
                runs[threads].append(run_case(name, threads))
        for threads, records in runs.items():
            wall = [r["seconds"] for r in records]
            cpu = [r["cpu"] for r in records]
            hashes = sorted({r["hash"] for r in records})
            print(f"{name:18s} threads {threads}: {min(wall):6.2f}-{max(wall):6.2f} s wall, "
                  f"{min(cpu):6.2f}-{max(cpu):6.2f} s cpu, output {','.join(hashes)}")
        sys.stdout.flush()
    print(f"load after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
