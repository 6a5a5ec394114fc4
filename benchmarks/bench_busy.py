"""Jobs beside a busy process: no oversubscription (issue 12, point 4), run by hand.

    PYTHONPATH=. python benchmarks/bench_busy.py [--runs 3] [--no-limit] [--same-session]
                                                 [--cases mammogram,segment]

Times ``detect_mammogram_rois`` on the 1024x1024 mini-MIAS sample
(resources/mammogram_mdb001.png) and ``segment`` on a 512x512 RGB VisTex mosaic
(benchmarks/mosaics.py, the first of ``mosaic_set("vistex")``), each ``--runs``
times on the quiet machine and as often with a busy process beside it: a
separate Python process multiplying 1500x1500 matrices with NumPy's default
BLAS threads (one per CPU), started before each busy run and stopped after
it. Quiet and busy runs alternate, so that a drift of the machine's load
(other users) falls on both. Prints each case's wall-clock times (median
[min-max]), the ratio busy / quiet of the medians (the issue asks for at
most 2) and the job's CPU time (this process's, median): a job whose threads
fight spends more CPU time when the machine is busy, not only more wall time.

The busy process is started as another program would be, in a session of
its own: Linux's scheduler (autogroup) then shares the CPUs between the two
programs. ``--same-session`` starts it in the benchmark's session instead,
where the scheduler shares this session's part of the CPUs among the job's
one thread and the busy process's threads (the job then gets a third of its
session's share, whatever its own thread use).

``--no-limit`` runs the jobs with the BLAS limit lifted
(``CAR_NAPARI_BLAS_THREADS=off``: BLAS at its default, one thread per CPU),
to show what the limit does. Do not run it under ``nice``: it measures the
contention between the job's threads and the busy process's.

A first untimed run of each function on a small input loads (or compiles)
the Numba kernels.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from skimage import io

import car_napari as car
from car_napari._threads import blas_threads, usable_cpus

TOP = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TOP / "benchmarks"))

BUSY = """
import numpy as np
a = np.random.default_rng(0).random((1500, 1500))
b = np.empty_like(a)
np.matmul(a, a, out=b)
print("ready", flush=True)
while True:
    np.matmul(a, a, out=b)
"""


class Busy:
    """A separate process keeping every CPU busy with BLAS matrix products
    (NumPy's default threads: none of this process's limits reach it)."""

    def __init__(self, same_session=False):
        self.same_session = same_session

    def __enter__(self):
        env = {k: v for k, v in os.environ.items()
               if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                            "CAR_NAPARI_BLAS_THREADS")}
        self.process = subprocess.Popen([sys.executable, "-c", BUSY], env=env,
                                        stdout=subprocess.PIPE, text=True,
                                        start_new_session=not self.same_session)
        if self.process.stdout.readline().strip() != "ready":
            raise RuntimeError("the busy process did not start")
        time.sleep(0.5)  # its threads at full speed
        return self

    def __exit__(self, *exc):
        self.process.terminate()
        self.process.wait(10)


def mammogram():
    return io.imread(TOP / "resources" / "mammogram_mdb001.png")


def mosaic():
    from mosaics import mosaic_set

    image, _ = next(mosaic_set("vistex", count=1))
    if image.ndim != 3:
        raise RuntimeError("the VisTex mosaic is not RGB")
    return image


CASES = {
    "mammogram": ("detect_mammogram_rois 1024x1024", mammogram,
                  lambda image: car.detect_mammogram_rois(image),
                  lambda image: car.detect_mammogram_rois(image[::2, ::2])),
    "segment": ("segment 512x512x3 mosaic", mosaic,
                lambda image: car.segment(image),
                lambda image: car.segment(image[:128, :128])),
}


def timed(run, image):
    """(wall-clock, CPU) seconds of ``run(image)``."""
    t0, c0 = time.perf_counter(), time.process_time()
    run(image)
    return time.perf_counter() - t0, time.process_time() - c0


def summary(times):
    return (f"{statistics.median(times):7.2f} [{min(times):.2f}-{max(times):.2f}]"
            if times else "-")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="timed runs per case and load")
    parser.add_argument("--no-limit", action="store_true",
                        help="lift the BLAS limit (CAR_NAPARI_BLAS_THREADS=off)")
    parser.add_argument("--same-session", action="store_true",
                        help="start the busy process in this session (see above)")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated, of {', '.join(CASES)}")
    args = parser.parse_args(argv)
    if args.no_limit:
        os.environ["CAR_NAPARI_BLAS_THREADS"] = "off"
    limit = blas_threads()
    print(f"{usable_cpus()} usable CPUs; BLAS in the jobs: "
          f"{'default (no limit)' if limit is None else f'{limit} thread(s)'}; busy process: "
          f"1500x1500 matmuls at NumPy's default BLAS threads, "
          f"{'in this session' if args.same_session else 'in its own session'}; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'case':32s} {'quiet, s: median [range]':>25s} {'busy, s: median [range]':>25s}"
          f" {'ratio':>6s} {'CPU s quiet/busy':>17s}")
    ratios = {}
    for key in args.cases.split(","):
        label, load, run, warm = CASES[key]
        image = load()
        warm(image)
        quiet, busy = [], []
        for _ in range(args.runs):
            quiet.append(timed(run, image))
            with Busy(args.same_session):
                busy.append(timed(run, image))
        (wall_q, cpu_q), (wall_b, cpu_b) = zip(*quiet, strict=True), zip(*busy, strict=True)
        ratios[key] = statistics.median(wall_b) / statistics.median(wall_q)
        cpu = f"{statistics.median(cpu_q):.2f}/{statistics.median(cpu_b):.2f}"
        print(f"{label:32s} {summary(wall_q):>25s} {summary(wall_b):>25s} {ratios[key]:6.2f}"
              f" {cpu:>17s}", flush=True)
    worst = max(ratios.values())
    print(f"largest ratio {worst:.2f} (must hold: at most 2): "
          f"{'holds' if worst <= 2 else 'DOES NOT HOLD'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
