"""Motion between the frames of a clip (the 3.5D model's temporal context,
docs/inpainting.md).

:func:`estimate_motion` estimates a dense displacement field (optical flow)
from a frame to another one: coarse-to-fine Lucas-Kanade with warping, on
the grey frames (the channel mean), regularised so that a flat region keeps
the motion of its surroundings, and weighted so that damaged pixels (a mask)
do not steer it. :func:`warp_frame` moves a frame by such a field, and
:func:`compensate_motion` gives every frame of a clip its two neighbours
warped onto it: moving content then agrees with them, a blotch does not.

The flow follows scikit-image's convention (``skimage.registration``): a
``(2, H, W)`` array ``v`` of row and column displacements such that
``moving[r + v[0], c + v[1]]`` matches ``reference[r, c]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._docstrings import documents_job, shared_parameters
from .._progress import Progress, drain, mapped
from .._validation import as_channel_last_float, check_mask, check_real
from ._layout import read_layout

__all__ = ["compensate_motion", "estimate_motion", "iter_compensate_motion",
           "iter_estimate_motion", "warp_frame"]

# The flow is estimated on a pyramid of 2x2 block means, from the coarsest
# level (its short side at least MIN_LEVEL_SIZE pixels) down to the finest
# level of at most FLOW_PIXELS pixels (half resolution or coarser: the
# motion of film is smooth at that scale, and it is four times cheaper), and
# interpolated (bilinear) to the frame. Chosen on the tuning clips of
# benchmarks/bench_clip.py and the archival sample clip (warped-neighbour
# residual and blotch-test false alarms), never on the report clips.
FLOW_PIXELS = 1 << 17
MIN_LEVEL_SIZE = 24
RADIUS = 4  # the Lucas-Kanade window is (2 * RADIUS + 1) pixels square, at every level
ITERATIONS = 3  # warps per level
REGULARISATION = 1e-2  # Tikhonov term, relative to the mean gradient energy of the level
ROBUST = 0.15  # scale of the Cauchy weights of the residuals (frames normalised to unit variance)


def _grey(frame):
    """The channel mean of an (H, W, C) float frame, as float32: scaled by a
    power of two where its values are huge (the flow normalises each frame
    to unit variance anyway, but 1e120 is inf in float32 and 1e20 squared
    too, which made the flow NaN)."""
    grey = frame.mean(axis=2, dtype=np.float64)
    top = float(np.max(np.abs(grey)))
    if top > _HUGE:
        grey = grey * 2.0 ** -math.frexp(top)[1]
    return grey.astype(np.float32)


_HUGE = 2.0**40  # a float32 frame's squares stay finite (< 2**128) below it


def _normalised(grey, weight):
    """Zero mean, unit standard deviation over the weighted pixels (global
    flicker and exposure do not count as motion)."""
    w = weight if weight is not None else np.ones_like(grey)
    total = float(w.sum())
    if total <= 0:
        w, total = np.ones_like(grey), float(grey.size)
    mean = float((grey * w).sum() / total)
    std = float(np.sqrt(((grey - mean) ** 2 * w).sum() / total)) + 1e-6
    return (grey - mean) / std


def _down(image):
    """2x2 block means (an odd last row or column is repeated)."""
    H, W = image.shape
    if H % 2 or W % 2:
        image = np.pad(image, ((0, H % 2), (0, W % 2)), mode="edge")
    return 0.25 * (image[0::2, 0::2] + image[1::2, 0::2] + image[0::2, 1::2]
                   + image[1::2, 1::2])


@njit(cache=True, nogil=True)
def _resample_kernel(field, out):
    """Bilinear samples of the (K, h, w) ``field`` at the pixel centres of
    the (K, H, W) ``out`` grid of the same extent (edges repeated)."""
    K, H, W = out.shape
    h, w = field.shape[1], field.shape[2]
    for i in range(H):
        y = min(max((i + 0.5) * h / H - 0.5, 0.0), h - 1.0)
        a0 = min(int(y), h - 2) if h > 1 else 0
        a1 = min(a0 + 1, h - 1)
        fy = y - a0
        for j in range(W):
            x = min(max((j + 0.5) * w / W - 0.5, 0.0), w - 1.0)
            b0 = min(int(x), w - 2) if w > 1 else 0
            b1 = min(b0 + 1, w - 1)
            fx = x - b0
            for k in range(K):
                out[k, i, j] = ((field[k, a0, b0] * (1.0 - fx) + field[k, a0, b1] * fx)
                                * (1.0 - fy)
                                + (field[k, a1, b0] * (1.0 - fx) + field[k, a1, b1] * fx)
                                * fy)


def _resample(field, shape):
    """A (K, h, w) field sampled bilinearly at the centres of an (H, W)
    grid covering the same extent (pixel centres aligned, edges repeated)."""
    if field.shape[-2:] == tuple(shape):
        return field.copy()
    out = np.empty((field.shape[0],) + tuple(shape), field.dtype)
    _resample_kernel(np.ascontiguousarray(field), out)
    return out


@njit(cache=True, nogil=True)
def _sample(image, y, x, c):
    """Bilinear value of channel ``c`` of an (H, W, C) image at (y, x), the
    position clamped to the frame (edges repeated)."""
    H, W = image.shape[0], image.shape[1]
    y = min(max(y, 0.0), H - 1.0)
    x = min(max(x, 0.0), W - 1.0)
    i0 = min(int(y), H - 2) if H > 1 else 0
    j0 = min(int(x), W - 2) if W > 1 else 0
    i1 = min(i0 + 1, H - 1)
    j1 = min(j0 + 1, W - 1)
    fy = y - i0
    fx = x - j0
    top = image[i0, j0, c] * (1.0 - fx) + image[i0, j1, c] * fx
    bottom = image[i1, j0, c] * (1.0 - fx) + image[i1, j1, c] * fx
    return top * (1.0 - fy) + bottom * fy


@njit(cache=True, nogil=True)
def _warp_kernel(image, flow, out):
    """``out[r, c] = image[r + v[0], c + v[1]]`` (bilinear, edges repeated),
    ``v`` the (2, h, w) ``flow`` sampled bilinearly at the centre of pixel
    (r, c) of the (H, W) output (its grid covers the same extent; ``h, w =
    H, W`` is the plain warp) and scaled to output pixels."""
    H, W, C = out.shape
    h, w = flow.shape[1], flow.shape[2]
    sy = h / H
    sx = w / W
    for i in range(H):
        y = min(max((i + 0.5) * sy - 0.5, 0.0), h - 1.0)
        a0 = min(int(y), h - 2) if h > 1 else 0
        a1 = min(a0 + 1, h - 1)
        fy = y - a0
        for j in range(W):
            x = min(max((j + 0.5) * sx - 0.5, 0.0), w - 1.0)
            b0 = min(int(x), w - 2) if w > 1 else 0
            b1 = min(b0 + 1, w - 1)
            fx = x - b0
            dy = ((flow[0, a0, b0] * (1.0 - fx) + flow[0, a0, b1] * fx) * (1.0 - fy)
                  + (flow[0, a1, b0] * (1.0 - fx) + flow[0, a1, b1] * fx) * fy)
            dx = ((flow[1, a0, b0] * (1.0 - fx) + flow[1, a0, b1] * fx) * (1.0 - fy)
                  + (flow[1, a1, b0] * (1.0 - fx) + flow[1, a1, b1] * fx) * fy)
            for c in range(C):
                out[i, j, c] = _sample(image, i + dy / sy, j + dx / sx, c)


def _warp(image, flow):
    """An (H, W, C) float image warped by a (2, h, w) flow of a grid of the
    same extent (see :func:`_warp_kernel`), as float64."""
    image = np.ascontiguousarray(image, dtype=np.float64)
    out = np.empty(image.shape)
    _warp_kernel(image, np.ascontiguousarray(flow, dtype=np.float64), out)
    return out


def _warp_grey(image, flow):
    """``image[r + flow[0], c + flow[1]]`` bilinearly, edges repeated."""
    return _warp(image[..., None], flow)[..., 0].astype(np.float32)


@njit(cache=True, nogil=True)
def _median3x3_kernel(field, out):
    """The median of the 3x3 neighbourhood (edges repeated) of every pixel
    of each (h, w) plane of ``field``; a selection network (Paeth's median
    of 9), so the value is one of the nine, as any median filter's."""
    K, H, W = field.shape
    for k in range(K):
        for i in range(H):
            up, down = max(i - 1, 0), min(i + 1, H - 1)
            for j in range(W):
                left, right = max(j - 1, 0), min(j + 1, W - 1)
                p0, p1, p2 = field[k, up, left], field[k, up, j], field[k, up, right]
                p3, p4, p5 = field[k, i, left], field[k, i, j], field[k, i, right]
                p6, p7, p8 = field[k, down, left], field[k, down, j], field[k, down, right]
                p1, p2 = min(p1, p2), max(p1, p2)
                p4, p5 = min(p4, p5), max(p4, p5)
                p7, p8 = min(p7, p8), max(p7, p8)
                p0, p1 = min(p0, p1), max(p0, p1)
                p3, p4 = min(p3, p4), max(p3, p4)
                p6, p7 = min(p6, p7), max(p6, p7)
                p1, p2 = min(p1, p2), max(p1, p2)
                p4, p5 = min(p4, p5), max(p4, p5)
                p7, p8 = min(p7, p8), max(p7, p8)
                p0, p3 = min(p0, p3), max(p0, p3)
                p5, p8 = min(p5, p8), max(p5, p8)
                p4, p7 = min(p4, p7), max(p4, p7)
                p3, p6 = min(p3, p6), max(p3, p6)
                p1, p4 = min(p1, p4), max(p1, p4)
                p2, p5 = min(p2, p5), max(p2, p5)
                p4, p7 = min(p4, p7), max(p4, p7)
                p4, p2 = min(p4, p2), max(p4, p2)
                p6, p4 = min(p6, p4), max(p6, p4)
                p4, p2 = min(p4, p2), max(p4, p2)
                out[k, i, j] = p4


