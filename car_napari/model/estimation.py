"""Whole-image Bayesian estimation and support selection.

The statistics and estimates ((14.7)-(14.14), (14.21), docs/model.md), the
decision rule (14.6) that chooses the support (docs/model.md) and the 2DCAR
path of the model ((14.1)-(14.4), docs/model.md). The fitted model and its
Student-t prediction are :mod:`.fitted`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import Progress, drain, row_blocks, stage
from .._validation import (
    check_not_constant,
    check_size,
)
from ._doc_sections import EXAMPLES_RECORDS
from .blocks import iter_centre, iter_channel_last_float
from .directions import check_direction, scan_view
from .fitted import CARModel
from .neighbourhood import Context, as_offsets
from .statistics import estimate_parameters, iter_data_statistics

__all__ = ["SupportSelection", "fit_car", "iter_fit_car", "iter_select_support",
           "select_support"]

_PRIOR = 1e-9  # V_0 = _PRIOR * (per-pixel variance) * I: almost uninformative


def _decision_score(chol, beta, beta0, m, d):
    """D_j of (14.6) with log-determinants from the augmented Cholesky factor."""
    diag = np.log(np.diag(chol))
    log_det_vx = 2.0 * np.sum(diag[:m])
    log_det_lam = 2.0 * np.sum(diag[m:])
    eta = m // d
    lgammas = sum(
        math.lgamma(0.5 * (beta - m + d + 2 - i)) - math.lgamma(0.5 * (beta0 - m + d + 2 - i))
        for i in range(1, d + 1)
    )
    return float(
        -0.5 * d * log_det_vx
        - 0.5 * (beta - m + d + 1) * log_det_lam
        + 0.5 * d * d * eta * math.log(math.pi)
        + lgammas
    )


def _iter_prepare(image, channel_axis, name="image"):
    """Validated float copy, centred, by blocks of rows: Progress records
    (stage "prepare"), then (data, mean, per-channel variance)."""
    data, summary = yield from stage(
        iter_channel_last_float(image, channel_axis=channel_axis, name=name), 0.0, 0.75)
    check_not_constant(data, name=name, summary=summary)
    yield from stage(iter_centre(data, summary.mean), 0.75, 1.0)
    return data, summary.mean, summary.var


# Work per pixel of the parts of a fit, for progress fractions (about ns on one
# core, 4000x4000 RGB): the float copy, summary and centring ~60 per channel,
# the whitening ~80 per channel, a pass of statistics ~2 (columns)^2.
def _prepare_cost(d):
    return 60.0 * d


def _whiten_cost(d):
    return 80.0 * d


def _statistics_cost(n_columns):
    return 2.0 * n_columns**2


def _channels(image, channel_axis):
    """The channels an image will have (for progress shares only; 1 if unclear)."""
    shape = np.shape(image)
    if len(shape) == 3 and channel_axis is not None:
        try:
            return int(shape[channel_axis])
        except (IndexError, TypeError):
            return 1
    return 1


_MAX_CANDIDATES = 256  # more candidate supports than there are orders and then some


def _candidate_offsets(orders):
    if isinstance(orders, (str, bytes)) or not hasattr(orders, "__iter__"):
        raise TypeError(f"orders must be an iterable of orders (ints) or (eta, 2) offset "
                        f"arrays, e.g. range(1, 6); got {orders!r}.")
    cands = []
    for item in orders:
        if len(cands) == _MAX_CANDIDATES:  # an endless iterable would never end the loop
            raise ValueError(f"orders has more than {_MAX_CANDIDATES} candidates; pass fewer.")
        try:
            offsets, order = as_offsets(item)
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"orders: candidate {item!r}: {exc}") from None
        key = order if order is not None else tuple(map(tuple, offsets.tolist()))
        cands.append((key, offsets))
    if not cands:
        raise ValueError("orders is empty: pass at least one candidate neighbourhood.")
    return cands


class SupportSelection(NamedTuple):
    """What :func:`select_support` returns (unpacks as ``best, scores``).

    Parameters
    ----------
    best : int or tuple
        The winning candidate: its order, or its offsets as a tuple of
        ``(di, dj)`` pairs for a custom candidate.
    scores : dict
        ``D_j`` of every candidate, keyed like ``best``; larger is more
        probable.

    Examples
    --------
    >>> best, scores = SupportSelection(2, {1: -5.0, 2: -3.0})
    >>> best
    2
    """

    best: int | tuple
    scores: dict


def _candidate_label(key, k, n):
    return f"order {key}" if isinstance(key, int) else f"candidate {k}/{n}"


def _offset_union(neighbourhoods):
    """The offsets of several (eta, 2) neighbourhoods, each once, in the
    order first met: an (n, 2) int64 array."""
    union = []
    for offsets in neighbourhoods:
        for s in map(tuple, offsets.tolist()):
            if s not in union:
                union.append(s)
    return np.array(union, dtype=np.int64)


def _iter_scores(centred, candidates, direction):
    """Score every candidate on the same pixels (the first condition of the
    decision rule (14.6), docs/model.md): Progress records, then the scores."""
    d = centred.shape[2]
    union = _offset_union(offs for _, offs in candidates)
    ctx = Context.spatial(union, d)
    view_shape = scan_view(centred, direction).shape
    check_size(np.empty(view_shape[:2]), ctx.reach, minimum_pixels=4 * ctx.n_regressors + 4)
    # Whiten the channels: the scores then do not change under any invertible
    # colour transform Y -> B Y (in particular, under the image's value range).
    # The one pass over the pixels is the work; the candidates' scores are small
    # factorisations of its sub-blocks.
    white_cost = _whiten_cost(d)
    split = 0.9 * white_cost / (white_cost + _statistics_cost(ctx.n_regressors + d))
    white = yield from stage(_iter_whiten(centred), 0.0, split, name="support")
    V, count = yield from stage(
        iter_data_statistics(white, ctx, direction=direction), split, 0.9, name="support")
    del white
    mu = ctx.n_regressors
    index = {s: k for k, s in enumerate(map(tuple, union.tolist()))}
    scores = {}
    for k, (key, offs) in enumerate(candidates, start=1):
        cols = np.array([index[s] * d + c for s in map(tuple, offs.tolist()) for c in range(d)])
        sel = np.r_[cols, mu + np.arange(d)]
        m = cols.size
        sub = V[np.ix_(sel, sel)]
        _, _, _, beta, L = estimate_parameters(sub, count, m, np.full(m + d, _PRIOR))
        scores[key] = _decision_score(L, beta, float(m - 1), m, d)
        yield Progress("support", 0.9 + 0.1 * k / len(candidates),
                       f"{_candidate_label(key, k, len(candidates))}: D = {scores[key]:.6g}")
    return scores


def _scores_cost(candidates, d):
    """Work per pixel of choosing the support: the whitening and one pass of
    statistics over the union of the candidates."""
    union = {s for _, offs in candidates for s in map(tuple, offs.tolist())}
    return _whiten_cost(d) + _statistics_cost(len(union) * d + d)


def _support_share(candidates, d):
    """The part of a fit with ``neighbourhood='auto'`` spent choosing the
    support: the whitening and one pass over the union of the candidates
    against one over the winner (taken as the largest candidate)."""
    choose = _scores_cost(candidates, d)
    fit = _statistics_cost(max(len(offs) for _, offs in candidates) * d + d)
    return choose / (choose + fit)


# rows of (N, d) per block of the whitening: a multiple of the BLAS kernels'
# tiles and never a short tail, so each block computes what one call would
_WHITEN_ROWS = 1 << 18


def _iter_whiten(centred):
    """The channels whitened (unit covariance), by blocks of pixels:
    Progress records, then the whitened copy."""
    d = centred.shape[2]
    flat = centred.reshape(-1, d)
    # np.dot, not @: the same BLAS product (bit for bit), but NumPy's matmul
    # holds the GIL through it (0.1-0.2 s on 16 MP: the viewer froze), dot lets it go
    cov = np.dot(flat.T, flat) / flat.shape[0]
    cov += 1e-12 * np.trace(cov) / d * np.eye(d)
    L = np.linalg.cholesky(cov)
    out = np.empty_like(centred)
    out_flat = out.reshape(-1, d)
    blocks = row_blocks(flat.shape[0], _WHITEN_ROWS, merge_tail=True)
    for k, (start, stop) in enumerate(blocks, start=1):
        out_flat[start:stop] = np.linalg.solve(L, flat[start:stop].T).T
        yield Progress("whitening", k / len(blocks), f"whitening: {k}/{len(blocks)}")
    return out


# the Parameters of select_support and iter_select_support, written once
_SELECT_SUPPORT_PARAMETERS = """
    image : (H, W) or (H, W, C) array_like
        Grey or multichannel image; any numeric dtype (integers are scaled
        to [0, 1]).
    orders : iterable of int or (eta, 2) arrays, optional
        Candidate neighbourhoods: orders (see :func:`causal_neighbourhood`)
        or explicit causal offsets.
    channel_axis : int or None, optional
        The channel axis of a 3-D image; a 2-D image is grey.
    direction : {'down', 'up', 'right', 'left'}, optional
        The scan direction the offsets are relative to.
