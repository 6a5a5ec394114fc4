"""A clip with known motion and known damage (issue 13, points 3-5;
docs/inpainting.md): the blotch detector with and without motion
compensation, and the fill with motion-compensated temporal context.

    PYTHONPATH=. nice -n 5 python benchmarks/bench_clip.py [--part REPORT] [--skip-fill]
        [--sample]

**The clips.** Each clip is 9 frames of 216x288 RGB (8-bit): a real image
panned across the frame (0.5-1 px a frame down, 1.5-2.5 px across, in half
pixel steps: rendered at twice the size and block-averaged), with a region
of another real image (an ellipse of about 40 % of the frame's height)
sliding over it at another velocity (2-4 px a frame) and turning (about
1.5 degrees a frame). Damage, known exactly: on frames 1, 3, 5 and 7, five
synthetic blotches (irregular blobs, radius 2.5-8 px, dark or bright, soft
edged) and two real scratch artefacts (64x64 pieces of
``film-damage/scratch-overlays``, alpha-blended), half of them on the moving
region; on frames 2 to 6 two vertical line scratches 2-3 px wide (bright or
dark, drifting up to 1 px a frame). The damage mask is alpha > 0.25 (all
line pixels); a damaged pixel is *visible* when it changes the grey frame by
more than 0.05.

**TUNING and REPORT** (fixed): every image and overlay belongs to a part by
the SHA-1 of its name (``bench_inpainting.split``: first byte even =
TUNING); a clip is built from a background and a foreground of one part and
overlays of that part. TUNING: (astronaut, coffee), (Wall, chelsea),
(Bike, Flower); REPORT: (Eiffel, rocket), (Island, cat),
(Panel, camera), (b, grass). Every threshold of the motion
estimate and of the compensated blotch test was chosen on TUNING (and on
the archival sample clip, which has no ground truth); the figures to
report are REPORT's.

**Figures.** On the inner frames (the blotch test needs both neighbours):
- blotch *precision*: the flagged pixels within one pixel of damage (any
  damage: the 3x3 dilation the detector puts round what it finds) over all
  flagged pixels; *strict*: flagged pixels on damage;
- blotch *recall*: the visible blotch pixels (blobs and artefacts) flagged;
- *moving flagged*: the undamaged pixels of the moving region (more than
  one pixel from damage) flagged, as a fraction of them;
for ``detect_scratches(kinds="blotch")`` with ``motion=False`` (the old
test, SDIa on the raw neighbours) and ``motion=True``, and the moving
fraction also for both kinds (what the widget's Detect runs).
- The fill, PSNR (dB, 8-bit scale) on the damaged pixels with the true
  mask, pooled over the damaged frames: each frame alone; the previous
  restored frame as context (``inpaint(clip, temporal=True)``, today); the
  previous restored frame *warped onto the frame* (``estimate_motion`` with
  the frame's mask, ``warp_frame``) as context, through the public
  ``inpaint`` on the two-frame clip ``[warped previous, frame]``.

``--sample``: the speed of detect + restore (motion estimation included) on
the 24-frame archival clip ``old-film-clips/001`` (579x340), and the share
of its pixels flagged with and without motion compensation.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

import numpy as np
from scipy import ndimage
from skimage import data as skdata
from skimage import io
from skimage.transform import resize, rotate

from car_napari.inpainting import detect_scratches, inpaint
from car_napari.inpainting._motion import estimate_motion, warp_frame

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
PARTS = ("TUNING", "REPORT")
CLIPS = {
    "TUNING": [("astronaut", "coffee"), ("Wall", "chelsea"), ("Bike", "Flower")],
    "REPORT": [("Eiffel", "rocket"), ("Island", "cat"), ("Panel", "camera"),
               ("b", "grass")],
}
T, H, W = 9, 216, 288
BLOTCH_FRAMES = (1, 3, 5, 7)
LINE_FRAMES = (2, 3, 4, 5, 6)
VISIBLE = 0.05


def split(name):
    """The fixed part of an image or overlay: by the SHA-1 of its name."""
    return PARTS[hashlib.sha1(name.encode()).digest()[0] % 2]


def load(name):
    """A real colour image as float RGB in [0, 1]."""
    if hasattr(skdata, name) and name not in ("b",):
        img = getattr(skdata, name)()
    else:
        for path in (DATA / "inpainting" / f"{name}.jpg", DATA / "old-photos-scratched" /
                     f"{name}.png", DATA / "textures" / "natural" / f"{name}.jpg"):
            if path.exists():
                img = io.imread(path)
                break
        else:
            raise FileNotFoundError(name)
    img = np.asarray(img)
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    img = img[..., :3]
    return img.astype(float) / (255.0 if img.dtype.kind in "ui" else 1.0)


def overlays(part):
    folder = DATA / "film-damage" / "scratch-overlays"
    return [p for p in sorted(folder.glob("*.png")) if split(p.name) == part]


def block_mean(img):
    return 0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])


def make_clip(background, foreground, part, seed):
    """(clip (T, H, W, 3) uint8, clean (T, H, W, 3) float, damage (T, H, W),
    blotch damage, moving (T, H, W) bool)."""
    rng = np.random.default_rng(seed)
    vy, vx = rng.uniform(0.5, 1.0), rng.uniform(1.5, 2.5) * rng.choice([-1, 1])
    travel = int(np.ceil(max(abs(vy), abs(vx)) * T)) + 2
    bg = load(background)
    bg2 = resize(bg, (2 * (H + 2 * travel), 2 * (W + 2 * travel)), anti_aliasing=True)
    fg = load(foreground)
    fh, fw = int(0.42 * H), int(0.36 * W)
    side = int(np.hypot(fh, fw)) + 4  # room to turn
    fg2 = resize(fg, (2 * side, 2 * side), anti_aliasing=True)
    yy, xx = np.mgrid[: 2 * side, : 2 * side] + 0.5 - side
    ellipse = ((yy / fh) ** 2 + (xx / fw) ** 2 <= 1.0).astype(float)
    uy, ux = rng.uniform(-2, 2), -np.sign(vx) * rng.uniform(2.5, 4)
    spin = rng.uniform(1.0, 2.0) * rng.choice([-1, 1])
    cy, cx = rng.uniform(0.4, 0.6) * H, (0.3 if ux > 0 else 0.7) * W
    clean = np.empty((T, H, W, 3))
    moving = np.zeros((T, H, W), bool)
    for t in range(T):
        oy = int(round(2 * (travel + vy * t)))
        ox = int(round(2 * (travel + vx * t)))
        frame2 = bg2[oy : oy + 2 * H, ox : ox + 2 * W].copy()
        tile = rotate(fg2, spin * t, order=1, mode="edge")
        alpha = rotate(ellipse, spin * t, order=1)
        py = int(round(2 * (cy + uy * t))) - side
        px = int(round(2 * (cx + ux * t))) - side
        canvas_a = np.zeros((2 * H, 2 * W))
        canvas_f = np.zeros((2 * H, 2 * W, 3))
        r0, c0 = max(py, 0), max(px, 0)
        r1, c1 = min(py + 2 * side, 2 * H), min(px + 2 * side, 2 * W)
        if r1 > r0 and c1 > c0:
            canvas_a[r0:r1, c0:c1] = alpha[r0 - py : r1 - py, c0 - px : c1 - px]
            canvas_f[r0:r1, c0:c1] = tile[r0 - py : r1 - py, c0 - px : c1 - px]
        frame2 = canvas_a[..., None] * canvas_f + (1 - canvas_a[..., None]) * frame2
        clean[t] = block_mean(frame2)
        moving[t] = block_mean(canvas_a) > 0.5
    clean = np.round(clean * 255) / 255
    damaged = clean.copy()
    damage = np.zeros((T, H, W), bool)
    blotch = np.zeros((T, H, W), bool)
    pieces = overlays(part)
    for t in BLOTCH_FRAMES:
        for k in range(7):
            on_moving = k % 2 == 0 and moving[t].any()
            if on_moving:
                ys, xs = np.nonzero(ndimage.binary_erosion(moving[t], iterations=6))
                if not len(ys):
                    ys, xs = np.nonzero(moving[t])
                i = rng.integers(len(ys))
                y, x = ys[i], xs[i]
            else:
                y, x = rng.integers(12, H - 12), rng.integers(12, W - 12)
            if k < 5:  # a synthetic blotch: an irregular blob, soft edged
                r = rng.uniform(2.5, 8)
                n = int(2 * r + 6)
                yy, xx = np.mgrid[:n, :n] - (n - 1) / 2
                noise = ndimage.gaussian_filter(rng.standard_normal((n, n)), r / 2)
                blob = (np.hypot(yy, xx) / r + 0.6 * noise / (noise.std() + 1e-9)) < 1.0
                a = ndimage.gaussian_filter(blob.astype(float), 0.7)
                value = rng.uniform(0.0, 0.15) if rng.random() < 0.5 else rng.uniform(0.85, 1)
                rgb = np.full((n, n, 3), value)
            else:  # a real scratch artefact: a piece of an overlay
                ov = io.imread(pieces[int(rng.integers(len(pieces)))]).astype(float) / 255
                for _ in range(20):
                    r0, c0 = rng.integers(100, 400 - 164, size=2)
                    piece = ov[r0 : r0 + 64, c0 : c0 + 64]
                    if (piece[..., 3] > 0.25).mean() > 0.04:
                        break
                a, rgb, n = piece[..., 3], piece[..., :3], 64
            y0, x0 = int(y) - n // 2, int(x) - n // 2
            ry0, rx0 = max(y0, 0), max(x0, 0)
            ry1, rx1 = min(y0 + n, H), min(x0 + n, W)
            if ry1 <= ry0 or rx1 <= rx0:
                continue
            sa = a[ry0 - y0 : ry1 - y0, rx0 - x0 : rx1 - x0, None]
            sr = rgb[ry0 - y0 : ry1 - y0, rx0 - x0 : rx1 - x0]
            region = damaged[t, ry0:ry1, rx0:rx1]
            region[...] = sa * sr + (1 - sa) * region
            hit = sa[..., 0] > 0.25
            damage[t, ry0:ry1, rx0:rx1] |= hit
            blotch[t, ry0:ry1, rx0:rx1] |= hit
    columns = rng.uniform(20, W - 20, size=2)
    widths = rng.integers(2, 4, size=2)
    values = [rng.uniform(0.85, 1.0) if rng.random() < 0.5 else rng.uniform(0.0, 0.12)
              for _ in range(2)]
    for t in LINE_FRAMES:
        for k in range(2):
            c = int(round(columns[k] + rng.uniform(-1, 1) * (t - LINE_FRAMES[0]) * 0.5))
            damaged[t, :, c : c + widths[k]] = values[k]
            damage[t, :, c : c + widths[k]] = True
    clip = np.clip(np.round(damaged * 255), 0, 255).astype(np.uint8)
    return clip, clean, damage, blotch, moving


def detector_scores(clip, clean, damage, blotch, moving, **options):
    flagged = detect_scratches(clip, **options)[1:-1]
    damage, blotch, moving = damage[1:-1], blotch[1:-1], moving[1:-1]
    grey_change = np.abs(clip[1:-1].astype(float) / 255 - clean[1:-1]).mean(axis=-1)
    visible = blotch & (grey_change > VISIBLE)
    near = np.stack([ndimage.binary_dilation(d, structure=np.ones((3, 3), bool))
                     for d in damage])
    undamaged_moving = moving & ~near
    n = max(int(flagged.sum()), 1)
    return {
        "precision": float((flagged & near).sum() / n) if flagged.any() else 1.0,
        "strict": float((flagged & damage).sum() / n) if flagged.any() else 1.0,
        "recall": float((flagged & visible).sum() / max(int(visible.sum()), 1)),
        "moving": float((flagged & undamaged_moving).sum() / max(int(undamaged_moving.sum()),
                                                                 1)),
    }


def psnr(truth, out, mask):
    err = (truth[mask] - out[mask]) * 255.0
    return 10 * np.log10(255.0**2 / max(float(np.mean(err**2)), 1e-12))


def fill_scores(clip, clean, damage):
    frames = clip.astype(float) / 255
    damaged = [t for t in range(T) if damage[t].any()]
    single = frames.copy()
    for t in damaged:
        single[t] = inpaint(frames[t], damage[t])
    temporal = inpaint(frames, damage, temporal=True)
    compensated = frames.copy()
    compensated[0] = inpaint(frames[0], damage[0]) if damage[0].any() else frames[0]
    for t in range(1, T):
        if not damage[t].any():
            continue
        flow = estimate_motion(frames[t], compensated[t - 1], mask=damage[t])
        previous = warp_frame(compensated[t - 1], flow)
        pair = inpaint(np.stack([previous, frames[t]]),
                       np.stack([np.zeros_like(damage[t]), damage[t]]), temporal=True)
        compensated[t] = pair[1]
    mask = damage.copy()
    return {name: psnr(clean, out, mask) for name, out in
            (("single", single), ("temporal", temporal), ("compensated", compensated))}


def sample_speed():
    files = sorted((DATA / "old-film-clips" / "001").glob("*.png"))
    clip = np.stack([io.imread(f) for f in files])
    for motion in (False, True):
        t0 = time.perf_counter()
        mask = detect_scratches(clip, motion=motion)
        t1 = time.perf_counter()
        inpaint(clip, mask)
        t2 = time.perf_counter()
        print(f"sample clip {clip.shape}, motion={motion}: detect {t1 - t0:.2f} s, restore "
              f"{t2 - t1:.2f} s, total {t2 - t0:.2f} s; flagged {mask.mean() * 100:.2f} % of "
              "pixels")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=PARTS + ("both",), default="both")
    ap.add_argument("--skip-fill", action="store_true")
    ap.add_argument("--sample", action="store_true", help="only the sample clip's speed")
    args = ap.parse_args()
    if args.sample:
        sample_speed()
        return
    parts = PARTS if args.part == "both" else (args.part,)
    for part in parts:
        rows = []
        print(f"\n== {part} ==")
        for k, (bg, fg) in enumerate(CLIPS[part]):
            assert split(bg) == part and split(fg) == part, (bg, fg)
            clip, clean, damage, blotch, moving = make_clip(bg, fg, part, seed=100 + k)
            row = {}
            for name, options in (("SDIa raw", dict(kinds="blotch", motion=False)),
                                  ("compensated", dict(kinds="blotch", motion=True)),
                                  ("lines+compensated", dict(motion=True))):
                t0 = time.perf_counter()
                s = detector_scores(clip, clean, damage, blotch, moving, **options)
                s["seconds"] = time.perf_counter() - t0
                row[name] = s
            if not args.skip_fill:
                row["fill"] = fill_scores(clip, clean, damage)
            rows.append(row)
            print(f"{bg} + {fg}:")
            for name in ("SDIa raw", "compensated", "lines+compensated"):
                s = row[name]
                print(f"  {name:18s} precision {s['precision']:.3f} (strict {s['strict']:.3f})"
                      f"  recall {s['recall']:.3f}  moving flagged {s['moving'] * 100:.2f} %"
                      f"  ({s['seconds']:.1f} s)")
            if "fill" in row:
                f = row["fill"]
                print(f"  fill PSNR: single {f['single']:.2f}  temporal {f['temporal']:.2f}  "
                      f"compensated {f['compensated']:.2f} dB")
        print(f"-- {part}, mean over {len(rows)} clips --")
        for name in ("SDIa raw", "compensated", "lines+compensated"):
            m = {key: np.mean([r[name][key] for r in rows]) for key in
                 ("precision", "strict", "recall", "moving")}
            worst = {key: (min if key != "moving" else max)(r[name][key] for r in rows)
                     for key in ("precision", "recall", "moving")}
            print(f"  {name:18s} precision {m['precision']:.3f} (worst {worst['precision']:.3f}"
                  f", strict {m['strict']:.3f})  recall {m['recall']:.3f} (worst "
                  f"{worst['recall']:.3f})  moving flagged {m['moving'] * 100:.2f} % (worst "
                  f"{worst['moving'] * 100:.2f} %)")
        if not args.skip_fill:
            m = {key: np.mean([r["fill"][key] for r in rows]) for key in
                 ("single", "temporal", "compensated")}
            print(f"  fill PSNR: single {m['single']:.2f}  temporal {m['temporal']:.2f}  "
                  f"compensated {m['compensated']:.2f} dB")


if __name__ == "__main__":
    main()
