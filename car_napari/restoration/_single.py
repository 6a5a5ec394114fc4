"""Single-image restoration by the conditional mean of local CAR models
(section 14.5, docs/restoration.md).

Every pixel is predicted from its causal neighbours by a CAR model valid
around it, for four mirrored neighbourhoods (up-left, up-right, down-left,
down-right); the four one-step conditional means are combined, each weighted
by how well it predicts the pixels next to this one (the causal model's
directional bias cancels: +0.5 dB PSNR over one neighbourhood, measured on
blurred, noisy images). The edge rule (14.40) then keeps observed values
where the prediction errs by more than the noise explains, or the four
disagree. The local model is by default the least-squares estimate over a
window (:mod:`._windowed`, fast); ``estimator='recursive'`` uses the adaptive
recursive estimator ((14.26)-(14.32), section 14.2.1, docs/model.md) along
four scan directions.
"""

from __future__ import annotations

import queue
from concurrent.futures import wait
from dataclasses import dataclass
from functools import partial

import numpy as np

from .._progress import Progress, mapped, row_blocks, spans, stage
from .._threads import job_pool, pool_threads, submit
from .._validation import (
    channel_last_shape,
    check_flag,
    check_not_constant,
    check_real,
)
from ..model.blocks import iter_channel_last_float
from ..model.directions import DIRECTIONS
from ..model.neighbourhood import Context
from ._checks import (
    check_kappa,
    check_noise,
    check_options,
    check_restorable,
    resolve_offsets,
)
from ._combine import (
    DIRECTION_POWER,
    DirectionalAverage,
    chunk_rows,
    iter_calls,
    iter_directions,
    iter_edge_rule,
)
from ._combine_kernels import blend_edges, combine_predictions
from ._noise import median_abs_laplacian, noise_channel_last, noise_from_medians
from ._windowed import (
    block_moments,
    predict_block_models,
    predict_scratch_rows,
    valid_box,
    window_models,
)

# Side (pixels) of the window whose least-squares CAR model predicts a pixel
# (estimator='windowed'): 3 x 3 blocks of a third of it.
DEFAULT_WINDOW = 48
STRIP_ROWS = 64  # at most this many rows restored at a time by one core (windowed)
# The windowed estimator's four models: the causal neighbourhood mirrored so
# that the neighbours lie up-left, up-right, down-left or down-right of the
# pixel (the raster scans started from each corner). The recursive scans'
# down/up/right/left would repeat one: at order 1 'down' and 'right' both
# use the pixels above and to the left.
CORNERS = ("up-left", "up-right", "down-left", "down-right")
# The stages' shares of the work (progress fractions), measured on 4000 x
# 4000 colour, order 1 (CPU seconds of one core): with the probability map
# (the widget, return_result) and without (restore).
WINDOWED_WORK = {"reading": 0.6, "centre": 0.5, "moments": 0.4, "models": 0.6, "rows": 3.0,
                 "noise": 0.4, "edges": 0.5}
WINDOWED_WORK_PLAIN = {"reading": 0.6, "centre": 0.3, "moments": 0.4, "models": 0.3,
                       "rows": 1.5, "noise": 0.4, "edges": 0.5}
RECURSIVE_WORK = {"reading": 0.6, "centre": 0.2, "directions": 30.0, "edges": 0.5}


