"""Recursive (adaptive) estimation along the four scan directions ((14.26)-(14.32),
section 14.2.1, docs/model.md)."""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float, check_not_constant, check_size, summarize
from ._kernels import recursive_scan
from .directions import DIRECTIONS, scan_shape, scan_view, unscan_view
from .neighbourhood import Context, as_offsets
from .statistics import data_statistics

__all__ = ["local_parameters", "scan", "ScanResult", "adaptive_scan", "default_prior",
           "DIRECTIONS", "scan_shape", "scan_view", "unscan_view"]


def _geometry(shape, direction, context):
    """Strides that map scan position (a, b) to the original (H, W, C) array."""
    h, w, c = shape
    if direction == "down":
        hs, ws, i0, j0, ia, ib, ja, jb = h, w, 0, 0, 1, 0, 0, 1
    elif direction == "up":
        hs, ws, i0, j0, ia, ib, ja, jb = h, w, h - 1, 0, -1, 0, 0, 1
    elif direction == "right":
        hs, ws, i0, j0, ia, ib, ja, jb = w, h, 0, 0, 0, 1, 1, 0
    elif direction == "left":
        hs, ws, i0, j0, ia, ib, ja, jb = w, h, 0, w - 1, 0, 1, -1, 0
    else:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    # pixel index of (i, j) is i*w + j; element index is that times c
    base_px = i0 * w + j0
    sa_px = ia * w + ja
    sb_px = ib * w + jb
    (up, down), (left, right) = context.reach
    geom = np.array(
        [hs, ws, base_px * c, sa_px * c, sb_px * c, base_px, sa_px, sb_px,
         up, hs - down, left, ws - right],
        dtype=np.int64,
    )
    di, dj, ch = context.taps.T
    tap_off = -(di * sa_px + dj * sb_px) * c + ch
    return geom, np.ascontiguousarray(tap_off, dtype=np.int64)


class ScanResult(dict):
    """Outputs of :func:`scan` by name, plus the final statistics.

    A plain dict: the requested outputs (``'gamma'``, ``'mean'``, ...) and
    ``'G'``, ``'lam'``, ``'T'``, ``'beta'``, ``'count'`` (see :func:`scan`).

    Examples
    --------
    >>> sorted(ScanResult(beta=1.0, count=3))
    ['beta', 'count']
    """


