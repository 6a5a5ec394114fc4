"""The conditional mean's solves (:mod:`._conditional`): ``Q_UU x = b`` batch
by batch of coupled holes, by a band Cholesky factorisation where the band is
narrow (scratches), else by SuperLU, on the job pool's threads."""

from __future__ import annotations

import math
from concurrent.futures import FIRST_COMPLETED, wait

import numpy as np
from numba import njit
from scipy import sparse
from scipy.sparse.linalg import spilu, splu

from .._progress import Progress, drain, stage
from .._threads import job_pool
from ._stencil import _csr_kernel, _iter_assemble

__all__ = ["iter_stencil_solve", "stencil_solve"]

# The solves go by batches of coupled groups of about SOLVE_UNKNOWNS
# unknowns, run on the job pool's threads, a record every
# SOLVE_RECORD_SECONDS while they run (a Cancel returns at the next record;
# a factorisation running finishes in its thread, its result dropped).
SOLVE_UNKNOWNS = 1 << 14
SOLVE_RECORD_SECONDS = 0.25
# The widest band (half-bandwidth, in unknowns) of a batch solved by the band
# Cholesky factorisation rather than SuperLU: on 640x480 RGB holes, the band
# solve is 3-5x faster on 3-8 px wide scratches (half-bandwidth 32-77), 1.2x
# at 221 (24 px wide) and slower from about 290 (32 px) on
BAND_WIDTH = 200


def _group_batches(groups, C):
    """Consecutive groups batched into solves of about :data:`SOLVE_UNKNOWNS`
    unknowns (a group never split)."""
    batches, start, size = [], None, 0
    for a, b in groups:
        if start is None:
            start = a
        size += (b - a) * C
        if size >= SOLVE_UNKNOWNS:
            batches.append((start, b))
            start, size = None, 0
    if start is not None:
        batches.append((start, groups[-1][1]))
    return batches


@njit(cache=True, nogil=True)
def _block_column(Q, block_rows, pixels, index, slots, start, p, t):
    """The column pixel (numbered from ``start``) of pixel ``p``'s ``t``-th
    block from the centre of ``slots`` on (see :func:`_assemble_kernel`):
    -1 where no unknown pixel lies or the block is all zero (left out, as
    the sparse matrix leaves it out)."""
    H, W = index.shape
    s = (slots.shape[0] - 1) // 2 + t
    qi, qj = pixels[p, 0] + slots[s, 0], pixels[p, 1] + slots[s, 1]
    if qi < 0 or qi >= H or qj < 0 or qj >= W or index[qi, qj] < 0:
        return -1
    row = block_rows[p]
    for b in range(Q.shape[2]):
        for c in range(Q.shape[3]):
            if Q[row, t, b, c] != 0.0:
                return index[qi, qj] - start
    return -1


@njit(cache=True, nogil=True)
def _block_bandwidth(Q, block_rows, pixels, index, slots, start, stop):
    """The half-bandwidth (in unknowns, pixel-major) of ``Q`` over the pixels
    ``start`` to ``stop`` (whole groups): the largest column less row of an
    entry of its upper triangle, all-zero blocks left out."""
    C = Q.shape[2]
    width = C - 1  # the diagonal blocks
    for p in range(start, stop):
        for t in range(1, Q.shape[1]):
            q = _block_column(Q, block_rows, pixels, index, slots, start, p, t)
            if q >= 0:
                width = max(width, (q - (p - start)) * C + C - 1)
    return width


