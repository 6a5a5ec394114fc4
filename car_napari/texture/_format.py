"""The file format of a texture model (``TextureModel.save``): writing,
and reading with every member checked before it is read."""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib
from functools import partial

import numpy as np

from .._validation import check_path
from ..model.directions import DIRECTIONS
from ..model.estimation import CARModel
from ..model.neighbourhood import as_offsets
from ._pyramid import _BLUR_SIGMA

FORMAT_NAME = "car-napari texture model"
FORMAT_VERSION = 3
PYRAMIDS = ("spectral", "gaussian")  # the kinds of pyramid a model can use


def write_model_file(texture, path):
    """Write ``texture`` to ``path`` (see ``TextureModel.save``)."""
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "levels": texture.levels,
        "n_channels": texture.n_channels,
        "grey": bool(texture.grey),
        "model": texture.model,
        "direction": [m.direction for m in texture.models],
        "order": [m.order for m in texture.models],
        "beta": [float(m.beta) for m in texture.models],
        "n_pixels": [int(m.n_pixels) for m in texture.models],
        "fallbacks": list(texture.fallbacks),
        "pyramid": ({"kind": "spectral", "split": "lowest ceil(n/2) cosine (DCT-II) "
                     "frequencies per axis; Fourier ones when tileable"}
                    if texture.pyramid == "spectral" else
                    {"kind": "gaussian", "blur_sigma": _BLUR_SIGMA,
                     "expand": "Keys cubic convolution, pixel extents aligned"}),
    }
    check_path(path)
    if os.path.isdir(path):  # np.savez would write "<folder>.npz" beside it
        raise IsADirectoryError(
            f"{os.fsdecode(path)!r} is an existing folder; pass a file name, e.g. "
            f"{os.path.join(os.fsdecode(path), 'texture.npz')!r}.")
    arrays = {key: (a.astype(np.int16) if key.endswith("_offsets") else
                    np.asarray(a, np.float64).astype(np.float32))
              for key, a in texture._parameter_arrays().items()}
    np.savez_compressed(path, header=np.array(json.dumps(header)), **arrays)



def model_fields(header, arrays, version=FORMAT_VERSION):
    """The fields of a ``TextureModel`` (its constructor's arguments) from
    a model file's header and arrays."""
    levels, d = int(header["levels"]), int(header["n_channels"])
    mean = np.asarray(arrays["mean"], float).reshape(d)
    std = np.asarray(arrays["std"], float).reshape(d)
    value_range = np.asarray(arrays["value_range"], float).reshape(2, d)
    models, ranges, band_quantiles, quantiles = [], [], [], None
    if version >= 2:
        quantiles = np.asarray(arrays["quantiles"], float).reshape(-1, d)
    for k in range(levels):
        gamma = np.asarray(arrays[f"band{k}_gamma"], float)
        offsets, _ = as_offsets(np.asarray(arrays[f"band{k}_offsets"]))
        eta = len(offsets)
        gamma = gamma.reshape(d, d * eta)
        sigma = np.asarray(arrays[f"band{k}_sigma"], float).reshape(d, d)
        beta = float(header["beta"][k])
        if not (np.all(np.isfinite(gamma)) and np.all(np.isfinite(sigma))):
            raise ValueError(f"band {k} has non-finite parameters")
        models.append(CARModel(
            gamma=gamma, sigma=sigma,
            mean=np.asarray(arrays[f"band{k}_mean"], float).reshape(d),
            offsets=offsets, lam=sigma * beta,
            vx=np.full((d * eta, d * eta), np.nan),  # not stored: synthesis does not need it
            beta=beta, n_pixels=int(header["n_pixels"][k]),
            order=header["order"][k], direction=str(header["direction"][k]),
        ))
        ranges.append(np.asarray(arrays[f"band{k}_range"], float).reshape(2, d))
        if version >= 2:
            band_quantiles.append(
                np.asarray(arrays[f"band{k}_quantiles"], float).reshape(-1, d)
            )
    return dict(
        models=tuple(models), band_ranges=np.stack(ranges), mean=mean, std=std,
        value_range=value_range, grey=bool(header["grey"]),
        model=str(header.get("model", "3d")),
        fallbacks=tuple(header.get("fallbacks", ())),
        band_quantiles=np.stack(band_quantiles) if version >= 2 else None,
        quantiles=quantiles, pyramid=_pyramid_kind(header, version),
        palette=(np.asarray(arrays["palette"], float).reshape(-1, d)
                 if "palette" in arrays else None),
        palette_radius=(np.asarray(arrays["palette_radius"], float).reshape(-1)
                        if "palette" in arrays else None),
    )