def _median3x3(field):
    """``ndimage.median_filter(field, size=(1, 3, 3), mode="nearest")`` of a
    (K, h, w) field (the same values), compiled: SciPy's generic rank filter
    took most of the flow's smoothing time."""
    out = np.empty_like(field)
    _median3x3_kernel(np.ascontiguousarray(field), out)
    return out


def _finest_level(H, W, flow_pixels):
    level = 1
    while H * W > flow_pixels * 4 ** level and min(H, W) >> level > MIN_LEVEL_SIZE:
        level += 1
    return level


def _iter_flow(reference, moving, weight, radius, iterations, regularisation, flow_pixels):
    """The flow of grey float32 frames; yields the warps done (one unit per
    warp at the finest level, a quarter per coarser level); returns the
    (2, h, w) float32 flow of the finest level, in its pixels (a grid of the
    frame's extent: :func:`_warp` and :func:`_full_flow` take it)."""
    from scipy import ndimage

    H, W = reference.shape
    finest = _finest_level(H, W, flow_pixels)
    ref = _normalised(reference, weight)
    mov = _normalised(moving, None)
    w = np.ones_like(ref) if weight is None else weight.astype(np.float32)
    refs, movs, weights = [ref], [mov], [w]
    while min(refs[-1].shape) >= 2 * MIN_LEVEL_SIZE:
        refs.append(_down(refs[-1]))
        movs.append(_down(movs[-1]))
        weights.append(_down(weights[-1]))
    finest = min(finest, len(refs) - 1)
    size = 2 * int(radius) + 1
    flow = None
    for level in range(len(refs) - 1, finest - 1, -1):
        R, M, Wt = refs[level], movs[level], weights[level]
        h, w_ = R.shape
        if flow is None:
            flow = np.zeros((2, h, w_), np.float32)
        else:
            flow = 2.0 * _resample(flow, (h, w_))
        gy, gx = np.gradient(R)
        energy = float((gy * gy + gx * gx).mean()) + 1e-12
        lam = np.float32(regularisation * energy)
        for _ in range(int(iterations)):
            warped = _warp_grey(M, flow)
            wy, wx = np.gradient(warped)
            Iy, Ix = 0.5 * (gy + wy), 0.5 * (gx + wx)
            It = warped - R
            # robust (Cauchy) weights: a blotch, a scratch or an occlusion,
            # where the frames disagree whatever the motion, barely counts
            Wr = Wt / (1.0 + (It * np.float32(1.0 / ROBUST)) ** 2) if ROBUST else Wt
            It *= Wr
            a11 = ndimage.uniform_filter(Wr * Iy * Iy, size) + lam
            a12 = ndimage.uniform_filter(Wr * Iy * Ix, size)
            a22 = ndimage.uniform_filter(Wr * Ix * Ix, size) + lam
            b1 = -ndimage.uniform_filter(Iy * It, size)
            b2 = -ndimage.uniform_filter(Ix * It, size)
            det = a11 * a22 - a12 * a12
            flow[0] += (a22 * b1 - a12 * b2) / det
            flow[1] += (a11 * b2 - a12 * b1) / det
            if _ + 1 == iterations:  # outliers (an occlusion, a blotch) do not spread
                flow = _median3x3(flow)
            yield 0.25 ** (level - finest)
    return flow


