"""Recursive estimation along the four scan directions ((14.26)-(14.32),
section 14.2.1, docs/model.md): the square-root estimator's scan
(:class:`RecursiveScan`, :func:`scan`); the adaptive estimator built on it
(its prior and warm start, the local parameters) is :mod:`.adaptive`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import Progress
from ._doc_sections import EXAMPLES_FIELD
from ._kernels import finish_factor, recursive_scan
from .directions import DIRECTIONS, check_direction, scan_shape, scan_view, unscan_view

__all__ = ["scan", "iter_scan", "RecursiveScan", "ScanChunk", "ScanResult", "default_prior",
           "scan_work", "DIRECTIONS", "scan_shape", "scan_view", "unscan_view"]


def _geometry(shape, direction, context):
    """Strides that map scan position (a, b) to the original (H, W, C) array."""
    check_direction(direction)
    h, w, c = shape
    if direction == "down":
        hs, ws, i0, j0, ia, ib, ja, jb = h, w, 0, 0, 1, 0, 0, 1
    elif direction == "up":
        hs, ws, i0, j0, ia, ib, ja, jb = h, w, h - 1, 0, -1, 0, 0, 1
    elif direction == "right":
        hs, ws, i0, j0, ia, ib, ja, jb = w, h, 0, 0, 0, 1, 1, 0
    else:  # 'left'
        hs, ws, i0, j0, ia, ib, ja, jb = w, h, 0, w - 1, 0, 1, -1, 0
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


# the Parameters of RecursiveScan, iter_scan and scan, written once
_SCAN_PARAMETERS = """
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
"""

# the chunk_rows entry of the jobs that run a scan in chunks (after their Parameters)
_CHUNK_ROWS_PARAMETER = """chunk_rows : int, optional
    Scan rows per chunk (default: about 0.1-0.25 s of work).
"""


@shared_parameters(_SCAN_PARAMETERS)
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

    {parameters}
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
    car_napari.model.adaptive.adaptive_scanner : The same with the adaptive estimator's
        prior and warm start.

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

    def run(self):
        """Scan the rows left in one kernel call and return :meth:`result`.

        Returns
        -------
        ScanResult
            What :func:`scan` returns.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import Context
        >>> y = np.random.default_rng(0).standard_normal((8, 8, 1))
        >>> RecursiveScan(y, Context.spatial([[0, 1]], 1), prior=np.ones(2)).run()["count"]
        56
        """
        self.advance(self.rows - self.position)
        return self.result()

    @shared_sections(examples_field=EXAMPLES_FIELD)
    def iter_run(self, chunk_rows=None):
        """:meth:`run` as a job: the rows left in chunks, a record after each.

        Parameters
        ----------
        chunk_rows : int, optional
            Scan rows per chunk (default :attr:`chunk_rows`: about
            0.1-0.25 s of work).

        Yields
        ------
        Progress
            Stage ``"scan"``, message ``"<direction> scan: rows k/n"``.

        Returns
        -------
        ScanResult
            What :meth:`run` returns, bit for bit.

        {examples_field}
        >>> scanner = RecursiveScan(y, Context.spatial([[0, 1]], 1), prior=np.ones(2))
        >>> drain(scanner.iter_run(chunk_rows=3))["count"]
        56
        """
        while not self.done:
            chunk = self.advance(chunk_rows)
            yield Progress("scan", chunk.stop / self.rows,
                           f"{self.direction} scan: rows {chunk.stop}/{self.rows}")
        return self.result()


_EMPTY = np.empty(0)




@shared_sections(parameters=_SCAN_PARAMETERS + _CHUNK_ROWS_PARAMETER,
                 raises=raises_as("scan", "ValueError"))
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

    {parameters}

    Returns
    -------
    ScanResult
        What :func:`scan` returns.

    Yields
    ------
    Progress
        Stage ``"scan"`` after each chunk, its fraction the rows done,
        message like ``"down scan: rows 512/2048"``.

    {raises}

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
    return (yield from scanner.iter_run(chunk_rows))


@shared_parameters(_SCAN_PARAMETERS)
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

    {parameters}

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
    return scanner.run()  # one kernel call


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