@dataclass
class RestorationResult:
    """Everything a restoration computed; :meth:`restored` re-thresholds it.

    Arrays are channel-last ``(H, W, C)`` floats (``C = 1`` for grey),
    whatever the input's layout.

    Attributes
    ----------
    observed : (H, W, C) ndarray
        The image that is restored (for a stack: the reference version).
    prediction : (H, W, C) ndarray
        The one-step conditional mean, combined over the directions.
    probability : (H, W) ndarray or None
        The prediction probability in [0, 1]: the Student-t predictive
        density of the observed value ((14.23)-(14.25), docs/model.md)
        divided by its peak value, averaged over directions. 1 where the
        observation is the prediction, near 0 where the model cannot explain
        it (edges, outliers). None when it was not computed (the
        multichannel restoration's reference prediction).
    weight : (H, W, C) ndarray or None
        The edge rule's weight of the observation (1 keeps it, 0 takes the
        prediction); None when edges are not kept.
    reference : int or None
        The index of the reference version in a stack, else None.
    kappa : float
        The threshold :meth:`restored` uses by default.
    noise : (C,) ndarray
        The per-channel noise standard deviation used by the edge rule.

    Examples
    --------
    >>> from car_napari.restoration import restore
    >>> rng = np.random.default_rng(0)
    >>> ramp = np.add.outer(np.linspace(0, 1, 32), np.linspace(0, 1, 32)) / 2
    >>> result = restore(ramp + rng.normal(0, 0.05, ramp.shape), return_result=True)
    >>> result.prediction.shape, result.probability.shape
    ((32, 32, 1), (32, 32))
    >>> bool(result.changed(0.5).sum() < result.changed(0.0).sum())
    True
    """

    observed: np.ndarray
    prediction: np.ndarray
    probability: np.ndarray | None
    weight: np.ndarray | None
    reference: int | None
    kappa: float
    noise: np.ndarray

    def restored(self, kappa=None):
        """Return the restored image at threshold ``kappa``.

        Pixels whose prediction probability is at most ``kappa`` keep their
        observed value (14.50); the others take the prediction, blended with
        the observation by the edge rule's weight when edges are kept.

        Parameters
        ----------
        kappa : float in [0, 1), optional
            The threshold on the prediction probability; default the run's
            :attr:`kappa`. 0 replaces every pixel.

        Returns
        -------
        restored : (H, W, C) float64 ndarray
            The restored image, channel-last.

        Raises
        ------
        ValueError
            If ``kappa`` is outside [0, 1), or is positive while the
            probability was not computed.
        TypeError
            If ``kappa`` is not a number.

        Examples
        --------
        >>> from car_napari.restoration import restore
        >>> rng = np.random.default_rng(0)
        >>> noisy = rng.normal(0.5, 0.1, (32, 32))
        >>> result = restore(noisy, return_result=True)
        >>> result.restored(0.3).shape
        (32, 32, 1)
        """
        kappa = self.kappa if kappa is None else check_kappa(kappa)
        if kappa > 0 and self.probability is None:
            raise ValueError("this result has no prediction probability to threshold; "
                             "use kappa=0 or restore with return_result=True.")
        out = self.prediction
        if self.weight is not None:  # as restore() blends in the edge rule's kernel
            parts = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (
                self.observed, self.prediction, self.weight)))
            out = np.empty(parts[0].shape)
            blend_edges(*parts, out)
        if kappa > 0:
            out = np.where((self.probability > kappa)[..., None], out, self.observed)
        return out

    def changed(self, kappa=None):
        """Return the pixels whose restored value differs from the observed.

        Parameters
        ----------
        kappa : float in [0, 1), optional
            The threshold, as in :meth:`restored`.

        Returns
        -------
        changed : (H, W) bool ndarray
            True where any channel of :meth:`restored` differs from
            :attr:`observed`.

        Examples
        --------
        >>> from car_napari.restoration import restore
        >>> rng = np.random.default_rng(0)
        >>> result = restore(rng.normal(0.5, 0.1, (32, 32)), return_result=True)
        >>> result.changed().shape
        (32, 32)
        """
        return np.any(self.restored(kappa) != self.observed, axis=-1)


# --- helpers ------------------------------------------------------------------


def to_layout(out, image_ndim, channel_axis):
    """Channel-last ``out`` (H, W, C) in the layout of the input image."""
    if image_ndim == 2 or channel_axis is None:
        return out[..., 0]
    return np.moveaxis(out, -1, channel_axis)


def corner_displacements(offsets, corner):
    """Image displacements (di, dj) of the neighbours of the model ``corner``."""
    di, dj = np.asarray(offsets, np.int64).T
    si = -1 if corner.startswith("up") else 1
    sj = -1 if corner.endswith("left") else 1
    return si * di, sj * dj


