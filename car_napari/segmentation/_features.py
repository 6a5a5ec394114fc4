"""Per-pixel texture features of the segmentation: multiresolution local CAR
parameters ((14.33), section 14.4, docs/segmentation.md) and the pseudo-colour
of grey images.

Bounded work between yields and bounded memory: the directional scans run in
chunks of rows (:class:`~car_napari.model.recursive.RecursiveScan`) and
stream their parameters, which are reduced on the fly (two passes per
direction: one gathers the samples the robust scaling and the PCA are fitted
on, the second re-runs the scan and projects every pixel), so no image-sized
array of local parameters ever exists; the smoothing runs in place by blocks
of rows and columns; the result is float32. The peak is about 90 (grey) to
120 (RGB) bytes per pixel, the (H, W, D) float32 result (72 to 96) included,
on the full-resolution level (the image in float64, its whitened copy, the
twelve directional parameters in float32, the energy); every block of work
is ~0.1 s with a yield after it. The blocked steps are :mod:`._blocked`, the
directional scans :mod:`._directional`; here, the levels and their assembly.
"""

from __future__ import annotations

import math

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import Progress, drain, row_blocks, side_by_side, stage
from .._threads import job_pool
from .._validation import (
    check_forgetting,
    check_not_constant,
    check_real,
    check_seed,
    summarize,
)
from ..model.blocks import iter_channel_last_float, row_ranges
from ..model.directions import DIRECTIONS
from ..model.neighbourhood import Context, as_offsets
from ..model.recursive import scan_work
from ._blocked import (
    _LONG_ROWS,
    _NS_GAUSS,
    _NS_SCAN,
    _NS_VALUE,
    _SMALL_BLOCK,
    _iter_gaussian,
    _iter_pyramid_reduce,
    _iter_upsample,
    _iter_whiten_channels,
    _taps,
    _Work,
)
from ._directional import _SAMPLE, _direction_groups, _iter_direction, _pca_fit

__all__ = ["iter_local_features", "iter_pseudo_colour", "local_features", "pseudo_colour"]

# the coarsest pyramid level must keep at least this many pixels a side
_MIN_LEVEL_SIDE = 16
# more levels than any image has (2**30 * 16 pixels a side), and the widest
# Gaussian smoothing (pixels) and PCA components an option may ask
_MAX_LEVELS = 30
_MAX_SMOOTHING = 256.0
_MAX_COMPONENTS = 64


def _check_feature_options(levels, forgetting, components, smoothing, mean_smoothing, clip,
                           level_smoothing, seed):
    """The numeric options of :func:`iter_local_features`, checked before any
    pass over the image: a TypeError / ValueError naming the option."""
    check_real(levels, "levels", low=1, high=_MAX_LEVELS, integer=True)
    check_forgetting(forgetting)
    check_real(components, "components", low=1, high=_MAX_COMPONENTS, integer=True)
    check_real(smoothing, "smoothing", low=0.0, high=_MAX_SMOOTHING)
    if mean_smoothing is not None:
        check_real(mean_smoothing, "mean_smoothing", low=0.0, high=_MAX_SMOOTHING)
    check_real(clip, "clip", low=0.0)
    check_seed(seed)
    if level_smoothing not in ("same", "scaled"):
        raise ValueError(f"level_smoothing must be 'same' or 'scaled'; got {level_smoothing!r}.")


_PSEUDO_COLOUR_PARAMETERS = """
grey : (H, W) array_like
    Grey image, any numeric dtype; it is scaled to [0, 1] by its own
    minimum and maximum (a constant image becomes zeros).
gammas : sequence of float, optional
    The gamma exponents of the channels after the first.
"""


