"""Multiresolution CAR texture synthesis and compression (section 14.8, docs/texture.md).

A texture is analysed by a Gaussian-Laplacian pyramid; every sub-band gets
its own CAR model with its own optimal support (the decision rule (14.6),
docs/model.md). The few numbers of those models are the compressed texture:
synthesis generates every sub-band from its model (synthesis, docs/model.md)
at any size, matches every generated band's histogram to a few stored
quantiles of the analysed band, collapses the pyramid and restores the
histogram of the input (from its stored quantiles).

The pyramid (Burt and Adelson, with operators chosen so that analysis and
synthesis match at any image size):

- ``reduce``: Gaussian blur (sigma 1 pixel), then the mean of 2 x 2 blocks;
  a level of size ``n`` gives ``ceil(n / 2)``.
- ``expand``: separable cubic convolution (Keys, a = -0.5) back to the finer
  level's size, pixel extents aligned; half-sample symmetric borders, or
  periodic ones for tileable synthesis.
- band ``k < levels - 1`` is ``G_k - expand(G_{k+1})`` (band-pass, about zero
  mean); the last band is the low-pass residual ``G_{levels-1}``. Collapsing
  ``G_k = band_k + expand(G_{k+1})`` reconstructs the input exactly.

The stored file format is described in :meth:`TextureModel.save`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._docstrings import constructor_sections, shared_parameters, shared_sections
from .._progress import drain
from .._validation import check_shape
from ..model.synthesis import cached_radius
from ._doc_sections import RAISES_SYNTHESIS
from ._fit import _AUTO_LEVELS, _auto_levels, iter_fit_fields
from ._format import FORMAT_NAME, FORMAT_VERSION, _read_model_file, model_fields, write_model_file
from ._pyramid import collapse_pyramid, laplacian_pyramid
from ._synthesis import iter_synthesize_texture

__all__ = [
    "TextureModel", "iter_fit_texture", "laplacian_pyramid", "collapse_pyramid", "FORMAT_NAME",
    "FORMAT_VERSION",
]


# the examples' shared start (docstring sections written once)
EXAMPLES_MODEL = """
Examples
--------
>>> import numpy as np
>>> from car_napari.texture import TextureModel
>>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
"""
EXAMPLES_TEXTURE = """
Examples
--------
>>> import numpy as np
>>> texture = np.random.default_rng(0).random((64, 64))
"""


_FIT_PARAMETERS = """
image : (H, W) or (H, W, C) array
    The texture; any dtype (integer images are scaled to [0, 1]).
    Every side must be at least ``16 * 2**(levels - 1)`` pixels
    (64 for 3 levels), so that the coarsest band can be modelled.
levels : int or None, optional
    Number of pyramid bands: ``levels - 1`` band-pass (Laplacian)
    bands plus the low-pass residual. 1 means no pyramid. None (the
    default): 5, or as many as the texture's size allows (see
    above), at least 1.
model : {'3d', '2d'}, optional
    '3d': one 3DCAR per band with full colour matrices. '2d': per band,
    a spectral PCA and one 2DCAR per factor.
neighbourhood : 'auto', int or (eta, 2) array, optional
    'auto' chooses each band's support among orders 1 to 5 by the
    decision rule (14.6), independently per band. An int or offsets
    use the same support in every band.
channel_axis : int or None, optional
    Axis of the channels of a 3-D image (default the last). A 2-D
    image is always grey; None requires one.
