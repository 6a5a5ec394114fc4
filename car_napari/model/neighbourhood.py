"""Causal neighbourhoods and the regression context X_r (causal neighbourhoods
and (14.1)-(14.4), docs/model.md).

A neighbourhood is an (eta, 2) int array of offsets ``s = (di, dj)``; the
neighbour of pixel ``r`` is ``r - s``. It is causal for the raster scan when
``di > 0`` or ``di == 0 and dj > 0``.

A :class:`Context` says what goes into the regression vector ``X_r``: a list of
taps ``(di, dj, channel)`` into a channel-last source array, and which channels
are the modelled ``Y_r``. The plain 3DCAR model taps every channel at every
causal offset; the 2.5D model (other images at ``r``) and the 3.5D model
(previous frames) only add taps into extra, fully known channels, so the same
kernels serve all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .._validation import check_real

__all__ = ["causal_neighbourhood", "as_offsets", "Context", "MAX_ORDER"]

MAX_ORDER = 30


@cache
def _hierarchy(max_order):
    radius = int(np.ceil(np.sqrt(max_order))) + 2
    cand = [
        (di * di + dj * dj, di, dj)
        for di in range(0, radius + 1)
        for dj in range(-radius, radius + 1)
        if di > 0 or (di == 0 and dj > 0)
    ]
    cand.sort()
    lengths = sorted({c[0] for c in cand})[:max_order]
    return cand, lengths


def causal_neighbourhood(order):
    """List the offsets of the hierarchical causal neighbourhood of a given order.

    Order ``k`` holds every causal offset whose squared length is at most the
    ``k``-th smallest squared length among causal offsets, sorted by squared
    length, then ``di``, then ``dj`` (causal neighbourhoods, docs/model.md).
    Orders are nested: the offsets of order ``k`` are the first rows of those
    of order ``k + 1``.

    Parameters
    ----------
    order : int
        Neighbourhood order, 1 to 30.

    Returns
    -------
    (eta, 2) ndarray of int
        Offsets ``(di, dj)``; the neighbour of ``r`` is ``r - (di, dj)``.

    Raises
    ------
    TypeError
        If ``order`` is not an int.
    ValueError
        If ``order`` is outside 1 to 30.

    Examples
    --------
    >>> causal_neighbourhood(2).tolist()
    [[0, 1], [1, 0], [1, -1], [1, 1]]
    """
    if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)):
        raise TypeError(f"order must be an int from 1 to {MAX_ORDER}; got {order!r}.")
    order = int(order)
    if not 1 <= order <= MAX_ORDER:
        raise ValueError(f"order must be between 1 and {MAX_ORDER}; got {order}.")
    cand, lengths = _hierarchy(MAX_ORDER)
    limit = lengths[order - 1]
    return np.array([(di, dj) for sq, di, dj in cand if sq <= limit], dtype=np.int64)


def as_offsets(neighbourhood, *, name="neighbourhood"):
    """Validate a neighbourhood given as an order or an offset array.

    Parameters
    ----------
    neighbourhood : int or (eta, 2) array_like of int
        An order (see :func:`causal_neighbourhood`) or explicit causal
        offsets ``(di, dj)``, without duplicates, each at most
        ``2**20`` pixels.
    name : str, optional
        The argument's name in the error messages (``'offsets'`` where a
        function takes the neighbourhood under that name).

    Returns
    -------
    offsets : (eta, 2) ndarray of int64
        The offsets.
    order : int or None
        The order, or None for explicit offsets.

    Raises
    ------
    ValueError
        If the order is out of range, or the offsets are not an (eta, 2)
        integer array, not causal, too far, or hold duplicates; for a string.
    TypeError
        If ``neighbourhood`` is not an int and cannot be read as an array,
        or the order is not an int.

    Examples
    --------
    >>> offsets, order = as_offsets(1)
    >>> offsets.tolist(), order
    ([[0, 1], [1, 0]], 1)
    >>> as_offsets([[1, 0], [0, 2]])[0].tolist()
    [[1, 0], [0, 2]]
    """
    subject = name if name == "offsets" else f"{name} offsets"
    allowed = (f"pass an order (an int from 1 to {MAX_ORDER}) or an (eta, 2) array of causal "
               "offsets (di, dj)")
    if isinstance(neighbourhood, (int, np.integer)) and not isinstance(
        neighbourhood, (bool, np.bool_)
    ):
        try:
            return causal_neighbourhood(neighbourhood), int(neighbourhood)
        except ValueError as exc:  # say which argument: the order came under this name
            raise ValueError(f"{name} {exc}") from None
    if isinstance(neighbourhood, str):
        raise ValueError(f"{name} {neighbourhood!r} is not understood here; {allowed}.")
    try:
        offsets = np.asarray(neighbourhood)
    except Exception as exc:
        raise TypeError(f"{name} could not be read as offsets ({exc}); {allowed}.") from exc
    if offsets.ndim != 2 or offsets.shape[1] != 2 or offsets.shape[0] == 0:
        raise ValueError(
            f"{subject} must be a non-empty (eta, 2) array of (di, dj); got "
            f"shape {offsets.shape} ({allowed})."
        )
    if offsets.dtype.kind not in "iu":
        if offsets.dtype.kind == "f" and np.all(np.isfinite(offsets)) and np.all(
            offsets == np.round(offsets)
        ):
            # bounded before the cast: 1e300 would wrap to a negative int64
            offsets = np.clip(offsets, -2.0 * _MAX_REACH, 2.0 * _MAX_REACH).astype(np.int64)
        else:
            raise ValueError(f"{subject} must be integers; got {offsets.tolist()}.")
    if offsets.dtype.kind == "u" and offsets.max() > _MAX_REACH:
        offsets = np.minimum(offsets, 2 * _MAX_REACH)  # uint64 beyond int64: no wrap
    offsets = offsets.astype(np.int64)
    noncausal = [
        (int(di), int(dj)) for di, dj in offsets if not (di > 0 or (di == 0 and dj > 0))
    ]
    if noncausal:
        raise ValueError(
            f"{subject} {noncausal} are not causal: each (di, dj) needs di > 0, "
            "or di == 0 and dj > 0 (the neighbour r - s must come before r in the raster "
            "scan)."
        )
    if np.any((offsets > _MAX_REACH) | (offsets < -_MAX_REACH)):  # no abs(): int64 min
        raise ValueError(f"{subject} must be at most {_MAX_REACH} pixels (an image "
                         f"side); got {np.asarray(neighbourhood).tolist()}.")
    if len({(int(a), int(b)) for a, b in offsets}) != len(offsets):
        raise ValueError(f"{subject} contain duplicates: {offsets.tolist()}.")
    return offsets, None


_MAX_CONTEXT_CHANNELS = 1 << 12  # channels of a context: far more than any stack holds
_MAX_REACH = 1 << 20  # the largest offset a context takes (an image side, MAX_SIDE)


def _offset_array(offsets):
    """``offsets`` as an (eta, 2) int64 array of integer values within
    ``_MAX_REACH``, or a TypeError / ValueError naming them (not an
    OverflowError or an IndexError from a later step)."""
    try:
        arr = np.asarray(offsets)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"offsets could not be read as an (eta, 2) array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"offsets must be an (eta, 2) array of (di, dj); got shape {arr.shape}.")
    if arr.dtype.kind not in "iuf" or (arr.dtype.kind == "f" and not (
            np.isfinite(arr).all() and np.array_equal(arr, np.round(arr)))):
        raise ValueError(f"offsets must be integers; got {arr.tolist()}.")
    if arr.size and np.abs(arr).max() > _MAX_REACH:
        raise ValueError(f"offsets must be at most {_MAX_REACH} pixels; got {arr.tolist()}.")
    return arr.astype(np.int64)


@dataclass(frozen=True)
class Context:
    """What goes into the regression vector ``X_r``.

    Parameters
    ----------
    taps : (m, 3) array_like of int
        The attribute below; rows ``(di, dj, channel)``.
    targets : (d,) array_like of int
        The attribute below.

    Attributes
    ----------
    taps : (m, 3) ndarray of int
        ``(di, dj, channel)``: ``X_r[k] = source[i - di, j - dj, channel]``
        relative to the scan. Taps into target channels must be causal; taps
        into other (context) channels may be anywhere, since those channels are
        fully known (other images for 2.5D, previous frames for 3.5D).
    targets : (d,) ndarray of int
        Source channels that form ``Y_r``.

    Raises
    ------
    ValueError
        If there is no tap or no target, the targets are not distinct and
        >= 0, a tap channel is negative, or a tap into a target channel is
        not causal.

    Examples
    --------
    >>> ctx = Context([[0, 1, 0], [1, 0, 0], [0, 0, 1]], [0])  # 2.5D: channel 1 at r
    >>> ctx.n_regressors, ctx.n_targets, ctx.n_channels, ctx.reach
    (3, 1, 2, ((1, 0), (1, 0)))
    """

    taps: np.ndarray
    targets: np.ndarray

    def __post_init__(self):
        taps = np.ascontiguousarray(self.taps, dtype=np.int64).reshape(-1, 3)
        targets = np.ascontiguousarray(self.targets, dtype=np.int64).ravel()
        if targets.size == 0 or taps.shape[0] == 0:
            raise ValueError("a context needs at least one tap and one target channel.")
        if len(set(targets.tolist())) != targets.size or targets.min() < 0:
            raise ValueError(f"target channels must be distinct and >= 0; got {targets}.")
        if taps[:, 2].min() < 0:
            raise ValueError("tap channels must be >= 0.")
        own = np.isin(taps[:, 2], targets)
        di, dj = taps[own, 0], taps[own, 1]
        if np.any(~((di > 0) | ((di == 0) & (dj > 0)))):
            raise ValueError(
                "taps into the modelled channels must be causal (di > 0, or di == 0 and dj > 0)."
            )
        object.__setattr__(self, "taps", taps)
        object.__setattr__(self, "targets", targets)

    @classmethod
    def spatial(cls, offsets, n_channels):
        """The 3DCAR context: every channel at every offset.

        Ordered as in (14.1)-(14.4), docs/model.md:
        ``X_r = [Y_{r-s_1}; ...; Y_{r-s_eta}]`` so that
        ``gamma = [A_1, ..., A_eta]`` with ``gamma[:, k*d + c] = A_k[:, c]``.

        Parameters
        ----------
        offsets : (eta, 2) array_like of int
            Causal offsets ``(di, dj)``.
        n_channels : int
            ``d``, the channels of the image (all modelled).

        Returns
        -------
        Context
            Taps ``(di, dj, c)`` offset by offset, channel by channel;
            targets ``0..d-1``.

        Raises
        ------
        ValueError
            If an offset is not causal or not an integer, the offsets are not
            an (eta, 2) array, or ``n_channels`` is not a positive int.
        TypeError
            If ``n_channels`` is not an int.

        Examples
        --------
        >>> Context.spatial([[0, 1], [1, 0]], 2).taps.tolist()
        [[0, 1, 0], [0, 1, 1], [1, 0, 0], [1, 0, 1]]
        """
        offsets = _offset_array(offsets)
        d = check_real(n_channels, "n_channels", low=1, high=_MAX_CONTEXT_CHANNELS,
                       integer=True)
        taps = np.empty((len(offsets) * d, 3), dtype=np.int64)
        taps[:, 0] = np.repeat(offsets[:, 0], d)
        taps[:, 1] = np.repeat(offsets[:, 1], d)
        taps[:, 2] = np.tile(np.arange(d), len(offsets))
        return cls(taps, np.arange(d))

    @property
    def n_regressors(self):
        """The length ``m`` of ``X_r``, one per tap (an int).

        Examples
        --------
        >>> Context.spatial([[0, 1], [1, 0]], 3).n_regressors
        6
        """
        return self.taps.shape[0]

    @property
    def n_targets(self):
        """The length ``d`` of ``Y_r``, one per target channel (an int).

        Examples
        --------
        >>> Context.spatial([[0, 1], [1, 0]], 3).n_targets
        3
        """
        return self.targets.size

    @property
    def n_channels(self):
        """The channels the source array must have at least (an int).

        Examples
        --------
        >>> Context([[0, 1, 0], [0, 0, 2]], [0]).n_channels
        3
        """
        return int(max(self.taps[:, 2].max(), self.targets.max())) + 1

    @property
    def reach(self):
        """How far the taps reach, in scan terms (a tuple of pairs).

        ``((rows above, rows below), (columns left, columns right))`` from
        ``r``; the pixels with a complete neighbourhood are those this far
        from the edges.

        Examples
        --------
        >>> Context.spatial([[0, 1], [1, -1], [1, 1]], 1).reach
        ((1, 0), (1, 1))
        """
        di, dj = self.taps[:, 0], self.taps[:, 1]
        return (
            (max(int(di.max()), 0), max(int(-di.min()), 0)),
            (max(int(dj.max()), 0), max(int(-dj.min()), 0)),
        )
