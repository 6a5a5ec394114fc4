"""Automatic K of the segmentation on simple mosaics, before and after, run by hand.

    PYTHONPATH=. python benchmarks/bench_auto_k.py [--split report|tuning|both]
        [--count 4] [--size 256] [--five] [--tuning-seeds 1 2] [--cache DIR]

Mosaics of 2 and 3 textures (``--size`` pixels a side) in two layouts,
straight strips (vertical or horizontal) and Voronoi-like cells
(benchmarks/mosaics.py), from four sets: ``brodatz`` (grey), ``vistex``
(colour), ``vistex-grey`` (VisTex made grey) and ``natural`` (colour);
``--count`` mosaics per set, number of textures and layout.

The split: the textures of every folder are split too, the sorted files
alternately: the odd ones (2nd, 4th, ...) make the TUNING mosaics, the even
ones (1st, 3rd, ...) the REPORT mosaics. TUNING mosaics have seeds 1 (more
with ``--tuning-seeds``, never 0); REPORT mosaics have seed 0. Nothing is
chosen on REPORT.

Every mosaic is segmented once (automatic K); the merge history is the same
whatever rule reads K off it, so the rule before issue 32 (``before``: the
first merge costing more than 0.06 nats per feature dimension), the first
step of issue 32 (``relative``: ... and more than 0.22 of the costliest
merge) and the rule of the package (``after``: ``segment``'s own rule, on
the same history) are scored on the same run (a fresh run also checks that
segment chose that state). Then ``segment(..., region_threshold=0.1)``
runs (``region``: the segments of ``after``'s state merged while their
whole-segment CAR models predict each other within 0.1 nats per pixel and
channel; 0.1 was chosen on the TUNING mosaics of seeds 1-3, the largest of
0.05-0.2 that kept the 5-texture TUNING mosaics' CS) and is scored too.
Printed: the rate of mosaics whose labels have exactly the true number of
segments, with a bootstrap 95 % interval over mosaics, the mean K, CS and
ARI, and the paired differences of exact K.

``--five`` also runs the 5-texture benchmark of bench_segmentation.py
(512x512, 6 mosaics per set, its TUNING or REPORT sets and seeds) and prints
its means (CS, OS, US, ME, NE, acc, ARI, VI, K) before and after.

``--cache DIR`` keeps every mosaic's merge history and per-state scores
(a pickle per mosaic) so a rerun only reads them.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from itertools import pairwise
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from mosaics import DATA, all_scores, make_mosaic, mosaic_set  # noqa: E402

SETS = {"brodatz": ("brodatz", False), "vistex": ("vistex", False),
        "vistex-grey": ("vistex", True), "natural": ("natural", False)}
LAYOUTS = ("strips", "voronoi")
N_TEXTURES = (2, 3)
# the 5-texture benchmark's sets and seeds (bench_segmentation.py)
FIVE_SETS = {"vistex": ("vistex", False), "brodatz": ("brodatz", False),
             "natural-grey": ("natural", True), "vistex-grey": ("vistex", True)}
FIVE_SPLITS = {"tuning": {"seeds": (1,), "kinds": ("brodatz", "vistex", "natural-grey")},
               "report": {"seeds": (0,), "kinds": tuple(FIVE_SETS)}}
OLD_NATS_PER_FEATURE = 0.06  # the stop before issue 32
OLD_RELATIVE = 0.22  # the first step of issue 32: also 0.22 of the costliest merge


def split_files(folder, split):
    """The textures of ``folder`` in ``split``: the sorted files alternately."""
    files = sorted(f for f in (DATA / folder).iterdir() if f.suffix in (".png", ".jpg"))
    return files[1::2] if split == "tuning" else files[0::2]


def simple_mosaics(kind, split, seed, count, n_textures, layout, size):
    """``count`` mosaics of ``n_textures`` textures of the split's files."""
    folder, grey = SETS[kind]
    files = split_files(folder, split)
    key = sum(map(ord, kind + layout)) + 7 * n_textures
    rng = np.random.default_rng([seed, key])
    for i in range(count):
        chosen = [files[j] for j in rng.choice(len(files), n_textures, replace=False)]
        yield make_mosaic(chosen, shape=(size, size), seed=seed * 1000 + key * 10 + i,
                          grey=grey, layout=layout)


def old_rule(history, n_features, relative=0.0):
    """K before issue 32: the first merge costing more than 0.06 nats per
    feature dimension (and, with ``relative``, more than that fraction of
    the costliest merge) stops the merging (index into ``history``)."""
    limit = max(OLD_NATS_PER_FEATURE * n_features,
                relative * max(a.loglik - b.loglik for a, b in pairwise(history)))
    for i in range(len(history) - 1):
        if history[i].loglik - history[i + 1].loglik > limit:
            return i
    return len(history) - 1


