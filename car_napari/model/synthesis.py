"""Synthesis from the model equation and the stability test (synthesis,
docs/model.md)."""

from __future__ import annotations

import math

import numpy as np

from .._docstrings import raises_as, shared_parameters, shared_sections
from .._progress import Progress, drain, row_blocks
from .._validation import check_memory, check_real, check_seed, output_shape
from ._kernels import synthesize_field
from .blocks import row_ranges
from .directions import unscan_view
from .fitted import check_model

__all__ = ["burn_in", "iter_synthesize", "synthesize", "spectral_radius"]

# rows of the (enlarged) lattice per kernel call: about this many multiply-adds
# (~0.1-0.2 s of one core)
_CHUNK_FLOPS = 1e8
# cost of a drawn noise value and of an output value (the crop and the mean),
# in multiply-adds of the kernel: for the progress fractions (measured)
_NOISE_COST, _FINISH_COST = 24.0, 6.0

_FREQUENCIES = 256
_MARGIN_TOLERANCE = 1e-4
_MAX_MARGIN = 1024  # four times the default's longest: beyond it only costs time
_RADIUS_CACHE = {}  # (gamma, offsets) bytes -> spectral radius; small and bounded


def cached_radius(model):
    """spectral_radius, remembered for repeated synthesis from one model
    (it costs more than a 512x512 field); keyed by the numbers it uses."""
    key = (np.ascontiguousarray(model.gamma).tobytes(), model.gamma.shape,
           np.ascontiguousarray(model.offsets).tobytes())
    radius = _RADIUS_CACHE.get(key)
    if radius is None:
        if len(_RADIUS_CACHE) > 256:
            _RADIUS_CACHE.clear()
        radius = _RADIUS_CACHE[key] = spectral_radius(model)
    return radius


def burn_in(radius, tolerance=_MARGIN_TOLERANCE):
    """The default burn-in margin of a model of spectral ``radius``.

    The field starts from zeros; its transient decays like
    ``radius ** rows`` (:func:`spectral_radius` bounds the decay of every
    frequency of the row-to-row and the in-row recursions), so the margin
    is the rows after which that is below ``tolerance``, between 16 and 256.

    Parameters
    ----------
    radius : float
        The model's spectral radius (below 1).
    tolerance : float, optional
        The transient's amplitude left at the output's edge, relative to
        the stationary field's (1e-4 by default: a variance share of 1e-8).

    Returns
    -------
    int
        The margin in pixels.

    Examples
    --------
    >>> burn_in(0.5), burn_in(0.9), burn_in(0.9, 1e-2), burn_in(0.999)
    (16, 88, 44, 256)
    """
    margin = math.ceil(math.log(tolerance) / math.log(max(radius, 1e-3)))
    return int(min(max(margin, 16), 256))


def innovation_factor(sigma):
    """The lower Cholesky factor of a (d, d) innovation covariance, by which a
    synthesis mixes its white noise.

    A covariance that is only semi-definite (linearly dependent channels, say
    a grey texture stored as RGB, rounded to float32) has no factor; it gets
    the smallest jitter of 1e-12, 1e-9 or 1e-6 times its mean variance that
    gives one. A positive definite one is factored as it is.

    Parameters
    ----------
    sigma : (d, d) ndarray
        A symmetric positive semi-definite covariance.

    Returns
    -------
    (d, d) ndarray
        Lower triangular ``L`` with ``L @ L.T`` equal to ``sigma`` (up to the
        jitter).

    Raises
    ------
    ValueError
        If ``sigma`` is not positive semi-definite (or not finite).

    Examples
    --------
    >>> import numpy as np
    >>> innovation_factor(np.array([[4.0, 0.0], [0.0, 1.0]])).tolist()
    [[2.0, 0.0], [0.0, 1.0]]
    >>> bool(np.isfinite(innovation_factor(np.ones((3, 3)))).all())  # rank 1
    True
    """
    sym = 0.5 * (sigma + sigma.T)
    d = sym.shape[0]
    try:
        return np.linalg.cholesky(sym + 1e-300 * np.eye(d))
    except np.linalg.LinAlgError:
        pass
    scale = float(np.trace(sym)) / d
    if np.isfinite(scale) and scale > 0:
        for jitter in (1e-12, 1e-9, 1e-6):
            try:
                return np.linalg.cholesky(sym + jitter * scale * np.eye(d))
            except np.linalg.LinAlgError:
                continue
    raise ValueError(
        "the model's innovation covariance (sigma) is not positive semi-definite: "
        "refit the model."
    )