pyramid : {'spectral', 'gaussian'}, optional
    The bands: 'spectral' (default) splits the frequencies so that no
    two bands share one; 'gaussian' is the Gaussian-Laplacian
    pyramid of :func:`laplacian_pyramid` (the models of format
    versions 1 and 2; its bands overlap, and their independent
    synthesis loses the texture's autocorrelation).
"""


_SYNTHESIZE_PARAMETERS = """
shape : tuple of 2 ints
    (height, width) of the output; any size of at least 1 x 1.
seed : int, numpy Generator or None, optional
    The same seed gives the same texture.
tileable : bool, optional
    Make the texture periodic: tiles placed side by side (or the
    texture wrapped on a torus) show no seam. Each band is generated
    larger and its opposite edges cross-faded over a quarter of its
    size; the pyramid is collapsed with periodic expansion.
"""


@dataclass(eq=False)
@shared_sections(examples_model=EXAMPLES_MODEL)
class TextureModel:
    """A multiresolution CAR texture model: the compressed texture.

    The texture model of section 14.8 (docs/texture.md). Build one with
    :meth:`fit` (or :func:`iter_fit_texture`) or :meth:`load`; generate
    textures of any size with :meth:`synthesize`. The fields below are
    also the constructor's parameters.

    Parameters
    ----------
    models : tuple of CARModel
        One model per pyramid band, finest first; the last models the low-pass
        residual. Models read by :meth:`load` carry only what synthesis needs
        (``vx`` is NaN; do not use them with :func:`car_napari.predict`).
    band_ranges : (levels, 2, d) ndarray
        Per band, the minimum and maximum of the analysed band; synthesised
        bands are clipped to it (keeps rare outliers of the Gaussian model
        from adding up across levels).
    mean : (d,) ndarray
        Mean of the input, restored after the collapse.
    std : (d,) ndarray
        Standard deviation of the input, restored after the collapse: the
        bands are generated independently, which drops the (positive)
        covariance between neighbouring bands of a real texture and would
        leave the result with about 20 % less contrast.
    value_range : (2, d) ndarray
        Per-channel minimum and maximum of the input; the output is clipped
        to it (the histogram-range restore).
    grey : bool
        True when the input was a 2-D grey image (synthesis then returns 2-D).
    model : {'3d', '2d'}
        The CAR variant of every band (see :func:`car_napari.fit_car`).
    fallbacks : tuple of str
        One entry per band whose first fitted model was unstable, saying what
        was used instead (a lower order, chosen by the decision-rule score
        when the support was 'auto'; as a last resort order 1 with a scaled
        ``gamma``). Empty when every first fit was stable.
    band_quantiles : (levels, 32, d) ndarray or None
        Per band and channel, the quantiles of the analysed band at the
        probabilities 0, 1/31, ..., 1. Every synthesised band is mapped onto
        them by rank (histogram matching): the CAR models are Gaussian, the
        bands of real textures are not (heavy-tailed, skewed), and the local
        sign patterns of a texture (LBP) depend on those marginals. The
        quantile function is linear between them but for the two end
        intervals, which follow an exponential tail up to the minimum and the
        maximum (a linear end interval scatters 1/31 of the pixels evenly up to
        the extremes: isolated speckle). None for models read from version-1
        files (no matching).
    quantiles : (64, d) ndarray or None
        Per channel, the quantiles of the input at 0, 1/63, ..., 1; the
        collapsed output is mapped onto them (the histogram restore, after
        the mean and contrast restore). None for version-1 files (then only
        the mean, contrast and range are restored).
    pyramid : {'gaussian', 'spectral'}
        How the bands split the texture: 'gaussian', the Gaussian-Laplacian
        pyramid (models of format versions 1 and 2); 'spectral', bands that
        share no frequency (what :meth:`fit` makes; see
        ``car_napari/texture/_spectral.py``): independently generated bands
        then keep the texture's spectrum, which overlapping bands lose.
    palette : (k, d) ndarray or None
        Colours of the input (k-means centres, ``k`` at most 32); with
        ``palette_radius`` they bound the synthesis's colours: a pixel
        farther from its nearest palette colour than that colour's radius is
        moved onto the radius, after the histogram restore (see
        ``car_napari/texture/_palette.py``). None for grey models and for
        files before version 3.
    palette_radius : (k,) ndarray or None
        Per palette colour, the distance that holds 95 % of the input's
        (sampled) pixels nearest to it, cut by :meth:`fit` to the ball the
        input's colours cover (files fitted before keep their radii).

    {examples_model}
    >>> model.synthesize((40, 50), seed=0).shape
    (40, 50)
    >>> model.nbytes
    728
    """

    models: tuple
    band_ranges: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    value_range: np.ndarray
    grey: bool
    model: str = "3d"
    fallbacks: tuple = field(default=())
    band_quantiles: np.ndarray = field(default=None)
    quantiles: np.ndarray = field(default=None)
    pyramid: str = "gaussian"
    palette: np.ndarray = field(default=None)
    palette_radius: np.ndarray = field(default=None)

    # ------------------------------------------------------------------ fit
    @classmethod
    @shared_sections(parameters=_FIT_PARAMETERS,
                     constructor=constructor_sections("TextureModel", "fit_texture"))
    def fit(cls, image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
            pyramid="spectral"):
        """Fit a multiresolution CAR model to a texture.

        The model's constructor: the same as :func:`fit_texture`.

        {parameters}

        {constructor}

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2).levels
        2
        """
        return fit_texture(image, levels=levels, model=model, neighbourhood=neighbourhood,
                           channel_axis=channel_axis, pyramid=pyramid)

    @staticmethod
    def levels_for(shape, most=_AUTO_LEVELS):
        """The pyramid levels ``fit(levels=None)`` uses for a texture of ``shape``.

        Parameters
        ----------
        shape : tuple of int
            (height, width) of the texture.
        most : int, optional
            The most levels wanted (5, the default of :meth:`fit`).

        Returns
        -------
        int
            ``most``, or fewer so that the coarsest band keeps at least 16
            pixels a side; at least 1.

        Examples
        --------
        >>> from car_napari.texture import TextureModel
        >>> TextureModel.levels_for((512, 640)), TextureModel.levels_for((64, 96))
        (5, 3)
        >>> TextureModel.levels_for((512, 512), 2)
        2
        """
        return _auto_levels(shape, most)

    # ----------------------------------------------------------- properties
    @property
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def levels(self):
        """Number of pyramid bands (int).

        {examples_model}
        >>> model.levels
        2
        """
        return len(self.models)

    @property
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def n_channels(self):
        """Number of channels of the fitted texture (int; 1 for grey).

        {examples_model}
        >>> model.n_channels
        1
        """
        return int(self.mean.shape[0])

    @property
    def orders(self):
        """Neighbourhood order of every band (tuple; None for a custom support).

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2,
        ...                           neighbourhood=1)
        >>> model.orders
        (1, 1)
        """
        return tuple(m.order for m in self.models)

    def _parameter_arrays(self):
        """The arrays that define the model, by file key (see :meth:`save`)."""
        arrays = {"mean": self.mean, "std": self.std, "value_range": self.value_range}
        for k, m in enumerate(self.models):
            arrays[f"band{k}_gamma"] = m.gamma
            arrays[f"band{k}_sigma"] = m.sigma
            arrays[f"band{k}_mean"] = m.mean
            arrays[f"band{k}_offsets"] = m.offsets
            arrays[f"band{k}_range"] = self.band_ranges[k]
            if self.band_quantiles is not None:
                arrays[f"band{k}_quantiles"] = self.band_quantiles[k]
        if self.quantiles is not None:
            arrays["quantiles"] = self.quantiles
        if self.palette is not None:
            arrays["palette"] = self.palette
            arrays["palette_radius"] = self.palette_radius
        return arrays

    @property
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def nbytes(self):
        """Bytes of the stored parameters (int): the compressed size.

        Every number (including the integer offsets) counts as a float32.

        {examples_model}
        >>> model.nbytes
        728
        """
        return 4 * sum(int(np.size(a)) for a in self._parameter_arrays().values())

    @shared_sections(examples_model=EXAMPLES_MODEL)
    def compression_ratio(self, input_shape):
        """Raw float32 bytes of an image of ``input_shape`` over :attr:`nbytes`.

        Parameters
        ----------
        input_shape : tuple of int
            (H, W) (then ``H * W * n_channels`` values) or (H, W, C). The model
            synthesises any size, so the ratio grows with the size.

        Returns
        -------
        float
            ``4 * number of values / nbytes``.

        Raises
        ------
        ValueError
            If ``input_shape`` is not (H, W) or (H, W, C) with positive sides.

        {examples_model}
        >>> round(model.compression_ratio((512, 512)), 1)
        1440.4
        """
        shape = check_shape(input_shape, "input_shape ((H, W) or (H, W, C))")
        values = math.prod(shape) * (self.n_channels if len(shape) == 2 else 1)
        return 4.0 * values / self.nbytes

    # ------------------------------------------------------------ synthesis
    @shared_parameters(_SYNTHESIZE_PARAMETERS)
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def synthesize(self, shape, *, seed=None, tileable=False):
        """Generate a texture of any size from the model.

        Every band is generated from its CAR model at its pyramid size
        (synthesis, docs/model.md), mapped by rank onto the band's stored
        quantiles (histogram matching) and clipped to its analysed range; the pyramid is collapsed
        (expand and add, as in the analysis); the input's per-channel mean
        and standard deviation are restored, the result is mapped onto the
        input's stored quantiles and clipped to its value range (the
        histogram restore). The matching is monotone per pixel value, so
        it keeps a tileable texture periodic.

        {parameters}

        Returns
        -------
        texture : (H, W) or (H, W, C) ndarray of float64
            2-D when the model was fitted to a grey image, channel-last
            otherwise.

        Raises
        ------
        ValueError
            If ``shape`` is not two positive sizes.

        {examples_model}
        >>> texture = model.synthesize((30, 40), seed=1, tileable=True)
        >>> texture.shape
        (30, 40)
        >>> np.array_equal(texture, model.synthesize((30, 40), seed=1, tileable=True))
        True
        """
        return drain(self.iter_synthesize(shape, seed=seed, tileable=tileable))

    @shared_parameters(_SYNTHESIZE_PARAMETERS)
    @shared_sections(raises_synthesis=RAISES_SYNTHESIS)
    def iter_synthesize(self, shape, *, seed=None, tileable=False):
        """Generate a texture from the model, as a job: Progress, then the texture.

        The generator form of :meth:`synthesize`, with the same parameters
        and, bit for bit, the same result. Every part runs by blocks of rows
        with a :class:`~car_napari.Progress` record between them (each
        band's field by :func:`~car_napari.iter_synthesize`, its tiling,
        its histogram matching; the collapse; the restore of the mean,
        contrast and histogram), so closing the generator (a Cancel) stops
        the synthesis within a fraction of a second even at 4000 x 4000.

        {parameters}

        Returns
        -------
        texture : (H, W) or (H, W, C) ndarray of float64
            What :meth:`synthesize` returns.

        Yields
        ------
        Progress
            Stage ``"synthesis"`` (each band's field, tiling and matching,
            message ``"band 2/3, rows 512/1024"``), ``"collapse"``, then
            ``"restore"`` (the mean, contrast and histogram of the input);
            fractions in proportion to each part's measured cost. The
            records of the last pass carry a preview: the texture filling in
            (rows not yet done are 0; it is the array returned, do not
            modify it).

        {raises_synthesis}

        Examples
        --------
        >>> import numpy as np
        >>> from car_napari._progress import drain
        >>> from car_napari.texture import TextureModel
        >>> model = TextureModel.fit(np.random.default_rng(0).random((64, 64)), levels=2)
        >>> records = []
        >>> texture = drain(model.iter_synthesize((30, 40), seed=1), records.append)
        >>> list(dict.fromkeys(r.stage for r in records))
        ['synthesis', 'collapse', 'restore']
        >>> records[-1].fraction, np.array_equal(texture, model.synthesize((30, 40), seed=1))
        (1.0, True)
        """
        return (yield from iter_synthesize_texture(self, shape, seed=seed, tileable=tileable))

    # ---------------------------------------------------------- persistence
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def save(self, path):
        """Write the model to an ``.npz`` file.

        Format (version 3): a compressed NumPy ``.npz`` archive (no pickles) holding

        - ``header``: a JSON string ``{"format": "car-napari texture model",
          "version": 3, "levels": L, "n_channels": d, "grey": bool,
          "model": "3d"|"2d", "direction": [...], "order": [...], "beta": [...],
          "n_pixels": [...], "fallbacks": [...], "pyramid": {...}}``;
        - ``mean`` (d,), ``std`` (d,), ``value_range`` (2, d) and, per band ``k``,
          ``band{k}_gamma`` (d, d*eta), ``band{k}_sigma`` (d, d),
          ``band{k}_mean`` (d,), ``band{k}_offsets`` (eta, 2) int16,
          ``band{k}_range`` (2, d), ``band{k}_quantiles`` (32, d);
          ``quantiles`` (64, d) (the quantiles at equally spaced
          probabilities from 0 to 1, see :attr:`band_quantiles`); from
          version 3, for colour models, ``palette`` (k, d) and
          ``palette_radius`` (k,) (see :attr:`palette`).

        The header's ``pyramid`` names the kind of pyramid
        (``{"kind": "spectral"}`` or ``{"kind": "gaussian", ...}``, see
        :attr:`pyramid`). Version 2 is the same with a Gaussian pyramid
        always (its ``pyramid`` has no ``kind``); version 1 is version 2
        without the quantiles. :meth:`load` reads all three (a version-1
        model synthesises without histogram matching).

        Numbers are stored as float32 (offsets as int16); :meth:`fit` rounds
        the parameters to float32 already, so a loaded model synthesises
        exactly what the original does. :attr:`nbytes` counts 4 bytes a
        number (2 an offset coordinate would do; we count 4).

        Parameters
        ----------
        path : str or path-like
            Destination; NumPy adds ``.npz`` when the name has no suffix.

        Raises
        ------
        OSError
            If the file cannot be written; IsADirectoryError (before
            anything is written) if ``path`` is an existing folder.
        TypeError
            If ``path`` is not a file name (a str or path-like object).

        See Also
        --------
        load : Read the file back.

        {examples_model}
        >>> import os, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = os.path.join(folder, "noise.npz")
        ...     model.save(path)
        ...     loaded = TextureModel.load(path)
        >>> loaded.levels, loaded.nbytes == model.nbytes
        (2, True)
        """
        write_model_file(self, path)

    @classmethod
    @shared_sections(examples_model=EXAMPLES_MODEL)
    def load(cls, path):
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : str or path-like
            An ``.npz`` file of format version 1, 2 or 3.

        Returns
        -------
        TextureModel
            The model; it synthesises exactly what the saved one did. Its band
            models carry only what synthesis needs (``vx`` is NaN).

        Raises
        ------
        ValueError
            If the file is not a readable texture model, or was written by a
            newer version of the format than this code reads.
        FileNotFoundError
            If ``path`` does not exist.
        TypeError
            If ``path`` is not a file name (a str or path-like object; an int
            would be taken for a file descriptor).

        See Also
        --------
        save : The file format.

        {examples_model}
        >>> import os, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     model.save(os.path.join(folder, "noise.npz"))
        ...     loaded = TextureModel.load(os.path.join(folder, "noise.npz"))
        >>> np.array_equal(loaded.synthesize((20, 20), seed=0), model.synthesize((20, 20), seed=0))
        True
        """
        arrays, header, version = _read_model_file(path)
        try:
            model = cls(**model_fields(header, arrays, version))
        except (KeyError, ValueError, TypeError, IndexError, np.linalg.LinAlgError) as exc:
            raise ValueError(
                f"{path} is a damaged texture model: {type(exc).__name__}: {exc}."
            ) from exc
        for k, band in enumerate(model.models):
            radius = cached_radius(band)  # synthesis asks again: remembered
            if not radius < 1.0:
                raise ValueError(
                    f"{path} is a damaged texture model: band {k} is unstable (spectral "
                    f"radius {radius:.4g} >= 1), its field would grow without bound."
                )
        return model



