"""The core's float units (car_napari/_validation.py): integer images scaled
as scikit-image's ``img_as_float`` scales them, and back to uint8 / uint16
as ``img_as_ubyte`` / ``img_as_uint`` do."""

import numpy as np
import pytest
from skimage.util import img_as_float, img_as_ubyte, img_as_uint

from car_napari._validation import as_channel_last_float, from_unit, scale_exponent


def _full_range(dtype, shape, rng):
    """Random values of ``dtype`` over its whole range, both ends included."""
    if dtype == np.bool_:
        return rng.random(shape) < 0.5
    if np.dtype(dtype).kind == "f":
        return rng.normal(0, 3, shape).astype(dtype)
    info = np.iinfo(dtype)
    values = rng.integers(info.min, info.max, shape, dtype=dtype, endpoint=True)
    values.flat[:2] = info.min, info.max
    return values


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32, np.int8, np.int16,
                                   np.int32, np.bool_, np.float16, np.float32, np.float64])
def test_images_are_scaled_as_skimages_img_as_float(dtype):
    """Every dtype, 2-D and 3-D with the channels on each axis: the values
    of ``img_as_float`` (signed integers divided by the dtype's maximum and
    clipped at -1, floats kept; it multiplies by the reciprocal: an ulp
    apart), float64 C-contiguous (H, W, d), the input left alone."""
    rng = np.random.default_rng(0)
    grey = _full_range(dtype, (7, 9), rng)
    kept = grey.copy()
    got = as_channel_last_float(grey, channel_axis=None)
    assert got.dtype == np.float64 and got.flags.c_contiguous and got.shape == (7, 9, 1)
    np.testing.assert_allclose(got[..., 0], img_as_float(grey), rtol=1e-15, atol=0)
    np.testing.assert_array_equal(grey, kept)
    image = _full_range(dtype, (4, 7, 9), rng)
    want = img_as_float(image).astype(np.float64)
    for axis in (0, 1, 2, -1, -3):
        got = as_channel_last_float(image, channel_axis=axis)
        assert got.dtype == np.float64 and got.flags.c_contiguous
        np.testing.assert_allclose(got, np.moveaxis(want, axis, -1), rtol=1e-15, atol=0)
        assert not np.shares_memory(got, image)


def test_signed_and_unsigned_integers_by_the_formula_written_out():
    """The formula on literal values: uint8 and uint16 divided by 255 and
    65535; int16 by 32767, its minimum -32768 clipped to -1; bool 0 and 1."""
    cases = [(np.array([[0, 1, 128, 255]], np.uint8), [0, 1 / 255, 128 / 255, 1]),
             (np.array([[0, 1, 40000, 65535]], np.uint16), [0, 1 / 65535, 40000 / 65535, 1]),
             (np.array([[-32768, -32767, -5, 0, 7, 32767]], np.int16),
              [-1, -1, -5 / 32767, 0, 7 / 32767, 1]),
             (np.array([[True, False]]), [1, 0]),
             (np.array([[-2.5, 0.25, 300.0]], np.float32), [-2.5, 0.25, 300.0])]
    for image, want in cases:
        got = as_channel_last_float(image, channel_axis=None)
        np.testing.assert_allclose(got[0, :, 0], want, rtol=1e-15, atol=0)


def test_from_unit_is_skimages_img_as_ubyte_and_img_as_uint():
    """Back from [0, 1]: uint8 and uint16 as ``img_as_ubyte`` and
    ``img_as_uint`` give them (scaled and rounded), out-of-range values
    clipped to the dtype's ends; other dtypes float32 values as they are;
    an integer image through both ways is itself."""
    rng = np.random.default_rng(1)
    unit = np.concatenate([rng.random(500), [0.0, 1.0, 0.5, 127.5 / 255, 0.4999 / 255]])
    np.testing.assert_array_equal(from_unit(unit, np.uint8), img_as_ubyte(unit))
    np.testing.assert_array_equal(from_unit(unit, np.uint16), img_as_uint(unit))
    assert from_unit(unit, np.uint8).dtype == np.uint8
    assert from_unit(unit, np.uint16).dtype == np.uint16
    np.testing.assert_array_equal(from_unit(np.array([-0.3, 1.7]), np.uint8), [0, 255])
    np.testing.assert_array_equal(from_unit(np.array([-0.3, 1.7]), np.uint16), [0, 65535])
    for dtype in (np.float64, np.int16, np.bool_):
        got = from_unit(np.array([-0.3, 0.1, 1.7]), dtype)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, np.float32([-0.3, 0.1, 1.7]))
    for dtype in (np.uint8, np.uint16):
        image = _full_range(dtype, (6, 8), rng)
        np.testing.assert_array_equal(
            from_unit(as_channel_last_float(image, channel_axis=None)[..., 0], dtype), image)


def _nearest_power(spread):
    """The integer nearest log2(spread), from the binary exponent:
    spread = m 2**k with 0.5 <= m < 1 is nearer 2**k than 2**(k - 1) when
    m >= 2**-0.5 (m is never exactly sqrt(1/2))."""
    m, k = np.frexp(spread)
    return int(k) if m >= np.sqrt(0.5) else int(k) - 1


def test_scale_exponent_is_the_nearest_power_of_two_of_the_spread_beyond_2_to_the_32():
    """e = round(log2(max - min)) when |e| > 32, else 0; 0 for integers,
    constant, empty or non-finite images and values beyond 1e150; the
    scaled spread is then within [2**-0.5, 2**0.5]."""
    rng = np.random.default_rng(6)
    for target in [-480, -300, -120, -34, -33, -32, -5, 0, 5, 32, 33, 34, 120, 300, 440]:
        for _ in range(4):
            image = rng.random((5, 6)) * 2.0 ** (target + rng.uniform(-0.5, 0.5))
            image += rng.normal() * 2.0 ** (target + 2)  # an offset: the spread decides
            image = image.astype(np.float64)
            spread = float(image.max() - image.min())
            want = _nearest_power(spread)
            want = want if abs(want) > 32 else 0
            got = scale_exponent(image)
            assert isinstance(got, int) and got == want, (target, spread)
            if got:
                assert 2**-0.5 <= spread * 2.0**-got <= 2**0.5
            if abs(target) <= 100:  # float32: the spread of its own values
                small = image.astype(np.float32)
                want = _nearest_power(float(small.max()) - float(small.min()))
                assert scale_exponent(small) == (want if abs(want) > 32 else 0)
    # log2(1e-120) = -398.6, log2(3e40 + 5) = 134.5
    for image, want in [(np.array([0, 2**40], np.int64), 0), (np.full((3, 3), 2.0**80), 0),
                        (np.zeros((0, 4)), 0), (np.array([0.0, np.inf]), 0),
                        (np.array([0.0, np.nan]), 0), (np.array([0.0, 2e150]), 0),
                        (np.array([-2e150, 0.0]), 0), (np.array([0.0, 1e-120]), -399),
                        (np.array([-3e40, 5.0]), 134), (np.array([1.0, 1.0 + 2**-32]), 0),
                        (np.array([1.0, 1.0 + 2**-33]), -33)]:
        assert scale_exponent(image) == want, image
