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


def resource_path(name):
    """Path of a shipped sample file: in the installed package, else in the
    source checkout."""
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
    """VisTex VS50, a 256x256 colour texture (research use with attribution)."""
    return [(_read("texture_vistex_VS50.png"), {"name": "VisTex VS50", "rgb": True}, "image")]


def mammogram():
    """mini-MIAS mdb001 (research use only; cite Suckling et al. 1994)."""
    return [(_read("mammogram_mdb001.png"), {"name": "mini-MIAS mdb001",
                                             "colormap": "gray"}, "image")]


def damaged_film():
    """A damaged 35 mm film scan (FILM-AA) with its damage mask as labels."""
    frame = _read("film_cinestill50d_damaged.jpg")
    mask = (_read("film_cinestill50d_mask.png") > 127).astype(np.uint8)
    return [
        (frame, {"name": "damaged film", "rgb": True}, "image"),
        (mask, {"name": "damaged film scratch mask", "opacity": 0.6}, "labels"),
    ]


def degraded_stack(n_versions=8, seed=0):
    """Eight degraded versions of the VisTex sample, as from a burst of
    exposures: Gaussian blurs of 0.5 to 2 pixels in shuffled order and
    independent Gaussian noise of 0.05 (the restoration benchmark's setting);
    float32 in [0, 1], versions along axis 0."""
    from scipy import ndimage

    clean = _read("texture_vistex_VS50.png")[..., :3] / 255.0
    rng = np.random.default_rng(seed)
    blurs = rng.permutation(np.linspace(0.5, 2.0, n_versions))
    versions = [ndimage.gaussian_filter(clean, (b, b, 0)) + rng.normal(0, 0.05, clean.shape)
                for b in blurs]
    stack = np.clip(np.stack(versions), 0.0, 1.0).astype(np.float32)
    return [(stack, {"name": "degraded burst", "rgb": True}, "image")]
