"""Directional predictions and their combination: the adaptive scans run two
at a time, their precision-weighted average, and the edge rule (14.40)."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .._validation import check_size
from ..model.directions import scan_shape
from ..model.recursive import adaptive_scan
from ._kernels import accumulate_direction, combine_directions
from ._windowed import edge_weight

# Windows (pixels) over which the edge rule, and the weighting of the scan
# directions, measure the local prediction error.
EDGE_WINDOW = 7
DIRECTION_WINDOW = 3
DIRECTION_POWER = 4
# Edge rule: directional predictions whose variance (3x3 mean) exceeds this
# many noise variances mark an edge (flat noise: 99.9 % of 3x3 means below 0.4).
EDGE_SPREAD = 0.7


def in_halves(pool, kernel, n, *args):
    """Run ``kernel(*args, start, stop)`` over [0, n) in two halves on ``pool``."""
    half = (n + 1) // 2
    futures = [pool.submit(kernel, *args, a, b) for a, b in ((0, half), (half, n)) if b > a]
    for future in futures:
        future.result()


def run_directions(source, context, targets_var, *, forgetting, directions, outputs, prior):
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


class DirectionalAverage:
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
        """Add one direction's (H, W, C) conditional mean and (H, W) log
        relative density (NaN where it does not predict)."""
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


def edge_rule(observed, prediction, spread, noise, pool=None, blend=False, out=None):
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
        in_halves(pool, edge_weight, observed.shape[0], *args)
    return out
