"""The CAR model's conditional mean of the missing pixels (docs/inpainting.md):
checked against a dense NumPy Gaussian conditional, against scikit-image's
biharmonic inpainting (the squared-Laplacian precision) and against a plain
least-squares fit."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata
from skimage.restoration import inpaint_biharmonic

from car_napari.inpainting import _conditional, _solver, inpaint
from car_napari.inpainting._conditional import conditional_mean, direction_offsets
from car_napari.inpainting._local_fits import PREVIOUS_OFFSETS, LocalModels, fit_local_models
from car_napari.inpainting._solver import BAND_WIDTH, stencil_solve
from car_napari.model import causal_neighbourhood


def _dense_precision(models, H, W, previous=None):
    """The precision ``P`` and linear term ``h`` of the product of the
    models' densities over an H x W frame (negative log density ``y^T P y / 2
    - h^T y`` + const), built densely pixel by pixel, each pixel with its
    own tile's model: every pixel whose neighbourhood lies inside has the
    residual ``(Y_r - mu) - sum_k A_k (Y_{r - s_k} - mu) - sum_l B_l
    (P_{r - p_l} - mu_p)`` (with a ``previous`` frame ``P``, its taps
    ``p_l`` in ``PREVIOUS_OFFSETS``, a tap outside the frame repeating its
    edge pixel; no ``B`` term without one), covariance ``Sigma``, the others
    ``Y_r - mu`` with the marginal covariance (docs/inpainting.md,
    "Precision")."""
    P, h = 0, 0
    for model in models:
        C = model.sigma.shape[-1]
        eta = len(model.offsets)
        N = H * W
        D = np.zeros((N * C, N * C))  # the residuals' rows: e = D y - m
        m = np.zeros(N * C)
        S_inv = np.zeros((N * C, N * C))
        for i in range(H):
            for j in range(W):
                t = (i // model.tile, j // model.tile)
                gamma, mu = model.gamma[t], model.mean[t]
                rows = slice((i * W + j) * C, (i * W + j + 1) * C)
                D[rows, rows] = np.eye(C)
                nb = [(i - di, j - dj) for di, dj in model.offsets]
                back = [] if previous is None else [
                    (min(max(i - di, 0), H - 1), min(max(j - dj, 0), W - 1))
                    for di, dj in PREVIOUS_OFFSETS]
                if all(0 <= a < H and 0 <= b < W for a, b in nb):
                    m[rows] = mu
                    for k, (a, b) in enumerate(nb):
                        A_k = gamma[:, k * C : (k + 1) * C]
                        D[rows, (a * W + b) * C : (a * W + b + 1) * C] -= A_k
                        m[rows] -= A_k @ mu
                    for k, (a, b) in enumerate(back):
                        B_k = gamma[:, (eta + k) * C : (eta + k + 1) * C]
                        m[rows] += B_k @ (previous[a, b] - model.previous_mean[t])
                    S = model.sigma[t]
                else:
                    m[rows] = mu
                    S = model.marginal[t]
                S_inv[rows, rows] = np.linalg.inv(S)
        P = P + D.T @ S_inv @ D
        h = h + D.T @ S_inv @ m
    return P, h


def _random_model(rng, offsets, C, mean, *, tile=100, previous_mean=None):
    """Random coefficients, innovation and marginal covariances per tile
    (``mean`` (d,): one tile; (ty, tx, d): a grid of ``tile`` pixels); with
    ``previous_mean`` (ty, tx, d), random ``B`` on the previous frame too."""
    mean = np.asarray(mean, float)
    mean = mean[None, None] if mean.ndim == 1 else mean
    ty, tx = mean.shape[:2]
    eta = len(offsets)
    n_prev = 0 if previous_mean is None else len(PREVIOUS_OFFSETS)
    gamma = np.zeros((ty, tx, C, (eta + n_prev) * C))
    sigma, marginal = np.zeros((2, ty, tx, C, C))
    for t in np.ndindex(ty, tx):
        A = rng.normal(0, 0.2, (eta, C, C))
        S = rng.normal(size=(C, C))
        S = S @ S.T + C * np.eye(C)
        gamma[t][:, : eta * C] = A.transpose(1, 0, 2).reshape(C, eta * C)
        if n_prev:
            B = rng.normal(0, 0.3, (n_prev, C, C))
            gamma[t][:, eta * C :] = B.transpose(1, 0, 2).reshape(C, n_prev * C)
        sigma[t], marginal[t] = S, 2 * S + np.eye(C)
    return LocalModels(tile, np.asarray(offsets), gamma, sigma, mean, previous_mean, marginal)


def _dense_conditional(frame, unknown, models, previous=None):
    """The Gaussian conditional mean of the unknown pixels given the known,
    by a dense solve: ((n, C) values, the precision over the unknowns)."""
    H, W, C = frame.shape
    P, h = _dense_precision(models, H, W, previous)
    y = frame.reshape(-1)
    u = np.repeat(unknown.reshape(-1), C)
    x = np.linalg.solve(P[np.ix_(u, u)], h[u] - P[np.ix_(u, ~u)] @ y[~u])
    return x.reshape(-1, C), P[np.ix_(u, u)]


@pytest.mark.parametrize("band_width", [BAND_WIDTH, -1], ids=["band", "superlu"])
def test_conditional_mean_matches_the_dense_gaussian_conditional(band_width, monkeypatch):
    monkeypatch.setattr(_solver, "BAND_WIDTH", band_width)
    rng = np.random.default_rng(0)
    H, W, C = 9, 11, 2
    mean = np.array([0.5, -0.2])
    frame = rng.normal(size=(H, W, C))
    unknown = np.zeros((H, W), bool)
    unknown[3:6, 4] = unknown[0, 0] = unknown[8, 10] = True  # corners: marginal rows
    unknown[7, 2:5] = True
    base = causal_neighbourhood(2)
    for directions in (("down",), ("down", "up", "right", "left")):
        models = [_random_model(rng, direction_offsets(base, d), C, mean) for d in directions]
        got = conditional_mean(frame, unknown, models)
        x, _ = _dense_conditional(frame, unknown, models)
        np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("band_width", [BAND_WIDTH, -1], ids=["band", "superlu"])
def test_conditional_mean_with_a_previous_frame_matches_the_dense_gaussian_conditional(
        band_width, monkeypatch):
    """The 3.5D rows: random models per tile of 5 x 5 pixels, four
    directions, each with ``B`` on the previous frame at ``PREVIOUS_OFFSETS``
    (known, so it moves only the rows' constants); damage across tiles, two
    pixels or more from the frame's edges."""
    monkeypatch.setattr(_solver, "BAND_WIDTH", band_width)
    rng = np.random.default_rng(6)
    H, W, C, tile = 12, 13, 2, 5
    frame = rng.normal(size=(H, W, C))
    previous = frame + rng.normal(0, 0.5, (H, W, C)) + 0.7
    unknown = np.zeros((H, W), bool)
    unknown[3:9, 4] = unknown[2, 2] = unknown[9, 10] = unknown[5, 10] = True
    unknown[7, 2:8] = unknown[4:6, 6:9] = True
    base = causal_neighbourhood(2)
    mean = rng.normal(0, 0.5, (3, 3, C))
    previous_mean = mean + 0.7 + rng.normal(0, 0.1, (3, 3, C))
    models = [_random_model(rng, direction_offsets(base, d), C, mean, tile=tile,
                            previous_mean=previous_mean)
              for d in ("down", "up", "right", "left")]
    got = conditional_mean(frame, unknown, models, previous=previous)
    x, _ = _dense_conditional(frame, unknown, models, previous)
    np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-10)
    without, _ = _dense_conditional(frame, unknown, models)  # B = 0: the test can tell
    assert np.abs(without - x).max() > 0.1