def _pyramid_kind(header, version):
    """The pyramid of a model file: 'gaussian' before version 3, else the
    header's ``pyramid.kind``."""
    if version < 3:
        return "gaussian"
    kind = header.get("pyramid", {}).get("kind") if isinstance(header.get("pyramid"),
                                                                dict) else None
    if kind not in PYRAMIDS:
        raise ValueError(f"the format-version-{version} header names pyramid kind {kind!r}, "
                         f"not one of {PYRAMIDS}")
    return kind


# ------------------------------------------------------------ model files
# What a model file may hold (the loader refuses anything else before reading
# it): the bounds of the format, far beyond what a fit produces (order 5
# reaches 2 pixels with 12 offsets, order 30 reaches 8 with 106).
MAX_FILE_LEVELS = 8
MAX_FILE_CHANNELS = 64
MAX_FILE_REACH = 16  # largest |di| or |dj| of a neighbour offset
MAX_FILE_OFFSETS = 256  # largest number of offsets per band
_MAX_FILE_QUANTILES = 4096
_MAX_FILE_PALETTE = 4096  # colours of a palette
_HEADER_BYTES = 1 << 16  # the JSON header's largest size
_NPY_HEADER_BYTES = 1 << 12  # room for an .npy member's own header


def _model_file_error(path, what):
    return ValueError(f"{path} is not a readable car-napari texture model (.npz): {what}. "
                      "Re-save the model with TextureModel.save.")


