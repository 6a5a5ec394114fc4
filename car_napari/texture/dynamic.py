"""Dynamic textures: the 3.5D CAR model over time (sections 14.7 and 14.8,
docs/inpainting.md and docs/texture.md).

A frame is modelled by its causal spatial neighbours and by the previous
frame at the same place and at the same offsets::

    Y_t,r = gamma [Y_t,r-s (s in I); Y_t-1,r; Y_t-1,r-s (s in I)] + e_t,r

fitted by the Bayesian least squares of (14.7)-(14.14), (14.21)
(docs/model.md) over all consecutive frame pairs; synthesis generates frame
after frame from the model equation (synthesis, docs/model.md), the first
frame from a spatial 3DCAR model of the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._progress import Progress, drain
from .._validation import check_not_constant, check_size, output_shape, summarize
from ..model.estimation import CARModel, fit_car
from ..model.neighbourhood import Context, as_offsets
from ..model.statistics import data_statistics, estimate_parameters
from ..model.synthesis import synthesize, synthesize_field
from ._stack import as_stack

__all__ = ["DynamicTextureModel", "iter_fit_dynamic_texture", "temporal_context"]

_PRIOR = 1e-6


def temporal_context(offsets, d):
    """The 3.5D context of a dynamic texture.

    Channels ``0..d-1`` are the current frame (the targets), ``d..2d-1`` the
    previous one; the previous frame enters at ``(0, 0)`` and at the causal
    offsets (so generation never needs pixels below or to the right).

    Parameters
    ----------
    offsets : (eta, 2) array of int
        Causal spatial offsets (row, column), as from
        :func:`car_napari.causal_neighbourhood`.
    d : int
        Number of channels of a frame.

    Returns
    -------
    Context
        Its taps are ``(row, column, channel)``: the ``eta * d`` current-frame
        taps, then the ``d`` previous-frame taps at ``(0, 0)``, then the
        ``eta * d`` previous-frame taps at the offsets; its targets are
        ``0..d-1``.

    Examples
    --------
    >>> from car_napari.texture import temporal_context
    >>> context = temporal_context([(0, 1), (1, 0)], 1)
    >>> context.taps.tolist()
    [[0, 1, 0], [1, 0, 0], [0, 0, 1], [0, 1, 1], [1, 0, 1]]
    >>> context.n_regressors
    5
    """
    offsets = np.asarray(offsets, np.int64)
    taps = [(di, dj, c) for di, dj in offsets for c in range(d)]
    taps += [(0, 0, d + c) for c in range(d)]
    taps += [(di, dj, d + c) for di, dj in offsets for c in range(d)]
    return Context(np.array(taps, np.int64), np.arange(d))


def iter_fit_dynamic_texture(frames, *, neighbourhood=2, channel_axis=-1):
    """Fit a 3.5D CAR model to a clip, as a job reporting progress.

    The generator form of :meth:`DynamicTextureModel.fit` (same arguments,
    same result): it yields a :class:`~car_napari.Progress` record before
    the statistics of every consecutive frame pair (``"frame pair 2/9"``),
    one before the first frame's spatial model and a last one when done,
    and returns the :class:`DynamicTextureModel`. Closing the generator
    stops the fit at the next frame pair.

    Parameters
    ----------
    frames : (T, H, W) or (T, H, W, C) array
        The clip; see :meth:`DynamicTextureModel.fit`.
    neighbourhood : int or (eta, 2) array, optional
        Causal spatial neighbourhood, in the current and the previous frame.
    channel_axis : int or None, optional
        Axis of the channels of a 4-D clip (default the last).

    Returns
    -------
    DynamicTextureModel
        The fitted model (the generator's return value).

    Yields
    ------
    Progress
        Stage ``"fitting"``; every frame pair and the first frame's model are
        an equal share of the range.

    Raises
    ------
    ValueError
        As :meth:`DynamicTextureModel.fit`, before the first record.
    TypeError
        As :meth:`DynamicTextureModel.fit`, before the first record.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import iter_fit_dynamic_texture
    >>> clip = np.random.default_rng(0).random((3, 24, 24))
    >>> for record in iter_fit_dynamic_texture(clip, neighbourhood=1):
    ...     print(record.message, round(record.fraction, 2))
    frame pair 1/2 0.0
    frame pair 2/2 0.33
    first frame 0.67
    3 frames fitted 1.0
    """
    clip, grey = as_stack(frames, channel_axis, name="frames", item="frame")
    if clip.shape[0] < 2:
        raise ValueError(f"a dynamic texture needs at least 2 frames; got {clip.shape[0]}.")
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
        yield Progress("fitting", (t - 1) / T, f"frame pair {t}/{T - 1}")
        source = np.ascontiguousarray(np.concatenate([centred[t], centred[t - 1]], axis=2))
        Vt, ct = data_statistics(source, context)
        V += Vt
        count += ct
    m = context.n_regressors
    var = float(np.mean(summary.var))
    gamma, lam, _, beta, _ = estimate_parameters(V, count, m, d, np.full(m + d, _PRIOR * var))
    yield Progress("fitting", (T - 1) / T, "first frame")
    first = fit_car(clip[0] if not grey else clip[0, ..., 0], offsets,
                    channel_axis=None if grey else -1)
    yield Progress("fitting", 1.0, f"{T} frames fitted")
    return DynamicTextureModel(gamma, lam / beta, np.asarray(summary.mean, float), offsets,
                               first, np.stack([summary.min, summary.max]).astype(float), grey)


@dataclass(eq=False)
class DynamicTextureModel:
    """A 3.5D CAR model of a texture video.

    The dynamic texture of section 14.8 (docs/texture.md), on the 3.5D CAR
    model of section 14.7 (docs/inpainting.md). Build one with :meth:`fit`
    (or :func:`iter_fit_dynamic_texture`). The fields below are also the
    constructor's parameters.

    Parameters
    ----------
    gamma : (d, n_regressors) ndarray
        Parameters, in :func:`temporal_context` order.
    sigma : (d, d) ndarray
        Innovation covariance.
    mean : (d,) ndarray
        Mean of the frames.
    offsets : (eta, 2) ndarray of int
        Causal spatial offsets.
    first : CARModel
        Spatial model for the first synthesised frame.
    value_range : (2, d) ndarray
        The frames' minimum and maximum (outputs are clipped to it).
    grey : bool
        True when the frames have no colour axis.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import DynamicTextureModel
    >>> clip = np.random.default_rng(0).random((3, 24, 24))
    >>> model = DynamicTextureModel.fit(clip, neighbourhood=1)
    >>> model.gamma.shape, model.synthesize(2, (16, 20), seed=0).shape
    ((1, 5), (2, 16, 20))
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
        """Fit a 3.5D CAR model to a clip of at least two frames.

        The same as running :func:`iter_fit_dynamic_texture` to its end.

        Parameters
        ----------
        frames : (T, H, W) or (T, H, W, C) array
            The clip, frames along axis 0 (a 3-D clip is grey); any dtype
            (integer frames are scaled to [0, 1]).
        neighbourhood : int or (eta, 2) array, optional
            Causal spatial neighbourhood, in the current and the previous frame.
        channel_axis : int or None, optional
            Axis of the channels of a 4-D clip (default the last; not 0, which
            holds the frames). None requires a 3-D grey clip.

        Returns
        -------
        DynamicTextureModel
            The fitted model.

        Raises
        ------
        ValueError
            If the clip is not (T, H, W) or (T, H, W, C), has fewer than two
            frames, is constant or not finite, or its frames are too small
            for the neighbourhood.
        TypeError
            If the clip is not numeric.

        See Also
        --------
        iter_fit_dynamic_texture : The same fit as a job that reports its progress.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import DynamicTextureModel
        >>> clip = np.random.default_rng(0).random((3, 24, 24, 2))
        >>> model = DynamicTextureModel.fit(clip, neighbourhood=1)
        >>> model.n_channels, model.grey
        (2, False)
        """
        return drain(iter_fit_dynamic_texture(frames, neighbourhood=neighbourhood,
                                              channel_axis=channel_axis))

    @property
    def n_channels(self):
        """Number of channels of a frame (int; 1 for grey).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import DynamicTextureModel
        >>> clip = np.random.default_rng(0).random((3, 24, 24))
        >>> DynamicTextureModel.fit(clip, neighbourhood=1).n_channels
        1
        """
        return int(self.mean.size)

    @property
    def nbytes(self):
        """Stored bytes (int): the compressed size.

        Every number of gamma, sigma, mean, offsets, range and the first
        frame's spatial model counts as a float32.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import DynamicTextureModel
        >>> clip = np.random.default_rng(0).random((3, 24, 24))
        >>> DynamicTextureModel.fit(clip, neighbourhood=1).nbytes
        68
        """
        first = self.first
        arrays = (self.gamma, self.sigma, self.mean, self.offsets, self.value_range,
                  first.gamma, first.sigma, first.mean)
        return 4 * sum(int(np.size(a)) for a in arrays)

    def compression_ratio(self, clip_shape):
        """Raw float32 bytes of a clip of ``clip_shape`` over :attr:`nbytes`.

        Parameters
        ----------
        clip_shape : tuple of int
            (T, H, W) or (T, H, W, C); the model synthesises any size and length.

        Returns
        -------
        float
            ``4 * prod(clip_shape) / nbytes``.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import DynamicTextureModel
        >>> clip = np.random.default_rng(0).random((3, 24, 24))
        >>> model = DynamicTextureModel.fit(clip, neighbourhood=1)
        >>> round(model.compression_ratio(clip.shape), 1)
        101.6
        """
        return 4.0 * float(np.prod(clip_shape)) / self.nbytes

    def synthesize(self, n_frames, shape, *, seed=None, burn_in=10):
        """Generate a clip from the model, frame after frame.

        Frames follow the model equation; the first ``burn_in`` frames (from
        the spatial model onward) are generated and discarded so that the clip
        starts in the model's temporal steady state.

        Parameters
        ----------
        n_frames : int
            Number of frames to return.
        shape : tuple of 2 ints
            (height, width) of every frame.
        seed : int, numpy Generator or None, optional
            The same seed gives the same clip.
        burn_in : int, optional
            Frames generated and discarded first.

        Returns
        -------
        clip : (n_frames, H, W) or (n_frames, H, W, C) ndarray of float64
            Grey when the fitted clip was, channel-last otherwise.

        Raises
        ------
        ValueError
            If ``n_frames`` or ``shape`` is not positive, or the model is
            unstable (the frames grow without bound).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import DynamicTextureModel
        >>> clip = np.random.default_rng(0).random((3, 24, 24))
        >>> model = DynamicTextureModel.fit(clip, neighbourhood=1)
        >>> model.synthesize(4, (10, 12), seed=0).shape
        (4, 10, 12)
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