@shared_parameters(_FIT_PARAMETERS)
@shared_sections(examples_texture=EXAMPLES_TEXTURE)
def iter_fit_texture(image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
                     pyramid="spectral"):
    """Fit a multiresolution CAR texture model, as a job reporting progress.

    The generator form of :func:`fit_texture` (same arguments, same
    result): every long pass runs by blocks of rows with a
    :class:`~car_napari.Progress` record between them (the reading of the
    image, its quantiles, the pyramid, each band's fit by
    :func:`~car_napari.iter_fit_car`, the bands' quantiles), a last record
    comes when all is done, and it returns the :class:`TextureModel`.
    Closing the generator (a Cancel) stops the fit at the next record.

    {parameters}

    Returns
    -------
    TextureModel
        The fitted model (the generator's return value).

    Yields
    ------
    Progress
        Stage ``"reading"`` (the conversion to float, ``"rows 512/2048"``),
        ``"quantiles"`` (message ``"texture, histogram"``), then
        ``"pyramid"`` (``"band 1/3, rows 512/1024"``), then ``"fitting"``,
        the records of each band's fit (``"level 2/3: rows 120/512"``,
        ``"level 2/3: order 3: D = ..."``), then ``"quantiles"`` of every
        band and a last ``"fitting"`` record at fraction 1. ``fraction``
        grows in proportion to the work: each part costs about its pixels.

    Raises
    ------
    ValueError
        As :func:`fit_texture`: bad options, layout or size before the
        first record; non-finite or constant values while the image is read
        (the first records).
    TypeError
        As :func:`fit_texture`, before the first record.

    {examples_texture}
    >>> from car_napari.texture import iter_fit_texture
    >>> records = list(iter_fit_texture(texture, levels=2))
    >>> list(dict.fromkeys(r.stage for r in records))  # in their order
    ['reading', 'quantiles', 'pyramid', 'fitting']
    >>> all(a.fraction <= b.fraction for a, b in zip(records, records[1:]))
    True
    >>> records[-1].message, records[-1].fraction
    ('2 levels fitted', 1.0)
    """
    return TextureModel(**(yield from iter_fit_fields(
        image, levels=levels, model=model, neighbourhood=neighbourhood,
        channel_axis=channel_axis, pyramid=pyramid)))