def _full_flow(flow, shape):
    """A flow of a coarser grid (see :func:`_iter_flow`) at the frame's
    resolution, in its pixels."""
    H, W = shape
    scale = np.array([H / flow.shape[1], W / flow.shape[2]], np.float32)[:, None, None]
    return (_resample(flow, (H, W)) * scale).astype(np.float32)


def _flow_records(reference, moving, weight, radius, iterations, done, total, message):
    """:func:`_iter_flow` of two grey frames as a job: a ``"motion"`` record
    after every warp, its fraction ``done / total`` with the warps' work
    added to ``done``; returns ``(flow, done)``."""
    job = _iter_flow(reference, moving, weight, int(radius), int(iterations), REGULARISATION,
                     FLOW_PIXELS)

    def record(units):
        nonlocal done
        done += units
        return Progress("motion", min(done / total, 1.0), message)

    return (yield from mapped(job, record)), done


def _work_units(H, W, iterations, flow_pixels):
    """The warps :func:`_iter_flow` yields for an (H, W) frame, in its units."""
    levels = 0
    h, w = H, W
    while min(h, w) >= 2 * MIN_LEVEL_SIZE:
        h, w = (h + 1) // 2, (w + 1) // 2
        levels += 1
    finest = min(_finest_level(H, W, flow_pixels), levels)
    return iterations * sum(0.25 ** (k - finest) for k in range(finest, levels + 1))