def _companion_radius(coeffs, lead=None):
    """Spectral radius of the VAR companion of ``y_t = sum_k C_k y_{t-k}``.

    ``coeffs`` is a list of (d, d) complex matrices C_1..C_K; with ``lead``,
    the recursion is ``lead y_t = sum_k C_k y_{t-k}``.
    """
    K = len(coeffs)
    if K == 0:
        return 0.0
    d = coeffs[0].shape[0]
    if lead is not None:
        coeffs = [np.linalg.solve(lead, c) for c in coeffs]
    comp = np.zeros((K * d, K * d), dtype=complex)
    comp[:d, :] = np.hstack(coeffs)
    comp[d:, :-d] = np.eye((K - 1) * d)
    return float(np.max(np.abs(np.linalg.eigvals(comp))))


def spectral_radius(model):
    """Stability margin of a CAR model's causal filter; stable when below 1.

    The raster-causal (non-symmetric half-plane) filter
    ``A(w1, w2) = I - sum_s A_s w1^di w2^dj`` is stable when (i) the in-row
    recursion ``A(0, w2)`` has all its zeros outside the unit disc and (ii)
    for every ``|w2| = 1`` the row-to-row recursion in ``w1`` has too
    (Ekstrom and Woods, 1976). Both become spectral radii of companion
    matrices; (ii) is checked on a grid of frequencies.

    Parameters
    ----------
    model : CARModel
        A model from :func:`~car_napari.model.fit_car`.

    Returns
    -------
    float
        The largest radius found (``inf`` when the in-row filter is singular
        at a frequency); below 1 means stable.

    Raises
    ------
    TypeError
        If ``model`` is not a CARModel.
    ValueError
        If its parameters are inconsistent or not finite, or its offsets
        reach too far (see :func:`~car_napari.model.fitted.check_model`).

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import fit_car
    >>> model = fit_car(np.random.default_rng(0).random((32, 32)), 2)
    >>> bool(spectral_radius(model) < 1)
    True
    """
    check_model(model)
    A = model.A
    di, dj = model.offsets[:, 0], model.offsets[:, 1]
    d = model.n_channels
    row = [np.zeros((d, d), complex) for _ in range(int(dj[di == 0].max(initial=0)))]
    for a, i, j in zip(A, di, dj, strict=True):
        if i == 0:
            row[j - 1] = row[j - 1] + a
    radius = _companion_radius(row)
    K = int(di.max())
    frequencies = np.linspace(0.0, 2 * np.pi, _FREQUENCIES, endpoint=False)
    if row:
        # The row-to-row recursion resonates where the in-row filter A(0, w2)
        # is nearly singular on |w2| = 1, between grid points maybe: add the
        # arguments of its zeros, 1 / (companion eigenvalues).
        comp = np.zeros((len(row) * d, len(row) * d), dtype=complex)
        comp[:d, :] = np.hstack(row)
        comp[d:, :-d] = np.eye((len(row) - 1) * d)
        frequencies = np.r_[frequencies, -np.angle(np.linalg.eigvals(comp))]
    # every frequency at once: the same sums, in the same order, as one
    # frequency at a time (LAPACK factors each matrix of a stack on its own)
    n_freq = len(frequencies)
    phases = np.exp((1j * frequencies[:, None]) * dj[None, :])  # (F, eta)
    lead = np.broadcast_to(np.eye(d, dtype=complex), (n_freq, d, d)).copy()
    coeffs = np.zeros((n_freq, K, d, d), complex)
    for s, (a, i) in enumerate(zip(A, di, strict=True)):
        term = a[None] * phases[:, s, None, None]
        if i == 0:
            lead -= term
        else:
            coeffs[:, i - 1] = coeffs[:, i - 1] + term
    if np.any(np.abs(np.linalg.det(lead)) < 1e-12):
        return math.inf
    if K == 0:
        return radius
    solved = np.linalg.solve(lead[:, None], coeffs)  # (F, K, d, d): lead^-1 C_k
    comp = np.zeros((n_freq, K * d, K * d), dtype=complex)
    comp[:, :d, :] = solved.transpose(0, 2, 1, 3).reshape(n_freq, d, K * d)
    comp[:, d:, :-d] = np.eye((K - 1) * d)
    return max(radius, float(np.max(np.abs(np.linalg.eigvals(comp)))))


