"""Synthesis from the model equation and the stability test (synthesis, docs/model.md)."""

import numpy as np
import pytest
from skimage import data as skdata

from car_fields import car_field, random_stable_model
from car_napari import CARModel, fit_car, spectral_radius, synthesize


@pytest.mark.parametrize("name, order", [("gravel", 3), ("grass", 2)])
def test_refit_of_synthesis_matches_first_fit(name, order):
    texture = getattr(skdata, name)()
    first = fit_car(texture, order)
    sample = synthesize(first, (512, 512), seed=0)
    second = fit_car(sample, order)
    assert np.abs(second.gamma - first.gamma).max() < 0.05
    np.testing.assert_allclose(second.sigma, first.sigma, rtol=0.05)
    np.testing.assert_allclose(second.mean, first.mean, atol=0.05)


def test_refit_colour_texture():
    texture = skdata.astronaut()[300:450, 30:180]  # grass-like background
    first = fit_car(texture, 2)
    second = fit_car(synthesize(first, (512, 512), seed=3), 2)
    assert np.abs(second.gamma - first.gamma).max() < 0.05


def test_shape_seed_and_channels():
    model = fit_car(skdata.astronaut()[:64, :64], 1)
    a = synthesize(model, (30, 70), seed=5)
    b = synthesize(model, (30, 70), seed=5)
    c = synthesize(model, (30, 70), seed=6)
    assert a.shape == (30, 70, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    grey = synthesize(fit_car(skdata.camera()[:64, :64], 1), (17, 9), seed=0)
    assert grey.shape == (17, 9)


@pytest.mark.parametrize("direction", ["up", "right", "left"])
def test_synthesis_in_other_directions_has_the_model_statistics(direction):
    A, offsets, sigma = random_stable_model(2, 1, seed=4)
    field = car_field(A, offsets, sigma, (200, 200), seed=2)[..., 0]
    # the image whose scan in 'direction' reads the raster field: fitting there recovers A
    model = fit_car(_unscan(field, direction), 2, direction=direction)
    np.testing.assert_allclose(model.gamma[0], [a[0, 0] for a in A], atol=0.03)
    out = synthesize(model, (150, 120), seed=1)
    assert out.shape == (150, 120)
    refit = fit_car(out, 2, direction=direction)
    np.testing.assert_allclose(refit.gamma, model.gamma, atol=0.06)


def _unscan(field, direction):
    """The image whose scan in ``direction`` reads ``field`` in raster order."""
    return {"up": field[::-1], "right": field.T, "left": field.T[:, ::-1]}[direction]


def test_unstable_model_raises_clear_error():
    model = fit_car(np.random.default_rng(0).random((20, 20)), 1)
    model.gamma = np.array([[0.6, 0.55]])  # Y = 0.6 left + 0.55 up: grows row after row
    assert spectral_radius(model) > 1
    with pytest.raises(ValueError, match="unstable"):
        synthesize(model, (32, 32), seed=0)


def test_stability_criterion_agrees_with_a_real_explosion():
    # The brick texture's order-2 least-squares model is (just) unstable; order 5 is not.
    brick = skdata.brick()
    unstable, stable = fit_car(brick, 2), fit_car(brick, 5)
    assert spectral_radius(unstable) > 1 > spectral_radius(stable)
    with pytest.raises(ValueError, match="unstable"):
        synthesize(unstable, (64, 64))
    out = synthesize(stable, (600, 300), seed=0)
    top, bottom = out[:300].std(), out[300:].std()
    assert 0.8 < bottom / top < 1.25


def test_bad_shapes_and_model():
    model = fit_car(skdata.camera()[:32, :32], 1)
    with pytest.raises(ValueError, match="shape"):
        synthesize(model, (0, 10))
    with pytest.raises(ValueError, match="shape"):
        synthesize(model, 10)
    with pytest.raises(TypeError, match="CARModel"):
        synthesize(np.eye(2), (10, 10))
    assert isinstance(model, CARModel)


def test_unstable_fit_really_explodes():
    """Not circular: generate with the raw kernel, bypassing the check."""
    from car_napari.model.synthesis import synthesize_field

    for order, explodes in ((2, True), (5, False)):
        model = fit_car(skdata.brick(), order)
        noise = np.random.default_rng(0).standard_normal((1200, 400, 1))
        taps = model.context.taps
        synthesize_field(model.gamma, np.sqrt(model.sigma), noise,
                         taps[:, 0].copy(), taps[:, 1].copy(), taps[:, 2].copy(), 1e300)
        growth = noise[900:1200, 100:300].std() / noise[300:600, 100:300].std()
        assert (growth > 100) == explodes, (order, growth)
        assert (spectral_radius(model) > 1) == explodes


def test_narrow_in_row_resonance_is_found():
    # In-row AR(2) with roots 0.9999 exp(+-i pi/256) plus a tiny vertical tap:
    # the resonance falls between the frequency grid points.
    r, th = 0.9999, np.pi / 256
    model = fit_car(np.random.default_rng(0).random((20, 20)), 3)
    model.gamma = np.zeros((1, 6))
    model.gamma[0, 0] = 2 * r * np.cos(th)  # (0, 1)
    model.gamma[0, 4] = -r * r  # (0, 2)
    model.gamma[0, 1] = 1e-5  # (1, 0)
    assert spectral_radius(model) > 1


def test_synthesis_in_chunks_of_rows_is_the_one_call_field(monkeypatch):
    # issue 12: the field in chunks of rows (and its noise drawn by blocks of
    # rows) is, bit for bit, the field of one kernel call
    from car_napari._progress import drain
    from car_napari.model import blocks, iter_synthesize
    from car_napari.model import synthesize as synth

    rng = np.random.default_rng(4)
    model = fit_car(rng.random((64, 64, 3)), 2)
    whole = synth(model, (50, 70), seed=3)
    for rows in (1, 7, 1000):
        records = []
        got = drain(iter_synthesize(model, (50, 70), seed=3, chunk_rows=rows), records.append)
        np.testing.assert_array_equal(got, whole)
        assert records[-1].fraction == 1.0 and records[-1].stage == "synthesis"
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 500)
    np.testing.assert_array_equal(synth(model, (50, 70), seed=3), whole)
    left = fit_car(rng.random((64, 64)), 1, direction="left")
    np.testing.assert_array_equal(drain(iter_synthesize(left, (30, 40), seed=1, chunk_rows=3)),
                                  synth(left, (30, 40), seed=1))


