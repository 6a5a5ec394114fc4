"""Numba kernels: the recursive square-root CAR estimator and synthesis.

Every kernel is compiled with ``cache=True`` (a fast second start) and
``nogil=True`` (so a napari worker thread running it leaves the viewer
responsive). Kernels see flat C-ordered arrays plus integer strides, so one
compiled kernel serves all four scan directions without copying the image.

Square-root form ((14.26)-(14.29), section 14.2.2, docs/model.md): the inverse of the
regressors' data-gathering matrix is kept as ``P = V_x^{-1} = tau^2 S S^T``
with ``S`` upper triangular (stored transposed, ``T = S^T``) and ``tau`` a
scalar, and updated by Carlson's square-root measurement update; no inverse
is ever formed, so rounding cannot make it indefinite. Forgetting divides
``tau`` by ``phi`` instead of touching ``S``. ``gamma`` and ``lambda`` follow
the recursions of (14.26)-(14.32) with the gain that update yields.

Wind-up: in a flat region the data excite at most one direction while
forgetting inflates ``P`` in all others. We use stabilised forgetting,
``V(t) = phi^2 V(t-1) + (1 - phi^2) V_0 + z z^T``, which keeps ``V >= V_0``
(``P <= V_0^{-1}``). The ``(1 - phi^2) V_0`` term enters as pseudo-data,
round robin over the coordinates, scaled so the average amount is exact
(``x = a e_k, y = 0`` for a regressor coordinate, ``lambda += a^2 e_t e_t^T``
for a target one), which is what the prior ``V_0`` is. Every coordinate is
revisited before forgetting halves it (``phi^(2 period) >= 1/2``), so the
floor holds to a factor of two at any ``phi`` and any number of regressors.
"""


from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..._linalg import cholesky_logdet, mahalanobis

