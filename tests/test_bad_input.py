"""Bad input gets a clear error naming the problem and the fix."""

import numpy as np
import pytest

from car_napari import (
    fit_car,
    illumination_invariants,
    local_parameters,
    predict,
    restore,
    select_support,
)

rng = np.random.default_rng(0)
GOOD = rng.random((32, 32, 3))

ENTRY_POINTS = [
    lambda im, **kw: fit_car(im, 2, **kw),
    lambda im, **kw: select_support(im, **kw),
    lambda im, **kw: local_parameters(im, 2, **kw),
    lambda im, **kw: illumination_invariants(im, **kw),
]


@pytest.mark.parametrize("call", ENTRY_POINTS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_inf(call, bad):
    img = GOOD.copy()
    img[3, 4, 1] = bad
    with pytest.raises(ValueError, match="NaN or infinite"):
        call(img)


@pytest.mark.parametrize("call", ENTRY_POINTS + [
    lambda im, **kw: predict(fit_car(GOOD, 1), im, **kw),
    lambda im, **kw: restore(im, **kw),
    lambda im, **kw: restore(im, estimator="recursive", **kw),
])
@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e160, 1e300])
def test_extreme_magnitude_is_a_clear_error(call, scale):
    # their squares leave float64: a message, never NaN output or LinAlgError
    img = GOOD * scale
    with pytest.raises(ValueError, match="magnitude .* Rescale"):
        call(img)
    np.testing.assert_array_equal(img, GOOD * scale)  # the input is untouched


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_wrong_number_of_dimensions(call):
    with pytest.raises(ValueError, match="2-D .* or 3-D"):
        call(np.zeros((2, 8, 8, 3)))
    with pytest.raises(ValueError, match="2-D .* or 3-D"):
        call(np.zeros(10))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_smaller_than_neighbourhood(call):
    with pytest.raises(ValueError, match="too small"):
        call(GOOD[:2, :2])


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_constant_image(call):
    with pytest.raises(ValueError, match="constant"):
        call(np.full((32, 32), 0.5))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_empty_image(call):
    with pytest.raises(ValueError, match="empty"):
        call(np.zeros((0, 5)))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_non_numeric(call):
    with pytest.raises(TypeError, match="dtype"):
        call(np.array([["a", "b"], ["c", "d"]]))
    with pytest.raises(TypeError, match="None"):
        call(None)


@pytest.mark.parametrize(
    "neighbourhood, match",
    [([[0, -1]], "not causal"), ([[1]], r"\(eta, 2\)"), (0, "order"), ("big", "order")],
)
def test_invalid_offsets(neighbourhood, match):
    with pytest.raises(ValueError, match=match):
        fit_car(GOOD, neighbourhood)
    if not isinstance(neighbourhood, str):
        with pytest.raises(ValueError, match=match):
            local_parameters(GOOD, neighbourhood)


def test_bad_options():
    with pytest.raises(ValueError, match="forgetting"):
        local_parameters(GOOD, 1, forgetting=1.5)
    with pytest.raises(ValueError, match="direction"):
        local_parameters(GOOD, 1, direction="diagonal")
    with pytest.raises(ValueError, match="model"):
        fit_car(GOOD, 1, model="4d")
    with pytest.raises(ValueError, match="channel_axis"):
        fit_car(GOOD, 1, channel_axis=None)


def test_predict_with_wrong_channels():
    model = fit_car(GOOD, 1)
    with pytest.raises(ValueError, match="3 channels|fitted to 3"):
        predict(model, GOOD[..., 0])
    with pytest.raises(TypeError, match="CARModel"):
        predict("model", GOOD)


def test_channel_axis_first():
    a = fit_car(GOOD, 1)
    b = fit_car(np.moveaxis(GOOD, -1, 0), 1, channel_axis=0)
    np.testing.assert_allclose(a.gamma, b.gamma)


@pytest.mark.parametrize("option, value, error", [
    ("forgetting", np.nan, ValueError), ("forgetting", 0.0, ValueError),
    ("forgetting", 1.5, ValueError), ("forgetting", "0.9", TypeError),
    ("prior", np.inf, ValueError), ("prior", -1.0, ValueError), ("prior", None, TypeError),
    ("warm_start", "yes", TypeError),
])
def test_local_parameters_options_checked_first(option, value, error):
    # a string image would fail too: the option's message must come first
    with pytest.raises(error, match=option):
        local_parameters("not an image", 1, **{option: value})


@pytest.mark.parametrize("margin, error", [(-5, ValueError), (2.5, ValueError),
                                           (10**7, ValueError), ("8", TypeError)])
def test_synthesis_margin_is_checked(margin, error):
    from car_napari import synthesize

    with pytest.raises(error, match="margin"):
        synthesize(fit_car(GOOD, 1), (16, 16), margin=margin)
    assert synthesize(fit_car(GOOD, 1), (16, 16), margin=0, seed=0).shape == (16, 16, 3)
