"""Multichannel restoration: one scene from several registered degraded
versions (section 14.6, docs/restoration.md).

The least degraded version is modelled by the 2.5D CAR model whose regression
vector holds the causal neighbours in all versions and the other versions'
pixels at the same place; a pixel is replaced by its prediction where the
prediction probability exceeds ``kappa`` (14.50)-(14.52).
"""

from __future__ import annotations

import operator
from functools import partial
from typing import NamedTuple

import numpy as np

from .._docstrings import documents_job, shared_parameters
from .._progress import Progress, drain, row_blocks, spans, stage
from .._threads import job_pool, submit
from .._validation import (
    channel_last_shape,
    check_channel_axis,
    check_not_constant,
    check_real,
    scale_exponent,
    summarize,
)
from ..model.blocks import iter_channel_last_float
from ..model.neighbourhood import Context, as_offsets
from ._checks import check_flags, check_kappa, check_options, resolve_offsets
from ._combine import (
    DirectionalAverage,
    chunk_rows,
    iter_calls,
    iter_directions,
)
from ._noise import estimate_noise, median_abs_laplacian, noise_from_medians
from ._single import DEFAULT_WINDOW, RestorationResult, _iter_edges, iter_restoration

# Threshold on the prediction probability (the predictive density relative to
# its peak, in [0, 1]) above which a pixel is replaced by its prediction;
# exp(-z^2/2) for a standardised error z, so 0.05 replaces |z| < 2.45.
DEFAULT_KAPPA = 0.05
# Time of one scan direction of the 2.5D model over the time of the
# reference's single-image (windowed) prediction, which shares out the
# progress fraction: about 2 (measured on 192 x 192 stacks of 3 and 6
# versions, grey and colour).
_SCAN_COST = 2.0
# Rows either side a strip of the sharpness measure reads: more than the
# Gaussian's reach (truncated at 4 sigma of 1 pixel, twice: 8 is ample).
_LOG_REACH = 12


class MultichannelRestoration(NamedTuple):
    """The restored reference and its prediction-probability image.

    What :func:`restore_multichannel` returns; unpacks as
    ``restored, probability = restore_multichannel(stack)``.

    Attributes
    ----------
    restored : (H, W) or (H, W, C) float64 ndarray
        The restored reference version, in the layout of one version of the
        stack (the stack without its versions axis).
    probability : (H, W) float64 ndarray
        The prediction-probability image in [0, 1] (see
        :class:`RestorationResult`).

    Examples
    --------
    >>> from car_napari.restoration import restore_multichannel
    >>> rng = np.random.default_rng(0)
    >>> stack = 0.5 + 0.1 * rng.standard_normal((2, 24, 24))
    >>> out = restore_multichannel(stack)
    >>> out.restored.shape, out.probability.shape
    ((24, 24), (24, 24))
    """

    restored: np.ndarray
    probability: np.ndarray


def multichannel_context(offsets, n_versions, reference, *, with_prediction=False):
    """Build the 2.5D context of multichannel restoration.

    Section 14.6, docs/restoration.md: the target is the reference version;
    the regressors are the causal neighbours in every version, then the
    other versions at ``r``, and with ``with_prediction`` also channel
    ``n_versions`` at ``r`` (the reference's single-image prediction).

    Parameters
    ----------
    offsets : (eta, 2) array of int
        The causal neighbourhood (row, column offsets) in every version.
    n_versions : int
        The number of versions (channels 0 to ``n_versions - 1``).
    reference : int
        The channel of the version restored.
    with_prediction : bool, optional
        Also regress on channel ``n_versions`` at ``r``.

    Returns
    -------
    context : Context
        Taps ``(di, dj, channel)`` and the target channel ``reference``.

    Examples
    --------
    >>> from car_napari.restoration import multichannel_context
    >>> context = multichannel_context([[1, 0], [0, 1]], 3, 0)
    >>> len(context.taps), context.targets.tolist()
    (8, [0])
    """
    offsets, _ = as_offsets(offsets, name="offsets")
    n_versions = check_real(n_versions, "n_versions", low=1, high=MAX_VERSIONS, integer=True)
    reference = check_real(reference, f"reference (a version in 0..{n_versions - 1})", low=0,
                           high=n_versions - 1, integer=True)
    taps = [(di, dj, v) for v in range(n_versions) for di, dj in offsets]
    taps += [(0, 0, v) for v in range(n_versions) if v != reference]
    if with_prediction:
        taps.append((0, 0, n_versions))
    return Context(np.array(taps, np.int64), np.array([reference]))