def scan(
    data,
    context,
    *,
    direction="down",
    forgetting=1.0,
    intercept=False,
    prior=None,
    initial=None,
    update=True,
    outputs=("gamma",),
    missing=None,
    fill_range=None,
    suspect_logrel=-np.inf,
):
    """Run the recursive square-root estimator over an image.

    The recursion of (14.26)-(14.32), section 14.2.1, docs/model.md, in one
    of the four scan directions, with exponential forgetting; it keeps a
    Cholesky factor of the statistics, never an explicit inverse.

    Parameters
    ----------
    data : (H, W, C) ndarray of float64
        C-contiguous, already centred; modified in place only where
        ``missing`` asks for fills.
    context : Context
        What goes into ``X_r`` and ``Y_r``; ``C >= context.n_channels``.
    direction : {'down', 'up', 'right', 'left'}, optional
        The scan direction.
    forgetting : float in (0, 1], optional
        The forgetting factor ``phi``.
    intercept : bool, optional
        Add a constant regressor.
    prior : (n,) array_like, optional
        Diagonal of ``V_0`` (``n = m + intercept + d``); required unless
        ``initial`` is given.
    initial : tuple, optional
        ``(U0, beta0)`` to start from given statistics instead of the prior:
        ``U0`` the upper Cholesky factor of the augmented ``V = U0^T U0`` of
        ``[X; (1); Y]`` (prior included). ``prior``, if also given, is still
        the floor that forgetting re-injects.
    update : bool, optional
        False predicts with fixed statistics.
    outputs : subset of {'gamma', 'mean', 'logp', 'q', 'maha', 'logrel'}, optional
        The per-pixel arrays to return (``logrel``: log predictive density
        relative to its peak, <= 0).
    missing : (H, W) array of bool or uint8, optional
        Pixels to fill in place in ``data`` (its target channels) with the
        conditional mean as the scan reaches them (section 14.7,
        docs/inpainting.md); they and pixels whose neighbourhood holds one do
        not update the statistics.
    fill_range : tuple of 2 arrays of d values, optional
        ``(lo, hi)`` bounds for the filled values (default: unbounded).
    suspect_logrel : float <= 0, optional
        ``missing`` may also be a uint8 array holding 2 at suspect known
        pixels (the edge of the damage): one the model finds improbable when
        the scan reaches it (log predictive density relative to its peak, as
        the ``logrel`` output, below this) is filled too. Such a ``missing``
        is modified in place (1 where filled, 0 where kept).

    Returns
    -------
    ScanResult
        The requested arrays in image geometry (``gamma``: (H, W, d, m),
        ``mean``: (H, W, d), others (H, W)), and the final statistics: ``G``
        (d, p) gamma with its intercept column, ``lam``, ``T`` (lower,
        ``V_x^{-1} = T^T T``), ``beta`` and ``count`` (updates made).

    Raises
    ------
    ValueError
        If ``data`` has fewer channels than the context needs, the prior is
        not ``n`` positive values, ``missing`` is not (H, W), or
        ``direction`` is unknown.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
    >>> res = scan(y, Context.spatial([[0, 1], [1, 0]], 1), prior=np.full(3, 1e-6),
    ...            outputs=("mean",))
    >>> res["mean"].shape, res["count"]
    ((8, 8, 1), 49)
    """
    h, w, c = data.shape
    if c < context.n_channels:
        raise ValueError(f"context needs {context.n_channels} channels, data has {c}.")
    m, d = context.n_regressors, context.n_targets
    p = m + int(bool(intercept))
    n = p + d
    geom, tap_off = _geometry(data.shape, direction, context)
    if initial is None:
        prior = np.ascontiguousarray(prior, dtype=np.float64)
        if prior.shape != (n,) or np.any(prior <= 0):
            raise ValueError("prior must hold n positive values.")
        T0 = np.diag(1.0 / np.sqrt(prior[:p]))
        G0 = np.zeros((d, p))
        lam0 = np.diag(prior[p:])
        beta0 = float(p - 1)
    else:
        U0, beta0 = initial
        U11, U12, U22 = U0[:p, :p], U0[:p, p:], U0[p:, p:]
        S = np.linalg.solve(U11, np.eye(p))  # U11^{-1}: upper, V_x^{-1} = S S^T
        T0 = np.ascontiguousarray(np.triu(S).T)
        G0 = np.ascontiguousarray((S @ U12).T)
        lam0 = U22.T @ U22
        if prior is None:  # re-inject what we started from
            prior = np.diag(U0.T @ U0).copy()
        prior = np.ascontiguousarray(prior, dtype=np.float64)
    npx = h * w
    empty = np.empty(0)
    arrays = {
        "gamma": np.empty(npx * d * m) if "gamma" in outputs else empty,
        "mean": np.empty(npx * d) if "mean" in outputs else empty,
        "logp": np.empty(npx) if "logp" in outputs else empty,
        "q": np.empty(npx) if "q" in outputs else empty,
        "maha": np.empty(npx) if "maha" in outputs else empty,
        "logrel": np.empty(npx) if "logrel" in outputs else empty,
    }
    if missing is None:
        missing_flat = np.empty(0, np.uint8)
    else:
        missing_flat = np.ascontiguousarray(missing, dtype=np.uint8).reshape(-1)
        if missing_flat.size != h * w:
            raise ValueError(f"missing must be an (H, W) mask like the data {(h, w)}.")
    if fill_range is None:
        fill_lo, fill_hi = np.full(d, -np.inf), np.full(d, np.inf)
    else:
        fill_lo = np.ascontiguousarray(np.broadcast_to(fill_range[0], (d,)), dtype=np.float64)
        fill_hi = np.ascontiguousarray(np.broadcast_to(fill_range[1], (d,)), dtype=np.float64)
    di, dj = context.taps[:, 0], context.taps[:, 1]
    tap_px = np.ascontiguousarray(-(di * geom[6] + dj * geom[7]), dtype=np.int64)
    T_final = np.empty((p, p))
    G_final = np.empty((d, p))
    lam_final = np.empty((d, d))
    state = np.empty(2)
    recursive_scan(
        data.reshape(-1),
        geom,
        tap_off,
        context.taps[:, 2].copy(),
        context.targets,
        bool(intercept),
        T0,
        G0,
        np.ascontiguousarray(lam0),
        float(beta0),
        float(p - 1),
        float(forgetting),
        prior,
        bool(update),
        arrays["gamma"],
        arrays["mean"],
        arrays["logp"],
        arrays["q"],
        arrays["maha"],
        arrays["logrel"],
        missing_flat,
        tap_px,
        fill_lo,
        fill_hi,
        float(suspect_logrel),
        T_final,
        G_final,
        lam_final,
        state,
    )
    shapes = {"gamma": (h, w, d, m), "mean": (h, w, d), "logp": (h, w), "q": (h, w),
              "maha": (h, w), "logrel": (h, w)}
    result = ScanResult({k: arrays[k].reshape(shapes[k]) for k in outputs})
    result.update(T=T_final, G=G_final, lam=lam_final, beta=float(state[0]),
                  count=int(state[1]))
    return result


