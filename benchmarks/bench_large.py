"""Restoration of an image larger than memory, zarr to zarr (issue 16, point 5),
run by hand under ``nice``:

    nice -n 10 .venv/bin/python benchmarks/bench_large.py [--side 16000] [--tile 2048]

The input: a real photograph (``../shared/data/textures/natural/bark.jpg``,
grey) mirrored to ``--side`` x ``--side`` pixels, 8-bit, with Gaussian noise
(sigma 12/255), written to a zarr store of 1024 x 1024 chunks tile by tile
(never whole in this process). Then the real command runs in a fresh process
(``python -m car_napari.cli restore in.zarr -o out.zarr --tile T``) and its
peak resident memory is sampled every 0.2 s with psutil. Printed: the image,
wall-clock seconds, megapixels per second, the peak RSS (GB), the load; and
a check on a crop: the output's 8-bit values against ``restore`` of the
crop's region taken with a halo and the global statistics the command used
(the tile function itself), to show the output is the restoration.

``--inpaint`` measures instead how far filling a frame by tiles is from one
fill of the whole frame (see car_napari/inpainting/_tiled.py):
on the 11 images of ``../shared/data/inpainting`` with their hand-drawn
masks, ``inpaint`` in memory against ``iter_inpaint_tiles`` with 128-pixel
tiles (so that every image is split) and halos of 32, 64 and 128 (the images
are 183 to 960 pixels: the default halo, 256, would hold most of them whole;
nothing is tuned here): the mean absolute difference of the two fills over
the masked pixels (8-bit levels) and their PSNR (one against the other). The
masks mark objects to remove, so the pixels under them are no ground truth:
this is the distance to the in-memory fill, not a quality score.

``--inpaint-compare SIDE`` fills the real damaged film scan
(``film-damage/cinestill50d_half_1``, its hand-made mask) resized to SIDE x
SIDE, two rounds alternating: ``inpaint`` in memory (a frame larger than
2048 a side is filled by its tiles), ``inpaint`` of the same frame as a dask
array, and the whole frame as one fill (``iter_inpaint_in_memory`` without
``by_tiles``, the definition before issue 16). Printed: the times, whether
the in-memory and the dask results are equal, and the PSNR of the tiles
against the one fill over the masked pixels.

``--compare SIDE`` times, in one process, ``restore`` in memory against
``restore_tiled`` (NumPy in and out, ``--tile``) on the noisy photograph at
SIDE x SIDE, two rounds alternating: the cost of the global passes and the
halos, and the largest difference of the two results.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
PHOTO = ROOT.parent / "shared" / "data" / "textures" / "natural" / "bark.jpg"


def make_input(path, side, seed=0):
    """The noisy mirrored photograph, written by bands of 1024 rows."""
    from skimage import color, io

    from car_napari.io.arrays import create_array

    photo = io.imread(str(PHOTO))
    grey = color.rgb2gray(photo[..., :3]) if photo.ndim == 3 else photo / 255.0
    tile = np.concatenate([grey, grey[::-1]], axis=0)
    tile = np.concatenate([tile, tile[:, ::-1]], axis=1)  # mirrored: seamless
    out = create_array(path, (side, side), np.uint8, chunks=1024)
    rng = np.random.default_rng(seed)
    h, w = tile.shape
    cols = np.arange(side) % w
    for r0 in range(0, side, 1024):
        rows = np.arange(r0, min(side, r0 + 1024)) % h
        band = tile[rows][:, cols] * 255 + rng.normal(0, 12, (len(rows), side))
        out[r0 : r0 + len(rows)] = np.clip(np.round(band), 0, 255).astype(np.uint8)
    return out


def run(cmd):
    """(seconds, peak RSS of the process tree in bytes, stderr)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    peak = 0
    parent = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            peak = max(peak, sum(p.memory_info().rss
                                 for p in [parent, *parent.children(recursive=True)]))
        except psutil.Error:
            pass
        time.sleep(0.2)
    seconds = time.perf_counter() - t0
    err = proc.stderr.read()
    if proc.returncode != 0:
        sys.exit(f"the command failed ({proc.returncode}):\n{err}")
    return seconds, peak, err


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=int, default=16000)
    parser.add_argument("--tile", type=int, default=2048)
    parser.add_argument("--keep", action="store_true", help="keep the stores")
    parser.add_argument("--inpaint", action="store_true",
                        help="the quality of a frame filled by tiles instead")
    parser.add_argument("--inpaint-compare", type=int, default=None, metavar="SIDE",
                        help="a large damaged frame: in memory, dask and one fill")
    parser.add_argument("--compare", type=int, default=None, metavar="SIDE",
                        help="in memory against tiles at SIDE x SIDE instead")
    args = parser.parse_args()
    if args.inpaint:
        return inpaint_quality()
    if args.inpaint_compare:
        return inpaint_compare(args.inpaint_compare)
    if args.compare:
        return compare(args.compare, args.tile)
    work = Path(tempfile.mkdtemp(prefix="car_bench_large_"))
    try:
        t0 = time.perf_counter()
        make_input(work / "in.zarr", args.side)
        made = time.perf_counter() - t0
        cmd = [sys.executable, "-m", "car_napari.cli", "restore", str(work / "in.zarr"),
               "-o", str(work / "out.zarr"), "--tile", str(args.tile)]
        seconds, peak, err = run(cmd)
        load = psutil.getloadavg()
        print(f"input {args.side} x {args.side} uint8 zarr (written in {made:.0f} s)")
        print(f"command: {' '.join(cmd[1:])}")
        print("| pixels | tile | seconds | Mpx/s | peak RSS (GB) | load (1, 5, 15 min) |")
        print("|---|---|---|---|---|---|")
        print(f"| {args.side}^2 | {args.tile} | {seconds:.0f} | "
              f"{args.side ** 2 / 1e6 / seconds:.2f} | {peak / 1e9:.2f} | "
              f"{load[0]:.1f}, {load[1]:.1f}, {load[2]:.1f} |")
        print(err.strip().splitlines()[-1] if err.strip() else "")
        check_crop(work, args.side)
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def check_crop(work, side):
    """The output at a crop in the middle against the tile function run on
    the crop with its halo and the image's global statistics."""
    from car_napari._progress import drain
    from car_napari.io.arrays import open_array
    from car_napari.model.neighbourhood import as_offsets
    from car_napari.restoration._tiled import (
        CORNERS,
        _iter_statistics,
        _restore_part,
        tile_halo,
    )

    image = open_array(work / "in.zarr")
    out = open_array(work / "out.zarr")
    summary, noise = drain(_iter_statistics(image, True, 2048, (0.0, 1.0)))
    halo = tile_halo(48, 1)
    c = (side // 2) // 16 * 16
    part = np.asarray(image[c - halo : c + 256 + halo, c - halo : c + 256 + halo])
    restored = _restore_part(part, mean=summary.mean, var=summary.var, noise=noise,
                             offsets=as_offsets(1)[0], directions=CORNERS, window=48,
                             keep_edges=True, kappa=0.0)[halo:-halo, halo:-halo]
    expect = np.round(np.clip(restored, 0, 1) * 255).astype(np.uint8)
    got = np.asarray(out[c : c + 256, c : c + 256])
    print(f"crop 256^2 at ({c}, {c}): {int(np.count_nonzero(got != expect))} of 65536 "
          f"8-bit values differ from the tile function; noise {noise[0]:.4f}")


def compare(side, tile):
    from car_napari.io.arrays import open_array
    from car_napari.restoration import restore, restore_tiled

    work = Path(tempfile.mkdtemp(prefix="car_bench_large_"))
    try:
        make_input(work / "in.zarr", side)
        image = np.asarray(open_array(work / "in.zarr")[:])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    restore(image[:256, :256])  # compiled kernels loaded
    times = {"in memory": [], "tiles": []}
    for _ in range(2):
        t0 = time.perf_counter()
        whole = restore(image)
        times["in memory"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        tiled = restore_tiled(image, tile=tile)
        times["tiles"].append(time.perf_counter() - t0)
    load = psutil.getloadavg()
    print(f"{side} x {side} uint8, tile {tile}, load {load[0]:.1f}, {load[1]:.1f}, "
          f"{load[2]:.1f}; max |tiles - in memory| = {np.abs(tiled - whole).max():.2g}")
    for name, values in times.items():
        print(f"| {name} | {min(values):.1f}-{max(values):.1f} s |")


def inpaint_compare(side):
    import dask.array as da
    from skimage import io
    from skimage.transform import resize

    from car_napari._progress import drain
    from car_napari.inpainting import inpaint
    from car_napari.inpainting._filling import iter_inpaint_in_memory

    film = ROOT.parent / "shared" / "data" / "film-damage" / "cinestill50d_half_1"
    frame = io.imread(film / "damaged.jpg")[..., :3]
    frame = np.clip(np.round(resize(frame, (side, side), order=1, preserve_range=True,
                                    anti_aliasing=False)), 0, 255).astype(np.uint8)
    mask = io.imread(film / "mask.png")
    mask = mask[..., :3].max(axis=2) if mask.ndim == 3 else mask
    rows = (np.arange(side) * mask.shape[0]) // side
    cols = (np.arange(side) * mask.shape[1]) // side
    mask = mask[rows][:, cols] > 127
    inpaint(frame[:256, :256], mask[:256, :256])  # compiled kernels loaded
    times = {"in memory (tiles)": [], "dask (tiles)": [], "one fill": []}
    for _ in range(2):
        t0 = time.perf_counter()
        tiles = inpaint(frame, mask)
        times["in memory (tiles)"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        lazy = inpaint(da.from_array(frame, chunks=(1024, 1024, 3)), mask)
        times["dask (tiles)"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        whole = drain(iter_inpaint_in_memory(frame, mask))
        times["one fill"].append(time.perf_counter() - t0)
    load = psutil.getloadavg()
    diff = tiles[mask].astype(float) - whole[mask].astype(float)
    psnr = 10 * np.log10(255.0 ** 2 / max(float(np.mean(diff ** 2)), 1e-12))
    print(f"{side} x {side} RGB uint8, {100 * mask.mean():.2f} % masked, load "
          f"{load[0]:.1f}, {load[1]:.1f}, {load[2]:.1f}; in memory == dask: "
          f"{bool(np.array_equal(tiles, lazy))}; tiles against one fill: {psnr:.1f} dB PSNR, "
          f"max |difference| {np.abs(diff).max():.0f} levels")
    for name, values in times.items():
        print(f"| {name} | {min(values):.1f}-{max(values):.1f} s |")


def inpaint_quality():
    from skimage import io

    from car_napari._progress import drain
    from car_napari.inpainting import inpaint
    from car_napari.inpainting._tiled import iter_inpaint_tiles

    folder = ROOT.parent / "shared" / "data" / "inpainting"
    halos = (32, 64, 128)
    print("| image | size | masked % | " + " | ".join(
        f"halo {h}: mean abs diff, PSNR vs in memory (dB)" for h in halos) + " |")
    print("|---" * (3 + len(halos)) + "|")
    rows = []
    for path in sorted(folder.glob("*.jpg")):
        image = io.imread(path)
        mask = io.imread(folder / "Mask" / f"{path.stem}_mask.jpg")
        mask = (mask[..., :3].max(axis=2) if mask.ndim == 3 else mask) > 128
        if mask.shape != image.shape[:2]:
            continue
        whole = inpaint(image, mask)[mask].astype(float)
        row, cells = [], []
        for h in halos:
            tiled = drain(iter_inpaint_tiles(image, mask, tile=128, tile_halo=h))[mask]
            diff = np.abs(tiled.astype(float) - whole)
            mse = max(float(np.mean(diff ** 2)), 1e-12)
            row += [diff.mean(), min(10 * np.log10(255.0 ** 2 / mse), 99.0)]
            cells.append(f"{row[-2]:.2f}, {row[-1]:.1f}")
        rows.append(row)
        print(f"| {path.stem} | {image.shape[1]}x{image.shape[0]} | {100 * mask.mean():.1f} | "
              + " | ".join(cells) + " |", flush=True)
    mean = np.mean(rows, axis=0)
    print("| mean | | | " + " | ".join(
        f"{mean[2 * k]:.2f}, {mean[2 * k + 1]:.1f}" for k in range(len(halos))) + " |")


if __name__ == "__main__":
    main()
