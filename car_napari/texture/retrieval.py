"""Illumination-invariant texture retrieval (SPEC section 2, 14.3).

A texture is described by a few of the illumination invariants of the 3DCAR
model (:func:`car_napari.illumination_invariants`) on every band of a
Gaussian-Laplacian pyramid; a gallery is ranked by an L1 distance in which
every feature is scaled by its spread over the gallery.

If two images of one surface differ only in the illumination spectrum,
``Y' = B Y`` for an invertible ``d x d`` matrix ``B`` (14.30), and the
features are identical up to rounding: the ranking does not see the change
of illumination.

Which invariants, and which normalisation (measured on the VisTex retrieval
benchmark of ``benchmarks/bench_texture.py``: 30 textures x 4 tiles of
256 x 256, each under a random positive ``B`` plus Gaussian noise 0.03,
leave-one-out, 3 levels, order-2 support; precision at 1 / mean average
precision):

- the traces of ``A_m`` and ``alpha_3`` per band (what :func:`texture_features`
  returns): 0.94 / 0.87; all ``eta + 2 * eta * d + 3`` invariants per band
  of SPEC section 2: 0.74 / 0.61 with the same distance. The eigenvalues of the
  individual ``A_m`` are ordered by modulus, so noise swaps them and their
  imaginary parts are mostly zero; ``alpha_1`` and ``alpha_2`` are nearly the
  same constant for every texture. Those features add noise, not
  information, once every feature gets the same weight.
- the Gaussian-Laplacian (band-pass) pyramid beat a Gaussian (low-pass)
  pyramid: 0.94 versus 0.85 precision at 1.
- distances on these features: per-feature scaling by the gallery's
  standard deviation (what :func:`rank` does) 0.94 / 0.87; by the gallery's
  median absolute deviation 0.94 / 0.87 (0.866); plain L1 0.92 / 0.85; the
  Canberra form ``sum |a - b| / (|a| + |b|)`` 0.88 / 0.78 (traces near zero
  turn its terms into noise).
"""

from __future__ import annotations

import numpy as np

from .._validation import as_channel_last_float
from ..model.invariants import illumination_invariants
from ..model.neighbourhood import Context, as_offsets

__all__ = ["texture_features", "rank", "minimum_size"]


def _check_levels(levels):
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)) \
            or levels < 1:
        raise ValueError(f"levels must be a positive int; got {levels!r}.")
    return int(levels)


