"""The fitted CAR model: :class:`CARModel` (the estimates of
:func:`~car_napari.model.estimation.fit_car` and the statistics behind them),
its checks (:func:`check_model`) and Student-t prediction with it
((14.23)-(14.25), docs/model.md: :func:`predict`, :class:`Prediction`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .._validation import (
    MAGNITUDE_LIMIT,
    as_channel_last_float,
    check_size,
)
from .directions import scan_view
from .neighbourhood import Context
from .recursive import scan

__all__ = ["CARModel", "MAX_MODEL_REACH", "Prediction", "check_model", "predict"]


@dataclass(eq=False)
class CARModel:
    """A fitted 3DCAR model ``Y_r - mean = gamma X_r + e_r``, ``e_r ~ N(0, sigma)``.

    Made by :func:`fit_car`; used by :func:`predict`,
    :func:`~car_napari.model.synthesize` and
    :func:`~car_napari.model.spectral_radius`. The model is (14.1)-(14.4),
    docs/model.md.

    Parameters
    ----------
    gamma : (d, d*eta) ndarray
        ``[A_1, ..., A_eta]`` with ``gamma[:, k*d + c] = A_k[:, c]``
        ((14.1)-(14.4), docs/model.md).
    sigma : (d, d) ndarray
        Noise covariance estimate ``lambda / beta``.
    mean : (d,) ndarray
        Mean subtracted before fitting.
    offsets : (eta, 2) ndarray of int
        The causal neighbourhood, relative to the scan ``direction``.
    lam : (d, d) ndarray
        ``lambda``, the residual scatter (with its prior part).
    vx : (d*eta, d*eta) ndarray
        ``V_x``, the regressors' data-gathering matrix including ``V_0``.
    beta : float
        ``beta(r)``: prior count plus the number of pixels used.
    n_pixels : int
        Pixels whose whole neighbourhood lay inside the image.
    order : int or None
        Hierarchical order, when the neighbourhood is one.
    scores : dict or None
        Decision-rule scores of every candidate, when the support was chosen.
    direction : str
        Scan direction the model was fitted in.
    basis, factors : ndarray and tuple of CARModel, or None
        For the 2DCAR path: an orthonormal spectral basis (d, d) whose columns
        are the principal components, and one single-channel model per factor.
        ``gamma`` and ``sigma`` then hold the equivalent colour-space model.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import fit_car
    >>> model = fit_car(np.random.default_rng(0).random((32, 32, 3)), 1)
    >>> model.gamma.shape, model.n_channels, model.eta, model.A.shape
    ((3, 6), 3, 2, (2, 3, 3))
    """

    gamma: np.ndarray
    sigma: np.ndarray
    mean: np.ndarray
    offsets: np.ndarray
    lam: np.ndarray
    vx: np.ndarray
    beta: float
    n_pixels: int
    order: int | None = None
    scores: dict | None = None
    direction: str = "down"
    basis: np.ndarray | None = None
    factors: tuple | None = field(default=None, repr=False)

    @property
    def n_channels(self):
        """The number of modelled channels ``d`` (an int).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> fit_car(np.random.default_rng(0).random((16, 16)), 1).n_channels
        1
        """
        return int(self.gamma.shape[0])

    @property
    def eta(self):
        """The number of offsets ``eta`` in the neighbourhood (an int).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> fit_car(np.random.default_rng(0).random((16, 16)), 2).eta
        4
        """
        return int(self.offsets.shape[0])

    @property
    def A(self):
        """The matrices ``A_s``, one per offset, as an (eta, d, d) ndarray.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> model = fit_car(np.random.default_rng(0).random((16, 16, 2)), 1)
        >>> bool(np.array_equal(model.A[1], model.gamma[:, 2:4]))
        True
        """
        d = self.n_channels
        return self.gamma.reshape(d, self.eta, d).transpose(1, 0, 2)

    @property
    def log_det_vx(self):
        """The log-determinant ``ln |V_x|`` of :attr:`vx` (a float).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> model = fit_car(np.random.default_rng(0).random((16, 16)), 1)
        >>> bool(np.isclose(model.log_det_vx, np.log(np.linalg.det(model.vx))))
        True
        """
        return float(np.linalg.slogdet(self.vx)[1])

    @property
    def context(self):
        """The model's regression vector ``X_r`` as a Context: every channel at every offset.

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> fit_car(np.random.default_rng(0).random((16, 16, 3)), 1).context.n_regressors
        6
        """
        return Context.spatial(self.offsets, self.n_channels)

    def to_dict(self):
        """Plain, JSON-serialisable summary of the model.

        Returns
        -------
        dict
            Order, offsets, direction, channels, ``gamma``, ``sigma``, mean,
            ``beta``, pixel count, ``"model"`` ('3d' or '2d') and, when the
            support was chosen, the decision-rule scores; lists and numbers only.

        Examples
        --------
        >>> import json
        >>> import numpy as np
        >>> from car_napari.model import fit_car
        >>> summary = fit_car(np.random.default_rng(0).random((16, 16)), 1).to_dict()
        >>> summary["order"], summary["offsets"], summary["model"]
        (1, [[0, 1], [1, 0]], '3d')
        >>> isinstance(json.dumps(summary), str)
        True
        """
        out = {
            "order": self.order,
            "offsets": self.offsets.tolist(),
            "direction": self.direction,
            "n_channels": self.n_channels,
            "gamma": self.gamma.tolist(),
            "sigma": self.sigma.tolist(),
            "mean": self.mean.tolist(),
            "beta": self.beta,
            "n_pixels": self.n_pixels,
            "model": "2d" if self.factors is not None else "3d",
        }
        if self.scores is not None:
            out["scores"] = {str(k): float(v) for k, v in self.scores.items()}
        return out


# the stability test solves an eigenproblem of (reach x channels) rows per
# frequency, and synthesis pads by the reach: beyond it a test takes minutes
MAX_MODEL_REACH = 64


def check_model(model, name="model"):
    """A TypeError unless ``model`` is a CARModel, and a ValueError naming it
    unless its parameters fit together and are finite (gamma and mean at most
    ``MAGNITUDE_LIMIT``, as an image's values): gamma (d, d * eta),
    sigma (d, d), mean (d,), eta causal integer offsets that reach at most
    ``MAX_MODEL_REACH`` pixels (a hand-made or edited model; those of
    :func:`fit_car` with orders pass).

    Parameters
    ----------
    model : CARModel
        The model to check.
    name : str, optional
        What to call it in the messages.

    Raises
    ------
    TypeError
        If ``model`` is not a CARModel.
    ValueError
        If its parameters are inconsistent, not finite or reach too far.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import fit_car
    >>> model = fit_car(np.random.default_rng(0).random((16, 16)), 1)
    >>> check_model(model)
    >>> model.gamma = model.gamma * np.nan
    >>> check_model(model)
    Traceback (most recent call last):
    ...
    ValueError: model.gamma holds NaN or infinite values; refit the model.
    """
    if not isinstance(model, CARModel):
        raise TypeError(f"{name} must be a CARModel (from fit_car); got "
                        f"{type(model).__name__}.")
    try:
        gamma, sigma, mean = (np.asarray(getattr(model, k), dtype=np.float64)
                              for k in ("gamma", "sigma", "mean"))
        offsets = np.asarray(model.offsets)
    except (TypeError, ValueError):
        raise ValueError(f"{name}'s gamma, sigma and mean must be numeric arrays; refit the "
                         "model.") from None
    if offsets.ndim != 2 or offsets.shape[1] != 2 or offsets.shape[0] == 0 \
            or offsets.dtype.kind not in "iu":
        raise ValueError(f"{name}.offsets must be a non-empty (eta, 2) integer array; got "
                         f"shape {offsets.shape} of {offsets.dtype}.")
    d, eta = (gamma.shape[0] if gamma.ndim == 2 else 0), offsets.shape[0]
    if gamma.ndim != 2 or d == 0 or gamma.shape[1] != d * eta:
        raise ValueError(f"{name}.gamma has shape {gamma.shape}; with {eta} offsets it must be "
                         f"(d, d * {eta}).")
    if sigma.shape != (d, d) or mean.shape != (d,):
        raise ValueError(f"{name} has sigma {sigma.shape} and mean {mean.shape}; for {d} "
                         f"channels they must be {(d, d)} and {(d,)}.")
    for key, values in (("gamma", gamma), ("sigma", sigma), ("mean", mean)):
        if not np.isfinite(values).all():
            raise ValueError(f"{name}.{key} holds NaN or infinite values; refit the model.")
        # gamma and mean at most the magnitude of an image's values (sigma is
        # of their squares): beyond it the predictions overflow
        if key != "sigma" and values.size and np.abs(values).max() > MAGNITUDE_LIMIT:
            raise ValueError(f"{name}.{key} holds values of magnitude "
                             f"{np.abs(values).max():.3g}, beyond {MAGNITUDE_LIMIT:g}; refit the "
                             "model.")
    di, dj = offsets[:, 0], offsets[:, 1]
    if np.any((di < 0) | ((di == 0) & (dj <= 0))):
        raise ValueError(f"{name}.offsets are not causal (each needs di > 0, or di == 0 and "
                         f"dj > 0); got {offsets.tolist()}.")
    reach = int(max(di.max(), np.abs(dj).max()))
    if reach > MAX_MODEL_REACH:
        raise ValueError(f"{name}.offsets reach {reach} pixels; at most {MAX_MODEL_REACH} are "
                         "allowed (the stability test and the synthesis margin grow with it).")


class Prediction(NamedTuple):
    """What :func:`predict` returns (unpacks as ``mean, log_density``).

    Parameters
    ----------
    mean : ndarray
        The conditional mean, the image's shape.
    log_density : (H, W) ndarray
        The log predictive density of every observed pixel.

    Examples
    --------
    >>> import numpy as np
    >>> mean, log_density = Prediction(np.zeros((2, 2)), np.zeros((2, 2)))
    >>> log_density.shape
    (2, 2)
    """

    mean: np.ndarray
    log_density: np.ndarray


def _augmented_factor(model):
    """Upper factor U of the model's augmented statistics V = U^T U, built
    block by block (forming V and factoring it loses lambda to cancellation
    when channels are nearly collinear)."""
    m = model.vx.shape[0]
    d = model.n_channels
    U = np.zeros((m + d, m + d))
    U[:m, :m] = np.linalg.cholesky(model.vx).T
    U[:m, m:] = U[:m, :m] @ model.gamma.T
    U[m:, m:] = np.linalg.cholesky(model.lam).T
    return U


def _check_predictable(model):
    """A ValueError, before any work, when ``model`` (or one of its factor
    models) lacks the statistics the density needs: ``vx`` and ``lam``
    finite. The models of a :class:`~car_napari.TextureModel` read from a
    file carry only what synthesis needs (``vx`` is NaN), and their
    densities used to come out all NaN without a word."""
    for part in (model,) if model.factors is None else model.factors:
        if not (np.all(np.isfinite(part.vx)) and np.all(np.isfinite(part.lam))):
            raise ValueError(
                "model has no data statistics (its vx or lam is not finite), as the band "
                "models of a TextureModel read from a file, which keep only what synthesis "
                "needs: its predictive density cannot be computed. Fit a model to the image "
                "instead (fit_car, or TextureModel.fit, whose models predict).")


def predict(model, image, *, channel_axis=-1):
    """Conditional mean and log predictive density of every pixel.

    Each pixel is predicted from its causal neighbours by the fitted model
    ((14.23)-(14.25), docs/model.md): the mean is ``mean + gamma_hat X_r``
    and the density the Student t of (14.23) with ``nu = beta - d*eta + 2``
    degrees of freedom.

    Parameters
    ----------
    model : CARModel
        A model from :func:`fit_car`.
    image : (H, W) or (H, W, C) array_like
        With the model's number of channels; any numeric dtype (integers are
        scaled to [0, 1]).
    channel_axis : int or None, optional
        The channel axis of a 3-D image; a 2-D image is grey.

    Returns
    -------
    Prediction
        ``(mean, log_density)``: the conditional mean, float64 in the shape
        of ``image`` (NaN where the neighbourhood leaves the image), and the
        (H, W) log predictive density of the observed pixel (NaN at the
        borders).

    Raises
    ------
    TypeError
        If ``model`` is not a CARModel, or the image is not numeric.
    ValueError
        If the image's channels differ from the model's, or the image is too
        small for the neighbourhood, not 2-D or 3-D, or holds NaN or
        infinite values; if the model has no data statistics (the band
        models of a :class:`~car_napari.TextureModel` read by its ``load``
        keep only what synthesis needs).

    Notes
    -----
    A constant image (no texture) is accepted: each pixel is predicted
    from its equal neighbours, so the mean and the log density are finite
    wherever the neighbourhood lies inside the image (NaN only at the
    borders, as for any image); the density then says how unlike the
    model's texture a flat field is.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((16, 16))
    >>> from car_napari.model import fit_car
    >>> mean, log_density = predict(fit_car(image, 1), image)
    >>> mean.shape, bool(np.isnan(log_density[0]).all())
    ((16, 16), True)
    >>> bool(np.isfinite(log_density[1:, 1:]).all())
    True
    """
    check_model(model)
    _check_predictable(model)
    data = as_channel_last_float(image, channel_axis=channel_axis)
    d = model.n_channels
    if data.shape[2] != d:
        raise ValueError(
            f"image has {data.shape[2]} channels but the model was fitted to {d}; "
            "pass an image with the same channels (or check channel_axis)."
        )
    data -= model.mean
    ctx = model.context
    check_size(np.empty(scan_view(data, model.direction).shape[:2]), ctx.reach)
    if model.factors is not None:
        fdata = data @ model.basis
        mean = np.empty_like(fdata)
        logp = np.zeros(data.shape[:2])
        for k, fm in enumerate(model.factors):
            mk, lk = predict(fm, np.ascontiguousarray(fdata[..., k]), channel_axis=None)
            mean[..., k] = mk
            logp += lk
        mean = mean @ model.basis.T
    else:
        res = scan(
            data, ctx, direction=model.direction,
            initial=(_augmented_factor(model), model.beta), update=False,
            outputs=("mean", "logp"),
        )
        mean, logp = res["mean"], res["logp"]
    mean += model.mean
    if np.ndim(image) == 2 or channel_axis is None:
        mean = mean[..., 0]
    elif channel_axis not in (-1, np.ndim(image) - 1):
        mean = np.moveaxis(mean, -1, channel_axis)
    return Prediction(mean, logp)
