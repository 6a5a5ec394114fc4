"""Dynamic textures: the 3.5D CAR model over time (SPEC 6 and 7).

A frame is modelled by its causal spatial neighbours and by the previous
frame at the same place and at the same offsets::

    Y_t,r = gamma [Y_t,r-s (s in I); Y_t-1,r; Y_t-1,r-s (s in I)] + e_t,r

fitted by the Bayesian least squares of SPEC 1.3 over all consecutive frame
pairs; synthesis generates frame after frame from the model equation
(SPEC 1.7), the first frame from a spatial 3DCAR model of the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.synthesis import synthesize_field
from .._validation import (
    as_channel_last_float,
    check_not_constant,
    check_size,
    output_shape,
    summarize,
)
from ..model.estimation import CARModel, fit_car
from ..model.statistics import data_statistics, estimate_parameters
from ..model.neighbourhood import Context, as_offsets

__all__ = ["DynamicTextureModel", "temporal_context"]

_PRIOR = 1e-6


def temporal_context(offsets, d):
    """The 3.5D context: channels ``0..d-1`` the current frame (targets),
    ``d..2d-1`` the previous one; the previous frame enters at ``(0, 0)`` and
    at the causal offsets (so generation never needs pixels below or right)."""
    offsets = np.asarray(offsets, np.int64)
    taps = [(di, dj, c) for di, dj in offsets for c in range(d)]
    taps += [(0, 0, d + c) for c in range(d)]
    taps += [(di, dj, d + c) for di, dj in offsets for c in range(d)]
    return Context(np.array(taps, np.int64), np.arange(d))


@dataclass(eq=False)
class DynamicTextureModel:
    """A 3.5D CAR model of a texture video.

    Attributes
    ----------
    gamma : (d, n_regressors) parameters in :func:`temporal_context` order.
    sigma : (d, d) innovation covariance.
    mean : (d,) mean of the frames.
    offsets : (eta, 2) causal spatial offsets.
    first : CARModel, spatial model for the first synthesised frame.
    value_range : (2, d) the frames' minimum and maximum (outputs are clipped).
    grey : bool.
    """

    gamma: np.ndarray
    sigma: np.ndarray
    mean: np.ndarray
    offsets: np.ndarray
    first: CARModel
    value_range: np.ndarray
    grey: bool

    @classmethod
    def fit(cls, frames, *, neighbourhood=2, channel_axis=-1):
        """Fit to a clip ``(T, H, W[, C])`` of at least two frames.

        Parameters
        ----------
        frames : (T, H, W) grey (``channel_axis=None``) or (T, H, W, C) array.
        neighbourhood : int or (eta, 2) array, optional
            Causal spatial neighbourhood, in the current and the previous frame.
        channel_axis : int or None, optional
            Colour axis of each frame (-1: the last); None for grey clips.
        """
        arr = np.asarray(frames)
        grey = channel_axis is None
        if arr.ndim != (3 if grey else 4):
            raise ValueError(
                f"frames must be (T, H, W{'' if grey else ', C'}); got shape {arr.shape}."
                + ("" if grey else " For a grey clip pass channel_axis=None."))
        if arr.shape[0] < 2:
            raise ValueError(f"a dynamic texture needs at least 2 frames; got {arr.shape[0]}.")
        clip = np.stack([as_channel_last_float(f, channel_axis=None if grey else -1,
                                               name=f"frame {t}") for t, f in enumerate(arr)])
        T, H, W, d = clip.shape
        summary = summarize(clip.reshape(T * H, W, d))
        check_not_constant(clip.reshape(T * H, W, d), summary=summary, name="frames")
        offsets, _ = as_offsets(neighbourhood)
        context = temporal_context(offsets, d)
        check_size(clip[0], context.reach, minimum_pixels=context.n_regressors + 2,
                   name="each frame")
        centred = clip - summary.mean
        n = context.n_regressors + d
        V, count = np.zeros((n, n)), 0
        for t in range(1, T):
            source = np.ascontiguousarray(np.concatenate([centred[t], centred[t - 1]], axis=2))
            Vt, ct = data_statistics(source, context)
            V += Vt
            count += ct
        m = context.n_regressors
        var = float(np.mean(summary.var))
        gamma, lam, _, beta, _ = estimate_parameters(V, count, m, d, np.full(m + d, _PRIOR * var))
        first = fit_car(clip[0] if not grey else clip[0, ..., 0], offsets,
                        channel_axis=None if grey else -1)
        return cls(gamma, lam / beta, np.asarray(summary.mean, float), offsets, first,
                   np.stack([summary.min, summary.max]).astype(float), grey)

    @property
    def n_channels(self):
        return int(self.mean.size)

    @property
    def nbytes(self):
        """Stored numbers as float32: gamma, sigma, mean, offsets, range and
        the first frame's spatial model."""
        first = self.first
        arrays = (self.gamma, self.sigma, self.mean, self.offsets, self.value_range,
                  first.gamma, first.sigma, first.mean)
        return 4 * sum(int(np.size(a)) for a in arrays)

    def compression_ratio(self, clip_shape):
        """Raw float32 bytes of a clip of ``clip_shape`` over :attr:`nbytes`."""
        return 4.0 * float(np.prod(clip_shape)) / self.nbytes

    def synthesize(self, n_frames, shape, *, seed=None, burn_in=10):
        """Generate ``n_frames`` frames of ``shape`` (H, W): (n, H, W[, C]).

        Frame after frame from the model equation; the first ``burn_in``
        frames (from the spatial model onward) are generated and discarded so
        that the clip starts in the model's temporal steady state.
        """
        h, w = output_shape(shape)
        if int(n_frames) != n_frames or n_frames < 1:
            raise ValueError(f"n_frames must be a positive integer; got {n_frames!r}.")
        rng = np.random.default_rng(seed)
        d = self.n_channels
        reach = int(np.abs(self.offsets).max())
        margin = 32 + reach
        H, W = h + margin, w + 2 * margin
        context = temporal_context(self.offsets, d)
        taps = context.taps
        chol = np.linalg.cholesky(0.5 * (self.sigma + self.sigma.T) + 1e-300 * np.eye(d))
        first = self.first
        from ..model.synthesis import synthesize

        previous = synthesize(first, (H, W), seed=rng.integers(2**63)).reshape(H, W, d)
        previous = previous - self.mean
        limit = 1e6 * math.sqrt(float(np.trace(self.sigma))) + 1e6 * float(
            np.ptp(self.value_range))
        frames = []
        for t in range(int(burn_in) + int(n_frames)):
            lattice = np.concatenate([rng.standard_normal((H, W, d)), previous], axis=2)
            ok = synthesize_field(np.ascontiguousarray(self.gamma), chol, lattice,
                                  taps[:, 0].copy(), taps[:, 1].copy(), taps[:, 2].copy(),
                                  limit)
            if not ok:
                raise ValueError("the dynamic model is unstable: the frames grow without "
                                 "bound. Fit it to a longer or more stationary clip, or use "
                                 "a smaller neighbourhood.")
            previous = lattice[..., :d].copy()
            if t >= burn_in:
                frame = np.clip(previous[margin:, margin : margin + w] + self.mean,
                                self.value_range[0], self.value_range[1])
                frames.append(frame[..., 0] if self.grey else frame)
        return np.stack(frames)