REGION_THRESHOLD = 0.1  # segment's region_threshold of the ``region`` rule


def run_mosaic(image, truth, cache_file=None):
    """Segment once; per merge state: the mixture's summary and the scores
    of its labels; then the scores with the region merging
    (``record["region"]``). Returns a record (dict), cached in
    ``cache_file`` (the region merging's part beside it)."""
    record = _history_record(image, truth, cache_file)
    region_file = cache_file and cache_file.with_name(cache_file.stem + "-region.pkl")
    if region_file is not None and region_file.exists():
        record["region"] = pickle.loads(region_file.read_bytes())
        return record
    from car_napari.segmentation import segment

    result = segment(image, channel_axis=-1 if image.ndim == 3 else None,
                     region_threshold=REGION_THRESHOLD)
    record["region"] = dict(scores=all_scores(truth, result.labels))
    if region_file is not None:
        region_file.write_bytes(pickle.dumps(record["region"]))
    return record


def _history_record(image, truth, cache_file):
    """The merge history's states and scores (segment's defaults)."""
    if cache_file is not None and cache_file.exists():
        return pickle.loads(cache_file.read_bytes())
    from car_napari.segmentation import segment

    t0 = time.perf_counter()
    result = segment(image, channel_axis=-1 if image.ndim == 3 else None)
    seconds = time.perf_counter() - t0
    states = []
    for mix in result.history:
        labels = result.labels_at(mix.k)
        states.append(dict(k=mix.k, loglik=mix.loglik, weights=mix.weights,
                           means=mix.means, variances=mix.variances,
                           areas=np.bincount(labels.ravel())[1:],
                           scores=all_scores(truth, labels)))
    record = dict(states=states, final=result._final, n_features=result.features.shape[2],
                  true_k=int(truth.max()), seconds=seconds, shape=truth.shape)
    if new_rule(record) != result._final:
        raise RuntimeError("segment chose another state than its rule on its history")
    if cache_file is not None:
        cache_file.parent.mkdir(parents=True, exist_ok=True)
        cache_file.write_bytes(pickle.dumps(record))
    return record


class _State:
    """What a rule reads of a history state (like a Mixture)."""

    def __init__(self, state):
        self.k, self.loglik, self.weights = state["k"], state["loglik"], state["weights"]
        self.means, self.variances = state["means"], state["variances"]


def new_rule(record):
    """K of the package (index into the record's states): segment's own
    rule (:func:`_choose_k` with the default stop) on the same history."""
    from car_napari.segmentation._mixture import _choose_k
    from car_napari.segmentation._segment import MERGE_NATS_PER_FEATURE, MERGE_RELATIVE

    history = [_State(s) for s in record["states"]]
    k = _choose_k(history, MERGE_NATS_PER_FEATURE * record["n_features"], MERGE_RELATIVE)
    return next(i for i, mix in enumerate(history) if mix.k == k)


def rules():
    """The rules compared: before (the stop before issue 32), relative (its
    first step, the relative stop alone), after (the history's stop, as
    segment applies it) and package (segment as shipped: the region test
    after that state); each gives its state's scores."""
    def history_rule(rule):
        return lambda rec: rec["states"][rule(rec)]["scores"]

    return {"before": history_rule(lambda rec: old_rule([_State(s) for s in rec["states"]],
                                                        rec["n_features"])),
            "relative": history_rule(lambda rec: old_rule([_State(s) for s in rec["states"]],
                                                          rec["n_features"], OLD_RELATIVE)),
            "after": history_rule(new_rule),
            "region": lambda rec: rec["region"]["scores"]}


def bootstrap(values, n=2000, seed=0):
    """Mean and bootstrap 95 % interval of ``values`` (resampled mosaics)."""
    values = np.asarray(values, float)
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, values.size, (n, values.size))].mean(axis=1)
    return values.mean(), np.percentile(means, 2.5), np.percentile(means, 97.5)


