"""Whole-image estimation, the decision rule and prediction ((14.7)-(14.14), (14.6),
(14.23)-(14.25), docs/model.md)."""

import numpy as np
import pytest
from skimage import data as skdata

from car_fields import ORDERS, car_field, gamma_of, random_stable_model
from car_napari import CARModel, Progress, fit_car, predict, select_support
from car_napari._progress import drain
from car_napari.model import (
    Prediction,
    SupportSelection,
    iter_fit_car,
    iter_select_support,
)


def test_fit_recovers_true_parameters_of_a_3dcar_field():
    A, offsets, sigma = random_stable_model(2, 3, seed=0)
    field = car_field(A, offsets, sigma, (256, 256), seed=1)
    model = fit_car(field, 2)
    assert isinstance(model, CARModel)
    assert model.gamma.shape == (3, 12) and model.sigma.shape == (3, 3)
    assert model.offsets.tolist() == [list(s) for s in offsets]
    assert np.abs(model.gamma - gamma_of(A)).max() < 0.03
    assert np.abs(model.sigma - sigma).max() < 0.1
    np.testing.assert_allclose(model.A, A, atol=0.03)


def test_fit_equals_plain_least_squares_on_centred_data():
    img = skdata.astronaut()[200:260, 180:250] / 255.0
    model = fit_car(img, 3)
    Y = img - img.mean(axis=(0, 1))
    offs = ORDERS[3]
    H, W, d = Y.shape
    X = np.concatenate([Y[2 - a : H - a, 2 - b : W - 1 - b] for a, b in offs], axis=2)
    X = X.reshape(-1, d * len(offs))
    T = Y[2:H, 2 : W - 1].reshape(-1, d)
    # our documented choice: exactly flat neighbourhoods (saturated here) carry no texture
    flat = np.all(X == np.tile(T, len(offs)), axis=1)
    assert 0 < flat.sum() < 0.5 * flat.size
    X, T = X[~flat], T[~flat]
    coef, *_ = np.linalg.lstsq(X, T, rcond=None)
    np.testing.assert_allclose(model.gamma, coef.T, rtol=1e-5, atol=1e-6)
    resid = T - X @ coef
    np.testing.assert_allclose(model.lam, resid.T @ resid, rtol=1e-4)
    assert model.n_pixels == X.shape[0]
    np.testing.assert_allclose(model.sigma, model.lam / model.beta)


@pytest.mark.parametrize("d", [1, 3])
@pytest.mark.parametrize("true_order", [2, 3, 5])
def test_decision_rule_picks_true_order(d, true_order):
    hits = 0
    for seed in range(10):
        A, offsets, sigma = random_stable_model(true_order, d, seed=seed)
        field = car_field(A, offsets, sigma, (128, 128), seed=100 + seed)
        best, scores = select_support(field, orders=range(1, 6))
        assert set(scores) == {1, 2, 3, 4, 5}
        hits += best == true_order
    assert hits >= 9


def test_decision_rule_is_scale_invariant():
    img = skdata.brick()[:128, :128]
    best8, scores8 = select_support(img)
    best_f, scores_f = select_support(img.astype(float) * 1000.0)
    assert best8 == best_f
    np.testing.assert_allclose(list(scores8.values()), list(scores_f.values()), rtol=1e-9)


def test_auto_support_is_used_by_fit():
    img = skdata.gravel()[:128, :128]
    model = fit_car(img, "auto")
    best, scores = select_support(img)
    assert model.order == best and model.scores == scores


def _density_probe(model, x_values, y_grid):
    """Log density at pixel (1, 3k+1) of a (2, 3K) image whose neighbours are
    fixed (order 2: up-left, up, up-right, left) and whose value runs over y_grid."""
    d = model.n_channels
    K = len(y_grid)
    img = np.zeros((2, 3 * K, d))
    up_left, up, up_right, left = x_values
    img[0, 0::3], img[0, 1::3], img[0, 2::3], img[1, 0::3] = up_left, up, up_right, left
    img[1, 1::3] = y_grid
    img[1, 2::3] = y_grid  # any value; these pixels are not probed
    mean, logp = predict(model, img if d > 1 else img[..., 0])
    return mean.reshape(2, 3 * K, d)[1, 1::3], logp[1, 1::3]