MAX_VERSIONS = 64  # more versions than this: the versions axis is probably wrong


def _check_axis(axis, ndim, shape):
    """The versions axis as an index in [0, ndim), or a clear error."""
    try:
        if isinstance(axis, (bool, np.bool_)):
            raise TypeError
        axis = operator.index(axis)
    except TypeError:
        raise TypeError(f"axis must be an integer: the axis of the stack that holds the "
                        f"versions; got {axis!r}.") from None
    if not -ndim <= axis < ndim:
        raise ValueError(
            f"axis={axis} is out of range for the {ndim}-D stack of shape {shape}: it names "
            f"the axis that holds the versions, in {-ndim}..{ndim - 1} (0 for (n, H, W) or "
            "(n, H, W, C))."
        )
    return axis % ndim


def _stack_layout(stack, *, axis, channel_axis):
    """(the stack with its versions first, position of the channel axis in
    one version's layout or None for grey), with clear errors."""
    check_channel_axis(channel_axis)
    if isinstance(stack, (list, tuple)):
        shapes = {np.shape(v) for v in stack}
        if len(shapes) > 1:
            raise ValueError(
                f"the versions differ in shape ({sorted(shapes)}); register and crop them "
                "to one shape first.")
        if stack:
            shape = np.shape(stack[0])
            axis = _check_axis(axis, len(shape) + 1, (len(stack), *shape))
        stack = np.stack(stack, axis=axis) if stack else np.empty((0, 0, 0))
    try:
        arr = np.asarray(stack)
    except Exception as exc:
        raise TypeError(f"stack could not be converted to an array: {exc}") from exc
    if arr.ndim not in (3, 4):
        raise ValueError(
            f"stack must be (n, H, W) or (n, H, W, C) with the versions along `axis`; got "
            f"shape {arr.shape}. (Versions of different shapes: register and crop them to "
            "one shape first.)"
        )
    if arr.dtype == object:
        raise ValueError("the versions in the stack differ in shape; register and crop them "
                         "to one shape first.")
    axis = _check_axis(axis, arr.ndim, arr.shape)
    position = None  # a 3-D stack has no room for a channel axis: grey
    if arr.ndim == 4:
        if channel_axis is None:
            raise ValueError(
                f"the stack is 4-D {arr.shape} but channel_axis=None (grey); pass the colour "
                "axis (e.g. channel_axis=-1 for (n, H, W, C)) or a 3-D (n, H, W) grey stack.")
        ch = int(channel_axis)  # an integer: check_channel_axis above
        if not -4 <= ch < 4:
            raise ValueError(f"channel_axis={ch} is out of range for the 4-D stack of shape "
                             f"{arr.shape}; pass one in -4..3 (-1 for (n, H, W, C)).")
        ch %= 4
        if ch == axis:
            raise ValueError(f"channel_axis and axis must differ (both name axis {ch} of the "
                             f"stack of shape {arr.shape}).")
        position = ch if ch < axis else ch - 1  # in the layout of one version
    arr = np.moveaxis(arr, axis, 0)
    if arr.shape[0] < 2:
        raise ValueError(
            f"the stack holds {arr.shape[0]} version along axis {axis}; multichannel "
            "restoration needs at least 2 (use restore() for a single image)."
        )
    plane = channel_last_shape(arr[0], channel_axis=position, name="version 0")[:2]
    if arr.shape[0] > min(MAX_VERSIONS, *plane):
        raise ValueError(
            f"axis={axis} gives {arr.shape[0]} versions of {plane[0]}x{plane[1]} images: more "
            f"versions than the images have pixels a side (or than {MAX_VERSIONS}). Is axis "
            "right? It names the axis that holds the versions (0 for (n, H, W) or "
            "(n, H, W, C))."
        )
    return arr, position


def _versions(stack, *, axis, channel_axis):
    """(list of channel-last float versions, position of the channel axis in
    one version's layout or None for grey), with clear errors."""
    arr, position = _stack_layout(stack, axis=axis, channel_axis=channel_axis)
    return drain(_iter_versions(arr, position)), position