def minimum_size(*, levels=3, neighbourhood=2):
    """Smallest side (in pixels) of an image :func:`texture_features` accepts.

    Every pyramid level halves the image; the coarsest must still be a few
    pixels larger than the neighbourhood.

    Parameters
    ----------
    levels : int, optional
        Levels of the Gaussian-Laplacian pyramid.
    neighbourhood : int or (eta, 2) array, optional
        Order of the causal neighbourhood (SPEC 1.1) or explicit offsets.

    Returns
    -------
    int
        ``2**(levels - 1) * (reach + 4)`` with ``reach`` the neighbourhood's
        larger extent (rows or columns); 24 for the defaults.
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    (up, down), (left, right) = Context.spatial(offsets, 1).reach
    return 2 ** (levels - 1) * (max(up + down, left + right) + 4)


def _as_image(image, *, levels, neighbourhood, channel_axis, name):
    data = as_channel_last_float(image, channel_axis=channel_axis, name=name)
    need = minimum_size(levels=levels, neighbourhood=neighbourhood)
    if min(data.shape[:2]) < need:
        raise ValueError(
            f"{name} is {data.shape[0]}x{data.shape[1]}: too small for {levels} pyramid "
            f"level(s) with this neighbourhood; each side needs at least {need} pixels. "
            "Use a larger image, fewer levels or a lower order."
        )
    return data


def _features(data, *, levels, offsets, name):
    eta = len(offsets)
    d = data.shape[2]
    try:
        raw = illumination_invariants(data, offsets, levels=levels, channel_axis=-1)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    per_level = raw.reshape(levels, eta + 2 * eta * d + 3)
    # traces (eta values) and alpha_3 (the last value) of every level
    return np.ascontiguousarray(
        np.concatenate([per_level[:, :eta], per_level[:, -1:]], axis=1).ravel()
    )


def texture_features(image, *, levels=3, neighbourhood=2, channel_axis=-1):
    """Illumination-invariant texture feature vector (SPEC section 2).

    The image is decomposed by the Gaussian-Laplacian pyramid of
    :func:`car_napari.illumination_invariants` (``levels`` band-pass levels,
    finest first, each half the size of the one before). On every level a
    3DCAR model (full ``d x d`` matrices ``A_m``, one per neighbour offset)
    is fitted to the mean-subtracted band, and these invariants are kept:

    1. ``trace(A_m)`` for ``m = 1..eta`` in the neighbourhood's order
       (feature 1 of SPEC section 2; ``eta`` values);
    2. ``alpha_3 = sqrt(sum_r (Y_r - mu)^T lambda^{-1} (Y_r - mu))`` (feature
       5 of SPEC section 2), with ``lambda`` the residual scatter of the fit
       (a sum over pixels, like the numerator, so the value does not grow
       with the image size).

    The vector is ``[trace(A_1), ..., trace(A_eta), alpha_3]`` of level 0,
    then of level 1, and so on: ``levels * (eta + 1)`` values (15 for the
    defaults). Every value is invariant to ``Y -> B Y`` for any invertible
    ``d x d`` matrix ``B`` applied to the channels (exactly, up to
    rounding), and for a grey image to any gain. The eigenvalues of the
    ``A_m`` and ``alpha_1``, ``alpha_2`` are invariant too but are left out:
    they hurt retrieval (measured; see the module docstring).

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Grey or colour texture; integer images are scaled to [0, 1]. Each side
        needs at least :func:`minimum_size` pixels (24 for the defaults). The
        channels must be linearly independent (a grey image stored as RGB is
        refused: pass it as 2-D with ``channel_axis=None``).
    levels : int, optional
        Levels of the pyramid.
    neighbourhood : int or (eta, 2) array, optional
        Order of the causal neighbourhood (SPEC 1.1) or explicit offsets.
    channel_axis : int or None, optional
        Axis of the channels; None for a 2-D grey image.

    Returns
    -------
    features : (levels * (eta + 1),) ndarray of float64

    Raises
    ------
    ValueError
        Bad ``levels`` or ``neighbourhood``, an image too small, constant, with
        dependent channels, or with NaN.
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    data = _as_image(image, levels=levels, neighbourhood=offsets,
                     channel_axis=channel_axis, name="image")
    return _features(data, levels=levels, offsets=offsets, name="image")


def _describe(item, name, *, levels, offsets, channel_axis):
    """(features or None, image data or None, n_channels or None) for one
    query/gallery entry: 1-D is a feature vector, 2-D or 3-D an image."""
    try:
        arr = np.asarray(item)
    except Exception as exc:
        raise TypeError(f"{name} could not be converted to an array: {exc}") from None
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} has dtype {arr.dtype}; pass a numeric image or feature vector.")
    if arr.ndim == 0:
        raise ValueError(
            f"{name} is a scalar; pass an image (2-D or 3-D) or a 1-D feature vector."
        )
    if arr.ndim == 1:
        if arr.size == 0:
            raise ValueError(f"{name} is an empty feature vector.")
        vec = arr.astype(np.float64)
        if not np.all(np.isfinite(vec)):
            raise ValueError(f"{name} (a feature vector) contains NaN or infinite values.")
        return vec, None, None
    data = _as_image(arr, levels=levels, neighbourhood=offsets,
                     channel_axis=channel_axis if arr.ndim == 3 else None, name=name)
    return None, data, data.shape[2]


