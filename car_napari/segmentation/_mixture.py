"""Gaussian mixture with diagonal covariances ((14.34)-(14.35)), its EM fit and
Kullback-Leibler merging ((14.36)), section 14.4, docs/segmentation.md."""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from numba import njit

from .._progress import Progress, drain
from .._threads import job_pool

__all__ = ["Mixture"]


@dataclass
class Mixture:
    """Gaussian mixture with diagonal covariances, one state of a merge history.

    ``ids`` name the components stably across merges: a merged component
    keeps its stronger partner's id, so labels of one history agree.

    Parameters
    ----------
    weights : (K,) ndarray
        Component weights (they sum to 1).
    means : (K, D) ndarray
        Component means.
    variances : (K, D) ndarray
        Diagonal covariances.
    ids : (K,) ndarray of int
        Stable component ids, 1.. (the labels of the segmentation).
    loglik : float, optional
        Mean log-likelihood per sample of the data the mixture was fitted to.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import Mixture
    >>> mix = Mixture(np.array([0.5, 0.5]), np.zeros((2, 3)), np.ones((2, 3)),
    ...               np.array([1, 2]))
    >>> mix.k
    2
    """

    weights: np.ndarray
    means: np.ndarray
    variances: np.ndarray
    ids: np.ndarray
    loglik: float = np.nan

    def copy(self):
        """Return an independent copy (the arrays are copied).

        Returns
        -------
        Mixture
            A mixture equal to this one that shares no array with it.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.segmentation import Mixture
        >>> mix = Mixture(np.ones(1), np.zeros((1, 2)), np.ones((1, 2)), np.array([1]))
        >>> mix.copy().means is mix.means
        False
        """
        return Mixture(self.weights.copy(), self.means.copy(), self.variances.copy(),
                       self.ids.copy(), self.loglik)

    @property
    def k(self):
        """Number of components ``K`` (an int).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.segmentation import Mixture
        >>> Mixture(np.ones(1), np.zeros((1, 2)), np.ones((1, 2)), np.array([1])).k
        1
        """
        return self.weights.size


