"""Recursive square-root estimator ((14.26)-(14.32), docs/model.md) against
independent computations."""

import math

import numpy as np
import pytest
from skimage import data as skdata

from car_fields import ORDERS, SHARED_DATA
from car_napari import Context, local_parameters
from car_napari._progress import drain
from car_napari.model.recursive import default_prior, iter_scan, scan


def batch_ls_with_intercept(Y, offsets):
    """Least squares of Y_r on [X_r, 1] over pixels with a complete
    neighbourhood, in plain NumPy (the raster scan)."""
    H, W, d = Y.shape
    di = np.array([s[0] for s in offsets])
    dj = np.array([s[1] for s in offsets])
    i0, j0, j1 = di.max(), max(dj.max(), 0), W + min(dj.min(), 0)
    cols = [Y[i0 - a : H - a, j0 - b : j1 - b] for a, b in offsets]
    X = np.concatenate(cols, axis=2).reshape(-1, d * len(offsets))
    X = np.hstack([X, np.ones((X.shape[0], 1))])
    target = Y[i0:H, j0:j1].reshape(-1, d)
    coef, *_ = np.linalg.lstsq(X, target, rcond=None)
    return coef[:-1].T


# How each scan direction sees the image, and the last pixel it updates.
VIEWS = {
    "down": lambda a: a,
    "up": lambda a: a[::-1],
    "right": lambda a: a.swapaxes(0, 1),
    "left": lambda a: a[:, ::-1].swapaxes(0, 1),
}


@pytest.mark.parametrize("direction", ["down", "up", "right", "left"])
@pytest.mark.parametrize("d, order", [(1, 2), (3, 2), (2, 4)])
def test_forgetting_one_equals_batch_least_squares(direction, d, order):
    rng = np.random.default_rng(d * 10 + order)
    img = rng.random((41, 37, d)) + np.linspace(0, 1, 37)[None, :, None]
    gamma = local_parameters(img, order, forgetting=1.0, direction=direction)
    assert gamma.shape == (41, 37, d, d * len(ORDERS[order]))
    view = VIEWS[direction](img)
    reference = batch_ls_with_intercept(view, ORDERS[order])
    # last pixel updated in the scan: last row, last column with a complete neighbourhood
    right_reach = max(-min(s[1] for s in ORDERS[order]), 0)
    last = VIEWS[direction](gamma)[-1, view.shape[1] - 1 - right_reach]
    np.testing.assert_allclose(last, reference, rtol=1e-6, atol=1e-6 * np.abs(reference).max())
    # and the running estimate carries over to the pixels after it
    np.testing.assert_array_equal(VIEWS[direction](gamma)[-1, -1], last)


def test_adaptive_estimate_tracks_a_change_of_texture():
    # Two AR(1)-like textures side by side in a raster scan: the local estimate
    # follows each one (forgetting 0.99: a window of about 50 pixels).
    rng = np.random.default_rng(3)
    H, W = 40, 800
    img = np.zeros((H, W))
    e = rng.standard_normal((H, W))
    for j in range(1, W):
        a = 0.9 if j < W // 2 else -0.6
        img[:, j] = a * img[:, j - 1] + e[:, j]
    gamma = local_parameters(img, [[0, 1]], forgetting=0.99)[..., 0, 0]
    assert abs(np.median(gamma[5:, 300:395]) - 0.9) < 0.05
    assert abs(np.median(gamma[5:, 700:795]) + 0.6) < 0.05


def _real_textures(shared_dir):
    grey = [skdata.gravel()[:64, :256], skdata.grass()[:64, :256], skdata.brick()[:64, :256]]
    textures = [g[..., None] / 255.0 for g in grey]
    colour = []
    if shared_dir is not None:
        from skimage import io

        for name in ("VS1.png", "VS10.png", "VS120.png"):
            path = shared_dir / "textures" / "vistex" / name
            if path.exists():
                colour.append(io.imread(path)[:64, :256, :3] / 255.0)
    return textures + colour


@pytest.fixture
def real_textures():
    return _real_textures(SHARED_DATA if SHARED_DATA.is_dir() else None)


