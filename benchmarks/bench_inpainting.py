"""Scratch and video restoration (section 14.7, docs/inpainting.md) by hand,
against OpenCV and scikit-image.

    PYTHONPATH=. python benchmarks/bench_inpainting.py [--frames N] [--skip-speed]

Needs ``opencv-python-headless`` (``pip install car-napari[bench]``).

(a) Real damaged 35 mm scans, ``../shared/data/film-damage/<scan>/``: the mask
    (white = damaged) resized to the scan by nearest neighbour; PSNR on the
    masked pixels against ``restored_by_hand.jpg``.
(b) Truth known: frames of ``../shared/data/old-film-clips/001`` (every 4th)
    and scikit-image's astronaut, coffee and chelsea, each with damage
    composited on: 3 real scratch artefacts from ``film-damage/scratch-
    overlays`` (alpha > 0.25 marks the scratch; RGBA over the image at their
    own scale, random positions, seed 0) and 3 vertical line scratches 2-4 px
    wide running the full height with a drift of up to 3 px, bright or dark.
    PSNR on the masked pixels.
(c) The clip as a clip: the 24 frames of ``old-film-clips/001``, each with
    its own line scratches and overlays (as in (b)), restored with and
    without the previous frame as context.
(d) ``detect_scratches`` (lines only) on (b): pixel precision and recall
    against the composited mask.
Speed: a 640x480 RGB frame with 2 % of its pixels masked (vertical lines).

Baselines, same masks, same run: ``cv2.inpaint`` Telea and Navier-Stokes
(radius 3) and ``skimage.restoration.inpaint_biharmonic``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from skimage import data as skdata
from skimage import io
from skimage.transform import resize

from car_napari.inpainting import detect_scratches, inpaint

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def methods():
    import cv2
    from skimage.restoration import inpaint_biharmonic

    def opencv(flag):
        def run(image, mask):
            return cv2.inpaint(image, mask.astype(np.uint8), 3, flag)
        return run

    def biharmonic(image, mask):
        out = inpaint_biharmonic(image, mask, channel_axis=-1 if image.ndim == 3 else None)
        return np.clip(np.round(out * 255), 0, 255).astype(np.uint8)

    return {
        "ours (CAR)": lambda image, mask: inpaint(image, mask),
        "OpenCV Telea": opencv(cv2.INPAINT_TELEA),
        "OpenCV Navier-Stokes": opencv(cv2.INPAINT_NS),
        "scikit-image biharmonic": biharmonic,
    }


def masked_psnr(truth, out, mask):
    err = truth[mask].astype(float) - out[mask].astype(float)
    return 10 * np.log10(255.0**2 / max(np.mean(err**2), 1e-12))


def line_scratches(shape, rng, count=3):
    """Vertical lines 2-4 px wide over the full height, drifting up to 3 px,
    each bright or dark: (mask, values)."""
    H, W = shape
    mask = np.zeros((H, W), bool)
    value = np.zeros((H, W))
    rows = np.arange(H)
    for _ in range(count):
        width = int(rng.integers(2, 5))
        start = rng.uniform(10, W - 20)
        drift = rng.uniform(-3, 3) * np.sin(np.pi * rows / H * rng.uniform(0.5, 2))
        bright = rng.random() < 0.5
        for i in rows:
            c = int(round(start + drift[i]))
            mask[i, c : c + width] = True
            value[i, c : c + width] = rng.uniform(200, 255) if bright else rng.uniform(0, 40)
    return mask, value


def composite(image, rng, overlays, n_overlays=3, n_lines=3):
    """Damaged copy and its mask (overlays at their own scale, then lines)."""
    out = image.astype(float).copy()
    colour = out.ndim == 3
    H, W = image.shape[:2]
    mask = np.zeros((H, W), bool)
    for k in rng.choice(len(overlays), n_overlays, replace=False):
        rgba = io.imread(overlays[k]).astype(float) / 255.0
        h, w = min(rgba.shape[0], H), min(rgba.shape[1], W)
        top, left = rng.integers(0, H - h + 1), rng.integers(0, W - w + 1)
        patch = rgba[:h, :w]
        alpha = patch[..., 3]
        rgb = patch[..., :3] * 255 if colour else patch[..., :3].mean(axis=2) * 255
        region = out[top : top + h, left : left + w]
        a = alpha[..., None] if colour else alpha
        region[...] = (1 - a) * region + a * rgb
        mask[top : top + h, left : left + w] |= alpha > 0.25
    lines, values = line_scratches((H, W), rng, n_lines)
    out[lines] = values[lines][:, None] if colour else values[lines]
    return np.clip(np.round(out), 0, 255).astype(np.uint8), mask | lines, lines


def bench_a(table):
    run = methods()
    for scan in sorted(p for p in (DATA / "film-damage").iterdir() if (p / "mask.png").exists()):
        damaged = io.imread(scan / "damaged.jpg")[..., :3]
        truth = io.imread(scan / "restored_by_hand.jpg")[..., :3]
        m = io.imread(scan / "mask.png")
        m = m[..., 0] if m.ndim == 3 else m
        mask = resize(m > 127, damaged.shape[:2], order=0, anti_aliasing=False).astype(bool)
        line = []
        for name, fn in run.items():
            t0 = time.perf_counter()
            out = fn(damaged, mask)
            seconds = time.perf_counter() - t0
            p = masked_psnr(truth, out, mask)
            table.setdefault(("a", name), []).append((p, seconds))
            line.append(f"{name.split(' (')[0]} {p:.2f}")
        print(f"(a) {scan.name} {damaged.shape} mask {100 * mask.mean():.1f} %: "
              + ", ".join(line), flush=True)


def test_images(frames):
    clip = sorted((DATA / "old-film-clips" / "001").glob("*.png"))
    for path in clip[::4][:frames]:
        yield f"film {path.stem}", io.imread(path)[..., :3]
    for name in ("astronaut", "coffee", "chelsea"):
        yield name, getattr(skdata, name)()


def bench_b_d(table, frames):
    rng = np.random.default_rng(0)
    overlays = sorted((DATA / "film-damage" / "scratch-overlays").glob("*.png"))
    run = methods()
    for name, image in test_images(frames):
        damaged, mask, lines = composite(image, rng, overlays)
        line = []
        for method, fn in run.items():
            t0 = time.perf_counter()
            out = fn(damaged, mask)
            seconds = time.perf_counter() - t0
            p = masked_psnr(image, out, mask)
            table.setdefault(("b", method), []).append((p, seconds))
            line.append(f"{method.split(' (')[0]} {p:.2f}")
        proposed = detect_scratches(damaged, kinds="line")
        hit = (proposed & lines).sum()
        precision, recall = hit / max(proposed.sum(), 1), hit / max(lines.sum(), 1)
        table.setdefault(("d", "detector, line scratches"), []).append((precision, recall))
        print(f"(b) {name} mask {100 * mask.mean():.1f} %: " + ", ".join(line)
              + f"; detector P {precision:.2f} R {recall:.2f}", flush=True)


def bench_c(table):
    rng = np.random.default_rng(1)
    overlays = sorted((DATA / "film-damage" / "scratch-overlays").glob("*.png"))
    frames = [io.imread(p)[..., :3] for p in sorted((DATA / "old-film-clips" / "001")
                                                     .glob("*.png"))]
    damaged, masks = zip(*[composite(f, rng, overlays, n_overlays=2, n_lines=2)[:2]
                           for f in frames], strict=True)
    clip, masks, truth = np.stack(damaged), np.stack(masks), np.stack(frames)
    for temporal in (True, False):
        t0 = time.perf_counter()
        out = inpaint(clip, masks, temporal=temporal)
        seconds = (time.perf_counter() - t0) / len(frames)
        p = masked_psnr(truth, out, masks)
        table[("c", f"ours, temporal context {'on' if temporal else 'off'}")] = [(p, seconds)]
        print(f"(c) temporal {temporal}: {p:.2f} dB, {seconds:.2f} s/frame", flush=True)


def bench_speed():
    image = (resize(skdata.astronaut(), (480, 640), order=1) * 255).astype(np.uint8)
    rng = np.random.default_rng(0)
    mask = np.zeros((480, 640), bool)
    while mask.mean() < 0.02:
        c = int(rng.integers(5, 630))
        mask[:, c : c + 3] = True
    inpaint(image[:64, :64], mask[:64, :64] | (np.arange(64) == 5))  # compile first
    best = min(_timed(inpaint, image, mask) for _ in range(3))
    print(f"\nspeed 640x480 RGB, {100 * mask.mean():.1f} % masked: {best:.2f} s (best of 3)")


def _timed(fn, *args):
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6, help="clip frames used in (b)")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args()
    table = {}
    bench_a(table)
    bench_b_d(table, args.frames)
    bench_c(table)
    print("\n| part | method | PSNR on masked pixels (dB) | s/image |")
    print("|---|---|---|---|")
    for (part, method), rows in table.items():
        if part == "d":
            continue
        v = np.array(rows)
        print(f"| ({part}) | {method} | {v[:, 0].mean():.2f} | {v[:, 1].mean():.2f} |")
    d = np.array(table[("d", "detector, line scratches")])
    print(f"\n(d) line detector on (b): precision {d[:, 0].mean():.2f}, "
          f"recall {d[:, 1].mean():.2f}")
    if not args.skip_speed:
        bench_speed()


if __name__ == "__main__":
    main()
