"""Recursive (adaptive) estimation along the four scan directions ((14.26)-(14.32),
section 14.2.1, docs/model.md)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._progress import Progress, drain
from .._validation import (
    as_channel_last_float,
    check_forgetting,
    check_not_constant,
    check_real,
    check_size,
    summarize,
)
from ._kernels import finish_factor, recursive_scan
from .directions import DIRECTIONS, scan_shape, scan_view, unscan_view
from .neighbourhood import Context, as_offsets
from .statistics import data_statistics

__all__ = ["local_parameters", "iter_local_parameters", "scan", "iter_scan", "RecursiveScan",
           "ScanChunk", "ScanResult", "adaptive_scan", "iter_adaptive_scan", "adaptive_scanner",
           "adaptive_start",
           "default_prior", "scan_work",
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


OUTPUTS = ("gamma", "mean", "logp", "q", "maha", "logrel")

# Rows per chunk of a scan: about this many work units (see _pixel_cost), which
# is ~0.1-0.25 s of one core: ~0.2 M pixels of an order-2 RGB scan writing its
# gamma (a new image-sized array: the page faults cost more than the update),
# ~0.6 M with a prediction output, ~1.3 M of a grey scan.
_CHUNK_WORK = 3.0e8
# A streaming scan's buffers: at most about this many float64 values per call.
_STREAM_VALUES = 1 << 19


def _pixel_cost(p, d, predict, width, stream=False):
    """Work units (~0.4-0.7 ns) of one pixel of a scan: the square-root
    update is ~p^2, the gamma and lambda updates ~d p and d^2, plus a fixed
    part; a prediction adds a d x d Cholesky factor and logarithms; each
    output value written costs a store, and in a new image-sized array its
    share of a page fault (measured: ~4 units a byte; a streaming scan's
    buffer is reused, ~2 a value)."""
    cost = p * p + 2 * d * p + d * d + 60 + (2 if stream else 32) * width
    if predict:
        cost += d * d * d + 2 * d * d + 40
    return cost


def scan_work(context, *, intercept=True, outputs=("gamma",), stream=False):
    """The work of one pixel of a scan, in the units :class:`RecursiveScan`
    sizes its chunks in (about 0.7 ns of one core each).

    Parameters
    ----------
    context : Context
        What goes into ``X_r`` and ``Y_r``.
    intercept : bool, optional
        Whether the scan adds a constant regressor.
    outputs : tuple of str, optional
        The outputs it writes (see :func:`scan`).
    stream : bool, optional
        Whether they go to a streaming scan's reused buffer (see
        :class:`RecursiveScan`) rather than to image-sized arrays.

    Returns
    -------
    float
        Work units per pixel: the square-root update (~p^2), the gamma and
        lambda updates, the prediction if an output needs it, the stores.

    Examples
    --------
    >>> from car_napari.model import Context
    >>> grey = scan_work(Context.spatial([[0, 1], [1, 0]], 1))
    >>> rgb = scan_work(Context.spatial([[0, 1], [1, 0]], 3))
    >>> rgb > 3 * grey
    True
    """
    m, d = context.n_regressors, context.n_targets
    p = m + int(bool(intercept))
    width = {"gamma": d * m, "mean": d}
    return float(_pixel_cost(p, d, any(k != "gamma" for k in outputs),
                             sum(width.get(k, 1) for k in outputs), stream))


class ScanChunk(NamedTuple):
    """The scan rows one :meth:`RecursiveScan.advance` ran, and their outputs.

    Parameters
    ----------
    start, stop : int
        The scan rows ``[start, stop)`` scanned (rows of the image as the
        scan sees it, see :func:`~car_napari.model.directions.scan_view`).
    outputs : dict
        The requested outputs of these rows in scan geometry: ``gamma``
        (rows, Ws, d, m), ``mean`` (rows, Ws, d), the others (rows, Ws).
        Views of the image-shaped outputs, or, for a streaming scan, of a
        buffer the next :meth:`RecursiveScan.advance` overwrites.

    Examples
    --------
    >>> chunk = ScanChunk(0, 4, {})
    >>> chunk.stop - chunk.start
    4
    """

    start: int
    stop: int
    outputs: dict


class RecursiveScan:
    """The recursive square-root estimator over an image, run in chunks of rows.

    What :func:`scan` runs, resumable: each :meth:`advance` scans the next
    rows (of the image as the scan sees it) in one ``nogil`` kernel call,
    carrying the whole estimator state (square-root factor, gamma, lambda,
    tau, beta, the counters and the prior re-injection's round robin
    position) to the next call, so any chunking gives, bit for bit, the
    one-call scan. A caller yields between chunks (a chance to cancel, to
    report progress); :func:`iter_scan` is that loop as a job. With
    ``stream=True`` the outputs are not kept at image size: each chunk's come
    back in a small reused buffer, for callers that reduce them on the fly
    (bounded memory on large images).

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
        ``(U0, beta0)``: start from these statistics (see :func:`scan`).
    update : bool, optional
        False predicts with fixed statistics.
    outputs : subset of {'gamma', 'mean', 'logp', 'q', 'maha', 'logrel'}, optional
        The per-pixel outputs (see :func:`scan`).
    missing : (H, W) array of bool or uint8, optional
        Pixels to fill in place (see :func:`scan`).
    fill_range : tuple of 2 arrays of d values, optional
        Bounds of the filled values.
    suspect_logrel : float <= 0, optional
        Outlier threshold of suspect pixels (see :func:`scan`).
    stream : bool, optional
        Return each chunk's outputs in a reused buffer instead of keeping
        image-sized arrays.

    Attributes
    ----------
    rows : int
        Scan rows in all (the image's height, or width for 'right'/'left').
    position : int
        The next scan row to scan; ``rows`` when done.
    chunk_rows : int
        Rows per chunk of about 0.1-0.25 s of work (the default of :meth:`advance`;
        a streaming scan's calls are capped by its buffer, see :attr:`stream_rows`).
    stream_rows : int
        A streaming scan's largest chunk (its buffer); ``rows`` otherwise.
    pixel_work : float
        The work of one pixel (see :func:`scan_work`).

    Raises
    ------
    ValueError
        As :func:`scan`.

    See Also
    --------
    iter_scan : The loop as a job.
    adaptive_scanner : The same with :func:`adaptive_scan`'s prior and warm start.

    Examples
    --------
    Scan in chunks, yielding between them, and get what :func:`scan` returns:

    >>> import numpy as np
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((40, 30, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
    >>> scanner = RecursiveScan(y, ctx, forgetting=0.99, intercept=True,
    ...                         prior=np.full(4, 1e-3), outputs=("mean",))
    >>> while not scanner.done:
    ...     chunk = scanner.advance(16)   # a generator would yield here
    >>> res = scanner.result()
    >>> whole = scan(y, ctx, forgetting=0.99, intercept=True, prior=np.full(4, 1e-3),
    ...              outputs=("mean",))
    >>> bool(np.array_equal(res["mean"], whole["mean"], equal_nan=True))
    True

    Streaming: each chunk's outputs, in scan order, reduced as they come:

    >>> scanner = RecursiveScan(y, ctx, direction="right", intercept=True,
    ...                         prior=np.full(4, 1e-3), outputs=("gamma",), stream=True)
    >>> sums = []
    >>> while not scanner.done:
    ...     chunk = scanner.advance()
    ...     sums.append(chunk.outputs["gamma"].sum(axis=(0, 1)))  # (d, m) per chunk
    >>> chunk.outputs["gamma"].shape[1:], scanner.position == scanner.rows
    ((40, 1, 2), True)
    """

    def __init__(
        self,
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
        stream=False,
    ):
        h, w, c = data.shape
        if c < context.n_channels:
            raise ValueError(f"context needs {context.n_channels} channels, data has {c}.")
        unknown = set(outputs) - set(OUTPUTS)
        if unknown:
            raise ValueError(f"unknown outputs {sorted(unknown)}; choose from {OUTPUTS}.")
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
            T0 = np.triu(S).T
            G0 = (S @ U12).T
            lam0 = U22.T @ U22
            if prior is None:  # re-inject what we started from
                prior = np.diag(U0.T @ U0).copy()
            prior = np.ascontiguousarray(prior, dtype=np.float64)
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
        self._shape = (h, w)
        self._m, self._d, self._p = m, d, p
        self.direction = direction
        self.outputs = tuple(outputs)
        self.stream = bool(stream)
        self.rows, self._ws = int(geom[0]), int(geom[1])
        self.position = 0
        # the estimator state, updated in place by each kernel call
        self._T = np.ascontiguousarray(T0, dtype=np.float64)
        self._G = np.ascontiguousarray(G0, dtype=np.float64)
        self._lam = np.ascontiguousarray(lam0, dtype=np.float64)
        self._fstate = np.array([1.0, float(beta0), 0.0])  # tau, beta, count
        self._istate = np.zeros(2, np.int64)  # tick, next_k
        self._args = (
            data.reshape(-1), geom, tap_off, context.taps[:, 2].copy(),
            np.ascontiguousarray(context.targets, dtype=np.int64), bool(intercept),
            float(p - 1), float(forgetting), prior, bool(update),
        )
        self._fill = (missing_flat,
                      np.ascontiguousarray(-(di * geom[6] + dj * geom[7]), dtype=np.int64),
                      fill_lo, fill_hi, float(suspect_logrel))
        self._width = {"gamma": d * m, "mean": d, "logp": 1, "q": 1, "maha": 1, "logrel": 1}
        self._tail = {"gamma": (d, m), "mean": (d,), "logp": (), "q": (), "maha": (), "logrel": ()}
        width = sum(self._width[k] for k in self.outputs)
        self.pixel_work = scan_work(context, intercept=intercept, outputs=self.outputs,
                                    stream=stream)
        self.chunk_rows = max(1, int(_CHUNK_WORK // (self.pixel_work * max(self._ws, 1))))
        self.stream_rows = self.rows
        if self.stream:
            self.stream_rows = max(1, _STREAM_VALUES // max(1, width * self._ws))
            self._flat = {k: np.empty(0) for k in self.outputs}
        else:
            self._flat = {k: np.empty(h * w * self._width[k]) for k in self.outputs}
        self._geom_out = np.array(geom[5:8])  # image geometry (pixel index)

    @property
    def done(self):
        """Whether every row has been scanned (a bool).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import Context
        >>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
        >>> s = RecursiveScan(y, Context.spatial([[0, 1]], 1), prior=np.ones(2))
        >>> s.done, s.advance().stop, s.done
        (False, 8, True)
        """
        return self.position >= self.rows

    def advance(self, rows=None):
        """Scan the next rows (one kernel call) and return them.

        Parameters
        ----------
        rows : int, optional
            How many scan rows (default :attr:`chunk_rows`; a streaming scan
            at most :attr:`stream_rows`). Fewer are left at the end.

        Returns
        -------
        ScanChunk
            ``(start, stop, outputs)``: the rows scanned and their outputs in
            scan geometry.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import Context
        >>> y = np.random.default_rng(0).standard_normal((8, 6, 1))
        >>> s = RecursiveScan(y, Context.spatial([[0, 1]], 1), prior=np.ones(2))
        >>> chunk = s.advance(3)
        >>> chunk.start, chunk.stop, chunk.outputs["gamma"].shape
        (0, 3, (3, 6, 1, 1))
        """
        rows = self.chunk_rows if rows is None else max(1, int(rows))
        if self.stream:
            rows = min(rows, self.stream_rows)
        start = self.position
        stop = min(self.rows, start + rows)
        ws = self._ws
        if self.stream:
            for k in self.outputs:
                need = (stop - start) * ws * self._width[k]
                if self._flat[k].size < need:
                    self._flat[k] = np.empty(min(self.stream_rows, self.rows) * ws
                                             * self._width[k])
            out_geom = np.array([-start * ws, ws, 1], np.int64)
        else:
            out_geom = self._geom_out
        flat = {k: self._flat.get(k, _EMPTY) for k in OUTPUTS}
        data, geom, tap_off, tap_ch, targets, intercept, beta_prior, phi, prior, update = (
            self._args)
        missing, tap_px, fill_lo, fill_hi, suspect = self._fill
        if stop > start:
            recursive_scan(
                data, geom, np.array([start, stop], np.int64), out_geom, tap_off, tap_ch,
                targets, intercept, self._T, self._G, self._lam, self._fstate, self._istate,
                beta_prior, phi, prior, update, flat["gamma"], flat["mean"], flat["logp"],
                flat["q"], flat["maha"], flat["logrel"], missing, tap_px, fill_lo, fill_hi,
                suspect,
            )
        self.position = stop
        return ScanChunk(start, stop, self._chunk_outputs(start, stop))

    def _chunk_outputs(self, start, stop):
        ws = self._ws
        out = {}
        for k in self.outputs:
            if self.stream:
                width = self._width[k]
                out[k] = self._flat[k][: (stop - start) * ws * width].reshape(
                    (stop - start, ws) + self._tail[k])
            else:
                out[k] = scan_view(self._image(k), self.direction)[start:stop]
        return out

    def _image(self, k):
        h, w = self._shape
        return self._flat[k].reshape((h, w) + self._tail[k])

    def result(self):
        """The outputs and statistics after the rows scanned so far.

        Returns
        -------
        ScanResult
            What :func:`scan` returns (for a streaming scan, the final
            statistics only: its outputs went out chunk by chunk).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import Context
        >>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
        >>> s = RecursiveScan(y, Context.spatial([[0, 1]], 1), prior=np.ones(2))
        >>> while not s.done:
        ...     _ = s.advance(3)
        >>> s.result()["count"]
        56
        """
        result = ScanResult() if self.stream else ScanResult(
            {k: self._image(k) for k in self.outputs})
        T = np.empty_like(self._T)
        finish_factor(self._T, float(self._fstate[0]), T)
        result.update(T=T, G=self._G.copy(), lam=self._lam.copy(),
                      beta=float(self._fstate[1]), count=int(self._fstate[2]))
        return result


_EMPTY = np.empty(0)


def _iter_rows(scanner, chunk_rows=None, stage_name="scan"):
    """Advance a scanner to its end, a Progress record after each chunk."""
    while not scanner.done:
        chunk = scanner.advance(chunk_rows)
        yield Progress(stage_name, chunk.stop / scanner.rows,
                       f"{scanner.direction} scan: rows {chunk.stop}/{scanner.rows}")


def iter_scan(
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
    chunk_rows=None,
):
    """Run the recursive square-root estimator over an image, as a job.

    The generator form of :func:`scan`, with the same parameters and result:
    the scan runs in chunks of rows (one ``nogil`` kernel call each, about
    0.1-0.25 s of work) with a yield between them, and its result is, bit for
    bit, the one-call scan's (the whole estimator state carries over).

    Parameters
    ----------
    data : (H, W, C) ndarray of float64
        C-contiguous, already centred; modified in place only where
        ``missing`` asks for fills.
    context : Context
        What goes into ``X_r`` and ``Y_r``.
    direction : {'down', 'up', 'right', 'left'}, optional
        The scan direction.
    forgetting : float in (0, 1], optional
        The forgetting factor ``phi``.
    intercept : bool, optional
        Add a constant regressor.
    prior : (n,) array_like, optional
        Diagonal of ``V_0``.
    initial : tuple, optional
        ``(U0, beta0)`` start statistics.
    update : bool, optional
        False predicts with fixed statistics.
    outputs : subset of {'gamma', 'mean', 'logp', 'q', 'maha', 'logrel'}, optional
        The per-pixel arrays to return.
    missing : (H, W) array of bool or uint8, optional
        Pixels to fill in place.
    fill_range : tuple of 2 arrays of d values, optional
        Bounds of the filled values.
    suspect_logrel : float <= 0, optional
        Outlier threshold of suspect pixels.
    chunk_rows : int, optional
        Scan rows per chunk (default: about 0.1-0.25 s of work).

    Returns
    -------
    ScanResult
        What :func:`scan` returns.

    Yields
    ------
    Progress
        Stage ``"scan"`` after each chunk, its fraction the rows done,
        message like ``"down scan: rows 512/2048"``.

    Raises
    ------
    ValueError
        As :func:`scan`.

    Notes
    -----
    Fills (``missing``) carry over between chunks like the statistics: the
    conditional means are written into ``data`` as the scan reaches them,
    and later chunks read them as neighbours.

    See Also
    --------
    scan : The same, run to its end.
    RecursiveScan : The chunks by hand, or streamed.

    Examples
    --------
    Another job runs a scan as one of its stages (a Cancel closes it between
    two chunks):

    >>> import numpy as np
    >>> from car_napari._progress import drain, stage
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((64, 32, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
    >>> def job():
    ...     res = yield from stage(iter_scan(y, ctx, prior=np.full(3, 1e-6),
    ...                                      outputs=("mean",), chunk_rows=16), 0.0, 0.5)
    ...     return res["mean"]
    >>> records = []
    >>> mean = drain(job(), records.append)
    >>> len(records), records[0].message, records[-1].fraction
    (4, 'down scan: rows 16/64', 0.5)
    """
    scanner = RecursiveScan(
        data, context, direction=direction, forgetting=forgetting, intercept=intercept,
        prior=prior, initial=initial, update=update, outputs=outputs, missing=missing,
        fill_range=fill_range, suspect_logrel=suspect_logrel,
    )
    yield from _iter_rows(scanner, chunk_rows)
    return scanner.result()


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
    scanner = RecursiveScan(
        data, context, direction=direction, forgetting=forgetting, intercept=intercept,
        prior=prior, initial=initial, update=update, outputs=outputs, missing=missing,
        fill_range=fill_range, suspect_logrel=suspect_logrel,
    )
    scanner.advance(scanner.rows)  # one kernel call
    return scanner.result()


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

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Grey or multichannel image; any dtype (integers are scaled to [0, 1]).
    neighbourhood : int or (eta, 2) array of int, optional
        Order of the hierarchical causal neighbourhood, or explicit offsets.
    forgetting : float in [0.5, 1], optional
        Exponential forgetting factor ``phi``.
    direction : {'down', 'up', 'right', 'left'}, optional
        Where the scan moves.
    channel_axis : int or None, optional
        Axis of the channels; None for a grey image.
    prior : float, optional
        Strength of the prior relative to one pixel's data.
    warm_start : bool, optional
        Start the scan from the whole image's statistics (see
        :func:`local_parameters`).
    chunk_rows : int, optional
        Scan rows per chunk (default: about 0.1-0.25 s of work).

    Returns
    -------
    (H, W, d, d*eta) ndarray of float64
        What :func:`local_parameters` returns.

    Yields
    ------
    Progress
        Stage ``"scan"`` after each chunk of rows, its fraction the rows
        done, message like ``"down scan: rows 512/2048"``.

    Raises
    ------
    ValueError
        As :func:`local_parameters`.
    TypeError
        As :func:`local_parameters`.

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
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    prior = check_real(prior, "prior", low=0.0, low_open=True)
    if not isinstance(warm_start, (bool, np.bool_)):
        raise TypeError(f"warm_start must be True or False; got {warm_start!r}.")
    data = as_channel_last_float(image, channel_axis=channel_axis)
    context = Context.spatial(offsets, data.shape[2])
    check_size(np.empty(scan_shape(data.shape, direction)), context.reach)
    summary = summarize(data)
    check_not_constant(data, summary=summary)
    data -= summary.mean
    res = yield from iter_adaptive_scan(
        data, context, summary.var, forgetting=float(forgetting), direction=direction,
        prior=prior, warm_start=warm_start, outputs=("gamma",), chunk_rows=chunk_rows)
    return res["gamma"]


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
    scanner = adaptive_scanner(centred, context, channel_var, forgetting=forgetting,
                               direction=direction, prior=prior, warm_start=warm_start,
                               outputs=outputs)
    scanner.advance(scanner.rows)  # one kernel call
    return scanner.result()


def adaptive_scanner(centred, context, channel_var, *, forgetting, direction, prior=1e-6,
                     warm_start=True, outputs=("gamma",), stream=False, start=None):
    """The scan of :func:`adaptive_scan` as a :class:`RecursiveScan`, to run in chunks.

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
        Not started; ``advance`` it to its end (yielding in between), then
        ``result()`` is what :func:`adaptive_scan` returns.

    Examples
    --------
    A job that keeps only a per-row summary of ``gamma`` (memory bounded by a
    chunk, whatever the image size), a yield after each chunk:

    >>> import numpy as np
    >>> from car_napari._progress import Progress, drain
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((64, 40, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
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
    >>> bool(np.array_equal(down, adaptive_scan(y, ctx, [1.0], forgetting=0.99,
    ...                     direction="down", outputs=("mean",))["mean"], equal_nan=True))
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


def iter_adaptive_scan(centred, context, channel_var, *, forgetting, direction, prior=1e-6,
                       warm_start=True, outputs=("gamma",), chunk_rows=None):
    """The scan of :func:`adaptive_scan` as a job: Progress per chunk of rows.

    The generator form of :func:`adaptive_scan`, with the same parameters
    and, bit for bit, the same result.

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
    chunk_rows : int, optional
        Scan rows per chunk (default: about 0.1-0.25 s of work).

    Returns
    -------
    ScanResult
        What :func:`adaptive_scan` returns.

    Yields
    ------
    Progress
        Stage ``"scan"`` after each chunk (see :func:`iter_scan`).

    Examples
    --------
    Inside a job, as one of its stages:

    >>> import numpy as np
    >>> from car_napari._progress import drain, stage
    >>> from car_napari.model import Context
    >>> y = np.random.default_rng(0).standard_normal((64, 40, 1))
    >>> ctx = Context.spatial([[0, 1], [1, 0]], 1)
    >>> def job():
    ...     res = yield from stage(iter_adaptive_scan(y, ctx, [1.0], forgetting=0.99,
    ...                                               direction="left"), 0.0, 0.8)
    ...     return res["gamma"]
    >>> drain(job()).shape
    (64, 40, 1, 2)
    """
    scanner = adaptive_scanner(centred, context, channel_var, forgetting=forgetting,
                               direction=direction, prior=prior, warm_start=warm_start,
                               outputs=outputs)
    yield from _iter_rows(scanner, chunk_rows)
    return scanner.result()


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
