import numpy as np
import pytest

from car_fields import ORDERS
from car_napari import Context, causal_neighbourhood
from car_napari.model.neighbourhood import as_offsets


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_orders_match_spec_table(order):
    assert causal_neighbourhood(order).tolist() == [list(s) for s in ORDERS[order]]


def test_orders_are_nested_and_causal():
    for k in range(1, 12):
        small, big = causal_neighbourhood(k), causal_neighbourhood(k + 1)
        assert np.array_equal(big[: len(small)], small)
        di, dj = big.T
        assert np.all((di > 0) | ((di == 0) & (dj > 0)))


@pytest.mark.parametrize("bad", [0, 31, -1])
def test_order_out_of_range(bad):
    with pytest.raises(ValueError, match="order"):
        causal_neighbourhood(bad)


@pytest.mark.parametrize(
    "offsets, match",
    [
        ([[0, -1]], "not causal"),
        ([[0, 0]], "not causal"),
        ([[-1, 2]], "not causal"),
        ([[0, 1], [0, 1]], "duplicates"),
        ([[0.5, 1]], "integers"),
        (np.zeros((0, 2)), "non-empty"),
        ([0, 1, 1], r"\(eta, 2\)"),
    ],
)
def test_invalid_offsets(offsets, match):
    with pytest.raises(ValueError, match=match):
        as_offsets(offsets)


def test_custom_offsets_accepted():
    offsets, order = as_offsets([[0, 3], [2, -1]])
    assert order is None and offsets.tolist() == [[0, 3], [2, -1]]


def test_spatial_context_order_is_spec_gamma_layout():
    ctx = Context.spatial(causal_neighbourhood(1), 3)
    # X_r = [Y_{r-s1}; Y_{r-s2}], channel fastest
    assert ctx.taps.tolist() == [[0, 1, 0], [0, 1, 1], [0, 1, 2], [1, 0, 0], [1, 0, 1], [1, 0, 2]]
    assert ctx.reach == ((1, 0), (1, 0))


def test_context_allows_non_causal_taps_into_known_channels():
    # 2.5D/3.5D: the other image (channel 1) at r itself is a valid regressor
    ctx = Context(taps=[[0, 1, 0], [0, 0, 1], [-1, -1, 1]], targets=[0])
    assert ctx.reach == ((0, 1), (1, 1))
    with pytest.raises(ValueError, match="causal"):
        Context(taps=[[0, 0, 0]], targets=[0])
