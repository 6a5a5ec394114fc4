"""Restoration by the conditional mean of local CAR models (SPEC 4 and 5).

* :func:`restore`: one degraded image. Every pixel is predicted from its
  causal neighbours by a CAR model valid around it, for four mirrored
  neighbourhoods (up-left, up-right, down-left, down-right); the four
  one-step conditional means are combined, each weighted by how well it
  predicts the pixels next to this one (the causal model's directional bias
  cancels: +0.5 dB PSNR over one neighbourhood, measured on blurred, noisy
  images). The edge rule (14.40) then keeps observed values where the
  prediction errs by more than the noise explains, or the four disagree.
  The local model is by default the least-squares estimate over a window
  (:mod:`car_napari._windowed`, fast); ``estimator='recursive'`` uses the
  adaptive recursive estimator of SPEC 1.4 along four scan directions.
* :func:`restore_multichannel`: several registered degraded versions of one
  scene. The least degraded version is modelled by the 2.5D CAR model whose
  regression vector holds the causal neighbours in all versions and the other
  versions' pixels at the same place; a pixel is replaced by its prediction
  where the prediction probability exceeds ``kappa`` (14.50)-(14.52).
* :func:`estimate_psf`: the least-squares point-spread function (14.46)-(14.47)
  relating a restored image to the observed one, globally or per window.

The generators :func:`iter_restore` and :func:`iter_restore_multichannel`
yield progress and the running result (rows filling in, or refined as each
scan direction finishes) and return a :class:`RestorationResult`, which
re-thresholds at any ``kappa`` without recomputation.
"""

from __future__ import annotations

import os
import queue
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .._progress import drain
from ._kernels import accumulate_direction, combine_directions
from ._windowed import (
    valid_box,
    block_moments,
    combine_predictions,
    edge_weight,
    median_abs_laplacian,
    predict_block_models,
    predict_scratch_rows,
    window_models,
)
from .._validation import as_channel_last_float, check_not_constant, check_size, summarize
from ..model.neighbourhood import Context, as_offsets
from ..model.directions import DIRECTIONS, scan_shape
from ..model.recursive import adaptive_scan

__all__ = [
    "DEFAULT_KAPPA",
    "RestorationResult",
    "RestorationState",
    "estimate_noise",
    "estimate_psf",
    "iter_restore",
    "iter_restore_multichannel",
    "psf_width",
    "restore",
    "restore_multichannel",
    "sharpness",
]

# Threshold on the prediction probability (the predictive density relative to
# its peak, in [0, 1]) above which a pixel is replaced by its prediction;
# exp(-z^2/2) for a standardised error z, so 0.05 replaces |z| < 2.45.
DEFAULT_KAPPA = 0.05
# Windows (pixels) over which the edge rule, and the weighting of the scan
# directions, measure the local prediction error.
EDGE_WINDOW = 7
DIRECTION_WINDOW = 3
DIRECTION_POWER = 4
# Edge rule: directional predictions whose variance (3x3 mean) exceeds this
# many noise variances mark an edge (flat noise: 99.9 % of 3x3 means below 0.4).
EDGE_SPREAD = 0.7
# Side (pixels) of the window whose least-squares CAR model predicts a pixel
# (estimator='windowed'): 3 x 3 blocks of a third of it.
DEFAULT_WINDOW = 48
STRIP_ROWS = 64  # at most this many rows restored at a time by one core (windowed)


@dataclass
class RestorationState:
    """What :func:`iter_restore` yields while running."""

    stage: str
    fraction: float
    restored: np.ndarray | None = None  # running result, channel-last (H, W, C)


@dataclass
class RestorationResult:
    """Everything a restoration computed; :meth:`restored` re-thresholds it.

    Arrays are channel-last ``(H, W, C)`` floats (``C = 1`` for grey).

    Attributes
    ----------
    observed : the image that is restored (for a stack: the reference version).
    prediction : the one-step conditional mean, combined over the directions.
    probability : (H, W) prediction probability in [0, 1]: the Student-t
        predictive density of the observed value (SPEC 1.6) divided by its
        peak value, averaged over directions. 1 where the observation is the
        prediction, near 0 where the model cannot explain it (edges, outliers).
    weight : (H, W, C) or None, the edge rule's weight of the observation
        (1 keeps it, 0 takes the prediction); None when edges are not kept.
    reference : index of the reference version in a stack, else None.
    kappa : the threshold :meth:`restored` uses by default.
    noise : per-channel noise standard deviation used by the edge rule.
    """

    observed: np.ndarray
    prediction: np.ndarray
    probability: np.ndarray
    weight: np.ndarray | None
    reference: int | None
    kappa: float
    noise: np.ndarray

    def restored(self, kappa=None):
        """The restored image at threshold ``kappa`` (default: the run's).

        Pixels whose prediction probability is at most ``kappa`` keep their
        observed value (14.50); the others take the prediction, blended with
        the observation by the edge rule's weight when edges are kept.
        """
        kappa = self.kappa if kappa is None else _check_kappa(kappa)
        out = self.prediction
        if self.weight is not None:
            out = np.subtract(self.observed, out)  # one new array, then in place
            out *= self.weight
            out += self.prediction
        if kappa > 0:
            out = np.where((self.probability > kappa)[..., None], out, self.observed)
        return out

    def changed(self, kappa=None):
        """(H, W) bool: pixels whose restored value differs from the observed."""
        return np.any(self.restored(kappa) != self.observed, axis=-1)