def _one_call_synthesis(model, shape, seed):
    """Today's (session 19's) synthesis, before it became a job: the noise in
    one draw, the field in one kernel call, the crop in one expression."""
    import math

    from car_napari.model.directions import unscan_view
    from car_napari.model.synthesis import synthesize_field

    h, w = shape
    radius = spectral_radius(model)
    margin = int(min(max(math.ceil(math.log(1e-4) / math.log(max(radius, 1e-3))), 16), 256))
    rng = np.random.default_rng(seed)
    d = model.n_channels
    hs, ws = (w, h) if model.direction in ("right", "left") else (h, w)
    reach = int(np.abs(model.offsets).max())
    top = side = margin + reach
    noise = rng.standard_normal((hs + top, ws + 2 * side, d))
    taps = model.context.taps
    chol = np.linalg.cholesky(0.5 * (model.sigma + model.sigma.T) + 1e-300 * np.eye(d))
    limit = 1e8 * max(math.sqrt(float(np.trace(model.sigma))), 1e-300) / max(1 - radius, 1e-6)
    assert synthesize_field(np.ascontiguousarray(model.gamma), chol, noise, taps[:, 0].copy(),
                            taps[:, 1].copy(), taps[:, 2].copy(), limit)
    out = np.ascontiguousarray(unscan_view(noise[top:, side : side + ws], model.direction)
                               + model.mean)
    return out[..., 0] if d == 1 else out