def _iter_versions(arr, position):
    """The versions of the (n, ...) ``arr`` as channel-last floats, converted
    in strips of rows: Progress('reading') after each."""
    versions = []
    n = len(arr)
    for i, v in enumerate(arr):
        data, _ = yield from stage(
            iter_channel_last_float(v, channel_axis=position, name=f"version {i}",
                                    stage="reading"),
            i / n, (i + 1) / n)
        versions.append(data)
    return versions


def _in_version_layout(out, position):
    """Channel-last ``out`` (H, W, C) in the layout of one version."""
    return out[..., 0] if position is None else np.moveaxis(out, -1, position)


def _sharpness(versions):
    """:func:`sharpness` of validated channel-last versions."""
    return drain(_iter_sharpness(versions))


def _iter_sharpness(versions, pool=None):
    """:func:`sharpness` in strips of rows (the Laplacian of Gaussian at a
    row needs only the rows within ``_LOG_REACH``: the strips' are, bit for
    bit, the whole image's), on ``pool`` if given: Progress('sharpness')
    after each strip."""
    from scipy import ndimage

    H, W, C = versions[0].shape
    rows = row_blocks(H, chunk_rows(W, 8.0))
    out = np.empty((H, W))
    values = []
    steps = len(versions) * C

    def strip(plane, a, b):
        a0, b0 = max(0, a - _LOG_REACH), min(H, b + _LOG_REACH)
        out[a:b] = ndimage.gaussian_laplace(plane[a0:b0], 1.0)[a - a0 : b - a0]

    step = 0
    for k, v in enumerate(versions):
        means = []
        for c in range(C):
            plane = v[..., c]
            for m, _ in enumerate(iter_calls(pool, [partial(strip, plane, a, b)
                                                   for a, b in rows]), start=1):
                yield Progress("sharpness", (step + m / len(rows)) / steps,
                               f"version {k + 1}/{len(versions)}")
            step += 1
            means.append(np.mean(out**2))
        values.append(np.mean(means))
    return np.array(values)


def sharpness(stack, *, axis=0, channel_axis=-1):
    """Measure the sharpness of each version of a stack.

    The mean squared Laplacian after a 1-pixel Gaussian (which tames the
    noise so that blur decides), averaged over channels.
    ``restore_multichannel(reference='auto')`` restores the sharpest version.

    Parameters
    ----------
    stack : (n, H, W) or (n, H, W, C) array, or a sequence of versions
        At least two registered versions of one shape, along ``axis``.
    axis : int, optional
        The axis holding the versions (default 0).
    channel_axis : int or None, optional
        The colour axis of a 4-D stack (default -1); a 3-D stack is grey.

    Returns
    -------
    sharpness : (n,) float64 ndarray
        One value per version; larger is sharper.

    Raises
    ------
    ValueError
        If the stack is not 3-D or 4-D, holds fewer than two versions, has
        versions of different shapes, NaN or infinite values, or ``axis``
        or ``channel_axis`` is out of range.

    Examples
    --------
    >>> from scipy import ndimage
    >>> from car_napari.restoration import sharpness
    >>> sharp = np.random.default_rng(0).random((32, 32))
    >>> stack = np.stack([ndimage.gaussian_filter(sharp, 2), sharp])
    >>> int(np.argmax(sharpness(stack)))
    1
    """
    versions, _ = _versions(stack, axis=axis, channel_axis=channel_axis)
    return _sharpness(versions)


# the Parameters of both forms of the job, written once
_PARAMETERS = """
    stack : (n, H, W) or (n, H, W, C) array, or a sequence of versions
        At least two registered versions of one shape (a telescope burst,
        repeated scans, frames of a static scene), along ``axis``. With the
        default ``channel_axis`` a 3-D stack is grey and a 4-D stack colour.
    axis : int, optional
        The axis holding the versions (default 0).
    kappa : float in [0, 1), optional
        Threshold on the prediction probability; default ``DEFAULT_KAPPA``
        (0.05).
    reference : 'auto' or int, optional
        The version restored; 'auto' takes the sharpest by :func:`sharpness`.
    neighbourhood : int, (eta, 2) array or 'auto', optional
        Causal neighbourhood in every version (default order 1: 2 neighbours,
        so ``3n - 1`` regressors; colour channels get one model each).
    forgetting : float in [0.5, 1], optional
        Forgetting factor of the adaptive estimator ((14.26)-(14.32),
        docs/model.md); default 0.9995.
    directions : 'all' or sequence of str, optional
        The scan directions averaged, any of {'down', 'up', 'right', 'left'}.
    keep_edges : bool, optional
        Also apply the single-image edge rule (default on: +1.2 dB measured).
    reference_prediction : bool, optional
        Add the reference's single-image prediction (:func:`restore`'s four
        directions, whose regressors never include ``X_r``) to the regression
        vector at ``r``: +0.5 dB measured on 5 scenes of 8 versions. Our
        extension of (14.52).
    channel_axis : int or None, optional
        The colour axis of a 4-D stack (default -1: the last); a 3-D stack
        is always grey. None forces grey (and rejects a 4-D stack).
    return_result : bool, optional
        Return the :class:`RestorationResult` instead (``.reference``,
        ``.prediction``, ``.probability``; ``.restored(kappa)``).
"""


