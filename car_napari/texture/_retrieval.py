"""Illumination-invariant texture retrieval (section 14.3, docs/model.md).

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
  of section 14.3: 0.74 / 0.61 with the same distance. The eigenvalues of the
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

from typing import NamedTuple

import numpy as np
from scipy import ndimage as ndi

from .._docstrings import shared_parameters, shared_sections
from .._progress import Progress, drain, mapped, result_of
from .._validation import (
    MAGNITUDE_LIMIT,
    Summary,
    as_channel_last_float,
    channel_last_view,
    check_channel_axis,
    check_not_constant,
    check_size,
)
from ..model.neighbourhood import Context, as_offsets
from ..model.statistics import covariant_estimates, design_chunks

__all__ = ["Ranking", "iter_rank", "minimum_size", "rank", "texture_features"]

# The features of an image are computed in bands of about this many pixels
# (of the pyramid level at hand, a few hundredths of a second each): a record
# can come between two bands, and memory beyond the input is the next
# pyramid level (a quarter of the image, as float64) and a few bands.
BAND_PIXELS = 1 << 17
# The Gaussian-Laplacian pyramid of skimage.transform.pyramid_laplacian
# (downscale 2, its default sigma, scipy.ndimage's default truncation) that
# illumination_invariants uses, computed band by band.
# the examples' shared start (docstring sections written once)
EXAMPLES_GALLERY = """
Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
"""


_SIGMA = 2 * 2 / 6.0
_TRUNCATE = 4.0
_RADIUS = int(_TRUNCATE * _SIGMA + 0.5)  # rows of the smoothing kernel on each side (3)


_MAX_LEVELS = 16  # beyond, the coarsest level of any image is below one pixel


def _check_levels(levels):
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)) \
            or not 1 <= levels <= _MAX_LEVELS:
        raise ValueError(f"levels must be a positive int up to {_MAX_LEVELS}; got {levels!r}.")
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
        Order of the causal neighbourhood (causal neighbourhoods,
        docs/model.md) or explicit offsets.

    Returns
    -------
    int
        ``2**(levels - 1) * (reach + 4)`` with ``reach`` the neighbourhood's
        larger extent (rows or columns); 24 for the defaults.

    Raises
    ------
    ValueError
        If ``levels`` is not a positive int or ``neighbourhood`` is invalid.

    Examples
    --------
    >>> from car_napari.texture import minimum_size
    >>> minimum_size(), minimum_size(levels=2, neighbourhood=1)
    (24, 10)
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    (up, down), (left, right) = Context.spatial(offsets, 1).reach
    return 2 ** (levels - 1) * (max(up + down, left + right) + 4)


def _level_shapes(height, width, levels):
    """(rows, columns) of every pyramid level: each halves the last, rounding up."""
    shapes = [(height, width)]
    for _ in range(levels - 1):
        height, width = -(-height // 2), -(-width // 2)
        shapes.append((height, width))
    return shapes


def _as_image(image, *, levels, offsets, channel_axis, name):
    """The image as a channel-last view, with every check that needs no pass
    over its values: numeric, 2-D or 3-D, large enough for every level."""
    view = channel_last_view(image, channel_axis=channel_axis, name=name)
    need = minimum_size(levels=levels, neighbourhood=offsets)
    if min(view.shape[:2]) < need:
        raise ValueError(
            f"{name} is {view.shape[0]}x{view.shape[1]}: too small for {levels} pyramid "
            f"level(s) with this neighbourhood; each side needs at least {need} pixels. "
            "Use a larger image, fewer levels or a lower order."
        )
    ctx = Context.spatial(offsets, view.shape[2])
    for h, w in _level_shapes(*view.shape[:2], levels):
        try:
            check_size(np.empty((h, w, 0)), ctx.reach,
                       minimum_pixels=ctx.n_regressors + view.shape[2] + 2,
                       name="pyramid level")
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
    return view


def _nonfinite(view):
    """The number of NaN or infinite values of ``view``, by bands of rows."""
    if view.dtype.kind != "f":
        return 0
    step = max(1, BAND_PIXELS // max(1, view.shape[1]))
    return sum(int(np.count_nonzero(~np.isfinite(view[a:a + step])))
               for a in range(0, view.shape[0], step))


class _Level0Rows:
    """Rows of the input as float64 (integers scaled to [0, 1], as
    :func:`~car_napari._validation.as_channel_last_float` converts them, and
    checked the same way), with the running per-channel range."""

    def __init__(self, view, name):
        self.view, self.name = view, name
        d = view.shape[2]
        self.lo, self.hi = np.full(d, np.inf), np.full(d, -np.inf)

    def __call__(self, start, stop):
        try:
            rows, summary = as_channel_last_float(self.view[start:stop], channel_axis=-1,
                                                  name=self.name, with_summary=True)
        except ValueError:
            bad = _nonfinite(self.view)  # the count of the whole image, not of the band
            if bad:
                raise ValueError(
                    f"{self.name} contains {bad} NaN or infinite values; fill or mask them "
                    "first (e.g. np.nan_to_num, or restrict the fit to a finite rectangle)."
                ) from None
            raise
        np.minimum(self.lo, summary.min, out=self.lo)
        np.maximum(self.hi, summary.max, out=self.hi)
        return rows

    def check(self):
        """The input must not be constant (after the pass over all its rows)."""
        d = self.lo.size
        summary = Summary(self.lo, self.hi, np.zeros(d), np.zeros(d), np.zeros(d))
        try:
            check_not_constant(None, summary=summary)
        except ValueError as exc:
            raise ValueError(f"{self.name}: {exc}") from None


def _iter_features(view, *, levels, offsets, name):
    """The features of :func:`texture_features` of a checked channel-last
    view, level by level and band by band of rows; yields ``(pixels, level)``
    after every band (the pixels of that band), returns the vector.

    Every level of the Gaussian-Laplacian pyramid is the band-pass
    ``R - G(R)`` of its image ``R`` (the input, then ``G(R)`` halved by
    linear interpolation and clipped to its range), as in
    :func:`skimage.transform.pyramid_laplacian`; with one level there is no
    pyramid: the level is the image itself. A band of ``G(R)`` is smoothed
    from the band of ``R`` with the kernel's rows around it: the same values
    as smoothing the whole image. A first pass over the bands makes the
    level (kept, float64) and the next level's image; a second one, after
    the level's mean, sums the statistics of the centred level band by band
    (the data-gathering matrix of
    :func:`~car_napari.model.statistics.data_statistics`, the scatter).
    """
    height, width, d = view.shape
    eta = len(offsets)
    ctx = Context.spatial(offsets, d)
    (up, down), _ = ctx.reach
    m = ctx.n_regressors
    shapes = _level_shapes(height, width, levels)
    level0 = _Level0Rows(view, name)
    rows = level0
    features = []
    for k, (H, W) in enumerate(shapes):
        last = k == levels - 1
        step = max(up + down + 1, BAND_PIXELS // W)
        bands = [(a, min(a + step, H)) for a in range(0, H, step)]
        level = np.empty((H, W, d))
        total = np.zeros(d)
        if not last:
            Hn, Wn = shapes[k + 1]
            nxt = np.empty((Hn, Wn, d))
            coord = (np.arange(Hn) + 0.5) * (H / Hn) - 0.5  # scipy.ndimage.zoom's grid
            top = np.floor(coord).astype(np.intp)
            row_t = (coord - top)[:, None, None]
            coord = (np.arange(Wn) + 0.5) * (W / Wn) - 0.5
            left = np.floor(coord).astype(np.intp)
            col_t = (coord - left)[None, :, None]
            right = np.minimum(left + 1, W - 1)
            smallest, largest = np.inf, -np.inf
        for a, b in bands:  # the level, and the next level's image
            s1 = b if last else min(b + 1, H)  # the rows of G(R) needed
            x0, x1 = max(a - _RADIUS, 0), min(s1 + _RADIUS, H)  # the rows of R they need
            image = rows(x0, x1)
            if levels == 1:
                level[a:b] = image[a - x0:b - x0]
                total += level[a:b].reshape(-1, d).sum(axis=0)
                yield (b - a) * W, k
                continue
            smooth = ndi.gaussian_filter(image, (_SIGMA, _SIGMA, 0), mode="reflect",
                                         truncate=_TRUNCATE)
            np.subtract(image[a - x0:b - x0], smooth[a - x0:b - x0], out=level[a:b])
            if not last:
                part = smooth[a - x0:b - x0]
                smallest = min(smallest, float(part.min()))
                largest = max(largest, float(part.max()))
                o0, o1 = np.searchsorted(top, [a, b])  # the next level's rows from these
                if o1 > o0:
                    r = top[o0:o1] - x0
                    t = row_t[o0:o1]
                    halved = (1.0 - t) * smooth[r] + t * smooth[r + 1]
                    nxt[o0:o1] = (1.0 - col_t) * halved[:, left] + col_t * halved[:, right]
            total += level[a:b].reshape(-1, d).sum(axis=0)
            del image, smooth
            yield (b - a) * W, k
        if k == 0:
            level0.check()
        mean = total / (H * W)
        scatter = np.zeros((d, d))
        V = np.zeros((m + d, m + d))
        count = 0
        for a, b in bands:  # the statistics of the centred level
            s0, e = max(a - up, 0), min(b + down, H)
            centred = level[s0:e] - mean
            own = centred[a - s0:b - s0].reshape(-1, d)
            scatter += own.T @ own
            for Z in design_chunks(centred, ctx):  # the rows a..b with a whole neighbourhood
                V += Z.T @ Z
                count += Z.shape[0]
            del centred, own
            yield (b - a) * W, k
        del level
        evals = np.linalg.eigvalsh(scatter)
        if evals[0] <= 1e-10 * evals[-1]:
            raise ValueError(
                f"{name}: the image's channels are linearly dependent (e.g. a grey image "
                "stored as RGB): illumination invariants need independent channels. Pass "
                "one channel (channel_axis=None on a 2-D image) or a true colour image."
            )
        # covariant prior: one pixel's worth of the data's own scatter (and a
        # small multiple of it where a degenerate texture leaves V singular)
        gamma, lam = covariant_estimates(V, count, m, d, scatter / (H * W))[0][:2]
        A = gamma.reshape(d, eta, d).transpose(1, 0, 2)
        chol = np.linalg.cholesky(lam)
        white = np.linalg.solve(chol, np.linalg.solve(chol, scatter).T)
        features.extend(np.trace(A, axis1=1, axis2=2))
        features.append(float(np.sqrt(np.trace(white))))  # alpha_3
        if not last:  # the next level's image: G(R) halved, clipped to its range
            def rows(start, stop, image=nxt, lo=smallest, hi=largest):
                return np.clip(image[start:stop], lo, hi)
    return np.asarray(features, dtype=np.float64)


def texture_features(image, *, levels=3, neighbourhood=2, channel_axis=-1):
    """Illumination-invariant texture feature vector (section 14.3, docs/model.md).

    The image is decomposed by the Gaussian-Laplacian pyramid of
    :func:`car_napari.illumination_invariants` (``levels`` band-pass levels,
    finest first, each half the size of the one before). On every level a
    3DCAR model (full ``d x d`` matrices ``A_m``, one per neighbour offset)
    is fitted to the mean-subtracted band, and these invariants are kept:

    1. ``trace(A_m)`` for ``m = 1..eta`` in the neighbourhood's order
       (feature 1 of section 14.3; ``eta`` values);
    2. ``alpha_3 = sqrt(sum_r (Y_r - mu)^T lambda^{-1} (Y_r - mu))`` (feature
       5 of section 14.3), with ``lambda`` the residual scatter of the fit
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
        refused: pass it as 2-D).
    levels : int, optional
        Levels of the pyramid.
    neighbourhood : int or (eta, 2) array, optional
        Order of the causal neighbourhood (causal neighbourhoods,
        docs/model.md) or explicit offsets.
    channel_axis : int or None, optional
        Axis of the channels of a 3-D image (default the last); a 2-D image
        is always grey, and None requires one.

    Returns
    -------
    features : (levels * (eta + 1),) ndarray of float64
        The traces and ``alpha_3`` of every level, finest level first.

    Raises
    ------
    ValueError
        Bad ``levels`` or ``neighbourhood``, an image too small, constant, with
        dependent channels, or with NaN.
    TypeError
        A non-numeric image.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import texture_features
    >>> image = np.random.default_rng(0).random((32, 32, 3))
    >>> features = texture_features(image, levels=1)
    >>> features.shape
    (5,)
    >>> B = np.array([[0.5, 0.2, 0.1], [0.1, 0.6, 0.2], [0.2, 0.1, 0.4]])
    >>> np.allclose(texture_features(image @ B.T, levels=1), features)
    True
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    view = _as_image(image, levels=levels, offsets=offsets, channel_axis=channel_axis,
                     name="image")
    return result_of(_iter_features(view, levels=levels, offsets=offsets, name="image"))