@njit(cache=True, nogil=True)
def _band_cholesky(Q, block_rows, pixels, index, slots, start, stop, width, right):
    """Solve ``Q x = right`` in place over the pixels ``start`` to ``stop``
    (whole groups) for ``Q`` of half-bandwidth ``width``, by the band
    Cholesky factorisation ``Q = L L^T``; returns False (``right`` partly
    changed) if ``Q`` is not numerically positive definite there.

    ``L`` is kept by columns, ``band[j, t] = L[j + t, j]``: each update of
    a column by an earlier one is then a contiguous multiply-add (which the
    compiler vectorises), not a dot product. The band is read straight from
    the blocks from the centre on (the upper triangle of the pixel-major
    rows: the columns of the lower one)."""
    C = Q.shape[2]
    n = (stop - start) * C
    band = np.zeros((n, width + 1))
    for p in range(start, stop):
        u0 = (p - start) * C
        row = block_rows[p]
        for t in range(Q.shape[1]):
            q = _block_column(Q, block_rows, pixels, index, slots, start, p, t)
            if q < 0:
                continue
            for a in range(C):
                for c in range(a if t == 0 else 0, C):  # the diagonal block's upper half
                    band[u0 + a, q * C + c - u0 - a] = Q[row, t, a, c]
    for j in range(n):
        column = band[j]
        for k in range(max(0, j - width), j):
            earlier = band[k]
            off = j - k
            f = earlier[off]  # L[j, k]
            if f == 0.0:
                continue
            for t in range(width + 1 - off):
                column[t] -= f * earlier[off + t]
        if not column[0] > 0.0:
            return False
        pivot = math.sqrt(column[0])
        column[0] = pivot
        for t in range(1, width + 1):
            column[t] /= pivot
    m = right.shape[1]
    for j in range(n):  # L y = right
        for s in range(m):
            right[j, s] /= band[j, 0]
        for t in range(1, min(width, n - 1 - j) + 1):
            f = band[j, t]
            for s in range(m):
                right[j + t, s] -= f * right[j, s]
    for j in range(n - 1, -1, -1):  # L^T x = y
        for t in range(1, min(width, n - 1 - j) + 1):
            f = band[j, t]
            for s in range(m):
                right[j, s] -= f * right[j + t, s]
        for s in range(m):
            right[j, s] /= band[j, 0]
    return True


def _batch_csc(system, a, b, C):
    """``Q`` over the pixels ``a`` to ``b`` (whole groups) as a sparse
    matrix, the unknowns numbered from ``a``: its CSR arrays, which are its
    CSC arrays (``Q`` is symmetric)."""
    n = b - a
    S = len(system.slots)
    indptr = np.zeros(n * C + 1, np.int64)
    found = np.empty((n, S), np.uint8 if S <= 256 else np.int64)
    found_n = np.empty(n, np.int64)
    args = (system.blocks, system.block_rows, system.pixels, system.index, system.slots)
    _csr_kernel(*args, indptr, np.zeros(0, np.int64), np.zeros(0), True, a, b, found, found_n)
    np.cumsum(indptr, out=indptr)
    # 32-bit indices when they fit, as SciPy and SuperLU keep them (no conversion)
    small = max(indptr[-1], n * C) < np.iinfo(np.int32).max
    indices = np.empty(indptr[-1], np.int32 if small else np.int64)
    data = np.empty(indptr[-1])
    _csr_kernel(*args, indptr, indices, data, False, a, b, found, found_n)
    return sparse.csc_matrix((data, indices, indptr.astype(indices.dtype)),
                             shape=(n * C, n * C))


