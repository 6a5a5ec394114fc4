"""A batch of real mammograms through ``car-napari mammo`` with 1 and with 2
workers (issue 16, point 5), run by hand, not under ``nice``:

    .venv/bin/python benchmarks/bench_batch.py [--count 100] [--workers 1,2] [--threaded]
        [--rounds 1]

Inputs: the mini-MIAS mammograms (1024x1024, ``../shared/data/mammograms``;
161 there today, so the default 100 are all mini-MIAS) and, to reach
``--count``, the DDSM film mammograms of ``ddsm-tissue``, in a fixed order.
Each configuration runs the real command in a fresh process
(``python -m car_napari.cli mammo ... --workers N -o <tmp>``), with a cold
start of its workers included, as a user meets it. Printed per
configuration: wall-clock seconds, images per minute, the throughput ratio
to 1 worker, and the peak resident memory of the command's process tree
(the client and each worker, sampled every 0.2 s with psutil): the largest
single worker and the sum; and the CPU seconds of the tree (user + system
of every process, its last sample) over the wall-clock seconds: the cores
the configuration kept busy.

Scale-out is per core (the brief): "1 worker" is one single-threaded
process, the command's in-process path (``--workers 1``: no cluster) with
``CAR_NAPARI_JOB_THREADS=1``, and N workers are the command's LocalCluster
of N single-threaded processes; the ratio is their throughput against it.
``--threaded`` adds the command's default in-process path as its own row
("1 worker, 2 job threads"), a different baseline: there the applications run
their kernels on two threads where they can (restoration strips, the
scans, the moments; Numba ``nogil``), so one process already keeps more
than one core busy part of the time. The "cores busy" column shows how
much. On a loaded machine (other processes runnable) the scheduler shares
the cores per thread, not per process, which favours the configuration
with more threads: read the figures with the load printed.
Rounds alternate the configurations, so that a drift of the machine's load
falls on all. The outputs of every run are compared with the first run's
(label PNGs byte for byte, the table row by row): they must be identical.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]
MAMMOGRAMS = ROOT.parent / "shared" / "data" / "mammograms"


def inputs(count, folder):
    """Links to ``count`` real mammograms in ``folder`` (mini-MIAS first)."""
    paths = sorted((MAMMOGRAMS / "mini-mias").glob("mdb*.png"))
    paths += sorted((MAMMOGRAMS / "ddsm-tissue" / "fgt_seg").glob("*.png"))
    if len(paths) < count:
        sys.exit(f"only {len(paths)} mammograms under {MAMMOGRAMS}; asked for {count}")
    folder.mkdir(parents=True)
    for path in paths[:count]:
        (folder / path.name).symlink_to(path)
    return folder


THREADED = "1 worker, 2 job threads"  # the label of --threaded's row


def run(folder, out, config):
    """(seconds, peak RSS of the largest process, peak of the sum, CPU
    seconds of the tree) of one command; ``config`` is a number of workers
    (single-threaded processes) or :data:`THREADED`."""
    workers = 1 if config == THREADED else config
    cmd = [sys.executable, "-m", "car_napari.cli", "mammo", str(folder), "-o", str(out),
           "--workers", str(workers), "--quiet"]
    env = dict(os.environ)
    env.pop("CAR_NAPARI_JOB_THREADS", None)
    if config == 1:  # the cluster's workers set their own
        env["CAR_NAPARI_JOB_THREADS"] = "1"
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=env)
    largest = total = 0
    cpu = {}  # pid: user + system seconds, last sample
    parent = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            tree = [parent, *parent.children(recursive=True)]
            sizes = [p.memory_info().rss for p in tree]
            for p in tree:
                times = p.cpu_times()
                cpu[p.pid] = times.user + times.system
        except psutil.Error:
            sizes = []
        if sizes:
            largest, total = max(largest, max(sizes)), max(total, sum(sizes))
        time.sleep(0.2)
    seconds = time.perf_counter() - t0
    err = proc.stderr.read()
    if proc.returncode not in (0, 1):
        sys.exit(f"the command failed ({proc.returncode}):\n{err}")
    return seconds, largest, total, sum(cpu.values())


def _label(config):
    return config if config == THREADED else f"{config} worker{'s' * (config != 1)}"


def same_outputs(a, b):
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return False
    return all(filecmp.cmp(a / n, b / n, shallow=False) for n in names)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--threaded", action="store_true",
                        help="also the default in-process path, 2 job threads")
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    configs = [int(w) for w in args.workers.split(",")] + ([THREADED] if args.threaded else [])
    work = Path(tempfile.mkdtemp(prefix="car_bench_batch_"))
    try:
        folder = inputs(args.count, work / "in")
        times = {w: [] for w in configs}
        peaks = {w: [] for w in configs}
        cpus = {w: [] for w in configs}
        reference = None
        for r in range(args.rounds):
            for i, w in enumerate(configs):
                out = work / f"out_{i}_{r}"
                seconds, largest, total, cpu = run(folder, out, w)
                times[w].append(seconds)
                cpus[w].append(cpu / seconds)
                peaks[w].append((largest, total))
                if reference is None:
                    reference = out
                elif not same_outputs(reference, out):
                    sys.exit(f"outputs of {_label(w)} (round {r}) differ from the first run")
                print(f"round {r + 1}, {_label(w)}: {seconds:.1f} s, "
                      f"CPU {cpu:.0f} s ({cpu / seconds:.2f} cores busy)", flush=True)
        base = min(times[configs[0]])
        print(f"\n{args.count} mammograms (mini-MIAS 1024^2 first, then DDSM films), "
              f"{psutil.cpu_count()} CPUs, load {psutil.getloadavg()[0]:.1f}")
        print("| workers | seconds (min-max) | images/min | throughput vs "
              f"{_label(configs[0])} | cores busy | largest process (GB) | all processes (GB) |")
        print("|---|---|---|---|---|---|---|")
        for w in configs:
            best = min(times[w])
            largest = max(p[0] for p in peaks[w]) / 1e9
            total = max(p[1] for p in peaks[w]) / 1e9
            print(f"| {w} | {best:.1f} ({min(times[w]):.1f}-{max(times[w]):.1f}) | "
                  f"{60 * args.count / best:.1f} | {base / best:.2f}x | "
                  f"{min(cpus[w]):.2f}-{max(cpus[w]):.2f} | {largest:.2f} | "
                  f"{total:.2f} |")
        print("outputs identical across all runs: yes")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