def _iter_windowed(planes, mean, var, offsets, directions, window, pool, live, probability,
                   show, span, pred):
    """The windowed estimator's predictions (see :mod:`._windowed`) on the
    centred channel-first ``planes``: yields Progress as block rows of the
    statistics and models and strips of rows finish (with ``live``, previews
    ``show(running prediction)``), the fractions in ``span(stage)``; returns
    (prediction (H, W, C) plus ``mean``, written into ``pred``, probability
    or None when not asked for, spread over channels)."""
    C, H, W = planes.shape
    # the statistics of every corner come from one pass, over the pixels whose
    # neighbours in all four corners lie inside (whichever corners are used)
    displacements = {d: corner_displacements(offsets, d) for d in CORNERS}
    positions = sorted({(int(a), int(b)) for di, dj in displacements.values()
                        for a, b in zip(di, dj, strict=True)}) + [(0, 0)]
    index = {pos: k for k, pos in enumerate(positions)}
    disp_i, disp_j = (np.array(v, np.int64) for v in zip(*positions, strict=True))
    block = max(2, -(-int(window) // 3))
    nbi, nbj = -(-H // block), -(-W // block)
    A = len(positions) * C + 1
    moments = np.zeros((nbi, nbj, A, A))
    # block rows are independent: chunks of them, two at a time, a record each
    share = span("moments")
    ranges = row_blocks(nbi, chunk_rows(nbj * block * block, A * (A + 1) / 8))
    for k, _ in enumerate(iter_calls(pool, [
            partial(block_moments, planes, disp_i, disp_j, block, moments, a, b)
            for a, b in ranges]), start=1):
        yield Progress("moments", share.at(k, len(ranges)),
                       f"statistics {k}/{len(ranges)}")

    taps = []
    for direction in directions:
        di, dj = displacements[direction]
        tap_i, tap_j, tap_c = np.repeat(di, C), np.repeat(dj, C), np.tile(np.arange(C), len(di))
        taps.append((tap_i, tap_j, tap_c))
    ix = np.array([[index[(a, b)] * C + c for a, b, c in zip(*tap, strict=True)] + [A - 1]
                   for tap in taps])
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
    share = span("models")
    # work of one block's models: the window's sums, then per direction a
    # Cholesky factor and solves (and the inverses for the density)
    per_block = 9 * A * A + K * (p * p * (p + C) + (p * p * p if probability else 0))
    ranges = row_blocks(nbi, chunk_rows(nbj, per_block / 16))
    for k, _ in enumerate(iter_calls(pool, [
            partial(window_models, moments, ix, iy, prior_x, np.full(C, 1e-6 * var),
                    bool(probability), gamma, x_inv, lam_inv, exponent, a, b)
            for a, b in ranges]), start=1):
        yield Progress("models", share.at(k, len(ranges)),
                       f"{min(nbi, ranges[k - 1][1]) * nbj}/{nbi * nbj} local models")
    boxes = np.array([valid_box(H, W, tap[0], tap[1]) for tap in taps], np.int64)

    # Strips of rows, one a thread of the pool at a time, each with its own buffers:
    # the image fills in row by row, and the per-direction arrays stay small.
    # live: rows not yet restored show the observation (pred holds it)
    spread = np.zeros((H, W))
    density = np.empty((H, W)) if probability else None  # every strip writes its rows
    block_of_column = np.arange(W) // block
    height = int(np.clip(H // 8, 8, STRIP_ROWS))  # small images: still a few strips
    strips = row_blocks(H, height)
    buffers = queue.SimpleQueue()
    for _ in range(pool_threads(pool)):
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
                # each pixel's block exponent (the blocks' values spread out)
                exponent_px = exponent[np.arange(r0, r1) // block][:, block_of_column]
                relative = np.exp(-exponent_px * np.log1p(ratio[:, rows]))
                weights = weight[:, rows]
                density[r0:r1] = np.where(weights.sum(axis=0) > 0,
                                          np.sum(weights * relative, axis=0), 1.0)
        finally:
            buffers.put((means, err2, ratio, weight, scratch))

    if pool is None:  # one strip after the other, here, drawn as the loop asks
        futures = (submit(None, run, *strip) for strip in strips)
    else:
        futures = [pool.submit(run, *strip) for strip in strips]
    every = max(1, len(strips) // 8)  # a live image costs a copy: about 8 of them
    share = span("rows")
    try:
        for done, future in enumerate(futures, start=1):
            future.result()
            fraction = share.at(done, len(strips))
            message = f"rows {strips[done - 1][1]}/{H}"
            running = None
            if live and done < len(strips) and done % every == 0:
                # the copy in strips, a record between them (fresh memory of a
                # large image is slow to touch)
                running = np.empty_like(pred)
                for a, b in row_blocks(H, chunk_rows(W, 4 * C)):
                    np.copyto(running[a:b], pred[a:b])  # NumPy releases the GIL
                    yield Progress("rows", fraction, message)
                running = show(running)
            yield Progress("rows", fraction, message, running)
    finally:  # closing the generator early: do not start what is queued
        if pool is not None:
            for future in futures:
                future.cancel()
            wait(futures)  # the running strips write into pred
    return pred, density, spread


def _iter_recursive(centred, mean, context, var, forgetting, directions, live, show, pool,
                    span):
    """The adaptive (recursive) estimator's predictions, as _iter_windowed but
    on channel-last centred data (H, W, C): the scans run in chunks of rows,
    two directions at a time on ``pool``; the prediction returned is centred
    too (``mean`` only shifts the previews)."""
    average = DirectionalAverage(centred, np.zeros(centred.shape[2]))
    n = len(directions)
    H, W = centred.shape[:2]
    total = n * H * W
    share = span("directions")
    done = k = 0
    for pixels, finished in iter_directions(
            centred, context, var, forgetting=forgetting, directions=directions,
            outputs=("mean", "logrel"), prior=1e-6, pool=pool):
        done += pixels
        fraction = share.at(done, total)
        yield Progress("directions", fraction, f"scans {100 * done // total} %")
        for _, result in finished:
            k += 1
            for _ in average.iter_add(result["mean"], result["logrel"]):  # beside the scans
                yield Progress("directions", fraction, f"direction {k}/{n}: combining")
            running = None
            if live and k < n:
                running = average.prediction()[0]
                running += mean
                running = show(running)
            yield Progress("directions", fraction, f"direction {k}/{n}", running)
    pred, prob = average.prediction()
    return pred, prob, average.spread().mean(axis=-1)


def _median(c, plane):
    """(c, :func:`median_abs_laplacian` of ``plane``)."""
    return c, median_abs_laplacian(plane)


def iter_restoration(image, *, neighbourhood, estimator, window, forgetting, directions,
                     keep_edges, kappa, noise, channel_axis, live, probability, blend):
    """The restoration job behind :func:`iter_restore`, returning a
    :class:`RestorationResult`. ``live``: previews of the running prediction
    in the input's layout. Without ``probability`` (windowed estimator only,
    ``kappa`` 0) the prediction-probability map is not computed (about a
    third of the time). With ``blend`` the result's prediction is already
    the restored image (the edge rule applied, no weight array: what
    :func:`restore` needs and no more)."""
    kappa = check_kappa(kappa)
    if estimator not in ("windowed", "recursive"):
        raise ValueError(f"estimator must be 'windowed' or 'recursive'; got {estimator!r}.")
    forgetting, directions = check_options(
        forgetting, directions, CORNERS if estimator == "windowed" else DIRECTIONS)
    window = check_real(window, "window", low=6, integer=True)  # pixels, at least 6
    check_flag(keep_edges, "keep_edges")
    probability = bool(probability) or kappa > 0 or estimator == "recursive"
    H, W, C = channel_last_shape(image, channel_axis=channel_axis)
    # given offsets: the size is checked before the image is read ('auto': after)
    given = None if isinstance(neighbourhood, str) else resolve_offsets(neighbourhood, None)
    if given is not None:
        check_restorable((H, W, C), given, estimator, directions)
    if window > max(H, W, DEFAULT_WINDOW):  # its buffers grow with it
        raise ValueError(f"window {window} is larger than the image {(H, W)}: use at most "
                         f"{max(H, W, DEFAULT_WINDOW)}.")
    if noise is not None:
        noise = check_noise(noise, C)
    if estimator == "windowed":
        work = dict(WINDOWED_WORK if probability else WINDOWED_WORK_PLAIN)
    else:
        work = dict(RECURSIVE_WORK)
    if not keep_edges:
        work.pop("edges")
    span = spans(work)
    ndim = np.ndim(image)

    def show(running):  # a preview in the input's layout
        return to_layout(running, ndim, channel_axis)

    yield Progress("start", 0.0, f"{H} x {W} image")
    # blend: nothing keeps the image, so a float64 input need not be copied
    data, summary = yield from stage(
        iter_channel_last_float(image, channel_axis=channel_axis, stage="reading",
                                copy=not blend),
        *span("reading"))
    check_not_constant(data, summary=summary)
    if given is None:
        offsets = resolve_offsets(neighbourhood, data)
        check_restorable((H, W, C), offsets, estimator, directions)
    else:
        offsets = given
    context = Context.spatial(offsets, data.shape[2])
    share = span("centre")
    rows = row_blocks(H, chunk_rows(W, 2 * C))
    pool = job_pool()  # None: one thread (CAR_NAPARI_JOB_THREADS=1)
    if estimator == "windowed":
        # channel-first: every kernel runs along contiguous rows
        planes = np.empty(np.roll(data.shape, 1))
        source = np.moveaxis(data, -1, 0)
        # live: rows not yet restored show the observation
        pred = np.empty((H, W, C))

        def centre(a, b):  # NumPy releases the GIL
            np.subtract(source[:, a:b], summary.mean[:, None, None], out=planes[:, a:b])
            if live:
                np.add(np.moveaxis(planes[:, a:b], 0, -1), summary.mean, out=pred[a:b])

        for k, _ in enumerate(iter_calls(pool, [partial(centre, a, b) for a, b in rows]),
                              start=1):
            yield Progress("centre", share.at(k, len(rows)), "centring")
        pred, prob, spread = yield from _iter_windowed(
            planes, summary.mean, summary.var, offsets, directions, window, pool,
            live, probability, show, span, pred)
        if noise is None:  # one channel per call, side by side
            share = span("noise")
            medians = {}
            for k, (c, value) in enumerate(iter_calls(pool, [
                    partial(_median, c, plane) for c, plane in enumerate(planes)]),
                    start=1):
                medians[c] = value
                yield Progress("noise", share.at(k, C), f"channel {k}/{C}")
            noise = noise_from_medians([medians[c] for c in range(C)])
        weight = None
        if keep_edges and blend:  # the restored image straight away, no weight array,
            # written over the planes, which are no longer needed (fresh memory is
            # slow to touch: page faults cost as much as a kernel here)
            pred = yield from _iter_edges(data, pred, spread, noise, pool, span, blend=True,
                                          out=planes.reshape(data.shape), halves=True)
        elif keep_edges:
            weight = yield from _iter_edges(data, pred, spread, noise, pool, span, halves=True)
    else:
        centred = np.empty(data.shape)

        def centre(a, b):
            np.subtract(data[a:b], summary.mean, out=centred[a:b])

        for k, _ in enumerate(iter_calls(pool, [partial(centre, a, b) for a, b in rows]),
                              start=1):
            yield Progress("centre", share.at(k, len(rows)), "centring")
        noise_future = submit(pool, noise_channel_last, data) if noise is None else None
        pred, prob, spread = yield from _iter_recursive(
            centred, summary.mean, context, summary.var, forgetting, directions, live, show,
            pool, span)
        if noise_future is not None:
            noise = noise_future.result()
        pred += summary.mean
        weight = None
        # one segment of rows, in chunks here (bit for bit the one-call rule)
        if keep_edges and blend:
            pred = yield from _iter_edges(data, pred, spread, noise, None, span, blend=True)
        elif keep_edges:
            weight = yield from _iter_edges(data, pred, spread, noise, None, span)
    return RestorationResult(data, pred, prob, weight, None, kappa, noise)


def _iter_edges(observed, prediction, spread, noise, pool, span, blend=False, out=None,
                halves=False):
    """The edge rule in chunks of rows (``halves``: see
    :func:`~car_napari.restoration._combine.iter_edge_rule`), a Progress
    record after each."""
    share = span("edges")
    H = observed.shape[0]
    job = iter_edge_rule(observed, prediction, spread, noise, pool, blend=blend, out=out,
                         halves=halves)
    done = 0

    def record(rows):
        nonlocal done
        done += rows
        return Progress("edges", share.at(done, H), f"edge rule: rows {done}/{H}")

    return (yield from mapped(job, record))
