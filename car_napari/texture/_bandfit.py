"""The fit of one pyramid band: the CAR model of the decision rule, and
the fallbacks to lower orders (or a scaled ``gamma``) while it is unstable."""

from __future__ import annotations

from .._progress import Progress, stage
from ..model.estimation import CARModel, iter_fit_car
from ..model.neighbourhood import as_offsets
from ..model.synthesis import cached_radius, spectral_radius
from ._blocks import _f32

_MAX_ORDER = 5  # largest candidate order for neighbourhood='auto'
_SHRINK_RADIUS = 0.99  # last-resort target when even order 1 is unstable
# a fit is usable below this radius: degenerate textures (ramps, step edges)
# fit unit roots, 1 - 1e-12, that the float32 rounding of the file and of
# the fit's end pushes to 1 or beyond (synthesis then refuses them)
_STABLE_RADIUS = 1.0 - 1e-6


def _max_order_below(offsets):
    """Largest hierarchical order with fewer offsets than ``offsets``."""
    eta = len(offsets)
    best = 0
    for k in range(1, _MAX_ORDER + 1):
        if len(as_offsets(k)[0]) < eta:
            best = k
    return best


def _fallback_orders(first):
    """Orders to try, in turn, when the first fitted model is unstable."""
    if first.scores is not None and all(isinstance(k, int) for k in first.scores):
        ranked = sorted(first.scores, key=first.scores.get, reverse=True)
        return [k for k in ranked if k != first.order]
    if first.factors is not None:
        top = max(int(f.order or _max_order_below(f.offsets) + 1) for f in first.factors)
        # a 2DCAR whose factors all have the same order falls to the next lower one
        return list(range(top - 1, 0, -1)) if top > 1 else []
    top = first.order if first.order is not None else _max_order_below(first.offsets) + 1
    return list(range(top - 1, 0, -1))


def _iter_scale(radius, target=_SHRINK_RADIUS, steps=40):
    """The largest factor ``c`` in [0, 1] (by ``steps`` bisection steps) for
    which ``radius(c) < target``: how far to scale a ``gamma`` down. A job: a
    record every few steps (each costs a stability test), then ``c``."""
    lo, hi = 0.0, 1.0
    for step in range(steps):
        if step % 4 == 0:
            yield Progress("stabilising", step / steps, f"gamma scale, step {step + 1}/{steps}")
        mid = 0.5 * (lo + hi)
        if radius(mid) < target:
            lo = mid
        else:
            hi = mid
    return lo


def _iter_shrunk(model, target=_SHRINK_RADIUS):
    """Copy of ``model`` with ``gamma`` scaled down until its spectral radius is
    ``target``: the last resort when even order 1 is unstable. A job (see
    :func:`_iter_scale`); returns ``(model, scale)``."""
    trial = CARModel(**{**model.__dict__})

    def radius(scale):
        trial.gamma = model.gamma * scale
        return spectral_radius(trial)

    scale = yield from _iter_scale(radius, target)
    trial.gamma = model.gamma * scale
    trial.factors = None  # the per-factor models no longer match gamma
    return trial, scale


def _stored_radius(model):
    """The spectral radius of ``model`` with ``gamma`` rounded to float32, as
    a fitted texture keeps it (the stability that synthesis will test):
    remembered (:func:`~car_napari.model.synthesis.cached_radius`), so that
    the first synthesis from the fitted texture does not compute it again."""
    rounded = CARModel(**{**model.__dict__})
    rounded.gamma = _f32(model.gamma)
    return cached_radius(rounded)


def _radius_text(radius):
    """``radius`` to 4 digits, or to 10 when those would show a unit root as 1."""
    text = f"{radius:.4g}"
    return f"{radius:.10g}" if text == "1" else text


def _iter_stable_fit(band, neighbourhood, *, model="3d", orders=range(1, _MAX_ORDER + 1),
                     what="the fitted model"):
    """Fit ``band`` (channel-last) by :func:`~car_napari.model.iter_fit_car`
    and fall back to lower orders while the model is unstable; as a job.

    The first fit's records cover [0, 1]; a fallback's refits repeat the last
    fraction (their records keep a cancel prompt). Returns ``(CARModel,
    note)`` where ``note`` is None when the first fit was stable, else a
    sentence saying what was done.
    """
    first = yield from iter_fit_car(band, neighbourhood, model=model, orders=orders,
                                    channel_axis=-1)
    radius = _stored_radius(first)
    if radius < _STABLE_RADIUS:
        return first, None
    label = first.order if first.order is not None else f"{first.eta} offsets"
    for order in _fallback_orders(first):
        trial = yield from stage(iter_fit_car(band, order, model=model, channel_axis=-1),
                                 1.0, 1.0, prefix=f"unstable, refitting order {order}: ")
        if _stored_radius(trial) < _STABLE_RADIUS:
            return trial, (
                f"{what} (order {label}) was unstable (spectral radius "
                f"{_radius_text(radius)}); used order {order} instead"
            )
    lowest = yield from stage(iter_fit_car(band, 1, model=model, channel_axis=-1), 1.0, 1.0,
                              prefix="unstable, refitting order 1: ")
    shrunk, scale = yield from stage(_iter_shrunk(lowest), 1.0, 1.0)
    return shrunk, (
        f"{what} (order {label}) was unstable (spectral radius {_radius_text(radius)}) "
        f"and so was every lower order; used order 1 with gamma scaled by {scale:.4g} "
        f"(spectral radius {_SHRINK_RADIUS})"
    )

