"""Option checks shared by the restoration entry points: fail before any
work, and say what to pass instead."""

from __future__ import annotations

import math

import numpy as np

from .._validation import MAGNITUDE_LIMIT, check_forgetting
from ..model.directions import DIRECTIONS
from ..model.estimation import select_support
from ..model.neighbourhood import as_offsets


def check_kappa(kappa):
    """``kappa`` as a float in [0, 1), or a TypeError/ValueError that says so."""
    if isinstance(kappa, (bool, np.bool_)) or not isinstance(kappa, (int, float, np.number)):
        raise TypeError(f"kappa must be a number in [0, 1); got {kappa!r}.")
    value = float(kappa) if not isinstance(kappa, int) or abs(kappa) < 2 else 2.0
    if not 0.0 <= value < 1.0:
        raise ValueError(
            f"kappa must be in [0, 1) (a prediction probability: 0 replaces every pixel, "
            f"values near 1 almost none); got {kappa}."
        )
    return value


def check_flags(**flags):
    """Every keyword a bool (True or False), or a TypeError naming it."""
    for name, value in flags.items():
        if not isinstance(value, (bool, np.bool_)):
            raise TypeError(f"{name} must be True or False; got {value!r}.")


def check_options(forgetting, directions, names=DIRECTIONS):
    """``(forgetting, directions)`` validated: a float in (0, 1] and a
    non-empty tuple of ``names`` ('all' is every name)."""
    forgetting = check_forgetting(forgetting)
    if isinstance(directions, str):
        directions = names if directions == "all" else (directions,)
    try:
        directions = tuple(directions)
    except TypeError:
        raise TypeError(f"directions must be 'all' or a sequence of {names}; got "
                        f"{directions!r}.") from None
    bad = [d for d in directions if d not in names]
    if bad or not directions:
        raise ValueError(f"directions must be 'all' or a non-empty subset of {names}; "
                         f"got {directions}.")
    return float(forgetting), directions


def resolve_offsets(neighbourhood, data):
    """The (eta, 2) causal offsets of ``neighbourhood`` (an order, offsets,
    or 'auto': the order chosen by the decision rule (14.6) on the
    channel-last ``data``)."""
    if isinstance(neighbourhood, str):
        if neighbourhood != "auto":
            raise ValueError(f"neighbourhood must be an order, offsets or 'auto'; got "
                             f"{neighbourhood!r}.")
        neighbourhood, _ = select_support(data, channel_axis=-1)
    offsets, _ = as_offsets(neighbourhood)
    return offsets


def check_restorable(shape, offsets, estimator, directions):
    """An (H, W, C) image large enough for the local models of ``estimator``
    with these causal ``offsets``, or a ValueError that says so, by the
    rule of :func:`~car_napari.fit_car`: at least ``parameters + 2`` pixels
    to learn from (``parameters``: the regressors of a channel's model,
    ``eta * C``, plus the windowed estimator's intercept). Smaller images
    used to be restored from the prior alone (each pixel its channel's mean,
    or left as it was), without a word.

    The windowed estimator learns from the pixels whose neighbours in all
    four mirrored neighbourhoods lie inside the image (its one pass of
    sums); the recursive one, per scan direction, from those whose causal
    neighbourhood does (the transposed scans see the image turned)."""
    H, W, C = shape
    offsets = np.asarray(offsets, np.int64).reshape(-1, 2)
    eta = offsets.shape[0]
    if estimator == "windowed":
        up = int(np.max(np.abs(offsets[:, 0])))
        side = int(np.max(np.abs(offsets[:, 1])))
        usable = max(H - 2 * up, 0) * max(W - 2 * side, 0)
        parameters = eta * C + 1
        where = (f"the pixels at least {up} rows and {side} columns from every edge (whose "
                 "neighbours in all four mirrored neighbourhoods lie inside)")
    else:
        top = int(np.max(offsets[:, 0]))
        left = max(int(np.max(offsets[:, 1])), 0)
        right = max(int(-np.min(offsets[:, 1])), 0)
        counts = {}
        for direction in directions:
            h, w = (H, W) if direction in ("down", "up") else (W, H)
            counts[direction] = max(h - top, 0) * max(w - left - right, 0)
        worst = min(counts, key=counts.get)
        usable = counts[worst]
        parameters = eta * C
        where = f"the pixels with a complete neighbourhood in the {worst!r} scan"
    if usable < parameters + 2:
        raise ValueError(
            f"image of size {H}x{W} is too small for this neighbourhood and the {estimator} "
            f"estimator: it learns from {where}, {usable} here, and its model of "
            f"{parameters} parameters a channel needs at least {parameters + 2}. Use a "
            "larger image or a lower order.")


def check_noise(noise, C):
    """A given ``noise`` as ``C`` values (one a channel), finite and >= 0,
    or a ValueError saying so."""
    try:
        noise = np.broadcast_to(np.asarray(noise, float), (C,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"noise must be None, a number or {C} numbers (one a channel); "
                         f"got {noise!r}.") from None
    if np.any(noise < 0) or not np.all(np.isfinite(noise)):
        raise ValueError(f"noise must be finite and >= 0; got {noise}.")
    return noise


def check_noise_magnitude(noise, exponent=0):
    """A ValueError when a given ``noise`` passes ``MAGNITUDE_LIMIT`` (times
    ``2**exponent``, the power of two by which the image is scaled for the
    work): the edge rule squares it, and 1e300 overflowed with a warning.
    Other bad values (negative, NaN, wrong length) are left to the noise
    checks that name them."""
    if noise is None:
        return
    try:
        values = np.abs(np.asarray(noise, float))
    except (TypeError, ValueError):
        return
    limit = math.ldexp(MAGNITUDE_LIMIT, int(exponent))
    if np.any(values > limit) and np.all(np.isfinite(values)):
        raise ValueError(
            f"noise {noise!r} is too large: at most {limit:.3g} for this image (the edge rule "
            "squares it, and a noise far beyond the image's range makes every pixel noise). "
            "Pass the noise's standard deviation in the image's units, or None to "
            "estimate it.")