@pytest.mark.parametrize("d", [1, 2])
def test_predictive_density_integrates_to_one_with_mean_gamma_x(d):
    rng = np.random.default_rng(d)
    A, offsets, sigma = random_stable_model(2, d, seed=d)
    field = car_field(A, offsets, sigma, (14, 14), seed=7) + 3.0
    model = fit_car(field, 2)
    x_values = [rng.standard_normal(d) + 3.0 for _ in range(4)]
    # ordering of X_r (docs/model.md): offsets (0,1)=left, (1,0)=up, (1,-1)=up-right,
    # (1,1)=up-left
    X = np.concatenate([x_values[k] - model.mean for k in (3, 1, 2, 0)])
    expected_mean = model.gamma @ X + model.mean
    sd = np.sqrt(np.diag(model.sigma))
    if d == 1:
        y = expected_mean[0] + np.linspace(-25, 25, 4001) * sd[0]
        mean, logp = _density_probe(model, x_values, y[:, None])
        p = np.exp(logp)
        assert np.trapezoid(p, y) == pytest.approx(1.0, abs=1e-6)
        assert np.trapezoid(y * p, y) == pytest.approx(expected_mean[0], abs=1e-6)
        np.testing.assert_allclose(mean[:, 0], expected_mean[0], rtol=1e-9)
    else:
        g0 = expected_mean[0] + np.linspace(-10, 10, 241) * sd[0]
        g1 = expected_mean[1] + np.linspace(-10, 10, 241) * sd[1]
        Y0, Y1 = np.meshgrid(g0, g1, indexing="ij")
        ys = np.stack([Y0.ravel(), Y1.ravel()], axis=1)
        mean, logp = _density_probe(model, x_values, ys)
        p = np.exp(logp).reshape(Y0.shape)
        total = np.trapezoid(np.trapezoid(p, g1, axis=1), g0)
        assert total == pytest.approx(1.0, abs=1e-4)
        m0 = np.trapezoid(np.trapezoid(p * Y0, g1, axis=1), g0)
        m1 = np.trapezoid(np.trapezoid(p * Y1, g1, axis=1), g0)
        np.testing.assert_allclose([m0, m1], expected_mean, atol=1e-4 * sd.max())
        np.testing.assert_allclose(mean[0], expected_mean, rtol=1e-9)


def test_predict_shapes_and_borders():
    img = skdata.astronaut()[:40, :50]
    model = fit_car(img, 2)
    mean, logp = predict(model, img)
    assert mean.shape == img.shape and logp.shape == img.shape[:2]
    assert np.isnan(logp[0]).all() and np.isnan(logp[:, 0]).all() and np.isnan(logp[:, -1]).all()
    assert np.isfinite(logp[1:, 1:-1]).all()
    # a well-fitted model predicts its own texture better than the mean does
    inner = (slice(1, None), slice(1, -1))
    assert np.mean((mean[inner] - img[inner] / 255.0) ** 2) < np.var(img / 255.0)


def test_2d_path_spectral_factors():
    img = skdata.astronaut()[100:228, 100:228]
    model = fit_car(img, "auto", model="2d")
    assert len(model.factors) == 3
    np.testing.assert_allclose(model.basis.T @ model.basis, np.eye(3), atol=1e-12)
    # each factor's A_s are the diagonal of the colour-space A_s in the PCA basis
    A_pca = model.basis.T @ model.A @ model.basis
    for k, fm in enumerate(model.factors):
        pos = {tuple(s): i for i, s in enumerate(model.offsets.tolist())}
        for s, a in zip(map(tuple, fm.offsets.tolist()), fm.gamma[0], strict=True):
            assert A_pca[pos[s], k, k] == pytest.approx(a)
        off = A_pca[:, k, :].copy()
        off[:, k] = 0
        assert np.abs(off).max() < 1e-12
    mean, logp = predict(model, img)
    assert mean.shape == img.shape and np.isfinite(logp[5:-5, 5:-5]).all()


def test_predict_density_equals_independent_student_t():
    """logp of predict() against a multivariate t written out in NumPy from
    plain least-squares statistics ((14.23), docs/model.md: nu = beta - d*eta + 2)."""
    from math import lgamma

    img = skdata.astronaut()[300:340, 0:50] / 255.0
    model = fit_car(img, 1)
    _, logp = predict(model, img)
    Y = img - img.mean(axis=(0, 1))
    X = np.concatenate([Y[1:, :-1], Y[:-1, 1:]], axis=2).reshape(-1, 6)  # (0,1), (1,0)
    T = Y[1:, 1:].reshape(-1, 3)
    Vx, Vxy, Vy = X.T @ X, X.T @ T, T.T @ T
    gT = np.linalg.solve(Vx, Vxy)
    lam = Vy - Vxy.T @ gT
    beta = 6 - 1 + X.shape[0]
    nu = beta - 6 + 2
    E = T - X @ gT
    q = 1 + np.einsum("ij,ij->i", X, np.linalg.solve(Vx, X.T).T)
    maha = np.einsum("ij,ij->i", E, np.linalg.solve(lam, E.T).T)
    ref = (
        lgamma((nu + 3) / 2) - lgamma(nu / 2) - 1.5 * np.log(np.pi * q)
        - 0.5 * np.linalg.slogdet(lam)[1] - (nu + 3) / 2 * np.log1p(maha / q)
    )
    np.testing.assert_allclose(logp[1:, 1:].ravel(), ref, rtol=1e-6)


