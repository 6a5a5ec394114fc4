"""The spectral pyramid of the texture model: bands that share no frequency.

The Gaussian-Laplacian pyramid (``_pyramid.py``) smooths before it decimates
with a soft filter, so neighbouring bands hold the same frequencies: their
cross-spectra are large, and bands generated independently (as synthesis
generates them) lose them. On VisTex that loss, not the band models, is most
of the distance between the synthesis's autocorrelation and the input's:
collapsing bands that each have the exact spectrum of their band but
independent random phases is as far from the input as the CAR synthesis
(issue 34).

The spectral pyramid splits the frequencies instead. A level of size ``n``
gives the next of size ``ceil(n / 2)`` by keeping its lowest ``ceil(n / 2)``
cosine (DCT-II, half-sample symmetric borders) or Fourier (periodic) frequencies
per axis; ``band_k = G_k - expand(G_{k+1})`` then holds exactly the
frequencies the coarser level does not, and collapsing reconstructs the input
exactly. Synthesis projects every generated band-pass field onto its band's
frequencies (:func:`highpass`): a CAR field's spectrum covers every
frequency, and what it puts below the band would add to the coarser bands'.

Amplitudes: with orthonormal transforms a constant image of ``N`` pixels
and value ``c`` has a zero-frequency coefficient ``c sqrt(N)``; resampling
to ``M`` pixels keeps the values when the coefficients are scaled by
``sqrt(M / N)``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as sfft

from .._progress import Progress, drain

__all__ = ["collapse", "expand", "highpass", "iter_collapse", "iter_highpass", "iter_pyramid",
           "pyramid", "reduce"]


def _half(shape):
    return tuple((int(n) + 1) // 2 for n in shape)


def _fourier_resize(image, n_out, axis):
    """Periodic resampling of one axis to ``n_out`` samples by cropping or
    zero-padding its Fourier spectrum (the Nyquist term of an even length
    split or joined evenly, so real signals stay real); the amplitude is
    kept (the sum of the samples scales with the length)."""
    n_in = image.shape[axis]
    if n_in == n_out:
        return image.copy()
    spectrum = np.fft.fft(image, axis=axis)
    n = min(n_in, n_out)
    shape = list(image.shape)
    shape[axis] = n_out
    out = np.zeros(shape, complex)
    pos = (n + 1) // 2  # frequencies 0 .. pos - 1 and -(n - pos) .. -1
    neg = n - pos

    def take(arr, sl):
        index = [slice(None)] * arr.ndim
        index[axis] = sl
        return tuple(index)

    out[take(out, slice(0, pos))] = spectrum[take(spectrum, slice(0, pos))]
    if neg:
        out[take(out, slice(n_out - neg, n_out))] = spectrum[take(spectrum, slice(n_in - neg,
                                                                               n_in))]
    if n % 2 == 0:  # the Nyquist term of the shorter length
        nyq = n // 2
        if n_out > n_in:  # split between +nyq and -nyq
            half = spectrum[take(spectrum, slice(nyq, nyq + 1))] / 2
            out[take(out, slice(nyq, nyq + 1))] = half
            out[take(out, slice(n_out - nyq, n_out - nyq + 1))] = half
        else:  # join +nyq and -nyq of the longer length
            out[take(out, slice(nyq, nyq + 1))] = (
                spectrum[take(spectrum, slice(nyq, nyq + 1))]
                + spectrum[take(spectrum, slice(n_in - nyq, n_in - nyq + 1))])
    return np.real(np.fft.ifft(out, axis=axis)) * (n_out / n_in)


def reduce(image, *, wrap=False):
    """The next coarser level of a channel-last (h, w, d) image: its lowest
    ``ceil(h / 2) x ceil(w / 2)`` frequencies, at that size.

    Parameters
    ----------
    image : (h, w, d) ndarray
        The level.
    wrap : bool, optional
        Periodic borders (Fourier frequencies) instead of half-sample
        symmetric ones (cosine frequencies).

    Returns
    -------
    (ceil(h / 2), ceil(w / 2), d) ndarray
        The coarser level (same mean).
    """
    h2, w2 = _half(image.shape[:2])
    if wrap:
        return _fourier_resize(_fourier_resize(image, h2, 0), w2, 1)
    coeffs = sfft.dctn(image, axes=(0, 1), norm="ortho")
    scale = np.sqrt(h2 * w2 / (image.shape[0] * image.shape[1]))
    return scale * sfft.idctn(coeffs[:h2, :w2], axes=(0, 1), norm="ortho")


def _working(values, single):
    """``values`` as the transforms take them: float32 with ``single``."""
    return values.astype(np.float32, copy=False) if single else values


def expand(image, shape, *, wrap=False, single=False):
    """A coarse level at the finer ``shape`` (h, w): the same frequencies,
    none added (the inverse of :func:`reduce` on what it keeps).

    Parameters
    ----------
    image : (h2, w2, d) ndarray
        The coarse level, ``(h2, w2) == (ceil(h / 2), ceil(w / 2))``.
    shape : tuple of 2 ints
        The finer level's size.
    wrap : bool, optional
        Periodic borders, as in :func:`reduce`.
    single : bool, optional
        Cosine transforms in float32 (synthesis: a relative error of about
        1e-6 of the level's amplitude, two to three times faster).

    Returns
    -------
    (h, w, d) ndarray
    """
    h, w = int(shape[0]), int(shape[1])
    if wrap:
        return _fourier_resize(_fourier_resize(image, h, 0), w, 1)
    coeffs = np.zeros((h, w) + image.shape[2:], np.float32 if single else np.float64)
    coeffs[: image.shape[0], : image.shape[1]] = sfft.dctn(_working(image, single),
                                                           axes=(0, 1), norm="ortho")
    scale = math.sqrt(h * w / (image.shape[0] * image.shape[1]))  # (keeps float32 float32)
    up = sfft.idctn(coeffs, axes=(0, 1), norm="ortho")
    return np.multiply(up, scale, out=up)  # (scale * up, in place)


def highpass(band, *, wrap=False, single=False):
    """``band`` less its lowest ``ceil(h / 2) x ceil(w / 2)`` frequencies
    (those of the coarser levels): the projection onto a band's frequencies.

    Parameters
    ----------
    band : (h, w, d) ndarray
    wrap : bool, optional
        Periodic borders, as in :func:`reduce`.
    single : bool, optional
        Cosine transforms in float32, as in :func:`expand`.

    Returns
    -------
    (h, w, d) ndarray
    """
    h, w = band.shape[:2]
    if wrap:
        return band - expand(reduce(band, wrap=True), (h, w), wrap=True)
    coeffs = sfft.dctn(_working(band, single), axes=(0, 1), norm="ortho")
    h2, w2 = _half((h, w))
    coeffs[:h2, :w2] = 0.0
    return sfft.idctn(coeffs, axes=(0, 1), norm="ortho")


def pyramid(image, levels):
    """The bands of the spectral pyramid of a channel-last (H, W, d) image,
    finest first: ``levels - 1`` band-pass bands and the low-pass residual
    (cosine frequencies)."""
    return drain(iter_pyramid(image, levels))


def _by_channel(values, what, stage, start, share, message, single=False):
    """``what`` applied to every channel of (h, w, d) ``values`` in turn, as
    a job: a record after each (the transforms run on whole planes; with
    ``single`` each plane is handed over as float32)."""
    d = values.shape[2]
    out = None
    for c in range(d):
        # a contiguous copy of the plane: the transforms run a third faster
        # on it than on the strided view, with the same numbers
        # (float32 in the same one copy: the values the transforms' own
        # conversion would give)
        plane = what(np.ascontiguousarray(values[..., c : c + 1],
                                          np.float32 if single else None))
        if out is None:
            out = np.empty(plane.shape[:2] + (d,))
        out[..., c : c + 1] = plane
        yield Progress(stage, start + share * (c + 1) / d, f"{message}, channel {c + 1}/{d}")
    return out


def iter_pyramid(image, levels):
    """:func:`pyramid` as a job (stage ``"pyramid"``): a record after every
    channel of every level, fractions by pixels; then the bands."""
    gauss = [np.asarray(image, np.float64)]
    shapes = [image.shape[:2]]
    for _ in range(levels - 1):
        shapes.append(_half(shapes[-1]))
    pixels = np.array([h * w for h, w in shapes[:-1]], float)
    total, done = max(2.0 * pixels.sum(), 1.0), 0.0
    for k in range(levels - 1):
        gauss.append((yield from _by_channel(gauss[-1], reduce, "pyramid", done / total,
                                             pixels[k] / total, f"level {k + 2}/{levels}")))
        done += pixels[k]
    bands = []
    for k in range(levels - 1):
        g = gauss[k]
        up = yield from _by_channel(gauss[k + 1], lambda c, s=g.shape[:2]: expand(c, s),
                                    "pyramid", done / total, pixels[k] / total,
                                    f"band {k + 1}/{levels}")
        done += pixels[k]
        bands.append(g - up)
    return bands + [gauss[-1]]


def collapse(bands, *, wrap=False, single=False):
    """The image of spectral-pyramid ``bands`` (finest first): the inverse
    of :func:`pyramid` (and of its periodic form with ``wrap``; ``single``:
    see :func:`expand`)."""
    return drain(iter_collapse(bands, wrap=wrap, single=single))


def iter_collapse(bands, *, wrap=False, single=False):
    """:func:`collapse` as a job (stage ``"collapse"``): a record after
    every channel of every level; then the image (float64; ``single``: the
    expansions' transforms in float32, see :func:`expand`)."""
    out = bands[-1]
    finer = bands[-2::-1]
    pixels = np.array([b.shape[0] * b.shape[1] for b in finer], float)
    total, done = max(pixels.sum(), 1.0), 0.0
    for k, band in enumerate(finer):
        up = yield from _by_channel(
            out, lambda c, s=band.shape[:2]: expand(c, s, wrap=wrap, single=single), "collapse",
            done / total, pixels[k] / total, f"level {len(finer) - k}", single=single and not wrap)
        done += pixels[k]
        out = np.add(band, up, out=up)  # (up is ours: no new array)
    return out


def iter_highpass(band, *, wrap=False, single=False, stage="highpass"):
    """:func:`highpass` as a job: a record after every channel (the result
    is float64, whatever ``single``)."""
    return (yield from _by_channel(band, lambda c: highpass(c, wrap=wrap, single=single), stage,
                                   0.0, 1.0, "band frequencies", single=single and not wrap))