# the largest window radius (pixels) and warps per level an option may ask:
# far beyond any use, and each costs time in proportion
_MAX_RADIUS = 256
_MAX_ITERATIONS = 100


def _check_options(radius, iterations):
    check_real(radius, "radius (pixels)", low=1, high=_MAX_RADIUS, integer=True)
    check_real(iterations, "iterations", low=1, high=_MAX_ITERATIONS, integer=True)


def _as_frame(image, channel_axis, name):
    if channel_axis is not None:
        check_real(channel_axis, "channel_axis", integer=True)
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and channel_axis is None):
        raise ValueError(f"{name} must be a frame, (H, W) or (H, W, C) with channel_axis; "
                         f"got shape {arr.shape}.")
    frame = as_channel_last_float(arr, channel_axis=channel_axis if arr.ndim == 3 else None,
                                  name=name, copy=False)
    if not np.all(np.isfinite(frame)):
        raise ValueError(f"{name} contains NaN or infinite values; replace them first.")
    return frame


def _as_weight(mask, shape):
    if mask is None:
        return None
    m = check_mask(mask, "mask", meaning="True where the reference frame is damaged")
    if m.shape != shape:
        raise ValueError(f"mask has shape {m.shape}; it must be the frame's (H, W) = {shape}, "
                         "True where the reference frame is damaged.")
    return (m == 0).astype(np.float32)


