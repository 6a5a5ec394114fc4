"""Outputs of every application on small real inputs, for behaviour checks, run by hand.

    PYTHONPATH=<tree> python benchmarks/bench_behaviour.py save OUT.npz
    python benchmarks/bench_behaviour.py compare A.npz B.npz

``save`` runs the model core (fit_car, local_parameters, synthesize, predict,
select_support, illumination_invariants, local_features), segment (automatic
K and K=3), restore (grey, RGB, tiled), restore_multichannel,
detect_scratches, inpaint (a crop of the shipped film around its mask),
TextureModel fit and synthesis (plain, tileable), rank,
detect_mammogram_rois and segment_tissue on small crops of the shipped
samples, and writes every output array to one .npz. ``compare`` prints
which arrays differ (NaN equal to NaN). A refactoring gives none: run
``save`` with each tree on PYTHONPATH, then ``compare``.
"""

import sys

import numpy as np


def _arrays(name, value, out):
    """``value`` (an array, a number, or a dict/tuple/list of them) into ``out``."""
    if isinstance(value, dict):
        for key, item in value.items():
            _arrays(f"{name}.{key}", item, out)
    elif (isinstance(value, (tuple, list)) and value and not np.isscalar(value[0])
          and not isinstance(value[0], str)):
        for i, item in enumerate(value):
            _arrays(f"{name}.{i}", item, out)
    else:
        out[name] = np.asarray(value)


def save(path):
    import car_napari as car
    from car_napari.io import sample_data
    try:
        from car_napari.restoration import restore_large
    except ImportError:  # a tree from before issue 33's naming
        from car_napari.restoration import restore_tiled as restore_large

    out = {}

    def put(name, value):
        _arrays(name, value, out)

    texture = np.asarray(sample_data.colour_texture()[0][0])[:128, :128]
    (mammogram, _, _), = sample_data.mammogram()
    film = sample_data.damaged_film()
    frame, mask = np.asarray(film[0][0]), np.asarray(film[1][0]) > 0
    stack = np.asarray(sample_data.degraded_stack(n_versions=4)[0][0])
    grey, rgb = texture.mean(axis=2) / 255.0, texture / 255.0
    rng = np.random.default_rng(0)
    # the model core
    model = car.fit_car(grey, 2)
    put("fit_car", [model.gamma, model.sigma, model.mean])
    put("local_parameters", car.local_parameters(grey[:64, :64], 2))
    put("synthesize", car.synthesize(model, (48, 48), seed=1))
    put("predict", list(car.predict(model, grey)))
    best, scores = car.select_support(grey[:64, :64])
    put("select_support", {"best": best, **{str(k): v for k, v in scores.items()}})
    put("invariants", car.illumination_invariants(rgb[:64, :64]))
    put("local_features", car.local_features(rgb[:64, :64], levels=1))
    # segmentation
    result = car.segment(rgb, levels=1)
    put("segment_auto", result.labels)
    put("segment_auto_k", result.n_segments)
    put("segment_3", car.segment(rgb, n_segments=3, levels=1).labels)
    # restoration
    noisy = np.clip(grey + rng.normal(0, 0.05, grey.shape), 0, 1)
    put("restore_grey", car.restore(noisy))
    put("restore_rgb", car.restore(np.clip(rgb + rng.normal(0, 0.05, rgb.shape), 0, 1)))
    put("restore_tiled", restore_large(noisy, tile=64))
    put("restore_multichannel", car.restore_multichannel(stack[:, :64, :64]))
    # inpainting: a crop of the film around its scratches
    f = frame.mean(axis=-1)
    rows, cols = np.nonzero(mask)
    r0, c0 = max(0, int(rows.mean()) - 80), max(0, int(cols.mean()) - 80)
    crop, hole = f[r0 : r0 + 160, c0 : c0 + 160], mask[r0 : r0 + 160, c0 : c0 + 160]
    put("detect_scratches", car.detect_scratches(crop))
    put("mask_pixels", hole.sum())
    put("inpaint", car.inpaint(crop, hole))
    # texture
    fitted = car.TextureModel.fit(rgb)
    put("texture_synth", fitted.synthesize((96, 96), seed=2))
    put("texture_tile", fitted.synthesize((64, 64), seed=3, tileable=True))
    put("rank", car.rank(rgb[:64, :64], [rgb[64:, 64:], rgb[:64, 64:]]).distances)
    # mammography
    put("rois", list(car.detect_mammogram_rois(mammogram[::2, ::2], marks_per_image=None)))
    tissue = car.segment_tissue(mammogram[::2, ::2])
    put("tissue", [tissue.fibroglandular, tissue.density, tissue.tissue_class])
    np.savez(path, **out)
    print(len(out), "arrays")


def compare(a_path, b_path):
    a, b = np.load(a_path), np.load(b_path)
    print("only in one:", sorted(set(a) ^ set(b)))
    differing = [k for k in a if k in b and not (a[k].shape == b[k].shape and np.array_equal(
        a[k], b[k], equal_nan=a[k].dtype.kind in "fc"))]
    print(len(a), "arrays; differing:", differing)


if __name__ == "__main__":
    if sys.argv[1] == "save":
        save(sys.argv[2])
    else:
        compare(sys.argv[2], sys.argv[3])
