"""The public face of single-image restoration: :func:`restore` and
:func:`iter_restore` run one job, :func:`_iter_job`, which takes an image in
memory through :mod:`._single` and a dask or zarr image through
:mod:`._tiled` (by tiles, the same result).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._docstrings import documents_job, shared_parameters
from .._progress import drain
from .._tiles import is_lazy
from .._validation import scale_exponent
from ._checks import check_noise_magnitude
from ._single import DEFAULT_WINDOW, iter_restoration, to_layout
from ._tiled import iter_restore_large

__all__ = ["iter_restore", "restore"]

# the Parameters of both forms of the job, written once
_PARAMETERS = """
    image : (H, W) or (H, W, C) array
        The degraded image; integers are scaled to [0, 1]. A dask or zarr
        array (larger than memory) is restored by tiles
        (:func:`~car_napari.restoration.restore_large`, windowed estimator):
        a dask image gives a lazy dask array, a zarr one a NumPy array.
    neighbourhood : int, (eta, 2) array or 'auto', optional
        Causal neighbourhood order (default 1: the pixels above and before)
        or offsets; 'auto' chooses the order by the decision rule (14.6) on
        the image. Order 2 gains 0.13 dB on the benchmark at a third more time.
    estimator : {'windowed', 'recursive'}, optional
        How the local model is estimated. 'windowed' (default): least
        squares over a ``window`` x ``window`` square around the pixel, as
        the chapter estimates local PSFs (14.46)-(14.47); the four
        neighbourhoods are the causal one mirrored up-left, up-right,
        down-left and down-right. 'recursive': the adaptive estimator of
        (14.26)-(14.32), section 14.2.1, docs/model.md (recursive,
        square-root, with ``forgetting``) along the four scan directions
        down, up, right and left. Same quality on the benchmark (26.26 vs
        26.21 dB at orders 1 and 2); 'windowed' is about six times faster,
        'recursive' is the chapter's adaptive model to the letter.
    window : int, optional
        Side in pixels of the windowed estimator's square (3 x 3 blocks of a
        third of it; default 48). 24 gains 0.1 dB at a quarter more time.
    forgetting : float in [0.5, 1], optional
        Forgetting factor of the recursive estimator ((14.26)-(14.32),
        docs/model.md).
    directions : 'all' or sequence of str, optional
        The neighbourhoods whose predictions are combined: for 'windowed' any
        of {'up-left', 'up-right', 'down-left', 'down-right'}; for
        'recursive' any of {'down', 'up', 'right', 'left'}.
    keep_edges : bool, optional
        Apply the edge rule: keep the observed value where the local
        prediction error exceeds what the noise explains (see
        :class:`RestorationResult`). (14.40) read literally (keep ``X_r`` when
        its error exceeds the mean error of its neighbours) keeps about 40 %
        of the pixels of a flat noisy region, so no denoising; we compare with
        the noise level instead and blend smoothly.
    kappa : float in [0, 1), optional
        Also keep observed pixels whose prediction probability is at most
        ``kappa`` (14.50); 0 (default) disables this.
    noise : float or (C,) array, optional
        Noise standard deviation (image units after scaling); default
        :func:`estimate_noise`.
    channel_axis : int or None, optional
        The colour axis of a 3-D image (default -1); None for a grey image.
        A 2-D image is always grey.
    return_result : bool, optional
        Return the :class:`RestorationResult` instead (prediction, prediction
        probability, edge weights; ``.restored(kappa)`` re-thresholds: the
        widget's choice).
"""


def iter_restore(image, *, neighbourhood=1, estimator="windowed", window=DEFAULT_WINDOW,
                 forgetting=0.995, directions="all", keep_edges=True, kappa=0.0, noise=None,
                 channel_axis=-1, return_result=False):
    """Restore a degraded image step by step, with progress and previews.

    It yields :class:`~car_napari.Progress` records as strips of rows (or,
    with ``estimator='recursive'``, scan directions) finish, whose previews
    show the restored image filling in. Closing the generator stops the
    work after the strips (or scans) in progress.

    {plain form}

    Yields
    ------
    progress : Progress
        Stage ``'start'``, then ``'reading'`` (large images), ``'centre'``,
        and for 'windowed' ``'moments'``, ``'models'``, ``'rows'`` (message
        like ``'rows 128/1024'``) and ``'noise'``, for 'recursive'
        ``'directions'``, then ``'edges'`` (the edge rule); a record at least
        every few tenths of a second of work (docs/restoration.md), the
        fraction proportional to the work done. Some records (about eight
        for 'windowed', one per direction but the last for 'recursive')
        carry a preview: the image restored so far (the prediction, before
        the edge rule; rows not yet restored show the observation), in the
        layout of ``image``.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> from car_napari.restoration import iter_restore
    >>> rng = np.random.default_rng(0)
    >>> noisy = rng.normal(0.5, 0.1, (64, 48))
    >>> records = []
    >>> restored = drain(iter_restore(noisy), on_progress=records.append)
    >>> restored.shape, records[-1].fraction <= 1.0
    ((64, 48), True)
    >>> [r.preview.shape for r in records if r.preview is not None][0]
    (64, 48)
    """
    return (yield from _iter_job(
        image, neighbourhood=neighbourhood, estimator=estimator, window=window,
        forgetting=forgetting, directions=directions, keep_edges=keep_edges, kappa=kappa,
        noise=noise, channel_axis=channel_axis, return_result=return_result, live=True))


@documents_job(iter_restore)
@shared_parameters(_PARAMETERS)
def restore(image, *, neighbourhood=1, estimator="windowed", window=DEFAULT_WINDOW,
            forgetting=0.995, directions="all", keep_edges=True, kappa=0.0, noise=None,
            channel_axis=-1, return_result=False):
    """Restore a degraded image by the conditional mean of a local CAR model.

    Section 14.5, docs/restoration.md: ``E{X_r | past} = gamma_hat Z_r``
    (14.44)-(14.45) from a 3DCAR model of the observed image valid around
    ``r``, averaged over four causal neighbourhoods (the four directions),
    with the edge rule (14.40). ``restore(image, ...)`` returns exactly
    ``drain(iter_restore(image, ...))`` (without computing the previews).

    {parameters}

    Returns
    -------
    restored : float64 ndarray or RestorationResult
        The restored image, in the shape and layout of ``image``; or, with
        ``return_result``, the :class:`RestorationResult` (channel-last).

    Raises
    ------
    ValueError
        If the image is empty, constant, has NaN or infinite values, the
        wrong number of dimensions or is too small for the neighbourhood, or
        an option is out of range (``kappa``, ``window``, ``forgetting``,
        ``directions``, ``estimator``, ``noise``).
    TypeError
        If the image or ``kappa`` is not numeric.

    See Also
    --------
    iter_restore : The same, with progress and previews.
    restore_multichannel : Several degraded versions of one scene.

    Examples
    --------
    >>> from car_napari.restoration import restore
    >>> rng = np.random.default_rng(0)
    >>> clean = np.add.outer(np.linspace(0, 1, 48), np.linspace(0, 1, 48)) / 2
    >>> noisy = clean + rng.normal(0, 0.05, clean.shape)
    >>> restored = restore(noisy)
    >>> restored.shape, restored.dtype
    ((48, 48), dtype('float64'))
    >>> bool(np.std(restored - clean) < 0.7 * np.std(noisy - clean))
    True
    """
    return drain(_iter_job(
        image, neighbourhood=neighbourhood, estimator=estimator, window=window,
        forgetting=forgetting, directions=directions, keep_edges=keep_edges, kappa=kappa,
        noise=noise, channel_axis=channel_axis, return_result=return_result, live=False))


def _iter_job(image, *, neighbourhood, estimator, window, forgetting, directions, keep_edges,
              kappa, noise, channel_axis, return_result, live):
    """The job of :func:`iter_restore` and :func:`restore`; ``live`` adds the
    previews (which ``restore``, where nobody sees them, skips).

    A dask or zarr image goes by tiles (:func:`iter_restore_large`, every
    option passed on: ``forgetting`` is checked as for an image in memory;
    only the recursive estimator, which tiles refuse, uses it). An image in
    memory goes through :func:`~car_napari.restoration._single.iter_restoration`;
    a float image of a spread beyond ``2**±32`` is restored scaled by a
    power of two (exact) and its results scaled back: the estimators'
    floors and caps (the directions' weights ``min(n / total, 1e30) ** 4``)
    are absolute, so that its magnitude would otherwise decide the result.
    Ordinary images take the unscaled path, bit for bit."""
    options = dict(neighbourhood=neighbourhood, estimator=estimator, window=window,
                   forgetting=forgetting, directions=directions, keep_edges=keep_edges,
                   kappa=kappa, channel_axis=channel_axis)
    if is_lazy(image):
        if return_result:
            raise ValueError("return_result needs the image in memory; a dask or zarr image "
                             "is restored by tiles into an array (restore_large).")
        return (yield from iter_restore_large(image, noise=noise, **options))
    exponent = scale_exponent(image)
    check_noise_magnitude(noise, exponent)
    if exponent:
        image = np.ldexp(np.asarray(image, np.float64), -exponent)
        if noise is not None:
            noise = np.ldexp(np.asarray(noise, np.float64), -exponent)
    result = yield from iter_restoration(image, noise=noise, live=live,
                                         probability=return_result, blend=not return_result,
                                         **options)
    if exponent:  # back to the image's units; probabilities and weights have none
        result = replace(result, observed=np.ldexp(result.observed, exponent),
                         prediction=np.ldexp(result.prediction, exponent),
                         noise=np.ldexp(result.noise, exponent))
    if return_result:
        return result
    return to_layout(result.restored(), np.ndim(image), channel_axis)