def default_prior(channel_var, n_regressors, intercept, n_targets, strength):
    """Diagonal of the prior ``V_0``: ``strength`` times the data variance.

    Parameters
    ----------
    channel_var : array_like
        Per-channel variance of the data; their mean sets the scale (1 when
        it is not positive).
    n_regressors : int
        ``m``, the length of ``X_r``.
    intercept : bool
        Whether a constant regressor follows ``X_r`` (its entry is
        ``strength``, unscaled).
    n_targets : int
        ``d``, the length of ``Y_r``.
    strength : float
        The prior's weight relative to one pixel's data.

    Returns
    -------
    (m + intercept + d,) ndarray of float64
        The diagonal, in the order of ``[X_r; (1); Y_r]``.

    Examples
    --------
    >>> default_prior([2.0, 4.0], 2, True, 1, 0.5).tolist()
    [1.5, 1.5, 0.5, 1.5]
    """
    var = float(np.mean(channel_var))
    var = var if var > 0 else 1.0
    prior = np.full(n_regressors + int(intercept) + n_targets, strength * var)
    if intercept:
        prior[n_regressors] = strength
    return prior


def local_parameters(
    image,
    neighbourhood=2,
    *,
    forgetting=0.99,
    direction="down",
    channel_axis=-1,
    prior=1e-6,
    warm_start=True,
):
    """Adaptive 3DCAR parameters ``gamma_hat_r`` at every pixel.

    The recursive Bayesian estimator with exponential forgetting
    ((14.26)-(14.32), section 14.2.1, docs/model.md) scans the image in one
    direction, keeping a square-root (Cholesky) factor of its statistics, so
    it stays finite and accurate on flat regions.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Grey or multichannel image; any dtype (integers are scaled to [0, 1]).
    neighbourhood : int or (eta, 2) array of int, optional
        Order of the hierarchical causal neighbourhood, or explicit offsets.
    forgetting : float in (0, 1], optional
        Exponential forgetting factor ``phi``; the effective window is about
        ``1 / (1 - phi**2)`` pixels along the scan. 1 means no forgetting.
    direction : {'down', 'up', 'right', 'left'}, optional
        Where the scan moves: 'down' is the raster (rows top to bottom, each
        left to right), 'up' bottom to top, 'right' columns left to right,
        'left' columns right to left. Offsets are relative to the scan.
    channel_axis : int or None, optional
        Axis of the channels; None for a grey image.
    prior : float, optional
        Strength of the prior ``V_0 = prior * var(image) * I`` relative to one
        pixel's data; also the floor the statistics never fall below.
    warm_start : bool, optional
        Start the scan from the whole image's statistics weighted as one
        forgetting window (``1 / (1 - phi**2)`` pixels) instead of the bare
        prior: the first pixels of the scan then get the global model, not a
        transient fitted to a handful of pixels. Ignored when ``forgetting=1``.

    Returns
    -------
    (H, W, d, d*eta) ndarray of float64
        ``gamma[i, j] = [A_1, ..., A_eta]`` estimated from the pixels scanned
        up to and including ``(i, j)``; where the neighbourhood leaves the image
        the running estimate carries over (zeros before the first update).

    Raises
    ------
    ValueError
        If the image is empty, constant, not 2-D or 3-D, holds NaN or
        infinite values, or is too small; if the neighbourhood,
        ``forgetting``, ``direction`` or ``prior`` is invalid.
    TypeError
        If the image is None or not numeric.

    Notes
    -----
    A local intercept is estimated with ``gamma`` (and dropped from the
    output), so the parameters describe texture, not local brightness; with
    ``forgetting=1`` the estimate at the last pixel equals least squares with
    an intercept over all pixels whose neighbourhood lies inside the image.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((16, 16, 3))
    >>> local_parameters(image, 1).shape
    (16, 16, 3, 6)
    """
    data = as_channel_last_float(image, channel_axis=channel_axis)
    offsets, _ = as_offsets(neighbourhood)
    if not (0.0 < float(forgetting) <= 1.0):
        raise ValueError(f"forgetting must be in (0, 1]; got {forgetting}.")
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    if not prior > 0:
        raise ValueError(f"prior must be positive; got {prior}.")
    context = Context.spatial(offsets, data.shape[2])
    check_size(np.empty(scan_shape(data.shape, direction)), context.reach)
    summary = summarize(data)
    check_not_constant(data, summary=summary)
    data -= summary.mean
    return adaptive_scan(data, context, summary.var, forgetting=float(forgetting),
                         direction=direction, prior=prior, warm_start=warm_start,
                         outputs=("gamma",))["gamma"]


