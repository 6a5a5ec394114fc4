"""Command line: ``car-napari fit | fit-texture | synthesize | retrieve | segment |
mammo | restore | inpaint | descratch``.

Uses only the public core API; no Qt, no napari.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .._progress import drain


def _read(path):
    from pathlib import Path

    from skimage import io

    if Path(path).suffix.lower() in DICOM_SUFFIXES:
        from ..io.dicom import read_dicom

        if not Path(path).exists():
            raise ValueError(f"no such file: {path}")
        return read_dicom(str(path))[0]
    try:
        image = io.imread(path)
    except FileNotFoundError:
        raise ValueError(f"no such file: {path}") from None
    except Exception as exc:
        raise ValueError(f"cannot read {path} as an image: {exc}") from None
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]  # drop alpha
    return image


def _order(text):
    """argparse type for --order: 'auto' or a positive integer."""
    if text == "auto":
        return text
    try:
        order = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"order must be 'auto' or a positive integer; got {text!r}") from None
    if order < 1:
        raise argparse.ArgumentTypeError(f"order must be 'auto' or a positive integer; got {order}")
    return order


def _fit(image, order):
    from ..model import fit_car

    neighbourhood = "auto" if order == "auto" else int(order)
    return fit_car(image, neighbourhood, channel_axis=-1 if image.ndim == 3 else None)


def cmd_fit(args):
    model = _fit(_read(args.image), args.order)
    json.dump(model.to_dict(), sys.stdout, indent=2)
    sys.stdout.write("\n")


def _from_unit(values, dtype):
    """Float values on the core's [0, 1] scale as ``dtype``: uint8 and uint16
    scaled and rounded, anything else float32."""
    if dtype in (np.uint8, np.uint16):
        return np.round(np.clip(values, 0.0, 1.0) * np.iinfo(dtype).max).astype(dtype)
    return np.asarray(values).astype(np.float32)


def _write_texture(path, sample, *, uint16=False):
    """PNG/JPEG/BMP: 8-bit (16-bit PNG with ``uint16``) of values in [0, 1];
    TIFF: float32 as is."""
    from pathlib import Path

    from skimage import io

    suffix = Path(path).suffix.lower()
    if suffix in (".tif", ".tiff"):
        out = _from_unit(sample, np.float32)
    elif suffix in (".png", ".jpg", ".jpeg", ".bmp"):
        out = _from_unit(sample, np.uint16 if uint16 and suffix == ".png" else np.uint8)
    else:
        raise ValueError(f"cannot write {path}: use .png, .jpg, .bmp (8-bit) or .tif (float).")
    io.imsave(path, out, check_contrast=False)
    return out


def _texture_model(args):
    """A TextureModel from a saved model (.npz) or fitted to an image."""
    from ..texture import TextureModel

    if str(args.source).lower().endswith(".npz"):
        return TextureModel.load(args.source), None
    image = _read(args.source)
    neighbourhood = "auto" if args.order == "auto" else int(args.order)
    model = TextureModel.fit(image, levels=args.levels, neighbourhood=neighbourhood,
                             channel_axis=-1 if image.ndim == 3 else None)
    return model, image


def cmd_fit_texture(args):
    model, image = _texture_model(args)
    model.save(args.output)
    print(f"wrote {args.output}: orders {list(model.orders)} per band, {model.nbytes} bytes "
          f"of parameters, compression {model.compression_ratio(image.shape):.0f}:1 at "
          f"{'x'.join(map(str, image.shape))}", file=sys.stderr)


def cmd_synthesize(args):
    model, image = _texture_model(args)
    sample = model.synthesize(tuple(args.size), seed=args.seed, tileable=args.tileable)
    uint16 = image is not None and image.dtype == np.uint16
    _write_texture(args.output, sample, uint16=uint16)
    print(f"wrote {args.output}: {sample.shape}, orders {list(model.orders)}",
          file=sys.stderr)



DICOM_SUFFIXES = {".dcm", ".dicom"}
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".gif",
                  *DICOM_SUFFIXES}


def expand_inputs(items):
    """Files, folders (their images, sorted) and glob patterns, in order."""
    import glob
    from pathlib import Path

    paths = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            paths += sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        elif any(ch in item for ch in "*?["):
            paths += sorted(Path(f) for f in glob.glob(item))
        else:
            paths.append(p)
    if not paths:
        raise ValueError(f"no input images found in {list(items)}")
    return paths


def _progress(i, n, label, stream=sys.stderr):
    width = 30
    filled = int(round(width * i / max(n, 1)))
    stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {i}/{n} {label[:40]:40s}")
    stream.flush()
    if i == n:
        stream.write("\n")


def _each_input(inputs, output):
    """(output folder, input path) for every input, with a progress bar."""
    from pathlib import Path

    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    paths = expand_inputs(inputs)
    for i, path in enumerate(paths):
        _progress(i, len(paths), path.name)
        yield out, path
    _progress(len(paths), len(paths), "done")


def cmd_segment(args):
    import time

    from skimage import io

    from ..segmentation import segment

    for out, path in _each_input(args.inputs, args.output):
        image = _read(str(path))
        t0 = time.perf_counter()
        result = segment(image, n_segments=args.segments, levels=args.levels,
                         channel_axis=-1 if image.ndim == 3 else None)
        labels = result.labels.astype(np.uint8 if result.labels.max() < 256 else np.uint16)
        io.imsave(out / f"{path.stem}_segments.png", labels, check_contrast=False)
        print(f"{path.name}: {result.n_segments} segments, {time.perf_counter() - t0:.1f} s",
              file=sys.stderr if args.quiet else sys.stdout)


def cmd_mammo(args):
    import csv
    import time
    from pathlib import Path

    from skimage import io

    from ..mammography import DEFAULT_MAX_REGIONS, TABLE_COLUMNS, detect_mammogram_rois

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    paths = expand_inputs(args.inputs)
    table_path = out / "rois.csv"
    failed = 0
    max_regions = DEFAULT_MAX_REGIONS if args.max_regions is None else args.max_regions or None
    with open(table_path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(("image", *TABLE_COLUMNS))
        for i, path in enumerate(paths):
            _progress(i, len(paths), path.name)
            t0 = time.perf_counter()
            try:
                image = _read(str(path))
                labels, table = detect_mammogram_rois(
                    image, reference=args.reference, tolerance=args.tolerance,
                    max_regions=max_regions, channel_axis=-1 if image.ndim == 3 else None)
            except ValueError as exc:  # one bad file must not lose the others
                failed += 1
                print(f"\n{path.name}: skipped: {exc}", file=sys.stderr)
                continue
            dtype = np.uint8 if labels.max() < 256 else np.uint16
            io.imsave(out / f"{path.stem}_rois.png", labels.astype(dtype), check_contrast=False)
            for row in zip(*(np.asarray(table[k]).tolist() for k in TABLE_COLUMNS)):
                writer.writerow((path.name, *row))
            fh.flush()
            print(f"{path.name}: {len(table['label'])} regions, "
                  f"{time.perf_counter() - t0:.1f} s",
                  file=sys.stderr if args.quiet else sys.stdout)
    _progress(len(paths), len(paths), "done")
    print(f"table: {table_path}", file=sys.stderr)
    if failed == len(paths):
        raise ValueError("no mammogram could be processed (see the messages above).")


def _kappa(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"kappa must be a number in [0, 1); got {text!r}") \
            from None
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"kappa must be in [0, 1); got {value}")
    return value


def cmd_restore(args):
    import time

    from skimage import io

    from ..restoration import DEFAULT_KAPPA, iter_restore, iter_restore_multichannel

    for out, path in _each_input(args.inputs, args.output):
        t0 = time.perf_counter()
        image = _read(str(path))
        if args.stack_axis is None:
            gen = iter_restore(image, channel_axis=-1 if image.ndim == 3 else None,
                               kappa=args.kappa or 0.0)
        else:
            kappa = DEFAULT_KAPPA if args.kappa is None else args.kappa
            colour = image.ndim == 4
            gen = iter_restore_multichannel(image, axis=args.stack_axis, kappa=kappa,
                                            channel_axis=-1 if colour else None)
        result = drain(gen)
        restored = result.restored()
        restored = restored[..., 0] if restored.shape[2] == 1 else restored
        source = image if args.stack_axis is None else np.take(image, 0, axis=args.stack_axis)
        restored = _from_unit(restored, source.dtype)
        suffix = ".tif" if restored.dtype == np.float32 else ".png"
        io.imsave(out / f"{path.stem}_restored{suffix}", restored, check_contrast=False)
        if args.probability:
            io.imsave(out / f"{path.stem}_probability.tif",
                      result.probability.astype(np.float32), check_contrast=False)
        ref = "" if result.reference is None else f", reference version {result.reference}"
        print(f"{path.name}: restored{ref}, {time.perf_counter() - t0:.1f} s",
              file=sys.stderr if args.quiet else sys.stdout)


def _read_mask(path, shape):
    from skimage.transform import resize

    mask = _read(str(path))
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2)
    mask = mask > (127 if mask.dtype == np.uint8 else 0.5 * mask.max())
    if mask.shape != shape:  # masks are often drawn at another resolution
        mask = resize(mask, shape, order=0, anti_aliasing=False).astype(bool)
    return mask


def cmd_inpaint(args):
    import time

    from skimage import io

    from ..inpainting import inpaint

    image = _read(args.image)
    mask = _read_mask(args.mask, image.shape[:2])
    t0 = time.perf_counter()
    out = inpaint(image, mask, channel_axis=-1 if image.ndim == 3 else None)
    io.imsave(args.output, out, check_contrast=False)
    print(f"wrote {args.output}: {int(mask.sum())} pixels restored "
          f"({100 * mask.mean():.1f} %), {time.perf_counter() - t0:.1f} s", file=sys.stderr)


def cmd_descratch(args):
    import re
    from pathlib import Path

    from skimage import io

    from ..inpainting import detect_scratches, iter_inpaint

    folder = Path(args.input)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of numbered frames.")
    paths = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    numbered = [p for p in paths if re.search(r"\d+", p.stem)]
    if not numbered:
        raise ValueError(f"no numbered frames (like 0001.png) in {folder}.")
    numbered.sort(key=lambda p: (int(re.findall(r"\d+", p.stem)[-1]), p.name))
    frames = np.stack([_read(str(p)) for p in numbered])
    colour = frames.ndim == 4
    kinds = ("line", "blotch") if len(frames) >= 3 else ("line",)
    masks = detect_scratches(frames, kinds=kinds, channel_axis=-1 if colour else None)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    gen = iter_inpaint(frames, masks, channel_axis=-1 if colour else None)
    n = len(numbered)
    while True:
        try:
            state = next(gen)
        except StopIteration:
            break
        path = numbered[state.frame]
        io.imsave(out / path.name, state.restored, check_contrast=False)
        if args.masks:
            io.imsave(out / f"{path.stem}_mask.png",
                      (masks[state.frame] * 255).astype(np.uint8), check_contrast=False)
        _progress(state.frame + 1, n, path.name)
    print(f"{n} frames, {100 * masks.mean():.2f} % of pixels restored -> {out}",
          file=sys.stderr)


def cmd_retrieve(args):
    from pathlib import Path

    from ..texture.retrieval import rank

    query = _read(args.query)
    folder = Path(args.gallery)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder of images.")
    colour = query.ndim == 3
    paths, images, skipped = [], [], []
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in IMAGE_SUFFIXES - DICOM_SUFFIXES:
            continue
        image = _read(str(path))
        if (image.ndim == 3) != colour:
            skipped.append(path.name)
            continue
        paths.append(path)
        images.append(image)
    if not images:
        raise ValueError(f"no {'colour' if colour else 'grey'} images in {folder}.")
    indices, distances = rank(query, images, channel_axis=-1 if colour else None)
    top = len(paths) if args.top is None else args.top
    for k, (i, dist) in enumerate(zip(indices[:top], distances[:top]), start=1):
        print(f"{k}\t{dist:.4g}\t{paths[i]}")
    if skipped:
        print(f"skipped ({'grey' if colour else 'colour'}, the query is "
              f"{'colour' if colour else 'grey'}): {', '.join(skipped)}", file=sys.stderr)


def build_parser():
    parser = argparse.ArgumentParser(
        prog="car-napari",
        description="Haindl's causal autoregressive (CAR) random-field models, headless.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("fit", help="fit a CAR model and print it as JSON")
    p.add_argument("image", help="image file (grey or RGB)")
    p.add_argument("--order", default="auto", type=_order,
                   help="neighbourhood order, or 'auto' for the decision rule (default)")
    p.set_defaults(run=cmd_fit)
    p = sub.add_parser("fit-texture", help="fit a multiresolution texture model; write it "
                                           "(.npz, a few kB)")
    p.add_argument("source", help="example texture (grey or RGB)")
    p.add_argument("-o", "--output", required=True, help="model file (.npz)")
    p.add_argument("--levels", type=int, default=3, help="pyramid levels (default 3)")
    p.add_argument("--order", default="auto", type=_order,
                   help="neighbourhood order, or 'auto' for the decision rule (default)")
    p.set_defaults(run=cmd_fit_texture)
    p = sub.add_parser("synthesize", help="synthesise a texture of any size from a model "
                                          "file or an example image")
    p.add_argument("source", help="model file (.npz from fit-texture) or example texture")
    p.add_argument("-o", "--output", required=True,
                   help="output image (.png/.jpg: 8-bit; .tif: float)")
    p.add_argument("--size", nargs=2, type=int, metavar=("H", "W"), default=(256, 256))
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--tileable", action="store_true", help="wrap seamlessly (toroidal)")
    p.add_argument("--levels", type=int, default=3, help="pyramid levels when fitting")
    p.add_argument("--order", default="auto", type=_order,
                   help="neighbourhood order when fitting, or 'auto' (default)")
    p.set_defaults(run=cmd_synthesize)
    p = sub.add_parser("retrieve", help="rank a folder of textures by illumination-invariant "
                                        "distance to a query")
    p.add_argument("query", help="query texture")
    p.add_argument("gallery", help="folder of images")
    p.add_argument("--top", type=int, default=None, help="print only the N nearest")
    p.set_defaults(run=cmd_retrieve)
    p = sub.add_parser("segment", help="unsupervised texture segmentation; label PNGs")
    p.add_argument("inputs", nargs="+", help="images, folders or glob patterns")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--segments", type=int, default=None,
                   help="number of segments (default: found automatically)")
    p.add_argument("--levels", type=int, default=3, help="resolutions (default 3)")
    p.add_argument("--quiet", action="store_true", help="per-image lines to stderr")
    p.set_defaults(run=cmd_segment)
    p = sub.add_parser("mammo", help="mammogram regions of interest; label PNGs and rois.csv")
    p.add_argument("inputs", nargs="+", help="mammograms (PNG, TIFF, DICOM), folders or globs")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--reference", type=float, default=None,
                   help="reference grey of a mass in [0, 1] (default: learned on mini-MIAS)")
    p.add_argument("--tolerance", type=float, default=None,
                   help="accepted distance from the reference (default: learned)")
    p.add_argument("--max-regions", type=int, default=None,
                   help="regions kept per image, best first (default: learned; 0: all)")
    p.add_argument("--quiet", action="store_true", help="per-image lines to stderr")
    p.set_defaults(run=cmd_mammo)
    p = sub.add_parser("restore", help="CAR restoration of degraded images or stacks")
    p.add_argument("inputs", nargs="+", help="images or stacks (e.g. multi-page TIFF), "
                                             "folders or globs")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--stack-axis", type=int, default=None,
                   help="each input is a stack of degraded versions along this axis "
                        "(multichannel restoration of the sharpest)")
    p.add_argument("--kappa", type=_kappa, default=None,
                   help="prediction-probability threshold in [0, 1) (default: 0.05 for "
                        "stacks, off for single images)")
    p.add_argument("--probability", action="store_true",
                   help="also write <name>_probability.tif (prediction probability)")
    p.add_argument("--quiet", action="store_true", help="per-image lines to stderr")
    p.set_defaults(run=cmd_restore)
    p = sub.add_parser("inpaint", help="fill the masked pixels of a frame (SPEC 6)")
    p.add_argument("image", help="damaged frame")
    p.add_argument("-m", "--mask", required=True,
                   help="mask image, white (nonzero) = damaged; resized to the frame if needed")
    p.add_argument("-o", "--output", required=True, help="output image file")
    p.set_defaults(run=cmd_inpaint)
    p = sub.add_parser("descratch", help="detect and restore scratches and blotches in a "
                                         "folder of numbered frames")
    p.add_argument("input", help="folder of numbered frames (0001.png, 0002.png, ...)")
    p.add_argument("-o", "--output", required=True, help="output folder (same file names)")
    p.add_argument("--masks", action="store_true", help="also write <frame>_mask.png")
    p.set_defaults(run=cmd_descratch)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except (ValueError, TypeError, OSError) as exc:
        print(f"car-napari: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