# --- helpers ------------------------------------------------------------------


def _check_kappa(kappa):
    try:
        value = float(kappa)
    except (TypeError, ValueError):
        raise TypeError(f"kappa must be a number in [0, 1); got {kappa!r}.") from None
    if not 0.0 <= value < 1.0:
        raise ValueError(
            f"kappa must be in [0, 1) (a prediction probability: 0 replaces every pixel, "
            f"values near 1 almost none); got {kappa}."
        )
    return value


def _check_options(forgetting, directions, names=DIRECTIONS):
    if not 0.0 < float(forgetting) <= 1.0:
        raise ValueError(f"forgetting must be in (0, 1]; got {forgetting}.")
    if isinstance(directions, str):
        directions = names if directions == "all" else (directions,)
    directions = tuple(directions)
    bad = [d for d in directions if d not in names]
    if bad or not directions:
        raise ValueError(f"directions must be 'all' or a non-empty subset of {names}; "
                         f"got {directions}.")
    return float(forgetting), directions


def _offsets(neighbourhood, data):
    if isinstance(neighbourhood, str):
        if neighbourhood != "auto":
            raise ValueError(f"neighbourhood must be an order, offsets or 'auto'; got "
                             f"{neighbourhood!r}.")
        from ..model.estimation import select_support

        neighbourhood, _ = select_support(data, channel_axis=-1)
    offsets, _ = as_offsets(neighbourhood)
    return offsets


def estimate_noise(image, *, channel_axis=-1):
    """Standard deviation of white Gaussian noise, per channel.

    Immerkaer's (1996) Laplacian-difference estimate made robust: the median
    absolute response of the kernel ``[[1,-2,1],[-2,4,-2],[1,-2,1]]`` (which
    cancels planes and is ``6 sigma`` on white noise) divided by
    ``6 * 0.6745``. Edges and texture raise it a little; blur does not.
    """
    data = as_channel_last_float(image, channel_axis=channel_axis)
    if min(data.shape[:2]) < 3:
        raise ValueError(f"the image {data.shape[:2]} is too small to estimate noise "
                         "(needs at least 3 x 3 pixels).")
    return _noise(data)


def _noise(data):
    """:func:`estimate_noise` of validated channel-last float data."""
    return _noise_planes(np.moveaxis(data, -1, 0))


def _noise_planes(planes):
    """:func:`estimate_noise` of channel-first (C, H, W) planes."""
    return np.array([median_abs_laplacian(plane) for plane in planes]) / (6.0 * 0.6745)


def sharpness(stack, *, axis=0, channel_axis=None):
    """Sharpness of each version of a stack: the mean squared Laplacian after
    a 1-pixel Gaussian (which tames the noise so that blur decides).

    ``restore_multichannel(reference='auto')`` restores the sharpest version.
    """
    from scipy import ndimage

    versions = _versions(stack, axis=axis, channel_axis=channel_axis)
    return np.array([
        np.mean([np.mean(ndimage.gaussian_laplace(v[..., c], 1.0) ** 2)
                 for c in range(v.shape[2])])
        for v in versions
    ])


def _versions(stack, *, axis, channel_axis):
    """A list of channel-last float versions with clear errors."""
    if isinstance(stack, (list, tuple)):
        shapes = {np.shape(v) for v in stack}
        if len(shapes) > 1:
            raise ValueError(
                f"the versions differ in shape ({sorted(shapes)}); register and crop them "
                "to one shape first.")
        stack = np.stack(stack, axis=int(axis)) if stack else np.empty((0, 0, 0))
    try:
        arr = np.asarray(stack)
    except Exception as exc:
        raise TypeError(f"stack could not be converted to an array: {exc}") from exc
    if arr.ndim not in (3, 4):
        raise ValueError(
            f"stack must be (n, H, W) or (n, H, W, C) with the versions along `axis`; got "
            f"shape {arr.shape}. (Versions of different shapes: register and crop them to "
            "one shape first.)"
        )
    if arr.dtype == object:
        raise ValueError("the versions in the stack differ in shape; register and crop them "
                         "to one shape first.")
    axis = int(axis) % arr.ndim
    arr = np.moveaxis(arr, axis, 0)
    if arr.shape[0] < 2:
        raise ValueError(
            f"the stack holds {arr.shape[0]} version along axis {axis}; multichannel "
            "restoration needs at least 2 (use restore() for a single image)."
        )
    if channel_axis is not None and arr.ndim == 4:
        ch = int(channel_axis) % 4
        if ch == axis:
            raise ValueError("channel_axis and axis must differ.")
        # position of the channel axis after moving `axis` to the front
        ch = ch if ch > axis else ch + 1
        arr = np.moveaxis(arr, ch, -1)
        cax = -1
    else:
        cax = None if arr.ndim == 3 else -1
    return [as_channel_last_float(v, channel_axis=cax, name=f"version {i}")
            for i, v in enumerate(arr)]