def _read_member(archive, path, key, *, kinds, count=None, max_count=None):
    """The array ``key`` of the open ``archive``: its declared sizes and its
    .npy header checked before any of its data is read (a bounded read)."""
    try:
        info = archive.getinfo(key + ".npy")
    except KeyError:
        raise ValueError(f"{path} is a damaged texture model: member {key!r} is missing."
                         ) from None
    if max_count is None:
        max_count = count
    limit = _NPY_HEADER_BYTES + 8 * max_count if kinds != "U" else _HEADER_BYTES
    if info.file_size > limit:
        raise ValueError(
            f"{path} is a damaged texture model: member {key!r} declares "
            f"{info.file_size} bytes, more than the {limit} it can take."
        )
    with archive.open(info) as stream:
        try:
            major, _ = np.lib.format.read_magic(stream)
            reader = (np.lib.format.read_array_header_1_0 if major == 1
                      else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = reader(stream)
        except ValueError as exc:
            raise ValueError(f"{path} is a damaged texture model: member {key!r} is not a "
                             f"NumPy array ({exc}).") from None
        if dtype.hasobject or dtype.kind not in kinds:
            raise ValueError(
                f"{path} is a damaged texture model: member {key!r} has dtype {dtype} "
                f"(allowed kinds {kinds!r}; objects and pickles are refused)."
            )
        n = math.prod(shape)
        if (count is not None and n != count) or (max_count is not None and n > max_count) \
                or n == 0:
            want = count if count is not None else f"1 to {max_count}"
            raise ValueError(
                f"{path} is a damaged texture model: member {key!r} has shape {shape} "
                f"({n} values) but needs {want}."
            )
        data = stream.read(n * dtype.itemsize)
    if len(data) != n * dtype.itemsize:
        raise ValueError(f"{path} is a damaged texture model: member {key!r} is truncated.")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def _header_value(header, path, key, kind, low, high):
    value = header.get(key)
    if isinstance(value, bool) or not isinstance(value, kind) or not low <= value <= high:
        raise ValueError(f"{path} has an invalid texture-model header: {key!r} is "
                         f"{value!r}, not in {low} to {high}.")
    return value


def _check_header(header, path):
    """The header's fields that decide what is read, checked (the rest is
    checked as the model is built)."""
    levels = _header_value(header, path, "levels", int, 1, MAX_FILE_LEVELS)
    d = _header_value(header, path, "n_channels", int, 1, MAX_FILE_CHANNELS)
    for key in ("beta", "n_pixels", "order", "direction"):
        if not isinstance(header.get(key), list) or len(header[key]) != levels:
            raise ValueError(f"{path} has an invalid texture-model header: {key!r} must be "
                             f"a list of {levels} entries.")
    for k in range(levels):
        beta, n_pixels = header["beta"][k], header["n_pixels"][k]
        order, direction = header["order"][k], header["direction"][k]
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) \
                or not math.isfinite(beta) or beta < 0:
            raise ValueError(f"{path} has an invalid texture-model header: beta of band {k} "
                             f"is {beta!r}.")
        if isinstance(n_pixels, bool) or not isinstance(n_pixels, int) or n_pixels < 0:
            raise ValueError(f"{path} has an invalid texture-model header: n_pixels of band "
                             f"{k} is {n_pixels!r}.")
        if order is not None and (isinstance(order, bool) or not isinstance(order, int)):
            raise ValueError(f"{path} has an invalid texture-model header: order of band {k} "
                             f"is {order!r}.")
        if direction not in DIRECTIONS:
            raise ValueError(f"{path} has an invalid texture-model header: direction of band "
                             f"{k} is {direction!r}, not one of {DIRECTIONS}.")
    if not isinstance(header.get("grey"), bool) or (header["grey"] and d != 1):
        raise ValueError(f"{path} has an invalid texture-model header: grey is "
                         f"{header.get('grey')!r} for {d} channels.")
    if header.get("model", "3d") not in ("3d", "2d"):
        raise ValueError(f"{path} has an invalid texture-model header: model is "
                         f"{header.get('model')!r}.")
    fallbacks = header.get("fallbacks", [])
    if not isinstance(fallbacks, list) or not all(isinstance(f, str) for f in fallbacks):
        raise ValueError(f"{path} has an invalid texture-model header: fallbacks is "
                         f"{fallbacks!r}.")
    return levels, d


def _check_parameters(arrays, path, levels, d):
    """Every stored number finite and every array consistent: ranges
    ordered, quantiles non-decreasing, covariances symmetric positive
    semi-definite, offsets causal and within the format's bounds."""
    for key, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{path} is a damaged texture model: {key} holds NaN or "
                             "infinite values.")
    if np.any(arrays["std"] < 0):
        raise ValueError(f"{path} is a damaged texture model: std is negative.")
    if "palette" in arrays and (arrays["palette"].size % d
                                or np.any(arrays["palette_radius"] < 0)):
        raise ValueError(f"{path} is a damaged texture model: the palette has "
                         f"{arrays['palette'].size} values for {d} channels or a negative "
                         "radius.")
    keys = ["value_range"] + [f"band{k}_range" for k in range(levels)]
    for key in keys:
        lo, hi = arrays[key].reshape(2, d)
        if np.any(lo > hi):
            raise ValueError(f"{path} is a damaged texture model: {key} has its minimum "
                             "above its maximum.")
    for key in [k for k in arrays if k.endswith("quantiles")]:
        if arrays[key].size % d or arrays[key].size < 2 * d:
            raise ValueError(f"{path} is a damaged texture model: {key} has "
                             f"{arrays[key].size} values, not at least 2 per channel.")
        if np.any(np.diff(arrays[key].reshape(-1, d), axis=0) < 0):
            raise ValueError(f"{path} is a damaged texture model: {key} are not "
                             "non-decreasing.")
    for k in range(levels):
        offsets = arrays[f"band{k}_offsets"]
        if np.abs(offsets).max() > MAX_FILE_REACH:
            raise ValueError(
                f"{path} is a damaged texture model: band {k} has a neighbour offset "
                f"reaching {int(np.abs(offsets).max())} pixels (the format allows at most "
                f"{MAX_FILE_REACH})."
            )
        sigma = arrays[f"band{k}_sigma"].reshape(d, d).astype(float)
        scale = max(float(np.abs(sigma).max()), np.finfo(float).tiny)
        symmetric = np.abs(sigma - sigma.T).max() <= 1e-5 * scale
        if not symmetric or np.linalg.eigvalsh(sigma).min() < -1e-5 * scale:
            raise ValueError(f"{path} is a damaged texture model: band {k}'s covariance "
                             "is not symmetric positive semi-definite.")