@shared_parameters(_PSEUDO_COLOUR_PARAMETERS)
def iter_pseudo_colour(grey, gammas=(0.5, 2.0)):
    """:func:`pseudo_colour` as a job: Progress per block of rows, then the image.

    {parameters}

    Returns
    -------
    (H, W, 1 + len(gammas)) ndarray of float64
        What :func:`pseudo_colour` returns.

    Yields
    ------
    Progress
        Stage "pseudo-colour" after each block of rows.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> drain(iter_pseudo_colour(np.array([[0, 1], [2, 4]])))[1, 0]
    array([0.5       , 0.70710678, 0.25      ])
    """
    g = np.asarray(grey)
    if g.ndim != 2 or g.size == 0 or g.dtype.kind not in "biuf":
        raise ValueError(f"grey must be a non-empty 2-D numeric image (H, W); got shape "
                         f"{g.shape}, dtype {g.dtype}.")
    try:
        gammas = tuple(check_real(gm, "gammas", low=0.0, low_open=True) for gm in gammas)
    except TypeError:
        raise TypeError(f"gammas must be positive exponents; got {gammas!r}.") from None
    if g.dtype != np.float64:
        g = g.astype(np.float64)
    if not np.isfinite(g).all():
        raise ValueError("grey has NaN or infinite values; pass finite values.")
    lo, hi = g.min(), g.max()
    out = np.empty(g.shape + (1 + len(gammas),))
    blocks = row_ranges(g.shape[0], g.shape[1] * 8 * (1 + len(gammas)))
    for k, (start, stop) in enumerate(blocks, start=1):
        base = out[start:stop, ..., 0]
        if hi > lo:
            np.subtract(g[start:stop], lo, out=base)
            base /= hi - lo
        else:
            base[...] = 0.0
        for c, gm in enumerate(gammas, start=1):
            np.power(base, gm, out=out[start:stop, ..., c])
        yield Progress("pseudo-colour", k / len(blocks), f"rows {stop}/{g.shape[0]}")
    return out


@shared_parameters(_PSEUDO_COLOUR_PARAMETERS)
def pseudo_colour(grey, gammas=(0.5, 2.0)):
    """Pseudo-colour ``[Y, Y^g1, Y^g2]`` of a grey image scaled to [0, 1].

    A grey image gives the three-channel CAR models of the segmentation
    something to correlate (section 14.4, docs/mammography.md).

    {parameters}

    Returns
    -------
    (H, W, 1 + len(gammas)) ndarray of float64
        The scaled image and its gamma transforms, channel last.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import pseudo_colour
    >>> pseudo_colour(np.array([[0, 1], [2, 4]]))[1, 0]
    array([0.5       , 0.70710678, 0.25      ])
    """
    return drain(iter_pseudo_colour(grey, gammas))


def _check_levels(shape, levels, neighbourhood):
    levels = check_real(levels, "levels", low=1, high=_MAX_LEVELS, integer=True)
    offsets, _ = as_offsets(neighbourhood)
    reach = Context.spatial(offsets, 1).reach
    need = (2 ** (levels - 1)) * max(_MIN_LEVEL_SIDE, 4 * (1 + sum(reach[1]) + sum(reach[0])))
    if min(shape[:2]) < need:
        raise ValueError(
            f"image {shape[0]}x{shape[1]} is too small for {levels} resolution "
            f"levels with this neighbourhood: each side needs at least {need} pixels. Use "
            "fewer levels, a smaller neighbourhood or a larger image."
        )






_FEATURE_PARAMETERS = """
image : (H, W) or (H, W, C) array_like
    The image, any numeric dtype (integers are scaled to [0, 1]).
levels : int, optional
    Resolutions; each halves the previous one.
neighbourhood : int or (eta, 2) array_like, optional
    Causal neighbourhood of the local models: an order or explicit
    (row, column) offsets (causal neighbourhoods, docs/model.md).
forgetting : float, optional
    Forgetting factor of the adaptive models, in [0.5, 1] (0.98: an effective
    window of about 50 pixels along each scan; 0.97-0.98 was best on the
    TUNING mosaics, docs/segmentation.md).
components : int, optional
    PCA components kept per direction (and ``components + 1`` per level).
smoothing : float, optional
    Gaussian width (pixels) of the smoothing of the stacked parameters.
mean_smoothing : float, optional
    Gaussian width of the local mean spectrum (default: ``smoothing``).
decorrelate : bool, optional
    Decorrelate the channels (spectral Karhunen-Loeve transform) first.
centre : bool, optional
    Re-centre each scan's estimates on the pixel (undo the forgetting lag).
clip : float, optional
    Robust standardisation clip (in MADs) of the parameters; 0 turns the
    standardisation off.
energy : bool, optional
    Append the log prediction-error energy of the local models.
level_smoothing : {'same', 'scaled'}, optional
    'same': the same widths on every level; otherwise halved per level.
channel_axis : int or None, optional
    Axis of the channels; a 2-D image is grey, None forces grey.
seed : int, optional
    Seed of the PCA subsampling.
"""