def iter_restore_multichannel(stack, *, axis=0, kappa=DEFAULT_KAPPA, reference="auto",
                              neighbourhood=1, forgetting=0.9995, directions="all",
                              keep_edges=True, reference_prediction=True, channel_axis=-1,
                              return_result=False):
    """Restore one scene from several degraded versions, step by step.

    It yields :class:`~car_napari.Progress` records while the reference's
    single-image prediction and then each scan direction of the 2.5D model
    run. Closing the generator stops the work after the scans in progress.

    {plain form}

    Yields
    ------
    progress : Progress
        Stage ``'start'`` (message: the number of versions), ``'reading'``
        (large versions), ``'sharpness'`` (with ``reference='auto'``),
        ``'reference'`` (the reference version, then its single-image
        prediction), ``'directions'`` (the 2.5D scans in chunks of rows; after
        each direction a record with a message like ``'channel 1/3,
        direction 2/4'`` and a preview: the running restored image, channels
        not yet restored showing the observation, in the layout of one
        version), then ``'edges'``.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> from car_napari.restoration import iter_restore_multichannel
    >>> rng = np.random.default_rng(0)
    >>> stack = 0.5 + 0.1 * rng.standard_normal((2, 24, 24))
    >>> records = []
    >>> restored, probability = drain(iter_restore_multichannel(stack), records.append)
    >>> restored.shape, [r.stage for r in records][-1]
    ((24, 24), 'edges')
    """
    kappa = check_kappa(kappa)
    forgetting, directions = check_options(forgetting, directions)
    check_flags(keep_edges=keep_edges, reference_prediction=reference_prediction,
                return_result=return_result)
    if not isinstance(neighbourhood, str):
        as_offsets(neighbourhood)  # its own message, before the stack is read
    arr, position = _stack_layout(stack, axis=axis, channel_axis=channel_axis)
    # a float stack of a spread beyond 2**±32 is restored scaled by a power of
    # two (exact) and scaled back: the directions' weights have absolute caps
    exponent = scale_exponent(arr)
    if exponent:
        arr = np.ldexp(arr.astype(np.float64), -exponent)
    n = len(arr)
    if isinstance(reference, str):
        if reference != "auto":
            raise ValueError(f"reference must be 'auto' or a version index; got "
                             f"{reference!r}.")
    else:
        reference = check_real(reference, f"reference ('auto' or a version index in "
                               f"{-n}..{n - 1})", low=-n, high=n - 1, integer=True)
    C = channel_last_shape(arr[0], channel_axis=position)[2]
    steps = C * len(directions)
    # the stages' shares of the work, as measured on 4 x 2048 x 2048 colour
    work = {"reading": 0.15 * n, "sharpness": 0.6 * n if reference == "auto" else 0.0,
            "reference": 1.0 if reference_prediction else 0.0,
            "directions": len(directions) * _SCAN_COST, "edges": 0.1 if keep_edges else 0.0}
    span = spans(work)
    yield Progress("start", 0.0, f"{n} versions")
    versions = yield from stage(_iter_versions(arr, position), *span("reading"))
    pool = job_pool()  # None: one thread (CAR_NAPARI_JOB_THREADS=1)
    if isinstance(reference, str):
        sharp = yield from stage(_iter_sharpness(versions, pool), *span("sharpness"))
        reference = int(np.argmax(sharp))
    else:
        reference = int(reference) % n
    observed = versions[reference]
    summary = summarize(observed)
    check_not_constant(observed, name=f"the reference version {reference}",
                       summary=summary)
    offsets = resolve_offsets(neighbourhood, observed)
    context = multichannel_context(offsets, n, reference,
                                   with_prediction=reference_prediction)
    # the noise level beside the scans, one channel per call
    noise_futures = [submit(pool, median_abs_laplacian, np.ascontiguousarray(
        observed[..., c])) for c in range(C)] if keep_edges else []
    try:
        result = yield from _iter_scans(
            versions, observed, reference, context, forgetting, directions,
            reference_prediction, position, pool, span, steps)
        pred, prob, spread = result
        noise = (noise_from_medians([f.result() for f in noise_futures]) if keep_edges
                 else estimate_noise(observed))
    finally:
        for future in noise_futures:
            future.cancel()
    weight = None
    if keep_edges:  # one segment of rows, in chunks here
        weight = yield from _iter_edges(observed, pred, spread.mean(axis=-1), noise, None, span)
    if exponent:  # back to the stack's units; probabilities and weights have none
        observed, pred, noise = (np.ldexp(a, exponent) for a in (observed, pred, noise))
    result = RestorationResult(observed, pred, prob, weight, reference, kappa, noise)
    if return_result:
        return result
    return MultichannelRestoration(_in_version_layout(result.restored(), position),
                                   result.probability)