def _describe(item, name, *, levels, offsets, channel_axis):
    """(features or None, image data or None, n_channels or None) for one
    query/gallery entry: 1-D is a feature vector, 2-D or 3-D an image."""
    check_channel_axis(channel_axis)
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
    view = _as_image(arr, levels=levels, offsets=offsets,
                     channel_axis=channel_axis if arr.ndim == 3 else None, name=name)
    return None, view, view.shape[2]


class Ranking(NamedTuple):
    """A gallery ranked by distance to a query: what :func:`rank` returns.

    Unpacks like a pair: ``indices, distances = rank(query, gallery)``.

    Parameters
    ----------
    indices : (n,) ndarray of int
        Gallery indices, nearest first (ties keep the gallery order).
    distances : (n,) ndarray of float64
        The distances in that order (``distances[0]`` is the smallest).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.texture import Ranking
    >>> indices, distances = Ranking(np.array([1, 0]), np.array([0.5, 2.0]))
    >>> indices.tolist(), distances.tolist()
    ([1, 0], [0.5, 2.0])
    """

    indices: np.ndarray
    distances: np.ndarray


def _gallery_entries(gallery):
    """The gallery as a list of entries (a stacked array split along axis 0)."""
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
    return entries


def _check_comparable(names, described, *, levels, offsets):
    """Grey and colour must not be mixed; feature vectors must have the right length."""
    channels = {n: c for n, (_, _, c) in zip(names, described, strict=True) if c is not None}
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
    for n, (vec, _, _) in zip(names, described, strict=True):
        if vec is not None and vec.size != expected:
            raise ValueError(
                f"{n} is a feature vector of length {vec.size}, but levels={levels} with "
                f"this neighbourhood ({len(offsets)} offsets) gives {expected} features: "
                "compute every vector with texture_features and the same levels and "
                "neighbourhood."
            )