def exact_k_table(title, records, groups):
    """Exact-K rate (bootstrap 95 %), mean K, CS and ARI of every rule."""
    print(f"\n{title}\n")
    print("| rule | group | n | exact K % (95 %) | mean K | CS | ARI |")
    print("|---|---|---|---|---|---|---|")
    for name, rule in rules().items():
        for group, recs in [("all", records)] + [(g, [r for r in records if r["group"] in v])
                                                 for g, v in groups.items()]:
            if not recs:
                continue
            picked = [rule(r) for r in recs]
            exact = [100.0 * (s["K"] == r["true_k"]) for s, r in zip(picked, recs, strict=True)]
            m, lo, hi = bootstrap(exact)
            print(f"| {name} | {group} | {len(recs)} | {m:.1f} ({lo:.1f}-{hi:.1f}) | "
                  f"{np.mean([s['K'] for s in picked]):.2f} | "
                  f"{np.mean([s['CS'] for s in picked]):.1f} | "
                  f"{np.mean([s['ARI'] for s in picked]):.3f} |", flush=True)
    exact = {name: np.array([rule(r)["K"] == r["true_k"] for r in records], float)
             for name, rule in rules().items()}
    for new, old in (("after", "before"), ("after", "relative"), ("region", "after")):
        m, lo, hi = bootstrap(100.0 * (exact[new] - exact[old]))
        print(f"\nexact K {new} - {old}, paired over the {len(records)} mosaics: "
              f"{m:+.1f} points (95 %: {lo:+.1f} to {hi:+.1f}; "
              f"{int((exact[new] > exact[old]).sum())} more, "
              f"{int((exact[new] < exact[old]).sum())} fewer)", flush=True)


def five_table(title, records):
    """The 5-texture benchmark's means, before and after."""
    keys = ("CS", "OS", "US", "ME", "NE", "acc", "ARI", "VI", "K")
    print(f"\n{title}\n")
    print("| rule | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, rule in rules().items():
        picked = [rule(r) for r in records]
        print(f"| {name} | " + " | ".join(
            f"{np.mean([s[k] for s in picked]):.3f}" if k in ("ARI", "VI")
            else f"{np.mean([s[k] for s in picked]):.2f}" for k in keys) + " |", flush=True)
    changed = sum(rules()["region"](r) != rules()["after"](r) for r in records)
    print(f"\nthe region merging changed {changed} of {len(records)} mosaics", flush=True)


def run_simple(split, seeds, count, size, cache):
    records = []
    for kind in SETS:
        for n in N_TEXTURES:
            for layout in LAYOUTS:
                for seed in seeds:
                    mosaics = simple_mosaics(kind, split, seed, count, n, layout, size)
                    for i, (image, truth) in enumerate(mosaics):
                        name = f"simple-{split}-{kind}-{n}-{layout}-{size}-s{seed}-{i}.pkl"
                        rec = run_mosaic(image, truth, cache and cache / name)
                        rec["group"] = (kind, n, layout)
                        records.append(rec)
    return records


def run_five(split, seeds, count, cache):
    records = []
    for kind in FIVE_SPLITS[split]["kinds"]:
        folder, grey = FIVE_SETS[kind]
        for seed in seeds:
            for i, (image, truth) in enumerate(mosaic_set(folder, count=count, seed=seed,
                                                          grey=grey)):
                name = f"five-{kind}-s{seed}-{i}.pkl"
                rec = run_mosaic(image, truth, cache and cache / name)
                rec["group"] = kind
                records.append(rec)
    return records


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--split", choices=("report", "tuning", "both"), default="report")
    parser.add_argument("--count", type=int, default=4,
                        help="mosaics per set, number of textures and layout")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--five", action="store_true",
                        help="also the 5-texture benchmark (bench_segmentation.py)")
    parser.add_argument("--five-count", type=int, default=6)
    parser.add_argument("--tuning-seeds", nargs="+", type=int, default=(1,))
    parser.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args()
    if 0 in args.tuning_seeds:
        parser.error("seed 0 is the REPORT split; tuning seeds must not include it")
    splits = ("tuning", "report") if args.split == "both" else (args.split,)
    groups = {**{kind: [(kind, n, lay) for n in N_TEXTURES for lay in LAYOUTS]
                 for kind in SETS},
              **{f"{n} textures": [(kind, n, lay) for kind in SETS for lay in LAYOUTS]
                 for n in N_TEXTURES},
              **{lay: [(kind, n, lay) for kind in SETS for n in N_TEXTURES]
                 for lay in LAYOUTS}}
    for split in splits:
        seeds = tuple(args.tuning_seeds) if split == "tuning" else (0,)
        records = run_simple(split, seeds, args.count, args.size, args.cache)
        exact_k_table(f"{split.upper()}: {len(records)} mosaics {args.size}x{args.size} of 2 "
                      f"and 3 textures, seeds {seeds}", records, groups)
        if args.five:
            five = run_five(split, FIVE_SPLITS[split]["seeds"] if split == "report" else seeds,
                            args.five_count, args.cache)
            for kind in FIVE_SPLITS[split]["kinds"]:
                five_table(f"{split.upper()} 5 textures, {kind}: {args.five_count} mosaics "
                           f"512x512", [r for r in five if r["group"] == kind])
            five_table(f"{split.upper()} 5 textures, all {len(five)} mosaics", five)


if __name__ == "__main__":
    main()