def _plan(shape, levels, ctx, *, smoothing, mean_smoothing, level_smoothing, energy,
          components, decorrelate):
    """Estimated work of the whole job, step by step as it runs (for progress
    fractions proportional to the work)."""
    h, w = shape
    d = ctx.n_targets
    width = ctx.n_targets * ctx.n_regressors
    first = scan_work(ctx, outputs=("gamma", "mean") if energy else ("gamma",), stream=True)
    second = scan_work(ctx, stream=True)
    per_level = (components + 1) + int(energy) + d
    total = 0.0
    hm, wm = h, w
    for m in range(levels):
        npx = hm * wm
        sig = smoothing if level_smoothing == "same" else smoothing / 2**m
        msig = mean_smoothing if level_smoothing == "same" else mean_smoothing / 2**m
        if decorrelate:
            total += (2 if d > 1 else 1) * _NS_VALUE * d * npx
        total += len(DIRECTIONS) * npx * (_NS_SCAN * (first + second) + _NS_VALUE * width)
        if msig > 0:
            total += 2 * _NS_GAUSS * _taps(msig) * npx * d
        if m + 1 < levels:
            total += 2 * _NS_GAUSS * _taps(2 / 3) * npx * d + _NS_VALUE * npx
        if sig > 0:
            total += 2 * _NS_GAUSS * _taps(sig) * npx * (len(DIRECTIONS) * components
                                                         + int(energy))
        total += _NS_VALUE * npx * len(DIRECTIONS) * components
        hm, wm = math.ceil(hm / 2), math.ceil(wm / 2)
    total += (levels - 1) * _NS_VALUE * 4 * h * w * per_level  # the resizing
    total += 2 * _NS_VALUE * h * w * per_level * levels  # the standardisation
    return total


@shared_sections(parameters=_FEATURE_PARAMETERS,
                 raises=raises_as("local_features", "ValueError"))