def test_grey_image_stored_as_rgb():
    # Exactly collinear channels: the model is not identifiable in two colour
    # directions, so the prior pins them; nothing may crash or blow up.
    grey = skdata.camera()[:96, :96]
    rgb = np.repeat(grey[..., None], 3, axis=2)
    rgb_nearly = rgb.astype(float)
    rgb_nearly[5, 5, 1] += 1.0
    for img in (rgb, rgb_nearly):
        best, scores = select_support(img)
        model = fit_car(img, "auto")
        mean, logp = predict(model, img)
        assert np.all(np.isfinite(list(scores.values())))
        assert np.isfinite(mean[3:, 3:-3]).all() and np.isfinite(logp[3:, 3:-3]).all()
        assert np.abs(model.gamma).max() < 10


def _same_model(a, b):
    for name in ("gamma", "sigma", "mean", "offsets", "lam", "vx"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.beta, a.n_pixels, a.order, a.scores, a.direction) == (
        b.beta, b.n_pixels, b.order, b.scores, b.direction)


def _run(job):
    records = []
    result = drain(job, records.append)
    assert records and all(isinstance(r, Progress) for r in records)
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and 0 <= fractions[0] and fractions[-1] == 1.0
    return result, records


@pytest.mark.parametrize("kwargs", [
    dict(neighbourhood=2),
    dict(neighbourhood="auto", orders=range(1, 4)),
    dict(neighbourhood="auto", model="2d", orders=[1, 2]),
    dict(neighbourhood=[[0, 1], [2, 0]], direction="left"),
])
def test_iter_fit_car_yields_progress_and_returns_what_fit_car_returns(kwargs):
    img = skdata.astronaut()[100:164, 100:164]
    model, records = _run(iter_fit_car(img, **kwargs))
    assert isinstance(model, CARModel)
    _same_model(model, fit_car(img, **kwargs))
    if model.factors is not None:
        for a, b in zip(model.factors, fit_car(img, **kwargs).factors, strict=True):
            _same_model(a, b)
    assert records[-1].stage == "statistics"


def test_iter_fit_car_reports_every_candidate_order():
    img = skdata.gravel()[:96, :96]
    model, records = _run(iter_fit_car(img, "auto", orders=range(1, 6)))
    support = [r for r in records if r.stage == "support"]
    scored = [r.message for r in support if ": D = " in r.message]
    assert [m.split(":")[0] for m in scored] == [f"order {k}" for k in range(1, 6)]
    assert records.index(support[-1]) < records.index(
        next(r for r in records if r.stage == "statistics"))
    # the scores printed are the model's
    for k, m in zip(range(1, 6), scored, strict=True):
        assert float(m.split("= ")[1]) == pytest.approx(model.scores[k], rel=1e-5)


def test_iter_select_support_returns_what_select_support_returns():
    img = skdata.brick()[:96, :96]
    selection, records = _run(iter_select_support(img, orders=[1, 2, [[0, 1], [1, 1]]]))
    assert isinstance(selection, SupportSelection)
    best, scores = select_support(img, orders=[1, 2, [[0, 1], [1, 1]]])
    assert selection.best == best and selection.scores == scores
    assert {r.stage for r in records} == {"support"}
    assert records[-1].message.startswith("candidate 3/3: D = ")


def test_predict_returns_a_named_pair():
    img = skdata.camera()[:32, :32]
    result = predict(fit_car(img, 1), img)
    assert isinstance(result, Prediction)
    mean, logp = result
    assert result.mean is mean and result.log_density is logp


def test_closing_a_fit_stops_it():
    job = iter_fit_car(skdata.astronaut()[:128, :128], "auto")
    assert next(job).stage == "support"
    job.close()


def _design(Y, offsets, reach):
    """(X, T) of plain NumPy least squares over the pixels whose neighbourhood
    under ``reach = (up, left, right)`` lies inside Y (the raster scan):
    X_r = [Y_{r-s_1}; ...; Y_{r-s_eta}], T_r = Y_r."""
    H, W, d = Y.shape
    up, left, right = reach
    X = np.concatenate([Y[up - a : H - a, left - b : W - right - b] for a, b in offsets],
                       axis=2).reshape(-1, d * len(offsets))
    return X, Y[up:H, left : W - right].reshape(-1, d)


