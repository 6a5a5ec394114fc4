"""The sparse normal equations of the conditional mean (:mod:`._conditional`):
``Q_UU`` and the right-hand sides assembled row by row by compiled kernels, in
compressed form, grouped into the coupled holes."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import ndimage

from .._progress import Progress
from ._local_fits import _dilate

_ASSEMBLE_ROWS = 1 << 15  # rows of the normal equations added between records


@njit(cache=True, nogil=True)
def _assemble_kernel(frame, index, offsets, coeffs, pairs, constant, extra, tile, slot_of,
                     reach2, rows, border, border_G, border_c, probes, state, Q, rhs, z,
                     with_q=True):
    """Add one set of whitened rows ``w_r = sum_k G_k Y_{r - s_k} + c (+
    extra_r)`` (every ``r`` with all taps inside the frame and one of them
    unknown) to the normal equations of the unknown pixels: ``Q[p, slot]
    += G_k^T G_l`` (``pairs[t, k, l]``) for unknown ``p = r - s_k`` and ``q
    = r - s_l`` (``slot`` the offset ``q - p`` in ``slot_of``), ``rhs[p] -=
    G_k^T (known part of w_r)``, and ``z[p, s] += G_k^T n_{r, s}`` for
    ``probes`` independent random signs ``n_{r, s}`` per channel (so that
    ``z`` has covariance ``Q``). ``rows`` (n, 2): the pixels ``r`` to visit,
    in raster order (those within ``reach`` of an unknown pixel: the others
    touch none); a call may take a part of them, ``state`` (1,) carries the
    random signs' generator from call to call. With ``border``: instead,
    an unknown pixel of ``rows`` without a full row gets ``border_G Y_p +
    border_c``. Without ``with_q``: ``rhs`` only (``Q`` and ``z`` left
    alone; no random signs drawn).

    ``Q`` holds the slots from the centre on only (offsets ``q - p`` at or
    after (0, 0) in ``slot_of``'s sorted order, ``Q[p, slot - centre]``):
    the block of the opposite offset is its transpose (``pairs[t, l, k] =
    pairs[t, k, l]^T``, added by the same rows in the same order)."""
    H, W, C = frame.shape
    K = offsets.shape[0]
    centre = slot_of[reach2, reach2]
    in_i, in_j, out_i, out_j = 0, 0, H, W
    for k in range(K):
        in_i = max(in_i, offsets[k, 0])
        out_i = min(out_i, H + offsets[k, 0])
        in_j = max(in_j, offsets[k, 1])
        out_j = min(out_j, W + offsets[k, 1])
    tap = np.empty(K, np.int64)
    kc = np.empty(C)
    noise = np.empty((probes, C))
    use_extra = extra.shape[0] == H
    rng = state[0]
    if border:
        for n in range(rows.shape[0]):
            i, j = rows[n, 0], rows[n, 1]
            p = index[i, j]
            if p < 0 or (in_i <= i < out_i and in_j <= j < out_j):
                continue
            ti = i // tile
            tj = j // tile
            if not with_q:
                for a in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * border_c[ti, tj, b]
                    rhs[p, a] -= acc
                continue
            for s in range(probes):
                for a in range(C):
                    rng ^= rng << np.uint64(13)
                    rng ^= rng >> np.uint64(7)
                    rng ^= rng << np.uint64(17)
                    noise[s, a] = 1.0 if (rng >> np.uint64(40)) & np.uint64(1) else -1.0
            for a in range(C):
                acc = 0.0
                for b in range(C):
                    acc += border_G[ti, tj, b, a] * border_c[ti, tj, b]
                rhs[p, a] -= acc
                for s in range(probes):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * noise[s, b]
                    z[p, s, a] += acc
                for c in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += border_G[ti, tj, b, a] * border_G[ti, tj, b, c]
                    Q[p, 0, a, c] += acc
        state[0] = rng
        return
    # the slot of each pair of taps (their offsets are fixed) and the
    # blocks of Q and of the pairs as rows of C * C values
    slot_kk = np.empty((K, K), np.int64)
    for k in range(K):
        for k2 in range(K):
            slot_kk[k, k2] = slot_of[reach2 + offsets[k, 0] - offsets[k2, 0],
                                     reach2 + offsets[k, 1] - offsets[k2, 1]]
    CC = C * C
    S = Q.shape[1]
    Qf = Q.reshape(Q.shape[0] * S, CC)
    ty, tx = pairs.shape[0], pairs.shape[1]
    pf = pairs.reshape(ty * tx * K * K, CC)
    # G_k^T n for each of the 2^d sign vectors n, per tile and tap: a draw's
    # term is then looked up (the same products and sums, made once)
    patterns = 1 << C
    signed = np.zeros((0, 0, K, patterns, C))
    pattern = np.zeros(probes, np.int64)
    if with_q and probes:
        signed = np.empty((coeffs.shape[0], coeffs.shape[1], K, patterns, C))
        for t0 in range(coeffs.shape[0]):
            for t1 in range(coeffs.shape[1]):
                for k in range(K):
                    for pat in range(patterns):
                        for a in range(C):
                            acc = 0.0
                            for b in range(C):
                                acc += coeffs[t0, t1, k, b, a] * (1.0 if (pat >> b) & 1 else -1.0)
                            signed[t0, t1, k, pat, a] = acc
    for n in range(rows.shape[0]):
        i, j = rows[n, 0], rows[n, 1]
        if not (in_i <= i < out_i and in_j <= j < out_j):
            continue
        hit = False
        for k in range(K):
            tap[k] = index[i - offsets[k, 0], j - offsets[k, 1]]
            if tap[k] >= 0:
                hit = True
        if not hit:
            continue
        ti = i // tile
        tj = j // tile
        for a in range(C):
            kc[a] = constant[ti, tj, a] + (extra[i, j, a] if use_extra else 0.0)
        for k in range(K):
            if tap[k] < 0:
                pi = i - offsets[k, 0]
                pj = j - offsets[k, 1]
                for a in range(C):
                    acc = 0.0
                    for b in range(C):
                        acc += coeffs[ti, tj, k, a, b] * frame[pi, pj, b]
                    kc[a] += acc
        if with_q:
            for s in range(probes):
                pat = 0
                for a in range(C):  # xorshift64: a random sign
                    rng ^= rng << np.uint64(13)
                    rng ^= rng >> np.uint64(7)
                    rng ^= rng << np.uint64(17)
                    if (rng >> np.uint64(40)) & np.uint64(1):
                        pat |= 1 << a
                pattern[s] = pat
        tile_pairs = (ti * tx + tj) * K * K
        for k in range(K):
            p = tap[k]
            if p < 0:
                continue
            for a in range(C):
                acc = 0.0
                for b in range(C):
                    acc += coeffs[ti, tj, k, b, a] * kc[b]
                rhs[p, a] -= acc
            if not with_q:
                continue
            for s in range(probes):
                for a in range(C):
                    z[p, s, a] += signed[ti, tj, k, pattern[s], a]
            row_p = p * S - centre
            for k2 in range(K):
                if tap[k2] < 0 or slot_kk[k, k2] < centre:
                    continue
                q_row = row_p + slot_kk[k, k2]
                pair_row = tile_pairs + k * K + k2
                for m in range(CC):
                    Qf[q_row, m] += pf[pair_row, m]
    state[0] = rng


@njit(cache=True, nogil=True)
def _csr_kernel(Q, block_rows, pixels, index, slots, indptr, indices, data, count_only,
                start, stop, found, found_n):
    """The CSR pattern (``count_only``: the entries per row into
    ``indptr[1:]``) or the entries of ``Q`` (per unknown pixel, per slot of
    ``slots`` (S, 2) offsets, a C x C block; pixel ``p``'s blocks are
    ``Q[block_rows[p]]``), the unknown pixels (their ``pixels``
    coordinates) in ``index`` order, blocks that are all zero left out; of
    the pixels ``start`` to ``stop`` (whole groups: coupled with no other
    pixel), numbered from ``start``. The counting pass keeps the slots of
    each pixel's nonzero blocks (``found`` (stop - start, S), ``found_n``
    (stop - start,)) for the other. ``Q`` holds the slots from the centre
    of ``slots`` on (see :func:`_assemble_kernel`); a slot before it is
    the transpose of the opposite slot's block of the column pixel."""
    S, C = slots.shape[0], Q.shape[2]
    centre = (S - 1) // 2
    H, W = index.shape
    for p in range(start, stop):
        row = block_rows[p]
        lp = p - start
        if count_only:
            i, j = pixels[p, 0], pixels[p, 1]
            n = 0
            for s in range(S):
                qi, qj = i + slots[s, 0], j + slots[s, 1]
                if qi < 0 or qi >= H or qj < 0 or qj >= W:
                    continue
                q = index[qi, qj]
                if q < 0:
                    continue
                if s >= centre:
                    r, t = row, s - centre
                else:
                    r, t = block_rows[q], S - 1 - s - centre
                nonzero = False
                for b in range(C):
                    for c in range(C):
                        if Q[r, t, b, c] != 0.0:
                            nonzero = True
                            break
                    if nonzero:
                        break
                if nonzero:
                    found[lp, n] = s
                    n += 1
            found_n[lp] = n
            for a in range(C):
                indptr[lp * C + a + 1] = n * C
            continue
        n = found_n[lp]
        i, j = pixels[p, 0], pixels[p, 1]
        for a in range(C):
            at = indptr[lp * C + a]
            for t in range(n):
                s = found[lp, t]
                q = index[i + slots[s, 0], j + slots[s, 1]]
                if s >= centre:
                    for c in range(C):
                        indices[at] = (q - start) * C + c
                        data[at] = Q[row, s - centre, a, c]
                        at += 1
                else:
                    r, u = block_rows[q], S - 1 - s - centre
                    for c in range(C):
                        indices[at] = (q - start) * C + c
                        data[at] = Q[r, u, c, a]
                        at += 1