@pytest.mark.parametrize("direction, channels", [("down", 3), ("right", 1), ("up", 2)])
def test_job_is_bit_identical_to_the_one_call_synthesis(direction, channels, monkeypatch):
    # issue 12: the job (noise by blocks, field by chunks, crop by blocks of
    # rows) gives, bit for bit, what the one-call synthesis gave
    from car_napari._progress import drain
    from car_napari.model import blocks, iter_synthesize

    rng = np.random.default_rng(7)
    model = fit_car(rng.random((48, 48, channels)), 2, direction=direction)
    expected = _one_call_synthesis(model, (37, 53), seed=5)
    np.testing.assert_array_equal(synthesize(model, (37, 53), seed=5), expected)
    monkeypatch.setattr(blocks, "BLOCK_VALUES", 300)  # many blocks of every kind
    records = []
    got = drain(iter_synthesize(model, (37, 53), seed=5, chunk_rows=4), records.append)
    np.testing.assert_array_equal(got, expected)
    assert got.shape == expected.shape and got.flags.c_contiguous == expected.flags.c_contiguous
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[0] > 0
    kinds = [r.message.split()[0] for r in records]
    assert kinds.index("rows") > kinds.index("noise") and kinds[-1] == "output"
    # the output records preview the texture filling in: the array returned
    previews = [r.preview for r in records if r.preview is not None]
    assert previews and all(p is previews[-1] for p in previews)
    np.testing.assert_array_equal(previews[-1], got)


def test_job_closed_midway_stops():
    from car_napari.model import iter_synthesize

    model = fit_car(np.random.default_rng(0).random((32, 32)), 1)
    job = iter_synthesize(model, (200, 200), seed=0, chunk_rows=10)
    for record in job:
        if record.message.startswith("rows"):
            break
    job.close()  # a Cancel: no error, nothing more
    assert list(job) == []


def _reference_spectral_radius(model):
    """The stability test one frequency at a time (the form before issue 34's
    batched one), kept as the reference of its numbers."""
    import math

    from car_napari.model.synthesis import _FREQUENCIES, _companion_radius

    A = model.A
    di, dj = model.offsets[:, 0], model.offsets[:, 1]
    d = model.n_channels
    row = [np.zeros((d, d), complex) for _ in range(int(dj[di == 0].max(initial=0)))]
    for a, i, j in zip(A, di, dj, strict=True):
        if i == 0:
            row[j - 1] = row[j - 1] + a
    radius = _companion_radius(row)
    K = int(di.max())
    frequencies = np.linspace(0.0, 2 * np.pi, _FREQUENCIES, endpoint=False)
    if row:
        comp = np.zeros((len(row) * d, len(row) * d), dtype=complex)
        comp[:d, :] = np.hstack(row)
        comp[d:, :-d] = np.eye((len(row) - 1) * d)
        frequencies = np.r_[frequencies, -np.angle(np.linalg.eigvals(comp))]
    for omega in frequencies:
        phase = np.exp(1j * omega * dj)
        lead = np.eye(d, dtype=complex)
        coeffs = [np.zeros((d, d), complex) for _ in range(K)]
        for a, i, ph in zip(A, di, phase, strict=True):
            if i == 0:
                lead -= a * ph
            else:
                coeffs[i - 1] = coeffs[i - 1] + a * ph
        if abs(np.linalg.det(lead)) < 1e-12:
            return math.inf
        radius = max(radius, _companion_radius(coeffs, lead))
    return radius


@pytest.mark.parametrize("channels, order", [(1, 1), (1, 4), (3, 2), (3, 5), (2, 3)])
def test_batched_spectral_radius_equals_the_per_frequency_loop(channels, order):
    rng = np.random.default_rng(order + 10 * channels)
    model = fit_car(rng.random((40, 40, channels)) if channels > 1 else rng.random((40, 40)),
                    order)
    for scale in (0.5, 1.0, 3.0):  # stable and unstable
        model.gamma = model.gamma * scale
        got, want = spectral_radius(model), _reference_spectral_radius(model)
        assert got == want, (scale, got, want)  # bit for bit
    # only vertical taps (no in-row recursion) and a singular in-row filter
    vertical = fit_car(rng.random((30, 30)), np.array([[1, 0], [2, 0]]))
    assert spectral_radius(vertical) == _reference_spectral_radius(vertical)
    singular = fit_car(rng.random((30, 30)), 1)
    singular.gamma = np.array([[1.0, 0.0]])  # (0, 1) tap of 1: A(0, w2) = 0 at w2 = 1
    assert spectral_radius(singular) == _reference_spectral_radius(singular) == np.inf