# the Parameters of estimate_motion and iter_estimate_motion, written once
_ESTIMATE_MOTION_PARAMETERS = """
    reference : ndarray
        The frame the motion is measured on: (H, W) grey or (H, W, C)
        colour (integers are scaled to [0, 1]).
    moving : ndarray
        The other frame, of the same size.
    mask : (H, W) array_like of bool, optional
        True where ``reference`` is damaged (ignored by the estimate).
    channel_axis : int or None, optional
        The colour axis of 3-D frames (default -1); None for grey frames.
    radius : int, optional
        Half size of the window (pixels, at every pyramid level).
    iterations : int, optional
        Warps per pyramid level.
"""


def iter_estimate_motion(reference, moving, *, mask=None, channel_axis=-1, radius=RADIUS,
                         iterations=ITERATIONS):
    """Estimate the motion from one frame to another, as a job.

    {plain form}

    Yields
    ------
    Progress
        Stage ``"motion"`` after every warp of every level.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> frame = np.random.default_rng(0).random((64, 64))
    >>> records = []
    >>> flow = drain(iter_estimate_motion(frame, frame), records.append)
    >>> flow.shape, records[-1].stage, records[-1].fraction
    ((2, 64, 64), 'motion', 1.0)
    """
    _check_options(radius, iterations)
    ref = _as_frame(reference, channel_axis, "reference")
    mov = _as_frame(moving, channel_axis, "moving")
    if ref.shape[:2] != mov.shape[:2]:
        raise ValueError(f"the frames differ in size: reference {ref.shape[:2]}, moving "
                         f"{mov.shape[:2]}; pass two frames of one clip.")
    H, W = ref.shape[:2]
    weight = _as_weight(mask, (H, W))
    total = _work_units(H, W, int(iterations), FLOW_PIXELS)
    flow, _ = yield from _flow_records(_grey(ref), _grey(mov), weight, radius, iterations,
                                       0.0, total, "estimating motion")
    return _full_flow(flow, (H, W))


@documents_job(iter_estimate_motion)
@shared_parameters(_ESTIMATE_MOTION_PARAMETERS)
def estimate_motion(reference, moving, *, mask=None, channel_axis=-1, radius=RADIUS,
                    iterations=ITERATIONS):
    """Estimate the motion (dense optical flow) from one frame to another.

    Coarse-to-fine Lucas-Kanade on the grey frames (the channel mean, each
    normalised to zero mean and unit variance so that flicker is not
    motion): on a pyramid of 2x2 block means, from a level about 24 pixels
    high down to half resolution (or coarser, so that the finest level has
    at most :data:`FLOW_PIXELS` pixels), ``iterations`` times per level the
    moving frame is warped by the current flow and the flow corrected by
    the least-squares solution of the linearised brightness constancy over a
    ``(2 radius + 1)``-pixel square window, plus a Tikhonov term (a flat
    window keeps the motion of the coarser level), then median-filtered
    (3x3). Damaged pixels of the reference (``mask``) carry no weight, so a
    blotch or a scratch takes the motion of its surroundings. The flow is
    interpolated bilinearly to the frame.

    {parameters}

    Returns
    -------
    (2, H, W) ndarray of float32
        Row and column displacements ``v`` such that
        ``moving[r + v[0], c + v[1]]`` matches ``reference[r, c]``
        (scikit-image's convention): :func:`warp_frame` ``(moving, v)``
        is the moving frame seen from the reference.

    Raises
    ------
    TypeError
        If a frame is not numeric.
    ValueError
        If the frames differ in size or are not frames, hold NaN or infinite
        values, the mask has another shape, or an option is out of range.

    See Also
    --------
    warp_frame : Move a frame by a flow.
    compensate_motion : Both neighbours of every frame of a clip, warped onto it.

    Examples
    --------
    >>> from scipy import ndimage
    >>> rng = np.random.default_rng(0)
    >>> frame = ndimage.gaussian_filter(rng.random((96, 96)), 2)
    >>> moved = np.roll(frame, 3, axis=1)  # the content moves 3 columns right
    >>> flow = estimate_motion(frame, moved)
    >>> [round(float(np.median(v)), 1) + 0.0 for v in flow]
    [0.0, 3.0]
    """
    return drain(iter_estimate_motion(reference, moving, mask=mask, channel_axis=channel_axis,
                                      radius=radius, iterations=iterations))


