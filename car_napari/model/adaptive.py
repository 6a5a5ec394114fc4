"""The adaptive estimator: the recursive scan (:mod:`.recursive`) with a
forgetting factor, a prior scaled to the data and a warm start from the whole
image, giving each pixel its local CAR parameters ((14.26)-(14.32), section
14.2.1, docs/model.md)."""

from __future__ import annotations

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import drain
from .._validation import (
    as_channel_last_float,
    check_forgetting,
    check_not_constant,
    check_real,
    check_size,
    summarize,
)
from .directions import check_direction, scan_shape
from .neighbourhood import Context, as_offsets
from .recursive import _CHUNK_ROWS_PARAMETER, RecursiveScan, default_prior
from .statistics import data_statistics

__all__ = ["adaptive_scanner", "adaptive_start", "iter_local_parameters", "local_parameters"]


_PARAMETERS = """
image : (H, W) or (H, W, C) array
    Grey or multichannel image; any dtype (integers are scaled to [0, 1]).
neighbourhood : int or (eta, 2) array of int, optional
    Order of the hierarchical causal neighbourhood, or explicit offsets.
forgetting : float in [0.5, 1], optional
    Exponential forgetting factor ``phi``; the effective window is about
    ``1 / (1 - phi**2)`` pixels along the scan. 1 means no forgetting;
    below 0.5 (a window of about one pixel) is refused.
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
"""


@shared_parameters(_PARAMETERS)
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

    {parameters}

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
    return drain(iter_local_parameters(
        image, neighbourhood, forgetting=forgetting, direction=direction,
        channel_axis=channel_axis, prior=prior, warm_start=warm_start))


@shared_sections(parameters=_PARAMETERS + _CHUNK_ROWS_PARAMETER,
                 raises=raises_as("local_parameters", "ValueError", "TypeError"))
def iter_local_parameters(
    image,
    neighbourhood=2,
    *,
    forgetting=0.99,
    direction="down",
    channel_axis=-1,
    prior=1e-6,
    warm_start=True,
    chunk_rows=None,
):
    """Adaptive 3DCAR parameters at every pixel, as a job: Progress, then the parameters.

    The generator form of :func:`local_parameters`, with the same parameters
    and, bit for bit, the same result: the scan runs in chunks of rows (about
    0.1-0.25 s of work each, see :class:`RecursiveScan`) with a yield
    between them, so a worker can report progress and stop at a Cancel.

    {parameters}

    Returns
    -------
    (H, W, d, d*eta) ndarray of float64
        What :func:`local_parameters` returns.

    Yields
    ------
    Progress
        Stage ``"scan"`` after each chunk of rows, its fraction the rows
        done, message like ``"down scan: rows 512/2048"``.

    {raises}

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> image = np.random.default_rng(0).random((64, 48, 3))
    >>> records = []
    >>> gamma = drain(iter_local_parameters(image, 1, chunk_rows=16), records.append)
    >>> gamma.shape, [r.message for r in records][-1]
    ((64, 48, 3, 6), 'down scan: rows 64/64')
    >>> bool(np.array_equal(gamma, local_parameters(image, 1)))
    True
    """
    offsets, _ = as_offsets(neighbourhood)  # the options first: no pass over a bad call
    forgetting = check_forgetting(forgetting)
    check_direction(direction)
    prior = check_real(prior, "prior", low=0.0, low_open=True)
    if not isinstance(warm_start, (bool, np.bool_)):
        raise TypeError(f"warm_start must be True or False; got {warm_start!r}.")
    data = as_channel_last_float(image, channel_axis=channel_axis)
    context = Context.spatial(offsets, data.shape[2])
    check_size(np.empty(scan_shape(data.shape, direction)), context.reach)
    summary = summarize(data)
    check_not_constant(data, summary=summary)
    data -= summary.mean
    scanner = adaptive_scanner(data, context, summary.var, forgetting=float(forgetting),
                               direction=direction, prior=prior, warm_start=warm_start)
    res = yield from scanner.iter_run(chunk_rows)
    return res["gamma"]