def _reference_field(gamma, chol, noise, taps, limit):
    """The field's recursion in plain Python, pixel by pixel in raster order
    (Python floats: the same IEEE sums, in the same order, as the kernel)."""
    H, W, _ = noise.shape
    d = gamma.shape[0]
    field = noise.copy()
    for i in range(H):
        for j in range(W):
            x = [float(field[i - di, j - dj, c]) if i - di >= 0 and 0 <= j - dj < W else 0.0
                 for di, dj, c in taps.tolist()]
            drawn = [float(v) for v in field[i, j, :d]]
            values = []
            for t in range(d):
                acc = 0.0
                for c in range(t + 1):
                    acc += float(chol[t, c]) * drawn[c]
                for k in range(len(x)):
                    acc += float(gamma[t, k]) * x[k]
                if not abs(acc) <= limit:
                    return False, field
                values.append(acc)
            field[i, j, :d] = values
    return True, field


@pytest.mark.parametrize("channels, context, order, direction", [
    (1, 0, 2, "down"), (3, 0, 3, "down"), (3, 0, 1, "right"), (2, 0, 2, "down"),
    (1, 1, 2, "down"), (3, 3, 1, "down")])
def test_field_kernel_matches_the_plain_recursion(channels, context, order, direction):
    # the two-row wavefront (grey and colour, C-contiguous) and the scan
    # (other channel counts, strided arrays) against the recursion itself,
    # bit for bit: interior and border pixels, chunks of rows, context
    # channels of the 3.5D model, and an exploding model's early stop
    from car_napari.model.synthesis import innovation_factor, synthesize_field
    from car_napari.texture import temporal_context

    rng = np.random.default_rng(channels + 10 * context + 100 * order)
    model = fit_car(rng.random((40, 40, channels))[..., :channels], order, direction=direction)
    taps = model.context.taps
    gamma = np.ascontiguousarray(model.gamma)
    if context:  # the previous frame's channels, read at (0, 0) and the offsets
        taps = temporal_context(model.offsets, channels).taps
        gamma = rng.normal(0.0, 0.05, (channels, len(taps)))
    chol = innovation_factor(model.sigma)
    args = (taps[:, 0].copy(), taps[:, 1].copy(), taps[:, 2].copy())
    for shape in ((23, 31), (4, 3), (1, 7), (9, 2)):
        noise = rng.standard_normal(shape + (channels + context,))
        ok, want = _reference_field(gamma, chol, noise, taps, 1e8)
        assert ok
        whole = noise.copy()
        assert synthesize_field(gamma, chol, whole, *args, 1e8)
        np.testing.assert_array_equal(whole, want)
        chunked = noise.copy()
        for start in range(0, shape[0], 3):
            assert synthesize_field(gamma, chol, chunked, *args, 1e8, start, start + 3)
        np.testing.assert_array_equal(chunked, want)
        strided = np.zeros((shape[0], 2 * shape[1], noise.shape[2]))[:, ::2]
        strided[...] = noise
        assert synthesize_field(gamma, chol, strided, *args, 1e8)
        np.testing.assert_array_equal(strided, want)
    exploding = gamma * 40.0
    noise = rng.standard_normal((30, 20, channels + context))
    assert not _reference_field(exploding, chol, noise, taps, 1e3)[0]
    assert not synthesize_field(exploding, chol, noise.copy(), *args, 1e3)