def _iter_scans(versions, observed, reference, context, forgetting, directions,
                reference_prediction, position, pool, span, steps):
    """The reference's single-image prediction, then the 2.5D scans of every
    colour channel in chunks of rows (the directions side by side on ``pool``),
    with a preview after each direction; returns (prediction, probability,
    spread per channel)."""
    shape = observed.shape
    C = shape[2]
    n_dir = len(directions)
    yield Progress("reference", span("reference")[0], f"reference version {reference}")
    extra = []
    if reference_prediction:
        # Section 14.5's four-direction prediction of the reference: a summary
        # of its neighbourhood on every side whose regressors never include
        # the pixel (the window models do, as one pixel of about 2300).
        prediction = yield from stage(iter_restoration(
            observed, neighbourhood=1, estimator="windowed", window=DEFAULT_WINDOW,
            forgetting=0.995, directions="all", keep_edges=False, kappa=0.0, noise=None,
            channel_axis=-1, live=False, probability=False, blend=False),
            *span("reference"), name="reference")
        extra = [prediction.prediction]
    share = span("directions")
    pred = np.empty(shape)
    prob_sum = np.zeros(shape[:2])
    spread = np.zeros(shape)
    total = steps * shape[0] * shape[1]
    scanned = done = 0
    channel_pred, channel_prob = np.empty(shape[:2] + (1,)), np.empty(shape[:2])
    rows = chunk_rows(shape[1], len(versions) + len(extra))
    for c in range(C):  # colour versions: one 2.5D model per colour channel
        fraction = share.at(scanned, total)
        message = f"channel {c + 1}/{C}: preparing"
        source, means, var = yield from _iter_centred_source(
            versions + extra, c, rows, Progress("directions", fraction, message))
        average = DirectionalAverage(source[..., reference : reference + 1], means[[reference]])
        k = 0
        for pixels, finished in iter_directions(
                source, context, var[[reference]], forgetting=forgetting,
                directions=directions, outputs=("mean", "logrel"), prior=1e-6, pool=pool):
            scanned += pixels
            fraction = share.at(scanned, total)
            yield Progress("directions", fraction,
                           f"channel {c + 1}/{C}: scans {100 * scanned // total} %")
            for _, result in finished:
                k += 1
                done += 1
                # here, beside the scans on the pool (bit for bit the same sums)
                for _ in average.iter_add(result["mean"], result["logrel"]):
                    yield Progress("directions", fraction,
                                   f"channel {c + 1}/{C}, direction {k}/{n_dir}: combining")
                del result
                # the preview in chunks of rows, a yield between (a 4000x4000
                # colour image is seconds in one piece: Cancel waits for it)
                message = f"channel {c + 1}/{C}, direction {k}/{n_dir}: preview"
                for _ in average.iter_prediction(channel_pred, channel_prob):
                    yield Progress("directions", fraction, message)
                running = np.empty(shape)
                for a, b in row_blocks(shape[0], rows):
                    pred[a:b, :, c] = channel_pred[a:b, :, 0]
                    running[a:b, :, : c + 1] = pred[a:b, :, : c + 1]
                    running[a:b, :, c + 1 :] = observed[a:b, :, c + 1 :]
                    yield Progress("directions", fraction, message)
                yield Progress("directions", fraction,
                               f"channel {c + 1}/{C}, direction {k}/{n_dir}",
                               _in_version_layout(running, position))
                del running
        prob_sum += channel_prob
        spread[..., c] = average.spread()[..., 0]
    return pred, prob_sum / C, spread