@shared_parameters(_FIT_PARAMETERS)
@shared_sections(examples_texture=EXAMPLES_TEXTURE)
def fit_texture(image, *, levels=None, model="3d", neighbourhood="auto", channel_axis=-1,
                pyramid="spectral"):
    """Fit a multiresolution CAR model to a texture.

    The same as running :func:`iter_fit_texture` to its end.

    {parameters}

    Returns
    -------
    TextureModel
        The fitted model.

    Raises
    ------
    ValueError
        If the texture is too small for the pyramid, constant, or not
        finite, or ``levels``, ``model`` or ``neighbourhood`` is invalid.
    TypeError
        If ``levels`` is not an int, or the image is not numeric.

    See Also
    --------
    iter_fit_texture : The same fit as a job that reports its progress.
    TextureModel.fit : The same, as the model's constructor.

    Notes
    -----
    A band whose fitted model is unstable (spectral radius >= 1, its field
    would explode) falls back to a lower order; see ``fallbacks``.

    {examples_texture}
    >>> from car_napari.texture import fit_texture
    >>> model = fit_texture(texture, levels=2)
    >>> model.levels, model.n_channels, model.grey
    (2, 1, True)
    """
    return drain(iter_fit_texture(image, levels=levels, model=model, neighbourhood=neighbourhood,
                                  channel_axis=channel_axis, pyramid=pyramid))