def _nshp_radius(gamma):
    """The stability radius of a grey order-3 model written out from its
    transfer function: the in-row recursion y_j = a1 y_{j-1} + a2 y_{j-2}
    (roots of z^2 - a1 z - a2), and for every frequency w the row-to-row
    recursion lead(w) y_i = C1(w) y_{i-1} + C2(w) y_{i-2}, lead(w) = 1 -
    a1 e^{iw} - a2 e^{2iw}, whose roots z solve lead z^2 - C1 z - C2 = 0
    (quadratic formula, on a fine grid plus the arguments of the in-row roots,
    where a resonance peaks)."""
    a1, c10, c1m, c11, a2, c20 = gamma  # ORDERS[3]: (0,1) (1,0) (1,-1) (1,1) (0,2) (2,0)
    in_row = np.roots([1.0, -a1, -a2])
    w = np.r_[np.linspace(0.0, 2 * np.pi, 1 << 16, endpoint=False), -np.angle(in_row)]
    ew = np.exp(1j * w)
    lead = 1 - a1 * ew - a2 * ew**2
    c1 = c10 + c1m / ew + c11 * ew
    root = np.sqrt(c1 * c1 + 4 * lead * c20)
    rows = np.maximum(np.abs((c1 + root) / (2 * lead)), np.abs((c1 - root) / (2 * lead)))
    return max(np.abs(in_row).max(), rows.max())


@pytest.mark.parametrize("seed", range(4))
def test_spectral_radius_equals_the_transfer_function_criterion(seed):
    rng = np.random.default_rng(seed)
    model = fit_car(rng.random((30, 30)), 3)
    base = rng.uniform(-1.0, 1.0, 6)
    base /= np.abs(base).sum()
    for gain in (0.6, 0.95, 1.3):  # stable, nearly unstable, unstable
        model.gamma = (gain * base)[None]
        want = _nshp_radius(model.gamma[0])
        got = spectral_radius(model)
        # a maximum over fewer frequencies than the fine grid: never above it, and close
        assert got <= want * (1 + 1e-9)
        assert got == pytest.approx(want, rel=1e-3), (gain, got, want)
        assert (got < 1) == (want < 1)


def test_burn_in_is_the_rows_until_the_transient_falls_below_the_tolerance():
    """The smallest n with radius**n <= tolerance (counted by repeated
    multiplication in the test), clipped to [16, 256]."""
    from car_napari.model.synthesis import burn_in

    rng = np.random.default_rng(12)
    radii = np.r_[rng.uniform(0.55, 0.999, 40), 0.0, 1e-6, 0.3, 0.9, 0.99, 0.9999]
    for radius in radii:
        for tolerance in (1e-4, 1e-2, 1e-8):
            n, left = 0, 1.0
            while left > tolerance and n < 300:
                left *= radius
                n += 1
            assert burn_in(radius, tolerance) == min(max(n, 16), 256), (radius, tolerance)
    assert burn_in(0.9) == burn_in(0.9, 1e-4)  # the default tolerance


def _rotated(eigenvalues, seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(len(eigenvalues),) * 2))
    return q @ np.diag(eigenvalues) @ q.T


@pytest.mark.parametrize("eigenvalues, jitter", [
    ([2.0, 1.0, 0.5], 0.0),  # positive definite: factored as it is
    ([3.0, 0.0, 0.0], 1e-12),  # rank 1 (grey stored as RGB): the smallest jitter
    ([2.0, 1.0, -1e-10], 1e-9),  # slightly indefinite (rounding): 1e-12 is not enough
    ([2.0, 1.0, -1e-8], 1e-6),
    ([2.0, 1.0, -1e-5], None),  # not semi-definite: an error
])
def test_innovation_factor_adds_the_smallest_listed_jitter_that_factors(eigenvalues, jitter):
    """L lower triangular with L L^T = sigma + jitter (trace / d) I, the
    jitter the first of 1e-12, 1e-9, 1e-6 that makes the matrix positive
    definite (its eigenvalues, from the test's construction, decide: the
    cases are far from the boundary)."""
    from car_napari.model.synthesis import innovation_factor

    sigma = _rotated(np.array(eigenvalues), 13)
    if jitter is None:
        with pytest.raises(ValueError, match="not positive semi-definite"):
            innovation_factor(sigma)
        return
    L = innovation_factor(sigma)
    np.testing.assert_array_equal(L, np.tril(L))
    mean_variance = np.trace(sigma) / 3
    want = sigma + jitter * mean_variance * np.eye(3)
    np.testing.assert_allclose(L @ L.T, want, rtol=0, atol=1e-15 * 8)
    # the jitter added is that one, not a larger or smaller one of the list
    np.testing.assert_allclose(np.diag(L @ L.T - sigma), jitter * mean_variance,
                               rtol=1e-2, atol=1e-15 * 8)