_RANK_PARAMETERS = """
query : (H, W) or (H, W, C) array, or 1-D array
    An image, or its precomputed :func:`texture_features` vector.
gallery : sequence of images or of 1-D feature vectors
    A list (or stacked array) of images, or of feature vectors computed
    with the same ``levels`` and ``neighbourhood``; the two may be mixed.
    A stacked array is split along its first axis: 2-D ``(n, features)``
    is n feature vectors, 3-D ``(n, H, W)`` n grey images and 4-D
    ``(n, H, W, C)`` n colour images.
levels : int, optional
    Levels of the pyramid, as for :func:`texture_features` (images only).
neighbourhood : int or (eta, 2) array, optional
    As for :func:`texture_features` (images only).
channel_axis : int or None, optional
    Axis of the channels of 3-D images, as for :func:`texture_features`.
    A 2-D image is always grey (its ``channel_axis`` is ignored).
"""


@shared_parameters(_RANK_PARAMETERS)
@shared_sections(examples_gallery=EXAMPLES_GALLERY)
def iter_rank(query, gallery, *, levels=3, neighbourhood=2, channel_axis=-1):
    """Rank a gallery by distance to a query, as a job reporting progress.

    The generator form of :func:`rank` (same arguments, same result): every
    entry's type, shape and size is checked first, then it yields a
    :class:`~car_napari.Progress` record before the features of the query
    (``"query"``) and of every gallery entry (``"gallery 3/12"``) are
    computed, records between the bands of rows of a large image (see
    below) and a last one when the gallery is ranked, and returns the
    :class:`Ranking`. Closing the generator stops the work at the next
    record: within a band (:data:`BAND_PIXELS` pixels, a fraction of a
    second).

    The images are read where they are (views, not copied) and never
    modified; an image's features are computed band by band, so that beyond
    the inputs the job holds about ``10 * d`` bytes per pixel of the image
    being described (``d`` channels: its current pyramid level and the next
    level's image, float64), and nothing of the images already described.

    {parameters}

    Returns
    -------
    Ranking
        ``(indices, distances)``, nearest first (the generator's return value).

    Yields
    ------
    Progress
        Stage ``"features"``, then ``"ranking"``; ``fraction`` is the share
        of the images' pixels already described (feature vectors cost
        nothing; a gallery of vectors only advances by entries). On an
        image of more than :data:`BAND_PIXELS` pixels, a record after every
        band's worth of work, message like ``"gallery 3/12, level 1/3"``.

    Raises
    ------
    ValueError
        As :func:`rank`: before the first record for the types, shapes and
        sizes; for the values (NaN, a constant image, dependent channels)
        when the entry's features are computed.
    TypeError
        As :func:`rank`, before the first record.

    {examples_gallery}
    >>> from car_napari.texture import iter_rank
    >>> gallery = [rng.random((24, 24)) for _ in range(2)]
    >>> for record in iter_rank(gallery[1], gallery, levels=1, neighbourhood=1):
    ...     print(record.stage, record.message, round(record.fraction, 2))
    features query 0.0
    features gallery 1/2 0.33
    features gallery 2/2 0.67
    ranking 2 ranked 1.0
    """
    levels = _check_levels(levels)
    offsets, _ = as_offsets(neighbourhood)
    entries = _gallery_entries(gallery)
    common = dict(levels=levels, offsets=offsets, channel_axis=channel_axis)
    described = [_describe(query, "query", **common)]
    described += [_describe(e, f"gallery[{i}]", **common) for i, e in enumerate(entries)]
    names = ["query"] + [f"gallery[{i}]" for i in range(len(entries))]
    _check_comparable(names, described, levels=levels, offsets=offsets)

    # the features' cost is proportional to the pixels; vectors cost nothing
    cost = np.array([0.0 if data is None else data.shape[0] * data.shape[1]
                     for _, data, _ in described])
    if cost.sum() == 0:
        cost[:] = 1.0
    done = np.concatenate([[0.0], np.cumsum(cost)]) / cost.sum()
    n = len(entries)
    feats = []
    for i, (name, (vec, view, _)) in enumerate(zip(names, described, strict=True)):
        label = "query" if i == 0 else f"gallery {i}/{n}"
        yield Progress("features", float(done[i]), label)
        if vec is not None:
            feats.append(vec)
            continue
        # a record between bands once a band's worth of pixels is done (none
        # on a small image): a Cancel stops the job within a band
        job = _iter_features(view, levels=levels, offsets=offsets, name=name)
        work = 2 * sum(h * w for h, w in _level_shapes(*view.shape[:2], levels))
        finished = pending = 0

        def band_record(step, i=i, label=label, work=work):
            nonlocal finished, pending
            pixels, level = step
            finished += pixels
            pending += pixels
            if pending >= BAND_PIXELS and finished < work:
                pending = 0
                fraction = done[i] + (done[i + 1] - done[i]) * finished / work
                return Progress("features", float(fraction),
                                f"{label}, level {level + 1}/{levels}")
            return None

        feats.append((yield from mapped(job, band_record)))
    q, G, exponents = _moderate(np.array(feats))
    spread = G.std(axis=0)
    # a feature without spread counts its absolute difference (in its own units)
    scale = np.where(spread > 1e-12 * np.maximum(np.abs(G).max(axis=0), 1e-300), spread,
                     np.ldexp(1.0, -exponents))
    with np.errstate(over="ignore"):  # an overflow is the ValueError below
        distances = (np.abs(G - q) / scale).sum(axis=1)
    if not np.all(np.isfinite(distances)):
        raise ValueError(
            "the distances overflow: the query's features are more than about 1e300 "
            "gallery spreads away from the gallery's in some feature (e.g. a gallery of "
            "near-identical vectors and a far query). Rescale or drop that feature.")
    order = np.argsort(distances, kind="stable")
    yield Progress("ranking", 1.0, f"{n} ranked")
    return Ranking(order, distances[order])


