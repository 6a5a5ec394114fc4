"""Illumination invariants of the 3DCAR model (section 14.3, docs/model.md).

If two images of one surface differ only in the illumination spectrum,
``Y' = B Y`` for an invertible ``d x d`` matrix ``B`` (14.30), the fitted
matrices transform as ``A_m -> B A_m B^{-1}`` and the statistics covariantly.
Every feature here is exactly invariant to ``B``: the prior is itself a
multiple of the data's own scatter, so it transforms with the data.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float, check_not_constant, check_size
from .neighbourhood import Context, as_offsets
from .recursive import scan
from .statistics import covariant_estimates, data_statistics

__all__ = ["illumination_invariants"]


def _unit_scale(data):
    """``data`` times a power of two that brings its spread near 1 when it is
    far from it (an exact scaling, to which every feature is invariant), so
    that squares neither overflow nor underflow; ordinary images are left as
    they are (bit for bit)."""
    spread = float(np.max(data) - np.min(data))
    exponent = int(np.round(np.log2(spread)))
    if abs(exponent) <= 64:
        return data
    return np.ldexp(data, -exponent)


def _level_features(level, offsets):
    d = level.shape[2]
    centred = level - level.mean(axis=(0, 1))
    ctx = Context.spatial(offsets, d)
    check_size(centred, ctx.reach, minimum_pixels=ctx.n_regressors + d + 2,
               name="pyramid level")
    flat = centred.reshape(-1, d)
    scatter = flat.T @ flat
    evals = np.linalg.eigvalsh(scatter)
    if evals[0] <= 1e-10 * evals[-1]:
        raise ValueError(
            "the image's channels are linearly dependent (e.g. a grey image stored as "
            "RGB): illumination invariants need independent channels. Pass one "
            "channel (channel_axis=None on a 2-D image) or a true colour image."
        )
    V, count = data_statistics(centred, ctx)
    m = ctx.n_regressors
    if count < m + 1:  # flat neighbourhoods are left out of the statistics
        raise ValueError(
            f"the image (or a pyramid level of {level.shape[0]}x{level.shape[1]}) has only "
            f"{count} pixels whose neighbourhood varies, and this neighbourhood needs at "
            f"least {m + 1}: it is nearly flat. Use a more textured region or a lower order."
        )
    # Covariant prior: one pixel's worth of the data's own scatter.
    (gamma, lam, _, _, _), prior_V = covariant_estimates(V, count, m, d, scatter / flat.shape[0],
                                                         factor_prior=True)
    A = gamma.reshape(d, len(offsets), d).transpose(1, 0, 2)
    traces = np.trace(A, axis1=1, axis2=2)
    eig = np.linalg.eigvals(A)  # (eta, d)
    order = np.lexsort((eig.real, np.abs(eig)), axis=-1)
    eig = np.take_along_axis(eig, order, axis=-1)
    # One-step-ahead statistics from the recursive estimator, started from the
    # same covariant prior.
    U0 = np.linalg.cholesky(prior_V + 1e-300 * np.eye(m + d)).T.copy()
    res = scan(np.ascontiguousarray(centred), ctx, initial=(U0, float(m - 1)),
               outputs=("mean", "q"))
    valid = np.isfinite(res["q"])
    err = centred[valid] - res["mean"][valid]
    lam_chol = np.linalg.cholesky(lam)
    white_err = np.linalg.solve(lam_chol, err.T)
    white_dev = np.linalg.solve(lam_chol, centred.reshape(-1, d).T)
    alpha1 = float(np.mean(res["q"][valid]))
    alpha2 = float(np.sqrt(np.sum(white_err**2)))
    alpha3 = float(np.sqrt(np.sum(white_dev**2)))
    return np.concatenate(
        [traces, eig.real.ravel(), np.abs(eig.imag).ravel(), [alpha1, alpha2, alpha3]]
    )


_MAX_LEVELS = 16  # beyond, the coarsest level of any image is below one pixel


def illumination_invariants(image, neighbourhood=2, *, levels=1, channel_axis=-1):
    """Illumination-invariant texture features (section 14.3, docs/model.md).

    Per level of a Gaussian-Laplacian pyramid (``levels=1``: the image itself),
    a 3DCAR model is fitted and these features are collected:

    1. ``trace(A_m)`` for every offset ``m`` (eta values);
    2. the eigenvalues of every ``A_m``, sorted by modulus: real parts, then
       absolute imaginary parts (2 * eta * d values);
    3. the mean over pixels of ``1 + Z_r^T V_z^{-1} Z_r`` with the recursive
       statistics before ``r``;
    4. ``sqrt(sum_r e_r^T lambda^{-1} e_r)`` with ``e_r`` the one-step-ahead
       prediction errors of the recursive estimator and ``lambda`` that of
       the whole image (with the final least-squares residuals this would be
       the constant ``sqrt(d)``);
    5. ``sqrt(sum_r (Y_r - mu)^T lambda^{-1} (Y_r - mu))``.

    All are exactly invariant to ``Y -> B Y`` for any invertible ``B``.
    A texture that its neighbours predict exactly (a ramp, stripes, a
    checkerboard, a step edge) gets a regularised estimate (a covariant prior
    of ``1e-9`` times the channels' scatter), so its features are finite, and
    the magnitude of the values never decides success.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array_like
        Grey or multichannel image with linearly independent channels; any
        numeric dtype (integers are scaled to [0, 1]).
    neighbourhood : int or (eta, 2) array_like, optional
        Order or explicit causal offsets.
    levels : int, optional
        Levels of the Gaussian-Laplacian pyramid (each halves the size).
    channel_axis : int or None, optional
        The channel axis of a 3-D image; a 2-D image is grey.

    Returns
    -------
    1-D ndarray of float64
        ``levels * (eta + 2 * eta * d + 3)`` values.

    Raises
    ------
    ValueError
        If the image is empty, constant, not 2-D or 3-D, holds NaN or
        infinite values, is too small for the neighbourhood and levels, or
        has linearly dependent channels; if ``levels`` or the neighbourhood
        is invalid.
    TypeError
        If the image is None or not numeric.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.random.default_rng(0).random((32, 32, 3))
    >>> f = illumination_invariants(image, 1)
    >>> B = np.array([[1.0, 0.2, 0.0], [0.0, 0.8, 0.0], [0.1, 0.0, 1.2]])  # an illumination change
    >>> g = illumination_invariants(image @ B.T, 1)
    >>> f.shape, bool(np.allclose(f, g, rtol=1e-4, atol=1e-6))
    ((17,), True)
    """
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)) \
            or not 1 <= levels <= _MAX_LEVELS:
        raise ValueError(f"levels must be a positive int up to {_MAX_LEVELS}; got {levels!r}.")
    offsets, _ = as_offsets(neighbourhood)
    data = as_channel_last_float(image, channel_axis=channel_axis)
    check_not_constant(data)
    data = _unit_scale(data)
    if levels == 1:
        pyramid = [data]
    else:
        from skimage.transform import pyramid_laplacian

        ctx = Context.spatial(offsets, data.shape[2])
        (up, down), (left, right) = ctx.reach
        need = 2 ** (levels - 1) * (max(up + down, left + right) + 4)
        if min(data.shape[:2]) < need:
            raise ValueError(
                f"image {data.shape[0]}x{data.shape[1]} is too small for {levels} pyramid "
                f"levels with this neighbourhood: each side needs at least {need} pixels. "
                "Use fewer levels or a larger image."
            )
        pyramid = [
            np.ascontiguousarray(lvl)
            for lvl in pyramid_laplacian(data, max_layer=levels - 1, channel_axis=-1)
        ]
    return np.concatenate([_level_features(lvl, offsets) for lvl in pyramid])
