"""Directional predictions and their combination: the adaptive scans run two
at a time, their precision-weighted average, and the edge rule (14.40)."""

from __future__ import annotations

from functools import partial

import numpy as np

from .._progress import iter_chains, result_of, row_blocks
from .._threads import pool_threads
from .._validation import check_size
from ..model.adaptive import adaptive_scanner
from ..model.directions import scan_shape
from ._combine_kernels import accumulate_direction, combine_directions, edge_weight

# Windows (pixels) over which the edge rule, and the weighting of the scan
# directions, measure the local prediction error.
EDGE_WINDOW = 7
DIRECTION_WINDOW = 3
DIRECTION_POWER = 4
# Edge rule: directional predictions whose variance (3x3 mean) exceeds this
# many noise variances mark an edge (flat noise: 99.9 % of 3x3 means below 0.4).
EDGE_SPREAD = 0.7
# Values (pixels x channels) of one chunk of the row-wise kernels: ~10-40 ms.
CHUNK_VALUES = 1 << 20


def chunk_rows(width, per_pixel=1.0):
    """Rows of ``width`` pixels of ``per_pixel`` work each that make a chunk
    (of about ``CHUNK_VALUES`` units)."""
    return max(1, int(CHUNK_VALUES // max(1.0, width * per_pixel)))


def iter_calls(pool, calls):
    """:func:`~car_napari._progress.iter_chains` of independent ``calls``,
    dealt out to a chain per thread of ``pool``."""
    calls = list(calls)
    n_chains = pool_threads(pool)
    return iter_chains(pool, [calls[k::n_chains] for k in range(n_chains)])


def _scan_chain(directions, make):
    """The calls of the scans in ``directions``, one after the other: each
    call advances a scan by one chunk and returns (pixels scanned, None), the
    last of a scan (0, (direction, ScanResult))."""
    for direction in directions:
        scanner = make(direction)
        while not scanner.done:
            def advance(scanner=scanner):
                chunk = scanner.advance()
                return (chunk.stop - chunk.start) * (scanner.pixels // scanner.rows), None
            yield advance
        yield lambda scanner=scanner, direction=direction: (0, (direction, scanner.result()))


def iter_directions(source, context, targets_var, *, forgetting, directions, outputs, prior,
                    pool=None):
    """Adaptive scans in several directions, in chunks of rows
    (:func:`~car_napari.model.adaptive.adaptive_scanner`, each chunk one
    ``nogil`` kernel call of about 0.1-0.25 s), the directions side by side
    on ``pool``'s threads. Yields (pixels scanned, finished) after every
    chunk; ``finished`` lists the (direction, ScanResult) that are complete,
    in the order of ``directions``. Bit for bit the one-call scans."""
    for direction in directions:
        check_size(np.empty(scan_shape(source.shape, direction)), context.reach)

    def make(direction):
        scanner = adaptive_scanner(source, context, targets_var, forgetting=forgetting,
                                   direction=direction, prior=prior, outputs=outputs)
        scanner.pixels = source.shape[0] * source.shape[1]
        return scanner

    n_chains = max(1, min(len(directions), pool_threads(pool)))
    chains = [_scan_chain(directions[k::n_chains], make) for k in range(n_chains)]
    ready = {}
    order = list(directions)
    for pixels, done in iter_chains(pool, chains):
        if done is not None:
            ready[done[0]] = done
        finished = []
        while order and order[0] in ready:
            finished.append(ready.pop(order.pop(0)))
        yield pixels, finished


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

    def add(self, mean, logrel, pool=None):
        """Add one direction's (H, W, C) conditional mean and (H, W) log
        relative density (NaN where it does not predict)."""
        for _ in self.iter_add(mean, logrel, pool):
            pass

    def iter_add(self, mean, logrel, pool=None):
        """:meth:`add` in chunks of rows (on ``pool`` if given); yields the
        rows done after each chunk. Bit for bit :meth:`add`."""
        mean, logrel = np.ascontiguousarray(mean), np.ascontiguousarray(logrel)
        H, W, C = self.observed.shape

        def call(a, b):
            accumulate_direction(self.observed, mean, logrel, DIRECTION_WINDOW // 2,
                                 int(DIRECTION_POWER), self.mean_sum, self.prob_sum,
                                 self.weight_sum, self.plain_sum, self.square_sum, self.count,
                                 a, b)
            return b - a

        rows = chunk_rows(W, 4 * C)
        yield from iter_calls(pool, [partial(call, a, b) for a, b in row_blocks(H, rows)])

    def spread(self):
        """(H, W, C) variance of the directional predictions (0 with < 2)."""
        n = np.maximum(self.count, 1)[..., None]
        var = self.square_sum / n - (self.plain_sum / n) ** 2
        return np.where(self.count[..., None] > 1, np.maximum(var, 0.0), 0.0)

    def prediction(self):
        """(prediction + offset, probability) in image shape."""
        pred = np.empty(self.observed.shape)
        prob = np.empty(self.observed.shape[:2])
        for _ in self.iter_prediction(pred, prob):
            pass
        return pred, prob

    def iter_prediction(self, pred, prob):
        """:meth:`prediction` into ``pred`` (H, W, C) and ``prob`` (H, W) in
        chunks of rows (a 4000x4000 image is ~0.3 s in one call); yields the
        rows done after each chunk. Rows are independent: bit for bit one call."""
        H, W, C = self.observed.shape
        for a, b in row_blocks(H, chunk_rows(W, C)):
            combine_directions(self.mean_sum, self.prob_sum, self.weight_sum, self.observed,
                               self.offset, pred, prob, a, b)
            yield b - a


def edge_rule(observed, prediction, spread, noise, pool=None, blend=False, out=None,
              halves=False):
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
    (observed - prediction)`` instead (no weight array); with ``halves`` the
    rows run in two halves (side by side on ``pool`` when given); the result
    goes into ``out`` if given.
    """
    return result_of(iter_edge_rule(observed, prediction, spread, noise, pool, blend=blend,
                                    out=out, halves=halves))


def iter_edge_rule(observed, prediction, spread, noise, pool=None, blend=False, out=None,
                   halves=False):
    """:func:`edge_rule` in chunks of rows: yields the rows done after each
    chunk, returns what :func:`edge_rule` returns, bit for bit the one-call
    kernel (one segment of rows, or with ``halves`` two, each run in chunks
    that carry its running sums; the halves side by side on ``pool`` when
    given: the split does not depend on the pool)."""
    H, W, C = observed.shape
    out = np.empty(observed.shape) if out is None else out
    args = (observed, np.ascontiguousarray(prediction), np.ascontiguousarray(spread), noise**2,
            EDGE_WINDOW // 2, EDGE_SPREAD * float(np.mean(noise**2)), bool(blend), out)
    half = (H + 1) // 2
    segments = [(a, b) for a, b in ((0, half), (half, H)) if b > a] if halves else [(0, H)]
    rows = chunk_rows(W, 2 * C)

    def chain(r0, r1):
        cols, spread_cols = np.zeros((W, C)), np.zeros(W)
        steps = row_blocks(r1, rows, start=r0)
        steps[0] = (r0 - 2 * (EDGE_WINDOW // 2) - 1, steps[0][1])  # the sums fill first
        for a, b in steps:
            def call(a=a, b=b):
                edge_weight(*args, r0, r1, a, b, cols, spread_cols)
                return b - max(a, r0)
            yield call

    yield from iter_chains(pool, [chain(r0, r1) for r0, r1 in segments])
    return out