_RESCALE_ABOVE = 1e20  # keeps alpha0 = phi^2 / tau^2 far from underflow in Carlson
_FAST = {"reassoc", "contract", "arcp"}


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _carlson_update(T, v, w, coef, alpha0, start, p):
    """Carlson's square-root update of ``P = S S^T`` (``T = S^T`` lower).

    ``v = S^T x`` on entry (entries before ``start`` are zero); on exit ``T``
    holds the factor of ``P - P x x^T P / (alpha0 + x^T P x)`` and ``w = P x``
    (before the update). Returns ``alpha0 + x^T P x``. ``coef`` (2, p) is
    scratch: the running sums ``alpha_j`` are formed first so that the
    square roots and divisions are independent (pipelined, not a chain).
    """
    alpha = alpha0
    for j in range(start, p):
        coef[0, j] = alpha
        alpha += v[j] * v[j]
        coef[1, j] = alpha
    for j in range(start, p):
        inv_gamma = 1.0 / math.sqrt(coef[0, j] * coef[1, j])
        coef[0, j] = coef[0, j] * inv_gamma  # eta_j
        coef[1, j] = v[j] * inv_gamma  # zeta_j
    for i in range(p):
        w[i] = 0.0
    for j in range(start, p):
        eta = coef[0, j]
        zeta = coef[1, j]
        sigma = v[j]
        row = T[j]
        for i in range(j + 1):
            tau = row[i]
            row[i] = eta * tau - zeta * w[i]
            w[i] += tau * sigma
    return alpha


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _project(T, x, v, p):
    """v = S^T x = T x (T lower triangular); returns v^T v."""
    vv = 0.0
    for j in range(p):
        acc = 0.0
        row = T[j]
        for i in range(j + 1):
            acc += row[i] * x[i]
        v[j] = acc
        vv += acc * acc
    return vv


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _inject_prior(T, G, lam, v, w, coef, e, k0, amount, tau, p, d):
    """Add ``amount^2`` to coordinate ``k0`` of ``V`` as a pseudo-datum."""
    if k0 >= p:
        lam[k0 - p, k0 - p] += amount * amount
        return
    # x = amount e_k0, y = 0, no forgetting
    vv0 = 0.0
    for j in range(p):
        v[j] = amount * T[j, k0] if j >= k0 else 0.0
        vv0 += v[j] * v[j]
    for t in range(d):
        e[t] = -amount * G[t, k0]
    alpha = _carlson_update(T, v, w, coef, 1.0 / (tau * tau), k0, p)
    inv_alpha = 1.0 / alpha
    for t in range(d):
        g = e[t] * inv_alpha
        for k in range(p):
            G[t, k] += w[k] * g
    shrink = 1.0 / (1.0 + tau * tau * vv0)
    for t in range(d):
        for c in range(t + 1):
            lam[t, c] += shrink * e[t] * e[c]
            lam[c, t] = lam[t, c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def recursive_scan(
    data,
    geom,
    rows,
    out_geom,
    tap_off,
    tap_ch,
    target_off,
    intercept,
    T,
    G,
    lam,
    fstate,
    istate,
    beta_prior,
    phi,
    prior_diag,
    update,
    gamma_out,
    mean_out,
    logp_out,
    q_out,
    maha_out,
    logrel_out,
    missing,
    tap_px,
    fill_lo,
    fill_hi,
    suspect_logrel,
):
    """Scan rows ``rows[0] .. rows[1] - 1`` of an image, in one direction,
    with the recursive estimator, resuming from the state it is given.

    The whole estimator state lives in ``T, G, lam, fstate, istate`` and is
    updated in place, so consecutive calls over consecutive row ranges give,
    bit for bit, the scan of one call over their union: a long scan runs in
    chunks with a yield (a chance to cancel) between them. Nothing is
    allocated per pixel; the scratch vectors are allocated once per call.

    Parameters (all flat / contiguous)
    ----------------------------------
    data : float64[:] the (H, W, C) source array, raveled.
    geom : int64[12] ``Hs, Ws, base, sa, sb, base_px, sa_px, sb_px, a_lo, a_hi,
        b_lo, b_hi``: scan extent, element offset of scan pixel (a, b) in
        ``data`` as ``base + a*sa + b*sb`` (pixel index ``px`` likewise, used
        by ``missing``) and the rectangle of scan positions whose taps are
        all inside.
    rows : int64[2] the scan rows ``[start, stop)`` of this call.
    out_geom : int64[3] ``base, sa, sb`` of the outputs: pixel (a, b) writes
        output entry ``base + a*sa + b*sb`` (times its width). The pixel
        geometry of ``geom`` writes image-shaped outputs; ``(-start*Ws, Ws, 1)``
        writes this call's rows, in scan order, to a chunk-sized buffer.
    tap_off : int64[m] element offset of each tap from the pixel's channel 0.
    tap_ch : int64[m] channel of each tap. A pixel whose every tap equals its
        own channel's value at ``r`` (a flat neighbourhood: a clipped,
        saturated or padded region; probability zero under the model) carries
        no texture information: it neither updates nor forgets, so a texture
        after a flat background is estimated as if the background were absent.
    target_off : int64[d] channel of each modelled component.
    intercept : bool, append a constant 1 regressor (a local mean).
    T, G, lam : the statistics, updated in place: float64[p, p] lower factor
        with ``V_x^{-1} = tau^2 T^T T`` (p = m + intercept), G (d, p) gamma
        with the intercept column, lam (d, d) lambda.
    fstate : float64[3] ``[tau, beta, count]``, updated in place (start:
        ``[1, beta(0), 0]``).
    istate : int64[2] ``[tick, next_k]``: learned pixels counted for the
        prior re-injection schedule and the coordinate it injects next (the
        round robin position), updated in place (start: zeros).
    beta_prior : the prior ``beta``.
    phi : forgetting factor (1 = none).
    prior_diag : float64[p + d] ``V_0`` diagonal re-injected when ``phi < 1``.
    update : bool, False freezes the statistics (prediction by a fixed model).
    gamma_out : float64[N*d*m] or empty (N pixels addressed by ``out_geom``).
        Estimate after each pixel (carried over where the neighbourhood
        leaves the image).
    mean_out, logp_out, q_out, maha_out : float64[N*d], [N], [N], [N] or empty.
        One-step-ahead conditional mean, Student-t log density ((14.23)-(14.25)),
        ``q = 1 + X^T V_x^{-1} X`` and ``e^T lambda^{-1} e`` from the
        statistics before the pixel's update; NaN where the neighbourhood
        leaves the image.
    logrel_out : float64[N] or empty. Log of the predictive density relative
        to its peak (at the conditional mean): ``-(nu + d)/2 log(1 + maha/q)``,
        in (-inf, 0]; scale-free, so thresholds on it need no units.
    missing : uint8[N] or empty. Pixels to fill (section 14.7): their targets in
        ``data`` are overwritten by the conditional mean as the scan reaches
        them, so later pixels use them as neighbours; they never update the
        statistics, nor do pixels whose neighbourhood holds a missing pixel.
        A value of 2 marks a suspect known pixel (the edge of the damage):
        if, when the scan reaches it, it is an outlier of the predictive
        density (its log density relative to the peak, as ``logrel_out``,
        below ``suspect_logrel``), it is filled like a missing pixel and its
        entry becomes 1; otherwise it is kept and its entry becomes 0.
        ``missing`` is written to: pass a copy per scan.
    tap_px : int64[m] pixel-index offset of each tap (used with ``missing``).
    fill_lo, fill_hi : float64[d] bounds of the filled values (a chain of
        predictions through a long hole must not run away).
    suspect_logrel : float, the outlier threshold (<= 0) for suspect pixels.

    The final ``V_x^{-1}`` factor is ``tau * T`` (see ``finish_factor``).
    """
    Hs, Ws = geom[0], geom[1]
    base, sa, sb = geom[2], geom[3], geom[4]
    base_px, sa_px, sb_px = geom[5], geom[6], geom[7]
    a_lo, a_hi, b_lo, b_hi = geom[8], geom[9], geom[10], geom[11]
    out_base, out_sa, out_sb = out_geom[0], out_geom[1], out_geom[2]
    row_start, row_stop = max(rows[0], 0), min(rows[1], Hs)
    m = tap_off.shape[0]
    d = target_off.shape[0]
    p = m + (1 if intercept else 0)
    n = p + d

    tau = fstate[0]
    beta = fstate[1]
    count = fstate[2]
    tick = istate[0]
    next_k = istate[1]
    phi2 = phi * phi
    forget = phi < 1.0
    # Prior re-injection schedule: `per_event` coordinates every `every`
    # learned pixels, so each coordinate comes back within `revisit` pixels
    # (the time forgetting takes to halve it).
    every = 1
    per_event = 1
    if forget:
        revisit = math.log(2.0) / (-2.0 * math.log(phi))  # decay to 1/2 at most
        if n <= revisit:
            every = max(1, int(revisit // n))
        else:
            per_event = min(n, int(math.ceil(n / max(revisit, 1e-12))))
    period = n * every / per_event
    inject = np.empty(n)
    for k in range(n):
        inject[k] = math.sqrt(period * (1.0 - phi2) * prior_diag[k]) if forget else 0.0

    want_gamma = gamma_out.shape[0] > 0
    want_mean = mean_out.shape[0] > 0
    want_logp = logp_out.shape[0] > 0
    want_q = q_out.shape[0] > 0
    want_maha = maha_out.shape[0] > 0
    want_logrel = logrel_out.shape[0] > 0
    want_pred = want_mean or want_logp or want_q or want_maha or want_logrel
    fill = missing.shape[0] > 0

    x = np.empty(p)
    y = np.empty(d)
    v = np.empty(p)
    w = np.empty(p)
    coef = np.empty((2, p))
    e = np.empty(d)
    u = np.empty(d)
    L = np.zeros((d, d))
    log_pi = math.log(math.pi)

    for a in range(row_start, row_stop):
        for b in range(Ws):
            px = base_px + a * sa_px + b * sb_px
            po = out_base + a * out_sa + b * out_sb
            inside = a >= a_lo and a < a_hi and b >= b_lo and b < b_hi
            if not inside:
                if want_gamma:
                    o = po * d * m
                    for t in range(d):
                        for k in range(m):
                            gamma_out[o + t * m + k] = G[t, k]
                if want_mean:
                    for t in range(d):
                        mean_out[po * d + t] = np.nan
                if want_logp:
                    logp_out[po] = np.nan
                if want_q:
                    q_out[po] = np.nan
                if want_maha:
                    maha_out[po] = np.nan
                if want_logrel:
                    logrel_out[po] = np.nan
                continue

            pos = base + a * sa + b * sb
            flat = True
            for k in range(m):
                x[k] = data[pos + tap_off[k]]
                if x[k] != data[pos + tap_ch[k]]:
                    flat = False
            if intercept:
                x[m] = 1.0
            for t in range(d):
                y[t] = data[pos + target_off[t]]
                acc = 0.0
                for k in range(p):
                    acc += G[t, k] * x[k]
                e[t] = y[t] - acc
            learn = update and not flat
            hole = False
            if fill:
                hole = missing[px] != 0
                if missing[px] == 2:
                    # a suspect edge pixel: damaged when the model finds it improbable
                    sq = 1.0 + tau * tau * _project(T, x, v, p)
                    cholesky_logdet(lam, L, d)
                    smaha = mahalanobis(L, e, u, d)
                    srel = -0.5 * (beta - p + 2.0 + d) * math.log1p(smaha / sq)
                    hole = srel < suspect_logrel
                    missing[px] = 1 if hole else 0
                if hole:
                    # the conditional mean fills the pixel for the rest of the scan
                    for t in range(d):
                        y[t] = min(max(y[t] - e[t], fill_lo[t]), fill_hi[t])
                        data[pos + target_off[t]] = y[t]
                        e[t] = 0.0
                    learn = False
                elif learn:
                    for k in range(m):
                        if missing[px + tap_px[k]] != 0:
                            learn = False
                            break
            vv = 0.0
            if want_pred or learn:
                vv = _project(T, x, v, p)

            if want_pred:
                # One-step-ahead prediction from the statistics before r.
                q = 1.0 + tau * tau * vv
                if want_mean:
                    for t in range(d):
                        mean_out[po * d + t] = y[t] - e[t]
                if want_q:
                    q_out[po] = q
                if want_logp or want_maha or want_logrel:
                    logdet = cholesky_logdet(lam, L, d)
                    maha = mahalanobis(L, e, u, d)
                    if want_maha:
                        maha_out[po] = maha
                    if want_logrel:
                        logrel_out[po] = -0.5 * (beta - p + 2.0 + d) * math.log1p(maha / q)
                    if want_logp:
                        nu = beta - p + 2.0
                        logp_out[po] = (
                            math.lgamma(0.5 * (nu + d))
                            - math.lgamma(0.5 * nu)
                            - 0.5 * d * (log_pi + math.log(q))
                            - 0.5 * logdet
                            - 0.5 * (nu + d) * math.log1p(maha / q)
                        )

            if learn:
                # gamma += P x e^T / (phi^2 + x^T P x); P -> (P - ...) / phi^2
                alpha = _carlson_update(T, v, w, coef, phi2 / (tau * tau), 0, p)
                inv_alpha = 1.0 / alpha
                for t in range(d):
                    g = e[t] * inv_alpha
                    for k in range(p):
                        G[t, k] += w[k] * g
                shrink = phi2 / (phi2 + tau * tau * vv)
                for t in range(d):
                    for c in range(t + 1):
                        lam[t, c] = phi2 * lam[t, c] + shrink * e[t] * e[c]
                        lam[c, t] = lam[t, c]
                if forget:
                    tau /= phi
                    beta = phi2 * beta + (1.0 - phi2) * beta_prior + 1.0
                    if tick % every == 0:
                        for _ in range(per_event):
                            k0 = next_k
                            next_k = (next_k + 1) % n
                            _inject_prior(T, G, lam, v, w, coef, e, k0, inject[k0], tau, p, d)
                    tick += 1
                    if tau > _RESCALE_ABOVE:
                        for j in range(p):
                            for i in range(j + 1):
                                T[j, i] *= tau
                        tau = 1.0
                else:
                    beta += 1.0
                count += 1.0

            if want_gamma:
                o = po * d * m
                for t in range(d):
                    for k in range(m):
                        gamma_out[o + t * m + k] = G[t, k]

    fstate[0] = tau
    fstate[1] = beta
    fstate[2] = count
    istate[0] = tick
    istate[1] = next_k


@njit(cache=True, nogil=True, error_model="numpy")
def finish_factor(T, tau, out):
    """``out = tau * T`` on the lower triangle, zeros above: the factor with
    ``V_x^{-1} = out^T out`` after a scan."""
    p = T.shape[0]
    for j in range(p):
        for i in range(p):
            out[j, i] = T[j, i] * tau if i <= j else 0.0