def iter_local_features(
    image,
    *,
    levels=3,
    neighbourhood=2,
    forgetting=0.98,
    components=3,
    smoothing=10.0,
    mean_smoothing=None,
    decorrelate=True,
    centre=True,
    clip=4.0,
    energy=True,
    level_smoothing="same",
    channel_axis=-1,
    seed=0,
):
    """Per-pixel texture features as a job: yield progress, return the features.

    See :func:`local_features` for what is computed. The work between two
    records is bounded (about 0.1 s: the scans in chunks of rows, the
    smoothing by blocks), and so is the memory: about 90 (grey) to 120 (RGB)
    bytes per pixel at the peak, the float32 result included.

    {parameters}

    Returns
    -------
    (H, W, D) ndarray of float32
        The features, what :func:`local_features` returns (the generator's return value).

    Yields
    ------
    Progress
        Stage "features", its fraction proportional to the estimated work:
        one record at the start, one after each directional scan and one
        after each level, and on a large image more in between (about every
        0.1 s of work: the rows of a scan, the blocks of the smoothing).

    {raises}

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import iter_local_features
    >>> job = iter_local_features(np.random.default_rng(0).random((32, 32)), levels=1)
    >>> messages = [record.message for record in job]
    >>> messages[0], sorted(m[11:] for m in messages if m.endswith(" scan"))
    ('level 1/1', ['down scan', 'left scan', 'right scan', 'up scan'])
    """
    _check_feature_options(levels, forgetting, components, smoothing, mean_smoothing, clip,
                           level_smoothing, seed)
    # the float copy by blocks (a large image yields on the way, at 0 %: a
    # small part of the work, and the plan needs its shape)
    convert = iter_channel_last_float(image, channel_axis=channel_axis, stage="features")
    data, summary = yield from stage(convert, 0.0, 0.0)
    check_not_constant(data, summary=summary)
    _check_levels(data.shape, levels, neighbourhood)
    offsets, _ = as_offsets(neighbourhood)
    if mean_smoothing is None:
        mean_smoothing = smoothing
    rng = np.random.default_rng(seed)
    h, w, d = data.shape
    ctx = Context.spatial(offsets, d)
    per_level = (components + 1) + int(bool(energy)) + d
    n_feats = levels * per_level
    work = _Work(_plan((h, w), levels, ctx, smoothing=smoothing, mean_smoothing=mean_smoothing,
                       level_smoothing=level_smoothing, energy=bool(energy),
                       components=components, decorrelate=decorrelate))
    q = float(forgetting) ** 2
    lag = int(round(q / (1.0 - q))) if (centre and q < 1) else 0
    # the result: level 0 is written, compact, to the end of the result's
    # buffer and spread out in place at the end (its untouched pages cost
    # nothing before); coarse levels are kept small until then
    buffer = np.empty(h * w * n_feats, np.float32)
    level_results = []
    yield Progress("features", 0.0, f"level 1/{levels}")
    level = data
    del data
    # the directional scans two at a time where two cores are there to take them
    # shared by every job (side_by_side waits for its steps: none is left on it)
    pool = job_pool()  # None: one thread
    for m in range(levels):
        label = f"level {m + 1}/{levels}"
        hm, wm = level.shape[:2]
        sig = smoothing if level_smoothing == "same" else smoothing / 2**m
        msig = mean_smoothing if level_smoothing == "same" else mean_smoothing / 2**m
        if decorrelate:
            centred = yield from _iter_whiten_channels(level, work, f"{label}: decorrelating")
        else:
            centred = level.copy()
        source_summary = summarize(centred)
        yield from work.progress(_NS_VALUE * hm * wm * d / 2, f"{label}: centring")
        for start, stop in row_blocks(hm * wm, _LONG_ROWS, merge_tail=True):
            centred.reshape(-1, d)[start:stop] -= source_summary.mean
            yield from work.progress(_NS_VALUE * (stop - start) * d, f"{label}: centring")
        reduced = np.empty((hm, wm, len(DIRECTIONS) * components), np.float32)
        err = np.zeros((hm, wm)) if energy else None
        # the PCA samples drawn in the directions' order, whatever runs when
        samples = [rng.choice(hm * wm, size=min(_SAMPLE, hm * wm), replace=False)
                   for _ in DIRECTIONS]
        # two directions side by side (their kernels release the GIL); the
        # second adds its energy into a buffer of its own, added after it, so
        # that the sum is the one of the directions in turn
        spare = np.zeros((hm, wm)) if energy and pool is not None else None
        for group in _direction_groups(pool):
            jobs = [_iter_direction(
                centred, ctx, source_summary.var, forgetting=forgetting,
                direction=DIRECTIONS[k], lag=lag, clip=clip, components=components,
                pca_index=samples[k],
                reduced=reduced[..., k * components : (k + 1) * components],
                err=spare if (energy and place) else err, work=work,
                message=f"{label}: {DIRECTIONS[k]} scan") for place, k in enumerate(group)]
            yield from side_by_side(jobs, pool)
            if spare is not None and len(group) > 1:
                err += spare
                spare[...] = 0.0
        del centred, spare
        # (in this order, so that the least is alive at once)
        current = level
        if m + 1 < levels:
            level = yield from _iter_pyramid_reduce(current, work, f"{label}: next level")
        # the stacked directional parameters, smoothed, reduced by PCA
        if sig > 0:  # the planes two at a time (ndimage releases the GIL)
            jobs = [_iter_gaussian(reduced[..., c], sig, work, f"{label}: smoothing")
                    for c in range(reduced.shape[2])]
            side = 2 if pool is not None else 1
            for k in range(0, len(jobs), side):
                yield from side_by_side(jobs[k : k + side], pool)
        flat = reduced.reshape(hm * wm, -1)
        idx = rng.choice(flat.shape[0], size=min(_SAMPLE, flat.shape[0]), replace=False)
        mean, axes = _pca_fit(flat[idx].astype(np.float64), components + 1)
        if m == 0:
            result = buffer[h * w * (n_feats - per_level):].reshape(h, w, per_level)
        else:
            result = np.empty((hm, wm, per_level), np.float32)
        out_flat = result.reshape(hm * wm, per_level)
        for start, stop in row_blocks(hm * wm, _LONG_ROWS, merge_tail=True):
            out_flat[start:stop, : components + 1] = (flat[start:stop] - mean) @ axes
            yield from work.progress(_NS_VALUE * flat.shape[1] * (stop - start),
                                     f"{label}: reducing")
        del reduced, flat
        # the local models' prediction-error energy (their Sigma, log scale)
        # and the local mean spectrum: their smoothings two at a time
        planes = [np.empty((hm, wm)) for _ in range(d)]
        jobs = [_iter_gaussian(err, sig, work, f"{label}: energy")] \
            if energy and sig > 0 else []
        for c in range(d):
            if msig > 0:
                jobs.append(_iter_gaussian(current[..., c], msig, work,
                                           f"{label}: local mean", out=planes[c]))
            else:
                planes[c][...] = current[..., c]
        side = 2 if pool is not None else 1
        for k in range(0, len(jobs), side):
            yield from side_by_side(jobs[k : k + side], pool)
        if energy:
            floor = 1e-6 * float(np.mean(source_summary.var))
            for start, stop in row_ranges(hm, wm):
                result[start:stop, :, components + 1] = np.log(err[start:stop] + floor)
            del err
        for c in range(d):
            # centred before the float32 store (every feature is standardised
            # at the end): an image far from zero keeps its contrast's precision
            result[..., per_level - d + c] = planes[c] - planes[c].mean()
        del planes, current
        level_results.append(result)
        if m + 1 < levels:
            yield work.step(0.0, f"{label} done", force=True)
    theta = yield from _iter_assemble(buffer, level_results, (h, w), work)
    yield Progress("features", 1.0, f"level {levels}/{levels} done")
    return theta




