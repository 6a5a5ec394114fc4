"""Single-image and multichannel restoration with the local CAR model and
its prediction-probability maps (sections 14.5 and 14.6,
docs/restoration.md).

* :func:`restore` / :func:`iter_restore`: one degraded image, by the
  conditional mean of local CAR models in four directions and the edge rule.
* :func:`restore_multichannel` / :func:`iter_restore_multichannel`: several
  registered degraded versions of one scene, by the 2.5D CAR model.
* :func:`estimate_psf`, :func:`psf_width`: the point-spread function relating
  a restored image to the observed one.
* :func:`estimate_noise`: the noise level the edge rule compares with.
* :func:`restore_large` / :func:`iter_restore_large`: an image larger than
  memory (dask, zarr, TIFF) by tiles with a halo (:func:`tile_halo`), the
  same result as :func:`restore` (``restore_tiled`` / ``iter_restore_tiled``,
  their names before, still work).
* :func:`restore_frames` / :func:`iter_restore_frames`: every frame of a clip
  longer than memory, a block of frames at a time, into any array or writer.

The ``iter_`` forms yield :class:`~car_napari.Progress` records with previews
of the image filling in, and return what the plain forms return; a
:class:`RestorationResult` re-thresholds at any ``kappa`` without
recomputation.
"""

from ._frames import iter_restore_frames, restore_frames
from ._multichannel import (
    DEFAULT_KAPPA,
    MultichannelRestoration,
    iter_restore_multichannel,
    multichannel_context,
    restore_multichannel,
    sharpness,
)
from ._noise import estimate_noise
from ._psf import estimate_psf, psf_width
from ._restore import iter_restore, restore
from ._single import RestorationResult
from ._tiled import iter_restore_large, restore_large, tile_halo

# the names before issue 33, kept working (not listed: one name each)
from ._tiled import iter_restore_tiled as iter_restore_tiled
from ._tiled import restore_tiled as restore_tiled

__all__ = [
    "DEFAULT_KAPPA",
    "MultichannelRestoration",
    "RestorationResult",
    "estimate_noise",
    "estimate_psf",
    "iter_restore",
    "iter_restore_frames",
    "iter_restore_large",
    "iter_restore_multichannel",
    "multichannel_context",
    "psf_width",
    "restore",
    "restore_frames",
    "restore_large",
    "restore_multichannel",
    "sharpness",
    "tile_halo",
]