def _pixel_order(Q, C):
    """A fill-reducing order of the pixels of ``Q`` (``C`` unknowns each,
    consecutive; from :func:`_batch_csc`): SuperLU's minimum degree of the
    pixels' graph.

    SciPy's ``splu`` orders the columns holding the GIL (the factorisation
    itself releases it): for a batch of 20,000-30,000 unknowns,
    ``MMD_AT_PLUS_A`` held it 100-130 ms, and the viewer froze as long. The
    pixels' graph has ``C**2`` times fewer entries; its ordering holds the
    GIL 8-16 ms, and factorising ``Q`` in that order (a pixel's unknowns
    together) fills as much as ``Q``'s own minimum degree did (the entries
    of L + U 0.998 times theirs, median over the 42 SuperLU batches of the
    4000x4000 film scan; at most 1.011).
    The graph: ``Q`` keeps every block it holds whole (C x C entries, a
    pixel's first unknown's row holding one entry per block first), so the
    first entry of each block of the first unknowns' rows is an edge; its
    matrix (-1 per edge, the degree on the diagonal) is diagonally
    dominant: SuperLU needs no pivoting. Over those batches, in one thread,
    the ordering takes 1.2-1.3 s, the permuting 0.9-1.0 s and the
    factorisations 12.9-14.1 s, against 14.0-15.7 s for the factorisations
    in ``Q``'s own order: 5-7 % more in all, for a viewer that does not
    freeze."""
    blocks = Q.indices.reshape(-1, C)[:, 0] // C  # the column pixel of each block
    block_at = Q.indptr // C
    first, edges = block_at[:-1:C], block_at[1::C] - block_at[:-1:C]  # first unknowns' rows
    ends = np.cumsum(edges)
    neighbours = blocks[np.repeat(first - (ends - edges), edges) + np.arange(ends[-1])]
    rows = np.repeat(np.arange(len(edges)), edges)
    values = np.where(neighbours == rows, edges[rows].astype(np.float64), -1.0)
    indptr = np.concatenate([[0], ends]).astype(Q.indptr.dtype)
    graph = sparse.csc_matrix((values, neighbours.astype(Q.indices.dtype), indptr),
                              shape=(len(edges), len(edges)))
    # the ordering is all that is wanted: an incomplete factorisation that
    # drops every entry costs half a complete one, and orders the same
    ordered = spilu(graph, drop_tol=1e3, fill_factor=1.0, permc_spec="MMD_AT_PLUS_A",
                    diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    return np.argsort(ordered.perm_c)


def _symmetric_permuted(Q, order):
    """``Q[order][:, order]`` of the symmetric CSC ``Q``, by its CSR twin (the
    same arrays): row then column gathers, the result's CSR arrays its CSC."""
    rows = sparse.csr_matrix((Q.data, Q.indices, Q.indptr), shape=Q.shape)[order][:, order]
    return sparse.csc_matrix((rows.data, rows.indices, rows.indptr), shape=Q.shape)


def _unknowns_order(pixel_order, C):
    """The unknowns of the pixels in ``pixel_order``, each pixel's ``C`` together."""
    return (pixel_order[:, None] * C + np.arange(C)).ravel()


def _solve_block(system, a, b, C):
    """Solve ``Q x = rhs`` and ``Q x_s = z_s`` over the pixels ``a`` to
    ``b`` (whole groups).

    A narrow band (a scratch: its pixels in raster order couple only with
    pixels a few rows away) is solved by a band Cholesky factorisation,
    3-5 times faster than SuperLU there; any other by SuperLU, in the
    order of :func:`_pixel_order`."""
    rhs, z = system.rhs, system.z
    right = rhs[a:b].reshape(-1, 1)
    if z.shape[1]:
        right = np.concatenate([right, z[a:b].transpose(0, 2, 1).reshape(-1, z.shape[1])],
                               axis=1)
    args = (system.blocks, system.block_rows, system.pixels, system.index, system.slots, a, b)
    x = None
    width = _block_bandwidth(*args)
    if width <= BAND_WIDTH:
        x = np.array(right, order="C")
        if not _band_cholesky(*args, width, x):
            x = None  # not positive definite in floating point: SuperLU pivots
    if x is None:
        Q = _batch_csc(system, a, b, C)
        order = _unknowns_order(_pixel_order(Q, C), C)
        lu = splu(_symmetric_permuted(Q, order), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                  options=dict(SymmetricMode=True))
        x = np.empty_like(right)
        x[order] = lu.solve(right[order])
    values = x[:, 0].reshape(-1, C)
    draws = x[:, 1:].reshape(b - a, C, -1).transpose(0, 2, 1)
    return values, draws


def _iter_solve(system, C, message):
    """Solve a :class:`_System` group batch by group batch, in threads (the
    factorisation releases the GIL), with a record every
    :data:`SOLVE_RECORD_SECONDS` while one runs: ``(values (n, d), draws (n,
    probes, d))``, draws of ``N(0, Q^-1)``."""
    n = system.rhs.shape[0]
    values = np.empty((n, C))
    draws = np.empty((n, system.z.shape[1], C))
    batches = _group_batches(system.groups, C)
    if len(batches) == 1 and (batches[0][1] - batches[0][0]) * C < SOLVE_UNKNOWNS:
        a, b = batches[0]  # small: no thread
        values[a:b], draws[a:b] = _solve_block(system, a, b, C)
        return values, draws
    pool = job_pool()
    done_pixels = 0
    if pool is None:  # one thread: the batches one after the other, a record after each
        for a, b in batches:
            values[a:b], draws[a:b] = _solve_block(system, a, b, C)
            done_pixels += b - a
            yield Progress("solve", done_pixels / max(n, 1), f"{message}, solving")
        return values, draws
    pending = {}
    try:
        pending = {pool.submit(_solve_block, system, a, b, C): (a, b) for a, b in batches}
        while pending:
            finished, _ = wait(pending, timeout=SOLVE_RECORD_SECONDS,
                               return_when=FIRST_COMPLETED)
            for future in finished:
                a, b = pending.pop(future)
                values[a:b], draws[a:b] = future.result()
                done_pixels += b - a
            yield Progress("solve", done_pixels / max(n, 1), f"{message}, solving")
    finally:  # a Cancel: the batches not started are dropped, a running one finishes
        for future in pending:
            future.cancel()
    return values, draws


def iter_stencil_solve(frame, unknown, row_sets, tile, *, probes=0, seed=0,
                       message="frame"):
    """:func:`stencil_solve` as a job (records while the solves run), with
    ``probes`` draws of the conditional distribution's fluctuation: returns
    ``(values, draws, diagonal)``, (n, d), (n, probes, d) and (n, d, d) in
    ``np.nonzero(unknown)`` order: the draws have covariance ``Q_UU^-1``;
    ``diagonal`` is the diagonal blocks of ``Q_UU``."""
    values, draws, diagonal, _ = yield from _iter_stencil_system(
        frame, unknown, row_sets, tile, probes=probes, seed=seed, message=message)
    return values, draws, diagonal


def _iter_stencil_system(frame, unknown, row_sets, tile, *, probes=0, seed=0,
                         message="frame", reuse=None):
    """:func:`iter_stencil_solve`, returning its :class:`_System` too;
    ``reuse``: see :func:`_iter_assemble`."""
    C = frame.shape[2]
    system = yield from stage(_iter_assemble(frame, unknown, row_sets, tile, probes=probes,
                                             seed=seed, reuse=reuse), 0.0, 0.3,
                              name="solve", prefix=f"{message}, ")
    yield Progress("solve", 0.3, f"{message}, solving")
    values, draws = yield from stage(_iter_solve(system, C, message), 0.3, 1.0)
    ui, uj = np.nonzero(unknown)
    order = np.full(unknown.shape, -1, np.int64)
    order[system.pixels[:, 0], system.pixels[:, 1]] = np.arange(len(system.pixels))
    at = order[ui, uj]
    return values[at], draws[at], system.diagonal[at], system


def stencil_solve(frame, unknown, row_sets, tile):
    """Least-squares values of the ``unknown`` pixels for residual rows
    ``w_r = sum_k coeffs[t, k] Y_{r - offsets[k]} + constant[t] (+ extra[r])``.

    ``row_sets``: a list of ``(offsets, coeffs, constant, extra, border)``:
    ``coeffs`` (ty, tx, K, d, d), ``constant`` (ty, tx, d), ``t`` the tile of
    ``r``; rows are every ``r`` with all taps in the frame and at least one
    tap unknown. ``extra`` (H, W, d) or None. ``border``: ``(G, c)``, (ty,
    tx, d, d) and (ty, tx, d), the row ``G Y_r + c`` of an unknown pixel that
    has no full row, or None. Returns the (n_unknown, d) values in
    ``np.nonzero(unknown)`` order: ``x = -(M^T M)^-1 M^T c``. The normal
    equations ``Q_UU = M^T M`` are assembled row by row (a compiled kernel)
    and solved per batch of coupled groups of unknown pixels (``Q_UU`` is
    block diagonal over them): by a band Cholesky factorisation where the
    batch's band is narrow (scratches), else by a sparse LU factorisation
    (SuperLU)."""
    return drain(iter_stencil_solve(frame, unknown, row_sets, tile))[0]