def rank(query, gallery, *, levels=3, neighbourhood=2, channel_axis=-1):
    """Rank a gallery of textures by their distance to a query texture.

    The distance between feature vectors ``a`` (the query) and ``b`` (a
    gallery entry), both from :func:`texture_features`, is the normalised L1

        ``sum_i |a_i - b_i| / s_i``,

    with ``s_i`` the standard deviation of feature ``i`` over the gallery
    (population, ``ddof=0``); a feature that does not vary over the gallery
    (or a one-entry gallery) gets ``s_i = 1``. This scaling gives every
    feature the same say whatever its units (traces are about 0.1-2,
    ``alpha_3`` about 1-10) and retrieved best of the normalisations tried
    (see the module docstring). The distances therefore depend on the
    gallery; the order between two gallery entries does not depend on the
    query's type (image or vector).

    Parameters
    ----------
    query : (H, W) or (H, W, C) array, or 1-D array
        An image, or its precomputed :func:`texture_features` vector.
    gallery : sequence of images or of 1-D feature vectors
        A list (or stacked array) of images, or of feature vectors computed
        with the same ``levels`` and ``neighbourhood``; the two may be mixed.
        A stacked array is split along its first axis: 2-D ``(n, features)``
        is n feature vectors, 3-D ``(n, H, W)`` n grey images and 4-D
        ``(n, H, W, C)`` n colour images.
    levels, neighbourhood, channel_axis
        As for :func:`texture_features`; used for the images only. A 2-D
        image is always grey (its ``channel_axis`` is ignored).

    Returns
    -------
    indices : (n,) ndarray of int
        Gallery indices, nearest first (ties keep the gallery order).
    distances : (n,) ndarray of float64
        The distances in that order (``distances[0]`` is the smallest).

    Raises
    ------
    ValueError
        An empty gallery; feature vectors of different lengths (e.g. computed
        with other ``levels`` or ``neighbourhood``); grey and colour images
        mixed, or colour images with different channel counts; an image too
        small (the message names the minimum side).
    TypeError
        A non-numeric entry.

    Notes
    -----
    A precomputed feature vector does not record whether it came from a grey
    or a colour image (both give ``levels * (eta + 1)`` values): keep grey and
    colour galleries apart yourself when passing vectors.
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    if gallery is None:
        raise TypeError("gallery is None: pass a sequence of images or feature vectors.")
    if isinstance(gallery, np.ndarray):
        if gallery.ndim in (2, 3, 4):
            entries = list(gallery)  # rows: feature vectors or images
        else:
            raise ValueError(
                f"gallery array must be 2-D (n, features) or a 3-D/4-D stack of images; "
                f"got shape {gallery.shape}."
            )
    else:
        try:
            entries = list(gallery)
        except TypeError:
            raise TypeError(
                f"gallery must be a sequence of images or feature vectors; got "
                f"{type(gallery).__name__}."
            ) from None
    if len(entries) == 0:
        raise ValueError("gallery is empty: pass at least one image or feature vector.")

    common = dict(levels=levels, offsets=offsets, channel_axis=channel_axis)
    described = [_describe(query, "query", **common)]
    described += [_describe(e, f"gallery[{i}]", **common) for i, e in enumerate(entries)]
    names = ["query"] + [f"gallery[{i}]" for i in range(len(entries))]

    # grey and colour (or different channel counts) must not be mixed
    channels = {n: c for n, (_, _, c) in zip(names, described) if c is not None}
    if len(set(channels.values())) > 1:
        first = names[0] if names[0] in channels else next(iter(channels))
        other = next(n for n, c in channels.items() if c != channels[first])
        kind = {1: "grey"}
        raise ValueError(
            f"{first} is {kind.get(channels[first], f'{channels[first]}-channel')} but {other} "
            f"is {kind.get(channels[other], f'{channels[other]}-channel')}: grey and colour "
            "textures (or different channel counts) cannot be compared. Convert them all "
            "to one kind first."
        )
    expected = levels * (len(offsets) + 1)
    for n, (vec, _, _) in zip(names, described):
        if vec is not None and vec.size != expected:
            raise ValueError(
                f"{n} is a feature vector of length {vec.size}, but levels={levels} with "
                f"this neighbourhood ({len(offsets)} offsets) gives {expected} features: "
                "compute every vector with texture_features and the same levels and "
                "neighbourhood."
            )

    feats = np.array([
        vec if vec is not None else _features(data, levels=levels, offsets=offsets, name=n)
        for n, (vec, data, _) in zip(names, described)
    ])
    q, G = feats[0], feats[1:]
    spread = G.std(axis=0)
    scale = np.where(spread > 1e-12 * np.maximum(np.abs(G).max(axis=0), 1e-300), spread, 1.0)
    distances = (np.abs(G - q) / scale).sum(axis=1)
    order = np.argsort(distances, kind="stable")
    return order, distances[order]