def _moderate(feats):
    """``(query, gallery, exponents)`` of the (1 + n, k) feature vectors, the
    features whose magnitude in the gallery passes ``MAGNITUDE_LIMIT``
    scaled by ``2**-exponents`` (the others as they are, exponent 0, so the distances
    of ordinary vectors are unchanged bit for bit): their squares, in the
    gallery's spread, would overflow to inf and their distances come out 0.
    Each feature's distance is a ratio to its spread, which an exact
    scaling does not change."""
    peak = np.abs(feats[1:]).max(axis=0)  # the gallery's: its spread is the divisor
    big = peak > MAGNITUDE_LIMIT
    exponents = np.zeros(feats.shape[1], np.int64)
    if big.any():
        exponents[big] = np.frexp(peak[big])[1]
        feats = feats.copy()
        feats[:, big] = np.ldexp(feats[:, big], -exponents[big])
    return feats[0], feats[1:], exponents


@shared_parameters(_RANK_PARAMETERS)
@shared_sections(examples_gallery=EXAMPLES_GALLERY)
def rank(query, gallery, *, levels=3, neighbourhood=2, channel_axis=-1):
    """Rank a gallery of textures by their distance to a query texture.

    The same as running :func:`iter_rank` to its end. The distance between
    feature vectors ``a`` (the query) and ``b`` (a gallery entry), both from
    :func:`texture_features`, is the normalised L1

        ``sum_i |a_i - b_i| / s_i``,

    with ``s_i`` the standard deviation of feature ``i`` over the gallery
    (population, ``ddof=0``); a feature that does not vary over the gallery
    (or a one-entry gallery) gets ``s_i = 1``. This scaling gives every
    feature the same say whatever its units (traces are about 0.1-2,
    ``alpha_3`` about 1-10) and retrieved best of the normalisations tried
    (see the module docstring). The distances therefore depend on the
    gallery; the order between two gallery entries does not depend on the
    query's type (image or vector).

    {parameters}

    Returns
    -------
    Ranking
        A named pair ``(indices, distances)``: the gallery indices, nearest
        first (ties keep the gallery order), and the distances in that
        order (``distances[0]`` is the smallest).

    Raises
    ------
    ValueError
        An empty gallery; feature vectors of different lengths (e.g. computed
        with other ``levels`` or ``neighbourhood``); grey and colour images
        mixed, or colour images with different channel counts; an image too
        small (the message names the minimum side); distances beyond
        float64's range (a query about 1e300 gallery spreads away; features
        of any magnitude are otherwise compared exactly, scaled).
    TypeError
        A non-numeric entry.

    See Also
    --------
    iter_rank : The same ranking as a job that reports its progress.

    Notes
    -----
    A precomputed feature vector does not record whether it came from a grey
    or a colour image (both give ``levels * (eta + 1)`` values): keep grey and
    colour galleries apart yourself when passing vectors.

    {examples_gallery}
    >>> from car_napari.texture import rank
    >>> gallery = [rng.random((24, 24)) for _ in range(3)]
    >>> indices, distances = rank(gallery[2], gallery, levels=1)
    >>> int(indices[0]), float(distances[0])
    (2, 0.0)
    """
    return drain(iter_rank(query, gallery, levels=levels, neighbourhood=neighbourhood,
                           channel_axis=channel_axis))