def _run_directions(source, context, targets_var, *, forgetting, directions, outputs, prior):
    """Adaptive scans in several directions, two at a time on two cores (the
    kernels release the GIL). Yields (direction, ScanResult) as they finish."""
    for direction in directions:
        check_size(np.empty(scan_shape(source.shape, direction)), context.reach)

    def run(direction):
        return direction, adaptive_scan(source, context, targets_var, forgetting=forgetting,
                                        direction=direction, prior=prior, outputs=outputs)

    workers = max(1, min(len(directions), os.cpu_count() or 1, 4))
    if workers == 1:
        for direction in directions:
            yield run(direction)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(run, d) for d in directions]
        try:
            for future in futures:
                yield future.result()
        finally:  # closing the generator early: do not start what is queued
            for future in futures:
                future.cancel()


class _Average:
    """Combination of the directional predictions, weighted per pixel by each
    direction's local precision: the inverse of its mean squared prediction
    error over the DIRECTION_WINDOW square around the pixel (the pixel itself
    left out, so the weights never depend on ``X_r``), to DIRECTION_POWER.
    Across an edge the scans that run along it predict well and the ones
    crossing it do not; a plain average would blur the edge. NaN (no
    neighbourhood) = no vote. The sums are kept by Numba kernels.
    """

    def __init__(self, observed, offset):
        self.observed = np.ascontiguousarray(observed, dtype=np.float64)
        self.offset = np.ascontiguousarray(offset, dtype=np.float64).reshape(-1)
        shape = observed.shape
        self.mean_sum = np.zeros(shape)
        self.plain_sum = np.zeros(shape)
        self.square_sum = np.zeros(shape)
        self.prob_sum = np.zeros(shape[:2])
        self.weight_sum = np.zeros(shape[:2])
        self.count = np.zeros(shape[:2])

    def add(self, mean, logrel):
        accumulate_direction(self.observed, np.ascontiguousarray(mean),
                             np.ascontiguousarray(logrel), DIRECTION_WINDOW // 2,
                             int(DIRECTION_POWER), self.mean_sum, self.prob_sum,
                             self.weight_sum, self.plain_sum, self.square_sum, self.count)

    def spread(self):
        """(H, W, C) variance of the directional predictions (0 with < 2)."""
        n = np.maximum(self.count, 1)[..., None]
        var = self.square_sum / n - (self.plain_sum / n) ** 2
        return np.where(self.count[..., None] > 1, np.maximum(var, 0.0), 0.0)

    def prediction(self):
        """(prediction + offset, probability) in image shape."""
        pred = np.empty(self.observed.shape)
        prob = np.empty(self.observed.shape[:2])
        combine_directions(self.mean_sum, self.prob_sum, self.weight_sum, self.observed,
                           self.offset, pred, prob)
        return pred, prob


