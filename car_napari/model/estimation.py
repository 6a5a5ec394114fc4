"""Whole-image Bayesian estimation, support selection and prediction.

SPEC 1.3 (statistics and estimates), 1.5 (the decision rule (14.6)), 1.6
(Student-t prediction (14.23)) and the 2DCAR path of 1.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._validation import as_channel_last_float, check_not_constant, check_size, summarize
from .directions import DIRECTIONS, scan_view
from .neighbourhood import Context, as_offsets
from .recursive import scan
from .statistics import data_statistics, estimate_parameters

__all__ = ["CARModel", "fit_car", "select_support", "predict"]

_PRIOR = 1e-9  # V_0 = _PRIOR * (per-pixel variance) * I: almost uninformative


@dataclass(eq=False)
class CARModel:
    """A fitted 3DCAR model ``Y_r - mean = gamma X_r + e_r``, ``e_r ~ N(0, sigma)``.

    Attributes
    ----------
    gamma : (d, d*eta) ndarray
        ``[A_1, ..., A_eta]`` with ``gamma[:, k*d + c] = A_k[:, c]`` (SPEC 1.2).
    sigma : (d, d) ndarray
        Noise covariance estimate ``lambda / beta``.
    mean : (d,) ndarray
        Mean subtracted before fitting.
    offsets : (eta, 2) ndarray of int
        The causal neighbourhood, relative to the scan ``direction``.
    lam : (d, d) ndarray
        ``lambda``, the residual scatter (with its prior part).
    vx : (d*eta, d*eta) ndarray
        ``V_x``, the regressors' data-gathering matrix including ``V_0``.
    beta : float
        ``beta(r)``: prior count plus the number of pixels used.
    n_pixels : int
        Pixels whose whole neighbourhood lay inside the image.
    order : int or None
        Hierarchical order, when the neighbourhood is one.
    scores : dict or None
        Decision-rule scores of every candidate, when the support was chosen.
    direction : str
        Scan direction the model was fitted in.
    basis, factors : ndarray and tuple of CARModel, or None
        For the 2DCAR path: an orthonormal spectral basis (d, d) whose columns
        are the principal components, and one single-channel model per factor.
        ``gamma`` and ``sigma`` then hold the equivalent colour-space model.
    """

    gamma: np.ndarray
    sigma: np.ndarray
    mean: np.ndarray
    offsets: np.ndarray
    lam: np.ndarray
    vx: np.ndarray
    beta: float
    n_pixels: int
    order: int | None = None
    scores: dict | None = None
    direction: str = "down"
    basis: np.ndarray | None = None
    factors: tuple | None = field(default=None, repr=False)

    @property
    def n_channels(self):
        return int(self.gamma.shape[0])

    @property
    def eta(self):
        return int(self.offsets.shape[0])

    @property
    def A(self):
        """The ``d x d`` matrices ``A_s`` as an (eta, d, d) array."""
        d = self.n_channels
        return self.gamma.reshape(d, self.eta, d).transpose(1, 0, 2)

    @property
    def log_det_vx(self):
        return float(np.linalg.slogdet(self.vx)[1])

    @property
    def context(self):
        return Context.spatial(self.offsets, self.n_channels)

    def to_dict(self):
        """Plain, JSON-serialisable summary of the model."""
        out = {
            "order": self.order,
            "offsets": self.offsets.tolist(),
            "direction": self.direction,
            "n_channels": self.n_channels,
            "gamma": self.gamma.tolist(),
            "sigma": self.sigma.tolist(),
            "mean": self.mean.tolist(),
            "beta": self.beta,
            "n_pixels": self.n_pixels,
            "model": "2d" if self.factors is not None else "3d",
        }
        if self.scores is not None:
            out["scores"] = {str(k): float(v) for k, v in self.scores.items()}
        return out


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


def _prepare(image, channel_axis, name="image"):
    """Validated float copy, centred; returns (data, mean, per-channel variance)."""
    data = as_channel_last_float(image, channel_axis=channel_axis, name=name)
    summary = summarize(data)
    check_not_constant(data, name=name, summary=summary)
    data -= summary.mean
    return data, summary.mean, summary.var


def _candidate_offsets(orders):
    cands = []
    for item in orders:
        offsets, order = as_offsets(item)
        key = order if order is not None else tuple(map(tuple, offsets.tolist()))
        cands.append((key, offsets))
    if not cands:
        raise ValueError("orders is empty: pass at least one candidate neighbourhood.")
    return cands


def _scores(centred, candidates, direction, channel_var):
    """Score every candidate on the same pixels (SPEC 1.5, first condition)."""
    d = centred.shape[2]
    union = []
    for _, offs in candidates:
        for s in map(tuple, offs.tolist()):
            if s not in union:
                union.append(s)
    union = np.array(union, dtype=np.int64)
    ctx = Context.spatial(union, d)
    view_shape = scan_view(centred, direction).shape
    check_size(np.empty(view_shape[:2]), ctx.reach, minimum_pixels=4 * ctx.n_regressors + 4)
    # Whiten the channels: the scores then do not change under any invertible
    # colour transform Y -> B Y (in particular, under the image's value range).
    V, count = data_statistics(_whiten(centred), ctx, direction=direction)
    mu = ctx.n_regressors
    index = {s: k for k, s in enumerate(map(tuple, union.tolist()))}
    scores = {}
    for key, offs in candidates:
        cols = np.array([index[s] * d + c for s in map(tuple, offs.tolist()) for c in range(d)])
        sel = np.r_[cols, mu + np.arange(d)]
        m = cols.size
        sub = V[np.ix_(sel, sel)]
        _, _, _, beta, L = estimate_parameters(sub, count, m, d, np.full(m + d, _PRIOR))
        scores[key] = _decision_score(L, beta, float(m - 1), m, d)
    return scores


def _whiten(centred):
    d = centred.shape[2]
    flat = centred.reshape(-1, d)
    cov = flat.T @ flat / flat.shape[0]
    cov += 1e-12 * np.trace(cov) / d * np.eye(d)
    L = np.linalg.cholesky(cov)
    return np.linalg.solve(L, flat.T).T.reshape(centred.shape)


def select_support(image, orders=range(1, 6), *, channel_axis=-1, direction="down"):
    """Choose the most probable causal neighbourhood by the rule (14.6).

    Every candidate is scored on the same pixels (those whose neighbourhood
    under the union of all candidates lies inside the image) with
    ``beta(0) = d*eta - 1``, the two conditions SPEC 1.5 requires. The
    channels are whitened first (unit covariance), so the scores do not
    change under any invertible colour transform, the value range included.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
    orders : iterable of int or (eta, 2) arrays, optional
        Candidate neighbourhoods.
    channel_axis : int or None, optional
    direction : {'down', 'up', 'right', 'left'}, optional

    Returns
    -------
    best : int or tuple
        The winning order (or offsets as a tuple of pairs for custom candidates).
    scores : dict
        ``D_j`` of every candidate; larger is more probable.
    """
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    centred, _, var = _prepare(image, channel_axis)
    candidates = _candidate_offsets(orders)
    scores = _scores(centred, candidates, direction, var)
    best = max(scores, key=scores.get)
    return best, scores


def fit_car(
    image,
    neighbourhood=2,
    *,
    model="3d",
    orders=range(1, 6),
    direction="down",
    channel_axis=-1,
):
    """Fit a CAR model to a whole image (Bayesian estimate, SPEC 1.3).

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Any dtype; integer images are scaled to [0, 1].
    neighbourhood : int, (eta, 2) array or 'auto', optional
        Order, explicit causal offsets, or 'auto' to choose among ``orders`` by
        the decision rule (14.6) (see :func:`select_support`).
    model : {'3d', '2d'}, optional
        '3d': one 3DCAR model with full ``d x d`` matrices. '2d': decorrelate
        the channels by a spectral PCA and fit a 2DCAR model to each factor
        (each with its own support when ``neighbourhood='auto'``).
    orders : iterable, optional
        Candidates for ``neighbourhood='auto'``.
    direction : {'down', 'up', 'right', 'left'}, optional
    channel_axis : int or None, optional

    Returns
    -------
    CARModel
    """
    if model not in ("3d", "2d"):
        raise ValueError(f"model must be '3d' or '2d'; got {model!r}.")
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    centred, mean, var = _prepare(image, channel_axis)
    if model == "2d":
        return _fit_2d(centred, mean, neighbourhood, orders, direction)
    return _fit_centred(centred, mean, var, neighbourhood, orders, direction)


def _fit_centred(centred, mean, channel_var, neighbourhood, orders, direction):
    d = centred.shape[2]
    scores = None
    if isinstance(neighbourhood, str):
        if neighbourhood != "auto":
            raise ValueError(
                f"neighbourhood must be an order, offsets or 'auto'; got {neighbourhood!r}."
            )
        candidates = _candidate_offsets(orders)
        scores = _scores(centred, candidates, direction, channel_var)
        best = max(scores, key=scores.get)
        offsets = dict(candidates)[best]
        order = best if isinstance(best, int) else None
    else:
        offsets, order = as_offsets(neighbourhood)
    ctx = Context.spatial(offsets, d)
    view_shape = scan_view(centred, direction).shape
    check_size(np.empty(view_shape[:2]), ctx.reach, minimum_pixels=ctx.n_regressors + 2)
    V, count = data_statistics(centred, ctx, direction=direction)
    m = ctx.n_regressors
    var = float(np.mean(channel_var))
    gamma, lam, vx, beta, _ = estimate_parameters(V, count, m, d, np.full(m + d, _PRIOR * var))
    return CARModel(
        gamma=gamma, sigma=lam / beta, mean=mean, offsets=offsets, lam=lam, vx=vx,
        beta=beta, n_pixels=count, order=order, scores=scores, direction=direction,
    )


def _fit_2d(centred, mean, neighbourhood, orders, direction):
    d = centred.shape[2]
    cov = np.cov(centred.reshape(-1, d), rowvar=False).reshape(d, d)
    evals, basis = np.linalg.eigh(cov)
    basis = basis[:, ::-1]  # strongest factor first
    factors_data = centred @ basis
    factors = []
    for k in range(d):
        f = np.ascontiguousarray(factors_data[..., k : k + 1])
        if np.ptp(f) <= 1e-12 * max(1.0, np.abs(f).max()):
            raise ValueError(
                f"spectral factor {k} is constant (the channels are linearly dependent); "
                "use model='3d' or fewer channels."
            )
        factors.append(
            _fit_centred(f, np.zeros(1), f.var(axis=(0, 1)), neighbourhood, orders, direction)
        )
    # Equivalent colour-space model over the union of the factors' offsets.
    union = []
    for fm in factors:
        for s in map(tuple, fm.offsets.tolist()):
            if s not in union:
                union.append(s)
    union = np.array(union, dtype=np.int64)
    eta = len(union)
    A = np.zeros((eta, d, d))
    for k, fm in enumerate(factors):
        pos = {s: i for i, s in enumerate(map(tuple, union.tolist()))}
        for s, a in zip(map(tuple, fm.offsets.tolist()), fm.gamma[0]):
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


def _augmented_factor(model):
    """Upper factor U of the model's augmented statistics V = U^T U, built
    block by block (forming V and factoring it loses lambda to cancellation
    when channels are nearly collinear)."""
    m = model.vx.shape[0]
    d = model.n_channels
    U = np.zeros((m + d, m + d))
    U[:m, :m] = np.linalg.cholesky(model.vx).T
    U[:m, m:] = U[:m, :m] @ model.gamma.T
    U[m:, m:] = np.linalg.cholesky(model.lam).T
    return U


def predict(model, image, *, channel_axis=-1):
    """Conditional mean and log predictive density of every pixel (SPEC 1.6).

    Each pixel is predicted from its causal neighbours by the fitted model:
    the mean is ``mean + gamma_hat X_r`` and the density the Student t of
    (14.23) with ``nu = beta - d*eta + 2`` degrees of freedom.

    Parameters
    ----------
    model : CARModel
    image : (H, W) or (H, W, C) array
        With the model's number of channels.
    channel_axis : int or None, optional

    Returns
    -------
    mean : ndarray, same shape as ``image`` (float64)
        Conditional mean; NaN where the neighbourhood leaves the image.
    log_density : (H, W) ndarray
        Log predictive density of the observed pixel; NaN at the borders.
    """
    if not isinstance(model, CARModel):
        raise TypeError(f"model must be a CARModel (from fit_car); got {type(model).__name__}.")
    data = as_channel_last_float(image, channel_axis=channel_axis)
    d = model.n_channels
    if data.shape[2] != d:
        raise ValueError(
            f"image has {data.shape[2]} channels but the model was fitted to {d}; "
            "pass an image with the same channels (or check channel_axis)."
        )
    data -= model.mean
    ctx = model.context
    check_size(np.empty(scan_view(data, model.direction).shape[:2]), ctx.reach)
    if model.factors is not None:
        fdata = data @ model.basis
        mean = np.empty_like(fdata)
        logp = np.zeros(data.shape[:2])
        for k, fm in enumerate(model.factors):
            mk, lk = predict(fm, np.ascontiguousarray(fdata[..., k]), channel_axis=None)
            mean[..., k] = mk
            logp += lk
        mean = mean @ model.basis.T
    else:
        res = scan(
            data, ctx, direction=model.direction,
            initial=(_augmented_factor(model), model.beta), update=False,
            outputs=("mean", "logp"),
        )
        mean, logp = res["mean"], res["logp"]
    mean += model.mean
    if np.ndim(image) == 2 or channel_axis is None:
        mean = mean[..., 0]
    elif channel_axis not in (-1, np.ndim(image) - 1):
        mean = np.moveaxis(mean, -1, channel_axis)
    return mean, logp