def warp_frame(frame, flow, *, channel_axis=-1):
    """Move a frame by a flow: ``out[r, c] = frame[r + flow[0], c + flow[1]]``.

    Bilinear interpolation; a position outside the frame takes the nearest
    edge pixel.

    Parameters
    ----------
    frame : ndarray
        (H, W) grey or (H, W, C) colour; integers are scaled to [0, 1].
    flow : (2, H, W) array_like of float
        Row and column displacements, as :func:`estimate_motion` returns.
    channel_axis : int or None, optional
        The colour axis of a 3-D frame (default -1); None for grey.

    Returns
    -------
    ndarray of float64
        The warped frame, in the frame's layout.

    Raises
    ------
    TypeError
        If the frame is not numeric.
    ValueError
        If the frame is not a frame or holds NaN or infinite values, or the
        flow is not (2, H, W) and finite.

    Examples
    --------
    >>> frame = np.arange(12.0).reshape(3, 4)
    >>> flow = np.zeros((2, 3, 4))
    >>> flow[1] = 1.0  # every pixel takes its right neighbour
    >>> warp_frame(frame, flow)
    array([[ 1.,  2.,  3.,  3.],
           [ 5.,  6.,  7.,  7.],
           [ 9., 10., 11., 11.]])
    """

    arr = np.asarray(frame)
    work = _as_frame(arr, channel_axis, "frame")
    H, W, C = work.shape
    v = np.asarray(flow, dtype=np.float64)
    if v.shape != (2, H, W) or not np.all(np.isfinite(v)):
        raise ValueError(f"flow must be a finite (2, H, W) = (2, {H}, {W}) array of row and "
                         f"column displacements; got shape {v.shape}.")
    out = _warp(work, v)
    if arr.ndim == 2:
        return out[..., 0]
    return np.moveaxis(out, -1, channel_axis)


# the Parameters of compensate_motion and iter_compensate_motion, written once
_COMPENSATE_MOTION_PARAMETERS = """
    clip : ndarray
        (T, H, W) grey or (T, H, W, C) colour, any numeric dtype (integers
        are scaled to [0, 1]), read by the rule of
        :func:`~car_napari.inpainting.inpaint`.
    mask : (H, W) or (T, H, W) array_like of bool, optional
        True where frames are damaged (ignored by the motion estimate).
    channel_axis : int or None, optional
        The colour axis (default -1); None forces grey.
    radius, iterations : int, optional
        As in :func:`estimate_motion`.
"""