def test_no_wind_up_after_a_long_flat_region(real_textures):
    """Left three quarters flat, right quarter a real texture, forgetting 0.99.

    Every estimate stays finite whatever the flat value. With the flat value
    at the texture's mean (so that no brightness edge enters the comparison),
    200 pixels into the texture the estimate is within 5 % (median over rows)
    of the estimate on the texture alone.
    """
    for tex in real_textures:
        d = tex.shape[2]
        alone = local_parameters(tex, 2, forgetting=0.99)
        for flat_value in (tex.mean(axis=(0, 1)), 0.0, 1.0):
            img = np.concatenate([np.broadcast_to(flat_value, (64, 768, d)), tex], axis=1)
            gamma = local_parameters(img, 2, forgetting=0.99)
            assert np.all(np.isfinite(gamma))
        img = np.concatenate([np.broadcast_to(tex.mean(axis=(0, 1)), (64, 768, d)), tex], axis=1)
        gamma = local_parameters(img, 2, forgetting=0.99)
        rel = [
            np.linalg.norm(gamma[r, 768 + 200] - alone[r, 200]) / np.linalg.norm(alone[r, 200])
            for r in range(2, 64)
        ]
        assert np.median(rel) < 0.05, (d, np.median(rel))


def test_near_flat_region_stays_finite_and_recovers():
    # Excitation 1e-9: plain recursion would blow P up; the floor keeps it bounded.
    rng = np.random.default_rng(0)
    tex = skdata.gravel()[:64, :256] / 255.0
    flat = tex.mean() + 1e-9 * rng.standard_normal((64, 3000))
    img = np.concatenate([flat, tex], axis=1)
    gamma = local_parameters(img, 2, forgetting=0.99, channel_axis=None)
    alone = local_parameters(tex, 2, forgetting=0.99, channel_axis=None)
    assert np.all(np.isfinite(gamma))
    rel = [
        np.linalg.norm(gamma[r, 3200] - alone[r, 200]) / np.linalg.norm(alone[r, 200])
        for r in range(2, 64)
    ]
    assert np.median(rel) < 0.05


def test_input_not_modified_and_any_dtype():
    img = (np.random.default_rng(1).random((30, 30, 3)) * 255).astype(np.uint8)
    before = img.copy()
    g8 = local_parameters(img, 1)
    g64 = local_parameters(img / 255.0, 1)
    np.testing.assert_array_equal(img, before)
    np.testing.assert_allclose(g8, g64, rtol=1e-9, atol=1e-12)


def _dense_recursion(img, offsets, phi, prior, with_density=False):
    """(14.32) with explicit matrices: V = phi^2 V + (1 - phi^2) V_0 + z z^T at
    every pixel, z = [X; 1; Y] (raster scan), estimates by np.linalg.solve."""
    H, W, d = img.shape
    m = d * len(offsets)
    p = m + 1
    V0 = np.diag(prior)
    V = V0.copy()
    beta = p - 1.0
    up = max(a for a, _ in offsets)
    left = max(max(b for _, b in offsets), 0)
    right = max(-min(b for _, b in offsets), 0)
    gammas = np.full((H, W, d, m), np.nan)
    logp = np.full((H, W), np.nan)
    for i in range(up, H):
        for j in range(left, W - right):
            x = np.concatenate([img[i - a, j - b] for a, b in offsets] + [[1.0]])
            y = img[i, j]
            if with_density:
                Vx, Vxy, Vy = V[:p, :p], V[:p, p:], V[p:, p:]
                gT = np.linalg.solve(Vx, Vxy)
                lam = Vy - Vxy.T @ gT
                q = 1 + x @ np.linalg.solve(Vx, x)
                e = y - gT.T @ x
                nu = beta - p + 2
                maha = e @ np.linalg.solve(lam, e)
                logp[i, j] = (
                    math.lgamma((nu + d) / 2) - math.lgamma(nu / 2)
                    - d / 2 * np.log(np.pi * q) - 0.5 * np.linalg.slogdet(lam)[1]
                    - (nu + d) / 2 * np.log1p(maha / q)
                )
            z = np.r_[x, y]
            V = phi**2 * V + (1 - phi**2) * V0 + np.outer(z, z)
            beta = phi**2 * beta + (1 - phi**2) * (p - 1) + 1
            gammas[i, j] = np.linalg.solve(V[:p, :p], V[:p, p:]).T[:, :m]
    return gammas, logp