def _read_model_file(path):
    """The header, the arrays and the format version of a model file, every
    member checked before it is read; a ValueError naming the file and what
    is wrong for anything else."""
    check_path(path)
    try:
        with open(path, "rb") as file:
            magic = file.read(6)
    except FileNotFoundError:
        raise
    except (OSError, TypeError) as exc:
        raise _model_file_error(path, exc) from exc
    if magic == b"\x93NUMPY":
        raise _model_file_error(path, "it is a single NumPy array (.npy), not the .npz "
                                "archive TextureModel.save writes")
    try:
        with zipfile.ZipFile(path) as archive:
            return _read_members(archive, path)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError,
            RuntimeError) as exc:
        raise _model_file_error(path, f"{type(exc).__name__}: {exc}") from exc


def _read_members(archive, path):
    if "header.npy" not in archive.namelist():
        raise ValueError(f"{path} has no texture-model header; it was not written by "
                         "TextureModel.save or is corrupt.")
    text = _read_member(archive, path, "header", kinds="U", max_count=1)
    try:
        header = json.loads(str(text.reshape(())))
    except (ValueError, TypeError) as exc:
        raise ValueError(
            f"{path} has no valid texture-model header ({exc}); it was not written "
            "by TextureModel.save or is corrupt."
        ) from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise ValueError(
            f"{path} is not a car-napari texture model (format "
            f"{header.get('format') if isinstance(header, dict) else header!r})."
        )
    version = header.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ValueError(f"{path} has an invalid format version {version!r}.")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{path} uses texture-model format version {version}, newer than this "
            f"car-napari reads (up to {FORMAT_VERSION}); upgrade car-napari to load it."
        )
    levels, d = _check_header(header, path)
    floats = "fi"
    read = partial(_read_member, archive, path)
    arrays = {"mean": read("mean", kinds=floats, count=d),
              "std": read("std", kinds=floats, count=d),
              "value_range": read("value_range", kinds=floats, count=2 * d)}
    if version >= 2:
        arrays["quantiles"] = read("quantiles", kinds=floats,
                                   max_count=_MAX_FILE_QUANTILES * d)
    if version >= 3 and "palette.npy" in archive.namelist():
        arrays["palette"] = read("palette", kinds=floats, max_count=_MAX_FILE_PALETTE * d)
        arrays["palette_radius"] = read("palette_radius", kinds=floats,
                                        count=arrays["palette"].size // d)
    for k in range(levels):
        offsets = read(f"band{k}_offsets", kinds="iu", max_count=2 * MAX_FILE_OFFSETS)
        arrays[f"band{k}_offsets"] = offsets
        eta = offsets.size // 2
        arrays[f"band{k}_gamma"] = read(f"band{k}_gamma", kinds=floats, count=d * d * eta)
        arrays[f"band{k}_sigma"] = read(f"band{k}_sigma", kinds=floats, count=d * d)
        arrays[f"band{k}_mean"] = read(f"band{k}_mean", kinds=floats, count=d)
        arrays[f"band{k}_range"] = read(f"band{k}_range", kinds=floats, count=2 * d)
        if version >= 2:
            arrays[f"band{k}_quantiles"] = read(f"band{k}_quantiles", kinds=floats,
                                                max_count=_MAX_FILE_QUANTILES * d)
    _check_parameters(arrays, path, levels, d)
    return arrays, header, version