def iter_compensate_motion(clip, *, mask=None, channel_axis=-1, radius=RADIUS,
                           iterations=ITERATIONS):
    """Both neighbours of every frame of a clip warped onto it, as a job.

    {plain form}

    Yields
    ------
    Progress
        Stage ``"motion"``, message ``"frame t/T"``, after every warp of
        every flow estimate; the fraction by the flows done.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> clip = np.random.default_rng(0).random((3, 48, 48))
    >>> records = []
    >>> previous, following = drain(iter_compensate_motion(clip), records.append)
    >>> previous.shape, records[-1].fraction
    ((3, 48, 48), 1.0)
    """
    _check_options(radius, iterations)
    arr = np.asarray(clip)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"clip has dtype {arr.dtype}; pass a numeric clip.")
    layout = read_layout(arr, channel_axis)
    frames = layout.clip
    T, H, W, C = frames.shape
    if layout.single or T < 2:
        raise ValueError(f"a clip of 2 frames or more is needed; got shape {arr.shape} "
                         f"({layout.reading}).")
    masks = None
    if mask is not None:
        m = check_mask(mask, "mask", meaning="True where the frames are damaged")
        if m.shape == (H, W):
            masks = np.broadcast_to(m, (T, H, W))
        elif m.shape == (T, H, W):
            masks = m
        else:
            raise ValueError(f"mask has shape {m.shape}; it must be ({H}, {W}) or "
                             f"({T}, {H}, {W}), True where the frames are damaged.")
    previous = np.empty((T, H, W, C))
    following = np.empty((T, H, W, C))
    per_flow = _work_units(H, W, int(iterations), FLOW_PIXELS)
    total = 2 * (T - 1) * per_flow
    done = 0.0

    def frame(t):
        f = as_channel_last_float(frames[t] if layout.colour else frames[t, ..., 0],
                                  channel_axis=-1 if layout.colour else None, name="clip",
                                  copy=False)
        if not np.all(np.isfinite(f)):
            raise ValueError("clip contains NaN or infinite values; replace them first.")
        return f

    current, after = None, frame(0)
    for t in range(T):
        before, current = current, after
        after = frame(t + 1) if t + 1 < T else None
        weight = None if masks is None else (np.asarray(masks[t]) == 0).astype(np.float32)
        grey = _grey(current)
        for other, out in ((before, previous), (after, following)):
            if other is None:
                out[t] = current
                continue
            flow, done = yield from _flow_records(grey, _grey(other), weight, radius,
                                                  iterations, done, total, f"frame {t + 1}/{T}")
            out[t] = _warp(other, flow)
    return layout.to_input(previous), layout.to_input(following)


@documents_job(iter_compensate_motion)
@shared_parameters(_COMPENSATE_MOTION_PARAMETERS)
def compensate_motion(clip, *, mask=None, channel_axis=-1, radius=RADIUS,
                      iterations=ITERATIONS):
    """Both neighbours of every frame of a clip, warped onto it.

    For frame ``t``, the motion to frames ``t - 1`` and ``t + 1`` is
    estimated (:func:`estimate_motion`, damaged pixels of frame ``t``
    ignored) and each neighbour warped by it (:func:`warp_frame`): moving
    content of the neighbours lands where it is in frame ``t``, so it agrees
    with frame ``t``, and a blotch of frame ``t`` disagrees with both. The
    first frame has no previous frame and the last no following one: there
    the frame itself is given.

    {parameters}

    Returns
    -------
    previous : ndarray of float64
        Like the clip: ``previous[t]`` is frame ``t - 1`` warped onto frame
        ``t`` (``previous[0]`` is frame 0).
    following : ndarray of float64
        ``following[t]`` is frame ``t + 1`` warped onto frame ``t`` (the last
        is the last frame).

    Raises
    ------
    TypeError
        If the clip is not numeric.
    ValueError
        If the clip is not a clip of 2 frames or more, holds NaN or
        infinite values, or the mask has another shape.

    See Also
    --------
    estimate_motion : The flow between two frames.
    warp_frame : Move a frame by a flow (e.g. the previous frame as restored).

    Examples
    --------
    >>> from scipy import ndimage
    >>> rng = np.random.default_rng(0)
    >>> scene = ndimage.gaussian_filter(rng.random((80, 120)), 2)
    >>> clip = np.stack([scene[:, 2 * t : 2 * t + 96] for t in range(3)])  # a pan
    >>> previous, following = compensate_motion(clip)
    >>> inner = (slice(8, -8), slice(8, -8))
    >>> still = np.abs(clip[1] - clip[0])[inner].mean()
    >>> moved = np.abs(clip[1] - previous[1])[inner].mean()
    >>> bool(moved < 0.1 * still)
    True
    """
    return drain(iter_compensate_motion(clip, mask=mask, channel_axis=channel_axis,
                                        radius=radius, iterations=iterations))