# the Parameters of synthesize and iter_synthesize, written once
_SYNTHESIZE_PARAMETERS = """
model : CARModel
    A model from :func:`~car_napari.model.fit_car`.
shape : tuple of 2 ints
    (height, width) of the output.
seed : int, numpy Generator or None, optional
    Random seed; the same seed gives the same texture.
margin : int, optional
    Burn-in margin in pixels on the top, left and right, 0 to 1024; by
    default long enough for the model's transient to decay to 1e-4 (16
    to 256).
"""


@shared_parameters(_SYNTHESIZE_PARAMETERS)
def synthesize(model, shape, *, seed=None, margin=None):
    """Generate a texture from a fitted CAR model (synthesis, docs/model.md).

    The field is generated directly from the model equation in scan order,
    ``Y_r = gamma X_r + Sigma^{1/2} w_r`` with white Gaussian ``w_r``, on a
    lattice enlarged by a burn-in margin that is cropped away; then the mean
    is added. No Monte Carlo iterations are needed.

    {parameters}

    Returns
    -------
    (H, W) or (H, W, d) ndarray of float64
        Single-channel models give a 2-D image.

    Raises
    ------
    ValueError
        If the model is unstable (its field would grow without bound) or its
        parameters are inconsistent or not finite, or ``shape`` is not two
        positive ints.
    TypeError
        If ``model`` is not a CARModel.

    See Also
    --------
    iter_synthesize : The same as a job, in chunks of rows.

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari.model import fit_car
    >>> model = fit_car(np.random.default_rng(0).random((32, 32, 3)), 1)
    >>> synthesize(model, (20, 30), seed=0).shape
    (20, 30, 3)
    """
    return drain(iter_synthesize(model, shape, seed=seed, margin=margin))


@shared_sections(parameters=_SYNTHESIZE_PARAMETERS,
                 raises=raises_as("synthesize", "ValueError", "TypeError"))
