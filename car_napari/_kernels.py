"""Numba kernels: the recursive square-root CAR estimator and synthesis.

Every kernel is compiled with ``cache=True`` (a fast second start) and
``nogil=True`` (so a napari worker thread running it leaves the viewer
responsive). Kernels see flat C-ordered arrays plus integer strides, so one
compiled kernel serves all four scan directions without copying the image.

Square-root form (SPEC 1.4): the data-gathering matrix of the augmented vector
``z = [X_r; 1 (optional intercept); Y_r]`` is kept as ``V = s^2 U^T U`` with
``U`` upper triangular and ``s`` a scalar. Forgetting multiplies ``s`` by
``phi`` instead of touching ``U``; new data enter ``U`` by a rank-one Cholesky
update with ``z / s``. Every estimate then comes from triangular solves:

    gamma^T = U11^{-1} U12,   lambda = s^2 U22^T U22,   V_x = s^2 U11^T U11.

No inverse is ever formed, so rounding cannot make it indefinite.

Wind-up: in a flat region ``z`` excites at most one direction while forgetting
shrinks all others. We use stabilised forgetting,
``V(t) = phi^2 V(t-1) + (1 - phi^2) V_0 + z z^T``, which keeps ``V >= V_0``;
the ``(1 - phi^2) V_0`` term is added one coordinate per pixel (round robin,
``n (1 - phi^2) v_k`` on coordinate ``k = t mod n``), which costs a third of
an update on average and equals the full term over every ``n`` pixels.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_RESCALE_BELOW = 1e-100


@njit(cache=True, nogil=True)
def _rank_one_update(U, x, start, n):
    """U^T U + x x^T, in place, for U upper triangular (x is overwritten)."""
    for k in range(start, n):
        ukk = U[k, k]
        xk = x[k]
        if xk == 0.0:
            continue
        r = math.sqrt(ukk * ukk + xk * xk)
        c = r / ukk
        sn = xk / ukk
        inv_c = 1.0 / c
        U[k, k] = r
        for i in range(k + 1, n):
            uki = (U[k, i] + sn * x[i]) * inv_c
            U[k, i] = uki
            x[i] = c * x[i] - sn * uki


@njit(cache=True, nogil=True)
def _forward_solve_transposed(U, x, u, p):
    """Solve U[:p, :p]^T u = x[:p] (forward substitution)."""
    for i in range(p):
        acc = x[i]
        for k in range(i):
            acc -= U[k, i] * u[k]
        u[i] = acc / U[i, i]


@njit(cache=True, nogil=True)
def _coefficients(U, G, p, d):
    """G = U11^{-1} U12 (p x d): the transposed parameter matrix gamma^T."""
    for t in range(d):
        col = p + t
        for i in range(p - 1, -1, -1):
            acc = U[i, col]
            for k in range(i + 1, p):
                acc -= U[i, k] * G[k, t]
            G[i, t] = acc / U[i, i]


@njit(cache=True, nogil=True)
def recursive_scan(
    data,
    geom,
    tap_off,
    tap_ch,
    target_off,
    intercept,
    U0,
    beta_init,
    beta_prior,
    phi,
    prior_diag,
    update,
    gamma_out,
    mean_out,
    logp_out,
    q_out,
    maha_out,
    U_final,
    state_final,
):
    """Scan an image once, in one direction, with the recursive estimator.

    Parameters (all flat / contiguous)
    ----------------------------------
    data : float64[:] the (H, W, C) source array, raveled.
    geom : int64[12] ``Hs, Ws, base, sa, sb, base_px, sa_px, sb_px, a_lo, a_hi,
        b_lo, b_hi``: scan extent, element offset of scan pixel (a, b) in
        ``data`` as ``base + a*sa + b*sb`` (pixel index likewise for outputs)
        and the rectangle of scan positions whose taps are all inside.
    tap_off : int64[m] element offset of each tap from the pixel's channel 0.
    tap_ch : int64[m] channel of each tap. A pixel whose every tap equals its
        own channel's value at ``r`` (a flat neighbourhood: a clipped,
        saturated or padded region; probability zero under the model) carries
        no texture information: it neither updates nor forgets, so a texture
        after a flat background is estimated as if the background were absent.
    target_off : int64[d] channel of each modelled component.
    intercept : bool, append a constant 1 regressor (a local mean).
    U0 : float64[n, n] initial square-root factor (n = m + intercept + d).
    beta_init, beta_prior : initial and prior ``beta``.
    phi : forgetting factor (1 = none).
    prior_diag : float64[n] ``V_0`` diagonal re-injected when ``phi < 1``.
    update : bool, False freezes the statistics (prediction by a fixed model).
    gamma_out : float64[N*d*m] or empty. Estimate after each pixel (carried
        over where the neighbourhood leaves the image).
    mean_out, logp_out, q_out, maha_out : float64[N*d], [N], [N], [N] or empty.
        One-step-ahead conditional mean, Student-t log density (SPEC 1.6),
        ``q = 1 + X^T V_x^{-1} X`` and ``e^T lambda^{-1} e`` from the
        statistics before the pixel's update; NaN where the neighbourhood
        leaves the image.
    U_final, state_final : outputs: the final factor and ``[s, beta, count]``.
    """
    Hs, Ws = geom[0], geom[1]
    base, sa, sb = geom[2], geom[3], geom[4]
    base_px, sa_px, sb_px = geom[5], geom[6], geom[7]
    a_lo, a_hi, b_lo, b_hi = geom[8], geom[9], geom[10], geom[11]
    m = tap_off.shape[0]
    d = target_off.shape[0]
    p = m + (1 if intercept else 0)
    n = p + d

    U = U0.copy()
    s = 1.0
    beta = beta_init
    phi2 = phi * phi
    forget = phi < 1.0
    inject = np.empty(n)
    for k in range(n):
        inject[k] = math.sqrt(n * (1.0 - phi2) * prior_diag[k]) if forget else 0.0

    want_gamma = gamma_out.shape[0] > 0
    want_mean = mean_out.shape[0] > 0
    want_logp = logp_out.shape[0] > 0
    want_q = q_out.shape[0] > 0
    want_maha = maha_out.shape[0] > 0
    want_pred = want_mean or want_logp or want_q or want_maha

    z = np.empty(n)
    work = np.empty(n)
    u = np.empty(p)
    e = np.empty(d)
    w = np.empty(d)
    G = np.zeros((p, d))
    log_pi = math.log(math.pi)
    count = 0.0
    tick = 0

    for a in range(Hs):
        for b in range(Ws):
            px = base_px + a * sa_px + b * sb_px
            inside = a >= a_lo and a < a_hi and b >= b_lo and b < b_hi
            if not inside:
                if want_gamma:
                    o = px * d * m
                    for t in range(d):
                        for k in range(m):
                            gamma_out[o + t * m + k] = G[k, t]
                if want_pred:
                    if want_mean:
                        for t in range(d):
                            mean_out[px * d + t] = np.nan
                    if want_logp:
                        logp_out[px] = np.nan
                    if want_q:
                        q_out[px] = np.nan
                    if want_maha:
                        maha_out[px] = np.nan
                continue

            pos = base + a * sa + b * sb
            for k in range(m):
                z[k] = data[pos + tap_off[k]]
            if intercept:
                z[m] = 1.0
            for t in range(d):
                z[p + t] = data[pos + target_off[t]]
            flat = True
            for k in range(m):
                if z[k] != data[pos + tap_ch[k]]:
                    flat = False
                    break

            if want_pred:
                # One-step-ahead prediction from the statistics before r.
                _forward_solve_transposed(U, z, u, p)
                uu = 0.0
                for k in range(p):
                    uu += u[k] * u[k]
                q = 1.0 + uu / (s * s)
                for t in range(d):
                    acc = 0.0
                    for k in range(p):
                        acc += U[k, p + t] * u[k]
                    e[t] = z[p + t] - acc
                    if want_mean:
                        mean_out[px * d + t] = acc
                # w = U22^{-T} e
                maha = 0.0
                logdet = 0.0
                for t in range(d):
                    acc = e[t]
                    for k in range(t):
                        acc -= U[p + k, p + t] * w[k]
                    w[t] = acc / U[p + t, p + t]
                    maha += w[t] * w[t]
                    logdet += math.log(abs(U[p + t, p + t]))
                maha /= s * s
                logdet = 2.0 * logdet + 2.0 * d * math.log(s)
                if want_q:
                    q_out[px] = q
                if want_maha:
                    maha_out[px] = maha
                if want_logp:
                    nu = beta - p + 2.0
                    logp_out[px] = (
                        math.lgamma(0.5 * (nu + d))
                        - math.lgamma(0.5 * nu)
                        - 0.5 * d * (log_pi + math.log(q))
                        - 0.5 * logdet
                        - 0.5 * (nu + d) * math.log1p(maha / q)
                    )

            if update and not flat:
                if forget:
                    s *= phi
                    if s < _RESCALE_BELOW:
                        for i in range(n):
                            for j in range(i, n):
                                U[i, j] *= s
                        s = 1.0
                    k0 = tick % n
                    for k in range(n):
                        work[k] = 0.0
                    work[k0] = inject[k0] / s
                    _rank_one_update(U, work, k0, n)
                    tick += 1
                    beta = phi2 * beta + (1.0 - phi2) * beta_prior + 1.0
                else:
                    beta += 1.0
                inv_s = 1.0 / s
                for k in range(n):
                    work[k] = z[k] * inv_s
                _rank_one_update(U, work, 0, n)
                count += 1.0

            if want_gamma:
                if update and not flat:
                    _coefficients(U, G, p, d)
                o = px * d * m
                for t in range(d):
                    for k in range(m):
                        gamma_out[o + t * m + k] = G[k, t]

    for i in range(n):
        for j in range(n):
            U_final[i, j] = U[i, j] * s if j >= i else 0.0
    state_final[0] = s
    state_final[1] = beta
    state_final[2] = count


@njit(cache=True, nogil=True)
def synthesize_field(gamma, chol_sigma, noise, tap_di, tap_dj, tap_ch, limit):
    """Generate a zero-mean CAR field in raster order (SPEC 1.7).

    ``noise`` (H, W, d) holds standard normal draws; it is overwritten by the
    field. Pixels whose neighbours leave the lattice use zeros (the burn-in
    margin removed by the caller absorbs that transient). Returns False as
    soon as a value exceeds ``limit`` (an unstable model).
    """
    H, W, d = noise.shape
    m = tap_di.shape[0]
    x = np.empty(m)
    innov = np.empty(d)
    for i in range(H):
        for j in range(W):
            for k in range(m):
                ii = i - tap_di[k]
                jj = j - tap_dj[k]
                if ii >= 0 and jj >= 0 and jj < W:
                    x[k] = noise[ii, jj, tap_ch[k]]
                else:
                    x[k] = 0.0
            for t in range(d):
                acc = 0.0
                for c in range(t + 1):
                    acc += chol_sigma[t, c] * noise[i, j, c]
                innov[t] = acc
            for t in range(d):
                acc = innov[t]
                for k in range(m):
                    acc += gamma[t, k] * x[k]
                if not (abs(acc) <= limit):
                    return False
                noise[i, j, t] = acc
    return True