def _iter_assemble(buffer, level_results, shape, work):
    """The (H, W, D) result in ``buffer``: level 0 spread out from the end of
    the buffer in place, the coarse levels interpolated to full resolution,
    every feature standardised (zero mean, unit variance)."""
    h, w = shape
    per_level = level_results[0].shape[2]
    n_feats = per_level * len(level_results)
    theta = buffer.reshape(h, w, n_feats)
    first = level_results[0]
    if len(level_results) > 1:
        # each block's compact rows are copied out before the wide rows they
        # spread to are written; those end before any later compact row starts
        for start, stop in row_ranges(h, w * n_feats, _SMALL_BLOCK):
            rows = first[start:stop].copy()
            theta[start:stop, :, :per_level] = rows
            yield from work.progress(_NS_VALUE * rows.size * n_feats / per_level, "assembling")
    del first
    for m, coarse in enumerate(level_results[1:], start=1):
        yield from _iter_upsample(coarse, theta[..., m * per_level : (m + 1) * per_level],
                                  work, f"level {m + 1}/{len(level_results)}: resizing")
    level_results.clear()
    # standardise each feature: mean and variance in float64, by blocks
    blocks = row_ranges(h, w * n_feats, _SMALL_BLOCK)
    total = np.zeros(n_feats)
    for start, stop in blocks:
        total += theta[start:stop].sum(axis=(0, 1), dtype=np.float64)
        yield from work.progress(_NS_VALUE * (stop - start) * w * n_feats / 2, "standardising")
    mean = total / (h * w)
    square = np.zeros(n_feats)
    for start, stop in blocks:
        square += ((theta[start:stop] - mean) ** 2).sum(axis=(0, 1))
        yield from work.progress(_NS_VALUE * (stop - start) * w * n_feats, "standardising")
    std = np.sqrt(square / (h * w))
    scale = np.where(std > 0, std, 1.0)
    for start, stop in blocks:
        theta[start:stop] = (theta[start:stop] - mean) / scale
        yield from work.progress(_NS_VALUE * (stop - start) * w * n_feats, "standardising")
    return theta




@shared_parameters(_FEATURE_PARAMETERS)
def local_features(
    image,
    *,
    levels=3,
    neighbourhood=2,
    forgetting=0.98,
    components=3,
    smoothing=10.0,
    mean_smoothing=None,
    decorrelate=True,
    centre=True,
    clip=4.0,
    energy=True,
    level_smoothing="same",
    channel_axis=-1,
    seed=0,
):
    """Per-pixel texture features ``Theta_r`` of the segmentation, at full resolution.

    On each level of a Gaussian pyramid (colour first decorrelated by a
    spectral Karhunen-Loeve transform), the adaptive parameters of the four
    directional models (re-centred on the pixel, robustly standardised) are
    each reduced by PCA to ``components`` values, stacked, smoothed
    (Gaussian, ``smoothing`` pixels), reduced by PCA again to
    ``components + 1`` values, and joined by the log prediction-error energy
    of the local models and the local mean spectrum; coarse levels are
    interpolated to full resolution. Every feature is standardised. This is
    the feature vector of (14.33), section 14.4, docs/segmentation.md.

    {parameters}

    Returns
    -------
    (H, W, D) ndarray of float32
        The features, standardised features (zero mean, unit variance each).

    Raises
    ------
    ValueError
        If the image is constant, has NaN or infinite values, or is too
        small for ``levels`` resolutions.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import local_features
    >>> local_features(np.random.default_rng(0).random((32, 32)), levels=1).shape
    (32, 32, 6)
    """
    return drain(iter_local_features(
        image, levels=levels, neighbourhood=neighbourhood, forgetting=forgetting,
        components=components, smoothing=smoothing, mean_smoothing=mean_smoothing,
        decorrelate=decorrelate, centre=centre, clip=clip, energy=energy,
        level_smoothing=level_smoothing, channel_axis=channel_axis, seed=seed,
    ))