"""


@shared_sections(parameters=_SELECT_SUPPORT_PARAMETERS,
                 raises=raises_as("select_support", "ValueError", "TypeError"))
@shared_sections(examples_records=EXAMPLES_RECORDS)
def iter_select_support(image, orders=range(1, 6), *, channel_axis=-1, direction="down"):
    """Choose the most probable causal neighbourhood, as a job.

    The generator form of :func:`select_support`, with the same parameters
    and result.

    {parameters}

    Returns
    -------
    SupportSelection
        What :func:`select_support` returns: ``(best, scores)``.

    Yields
    ------
    Progress
        Stage ``"support"``: after each block of rows of the float copy and
        centring of a large image (message ``"image: rows 512/4000"``) and
        of the whitening, after each block of rows of the one pass over the
        pixels (message ``"rows 120/512"``), then after each candidate's
        score (message ``"order 3: D = ..."``). No block is more than about
        0.2 s of work on a 4000x4000 RGB image.

    {raises}

    {examples_records}
    >>> best, scores = drain(iter_select_support(image, orders=[1, 2]), records.append)
    >>> [r.message.split(":")[0] for r in records[-2:]]
    ['order 1', 'order 2']
    """
    check_direction(direction)
    candidates = _candidate_offsets(orders)
    d = _channels(image, channel_axis)
    prep = _prepare_cost(d)
    split = prep / (prep + _scores_cost(candidates, d))
    centred, _, _ = yield from stage(_iter_prepare(image, channel_axis), 0.0, split,
                                       name="support")
    scores = yield from stage(_iter_scores(centred, candidates, direction), split, 1.0)
    best = max(scores, key=scores.get)
    return SupportSelection(best, scores)


@shared_parameters(_SELECT_SUPPORT_PARAMETERS)
def select_support(image, orders=range(1, 6), *, channel_axis=-1, direction="down"):
    """Choose the most probable causal neighbourhood by the decision rule (14.6).

    The rule is (14.6), docs/model.md. Every candidate is scored on the
    same pixels (those whose neighbourhood under the union of all candidates
    lies inside the image) with ``beta(0) = d*eta - 1``: the two conditions
    the rule needs. The channels are whitened first (unit covariance), so
    the scores do not change under any invertible colour transform, the
    value range included.

    {parameters}

    Returns
    -------
    SupportSelection
        ``(best, scores)``: the winning order (or offsets as a tuple of pairs
        for custom candidates) and ``D_j`` of every candidate (larger is more
        probable).

    Raises
    ------
    ValueError
        If the image is empty, constant, not 2-D or 3-D, holds NaN or
        infinite values, or is too small for the largest candidate; if
        ``orders`` is empty or holds an invalid neighbourhood; if
        ``direction`` is unknown.
    TypeError
        If the image is None or not numeric.

    See Also
    --------
    iter_select_support : The same as a job, with progress.
    fit_car : With ``neighbourhood='auto'``, fits the winner.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((32, 32))
    >>> best, scores = select_support(image, orders=[1, 2, 3])
    >>> sorted(scores), best in scores
    ([1, 2, 3], True)
    """
    return drain(iter_select_support(image, orders, channel_axis=channel_axis,
                                     direction=direction))


# the Parameters of fit_car and iter_fit_car, written once
_FIT_CAR_PARAMETERS = """
    image : (H, W) or (H, W, C) array_like
        Grey or multichannel image; any numeric dtype (integers are scaled
        to [0, 1]).
    neighbourhood : int, (eta, 2) array_like or 'auto', optional
        Order, explicit causal offsets, or 'auto' to choose among ``orders`` by
        the decision rule (14.6) (see :func:`select_support`).
    model : {'3d', '2d'}, optional
        '3d': one 3DCAR model with full ``d x d`` matrices. '2d': decorrelate
        the channels by a spectral PCA and fit a 2DCAR model to each factor
        (each with its own support when ``neighbourhood='auto'``).
    orders : iterable, optional
        Candidates for ``neighbourhood='auto'``.
    direction : {'down', 'up', 'right', 'left'}, optional
        The scan direction the offsets are relative to.
    channel_axis : int or None, optional
        The channel axis of a 3-D image; a 2-D image is grey.
