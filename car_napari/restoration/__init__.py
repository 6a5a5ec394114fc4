"""Single-image and multichannel restoration with the local CAR model and
its prediction-probability maps (chapter 14.5)."""

from ._restore import (
    DEFAULT_KAPPA,
    estimate_noise,
    estimate_psf,
    iter_restore,
    iter_restore_multichannel,
    psf_width,
    RestorationResult,
    RestorationState,
    restore,
    restore_multichannel,
    sharpness,
)

__all__ = [
    "DEFAULT_KAPPA",
    "RestorationResult",
    "RestorationState",
    "estimate_noise",
    "estimate_psf",
    "iter_restore",
    "iter_restore_multichannel",
    "psf_width",
    "restore",
    "restore_multichannel",
    "sharpness",
]