def _expectations(X, mix):
    """The E step on the rows of X: each component's posterior mass ``nk``
    (K,), posterior-weighted sums of x and x**2 (K, D) and the mean
    log-likelihood; one pass (:func:`_e_step`), no (N, K) array."""
    k, d = mix.means.shape
    means_t = np.ascontiguousarray(np.asarray(mix.means, np.float64).T)
    inv_t = np.ascontiguousarray(1.0 / np.asarray(mix.variances, np.float64).T)
    const = (-0.5 * (np.log(2 * np.pi * mix.variances).sum(axis=1))
             + np.log(mix.weights)).astype(np.float64)
    X = np.ascontiguousarray(X, dtype=np.float64)
    n = X.shape[0]
    # the halves depend on the rows only, so the sums (and the result) do
    # not depend on the threads that run them
    halves = [(0, n)] if n < _SPLIT_ROWS else [(0, n // 2), (n // 2, n)]
    parts = [(np.zeros(k), np.zeros((k, d)), np.zeros((k, d))) for _ in halves]

    def run(half, part):
        return _e_step(X[half[0]:half[1]], means_t, inv_t, const, *part)

    pool = job_pool() if len(halves) > 1 else None  # None: a job on one thread
    if pool is None:
        totals = [run(half, part) for half, part in zip(halves, parts, strict=True)]
    else:  # the two halves on two threads (the kernel releases the GIL), summed in order
        totals = list(pool.map(run, halves, parts))
    nk, sx, sx2 = (sum(arrays[1:], arrays[0]) for arrays in zip(*parts, strict=True))
    return nk, sx, sx2, sum(totals) / max(n, 1)


# an E step on more rows than this runs in two halves (on two threads where
# a job has them), whose sums are added
_SPLIT_ROWS = 1 << 14


# a posterior below exp(-37) (< 2**-53 of the best's) is taken as 0: it
# would not change the sum of the row's densities (>= 1, the best's) at all
_NEGLIGIBLE = -37.0


@njit(cache=True, nogil=True, inline="always")  # in the callers' loops, as if written there
def _log_joint(x, means_t, inv_t, const, acc):
    """``log w_j + log N(x | mu_j, diag var_j)`` of every component j into
    ``acc`` (K,), for one feature vector ``x`` (D,); returns the largest.
    ``means_t`` and ``inv_t`` are (D, K) and ``const`` (K,) holds ``log w_j``
    plus the normalisers: the loop over the components is the inner one
    (vectorised), each component's sum runs over the features in order."""
    d, k = means_t.shape
    acc[:] = 0.0
    for c in range(d):
        v = x[c]
        for j in range(k):
            t = v - means_t[c, j]
            acc[j] += t * t * inv_t[c, j]
    top = -np.inf
    for j in range(k):
        acc[j] = const[j] - 0.5 * acc[j]
        if acc[j] > top:
            top = acc[j]
    return top


@njit(cache=True, nogil=True)
def _e_step(X, means_t, inv_t, const, nk, sx, sx2):
    """Posteriors ``w_j N(x | mu_j, diag var_j)`` (normalised) of every row x
    of X, summed into ``nk`` (K,), ``sx`` and ``sx2`` (K, D) (times x and
    x**2); returns the sum of the rows' log-likelihoods. ``means_t`` and
    ``inv_t`` are (D, K): the component loop of the distances is the inner
    one (vectorised). Posteriors below ``exp(_NEGLIGIBLE)`` of the row's
    best are 0 (and skipped)."""
    n, d = X.shape
    k = means_t.shape[1]
    acc = np.empty(k)
    loglik = 0.0
    for i in range(n):
        top = _log_joint(X[i], means_t, inv_t, const, acc)
        total = 0.0
        for j in range(k):
            gap = acc[j] - top
            e = math.exp(gap) if gap > _NEGLIGIBLE else 0.0
            acc[j] = e
            total += e
        loglik += math.log(total) + top
        for j in range(k):
            if acc[j] > 0.0:
                p = acc[j] / total
                nk[j] += p
                for c in range(d):
                    v = X[i, c]
                    sx[j, c] += p * v
                    sx2[j, c] += p * (v * v)
    return loglik


def _em_steps(X, mix, steps, var_floor):
    """``steps`` EM iterations on the rows of X, in place; ``mix.loglik`` updated."""
    return drain(_iter_em(X, mix, steps, var_floor))


def _iter_em(X, mix, steps, var_floor, cache=None):
    """:func:`_em_steps` as a job: a :class:`~car_napari.Progress` record
    ("mixture", "EM") after each iteration (a job stops between them);
    returns the mixture.

    ``cache`` (a dict, optional) keeps the E step of the mixture returned: a
    next call on the same data and the same, unchanged mixture (its arrays
    are replaced at every step) starts from it instead of computing it
    again (the same numbers)."""
    known = (cache is not None and cache.get("X") is X
             and all(a is b for a, b in zip(cache["arrays"], _arrays(mix), strict=True)))
    for step in range(steps):
        nk, sx, sx2, loglik = cache["stats"] if known and step == 0 else \
            _expectations(X, mix)
        nk = nk + 1e-12
        mix.weights = nk / nk.sum()
        mix.means = sx / nk[:, None]
        mix.variances = np.maximum(sx2 / nk[:, None] - mix.means**2, var_floor)
        mix.loglik = loglik
        yield Progress("mixture", (step + 1) / (steps + 1), "EM")
    stats = _expectations(X, mix)
    mix.loglik = stats[3]
    if cache is not None:
        cache.update(X=X, arrays=_arrays(mix), stats=stats)
    return mix


def _arrays(mix):
    """What identifies a mixture's parameters: its arrays (EM replaces them,
    nothing changes them in place after an EM)."""
    return mix.weights, mix.means, mix.variances


def _block_init(features, n_init, var_floor):
    """Components from a regular division of the image into ~n_init blocks."""
    return drain(_iter_block_init(features, n_init, var_floor))


def _iter_block_init(features, n_init, var_floor):
    """:func:`_block_init` as a job: a :class:`~car_napari.Progress` record
    after each block; returns the mixture."""
    h, w, D = features.shape
    rows, cols = _block_grid(h, w, n_init)
    means, variances = [], []
    for bi in np.array_split(np.arange(h), rows):
        for bj in np.array_split(np.arange(w), cols):
            block = features[bi[0] : bi[-1] + 1, bj[0] : bj[-1] + 1].reshape(-1, D)
            means.append(block.mean(axis=0))
            variances.append(np.maximum(block.var(axis=0), var_floor))
            del block
            yield Progress("mixture", len(means) / (rows * cols), "initial division")
    k = len(means)
    return Mixture(np.full(k, 1.0 / k), np.array(means), np.array(variances), np.arange(1, k + 1))


def _block_grid(h, w, n_init):
    """Rows and columns of the regular division of an (h, w) image into
    about ``n_init`` blocks (more than h rows or w columns do not fit)."""
    rows = max(1, int(round(np.sqrt(n_init * h / w))))
    return rows, max(1, int(round(n_init / rows)))


def _drop_weak(mix, min_weight):
    """The mixture without components lighter than ``min_weight`` (unless all are)."""
    weak = mix.weights < min_weight
    if not weak.any() or weak.all():
        return mix
    keep = ~weak
    return Mixture(mix.weights[keep] / mix.weights[keep].sum(), mix.means[keep],
                   mix.variances[keep], mix.ids[keep])


def _kl_matrix(mix):
    """Symmetric KL divergence between every pair of diagonal Gaussians."""
    m, v = mix.means, mix.variances
    diff2 = (m[:, None, :] - m[None, :, :]) ** 2
    ratio = v[:, None, :] / v[None, :, :]
    kl = 0.5 * (ratio + diff2 / v[None, :, :] - 1.0 - np.log(ratio)).sum(axis=2)
    sym = kl + kl.T
    np.fill_diagonal(sym, np.inf)
    return sym


def _merge(mix, i, j):
    """Merge the weaker of (i, j) into the stronger by moment matching."""
    if mix.weights[i] < mix.weights[j]:
        i, j = j, i
    wi, wj = mix.weights[i], mix.weights[j]
    w = wi + wj
    mean = (wi * mix.means[i] + wj * mix.means[j]) / w
    var = (wi * (mix.variances[i] + mix.means[i] ** 2)
           + wj * (mix.variances[j] + mix.means[j] ** 2)) / w - mean**2
    mix.weights[i], mix.means[i], mix.variances[i] = w, mean, var
    keep = np.arange(mix.k) != j
    return Mixture(mix.weights[keep], mix.means[keep], mix.variances[keep], mix.ids[keep])


def _merge_closest(mix):
    """Merge the pair with the smallest symmetric KL divergence ((14.36));
    return the new mixture and that divergence."""
    kl = _kl_matrix(mix)
    i, j = np.unravel_index(np.argmin(kl), kl.shape)
    return _merge(mix, i, j), float(kl[i, j])


def _choose_k(history, threshold, relative=0.0):
    """Automatic number of segments, read off the merge history.

    Merging stops at the first merge (from ``K_ini`` down) that costs more
    than ``threshold`` nats of mean log-likelihood per pixel (the
    likelihood-gain stop of the KL merging, section 14.4,
    docs/segmentation.md) and more than ``relative`` times the costliest
    merge of the whole history; the state before that merge is kept. With
    a relative stop, when the costliest merges stand apart (each costs at
    least ``MERGE_APART`` times any other merge), only they stop it
    (:func:`_apart_limit`).

    Parameters
    ----------
    history : sequence of Mixture
        The merge states, ``K_ini`` components down to 1 (their ``loglik``).
    threshold : float
        The absolute stop, in nats per pixel.
    relative : float, optional
        The relative stop, a fraction of the costliest merge (0: none).

    Returns
    -------
    int
        The number of components ``k`` of the state kept.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.segmentation import Mixture
    >>> history = [Mixture(np.ones(k) / k, np.zeros((k, 1)), np.ones((k, 1)),
    ...                    np.arange(1, k + 1), loglik) for k, loglik in
    ...            [(4, -1.0), (3, -2.5), (2, -3.0), (1, -9.0)]]
    >>> _choose_k(history, 1.0), _choose_k(history, 1.0, relative=0.1)
    (4, 2)
    """
    return next((history[i].k for i in range(len(history) - 1)
                 if _stops(history, i, threshold, relative)), history[-1].k)


def _stops(history, i, threshold, relative=0.0):
    """The stop rule of the KL merging, in this one place: whether the merge
    from state ``i`` to state ``i + 1`` of ``history`` costs more than
    ``threshold`` nats of mean log-likelihood per pixel and more than
    ``relative`` times the costliest merge of ``history`` (the states known
    so far, for :func:`~car_napari.segmentation._segment._is_final`); with
    ``relative`` > 0, also more than :func:`_apart_limit` of those costs."""
    costs = np.array([prev.loglik - nxt.loglik for prev, nxt in pairwise(history)])
    limit = max(threshold, relative * costs.max())
    if relative > 0:
        limit = max(limit, _apart_limit(costs, limit))
    return costs[i] > limit


# the relative stop merges on through every merge but the costliest ones when
# these stand apart: each costs at least this many times any other merge. On
# mosaics of 2 or 3 textures the merges between textures are the last one or
# two and often cost several times any merge inside a texture, which the
# relative stop alone still took for a stop (over-split); on 5 textures the
# costliest merges are mostly close, but not always (the costliest was 3.13
# times the next on one of 90 TUNING mosaics). 3.25 changed none of the 90
# 5-texture TUNING mosaics (seeds 1-5; 2.5, chosen first on seeds 1-3,
# changed 4, 3.0 changed 1): exact K 34.1 -> 43.1 % on the 320 TUNING
# mosaics of benchmarks/bench_auto_k.py (2.5: 50.6 %; docs/segmentation.md)
MERGE_APART = 3.25


def _apart_limit(costs, limit):
    """The cost that only the merges standing apart exceed: with the costs
    sorted down, ``s[m]`` for the smallest ``m`` such that
    ``s[m - 1] >= MERGE_APART * s[m]`` and ``s[m - 1] > limit`` (the fewest
    costliest merges, each at least ``MERGE_APART`` times any other);
    ``limit`` when there is no such gap or ``s[m]`` is below it.

    Parameters
    ----------
    costs : (n,) ndarray
        The merge costs of a history, in nats per pixel (some may be <= 0).
    limit : float
        The stop without the gap (:func:`_stops`): only merges costlier
        than it may stand apart.

    Returns
    -------
    float
        The cost a merge must exceed to stop the merging (>= ``limit``).

    Examples
    --------
    >>> import numpy as np
    >>> float(_apart_limit(np.array([0.5, 2.0, 1.0, 10.0]), 1.5))  # 10 >= 3.25 * 2
    2.0
    >>> float(_apart_limit(np.array([0.5, 2.0, 1.0, 3.0]), 1.5))  # no gap of 3.25
    1.5
    """
    ranked = np.sort(np.asarray(costs, np.float64))[::-1]
    above, below = ranked[:-1], ranked[1:]
    gaps = np.flatnonzero((above > limit) & (above >= MERGE_APART * below))
    return max(limit, below[gaps[0]]) if gaps.size else limit