"""


@shared_sections(parameters=_FIT_CAR_PARAMETERS,
                 raises=raises_as("fit_car", "ValueError", "TypeError"))
@shared_sections(examples_records=EXAMPLES_RECORDS)
def iter_fit_car(
    image,
    neighbourhood=2,
    *,
    model="3d",
    orders=range(1, 6),
    direction="down",
    channel_axis=-1,
):
    """Fit a CAR model to a whole image, as a job: Progress records, then the model.

    The generator form of :func:`fit_car`, with the same parameters and
    result.

    {parameters}

    Returns
    -------
    CARModel
        What :func:`fit_car` returns.

    Yields
    ------
    Progress
        First the float copy and centring of a large image, by blocks of
        rows (message ``"image: rows 512/4000"``), in the name of the first
        stage; with ``neighbourhood='auto'``, stage ``"support"`` (the pass
        over the pixels, then one record per candidate order, message
        ``"order 3: D = ..."``); then stage ``"statistics"`` after each block
        of rows of the fit (message ``"rows 120/512"``). The ``'2d'`` model
        decorrelates the channels by blocks (stage ``"decorrelating"``) and
        runs these once per spectral factor. No block is more than about
        0.2 s of work on a 4000x4000 RGB image; the fractions follow the
        estimated work.

    {raises}

    {examples_records}
    >>> model = drain(iter_fit_car(image, "auto", orders=[1, 2]), records.append)
    >>> sorted({r.stage for r in records}), records[-1].fraction
    (['statistics', 'support'], 1.0)
    """
    if model not in ("3d", "2d"):
        raise ValueError(f"model must be '3d' or '2d'; got {model!r}.")
    check_direction(direction)
    d = _channels(image, channel_axis)
    auto = isinstance(neighbourhood, str)
    split = _prepare_share(d, neighbourhood, orders, model)
    centred, mean, var = yield from stage(_iter_prepare(image, channel_axis), 0.0, split,
                                          name="support" if auto else "statistics")
    if model == "2d":
        fit = _iter_fit_2d(centred, mean, neighbourhood, orders, direction)
    else:
        fit = _iter_fit_centred(centred, mean, var, neighbourhood, orders, direction)
    return (yield from stage(fit, split, 1.0))


def _fit_cost(d, neighbourhood, orders):
    """Work per pixel of fitting a centred image of d channels (the support
    choice included), or None for a neighbourhood the fit will reject."""
    try:
        if isinstance(neighbourhood, str):
            candidates = _candidate_offsets(orders)
            eta = max(len(offs) for _, offs in candidates)
            return _scores_cost(candidates, d) + _statistics_cost(eta * d + d)
        return _statistics_cost(len(as_offsets(neighbourhood)[0]) * d + d)
    except (TypeError, ValueError):  # the fit itself will say what is wrong
        return None


def _prepare_share(d, neighbourhood, orders, model):
    """The part of a fit spent preparing the image (for progress only)."""
    rest = _fit_cost(1 if model == "2d" else d, neighbourhood, orders)
    if rest is None:
        return 0.1
    if model == "2d":  # the decorrelation, then d single-channel fits
        rest = _decorrelate_cost(d) + d * rest
    prep = _prepare_cost(d)
    return prep / (prep + rest)


@shared_parameters(_FIT_CAR_PARAMETERS)
def fit_car(
    image,
    neighbourhood=2,
    *,
    model="3d",
    orders=range(1, 6),
    direction="down",
    channel_axis=-1,
):
    """Fit a CAR model to a whole image (the Bayesian estimate).

    The estimates are (14.7)-(14.14), (14.21), docs/model.md: the mean is
    subtracted, the data-gathering matrices are summed over the pixels whose
    whole neighbourhood lies inside the image (flat neighbourhoods left out)
    with an almost uninformative prior.

    {parameters}

    Returns
    -------
    CARModel
        The fitted model; ``scores`` holds the decision-rule scores when the
        support was chosen.

    Raises
    ------
    ValueError
        If the image is empty, constant, not 2-D or 3-D, holds NaN or
        infinite values, or is too small for the neighbourhood; if the
        neighbourhood, ``model`` or ``direction`` is invalid; for
        ``model='2d'``, if a spectral factor is constant.
    TypeError
        If the image is None or not numeric.

    See Also
    --------
    iter_fit_car : The same as a job, with progress.
    predict : The model's one-step predictions.
    car_napari.model.synthesize : A texture from the model.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((32, 32, 3))
    >>> model = fit_car(image, 2)
    >>> model.gamma.shape, model.sigma.shape, model.order
    ((3, 12), (3, 3), 2)
    """
    return drain(iter_fit_car(image, neighbourhood, model=model, orders=orders,
                              direction=direction, channel_axis=channel_axis))


def _iter_fit_centred(centred, mean, channel_var, neighbourhood, orders, direction):
    d = centred.shape[2]
    scores = None
    split = 0.0
    if isinstance(neighbourhood, str):
        if neighbourhood != "auto":
            raise ValueError(
                f"neighbourhood must be an order, offsets or 'auto'; got {neighbourhood!r}."
            )
        candidates = _candidate_offsets(orders)
        split = _support_share(candidates, d)
        scores = yield from stage(_iter_scores(centred, candidates, direction),
                                  0.0, split)
        best = max(scores, key=scores.get)
        offsets = dict(candidates)[best]
        order = best if isinstance(best, int) else None
    else:
        offsets, order = as_offsets(neighbourhood)
    ctx = Context.spatial(offsets, d)
    view_shape = scan_view(centred, direction).shape
    check_size(np.empty(view_shape[:2]), ctx.reach, minimum_pixels=ctx.n_regressors + 2)
    V, count = yield from stage(iter_data_statistics(centred, ctx, direction=direction),
                                split, 1.0)
    m = ctx.n_regressors
    var = float(np.mean(channel_var))
    gamma, lam, vx, beta, _ = estimate_parameters(V, count, m, np.full(m + d, _PRIOR * var))
    return CARModel(
        gamma=gamma, sigma=lam / beta, mean=mean, offsets=offsets, lam=lam, vx=vx,
        beta=beta, n_pixels=count, order=order, scores=scores, direction=direction,
    )


def _decorrelate_cost(d):
    return 100.0 * d


def _iter_covariance(flat):
    """``np.cov(flat, rowvar=False)``, the centring by blocks (the same
    arithmetic as NumPy's: its mean, its centred copy, one product)."""
    n, d = flat.shape
    mean = flat.mean(axis=0)
    centred = np.empty_like(flat)
    blocks = row_blocks(n, _WHITEN_ROWS, merge_tail=True)
    for k, (start, stop) in enumerate(blocks, start=1):
        np.subtract(flat[start:stop], mean, out=centred[start:stop])
        yield Progress("decorrelating", 0.5 * k / len(blocks), "spectral covariance")
    cov = np.dot(centred.T, centred) * (1.0 / (n - 1))
    return cov.reshape(d, d)


def _iter_fit_2d(centred, mean, neighbourhood, orders, direction):
    d = centred.shape[2]
    dec = _decorrelate_cost(d)
    fit_cost = _fit_cost(1, neighbourhood, orders) or dec
    share = dec / (dec + d * fit_cost)  # the decorrelation, then d equal fits
    each = (1.0 - share) / d
    flat = centred.reshape(-1, d)
    cov = yield from stage(_iter_covariance(flat), 0.0, share)
    evals, basis = np.linalg.eigh(cov)
    basis = basis[:, ::-1]  # strongest factor first
    factors_data = np.empty_like(centred)
    factors_flat = factors_data.reshape(-1, d)
    blocks = row_blocks(flat.shape[0], _WHITEN_ROWS, merge_tail=True)
    for k, (start, stop) in enumerate(blocks, start=1):
        factors_flat[start:stop] = flat[start:stop] @ basis
        yield Progress("decorrelating", share * (0.5 + 0.5 * k / len(blocks)),
                       "spectral factors")
    factors = []
    for k in range(d):
        start = share + k * each
        f = np.empty(centred.shape[:2] + (1,))
        f_flat = f.reshape(-1)
        for r0, r1 in blocks:
            f_flat[r0:r1] = factors_flat[r0:r1, k]
            yield Progress("decorrelating", start, f"spectral factor {k + 1}/{d}")
        lo, hi = f.min(), f.max()
        yield Progress("decorrelating", start, f"spectral factor {k + 1}/{d}")
        # np.ptp(f) and np.abs(f).max(), without a temporary
        if hi - lo <= 1e-12 * max(1.0, max(abs(lo), abs(hi))):
            raise ValueError(
                f"spectral factor {k} is constant (the channels are linearly dependent); "
                "use model='3d' or fewer channels."
            )
        # its variance by blocks (it only scales the tiny prior: rounding in
        # its last bits cannot reach the estimates)
        mu = f_flat.mean()
        square = 0.0
        for r0, r1 in blocks:
            square += float(np.square(f_flat[r0:r1] - mu).sum())
            yield Progress("decorrelating", start, f"spectral factor {k + 1}/{d}")
        var = np.array([square / f_flat.size])
        fit = _iter_fit_centred(f, np.zeros(1), var, neighbourhood, orders, direction)
        factors.append((yield from stage(fit, start, start + each)))
    del factors_data
    # Equivalent colour-space model over the union of the factors' offsets.
    union = _offset_union(fm.offsets for fm in factors)
    eta = len(union)
    A = np.zeros((eta, d, d))
    for k, fm in enumerate(factors):
        pos = {s: i for i, s in enumerate(map(tuple, union.tolist()))}
        for s, a in zip(map(tuple, fm.offsets.tolist()), fm.gamma[0], strict=True):
            A[pos[s], k, k] = a
    A = basis @ A @ basis.T
    gamma = A.transpose(1, 0, 2).reshape(d, eta * d)
    sigma = basis @ np.diag([fm.sigma[0, 0] for fm in factors]) @ basis.T
    lam = basis @ np.diag([fm.lam[0, 0] for fm in factors]) @ basis.T
    orders_found = {fm.order for fm in factors}
    return CARModel(
        gamma=gamma, sigma=sigma, mean=mean, offsets=union, lam=lam,
        vx=np.empty((0, 0)),  # per factor: see ``factors``
        beta=float(min(fm.beta for fm in factors)), n_pixels=min(fm.n_pixels for fm in factors),
        order=orders_found.pop() if len(orders_found) == 1 else None,
        scores=None, direction=direction, basis=basis, factors=tuple(factors),
    )
