"""Sufficient statistics of the CAR model and the Bayesian estimates from them
((14.7)-(14.14), (14.21), docs/model.md)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._docstrings import shared_parameters, shared_sections
from .._progress import Progress, drain
from ._doc_sections import EXAMPLES_FIELD
from .directions import scan_view

__all__ = ["Estimates", "covariant_estimates", "data_statistics", "design_chunks",
           "estimate_parameters", "iter_data_statistics"]

_CHUNK_ELEMENTS = 4_000_000


def _row_blocks(view, context):
    """The scan rows of ``view`` with a complete neighbourhood, in blocks of
    about ``_CHUNK_ELEMENTS`` design-matrix entries: a list of (start, stop),
    and the columns (b0, b1) with one."""
    hs, ws = view.shape[:2]
    (up, down), (left, right) = context.reach  # costs microseconds: once per call
    a0, a1, b0, b1 = up, hs - down, left, ws - right
    m, d = context.n_regressors, context.n_targets
    rows_per_chunk = max(1, _CHUNK_ELEMENTS // max(1, (b1 - b0) * (m + d)))
    blocks = [(start, min(start + rows_per_chunk, a1)) for start in range(a0, a1, rows_per_chunk)]
    return blocks, b0, b1


def design_chunks(view, context):
    """Yield blocks of the augmented design matrix ``[X | Y]``, in raster order.

    The rows are the scan positions whose taps are all inside ``view``,
    leaving out flat neighbourhoods (every tap equal to its channel's value
    at ``r``): they have probability zero under the model, come from
    clipping, saturation or padding, and carry no texture information (the
    recursive kernel skips them too).

    Parameters
    ----------
    view : (Hs, Ws, C) ndarray of float64
        The image as the scan sees it (see :func:`~car_napari.model.directions.scan_view`).
    context : Context
        What goes into ``X_r`` and ``Y_r``.

    Yields
    ------
    Z : (n, m + d) ndarray of float64
        One block of rows ``[X_r, Y_r]``, ``m = context.n_regressors`` and
        ``d = context.n_targets``.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> view = np.arange(12.0).reshape(3, 4, 1)
    >>> [Z.shape for Z in design_chunks(view, Context.spatial([[1, 0]], 1))]
    [(8, 2)]
    """
    blocks, b0, b1 = _row_blocks(view, context)
    yield from _design_blocks(view, context, blocks, b0, b1)


def _design_blocks(view, context, blocks, b0, b1):
    m, d = context.n_regressors, context.n_targets
    for start, stop in blocks:
        Z = np.empty((stop - start, b1 - b0, m + d))
        for k, (di, dj, ch) in enumerate(context.taps):
            Z[:, :, k] = view[start - di : stop - di, b0 - dj : b1 - dj, ch]
        for t, ch in enumerate(context.targets):
            Z[:, :, m + t] = view[start:stop, b0:b1, ch]
        centre = view[start:stop, b0:b1][:, :, context.taps[:, 2]]
        flat = np.all(Z[:, :, :m] == centre, axis=2)
        Z = Z.reshape(-1, m + d)
        yield Z[~flat.ravel()] if flat.any() else Z


# the Parameters of data_statistics and iter_data_statistics, written once
_DATA_STATISTICS_PARAMETERS = """
    centred : (H, W, C) ndarray of float64
        The image, mean already subtracted.
    context : Context
        What goes into ``X_r`` and ``Y_r``.
    direction : {'down', 'up', 'right', 'left'}, optional
        The scan direction.