def test_damage_at_the_edges_with_a_previous_frame_matches_the_dense_conditional():
    """As above, with damage on the frame's edges: a previous-frame tap
    outside the frame repeats the frame's edge pixel (before, it read 0,
    which pulled edge fills towards -B mu_p)."""
    rng = np.random.default_rng(6)
    H, W, C, tile = 12, 13, 2, 5
    frame = rng.normal(size=(H, W, C))
    previous = frame + rng.normal(0, 0.5, (H, W, C)) + 0.7
    unknown = np.zeros((H, W), bool)
    unknown[3:9, 0] = unknown[0, 4:9] = unknown[11, 12] = True
    mean = rng.normal(0, 0.5, (3, 3, C))
    previous_mean = mean + 0.7 + rng.normal(0, 0.1, (3, 3, C))
    models = [_random_model(rng, direction_offsets(causal_neighbourhood(2), d), C, mean,
                            tile=tile, previous_mean=previous_mean)
              for d in ("down", "up", "right", "left")]
    got = conditional_mean(frame, unknown, models, previous=previous)
    x, _ = _dense_conditional(frame, unknown, models, previous)
    np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-10)


def test_fill_with_a_previous_frame_is_the_dense_conditional_of_its_models(monkeypatch):
    """The fill of a clip's frame with the previous frame in the context
    (the rows near the damage only, the previous frame's taps shared by the
    four directions) against the dense Gaussian conditional under the same
    fitted models."""
    from car_napari.inpainting._conditional import fill_conditional

    rng = np.random.default_rng(7)
    H, W, C = 20, 22, 2
    scene = ndimage.uniform_filter(rng.random((H + 1, W, C)), (3, 3, 1))
    frame, previous = scene[1:], scene[:-1] + rng.normal(0, 0.01, (H, W, C))
    mask = np.zeros((H, W), bool)
    mask[6:9, 3:12] = mask[12:17, 15] = mask[2, 17:20] = True  # 2 px from the edges
    fitted = {}
    original = _conditional.iter_fit_local_models

    def spy(*args, **options):
        fitted["models"] = yield from original(*args, **options)
        return fitted["models"]

    monkeypatch.setattr(_conditional, "iter_fit_local_models", spy)
    got = fill_conditional(frame, mask, order=2, previous=previous, tile=8, margin=4,
                           fill_range=None)
    models = fitted["models"]
    assert models[0].previous_mean is not None and len(models) == 4
    x, _ = _dense_conditional(frame, mask, models, previous)
    np.testing.assert_allclose(got, x, rtol=1e-8, atol=1e-10)