def iter_synthesize(model, shape, *, seed=None, margin=None, chunk_rows=None):
    """Generate a texture from a fitted CAR model, as a job: Progress, then the texture.

    The generator form of :func:`synthesize`, with the same parameters and,
    bit for bit, the same result: the field is generated in chunks of rows
    (one ``nogil`` kernel call each, about 0.1-0.2 s of work) with a yield
    between them.

    {parameters}
    chunk_rows : int, optional
        Lattice rows per kernel call (default: about 0.1-0.2 s of work).

    Returns
    -------
    (H, W) or (H, W, d) ndarray of float64
        What :func:`synthesize` returns.

    Yields
    ------
    Progress
        Stage ``"synthesis"`` after each block of noise draws (``"noise
        512/4256"``), each chunk of the field (``"rows 512/4256"``: rows of the
        lattice, burn-in margin included) and each block of the output
        (``"output rows 512/4000"``); fractions in proportion to the measured
        cost of each part. The output records carry a preview: the output
        array filling in (rows not yet done are 0; it is the array returned,
        do not modify it).

    {raises}

    Examples
    --------
    >>> import numpy as np
    >>> from car_napari._progress import drain
    >>> from car_napari.model import fit_car
    >>> model = fit_car(np.random.default_rng(0).random((32, 32)), 1)
    >>> records = []
    >>> texture = drain(iter_synthesize(model, (40, 30), seed=0, chunk_rows=20),
    ...                 records.append)
    >>> records[-1].fraction, bool(np.array_equal(texture, synthesize(model, (40, 30), seed=0)))
    (1.0, True)
    """
    check_model(model)
    h, w = output_shape(shape)
    rng = check_seed(seed)
    if chunk_rows is not None:
        chunk_rows = check_real(chunk_rows, "chunk_rows", low=1, integer=True)
    d = model.n_channels
    check_memory(8 * d * 3 * h * w, f"shape {(h, w)}")  # the field, its noise, the output
    radius = cached_radius(model)
    if not radius < 1.0:
        raise ValueError(
            f"the model is unstable (spectral radius {radius:.4g} >= 1): its field would "
            "grow without bound. Fit it to a more stationary texture, use a lower order, "
            "or shrink gamma."
        )
    if margin is None:
        margin = burn_in(radius)
    else:  # a negative margin would crop into the output: (4, 0) for margin=-5
        margin = check_real(margin, "margin (burn-in pixels)", low=0, high=_MAX_MARGIN,
                            integer=True)
    hs, ws = (w, h) if model.direction in ("right", "left") else (h, w)
    reach = int(np.abs(model.offsets).max())
    top, side = margin + reach, margin + reach
    gamma = np.ascontiguousarray(model.gamma)
    noise = np.empty((hs + top, ws + 2 * side, d))
    n_rows, n_cols = noise.shape[:2]
    # the shares of the work: the draws, the field, the crop (measured costs)
    work = np.array([_NOISE_COST * noise.size, n_rows * n_cols * (gamma.size + d * d + 8),
                     _FINISH_COST * h * w * d], float)
    edges = (np.concatenate([[0.0], np.cumsum(work)]) / work.sum()).tolist()
    # the draws by blocks of rows: the same stream, in the same order, as one call
    for start, stop in row_ranges(n_rows, n_cols * d):
        rng.standard_normal(out=noise[start:stop])  # (no temporary: the same draws)
        yield Progress("synthesis", edges[1] * stop / n_rows, f"noise {stop}/{n_rows}")
    taps = model.context.taps
    chol = innovation_factor(model.sigma)
    scale = math.sqrt(float(np.trace(model.sigma)))
    tap_di, tap_dj, tap_ch = taps[:, 0].copy(), taps[:, 1].copy(), taps[:, 2].copy()
    limit = 1e8 * max(scale, 1e-300) / max(1.0 - radius, 1e-6)
    if chunk_rows is None:
        chunk_rows = _CHUNK_FLOPS // (n_cols * (gamma.size + d * d + 8))
    for start, stop in row_blocks(n_rows, chunk_rows):
        if not synthesize_field(gamma, chol, noise, tap_di, tap_dj, tap_ch, limit, start,
                                stop):
            raise ValueError(
                "the model is numerically unstable: the synthesised field exploded. "
                "Use a lower order or a more stationary texture."
            )
        fraction = edges[1] + (edges[2] - edges[1]) * stop / n_rows
        yield Progress("synthesis", fraction, f"rows {stop}/{n_rows}")
    # the crop, in the image's geometry, plus the mean: by blocks of output rows
    image = unscan_view(noise[top:, side : side + ws], model.direction)
    out = np.zeros((h, w, d))
    shown = out[..., 0] if d == 1 else out
    for start, stop in row_ranges(h, w * d):
        np.add(image[start:stop], model.mean, out=out[start:stop])  # (no temporary)
        fraction = edges[2] + (1.0 - edges[2]) * stop / h
        yield Progress("synthesis", fraction, f"output rows {stop}/{h}", shown)
    return shown