def adaptive_scanner(centred, context, channel_var, *, forgetting, direction, prior=1e-6,
                     warm_start=True, outputs=("gamma",), stream=False, start=None):
    """The adaptive scan behind :func:`local_parameters`, on centred, validated data.

    The one entry point of the adaptive estimator's scan: a
    :class:`RecursiveScan` with its prior (:func:`default_prior`) and warm
    start (:func:`adaptive_start`), with any of :func:`scan`'s outputs (e.g.
    the one-step conditional mean). ``.run()`` scans the whole image in one
    kernel call, ``.iter_run()`` is that as a job (a Progress record per
    chunk of rows), ``.advance()`` runs one chunk (then ``.result()``): any
    chunking gives the same result bit for bit.

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
    stream : bool, optional
        Hand each chunk's outputs out instead of keeping image-sized arrays
        (see :class:`RecursiveScan`).
    start : tuple, optional
        What :func:`adaptive_start` returns for these arguments, when a
        second scan of the same data starts as the first did (default:
        computed here).

    Returns
    -------
    RecursiveScan
        Not started: ``run()``, ``iter_run()``, or ``advance`` it to its end
        (yielding in between) and take ``result()``: a :class:`ScanResult`
        as :func:`scan`'s, with an intercept.

    Examples
    --------
    The whole scan, in one call or as a job:

    >>> import numpy as np
    >>> from car_napari._progress import drain, stage
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((64, 40, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
    >>> res = adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction="down").run()
    >>> res["gamma"].shape
    (64, 40, 1, 2)
    >>> def job():
    ...     scanner = adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction="down")
    ...     res = yield from stage(scanner.iter_run(), 0.0, 0.8)
    ...     return res["gamma"]
    >>> bool(np.array_equal(drain(job()), res["gamma"]))
    True

    A job that keeps only a per-row summary of ``gamma`` (memory bounded by a
    chunk, whatever the image size), a yield after each chunk:

    >>> from car_napari._progress import Progress
    >>> def row_means():
    ...     scanner = adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction="up",
    ...                                stream=True)
    ...     means = np.empty((scanner.rows, 2))
    ...     while not scanner.done:
    ...         start, stop, out = scanner.advance()
    ...         means[start:stop] = out["gamma"].mean(axis=1)[:, 0]
    ...         yield Progress("scan", stop / scanner.rows)
    ...     return means   # rows in scan order: bottom to top for 'up'
    >>> drain(row_means()).shape
    (64, 2)

    Several scans at once, one per thread (the kernel releases the GIL), a
    yield after each round of chunks, so a Cancel stops them all within one
    chunk:

    >>> from concurrent.futures import ThreadPoolExecutor
    >>> def two_directions():
    ...     scanners = [adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction=d,
    ...                                  outputs=("mean",)) for d in ("down", "up")]
    ...     with ThreadPoolExecutor(max_workers=2) as pool:
    ...         while not all(s.done for s in scanners):
    ...             list(pool.map(lambda s: s.advance(16), scanners))
    ...             yield Progress("scan", min(s.position / s.rows for s in scanners))
    ...     return [s.result()["mean"] for s in scanners]
    >>> down, up = drain(two_directions())
    >>> bool(np.array_equal(down, adaptive_scanner(y, ctx, [1.0], forgetting=0.99,
    ...                     direction="down", outputs=("mean",)).run()["mean"], equal_nan=True))
    True
    """
    pri, initial = start if start is not None else adaptive_start(
        centred, context, channel_var, forgetting=forgetting, direction=direction,
        prior=prior, warm_start=warm_start)
    return RecursiveScan(centred, context, direction=direction, forgetting=float(forgetting),
                         intercept=True, prior=pri, initial=initial, outputs=outputs,
                         stream=stream)


def adaptive_start(centred, context, channel_var, *, forgetting, direction, prior=1e-6,
                   warm_start=True):
    """The prior and warm start of :func:`adaptive_scanner` (its parameters).

    Returns
    -------
    (prior, initial)
        The prior's diagonal and the whole image's statistics weighted as
        one forgetting window (None without a warm start): what a second
        scan of the same data passes as ``start`` instead of computing them
        again.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((32, 32, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
    >>> start = adaptive_start(y, ctx, [1.0], forgetting=0.99, direction="down")
    >>> a = adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction="down", start=start)
    >>> b = adaptive_scanner(y, ctx, [1.0], forgetting=0.99, direction="down")
    >>> while not (a.done or b.done):
    ...     _ = a.advance(), b.advance()
    >>> bool(np.array_equal(a.result()["gamma"], b.result()["gamma"]))
    True
    """
    pri = default_prior(channel_var, context.n_regressors, True, context.n_targets, prior)
    initial = None
    if warm_start and forgetting < 1.0:
        initial = _window_statistics(centred, context, direction, pri, float(forgetting))
    return pri, initial


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