def test_superlu_solves_a_blob_in_the_pixel_graph_order(monkeypatch):
    """A 2-D hole of colour pixels (one coupled group, solved by SuperLU in
    the order of the pixels' graph) against the dense Gaussian conditional;
    the order is a permutation keeping each pixel's unknowns together, and
    the permuted matrix is the dense one permuted."""
    from scipy import sparse

    monkeypatch.setattr(_solver, "BAND_WIDTH", -1)
    rng = np.random.default_rng(3)
    H, W, C = 16, 15, 3
    mean = np.array([0.5, -0.2, 0.1])
    frame = rng.normal(size=(H, W, C))
    unknown = np.zeros((H, W), bool)
    unknown[3:13, 2:12] = True
    unknown[5, 13] = True
    models = [_random_model(rng, direction_offsets(causal_neighbourhood(2), d), C, mean)
              for d in ("down", "up")]
    got = conditional_mean(frame, unknown, models)
    x, Q = _dense_conditional(frame, unknown, models)
    np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-10)

    Q[np.abs(Q) < 1e-300] = 0.0
    csc = sparse.csc_matrix(Q)
    assert not (np.diff(csc.indptr) % C).any()  # whole blocks, as _batch_csc keeps them
    pixels = _solver._pixel_order(csc, C)
    assert sorted(pixels) == list(range(unknown.sum()))
    order = _solver._unknowns_order(pixels, C)
    np.testing.assert_array_equal(order.reshape(-1, C) // C, np.repeat(pixels[:, None], C, 1))
    np.testing.assert_array_equal(_solver._symmetric_permuted(csc, order).toarray(),
                                  Q[np.ix_(order, order)])


def test_band_cholesky_solves_a_group_and_refuses_an_indefinite_one():
    """Two groups of a row of grey pixels, each a tridiagonal block: the
    second solved alone against a dense solve; a negative pivot refused."""
    from car_napari.inpainting._solver import _band_cholesky, _block_bandwidth

    rng = np.random.default_rng(1)
    n = 10
    pixels = np.stack([np.zeros(n, np.int64), np.arange(n)], axis=1)
    index = np.arange(n)[None, :]
    slots = np.array([(0, -1), (0, 0), (0, 1)], np.int64)
    blocks = np.zeros((n, 2, 1, 1))  # the centre and the next pixel (see _assemble_kernel)
    blocks[:, 0, 0, 0] = 3.0 + rng.random(n)
    blocks[:-1, 1, 0, 0] = rng.normal(size=n - 1)
    blocks[4, 1] = 0.0  # pixels 0-4 and 5-9: two groups
    A = np.diag(blocks[5:, 0, 0, 0]) + np.diag(blocks[5:-1, 1, 0, 0], 1)
    A = A + np.triu(A, 1).T
    args = (blocks, np.arange(n), pixels, index, slots, 5, n)
    assert _block_bandwidth(*args) == 1
    right = rng.normal(size=(5, 3))
    x = right.copy()
    assert _band_cholesky(*args, 1, x)
    np.testing.assert_allclose(x, np.linalg.solve(A, right), rtol=1e-12)
    blocks[7, 0] = -1.0
    assert not _band_cholesky(*args, 1, right.copy())


def test_squared_laplacian_precision_is_biharmonic_inpainting():
    image = skdata.camera()[100:160, 100:170] / 255.0
    mask = np.zeros(image.shape, bool)
    mask[20:26, 10:40] = mask[5:50, 50:53] = True
    mask[40, 5] = True
    laplacian = np.array([(0, 0), (0, 1), (0, -1), (1, 0), (-1, 0)])
    coeffs = np.array([4.0, -1, -1, -1, -1]).reshape(1, 1, 5, 1, 1)
    got = stencil_solve(image[..., None], mask,
                        [(laplacian, coeffs, np.zeros((1, 1, 1)), None, None)], 1000)
    np.testing.assert_allclose(got[:, 0], inpaint_biharmonic(image, mask)[mask], atol=1e-9)


def test_local_fit_is_the_least_squares_fit_of_the_known_pixels():
    rng = np.random.default_rng(2)
    frame = ndimage.uniform_filter(rng.random((30, 34, 2)), (3, 3, 1))
    frame[..., 1] += 0.5 * frame[..., 0]
    unknown = np.zeros((30, 34), bool)
    unknown[10:14, 8:20] = True
    offsets = causal_neighbourhood(2)
    (model,) = fit_local_models(frame, unknown, [offsets], tile=64, prior=1e-12)
    # plain NumPy: pixels known with all 4 neighbours known and inside
    rows, targets = [], []
    for i in range(1, 30):
        for j in range(1, 33):
            nb = [(i - di, j - dj) for di, dj in offsets]
            if unknown[i, j] or any(unknown[a, b] for a, b in nb):
                continue
            rows.append(np.concatenate([frame[a, b] for a, b in nb]))
            targets.append(frame[i, j])
    X, Y = np.array(rows), np.array(targets)
    mu = Y.mean(axis=0)
    coef = np.linalg.lstsq(X - np.tile(mu, 4), Y - mu, rcond=None)[0]
    np.testing.assert_allclose(model.mean[0, 0], mu, rtol=1e-12)
    np.testing.assert_allclose(model.gamma[0, 0], coef.T, rtol=1e-6, atol=1e-8)
    resid = (Y - mu) - (X - np.tile(mu, 4)) @ coef
    np.testing.assert_allclose(model.sigma[0, 0], resid.T @ resid / (len(Y) - 8), rtol=1e-5)


def _psnr(truth, out, mask):
    err = truth[mask].astype(float) - out[mask].astype(float)
    return 10 * np.log10(255.0**2 / np.mean(err**2))


def test_conditional_fill_beats_the_scans_on_a_texture_and_keeps_known_pixels():
    image = skdata.astronaut()[:160, :160]
    mask = np.zeros(image.shape[:2], bool)
    mask[:, 50:53] = mask[80:96, 100:130] = True
    damaged = image.copy()
    damaged[mask] = 255
    out = inpaint(damaged, mask, method="conditional")
    np.testing.assert_array_equal(out[~mask], damaged[~mask])
    assert _psnr(image, out, mask) > _psnr(image, inpaint(damaged, mask, method="scans"),
                                           mask)


def test_edge_test_recovers_soft_edges_and_leaves_hard_ones(monkeypatch):
    """A blotch with a one-pixel fringe (a 50 % blend) outside its mask: the
    edge test finds the fringe (its blend estimate is 0.47-0.52). Unblended
    fully, or joining the unknowns, the fill goes from 1.1 to 16.7-17.0 dB
    at halo=-12; unblended by half (the default) to 5.6 dB. On the same
    blotch without a fringe it changes nothing (17.85 dB)."""
    from car_napari.inpainting import _filling

    image = skdata.astronaut()[100:228, 100:228]
    mask = np.zeros(image.shape[:2], bool)
    mask[80:100, 60:100] = True
    fringe = ndimage.binary_dilation(mask) & ~mask
    hard = image.copy()
    hard[mask] = 250
    soft = hard.copy()
    soft[fringe] = (0.5 * image[fringe] + 0.5 * 250).astype(np.uint8)
    off = _psnr(image, inpaint(soft, mask, halo=None, method="conditional"), mask)
    for unblend, gain in ((_filling.EdgeTest.unblend, 4.0), (1.0, 15.0), (None, 15.0)):
        monkeypatch.setattr(_filling, "CONDITIONAL_EDGE_TEST", _filling.EdgeTest(unblend=unblend))
        on = inpaint(soft, mask, halo=-12.0, method="conditional")
        np.testing.assert_array_equal(on[~mask], soft[~mask])
        assert _psnr(image, on, mask) > off + gain
        for halo in ("auto", -12.0):
            assert _psnr(image, inpaint(hard, mask, halo=halo, method="conditional"),
                         mask) >= _psnr(image, inpaint(hard, mask, halo=None,
                                                        method="conditional"), mask) - 0.05


@pytest.mark.xfail(strict=True, reason=(
    "the edge test is miscalibrated within the models' reach of the frame's "
    "edge: its clean ring pixels there have chi2 medians of 10-27 (0.2-0.8 "
    "inside, chi-square 1 expected), so they are called damaged and unblended "
    "by half alpha D, D the damage's deviation: a hard-edged scratch one pixel "
    "from the edge is filled 23 grey levels off (4 with halo=None). Not testing "
    "there fixes this case but loses 0.03 dB on the benchmark's soft-edged "
    "composites (TUNING and REPORT): the fix needs a calibrated statistic"))
def test_edge_test_beside_the_frame_edge_leaves_hard_edged_damage_alone():
    """A hard-edged scratch (value 255) one pixel from the frame's right
    edge, and the frame mirrored (the scratch one pixel from the left edge):
    the edge test (``halo="auto"``) changes the fill there as little as it
    does inside the frame, where it changes nothing."""
    rng = np.random.default_rng(0)
    scene = 0.5 + 5 * (ndimage.gaussian_filter(rng.random((64, 66)), 2) - 0.5)
    frame = np.clip(np.round(scene[:, 1:65] * 255), 0, 255).astype(np.uint8)

    def error(image, column, halo):
        mask = np.zeros(image.shape, bool)
        mask[20:40, column] = True
        damaged = image.copy()
        damaged[mask] = 255
        out = inpaint(damaged, mask, halo=halo, method="conditional")
        return int(np.abs(out[mask].astype(int) - image[mask]).max())

    assert error(frame, 32, "auto") == error(frame, 32, None)
    for image, column in ((frame, 62), (frame[:, ::-1], 1)):
        assert error(image, column, "auto") <= 1.5 * error(image, column, None) + 2


def test_draws_have_the_conditional_covariance():
    """The edge test's draws (random signs pushed through the rows, then
    solved) have covariance ``Q_UU^-1``: against the dense precision."""
    from car_napari._progress import drain
    from car_napari.inpainting._local_fits import _row_sets
    from car_napari.inpainting._solver import iter_stencil_solve

    rng = np.random.default_rng(3)
    H, W, C = 8, 9, 2
    frame = rng.normal(size=(H, W, C))
    unknown = np.zeros((H, W), bool)
    unknown[3:5, 3:6] = True
    base = causal_neighbourhood(2)
    models = [_random_model(rng, direction_offsets(base, d), C, np.zeros(C))
              for d in ("down", "up")]
    _, draws, diagonal = drain(iter_stencil_solve(frame, unknown, _row_sets(models, None),
                                                  100, probes=20000))
    P, _ = _dense_precision(models, H, W)
    u = np.repeat(unknown.reshape(-1), C)
    Quu = P[np.ix_(u, u)]
    flat = draws.transpose(1, 0, 2).reshape(draws.shape[1], -1)
    exact = np.linalg.inv(Quu)
    error = flat.T @ flat / len(flat) - exact
    assert np.linalg.norm(error) < 0.03 * np.linalg.norm(exact)  # sampling: ~0.01
    n = unknown.sum()
    blocks = Quu.reshape(n, C, n, C)[np.arange(n), :, np.arange(n), :]
    np.testing.assert_allclose(diagonal, blocks, rtol=1e-12)


def test_tiled_fit_is_each_windows_least_squares_fit():
    """Several tiles: each tile's model is the least-squares fit over its
    window (the tile and ``margin`` pixels round it), plain NumPy."""
    rng = np.random.default_rng(4)
    frame = ndimage.uniform_filter(rng.random((40, 52, 1)), (3, 3, 1))
    unknown = np.zeros((40, 52), bool)
    unknown[15:19, 20:30] = True
    offsets = causal_neighbourhood(1)
    tile, margin = 16, 8
    (model,) = fit_local_models(frame, unknown, [offsets], tile=tile, margin=margin,
                                prior=1e-12)
    for a, b in ((0, 0), (1, 2), (2, 3)):
        i0, i1 = max(a * tile - margin, 0), min((a + 1) * tile + margin, 40)
        j0, j1 = max(b * tile - margin, 0), min((b + 1) * tile + margin, 52)
        rows, targets = [], []
        for i in range(i0, i1):
            for j in range(j0, j1):
                nb = [(i - di, j - dj) for di, dj in offsets]
                if unknown[i, j] or not all(0 <= p < 40 and 0 <= q < 52 and not unknown[p, q]
                                            for p, q in nb):
                    continue
                rows.append(np.concatenate([frame[p, q] for p, q in nb]))
                targets.append(frame[i, j])
        X, Y = np.array(rows), np.array(targets)
        mu = Y.mean(axis=0)
        coef = np.linalg.lstsq(X - mu, Y - mu, rcond=None)[0]
        np.testing.assert_allclose(model.mean[a, b], mu, rtol=1e-10)
        np.testing.assert_allclose(model.gamma[a, b], coef.T, rtol=1e-5, atol=1e-8)


def test_conditional_fill_yields_often_and_stops_when_closed():
    """Records between the fit's bands, the assembly's row sets and the
    solves, fractions rising; closing the job mid-way stops it."""
    from car_napari.inpainting import iter_inpaint

    image = skdata.astronaut()[:200, :200]
    mask = np.zeros(image.shape[:2], bool)
    mask[:, 50:53] = mask[120:140, 100:150] = True
    records = []
    job = iter_inpaint(image, mask, method="conditional")
    for record in job:
        records.append(record)
    fractions = [r.fraction for r in records]
    assert len(records) >= 10 and fractions == sorted(fractions)
    assert {"solving", "assembling", "fitting"} <= {
        word for r in records for word in ("solving", "assembling", "fitting")
        if word in r.message}
    job = iter_inpaint(image, mask, method="conditional")
    for record in job:
        if "solving" in record.message:
            break
    job.close()
    assert job.gi_frame is None


def test_edge_statistics_match_a_pixel_by_pixel_computation():
    """The edge test's blend, its chi-square and the blend pooled over the
    ring nearby, against plain loops over the ring pixels."""
    from car_napari.inpainting._edges import EDGE_POOL, edge_statistics

    rng = np.random.default_rng(5)
    H, W, C, probes, region = 24, 26, 3, 4, 3
    frame, trial = rng.normal(size=(2, H, W, C))
    damage = np.zeros((H, W), bool)
    damage[0:6, 4:9] = damage[12:20, 14:16] = True
    ring = ndimage.binary_dilation(damage) & ~damage
    bi, bj = np.nonzero(ring)
    n = len(bi)
    draws = rng.normal(size=(n, probes, C))
    roots = rng.normal(size=(n, C, C))
    diagonal = roots @ roots.transpose(0, 2, 1) + C * np.eye(C)
    alpha, chi2, pooled, blend_d = edge_statistics(frame, trial, damage, ring, draws,
                                                   diagonal, region=region)

    kappa = [np.trace(diagonal[k] @ draws[k].T @ draws[k] / probes) / C for k in range(n)]

    def near(k, radius):
        return [m for m in range(n) if abs(bi[m] - bi[k]) <= radius
                and abs(bj[m] - bj[k]) <= radius]

    proj, dqd = np.zeros(n), np.zeros(n)
    for k, (i, j) in enumerate(zip(bi, bj, strict=True)):
        inside = [(i + a, j + b) for a, b in ((0, 1), (1, 0), (0, -1), (-1, 0))
                  if 0 <= i + a < H and 0 <= j + b < W and damage[i + a, j + b]]
        D = np.mean([frame[p] - trial[p] for p in inside], axis=0)
        e = frame[i, j] - trial[i, j]
        S_inv = diagonal[k] / np.mean([kappa[m] for m in near(k, EDGE_POOL)])
        proj[k], dqd[k] = D @ S_inv @ e, D @ S_inv @ D
        np.testing.assert_allclose(blend_d[k], D, rtol=1e-12)
    np.testing.assert_allclose(alpha, proj / dqd, rtol=1e-9)
    np.testing.assert_allclose(chi2, proj**2 / dqd, rtol=1e-9)
    want = [sum(proj[near(k, region)]) / sum(dqd[near(k, region)]) for k in range(n)]
    np.testing.assert_allclose(pooled, want, rtol=1e-9, atol=1e-12)
    none = edge_statistics(frame, trial, damage, np.zeros_like(ring), draws[:0], diagonal[:0])
    assert [a.shape for a in none] == [(0,), (0,), (0,), (0, C)]


def test_pooled_blend_leaves_a_lone_scene_edge_alone(monkeypatch):
    """A hard-edged bright blotch with a small bright detail of the scene on
    its border (two pixels, a blend of 0.3 towards the blotch, far outside
    the noise): without the pooled blend the edge test calls them damaged;
    with it (0.3 pooled over ~17 ring pixels), none."""
    from car_napari._progress import drain
    from car_napari.inpainting._conditional import iter_fill_conditional

    rng = np.random.default_rng(2)
    frame = rng.normal(0.5, 0.02, size=(96, 96, 1))
    mask = np.zeros((96, 96), bool)
    mask[30:60, 20:60] = True
    frame[mask] = 1.0
    frame[44:46, 60] = 0.65  # the scene's detail, right of the blotch
    calls = {}
    original = _conditional.iter_edge_statistics

    def spy(*args, **options):
        calls["stats"] = yield from original(*args, **options)
        return calls["stats"]

    monkeypatch.setattr(_conditional, "iter_edge_statistics", spy)
    for region_blend, want_flagged in ((-np.inf, True), (0.05, False)):
        drain(iter_fill_conditional(frame, mask, halo=-4.0, halo_region_blend=region_blend))
        edge = calls["stats"]
        bad = (edge.alpha > 0.1) & (-0.5 * edge.chi2 < -4.0) & (edge.pooled > region_blend)
        assert bad.any() == want_flagged


def test_dilation_is_scipys_binary_dilation():
    """The compiled dilation (the fit's ring, the tiles and rows the solves
    visit) against scipy's binary dilation by the cross or the 3 x 3 square,
    ``radius`` iterations, damage touching the borders included."""
    from car_napari.inpainting._local_fits import _dilate

    rng = np.random.default_rng(8)
    mask = rng.random((23, 19)) < 0.04
    mask[0, 5] = mask[22, 18] = mask[10, 0] = True
    cross = ndimage.generate_binary_structure(2, 1)
    square = np.ones((3, 3), bool)
    for radius in (1, 2, 4):
        np.testing.assert_array_equal(
            _dilate(mask, radius), ndimage.binary_dilation(mask, cross, iterations=radius))
        np.testing.assert_array_equal(
            _dilate(mask, radius, square=True),
            ndimage.binary_dilation(mask, square, iterations=radius))