def _edge_weight(observed, prediction, spread, noise, pool=None, blend=False, out=None):
    """The edge rule (14.40), our reading: the weight of the observation.

    1. Edges: where the directional models disagree (the variance of their
       predictions, averaged over channels and over 3x3 pixels, exceeds
       ``EDGE_SPREAD`` times the noise variance), the observation is kept
       (weight 1). At an edge, the scans running along it predict it and the
       ones crossing it do not; in flat or well-modelled parts they agree to
       a fraction of the noise.
    2. Elsewhere the observation is blended in with weight ``1 - sigma^2 / v``
       (clipped to [0, 1]), ``v`` the local mean squared prediction error
       over EDGE_WINDOW pixels: where the error is all noise the prediction
       replaces the pixel; where it is larger (detail the model cannot
       predict) the observation comes back in proportion.
    (Literally, (14.40) keeps ``X_r`` when its error exceeds the mean error
    of its neighbours: about 40 % of the pixels of a flat noisy region, so it
    hardly denoises.) ``spread`` is (H, W), already averaged over channels.
    With ``blend``, returns the restored image ``prediction + weight
    (observed - prediction)`` instead (no weight array); rows run in two
    halves on ``pool`` when given; the result goes into ``out`` if given.
    """
    out = np.empty(observed.shape) if out is None else out
    args = (observed, np.ascontiguousarray(prediction), np.ascontiguousarray(spread), noise**2,
            EDGE_WINDOW // 2, EDGE_SPREAD * float(np.mean(noise**2)), bool(blend), out)
    if pool is None:
        edge_weight(*args, 0, observed.shape[0])
    else:
        _in_halves(pool, edge_weight, observed.shape[0], *args)
    return out


def _to_layout(out, image_ndim, channel_axis):
    if image_ndim == 2 or channel_axis is None:
        return out[..., 0]
    return np.moveaxis(out, -1, channel_axis)


# --- single image --------------------------------------------------------------


# The windowed estimator's four models: the causal neighbourhood mirrored so
# that the neighbours lie up-left, up-right, down-left or down-right of the
# pixel (the raster scans started from each corner). The recursive scans'
# down/up/right/left would repeat one: at order 1 'down' and 'right' both
# use the pixels above and to the left.
CORNERS = ("up-left", "up-right", "down-left", "down-right")


def _corner_displacements(offsets, corner):
    """Image displacements (di, dj) of the neighbours of the model ``corner``."""
    di, dj = np.asarray(offsets, np.int64).T
    si = -1 if corner.startswith("up") else 1
    sj = -1 if corner.endswith("left") else 1
    return si * di, sj * dj


def _in_halves(pool, kernel, n, *args):
    """Run ``kernel(*args, start, stop)`` over [0, n) in two halves on ``pool``."""
    half = (n + 1) // 2
    futures = [pool.submit(kernel, *args, a, b) for a, b in ((0, half), (half, n)) if b > a]
    for future in futures:
        future.result()


def _iter_windowed(planes, mean, var, offsets, directions, window, pool, live, probability):
    """The windowed estimator's predictions (see :mod:`car_napari._windowed`)
    on the centred channel-first ``planes``: yields RestorationState as strips
    of rows finish, returns (prediction (H, W, C) plus ``mean``, probability
    or None when not asked for, spread over channels)."""
    C, H, W = planes.shape
    # the statistics of every corner come from one pass, over the pixels whose
    # neighbours in all four corners lie inside (whichever corners are used)
    displacements = {d: _corner_displacements(offsets, d) for d in CORNERS}
    positions = sorted({(int(a), int(b)) for di, dj in displacements.values()
                        for a, b in zip(di, dj)}) + [(0, 0)]
    index = {pos: k for k, pos in enumerate(positions)}
    disp_i, disp_j = (np.array(v, np.int64) for v in zip(*positions))
    block = max(2, -(-int(window) // 3))
    nbi, nbj = -(-H // block), -(-W // block)
    A = len(positions) * C + 1
    moments = np.zeros((nbi, nbj, A, A))
    _in_halves(pool, block_moments, nbi, planes, disp_i, disp_j, block, moments)

    taps = []
    for direction in directions:
        di, dj = displacements[direction]
        tap_i, tap_j, tap_c = np.repeat(di, C), np.repeat(dj, C), np.tile(np.arange(C), len(di))
        taps.append((tap_i, tap_j, tap_c))
    ix = np.array([[index[(a, b)] * C + c for a, b, c in zip(*tap)] + [A - 1] for tap in taps])
    iy = np.arange(C) + (len(positions) - 1) * C
    var = float(np.mean(var)) or 1.0
    prior_x = np.full(ix.shape[1], 1e-6 * var)
    prior_x[-1] = 1e-6  # the intercept, as default_prior
    K, p = ix.shape
    gamma = np.empty((K, nbi, nbj, C, p))
    density_shape = (nbi, nbj) if probability else (0, 0)  # factors only for the density
    x_inv = np.empty((K, *density_shape, p, p))
    lam_inv = np.empty((K, *density_shape, C, C))
    exponent = np.empty((nbi, nbj))
    _in_halves(pool, window_models, nbi, moments, ix, iy, prior_x, np.full(C, 1e-6 * var),
               bool(probability), gamma, x_inv, lam_inv, exponent)
    boxes = np.array([valid_box(H, W, tap[0], tap[1]) for tap in taps], np.int64)

    # Strips of rows, two at a time on two cores, each with its own buffers:
    # the image fills in row by row, and the per-direction arrays stay small.
    # live: rows not yet restored show the observation
    pred = np.moveaxis(planes, 0, -1) + mean if live else np.empty((H, W, C))
    spread = np.zeros((H, W))
    density = np.ones((H, W)) if probability else None
    exponent_px = (np.repeat(np.repeat(exponent, block, axis=0), block, axis=1)[:H, :W]
                   if probability else None)
    height = int(np.clip(H // 8, 8, STRIP_ROWS))  # small images: still a few strips
    strips = [(r, min(H, r + height)) for r in range(0, H, height)]
    buffers = queue.SimpleQueue()
    for _ in range(2):
        rows = height + 2
        buffers.put((np.empty((K, C, rows, W)), np.empty((K, rows, W)),
                     np.empty((K, rows, W) if probability else (K, 0, 0)),
                     np.empty((K, rows, W) if probability else (K, 0, 0)),
                     np.empty((predict_scratch_rows(p, C), W))))

    def run(r0, r1):
        means, err2, ratio, weight, scratch = buffers.get()
        try:
            a0, a1 = max(0, r0 - 1), min(H, r1 + 1)  # the 3 x 3 precision needs a row each side
            for k in range(K):
                predict_block_models(planes, block, gamma[k], x_inv[k], lam_inv[k], *taps[k],
                                     bool(probability), scratch, means[k], ratio[k], err2[k],
                                     a0, a0, a1)
            combine_predictions(planes, mean, means, err2, boxes, int(DIRECTION_POWER), pred,
                                weight, spread, a0, r0, r1)
            if probability:  # the weighted Student-t density relative to its peak
                rows = slice(r0 - a0, r1 - a0)
                relative = np.exp(-exponent_px[r0:r1] * np.log1p(ratio[:, rows]))
                weights = weight[:, rows]
                density[r0:r1] = np.where(weights.sum(axis=0) > 0,
                                          np.sum(weights * relative, axis=0), 1.0)
        finally:
            buffers.put((means, err2, ratio, weight, scratch))

    futures = [pool.submit(run, *strip) for strip in strips]
    every = max(1, len(strips) // 8)  # a live image costs a copy: about 8 of them
    try:
        for done, future in enumerate(futures, start=1):
            future.result()
            running = pred.copy() if live and done < len(strips) and done % every == 0 else None
            yield RestorationState(f"rows {strips[done - 1][1]}/{H}",
                                   0.1 + 0.85 * done / len(strips), running)
    finally:  # closing the generator early: do not start what is queued
        for future in futures:
            future.cancel()
    return pred, density, spread


def _iter_recursive(centred, context, var, forgetting, directions, live):
    """The adaptive (recursive) estimator's predictions, as _iter_windowed but
    channel-last (H, W, C)."""
    average = _Average(centred, np.zeros(centred.shape[2]))
    for k, (_, result) in enumerate(_run_directions(
            centred, context, var, forgetting=forgetting, directions=directions,
            outputs=("mean", "logrel"), prior=1e-6), start=1):
        average.add(result["mean"], result["logrel"])
        running = average.prediction()[0] if live and k < len(directions) else None
        yield RestorationState(f"direction {k}/{len(directions)}", 0.95 * k / len(directions),
                               running)
    pred, prob = average.prediction()
    return pred, prob, average.spread().mean(axis=-1)


def iter_restore(image, *, neighbourhood=1, estimator="windowed", window=DEFAULT_WINDOW,
                 forgetting=0.995, directions="all", keep_edges=True, kappa=0.0, noise=None,
                 channel_axis=-1, live=True, probability=True):
    """:func:`restore` as a generator: yields :class:`RestorationState` as the
    work proceeds (with the running restored image unless ``live`` is False),
    returns a :class:`RestorationResult`. Without ``probability`` (windowed
    estimator only, ``kappa`` 0) the prediction-probability map is not
    computed (``result.probability`` is None), which saves about a third of
    the time."""
    return (yield from _iter_restore(
        image, neighbourhood=neighbourhood, estimator=estimator, window=window,
        forgetting=forgetting, directions=directions, keep_edges=keep_edges, kappa=kappa,
        noise=noise, channel_axis=channel_axis, live=live, probability=probability, blend=False))


def _iter_restore(image, *, neighbourhood, estimator, window, forgetting, directions,
                  keep_edges, kappa, noise, channel_axis, live, probability, blend):
    """:func:`iter_restore`; with ``blend`` the result's prediction is already
    the restored image (the edge rule applied, no weight array: what
    :func:`restore` needs and no more)."""
    kappa = _check_kappa(kappa)
    if estimator not in ("windowed", "recursive"):
        raise ValueError(f"estimator must be 'windowed' or 'recursive'; got {estimator!r}.")
    forgetting, directions = _check_options(
        forgetting, directions, CORNERS if estimator == "windowed" else DIRECTIONS)
    if isinstance(window, (bool, np.bool_)) or int(window) != window or int(window) < 6:
        raise ValueError(f"window must be an integer of at least 6 pixels; got {window!r}.")
    probability = bool(probability) or kappa > 0 or estimator == "recursive"
    # blend: nothing keeps the image, so a float64 input need not be copied
    data, summary = as_channel_last_float(image, channel_axis=channel_axis, with_summary=True,
                                          copy=not blend)
    check_not_constant(data, summary=summary)
    offsets = _offsets(neighbourhood, data)
    context = Context.spatial(offsets, data.shape[2])
    check_size(data, context.reach)
    if noise is not None:
        noise = np.broadcast_to(np.asarray(noise, float), (data.shape[2],)).copy()
        if np.any(noise < 0) or not np.all(np.isfinite(noise)):
            raise ValueError(f"noise must be finite and >= 0; got {noise}.")
    yield RestorationState("start", 0.0)
    with ThreadPoolExecutor(max_workers=2) as pool:
        if estimator == "windowed":
            # channel-first: every kernel runs along contiguous rows
            planes = np.empty(np.roll(data.shape, 1))
            source = np.moveaxis(data, -1, 0)
            _in_halves(pool, lambda a, b: np.subtract(  # NumPy releases the GIL
                source[:, a:b], summary.mean[:, None, None], out=planes[:, a:b]), data.shape[0])
            # the noise level is estimated beside the kernels (the queue keeps
            # two cores busy); the Laplacian ignores the mean
            noise_future = pool.submit(_noise_planes, planes) if noise is None else None
            pred, prob, spread = yield from _iter_windowed(
                planes, summary.mean, summary.var, offsets, directions, window, pool, live,
                probability)
            if noise_future is not None:
                noise = noise_future.result()
            weight = None
            if keep_edges and blend:  # the restored image straight away, no weight array,
                # written over the planes, which are no longer needed (fresh memory is
                # slow to touch: page faults cost as much as a kernel here)
                pred = _edge_weight(data, pred, spread, noise, pool, blend=True,
                                  out=planes.reshape(data.shape))
            elif keep_edges:
                weight = _edge_weight(data, pred, spread, noise, pool)
        else:
            noise_future = pool.submit(_noise, data) if noise is None else None
            centred = np.ascontiguousarray(data - summary.mean)
            pred, prob, spread = yield from _iter_recursive(
                centred, context, summary.var, forgetting, directions, live)
            if noise_future is not None:
                noise = noise_future.result()
            pred += summary.mean
            weight = None
            if keep_edges and blend:
                pred = _edge_weight(data, pred, spread, noise, blend=True)
            elif keep_edges:
                weight = _edge_weight(data, pred, spread, noise)
    return RestorationResult(data, pred, prob, weight, None, kappa, noise)


def restore(image, *, neighbourhood=1, estimator="windowed", window=DEFAULT_WINDOW,
            forgetting=0.995, directions="all", keep_edges=True, kappa=0.0, noise=None,
            channel_axis=-1, return_result=False):
    """Restore a degraded image by the conditional mean of a local CAR model.

    SPEC section 4: ``E{X_r | past} = gamma_hat Z_r`` (14.44)-(14.45) from a
    3DCAR model of the observed image valid around ``r``, averaged over four
    causal neighbourhoods (the four directions), with the edge rule (14.40).

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The degraded image; integers are scaled to [0, 1].
    neighbourhood : int, (eta, 2) array or 'auto', optional
        Causal neighbourhood order (default 1: the pixels above and before)
        or offsets; 'auto' chooses the order by the decision rule (14.6) on
        the image. Order 2 gains 0.13 dB on the benchmark at a third more time.
    estimator : {'windowed', 'recursive'}, optional
        How the local model is estimated. 'windowed' (default): least
        squares over a ``window`` x ``window`` square around the pixel, as
        the chapter estimates local PSFs (14.46)-(14.47); the four
        neighbourhoods are the causal one mirrored up-left, up-right,
        down-left and down-right. 'recursive': the adaptive estimator of SPEC
        1.4 (recursive, square-root, with ``forgetting``) along the four scan
        directions down, up, right and left. Same quality on the benchmark
        (26.26 vs 26.21 dB at orders 1 and 2); 'windowed' is about six times
        faster, 'recursive' is the chapter's adaptive model to the letter.
    window : int, optional
        Side in pixels of the windowed estimator's square (3 x 3 blocks of a
        third of it; default 48). 24 gains 0.1 dB at a quarter more time.
    forgetting : float in (0, 1], optional
        Forgetting factor of the recursive estimator (SPEC 1.4).
    directions : 'all' or a sequence of names, optional
        The neighbourhoods whose predictions are combined: for 'windowed' any
        of {'up-left', 'up-right', 'down-left', 'down-right'}; for
        'recursive' any of {'down', 'up', 'right', 'left'}.
    keep_edges : bool, optional
        Apply the edge rule: keep the observed value where the local
        prediction error exceeds what the noise explains (see
        :class:`RestorationResult`). (14.40) read literally (keep ``X_r`` when
        its error exceeds the mean error of its neighbours) keeps about 40 %
        of the pixels of a flat noisy region, so no denoising; we compare with
        the noise level instead and blend smoothly.
    kappa : float in [0, 1), optional
        Also keep observed pixels whose prediction probability is at most
        ``kappa`` (14.50); 0 (default) disables this.
    noise : float or (C,) array, optional
        Noise standard deviation (image units after scaling); default
        :func:`estimate_noise`.
    channel_axis : int or None, optional
    return_result : bool, optional
        Return the :class:`RestorationResult` instead (prediction, prediction
        probability, edge weights; ``.restored(kappa)`` re-thresholds).

    Returns
    -------
    restored : ndarray of float64, the shape of ``image``.

    See Also
    --------
    iter_restore : the same, with progress, live results and the
        prediction-probability map.
    """
    gen = _iter_restore(image, neighbourhood=neighbourhood, estimator=estimator, window=window,
                        forgetting=forgetting, directions=directions, keep_edges=keep_edges,
                        kappa=kappa, noise=noise, channel_axis=channel_axis, live=False,
                        probability=return_result, blend=not return_result)
    result = drain(gen)
    if return_result:
        return result
    return _to_layout(result.restored(), np.ndim(image), channel_axis)


# --- several versions of one scene ---------------------------------------------


def multichannel_context(offsets, n_versions, reference, *, with_prediction=False):
    """The 2.5D context (SPEC 5): target = the reference version; regressors =
    causal neighbours in every version, then the other versions at ``r``;
    with ``with_prediction``, also channel ``n_versions`` at ``r`` (the
    reference's single-image prediction)."""
    offsets = np.asarray(offsets, np.int64)
    taps = [(di, dj, v) for v in range(n_versions) for di, dj in offsets]
    taps += [(0, 0, v) for v in range(n_versions) if v != reference]
    if with_prediction:
        taps.append((0, 0, n_versions))
    return Context(np.array(taps, np.int64), np.array([reference]))


def iter_restore_multichannel(stack, *, axis=0, kappa=DEFAULT_KAPPA, reference="auto",
                              neighbourhood=1, forgetting=0.9995, directions="all",
                              keep_edges=True, reference_prediction=True, channel_axis=None):
    """:func:`restore_multichannel` as a generator: yields
    :class:`RestorationState` (with the running restored reference), returns a
    :class:`RestorationResult` (``reference`` set)."""
    kappa = _check_kappa(kappa)
    forgetting, directions = _check_options(forgetting, directions)
    versions = _versions(stack, axis=axis, channel_axis=channel_axis)
    n = len(versions)
    shape = versions[0].shape
    if isinstance(reference, str):
        if reference != "auto":
            raise ValueError(f"reference must be 'auto' or a version index; got {reference!r}.")
        reference = int(np.argmax(sharpness(np.stack(versions), axis=0, channel_axis=-1)))
    else:
        if int(reference) != reference or not -n <= int(reference) < n:
            raise ValueError(f"reference must be 'auto' or an index in 0..{n - 1}; "
                             f"got {reference!r}.")
        reference = int(reference) % n
    observed = versions[reference]
    summary = summarize(observed)
    check_not_constant(observed, name=f"the reference version {reference}", summary=summary)
    offsets = _offsets(neighbourhood, observed)
    context = multichannel_context(offsets, n, reference, with_prediction=reference_prediction)
    yield RestorationState(f"reference version {reference}", 0.0)
    extra = []
    share = 0.0
    if reference_prediction:
        # SPEC 4's four-direction prediction of the reference: a summary of its
        # neighbourhood on every side whose regressors never include the pixel
        # (the window models do, as one pixel of about 2300).
        share = 0.3
        gen = iter_restore(observed, keep_edges=False, channel_axis=-1, live=False,
                           probability=False)
        while True:
            try:
                state = next(gen)
            except StopIteration as stop:
                extra = [stop.value.prediction]
                break
            yield RestorationState(f"reference prediction: {state.stage}",
                                   share * state.fraction)
    C = shape[2]
    pred = np.empty(shape)
    prob_sum = np.zeros(shape[:2])
    spread = np.zeros(shape)
    steps = C * len(directions)
    done = 0
    for c in range(C):  # colour versions: one 2.5D model per colour channel
        source = np.stack([v[..., c] for v in versions + extra], axis=-1)
        means = source.reshape(-1, source.shape[2]).mean(axis=0)
        source = np.ascontiguousarray(source - means)
        var = source.reshape(-1, source.shape[2]).var(axis=0)
        var = np.where(var > 0, var, 1.0)
        average = _Average(source[..., reference : reference + 1], means[[reference]])
        for _, result in _run_directions(source, context, var[[reference]],
                                         forgetting=forgetting, directions=directions,
                                         outputs=("mean", "logrel"), prior=1e-6):
            average.add(result["mean"], result["logrel"])
            done += 1
            pred[..., c] = average.prediction()[0][..., 0]
            running = pred.copy()
            running[..., c + 1 :] = observed[..., c + 1 :]
            yield RestorationState(f"channel {c + 1}/{C}, direction {done}/{steps}",
                                   share + (0.95 - share) * done / steps, running)
        _, prob_c = average.prediction()
        prob_sum += prob_c
        spread[..., c] = average.spread()[..., 0]
    noise = estimate_noise(observed)
    weight = (_edge_weight(observed, pred, spread.mean(axis=-1), noise)
              if keep_edges else None)
    return RestorationResult(observed, pred, prob_sum / C, weight, reference, kappa, noise)


def restore_multichannel(stack, *, axis=0, kappa=DEFAULT_KAPPA, reference="auto",
                         neighbourhood=1, forgetting=0.9995, directions="all", keep_edges=True,
                         reference_prediction=True, channel_axis=None, return_result=False):
    """Restore one scene from several registered degraded versions (SPEC 5).

    The reference version is modelled by the adaptive 2.5D CAR model whose
    regression vector holds the causal neighbours (``neighbourhood``) in all
    versions and the other versions' pixels at ``r`` (14.52); the one-step
    conditional means of the four scan directions are averaged, and a pixel
    takes its prediction where the prediction probability exceeds ``kappa``
    (14.50), else keeps its observed value.

    Parameters
    ----------
    stack : (n, H, W) or (n, H, W, C) array (versions along ``axis``)
        At least two registered versions of one shape (a telescope burst,
        repeated scans, frames of a static scene).
    axis : int, optional
        The axis holding the versions.
    kappa : float in [0, 1), optional
        Threshold on the prediction probability; default :data:`DEFAULT_KAPPA`.
    reference : 'auto' or int, optional
        The version restored; 'auto' takes the sharpest by :func:`sharpness`.
    neighbourhood : int or (eta, 2) array, optional
        Causal neighbourhood in every version (default order 1: 2 neighbours,
        so ``3n - 1`` regressors; colour channels get one model each).
    forgetting, directions : see :func:`restore`.
    keep_edges : bool, optional
        Also apply the single-image edge rule (default on: +1.2 dB measured).
    reference_prediction : bool, optional
        Add the reference's single-image prediction (:func:`restore`'s four
        directions, whose regressors never include ``X_r``) to the regression
        vector at ``r``: +0.5 dB measured on 5 scenes of 8 versions. Our
        extension of (14.52).
    channel_axis : int or None, optional
        Colour axis of a 4-D stack (default: the last when the stack is 4-D).
    return_result : bool, optional
        Return the :class:`RestorationResult` instead (``.reference``,
        ``.prediction``, ``.probability``; ``.restored(kappa)``).

    Returns
    -------
    restored : (H, W) or (H, W, C) float64 array
        The restored reference version.
    probability : (H, W) float64 array in [0, 1]
        The prediction-probability image (SPEC 1.6, see
        :class:`RestorationResult`).
    """
    result = drain(iter_restore_multichannel(
        stack, axis=axis, kappa=kappa, reference=reference, neighbourhood=neighbourhood,
        forgetting=forgetting, directions=directions, keep_edges=keep_edges,
        reference_prediction=reference_prediction, channel_axis=channel_axis))
    if return_result:
        return result
    restored = result.restored()
    return (restored[..., 0] if restored.shape[2] == 1 else restored), result.probability


# --- point-spread function ------------------------------------------------------


def estimate_psf(observed, restored, *, size=7, window=None, channel_axis=-1):
    """Least-squares point-spread function from a restored to an observed image.

    (14.46)-(14.47): ``psi = V_W^{-1} V_WX`` where ``W_r`` is the
    ``size x size`` neighbourhood of the restored image around ``r`` and
    ``X_r`` the observed pixel, summed over the image (or over each window).
    Colour channels share one PSF. Means are removed first, so a brightness
    offset does not bias it.

    Parameters
    ----------
    observed, restored : (H, W) or (H, W, C) arrays of one shape
    size : odd int, optional
        PSF support (pixels).
    window : int or None, optional
        None: one global PSF. An int: PSFs of non-overlapping
        ``window x window`` tiles (the local PSFs of a slowly varying blur).

    Returns
    -------
    psf : (size, size) array, or (H // window, W // window, size, size)
        ``observed ~ convolve(restored, psf)``.
    """
    obs = as_channel_last_float(observed, channel_axis=channel_axis, name="observed")
    res = as_channel_last_float(restored, channel_axis=channel_axis, name="restored")
    if obs.shape != res.shape:
        raise ValueError(f"observed {obs.shape} and restored {res.shape} must have one shape.")
    if int(size) != size or size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer; got {size}.")
    size = int(size)
    half = size // 2
    H, W, _ = obs.shape
    if window is None:
        tiles = [(slice(0, H), slice(0, W))]
        grid = None
    else:
        if int(window) != window or window < size + 2 * half:
            raise ValueError(f"window must be an integer of at least {size + 2 * half} "
                             f"(size + 2 * (size // 2)); got {window}.")
        window = int(window)
        grid = (H // window, W // window)
        if 0 in grid:
            raise ValueError(f"window {window} is larger than the image {obs.shape[:2]}.")
        tiles = [(slice(i * window, (i + 1) * window), slice(j * window, (j + 1) * window))
                 for i in range(grid[0]) for j in range(grid[1])]
    check_size(res, ((half, half), (half, half)), name="restored")
    psfs = []
    for rows, cols in tiles:
        o = obs[rows, cols] - obs[rows, cols].mean(axis=(0, 1))
        r = res[rows, cols] - res[rows, cols].mean(axis=(0, 1))
        h, w = o.shape[:2]
        # design matrix: one column per PSF tap, rows = interior pixels x channels
        cols_ = [r[half + di : h - half + di, half + dj : w - half + dj].ravel()
                 for di in range(-half, half + 1) for dj in range(-half, half + 1)]
        A = np.stack(cols_, axis=1)
        b = o[half : h - half, half : w - half].ravel()
        gram = A.T @ A
        if not np.isfinite(gram).all() or np.linalg.matrix_rank(gram) < gram.shape[0]:
            raise ValueError("the restored image is too flat to estimate a PSF of this size "
                             "(its neighbourhoods are linearly dependent); use a smaller size "
                             "or a more textured region.")
        psi = np.linalg.solve(gram, A.T @ b)
        # (14.46) fits X_r on W_r = restored[r + s]; convolution flips the taps
        psfs.append(psi.reshape(size, size)[::-1, ::-1])
    if grid is None:
        return psfs[0]
    return np.array(psfs).reshape(grid[0], grid[1], size, size)


def psf_width(psf):
    """Gaussian-equivalent standard deviation of a PSF (pixels): the root mean
    of its second moments about its centroid along rows and columns, negative
    taps clipped."""
    psf = np.clip(np.asarray(psf, float), 0, None)
    total = psf.sum()
    if total <= 0:
        raise ValueError("the PSF has no positive mass.")
    r, c = np.indices(psf.shape)
    mr, mc = (psf * r).sum() / total, (psf * c).sum() / total
    var = ((psf * (r - mr) ** 2).sum() + (psf * (c - mc) ** 2).sum()) / (2 * total)
    return float(np.sqrt(var))