def adaptive_scan(centred, context, channel_var, *, forgetting, direction, prior=1e-6,
                  warm_start=True, outputs=("gamma",)):
    """The scan behind :func:`local_parameters`, on centred, validated data.

    With any of :func:`scan`'s outputs (e.g. the one-step conditional mean).

    Parameters
    ----------
    centred : (H, W, C) ndarray of float64
        C-contiguous, mean already subtracted.
    context : Context
        What goes into ``X_r`` and ``Y_r``.
    channel_var : array_like
        Per-channel variance of the data (scales the prior).
    forgetting : float in (0, 1]
        The forgetting factor ``phi``.
    direction : {'down', 'up', 'right', 'left'}
        The scan direction.
    prior : float, optional
        Strength of the prior (see :func:`default_prior`).
    warm_start : bool, optional
        Start from the whole image's statistics weighted as one forgetting
        window (see :func:`local_parameters`).
    outputs : tuple of str, optional
        As :func:`scan`.

    Returns
    -------
    ScanResult
        As :func:`scan`, with an intercept.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
    >>> res = adaptive_scan(y, Context.spatial([[0, 1], [1, 0]], 1), [1.0],
    ...                     forgetting=0.99, direction="down")
    >>> res["gamma"].shape
    (8, 8, 1, 2)
    """
    pri = default_prior(channel_var, context.n_regressors, True, context.n_targets, prior)
    initial = None
    if warm_start and forgetting < 1.0:
        initial = _window_statistics(centred, context, direction, pri, float(forgetting))
    return scan(centred, context, direction=direction, forgetting=float(forgetting),
                intercept=True, prior=pri, initial=initial, outputs=outputs)


def _window_statistics(centred, context, direction, prior, forgetting):
    """Whole-image augmented statistics of [X; 1; Y], scaled to the weight of
    one forgetting window, plus the prior: (upper factor, beta). A prior worth
    one window needs no more than a central crop of 256 x 256 pixels."""
    h, w = centred.shape[:2]
    top, left = max(0, (h - 256) // 2), max(0, (w - 256) // 2)
    crop = centred[top : top + 256, left : left + 256]
    V, count = data_statistics(crop, context, direction=direction)
    m = context.n_regressors
    n = V.shape[0] + 1
    aug = np.zeros((n, n))
    aug[:m, :m], aug[:m, m + 1:], aug[m + 1:, :m], aug[m + 1:, m + 1:] = (
        V[:m, :m], V[:m, m:], V[m:, :m], V[m:, m:])
    aug[m, m] = count  # the data are centred: the intercept's cross terms are ~0
    window = 1.0 / (1.0 - forgetting**2)
    weight = min(1.0, window / max(count, 1))
    aug = aug * weight + np.diag(prior)
    return np.linalg.cholesky(aug).T.copy(), float(m) + weight * count