"""


@shared_parameters(_DATA_STATISTICS_PARAMETERS)
@shared_sections(examples_field=EXAMPLES_FIELD)
def iter_data_statistics(centred, context, *, direction="down"):
    """Accumulate the data-gathering matrix, as a job: Progress per block of rows.

    The generator form of :func:`data_statistics`, with the same parameters
    and result.

    {parameters}

    Returns
    -------
    (V, n_pixels)
        What :func:`data_statistics` returns.

    Yields
    ------
    Progress
        Stage ``"statistics"`` after each block of scan rows, message like
        ``"rows 120/512"``.

    {examples_field}
    >>> V, n = drain(iter_data_statistics(y, Context.spatial([[0, 1], [1, 0]], 1)))
    >>> V.shape, n
    ((3, 3), 49)
    """
    view = scan_view(centred, direction)
    n = context.n_regressors + context.n_targets
    V = np.zeros((n, n))
    count = 0
    blocks, b0, b1 = _row_blocks(view, context)
    if not blocks:
        return V, count
    first, rows = blocks[0][0], blocks[-1][1] - blocks[0][0]
    for (_, stop), Z in zip(blocks, _design_blocks(view, context, blocks, b0, b1),
                            strict=True):
        V += Z.T @ Z
        count += Z.shape[0]
        yield Progress("statistics", (stop - first) / rows, f"rows {stop - first}/{rows}")
    return V, count


@shared_parameters(_DATA_STATISTICS_PARAMETERS)
def data_statistics(centred, context, *, direction="down"):
    """The data-gathering matrix ``V = sum z z^T`` of ``z = [X_r; Y_r]``.

    The sum runs over the pixels whose whole neighbourhood lies inside the
    image (less the flat ones, see :func:`design_chunks`); no prior is
    included ((14.10)-(14.14), docs/model.md). Vectorised over pixels: one
    slice per tap, one BLAS product per block of rows.

    {parameters}

    Returns
    -------
    V : (m + d, m + d) ndarray of float64
        ``[[V_x, V_xy], [V_xy^T, V_y]]`` with ``m = context.n_regressors``
        and ``d = context.n_targets``.
    n_pixels : int
        The number of pixels summed.

    Raises
    ------
    ValueError
        If ``direction`` is not one of the four.

    See Also
    --------
    iter_data_statistics : The same as a job.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> y = np.arange(12.0).reshape(3, 4, 1)
    >>> V, n = data_statistics(y, Context.spatial([[1, 0]], 1))
    >>> n, V.tolist()
    (8, [[140.0, 252.0], [252.0, 492.0]])
    """
    return drain(iter_data_statistics(centred, context, direction=direction))


class Estimates(NamedTuple):
    """The Bayesian estimates of :func:`estimate_parameters` (unpacks like a tuple).

    Parameters
    ----------
    gamma : (d, m) ndarray
        ``gamma_hat``, with ``gamma_hat^T = V_x^{-1} V_xy``.
    lam : (d, d) ndarray
        ``lambda = V_y - V_xy^T V_x^{-1} V_xy``.
    vx : (m, m) ndarray
        ``V_x``, prior included.
    beta : float
        ``beta = beta(0) + n_pixels`` with ``beta(0) = m - 1``.
    chol : (m + d, m + d) ndarray
        The lower Cholesky factor of the augmented matrix, prior included.

    Examples
    --------
    >>> import numpy as np
    >>> gamma, lam, vx, beta, chol = estimate_parameters(np.eye(2), 5, 1, np.ones(2))
    >>> gamma.tolist(), beta
    ([[0.0]], 5.0)
    """

    gamma: np.ndarray
    lam: np.ndarray
    vx: np.ndarray
    beta: float
    chol: np.ndarray


def estimate_parameters(V, n_pixels, m, prior):
    """Bayesian estimates from the augmented statistics plus a diagonal prior.

    The estimates of (14.7)-(14.14), (14.21), docs/model.md. One Cholesky factor of
    the augmented ``V`` gives everything: its leading block factors ``V_x``
    and its trailing block factors ``lambda``, which is then positive
    definite even for nearly collinear channels (a subtraction
    ``V_y - V_xy^T V_x^{-1} V_xy`` can go indefinite there).

    Parameters
    ----------
    V : (m + d, m + d) ndarray
        The data-gathering matrix of ``[X_r; Y_r]`` (see :func:`data_statistics`).
    n_pixels : int
        The number of pixels summed in ``V``.
    m : int
        Length of ``X_r`` (regressors); the rest of ``V``'s ``m + d`` rows
        are ``Y_r``.
    prior : (m + d,) array_like
        The diagonal of the prior part ``V_0``; positive.

    Returns
    -------
    Estimates
        ``(gamma, lam, vx, beta, chol)``; see :class:`Estimates`.

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``V`` plus the prior is not positive definite.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[4.0, 2.0], [2.0, 5.0]])
    >>> est = estimate_parameters(V, 10, 1, np.zeros(2))
    >>> est.gamma.tolist(), est.lam.tolist(), est.beta
    ([[0.5]], [[4.0]], 10.0)
    """
    Vp = V + np.diag(prior)
    L = np.linalg.cholesky(Vp)
    L11, L21, L22 = L[:m, :m], L[m:, :m], L[m:, m:]
    gamma = np.linalg.solve(L11.T, L21.T).T  # gamma^T = V_x^{-1} V_xy = L11^{-T} L21^T
    lam = L22 @ L22.T
    beta = (m - 1) + n_pixels
    return Estimates(gamma, lam, Vp[:m, :m], float(beta), L)


# A texture that its neighbours predict exactly (a ramp, stripes, a checkerboard,
# a step) has a singular data matrix. The fallback prior is then a small multiple
# of kron(I, S), S the channels' scatter: each d x d block transforms as
# B S B^T, so estimates built on it stay exactly invariant to Y -> B Y.
DEGENERATE_PRIOR = 1e-9


def covariant_estimates(V, n_pixels, m, d, scatter, *, factor_prior=False):
    """:func:`estimate_parameters` with the covariant prior ``V / n_pixels``
    (one pixel's worth of the data), and, where that leaves the system
    singular (a degenerate texture), a prior of ``DEGENERATE_PRIOR`` times
    ``kron(I, scatter)`` added.

    Parameters
    ----------
    V : (m + d, m + d) ndarray
        The data-gathering matrix (see :func:`data_statistics`).
    n_pixels : int
        The number of pixels summed in ``V``.
    m, d : int
        Lengths of the regressors and of the modelled channels (``m`` a
        multiple of ``d``).
    scatter : (d, d) ndarray
        One pixel's scatter of the centred channels; positive definite.
    factor_prior : bool, optional
        Also require the prior itself to have a Cholesky factor (for a
        recursive estimator started from it).

    Returns
    -------
    estimates : Estimates
        As :func:`estimate_parameters`, with ``lam`` positive definite.
    prior_V : (m + d, m + d) ndarray
        The prior used.

    Raises
    ------
    ValueError
        If even the degenerate-texture prior leaves the system singular.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[1.0, 1.0], [1.0, 1.0]])  # exactly predicted: singular
    >>> est, prior = covariant_estimates(V, 10, 1, 1, np.array([[0.1]]))
    >>> bool(np.all(np.linalg.eigvalsh(est.lam) > 0))
    True
    """
    def estimates(prior_V):
        """The estimates with this prior; LinAlgError where it leaves ``lam``
        (or, with ``factor_prior``, the prior itself) without a Cholesky factor."""
        est = estimate_parameters(V + prior_V, n_pixels, m, np.zeros(m + d))
        np.linalg.cholesky(est.lam)
        if factor_prior:
            np.linalg.cholesky(prior_V + 1e-300 * np.eye(m + d))
        return est, prior_V

    prior_V = V / n_pixels
    try:
        return estimates(prior_V)
    except np.linalg.LinAlgError:
        prior_V = prior_V + DEGENERATE_PRIOR * np.kron(np.eye(m // d + 1), scatter)
    try:
        return estimates(prior_V)
    except np.linalg.LinAlgError:
        raise ValueError(
            "the texture is degenerate: its neighbours predict it exactly (a ramp, "
            "stripes, a step edge...) and even a regularised estimate is singular. "
            "Use a more textured region or a lower order."
        ) from None
