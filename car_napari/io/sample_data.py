"""Sample data for napari's File > Open Sample menu (Qt-free).

Each function returns a list of napari ``LayerData`` tuples. The files live
in the repository's top-level ``resources/`` folder (read in place from a
source checkout or an editable install) and are copied into wheels as
``car_napari/_resources``; see ``resources/README.md`` for their licences.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_PACKAGE = Path(__file__).resolve().parents[1]
_INSTALLED = _PACKAGE / "_resources"  # a wheel's copy
_CHECKOUT = _PACKAGE.parent / "resources"  # the source tree (editable install)


__all__ = ["colour_texture", "damaged_film", "degraded_stack", "mammogram", "resource_path"]


def resource_path(name):
    """The path of a shipped sample file.

    Parameters
    ----------
    name : str
        A file name in ``resources/`` (for example ``"mammogram_mdb001.png"``).

    Returns
    -------
    path : pathlib.Path
        The file in the installed package, else in the source checkout.

    Raises
    ------
    FileNotFoundError
        If the file is in neither place (a broken installation).

    Examples
    --------
    >>> resource_path("texture_vistex_VS50.png").name
    'texture_vistex_VS50.png'
    """
    for folder in (_INSTALLED, _CHECKOUT):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(
        f"sample file {name!r} is missing from the installation ({_INSTALLED}); reinstall "
        "car-napari."
    )


def _read(name):
    from skimage import io

    return io.imread(str(resource_path(name)))


def colour_texture():
    """VisTex VS50, a 256x256 colour texture (research use with attribution).

    Returns
    -------
    layers : list of tuple
        One napari ``LayerData`` tuple ``(image, kwargs, "image")``: a
        (256, 256, 3) uint8 RGB image.

    Examples
    --------
    >>> (image, kwargs, kind), = colour_texture()
    >>> image.shape, kwargs["rgb"], kind
    ((256, 256, 3), True, 'image')
    """
    return [(_read("texture_vistex_VS50.png"), {"name": "VisTex VS50", "rgb": True}, "image")]


def mammogram():
    """The mini-MIAS mammogram mdb001 (research use only; cite Suckling et al. 1994).

    Returns
    -------
    layers : list of tuple
        One napari ``LayerData`` tuple ``(image, kwargs, "image")``: a
        (1024, 1024) uint8 grey image.

    Examples
    --------
    >>> (image, kwargs, kind), = mammogram()
    >>> image.shape, image.dtype, kwargs["colormap"]
    ((1024, 1024), dtype('uint8'), 'gray')
    """
    return [(_read("mammogram_mdb001.png"), {"name": "mini-MIAS mdb001",
                                             "colormap": "gray"}, "image")]


def damaged_film():
    """A damaged 35 mm film scan (FILM-AA) with its damage mask.

    Returns
    -------
    layers : list of tuple
        Two napari ``LayerData`` tuples: the RGB scan ``(frame, kwargs,
        "image")`` and its damage mask ``(mask, kwargs, "labels")``, a uint8
        array of the frame's height and width with 1 on damaged pixels.

    Examples
    --------
    >>> (frame, _, _), (mask, _, kind) = damaged_film()
    >>> kind, mask.shape == frame.shape[:2], sorted(map(int, set(mask.ravel())))
    ('labels', True, [0, 1])
    """
    frame = _read("film_cinestill50d_damaged.jpg")
    mask = (_read("film_cinestill50d_mask.png") > 127).astype(np.uint8)
    return [
        (frame, {"name": "damaged film", "rgb": True}, "image"),
        (mask, {"name": "damaged film scratch mask", "opacity": 0.6}, "labels"),
    ]


def degraded_stack(n_versions=8, seed=0):
    """Degraded versions of the VisTex sample, as from a burst of exposures.

    Gaussian blurs of 0.5 to 2 pixels in shuffled order and independent
    Gaussian noise of standard deviation 0.05 (the restoration benchmark's
    setting).

    Parameters
    ----------
    n_versions : int, optional
        How many versions (default 8).
    seed : int, optional
        Seed of the blur order and the noise (default 0).

    Returns
    -------
    layers : list of tuple
        One napari ``LayerData`` tuple ``(stack, kwargs, "image")``: a
        (n_versions, 256, 256, 3) float32 stack in [0, 1], versions along
        axis 0.

    Examples
    --------
    >>> (stack, kwargs, kind), = degraded_stack(n_versions=2)
    >>> stack.shape, stack.dtype
    ((2, 256, 256, 3), dtype('float32'))
    """
    from scipy import ndimage

    clean = _read("texture_vistex_VS50.png")[..., :3] / 255.0
    rng = np.random.default_rng(seed)
    blurs = rng.permutation(np.linspace(0.5, 2.0, n_versions))
    versions = [ndimage.gaussian_filter(clean, (b, b, 0)) + rng.normal(0, 0.05, clean.shape)
                for b in blurs]
    stack = np.clip(np.stack(versions), 0.0, 1.0).astype(np.float32)
    return [(stack, {"name": "degraded burst", "rgb": True}, "image")]