def test_one_step_density_equals_dense_recursion():
    rng = np.random.default_rng(0)
    img = np.cumsum(rng.standard_normal((20, 30, 2)), axis=1) * 0.3
    img -= img.mean(axis=(0, 1))
    offsets = ORDERS[2]
    ctx = Context.spatial(np.array(offsets), 2)
    prior = default_prior(img.var(axis=(0, 1)), ctx.n_regressors, True, 2, 1e-2)
    res = scan(img, ctx, forgetting=1.0, intercept=True, prior=prior, outputs=("logp", "gamma"))
    gammas, logp = _dense_recursion(img, offsets, 1.0, prior, with_density=True)
    ok = np.isfinite(logp)
    np.testing.assert_allclose(res["logp"][ok], logp[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res["gamma"][ok], gammas[ok], rtol=1e-7, atol=1e-9)
    # in chunks of rows (issue 12): the same bits
    for rows in (1, 3):
        chunked = drain(iter_scan(img, ctx, forgetting=1.0, intercept=True, prior=prior,
                                  outputs=("logp", "gamma"), chunk_rows=rows))
        for key in ("logp", "gamma", "T", "G", "lam", "beta", "count"):
            np.testing.assert_array_equal(chunked[key], res[key])


@pytest.mark.parametrize(
    "phi, order, collinear", [(0.97, 2, False), (0.9, 5, False), (0.9, 5, True), (0.7, 2, True)]
)
def test_forgetting_tracks_the_exact_stabilised_recursion(phi, order, collinear):
    """The kernel's round-robin prior re-injection against V(t) = phi^2 V(t-1) +
    (1 - phi^2) V_0 + z z^T done exactly at every pixel, including a grey image
    stored as RGB (collinear channels: the prior alone pins two directions)."""
    grey = skdata.camera()[100:124, 100:200] / 255.0
    if collinear:
        img = np.repeat(grey[..., None], 3, axis=2)
    else:
        img = skdata.astronaut()[300:324, 0:100] / 255.0
    img = img - img.mean(axis=(0, 1))
    ctx = Context.spatial(np.array(ORDERS[order]), 3)
    prior = default_prior(img.var(axis=(0, 1)), ctx.n_regressors, True, 3, 1e-6)
    got = scan(np.ascontiguousarray(img), ctx, forgetting=phi, intercept=True, prior=prior)["gamma"]
    chunked = drain(iter_scan(np.ascontiguousarray(img), ctx, forgetting=phi, intercept=True,
                              prior=prior, chunk_rows=5))["gamma"]
    np.testing.assert_array_equal(chunked, got)  # in chunks of rows: the same bits
    exact, _ = _dense_recursion(img, ORDERS[order], phi, prior)
    ok = np.isfinite(exact[..., 0, 0])
    ok[: 4] = False  # the first rows, where the prior still dominates
    assert np.all(np.isfinite(got))
    assert np.abs(got[ok]).max() < 2 * np.abs(exact[ok]).max()
    rel = np.linalg.norm(got[ok] - exact[ok], axis=(1, 2)) / np.linalg.norm(exact[ok], axis=(1, 2))
    assert np.median(rel) < 0.05, np.median(rel)


@pytest.mark.parametrize("direction", ["up", "left"])
def test_prediction_outputs_equal_the_dense_one_step_statistics(direction):
    """The scan's 'mean', 'q', 'maha' and 'logrel' outputs (no forgetting, with
    an intercept) against the one-step-ahead statistics of (14.23)-(14.25)
    computed from explicit matrices in the scan's own view: V of the pixels
    before r plus V_0, gamma^T = V_x^-1 V_xy, lambda = V_y - V_xy^T V_x^-1 V_xy,
    q = 1 + X^T V_x^-1 X, maha = e^T lambda^-1 e, logrel = -(nu + d)/2
    log(1 + maha/q) with nu = beta - p + 2."""
    rng = np.random.default_rng(4)
    img = np.cumsum(rng.standard_normal((14, 17, 2)), axis=0) * 0.4
    img -= img.mean(axis=(0, 1))
    offsets = ORDERS[2]
    d, m = 2, 2 * len(offsets)
    p = m + 1
    ctx = Context.spatial(np.array(offsets), d)
    prior = default_prior(img.var(axis=(0, 1)), m, True, d, 1e-2)
    res = scan(np.ascontiguousarray(img), ctx, direction=direction, intercept=True,
               prior=prior, outputs=("mean", "q", "maha", "logrel"))
    view = VIEWS[direction](img)
    H, W, _ = view.shape
    V = np.diag(prior)
    beta = p - 1.0
    want = {k: np.full((H, W), np.nan) for k in ("q", "maha", "logrel")}
    want["mean"] = np.full((H, W, d), np.nan)
    for i in range(1, H):
        for j in range(1, W - 1):
            x = np.concatenate([view[i - a, j - b] for a, b in offsets] + [[1.0]])
            y = view[i, j]
            Vx, Vxy, Vy = V[:p, :p], V[:p, p:], V[p:, p:]
            gT = np.linalg.solve(Vx, Vxy)
            lam = Vy - Vxy.T @ gT
            e = y - gT.T @ x
            q = 1 + x @ np.linalg.solve(Vx, x)
            maha = e @ np.linalg.solve(lam, e)
            want["mean"][i, j] = gT.T @ x
            want["q"][i, j], want["maha"][i, j] = q, maha
            want["logrel"][i, j] = -(beta - p + 2 + d) / 2 * np.log1p(maha / q)
            z = np.r_[x, y]
            V = V + np.outer(z, z)
            beta += 1
    for key, value in want.items():
        got = VIEWS[direction](res[key])
        np.testing.assert_array_equal(np.isnan(got), np.isnan(value), err_msg=key)
        ok = ~np.isnan(value)
        np.testing.assert_allclose(got[ok], value[ok], rtol=1e-8, atol=1e-10, err_msg=key)


def test_warm_start_is_the_whole_image_statistics_weighted_as_one_window():
    """The adaptive scan's start (forgetting < 1) against the documented warm
    start written out in NumPy: the whole image's statistics of [X; 1; Y]
    (the intercept's cross terms taken as 0 on centred data, its own entry
    the pixel count) weighted as one forgetting window, 1 / (1 - phi^2)
    pixels, plus the prior V_0 = strength * var (strength alone for the
    intercept). The estimate carried to the pixels before the first update is
    its gamma, the first update's one-step prediction is its gamma X, and the
    estimate after it that of phi^2 V + z z^T (the prior's re-injection is
    below the tolerance: a 1e-6 share)."""
    from car_napari.model.adaptive import adaptive_scanner

    rng = np.random.default_rng(9)
    img = np.cumsum(rng.standard_normal((20, 23, 2)), axis=1) * 0.3
    img = np.ascontiguousarray(img - img.mean(axis=(0, 1)))
    offsets, d, phi, strength = ORDERS[1], 2, 0.95, 1e-6
    m = d * len(offsets)
    var = img.var(axis=(0, 1))
    res = adaptive_scanner(img, Context.spatial(np.array(offsets), d), var, forgetting=phi,
                           direction="down", prior=strength,
                           outputs=("gamma", "mean")).run()
    X = np.concatenate([img[1:, :-1], img[:-1, 1:]], axis=2).reshape(-1, m)  # (0,1), (1,0)
    T = img[1:, 1:].reshape(-1, d)
    n = X.shape[0]
    aug = np.zeros((m + 1 + d, m + 1 + d))
    aug[:m, :m], aug[:m, m + 1:], aug[m + 1:, m + 1:] = X.T @ X, X.T @ T, T.T @ T
    aug[m + 1:, :m] = T.T @ X
    aug[m, m] = n
    weight = min(1.0, 1.0 / (1.0 - phi**2) / n)
    prior = np.full(m + 1 + d, strength * var.mean())
    prior[m] = strength
    V = weight * aug + np.diag(prior)
    gT = np.linalg.solve(V[: m + 1, : m + 1], V[: m + 1, m + 1:])  # (m + 1, d)
    np.testing.assert_allclose(res["gamma"][0, 0], gT[:m].T, rtol=1e-8, atol=1e-12)
    x = np.r_[img[1, 0], img[0, 1], 1.0]
    np.testing.assert_allclose(res["mean"][1, 1], gT.T @ x, rtol=1e-8, atol=1e-12)
    z = np.r_[x, img[1, 1]]
    V = phi**2 * V + np.outer(z, z)
    after = np.linalg.solve(V[: m + 1, : m + 1], V[: m + 1, m + 1:])[:m].T
    assert np.abs(after - gT[:m].T).max() > 1e-3  # one pixel moves a window's estimate
    np.testing.assert_allclose(res["gamma"][1, 1], after, rtol=1e-5, atol=1e-9)