def _iter_centred_source(versions, c, rows, record):
    """Colour channel ``c`` of every version stacked as (H, W, n) float64,
    centred on its per-version means, in chunks of ``rows`` rows with
    ``record`` yielded between them; returns (source, means, variances, the
    variances 1 where 0). np.mean / np.var's two passes; the sums go by row
    sums, so that any chunking gives the same bits."""
    H, W = versions[0].shape[:2]
    n = len(versions)
    chunks = row_blocks(H, rows)
    source = np.empty((H, W, n))
    row_sums = np.empty((H, n))
    for a, b in chunks:
        for k, v in enumerate(versions):
            source[a:b, :, k] = v[a:b, :, c]
        row_sums[a:b] = source[a:b].sum(axis=1)
        yield record
    means = row_sums.sum(axis=0) / (H * W)
    for a, b in chunks:
        source[a:b] -= means
        row_sums[a:b] = source[a:b].sum(axis=1)
        yield record
    residual = row_sums.sum(axis=0) / (H * W)  # the centred mean, ~0: np.var subtracts it too
    for a, b in chunks:
        row_sums[a:b] = ((source[a:b] - residual) ** 2).sum(axis=1)
        yield record
    var = row_sums.sum(axis=0) / (H * W)
    return source, means, np.where(var > 0, var, 1.0)


@documents_job(iter_restore_multichannel)
@shared_parameters(_PARAMETERS)
def restore_multichannel(stack, *, axis=0, kappa=DEFAULT_KAPPA, reference="auto",
                         neighbourhood=1, forgetting=0.9995, directions="all", keep_edges=True,
                         reference_prediction=True, channel_axis=-1, return_result=False):
    """Restore one scene from several registered degraded versions.

    Section 14.6, docs/restoration.md: the reference version is modelled by
    the adaptive 2.5D CAR model whose regression vector holds the causal
    neighbours (``neighbourhood``) in all versions and the other versions'
    pixels at ``r`` (14.52); the one-step conditional means of the four scan
    directions are averaged, and a pixel takes its prediction where the
    prediction probability exceeds ``kappa`` (14.50), else keeps its
    observed value. ``restore_multichannel(stack, ...)`` is
    ``drain(iter_restore_multichannel(stack, ...))``.

    {parameters}

    Returns
    -------
    restored : MultichannelRestoration or RestorationResult
        The NamedTuple ``(restored, probability)``: the restored reference
        version in the layout of one version ((H, W) grey, or with the
        colour axis where the stack has it), and the (H, W)
        prediction-probability image in [0, 1] ((14.23)-(14.25),
        docs/model.md; see :class:`RestorationResult`). With
        ``return_result``, the :class:`RestorationResult`.

    Raises
    ------
    ValueError
        If the stack is not 3-D or 4-D, holds fewer than two versions or
        versions of different shapes, has NaN or infinite values, a constant
        reference, ``axis`` or ``channel_axis`` out of range (or equal), or
        an option out of range (``kappa``, ``reference``, ``forgetting``,
        ``directions``).
    TypeError
        If ``axis``, ``channel_axis`` or ``kappa`` has the wrong type, or
        the stack is not numeric.

    See Also
    --------
    iter_restore_multichannel : The same, with progress and previews.
    restore : A single image.

    Examples
    --------
    >>> from car_napari.restoration import restore_multichannel
    >>> rng = np.random.default_rng(0)
    >>> scene = np.add.outer(np.linspace(0, 1, 32), np.linspace(0, 1, 32)) / 2
    >>> stack = scene + rng.normal(0, 0.05, (3, 32, 32))
    >>> restored, probability = restore_multichannel(stack)
    >>> restored.shape, bool(probability.min() >= 0 and probability.max() <= 1)
    ((32, 32), True)
    """
    return drain(iter_restore_multichannel(
        stack, axis=axis, kappa=kappa, reference=reference, neighbourhood=neighbourhood,
        forgetting=forgetting, directions=directions, keep_edges=keep_edges,
        reference_prediction=reference_prediction, channel_axis=channel_axis,
        return_result=return_result))