@pytest.mark.parametrize("d", [1, 2])
def test_decision_scores_equal_the_formula_written_out_in_numpy(d):
    """D_j of (14.6), docs/model.md, from plain least-squares statistics of the
    channels whitened by PCA (any whitening gives the same D_j: the
    log-determinants do not see a rotation), every candidate on the pixels
    whose order-3 neighbourhood lies inside, beta(0) = d*eta - 1, V_0 = 1e-9 I."""
    from math import lgamma

    A, offsets, sigma = random_stable_model(2, d, seed=11 + d)
    field = car_field(A, offsets, sigma, (40, 44), seed=5) + 0.5
    _, scores = select_support(field if d > 1 else field[..., 0], orders=[1, 2, 3])
    Y = field - field.mean(axis=(0, 1))
    flat = Y.reshape(-1, d)
    evals, evecs = np.linalg.eigh(flat.T @ flat / flat.shape[0])
    Y = (flat @ evecs / np.sqrt(evals)).reshape(Y.shape)
    want = {}
    for order in (1, 2, 3):
        X, T = _design(Y, ORDERS[order], (2, 2, 1))  # the union's reach: order 3
        m, n = X.shape[1], X.shape[0]
        Z = np.hstack([X, T])
        V = Z.T @ Z + 1e-9 * np.eye(m + d)
        Vx, Vxy, Vy = V[:m, :m], V[:m, m:], V[m:, m:]
        lam = Vy - Vxy.T @ np.linalg.solve(Vx, Vxy)
        beta0 = m - 1.0
        beta = beta0 + n
        eta = len(ORDERS[order])
        want[order] = (
            -d / 2 * np.linalg.slogdet(Vx)[1]
            - (beta - m + d + 1) / 2 * np.linalg.slogdet(lam)[1]
            + d * d * eta / 2 * np.log(np.pi)
            + sum(lgamma((beta - m + d + 2 - i) / 2) - lgamma((beta0 - m + d + 2 - i) / 2)
                  for i in range(1, d + 1))
        )
    assert set(scores) == set(want)
    for order in want:
        assert scores[order] == pytest.approx(want[order], rel=1e-9, abs=1e-6), order


def test_2d_path_factors_and_density_equal_least_squares_on_the_pca_factors():
    """model='2d' against plain NumPy: the spectral factors are the principal
    components of the centred pixels (by SVD here), each gets the least-squares
    2DCAR of its own factor, the colour-space A_s and sigma are those rotated
    back, and predict's log density is the sum of the factors' Student-t
    densities ((14.23), nu = beta - eta + 2) since the rotation is orthonormal."""
    from math import lgamma

    img = skdata.astronaut()[300:340, 0:50] / 255.0
    model = fit_car(img, 1, model="2d")
    mean, logp = predict(model, img)
    Y = img - img.mean(axis=(0, 1))
    _, _, vt = np.linalg.svd(Y.reshape(-1, 3), full_matrices=False)
    basis = vt.T  # strongest first; each column's sign is arbitrary, as is the model's
    np.testing.assert_allclose(np.abs(basis.T @ model.basis), np.eye(3), atol=1e-8)
    A = np.zeros((2, 3, 3))
    sigma = np.zeros((3, 3))
    ref_logp = np.zeros(39 * 49)
    ref_mean = np.zeros((39 * 49, 3))
    for k in range(3):
        f = (Y @ basis[:, k])[..., None]
        X, T = _design(f, ORDERS[1], (1, 1, 0))
        coef, *_ = np.linalg.lstsq(X, T, rcond=None)
        resid = T - X @ coef
        lam = float(resid[:, 0] @ resid[:, 0])
        beta = 1 + X.shape[0]
        np.testing.assert_allclose(model.factors[k].gamma, coef.T, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(model.factors[k].lam[0, 0], lam, rtol=1e-6)
        A += coef[:, 0, None, None] * np.outer(basis[:, k], basis[:, k])
        sigma += lam / beta * np.outer(basis[:, k], basis[:, k])
        nu = beta - 2 + 2
        q = 1 + np.einsum("ij,ij->i", X, np.linalg.solve(X.T @ X, X.T).T)
        e = resid[:, 0]
        ref_logp += (lgamma((nu + 1) / 2) - lgamma(nu / 2) - 0.5 * np.log(np.pi * q)
                     - 0.5 * np.log(lam) - (nu + 1) / 2 * np.log1p(e * e / (lam * q)))
        ref_mean += np.outer((X @ coef)[:, 0], basis[:, k])
    np.testing.assert_allclose(model.A, A, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(model.sigma, sigma, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(logp[1:, 1:].ravel(), ref_logp, rtol=1e-6)
    np.testing.assert_allclose(mean[1:, 1:].reshape(-1, 3), ref_mean + img.mean(axis=(0, 1)),
                               rtol=1e-7, atol=1e-9)
