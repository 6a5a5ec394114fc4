"""Lazy clips by blocks of frames (issue 16, point 3): peak memory and time of
a 50- and a 500-frame clip read from zarr, restored frame by frame (the
Restoration widget's path) and scratch-filled with temporal context (the
Scratch restoration widget's path), the output written to zarr.

    PYTHONPATH=. nice -n 10 python benchmarks/bench_lazy.py [--frames 50,500]
        [--rows 170 --cols 290] [--only restore,scratches]

The clip: the 24 real archival frames of ``../shared/data/old-film-clips/001``
(grey, the top-left ``rows x cols`` of each: 170x290 by default, a quarter of
a frame, so that 500 frames run in minutes) repeated in order to the length,
written to a zarr store (a chunk a frame) and opened as a dask array
(``dask.array.from_zarr``, what napari's zarr reader gives). The damage of the
scratch fill: a 3 px vertical line drifting one column a frame over 9
columns, and a 6x8 blotch on every fifth frame (a mask per frame, a lazy
zarr array too). Each run is a fresh Python process (``subprocess``): the
core jobs ``car_napari.restoration.iter_restore_frames`` /
``car_napari.inpainting.iter_inpaint_frames`` (what the widgets run in their worker) from a dask
clip into a new zarr store. Peak memory: the process's resident memory
sampled every 20 ms (psutil) and its high-water mark, minus the resident
memory just before the job (after imports and a warm-up on 4 frames). Time:
the job's wall-clock seconds (the load is printed).

Nothing is tuned here; there is no threshold.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CLIP = HERE.parent.parent / "shared" / "data" / "old-film-clips" / "001"


def _frames(rows, cols):
    from PIL import Image

    files = sorted(CLIP.glob("*.png"))
    if not files:
        sys.exit(f"no frames in {CLIP}")
    return np.stack([np.asarray(Image.open(f).convert("L"))[:rows, :cols] for f in files])


def _zarr_clip(frames, n, folder):
    import zarr

    z = zarr.open_array(str(folder / f"clip{n}.zarr"), mode="w",
                        shape=(n, *frames.shape[1:]), chunks=(1, *frames.shape[1:]),
                        dtype=frames.dtype)
    for a in range(0, n, 24):
        b = min(a + 24, n)
        z[a:b] = frames[np.arange(a, b) % len(frames)]
    m = zarr.open_array(str(folder / f"mask{n}.zarr"), mode="w",
                        shape=(n, *frames.shape[1:]), chunks=(1, *frames.shape[1:]),
                        dtype=np.uint8)
    for t in range(n):
        mask = np.zeros(frames.shape[1:], np.uint8)
        c = 20 + t % 9
        mask[:, c:c + 3] = 1
        if t % 5 == 2:
            mask[30:36, 40:48] = 1
        m[t] = mask
    return folder / f"clip{n}.zarr", folder / f"mask{n}.zarr"


def child(kind, clip_path, mask_path):
    """One run in this process: a JSON line with the time and peak memory."""
    import dask.array as da
    import psutil

    from car_napari._frames import lazy_output
    from car_napari._progress import drain
    from car_napari.inpainting import iter_inpaint_frames
    from car_napari.restoration import iter_restore_frames

    def job(clip, mask):
        if kind == "restore":
            return iter_restore_frames(clip, lazy_output(clip.shape, np.float32),
                                       lazy_output(clip.shape, np.float32))
        return iter_inpaint_frames(clip, mask, lazy_output(clip.shape, clip.dtype))

    clip, mask = da.from_zarr(str(clip_path)), da.from_zarr(str(mask_path))
    drain(job(clip[:4], mask[:4]))  # warm-up: the kernels loaded from the cache
    process = psutil.Process()
    base = process.memory_info().rss
    peak = [base]
    done = threading.Event()

    def sample():
        while not done.wait(0.02):
            peak[0] = max(peak[0], process.memory_info().rss)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    t0 = time.perf_counter()
    drain(job(clip, mask))
    seconds = time.perf_counter() - t0
    done.set()
    sampler.join()
    import resource

    high = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    peak_bytes = max(peak[0], high if high > base else 0) - base
    print(json.dumps({"kind": kind, "frames": int(clip.shape[0]), "seconds": round(seconds, 1),
                      "peak_mb": round(peak_bytes / 2**20, 1),
                      "base_mb": round(base / 2**20, 1)}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", default="50,500")
    parser.add_argument("--rows", type=int, default=170)
    parser.add_argument("--cols", type=int, default=290)
    parser.add_argument("--only", default="restore,scratches")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return child(*args.child)
    import os

    frames = _frames(args.rows, args.cols)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-lazy-") as tmp:
        for n in (int(x) for x in args.frames.split(",")):
            clip_path, mask_path = _zarr_clip(frames, n, Path(tmp))
            for kind in args.only.split(","):
                out = subprocess.run([sys.executable, __file__, "--child", kind, str(clip_path),
                                      str(mask_path)], capture_output=True, text=True,
                                     check=False, env=dict(os.environ))
                if out.returncode:
                    print(out.stderr[-2000:], file=sys.stderr)
                    continue
                row = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(row)
                print(f"{row['kind']:>9} {row['frames']:>4} frames {args.rows}x{args.cols}: "
                      f"{row['seconds']:7.1f} s, peak {row['peak_mb']:6.1f} MB over "
                      f"{row['base_mb']:.0f} MB (load {os.getloadavg()[0]:.1f})", flush=True)
    for kind in args.only.split(","):
        mine = {r["frames"]: r for r in rows if r["kind"] == kind}
        if len(mine) == 2:
            (n0, a), (n1, b) = sorted(mine.items())
            print(f"{kind}: {n1} frames / {n0} frames: peak x{b['peak_mb'] / a['peak_mb']:.2f}, "
                  f"time x{b['seconds'] / a['seconds']:.1f}")


if __name__ == "__main__":
    main()