class _System(NamedTuple):
    """The normal equations ``Q x = rhs`` of the unknown pixels, pixels in
    ``index`` order grouped by coupled component: ``groups`` the (start,
    stop) pixel ranges (``Q`` is block diagonal over them); ``z`` (n, probes,
    d): draws of ``N(0, Q)``. ``Q`` is kept by blocks (``blocks``): each
    batch of groups is solved from them (:func:`_solve_block`)."""

    slots: np.ndarray  # (S, 2) the offsets q - p of the blocks, sorted
    rhs: np.ndarray
    z: np.ndarray
    groups: list
    pixels: np.ndarray  # (n, 2) the unknown pixels in index order
    diagonal: np.ndarray  # (n, d, d) the diagonal blocks of Q
    blocks: np.ndarray  # (m, slots, d, d) Q by pixel and offset from the centre on:
    # pixel p's at block_rows[p] (see _assemble_kernel)
    block_rows: np.ndarray  # (n,)
    index: np.ndarray  # (H, W) a pixel's place in index order, -1 if known


def _seed_state(seed):
    """The xorshift64 state of :func:`_assemble_kernel`'s random signs for ``seed``."""
    return (int(seed) * 6364136223846793005 + 1442695040888963407) % (1 << 64)


def _iter_assemble(frame, unknown, row_sets, tile, probes=0, seed=0, reuse=None):
    """The normal equations of the ``unknown`` pixels (a :class:`_System`),
    as a job: a record (stage ``"assembly"``) after each part of a set of
    rows. ``Q`` is kept by blocks; each batch's solve reads them
    (:func:`_solve_block`).

    ``reuse``: the :class:`_System` of a superset of the unknown pixels
    under the same rows. ``Q`` between two pixels sums the rows that touch
    both, the same rows (in the same order) whatever else is unknown: its
    blocks are taken from there, and only ``rhs`` is assembled."""
    H, W, C = frame.shape
    offsets_all = [np.asarray(r[0], np.int64) for r in row_sets]
    reach = max(int(np.abs(o).max()) if len(o) else 0 for o in offsets_all)
    reach2 = 2 * reach
    # pixels coupled through a row lie within 2 reach of each other: a group
    # is a connected component of the damage grown by ``reach``
    if reach:
        grown = _dilate(unknown, reach, square=True)
    else:
        grown = unknown
    yield Progress("assembly", 0.0, "assembling")
    labels, n_groups = ndimage.label(grown, structure=np.ones((3, 3), bool))
    yield Progress("assembly", 0.0, "assembling")
    ui, uj = np.nonzero(unknown)
    lab = labels[ui, uj]
    order = np.argsort(lab, kind="stable")  # row-major within a group
    ui, uj, lab = ui[order], uj[order], lab[order]
    n_u = len(ui)
    index = np.full((H, W), -1, np.int64)
    index[ui, uj] = np.arange(n_u)
    starts = np.searchsorted(lab, np.arange(1, n_groups + 2))
    groups = [(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True) if b > a]
    diffs = sorted({(int(a[0] - b[0]), int(a[1] - b[1])) for o in offsets_all
                    for a in o for b in o} | {(0, 0)})
    slots = np.array(diffs, np.int64)
    slot_of = np.full((2 * reach2 + 1, 2 * reach2 + 1), -1, np.int64)
    slot_of[slots[:, 0] + reach2, slots[:, 1] + reach2] = np.arange(len(slots))
    # sorted and symmetric: the opposite of slot s is len - 1 - s; Q keeps
    # the slots from the centre on (the others are their transposes)
    centre = (len(slots) - 1) // 2
    del labels
    yield Progress("assembly", 0.0, "assembling")
    rows = np.stack(np.nonzero(grown), axis=1).astype(np.int64)  # raster order
    del grown
    if reuse is not None:
        at = reuse.index[ui, uj]
        if len(at) and at.min() < 0:
            raise ValueError("reuse must be the system of a superset of the unknown pixels.")
        Q, block_rows = reuse.blocks, reuse.block_rows[at]  # read in place, not copied
        probes = 0
    else:
        Q, block_rows = np.zeros((n_u, len(slots) - centre, C, C)), np.arange(n_u)
    rhs = np.zeros((n_u, C))
    z = np.zeros((n_u, probes, C))
    frame = np.ascontiguousarray(frame, np.float64)
    parts = [(a, min(a + _ASSEMBLE_ROWS, len(rows))) for a in range(0, len(rows), _ASSEMBLE_ROWS)]
    steps = sum(2 if r[4] is not None else 1 for r in row_sets) * len(parts) + 1
    done = 0
    for number, (offsets, coeffs, constant, extra, border) in enumerate(row_sets):
        coeffs = np.ascontiguousarray(coeffs, np.float64)
        constant = np.ascontiguousarray(constant, np.float64)
        extra = np.zeros((0, 0, C)) if extra is None else np.ascontiguousarray(extra, float)
        if border is None:
            bG, bc = np.zeros((0, 0, C, C)), np.zeros((0, 0, C))
        else:
            bG, bc = (np.ascontiguousarray(b, np.float64) for b in border)
        if reuse is None:
            pairs = np.ascontiguousarray(np.einsum("tukba,tulbc->tuklac", coeffs, coeffs))
        else:  # Q is known: the pairs are not read
            pairs = np.zeros((1, 1, *coeffs.shape[2:3] * 2, C, C))
        offsets = np.ascontiguousarray(offsets, np.int64)
        # xorshift64's state, seeded per set of rows, carried from part to part
        state = np.array([_seed_state(1 + 7919 * int(seed) + number)], np.uint64)
        for phase in (False, True) if border is not None else (False,):
            for a, b in parts:
                _assemble_kernel(frame, index, offsets, coeffs, pairs, constant, extra,
                                 int(tile), slot_of, reach2, rows[a:b], phase, bG, bc,
                                 int(probes), state, Q, rhs, z, reuse is None)
                done += 1
                yield Progress("assembly", done / steps, "assembling")
    pixels = np.stack([ui, uj], axis=1).astype(np.int64)
    return _System(slots, rhs, z, groups, pixels, Q[block_rows, 0], Q, block_rows, index)
