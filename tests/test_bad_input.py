"""Bad input gets a clear error naming the problem and the fix."""

import functools
import re

import numpy as np
import pytest

from car_napari import (
    fit_car,
    illumination_invariants,
    local_parameters,
    predict,
    restore,
    select_support,
)

rng = np.random.default_rng(0)
GOOD = rng.random((32, 32, 3))

ENTRY_POINTS = [
    lambda im, **kw: fit_car(im, 2, **kw),
    lambda im, **kw: select_support(im, **kw),
    lambda im, **kw: local_parameters(im, 2, **kw),
    lambda im, **kw: illumination_invariants(im, **kw),
]


@pytest.mark.parametrize("call", ENTRY_POINTS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_inf(call, bad):
    img = GOOD.copy()
    img[3, 4, 1] = bad
    with pytest.raises(ValueError, match="NaN or infinite"):
        call(img)


@pytest.mark.parametrize("call", ENTRY_POINTS + [
    lambda im, **kw: predict(fit_car(GOOD, 1), im, **kw),
])
@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e160, 1e300])
def test_extreme_magnitude_is_a_clear_error(call, scale):
    # their squares leave float64: a message, never NaN output or LinAlgError
    img = GOOD * scale
    with pytest.raises(ValueError, match="magnitude .* Rescale"):
        call(img)
    np.testing.assert_array_equal(img, GOOD * scale)  # the input is untouched


def _restore_multichannel(stack):
    from car_napari import restore_multichannel

    return restore_multichannel(stack).restored


@pytest.mark.parametrize("call, data", [
    (lambda im: restore(im), GOOD),
    (lambda im: restore(im, estimator="recursive"), GOOD),
    (_restore_multichannel, np.stack([GOOD[..., 0], GOOD[..., 0] * 0.9 + 0.05, GOOD[..., 1]])),
])
@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e-20, 1e20, 1e160, 1e300])
def test_restorations_at_extreme_magnitudes(call, data, scale):
    # a clear error, or the result at scale 1 scaled (restorations scale the
    # data internally by a power of two: exact but for the input's rounding)
    img = data * scale
    try:
        out = call(img)
    except ValueError as exc:
        assert "magnitude" in str(exc) and "Rescale" in str(exc)
    else:
        assert np.isfinite(out).all()
        np.testing.assert_allclose(out / scale, call(data), rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(img, data * scale)  # the input is untouched


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_wrong_number_of_dimensions(call):
    with pytest.raises(ValueError, match="2-D .* or 3-D"):
        call(np.zeros((2, 8, 8, 3)))
    with pytest.raises(ValueError, match="2-D .* or 3-D"):
        call(np.zeros(10))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_smaller_than_neighbourhood(call):
    with pytest.raises(ValueError, match="too small"):
        call(GOOD[:2, :2])


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_constant_image(call):
    with pytest.raises(ValueError, match="constant"):
        call(np.full((32, 32), 0.5))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_empty_image(call):
    with pytest.raises(ValueError, match="empty"):
        call(np.zeros((0, 5)))


@pytest.mark.parametrize("call", ENTRY_POINTS)
def test_non_numeric(call):
    with pytest.raises(TypeError, match="dtype"):
        call(np.array([["a", "b"], ["c", "d"]]))
    with pytest.raises(TypeError, match="None"):
        call(None)


@pytest.mark.parametrize(
    "neighbourhood, match",
    [([[0, -1]], "not causal"), ([[1]], r"\(eta, 2\)"), (0, "order"), ("big", "order")],
)
def test_invalid_offsets(neighbourhood, match):
    with pytest.raises(ValueError, match=match):
        fit_car(GOOD, neighbourhood)
    if not isinstance(neighbourhood, str):
        with pytest.raises(ValueError, match=match):
            local_parameters(GOOD, neighbourhood)


def test_bad_options():
    with pytest.raises(ValueError, match="forgetting"):
        local_parameters(GOOD, 1, forgetting=1.5)
    with pytest.raises(ValueError, match="direction"):
        local_parameters(GOOD, 1, direction="diagonal")
    with pytest.raises(ValueError, match="model"):
        fit_car(GOOD, 1, model="4d")
    with pytest.raises(ValueError, match="channel_axis"):
        fit_car(GOOD, 1, channel_axis=None)


def test_predict_with_wrong_channels():
    model = fit_car(GOOD, 1)
    with pytest.raises(ValueError, match="3 channels|fitted to 3"):
        predict(model, GOOD[..., 0])
    with pytest.raises(TypeError, match="CARModel"):
        predict("model", GOOD)


def test_channel_axis_first():
    a = fit_car(GOOD, 1)
    b = fit_car(np.moveaxis(GOOD, -1, 0), 1, channel_axis=0)
    np.testing.assert_allclose(a.gamma, b.gamma)


@pytest.mark.parametrize("option, value, error", [
    ("forgetting", np.nan, ValueError), ("forgetting", 0.0, ValueError),
    ("forgetting", 1.5, ValueError), ("forgetting", "0.9", TypeError),
    ("prior", np.inf, ValueError), ("prior", -1.0, ValueError), ("prior", None, TypeError),
    ("warm_start", "yes", TypeError),
])
def test_local_parameters_options_checked_first(option, value, error):
    # a string image would fail too: the option's message must come first
    with pytest.raises(error, match=option):
        local_parameters("not an image", 1, **{option: value})


@pytest.mark.parametrize("margin, error", [(-5, ValueError), (2.5, ValueError),
                                           (10**7, ValueError), ("8", TypeError)])
def test_synthesis_margin_is_checked(margin, error):
    from car_napari import synthesize

    with pytest.raises(error, match="margin"):
        synthesize(fit_car(GOOD, 1), (16, 16), margin=margin)
    assert synthesize(fit_car(GOOD, 1), (16, 16), margin=0, seed=0).shape == (16, 16, 3)


# ---------------------------------------------------------------- model files
@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A small saved texture model, its arrays and its header."""
    import json

    from car_napari.texture import TextureModel

    model = TextureModel.fit(np.random.default_rng(1).random((32, 32, 3)), levels=2,
                             neighbourhood=1)
    path = tmp_path_factory.mktemp("models") / "good.npz"
    model.save(path)
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files}
    return path, arrays, json.loads(str(arrays["header"]))


def _edited(arrays, head, **changes):
    import json

    head = {**head, **changes.pop("header", {})}
    out = {**arrays, "header": np.array(json.dumps(head))}
    for key, value in changes.items():
        if value is None:
            out.pop(key)
        else:
            out[key] = value
    return out


def _set(array, index, value):
    array = array.copy()
    array[index] = value
    return array


def _corrupt_deflate(raw):
    """The first compressed byte of a member set to an invalid deflate block."""
    import io
    import struct
    import zipfile

    with zipfile.ZipFile(io.BytesIO(raw)) as archive:
        offset = archive.getinfo("band0_gamma.npy").header_offset
    n, m = struct.unpack("<HH", raw[offset + 26: offset + 30])
    raw = bytearray(raw)
    raw[offset + 30 + n + m] = 0xFF
    return bytes(raw)


# name: (edit of the arrays (None: of the raw bytes), words the message must hold)
MODEL_FILE_CASES = {
    "zlib error": (lambda raw: _corrupt_deflate(raw), "not a readable"),
    "truncated": (lambda raw: raw[: len(raw) // 2], "not a readable"),
    "not an archive": (lambda raw: b"hello, world", "not a readable"),
    "npy file": ("npy", r"\.npy"),
    "empty gamma": (dict(band0_gamma=np.zeros(0, np.float32)), "band0_gamma.*needs"),
    "empty offsets": (dict(band0_offsets=np.zeros((0, 2), np.int16)), "band0_offsets"),
    "missing member": (dict(band1_sigma=None), "band1_sigma.*missing"),
    "nan gamma": ("nan_gamma", "band0_gamma holds NaN"),
    "inf std": (dict(std=np.array([np.inf, 1, 1], np.float32)), "std holds NaN"),
    "offset (200, 0)": ("far_offset", "reaching 200 pixels"),
    "unstable": ("unstable", "unstable"),
    "negative variance": ("bad_sigma", "covariance"),
    "pickled member": (dict(mean=np.array([1, "a", None], dtype=object)), "dtype object"),
    "huge member": (dict(band0_gamma=np.zeros(10**6, np.uint8)), "declares .* bytes"),
    "levels 10**9": (dict(header={"levels": 10**9}), "levels"),
    "nan beta": (dict(header={"beta": [float("nan")] * 2}), "beta"),
}


@pytest.mark.parametrize("case", sorted(MODEL_FILE_CASES))
def test_damaged_model_files_are_refused_with_the_file_named(case, model_file, tmp_path):
    from car_napari.texture import TextureModel

    good, arrays, header = model_file
    edit, match = MODEL_FILE_CASES[case]
    path = tmp_path / "edited.npz"
    if callable(edit):
        path.write_bytes(edit(good.read_bytes()))
    elif edit == "npy":
        path = tmp_path / "array.npy"
        np.save(path, arrays["mean"])
    else:
        if isinstance(edit, str):
            edit = {
                "nan_gamma": dict(band0_gamma=_set(arrays["band0_gamma"], (0, 0), np.nan)),
                "far_offset": dict(band0_offsets=_set(arrays["band0_offsets"], 0, (200, 0))),
                "unstable": dict(band0_gamma=arrays["band0_gamma"] * 50),
                "bad_sigma": dict(band0_sigma=_set(arrays["band0_sigma"], (0, 0), -1.0)),
            }[edit]
        np.savez_compressed(path, **_edited(arrays, header, **edit))
    with pytest.raises(ValueError, match=match) as info:
        TextureModel.load(path)
    assert str(path) in str(info.value)


def test_unknown_members_are_never_read(model_file, tmp_path):
    # 50 MB of zeros under an unknown name: not read (the loader opens only
    # the members it knows), so loading costs what the model costs
    import tracemalloc

    from car_napari.texture import TextureModel

    good, arrays, header = model_file
    path = tmp_path / "padded.npz"
    np.savez_compressed(path, **arrays, padding=np.zeros(50_000_000, np.uint8))
    assert path.stat().st_size < 1_000_000
    tracemalloc.start()
    TextureModel.load(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 5_000_000


# ------------------------------------------------------------ output shapes
@functools.lru_cache
def _small_texture_model(levels):
    from car_napari.texture import TextureModel

    return TextureModel.fit(np.random.default_rng(1).random((64, 64, 3)), levels=levels,
                            neighbourhood=1)


@pytest.mark.parametrize("shape", [(1, 1), (1, 500), (64, 1), (2, 2), (2, 40), (3, 7)])
@pytest.mark.parametrize("levels", [1, 2, 3])
def test_tileable_synthesis_takes_any_size(shape, levels):
    """The README says any size: small tileable sizes (a pyramid level of
    side 1) were refused since sides under 2**(levels-1)+1 were."""
    model = _small_texture_model(levels)
    texture = model.synthesize(shape, seed=0, tileable=True)
    assert texture.shape == (*shape, 3) and np.isfinite(texture).all()
    np.testing.assert_array_equal(texture, model.synthesize(shape, seed=0, tileable=True))
    low, high = model.value_range
    assert np.all(texture >= low) and np.all(texture <= high)
    assert model.synthesize(shape, seed=0).shape == (*shape, 3)  # not tileable: any size


STACK = rng.random((3, 32, 32))


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(axis=5), ValueError, "axis=5 is out of range"),
    (dict(axis=1), ValueError, "axis=1 gives 32 versions .* Is axis right"),
    (dict(axis=True), TypeError, "axis must be an integer"),
    (dict(axis=1.0), TypeError, "axis must be an integer"),
    (dict(reference=np.inf), ValueError, "reference"),
    (dict(reference=3), ValueError, "reference"),
    (dict(kappa=10**400), ValueError, "kappa"),
    (dict(forgetting="0.9"), TypeError, "forgetting"),
    (dict(directions=5), TypeError, "directions"),
    (dict(keep_edges="no"), TypeError, "keep_edges"),
    (dict(neighbourhood=[[0, -1]]), ValueError, "not causal"),
])
def test_restore_multichannel_options(kwargs, error, match):
    from car_napari import restore_multichannel

    with pytest.raises(error, match=match):
        restore_multichannel(STACK, **kwargs)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(size=63), ValueError, r"size .* \[1, 31\]"),
    (dict(size=31), ValueError, "too large for the image of 32x32.*size <= "),
    (dict(size=8), ValueError, "odd"),
    (dict(size=np.nan), ValueError, "size"),
    (dict(size=np.inf), ValueError, "size"),
    (dict(size=True), TypeError, "size"),
    (dict(window=np.inf), ValueError, "window"),
    (dict(window=3), ValueError, "window"),
    (dict(window=200), ValueError, "larger than the image"),
])
def test_estimate_psf_size_is_bounded_up_front(kwargs, error, match):
    from car_napari import estimate_psf

    image = rng.random((32, 32))
    with pytest.raises(error, match=match):
        estimate_psf(image, image, **kwargs)
    if "image" not in match:  # what needs no image is checked before the images
        with pytest.raises(error, match=match):
            estimate_psf(image, "not an image", **kwargs)


# ---------------------------------------------------- options of the models
def _texture():
    from car_napari.texture import TextureModel

    return TextureModel.fit(rng.random((32, 32)), levels=1, neighbourhood=1)


def _dynamic():
    from car_napari.texture import DynamicTextureModel

    return DynamicTextureModel.fit(rng.random((3, 16, 16)), neighbourhood=1)


def _btf_fit(**kw):
    from car_napari.texture import BTFModel

    image = rng.random((16, 16))
    return BTFModel.fit(np.stack([image, image * 0.5]), levels=1, **kw)


def _call(name):
    """Entry points by name, for the table below (built lazily: fits cost)."""
    from car_napari import estimate_noise, illumination_invariants, synthesize, texture_features
    from car_napari.restoration import multichannel_context, psf_width
    from car_napari.texture import (
        collapse_pyramid,
        cumulative_histograms,
        laplacian_pyramid,
        minimum_size,
        temporal_context,
    )

    image = rng.random((32, 32))
    return {
        "synthesize": lambda **kw: synthesize(fit_car(GOOD, 1), (8, 8), **kw),
        "synthesize_shape": lambda shape: synthesize(fit_car(GOOD, 1), shape),
        "texture": lambda **kw: _texture().synthesize((8, 8), **kw),
        "texture_shape": lambda shape: _texture().synthesize(shape),
        "texture_ratio": lambda shape: _texture().compression_ratio(shape),
        "dynamic": lambda **kw: _dynamic().synthesize(**{"n_frames": 2, "shape": (8, 8), **kw}),
        "btf_fit": _btf_fit,
        "histograms": lambda **kw: cumulative_histograms(image[None], **kw),
        "pyramid": lambda **kw: laplacian_pyramid(image, **kw),
        "collapse": lambda **kw: collapse_pyramid(laplacian_pyramid(image, levels=2), **kw),
        "features": lambda **kw: texture_features(image, **kw),
        "minimum_size": lambda **kw: minimum_size(**kw),
        "invariants": lambda **kw: illumination_invariants(GOOD, 1, **kw),
        "noise": lambda **kw: estimate_noise(GOOD, **kw),
        "psf_width": lambda psf: psf_width(psf),
        "temporal_context": lambda d: temporal_context([[0, 1]], d),
        "multichannel_context": lambda **kw: multichannel_context([[0, 1]], **kw),
    }[name]


OPTION_CASES = [
    ("synthesize", dict(seed=-1), ValueError, "seed"),
    ("synthesize", dict(seed=1.5), TypeError, "seed"),
    ("synthesize", dict(margin=5000), ValueError, "margin"),
    ("synthesize_shape", ((10**6, 10**6),), ValueError, "too large"),
    ("synthesize_shape", ((2.5, 8),), ValueError, "shape"),
    ("synthesize_shape", ((np.nan, 8),), ValueError, "shape"),
    ("texture", dict(seed="0"), TypeError, "seed"),
    ("texture", dict(tileable="yes"), TypeError, "tileable"),
    ("texture_shape", ((10**5, 10**5),), ValueError, "too large"),
    ("texture_ratio", ((np.inf, 16),), ValueError, "input_shape"),
    ("texture_ratio", ((10**400, 16),), ValueError, "input_shape"),
    ("dynamic", dict(n_frames=np.inf), ValueError, "n_frames"),
    ("dynamic", dict(n_frames=0), ValueError, "n_frames"),
    ("dynamic", dict(burn_in=-5), ValueError, "burn_in"),
    ("dynamic", dict(burn_in=10**9), ValueError, "burn_in"),
    ("dynamic", dict(n_frames=10**5, shape=(512, 512)), ValueError, "memory"),
    ("btf_fit", dict(n_subspaces=np.inf), ValueError, "n_subspaces"),
    ("btf_fit", dict(n_subspaces=3), ValueError, "n_subspaces"),
    ("btf_fit", dict(seed=-1), ValueError, "seed"),
    ("histograms", dict(bins=10**9), ValueError, "bins"),
    ("pyramid", dict(levels=10**9), ValueError, "levels"),
    ("collapse", dict(wrap="no"), TypeError, "wrap"),
    ("features", dict(levels=10**9), ValueError, "levels"),
    ("minimum_size", dict(levels=10**9), ValueError, "levels"),
    ("invariants", dict(levels=10**9), ValueError, "levels"),
    ("noise", dict(channel_axis=1.5), TypeError, "channel_axis"),
    ("noise", dict(channel_axis=7), ValueError, "channel_axis"),
    ("noise", dict(channel_axis=10**400), ValueError, "channel_axis"),
    ("psf_width", (np.ones((3, 3, 3)),), ValueError, "2-D"),
    ("psf_width", (np.full((3, 3), np.nan),), ValueError, "NaN"),
    ("temporal_context", (10**9,), ValueError, "channels"),
    ("multichannel_context", dict(n_versions=10**9, reference=0), ValueError, "n_versions"),
    ("multichannel_context", dict(n_versions=3, reference=np.inf), ValueError, "reference"),
]


@pytest.mark.parametrize("name, args, error, match", OPTION_CASES,
                         ids=[f"{c[0]}-{c[1]}"[:60] for c in OPTION_CASES])
def test_numeric_options_are_checked(name, args, error, match):
    call = _call(name)
    with pytest.raises(error, match=match):
        call(**args) if isinstance(args, dict) else call(*args)


# ------------------------------------------------ degenerate textures, bands
def _degenerate_textures(n=16):
    i, j = np.mgrid[:n, :n]
    return {
        "ramp": j / n, "ramp_rows": i / n, "diagonal": (i + j) / (2 * n),
        "step": (j >= n // 2) * 1.0, "stripes": (i % 2) * 1.0,
        "checkerboard": ((i + j) % 2) * 1.0,
        "two_valued": (rng.random((n, n)) > 0.5) * 1.0,
        "colour_ramp": np.stack([j / n, i / n, (i + j) / (2 * n)], -1),
    }


@pytest.mark.parametrize("kind", list(_degenerate_textures()))
def test_texture_of_a_degenerate_image_synthesises(kind):
    # ramps and step edges fit unit roots (radius 1 - 1e-12) that the float32
    # rounding made >= 1: synthesis then refused the model it was given
    from car_napari.texture import TextureModel

    image = _degenerate_textures()[kind]
    model = TextureModel.fit(image, levels=1)
    for tileable in (False, True):
        out = model.synthesize((16, 16), seed=0, tileable=tileable)
        assert out.shape == image.shape and np.isfinite(out).all()


@pytest.mark.parametrize("bands, error, match", [
    ([np.ones((8, 8)), np.ones((8, 8))], ValueError, r"bands\[1\] .* needs \(4, 4\)"),
    ([np.ones((8, 8)), np.ones((2, 2))], ValueError, r"bands\[1\] .* needs \(4, 4\)"),
    ([np.ones((8, 8, 3)), np.ones((4, 4, 2))], ValueError, r"bands\[1\] .* \(4, 4, 3\)"),
    ([np.ones((8, 8)), np.ones((0, 0))], ValueError, r"bands\[1\] is empty"),
    ([np.ones((8, 8)), np.full((4, 4), np.nan)], ValueError, r"bands\[1\] .* NaN"),
    ([np.ones((8, 8), complex)], TypeError, r"bands\[0\] has dtype complex"),
    (np.ones((8, 8)), TypeError, "bands must be a list"),
    ([], ValueError, "bands is empty"),
])
def test_collapse_refuses_what_is_not_a_pyramid(bands, error, match):
    from car_napari.texture import collapse_pyramid

    with pytest.raises(error, match=match):
        collapse_pyramid(bands)


@pytest.mark.parametrize("kind", ["ramp", "ramp_rows", "diagonal", "step", "stripes",
                                  "checkerboard"])
def test_features_of_a_degenerate_image_are_finite(kind):
    # a singular data matrix (or its one-pixel prior) raised LinAlgError
    from car_napari import rank, texture_features

    image = _degenerate_textures(32)[kind]
    assert np.isfinite(illumination_invariants(image, 1)).all()
    assert np.isfinite(texture_features(image, levels=1, neighbourhood=1)).all()
    ranking = rank(image, [GOOD[..., 0], GOOD[..., 1]], levels=1, neighbourhood=1)
    assert np.isfinite(ranking.distances).all()


def test_texture_of_equal_channels_synthesises():
    # a grey texture stored as RGB: a singular innovation covariance, whose
    # Cholesky factor synthesis took (LinAlgError)
    from car_napari.texture import BTFModel, TextureModel

    image = np.dstack([GOOD[..., 0]] * 3)
    out = TextureModel.fit(image, levels=1).synthesize((16, 16), seed=0)
    assert out.shape == (16, 16, 3) and np.isfinite(out).all()
    out = BTFModel.fit([image, image], levels=1, n_subspaces=1).synthesize((8, 8), seed=0)
    assert np.isfinite(out).all()


@pytest.mark.parametrize("call, error, match", [
    (lambda: _tiled(tile=np.inf), ValueError, "tile"),
    (lambda: _tiled(tile=np.nan), ValueError, "tile"),
    (lambda: _tiled(window=np.inf), ValueError, "window"),
    (lambda: _tiled(window=1e300), ValueError, "window"),
    (lambda: _tiled(window=10**30), ValueError, "window"),
    (lambda: _tiled(window=None), TypeError, "window"),
    (lambda: _tiled(noise=[1.0, 2.0]), ValueError, "noise"),
    (lambda: _tiled(out=np.zeros((16, 16))), ValueError, "out"),
    (lambda: _tiled(out=3.0), TypeError, "out"),
    (lambda: _halo(window=np.inf), ValueError, "window"),
    (lambda: _halo(reach=-np.inf), ValueError, "reach"),
    (lambda: _halo(reach=None), TypeError, "reach"),
])
def test_tiled_restoration_options(call, error, match):
    # OverflowError, "cannot convert float NaN to integer" or an error of the
    # writes into out before
    with pytest.raises(error, match=match):
        call()


def _tiled(**kw):
    from car_napari.restoration import restore_tiled

    return restore_tiled(GOOD[..., 0], **{"tile": 16, **kw})


def _halo(**kw):
    from car_napari.restoration import tile_halo

    return tile_halo(**kw)


@pytest.mark.parametrize("image", [
    np.dstack([GOOD[..., :3], np.full(GOOD.shape[:2], 1.0)]),  # RGBA, opaque: alpha is flat
    np.full((40, 40), 0.5),
], ids=["rgba", "constant"])
def test_restore_tiled_refuses_a_flat_channel_allocating_little(image):
    # the noise pass's histogram was dense, 2**20 bins per channel (8 MB each,
    # ~75 MB with its cumulative sums for RGBA), allocated before the check
    import tracemalloc

    from car_napari.restoration import restore_tiled

    with pytest.raises(ValueError, match="constant in channel"):
        restore_tiled(image)  # compiles the kernels: not measured
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match="constant in channel"):
            restore_tiled(image)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4e6


def test_restore_tiled_takes_a_nested_list():
    from car_napari.restoration import restore_tiled

    image = GOOD[..., 0]
    np.testing.assert_array_equal(restore_tiled(image.tolist(), tile=16),
                                  restore_tiled(image, tile=16))


@pytest.mark.parametrize("orders, error", [(3, TypeError), (None, TypeError), ("12", TypeError),
                                           (range(0, 3), ValueError), ([1, "x"], ValueError)])
def test_select_support_orders(orders, error):
    with pytest.raises(error, match="orders"):
        select_support(GOOD, orders=orders)


@pytest.mark.parametrize("path, error", [(0, TypeError), (1, TypeError), (True, TypeError),
                                         (-1, TypeError), ("", ValueError)])
def test_model_paths_are_file_names(path, error):
    # an int was taken for a file descriptor: load(0) waited on stdin,
    # load(True) read and closed stdout
    from car_napari.texture import TextureModel

    with pytest.raises(error, match="path"):
        TextureModel.load(path)
    with pytest.raises(error, match="path"):
        _texture().save(path)


@pytest.mark.parametrize("offsets, n_channels, match", [
    (np.inf, 1, "offsets"), ([1, 2], 1, "offsets"), ([[1e300, 1]], 1, "offsets"),
    ([[0.5, 1]], 1, "offsets"), ([[0, 1]], np.inf, "n_channels"), ([[0, 1]], -1, "n_channels"),
    ([[0, 1]], 10**30, "n_channels"),
])
def test_context_checks_offsets_and_channels(offsets, n_channels, match):
    # OverflowError, IndexError or "Maximum allowed dimension exceeded" before
    from car_napari import Context

    with pytest.raises(ValueError, match=match):
        Context.spatial(offsets, n_channels)


@pytest.mark.parametrize("threads, error", [(np.inf, ValueError), (np.nan, ValueError),
                                            (1.5, ValueError), ([1], TypeError)])
def test_limited_blas_threads(threads, error):
    from car_napari import limited_blas

    with pytest.raises(error, match="threads"):
        with limited_blas(threads):
            pass


@pytest.mark.parametrize("path, image, error, match", [
    ("{tmp}", np.zeros((4, 4), np.uint8), ValueError, "folder"),
    ("", np.zeros((4, 4), np.uint8), ValueError, "path is empty"),
    (3, np.zeros((4, 4), np.uint8), TypeError, "path"),
    ("{tmp}/a.tif", None, TypeError, "object"),
    ("{tmp}/a.tif", np.float64(3.0), ValueError, "shape"),
    ("{tmp}/a.tif", np.ones((4, 4), complex), TypeError, "complex"),
])
def test_write_image_refuses_what_no_file_holds(tmp_path, path, image, error, match):
    # IndexError from tifffile for a scalar; OSError "ImageIO does not support
    # reading folders" when writing to a folder
    from car_napari.io import write_image

    path = path.format(tmp=tmp_path) if isinstance(path, str) else path
    with pytest.raises(error, match=match):
        write_image(path, image)


_SEGMENTS = np.repeat([[1] * 16 + [2] * 16], 32, 0)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(split_sigmas=3.0), TypeError, "split_sigmas"),
    (dict(split_sigmas=(-1.0,)), ValueError, "split_sigmas"),
    (dict(split_delta="x"), TypeError, "split_delta"),
    (dict(split_delta=[1, 2]), TypeError, "split_delta"),
    (dict(radius_range=(130.0, 20.0)), ValueError, "radius_range"),
    (dict(split="no"), TypeError, "split"),
])
def test_filter_regions_options(kwargs, error, match):
    # "'float' object is not iterable", UFuncTypeError or a NumPy broadcast
    # error from deep in the candidates before
    from car_napari.mammography import filter_regions

    with pytest.raises(error, match=match):
        filter_regions(GOOD[..., 0], _SEGMENTS, **kwargs)


@pytest.mark.parametrize("labels, error", [
    (_SEGMENTS * 1.0, TypeError), (np.full((4, 4), "a"), TypeError),
    (np.zeros((0, 0), int), ValueError), (-_SEGMENTS, ValueError),
])
def test_region_outlines_labels(labels, error):
    # float labels: "'numpy.float64' object cannot be interpreted as an
    # integer" from scipy; strings: UFuncTypeError; empty: a NumPy reduction
    from car_napari.mammography import region_outlines

    with pytest.raises(error, match="labels"):
        region_outlines(labels)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(pool=3), TypeError, "pool"), (dict(pool=(0,)), ValueError, "pool"),
    (dict(segment_options=3), TypeError, "segment_options"),
    (dict(segment_options={"nope": 1}), TypeError, "segment_options"),
])
def test_segment_breast_options(kwargs, error, match):
    # "object of type 'int' has no len()" or "argument after ** must be a
    # mapping" before
    from car_napari import segment_breast

    with pytest.raises(error, match=match):
        segment_breast(GOOD[..., 0], levels=1, n_init=2, **kwargs)


@pytest.mark.parametrize("call, error, match", [
    (lambda: _select_marks(threshold="x"), TypeError, "threshold"),
    (lambda: _select_marks(threshold=[1, 2]), TypeError, "threshold"),
    (lambda: _select_marks(threshold=np.nan), ValueError, "threshold"),
    (lambda: __import__("car_napari").drain(3), TypeError, "job"),
    (lambda: __import__("car_napari").drain(iter([]), on_progress=3), TypeError, "on_progress"),
    (lambda: __import__("car_napari.io").io.read_dicom(""), ValueError, "path"),
    (lambda: __import__("car_napari.io").io.read_dicom(0), TypeError, "path"),
])
def test_small_entry_points_check_their_arguments(call, error, match):
    # UFuncTypeError or a NumPy broadcast error (select_marks), "'int' object
    # is not an iterator" (drain), "cannot read  as DICOM" before
    with pytest.raises(error, match=match):
        call()


def _select_marks(**kw):
    from car_napari.mammography import MammogramROIs, select_marks

    labels = np.array([[1, 1, 2, 3]], np.int32)
    table = {"label": np.array([1, 2, 3]), "score": np.array([0.9, 0.5, 0.1])}
    return select_marks(MammogramROIs(labels, table), **kw)


def test_write_image_needs_a_suffix(tmp_path):
    # "cannot write ...: None. Write a .tif instead." before
    from car_napari.io import write_image

    with pytest.raises(ValueError, match="suffix"):
        write_image(tmp_path / "image", np.zeros((4, 4), np.uint8))


def _edited_model(**changes):
    model = fit_car(GOOD[..., 0], 1)
    for key, value in changes.items():
        setattr(model, key, value)
    return model


@pytest.mark.parametrize("changes, match", [
    (dict(gamma=np.full((1, 2), np.nan)), "gamma holds NaN"),
    (dict(sigma=np.full((1, 1), np.inf)), "sigma holds NaN"),
    (dict(mean=np.array([np.nan])), "mean holds NaN"),
    (dict(gamma=np.zeros((1, 1))), "gamma has shape"),
    (dict(offsets=np.array([[0, 1], [5000, 0]])), "reach 5000"),
    (dict(offsets=np.array([[0, -1], [1, 0]])), "not causal"),
    (dict(gamma=np.full((1, 2), 1e200)), "magnitude"),  # predict overflowed to inf
    (dict(gamma="x"), "numeric arrays"),
])
@pytest.mark.parametrize("use", ["radius", "synthesize", "predict"])
def test_edited_models_are_refused(changes, match, use):
    # NaN gamma: LinAlgError (radius, synthesis) or NaN predictions; NaN mean:
    # NaN synthesis; an offset of 5000: the stability test ran for minutes
    from car_napari import spectral_radius, synthesize

    model = _edited_model(**changes)
    call = {"radius": lambda: spectral_radius(model),
            "synthesize": lambda: synthesize(model, (8, 8), seed=0),
            "predict": lambda: predict(model, GOOD[..., 0])}[use]
    with pytest.raises(ValueError, match=match):
        call()


# --- segmentation and inpainting: options, shapes and magnitudes ------------------------

def _segmentation_calls():
    from car_napari.segmentation import local_features, pseudo_colour, segment

    image = np.random.default_rng(1).random((64, 64))
    result = segment(image, levels=1, n_init=4)
    return [
        (lambda: local_features(image, levels=10**30), ValueError, "levels"),
        (lambda: segment(image, levels=2**62), ValueError, "levels"),
        (lambda: local_features(image, forgetting=np.nan), ValueError, "forgetting"),
        (lambda: local_features(image, forgetting=0.0), ValueError, "forgetting"),
        (lambda: local_features(image, smoothing=np.inf), ValueError, "smoothing"),
        (lambda: local_features(image, mean_smoothing=1e300), ValueError, "mean_smoothing"),
        (lambda: local_features(image, clip=np.nan), ValueError, "clip"),
        (lambda: local_features(image, components=None), TypeError, "components"),
        (lambda: local_features(image, level_smoothing="x"), ValueError, "level_smoothing"),
        (lambda: result.labels_at("x"), TypeError, "k"),
        (lambda: result.mixture_at(np.nan), ValueError, "k"),
        (lambda: result.labels_at(2, threshold=2.0), ValueError, "threshold"),
        (lambda: pseudo_colour(None), ValueError, "grey"),
        (lambda: pseudo_colour(np.ones(5)), ValueError, "grey"),
        (lambda: pseudo_colour(image, gammas=(-1, 2)), ValueError, "gammas"),
        (lambda: local_features(image, seed=-1), ValueError, "seed"),
        (lambda: local_features(image, neighbourhood=9), ValueError, "neighbourhood"),
    ]


def _inpainting_calls():
    from car_napari.inpainting import detect_scratches, estimate_motion, fit_mask, inpaint

    frame = np.random.default_rng(2).random((48, 48))
    mask = np.zeros((48, 48), bool)
    mask[10:30, 20:22] = True
    return [
        (lambda: inpaint(frame, mask, neighbourhood=np.inf), ValueError, "neighbourhood"),
        (lambda: inpaint(frame, mask, method="scans", neighbourhood=1e300), ValueError,
         "neighbourhood"),
        (lambda: detect_scratches(frame, line_width=np.inf), ValueError, "line_width"),
        (lambda: detect_scratches(frame, line_length="3"), TypeError, "line_length"),
        (lambda: estimate_motion(frame, frame, radius=10**30), ValueError, "radius"),
        (lambda: estimate_motion(frame, frame, iterations=np.inf), ValueError, "iterations"),
        (lambda: fit_mask(mask, (10**6, 10**6)), ValueError, "shape"),
        (lambda: fit_mask(mask, 5), ValueError, "shape"),
        (lambda: fit_mask(mask, (48, 48), channel_axis=np.nan), TypeError, "channel_axis"),
        (lambda: detect_scratches(frame, kinds=3), TypeError, "kinds"),
        (lambda: detect_scratches(frame, blotch_threshold=[1]), TypeError, "blotch_threshold"),
        (lambda: inpaint(frame, mask, forgetting=None), TypeError, "forgetting"),
        (lambda: inpaint(frame, mask, interleave=[2]), TypeError, "interleave"),
        (lambda: inpaint(frame, mask, halo=[0]), TypeError, "halo"),
    ]


@pytest.mark.parametrize("case", range(17))
def test_segmentation_options_are_checked_first(case):
    call, error, match = _segmentation_calls()[case]
    with pytest.raises(error, match=match):
        call()


@pytest.mark.parametrize("case", range(14))
def test_inpainting_options_are_checked_first(case):
    call, error, match = _inpainting_calls()[case]
    with pytest.raises(error, match=match):
        call()


@pytest.mark.parametrize("scale, shift", [(1e300, 0.0), (1e-300, 0.0), (1.0, 1e10)])
def test_inpaint_of_any_finite_magnitude_is_the_unit_fill_rescaled(scale, shift):
    """The fill is affine-equivariant: an image near 1e300, 1e-300 or 1e10 +
    [0, 1] is filled as the unit one (once 'Factor is exactly singular')."""
    from skimage import data as skdata

    from car_napari.inpainting import inpaint

    frame = skdata.camera()[:64, :64] / 255.0
    mask = np.zeros(frame.shape, bool)
    mask[16:48, 30:33] = True
    unit = inpaint(frame, mask)
    image = frame * scale + shift
    got = inpaint(image, mask)
    assert np.isfinite(got).all()
    # 1e10 + x holds x to about 2e-6
    tolerance = 1e-9 if shift == 0 else 1e-5
    np.testing.assert_allclose((got[mask] - shift) / scale, unit[mask], rtol=0,
                               atol=tolerance)


@pytest.mark.parametrize("offsets, error, match", [
    ([[0, -1]], ValueError, r"^offsets \[\(0, -1\)\] are not causal"),
    ([[1.5, 0]], ValueError, r"^offsets must be integers"),
    ([1, 2, 3], ValueError, r"^offsets must be a non-empty \(eta, 2\) array.*or an \(eta, 2\)"),
    ([[1, 0], [1, 0]], ValueError, r"^offsets contain duplicates"),
    ([[1e300, 0]], ValueError, r"^offsets must be at most"),  # was wrapped to int64's min
    (np.array([[5, -2**63]]), ValueError, r"^offsets must be at most"),
    ("x", ValueError, r"^offsets 'x'.*an order \(an int from 1 to 30\)"),
    (0, ValueError, r"^offsets order must be between 1 and 30"),
])
@pytest.mark.parametrize("context", ["temporal", "multichannel"])
def test_contexts_name_their_offsets(context, offsets, error, match):
    from car_napari.restoration import multichannel_context
    from car_napari.texture import temporal_context

    call = {"temporal": lambda: temporal_context(offsets, 1),
            "multichannel": lambda: multichannel_context(offsets, 2, 0)}[context]
    with pytest.raises(error, match=match):
        call()


def test_neighbourhood_messages_still_name_the_neighbourhood():
    from car_napari.model.neighbourhood import as_offsets

    with pytest.raises(ValueError, match=r"^neighbourhood offsets \[\(0, -1\)\] are not"):
        as_offsets([[0, -1]])


def _channel_axis_calls():
    import car_napari as car
    from car_napari import mammography, restoration, texture

    img = np.random.default_rng(0).random((24, 24))
    clip = np.stack([img, img[::-1]])
    mask = np.zeros((24, 24), bool)
    mask[5:7, 5:9] = True
    return {
        "restore_multichannel": lambda a: car.restore_multichannel(clip, channel_axis=a),
        "sharpness": lambda a: restoration.sharpness(clip, channel_axis=a),
        "restore_tiled": lambda a: restoration.restore_tiled(img, channel_axis=a),
        "detect_scratches": lambda a: car.detect_scratches(img, channel_axis=a),
        "inpaint": lambda a: car.inpaint(img, mask, channel_axis=a),
        "rank": lambda a: car.rank(img, [img, img], channel_axis=a),
        "cumulative_histograms": lambda a: texture.cumulative_histograms(clip, channel_axis=a),
        "fit_dynamic_texture": lambda a: texture.DynamicTextureModel.fit(
            np.stack([img, img * 0.9, img * 0.8]), channel_axis=a),
        "TextureModel.fit": lambda a: texture.TextureModel.fit(
            np.random.default_rng(0).random((64, 64)), channel_axis=a),
        "detect_breast": lambda a: car.detect_breast(img, channel_axis=a),
        "filter_regions": lambda a: mammography.filter_regions(
            img, (img > 0.5).astype(np.int32) + 1, channel_axis=a),
    }


@pytest.mark.parametrize("name", sorted(_channel_axis_calls()))
@pytest.mark.parametrize("axis", [np.nan, np.inf, -1.0, True])
def test_channel_axis_checked_on_a_grey_image(name, axis):
    # a 2-D image ignores its channel axis; a NaN one was accepted there
    with pytest.raises(TypeError, match="channel_axis must be None"):
        _channel_axis_calls()[name](axis)


def _nan_mask_calls():
    import car_napari as car

    frame = np.random.default_rng(3).random((48, 48))
    mask = np.zeros((48, 48))
    mask[10:30, 20:22] = 1.0
    mask[0, 0] = np.nan
    breast = np.ones((64, 64))
    breast[5, 5] = np.nan
    mammogram = np.random.default_rng(4).random((64, 64))
    return [
        (lambda: car.inpaint(frame, mask), mask),
        (lambda: car.inpaint(np.stack([frame, frame]), np.stack([mask, mask]),
                             channel_axis=None), mask),
        (lambda: car.fit_mask(mask, (96, 96)), mask),
        (lambda: car.segment(frame, mask=mask, levels=1, n_init=4), mask),
        (lambda: car.estimate_motion(frame, frame, mask=mask), mask),
        (lambda: car.detect_mammogram_rois(mammogram, breast=breast), breast),
        (lambda: car.segment_breast(mammogram, breast=breast), breast),
    ]


@pytest.mark.parametrize("case", range(7))
def test_nan_in_a_mask_is_refused(case):
    """A NaN is non-zero: it used to be read as True without a word."""
    call, mask = _nan_mask_calls()[case]
    before = mask.copy()
    with pytest.raises(ValueError, match=r"contains \d NaN value.*Replace them"):
        call()
    np.testing.assert_array_equal(mask, before)  # the input is untouched


def test_check_mask_keeps_numeric_and_boolean_masks():
    from car_napari._validation import check_mask

    for mask in (np.array([[0, 2]]), np.array([[True, False]]), np.array([[0.0, 0.5]]),
                 [[0, 1]]):
        np.testing.assert_array_equal(check_mask(mask), np.asarray(mask))
    with pytest.raises(TypeError, match="boolean or numeric"):
        check_mask(np.array([["a"]]))
    with pytest.raises(ValueError, match="2 NaN values"):
        check_mask(np.array([np.nan, np.nan, 1.0]), "breast")


@pytest.mark.parametrize("option", ["n_segments", "n_init", "levels", "min_area", "seed"])
def test_segment_refuses_float_counts(option):
    """2.0 is refused as illumination_invariants(levels=2.0) refuses it."""
    from car_napari import segment

    image = np.random.default_rng(5).random((32, 32))
    with pytest.raises(ValueError, match=f"{option} must be an integer .*not a float"):
        segment(image, **{option: 2.0})
    with pytest.raises(ValueError, match="levels"):
        illumination_invariants(image, levels=2.0)


def test_save_refuses_an_existing_folder(model_file, tmp_path):
    from car_napari import TextureModel

    model = TextureModel.load(model_file[0])
    folder = tmp_path / "models"
    folder.mkdir()
    with pytest.raises(IsADirectoryError, match="existing folder.*file name"):
        model.save(folder)
    with pytest.raises(IsADirectoryError, match="existing folder"):
        model.save(str(folder))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["models"]  # no models.npz
    model.save(tmp_path / "fresh")  # a new name still gets numpy's .npz
    assert (tmp_path / "fresh.npz").is_file()


@pytest.mark.parametrize("shape, kwargs", [
    ((2, 2), {}),
    ((2, 2), {"estimator": "recursive"}),
    ((3, 3), {}),
    ((7, 7), {"neighbourhood": [[5, 5]]}),
    ((7, 7), {"neighbourhood": [[3, 3]]}),
    ((5, 5, 3), {"neighbourhood": 2}),
    ((6, 6), {"neighbourhood": 5, "estimator": "recursive"}),
    ((2, 32), {"neighbourhood": 2, "estimator": "recursive", "directions": ["right"]}),
])
def test_restore_refuses_images_too_small_to_learn_from(shape, kwargs):
    """Fewer pixels to learn from than parameters + 2 (fit_car's rule): the
    models were the prior alone and the image came back unchanged or moved
    to its mean."""
    image = np.random.default_rng(6).random(shape)
    before = image.copy()
    with pytest.raises(ValueError, match="too small for this neighbourhood.*needs at least"):
        restore(image, **kwargs)
    np.testing.assert_array_equal(image, before)


def test_restore_takes_images_just_large_enough():
    rng = np.random.default_rng(7)
    # windowed, order 1 grey: 3 parameters (2 neighbours, the intercept) need 5 pixels
    # at least a row and a column from every edge
    for image in (rng.random((4, 5)), rng.random((5, 4))):
        assert np.isfinite(restore(image)).all()
    # recursive, order 1 grey: 2 parameters need 4 pixels in every scan
    assert np.isfinite(restore(rng.random((3, 3)), estimator="recursive")).all()


def test_restore_tiled_refuses_what_restore_refuses():
    from car_napari.restoration import restore_tiled

    with pytest.raises(ValueError, match="too small for this neighbourhood"):
        restore_tiled(np.random.default_rng(8).random((7, 7)), neighbourhood=[[5, 5]])


@pytest.mark.parametrize("shape", [(1, 64), (64, 1), (2, 64), (64, 6), (1, 64, 3)])
def test_detect_scratches_sizes_are_consistent(shape):
    """Lines are vertical: at least 3 rows and more than 2 * line_width
    columns, said in the message (1x64 used to pass, 64x1 not)."""
    from car_napari import detect_scratches

    frame = np.random.default_rng(9).random(shape)
    with pytest.raises(ValueError, match=r"at least 3 rows and more than 6 columns"):
        detect_scratches(frame)
    assert detect_scratches(frame, kinds="blotch").shape == shape[:2]
    assert detect_scratches(np.random.default_rng(9).random((3, 7))).shape == (3, 7)


def _forgetting_calls():
    from car_napari import inpaint, local_features, restore_multichannel, segment

    image = np.random.default_rng(10).random((32, 32))
    mask = np.zeros((32, 32), bool)
    mask[10:20, 15] = True
    return [
        lambda f: local_parameters(image, 2, forgetting=f),
        lambda f: restore(image, estimator="recursive", forgetting=f),
        lambda f: restore_multichannel(np.stack([image, image * 0.9 + 0.05]), forgetting=f),
        lambda f: segment(image, forgetting=f),
        lambda f: local_features(image, forgetting=f),
        lambda f: inpaint(image, mask, forgetting=f),
    ]


@pytest.mark.parametrize("case", range(6))
@pytest.mark.parametrize("forgetting", [1e-300, 1e-100, 1e-10, 0.3, 0.49])
def test_tiny_forgetting_is_refused(case, forgetting):
    """local_parameters(forgetting=1e-300) was 97 % NaN without a word."""
    with pytest.raises(ValueError, match=r"forgetting must be in \[0.5, 1\].*window"):
        _forgetting_calls()[case](forgetting)


def test_smallest_forgetting_gives_finite_parameters():
    image = np.random.default_rng(11).random((32, 32))
    assert np.isfinite(local_parameters(image, 2, forgetting=0.5)).all()
    with pytest.raises(TypeError, match="forgetting"):
        local_parameters(image, 2, forgetting="0.9")


def test_predict_refuses_a_loaded_band_model(model_file):
    """A loaded TextureModel's band models keep no vx: predict gave an all-NaN
    log density without a word."""
    from car_napari import TextureModel

    image = np.random.default_rng(1).random((32, 32, 3))
    loaded = TextureModel.load(model_file[0])
    with pytest.raises(ValueError, match="no data statistics.*TextureModel read from a file"):
        predict(loaded.models[0], image)
    fitted = TextureModel.fit(image, levels=2, neighbourhood=1)  # these predict
    assert np.isfinite(predict(fitted.models[0], image).log_density[1:, 1:-1]).all()
    model = fit_car(GOOD[..., 0], 1)
    model.lam = np.full((1, 1), np.nan)
    with pytest.raises(ValueError, match="no data statistics"):
        predict(model, GOOD[..., 0])


def test_rank_of_huge_feature_vectors_is_exact():
    """Features near 1e200 overflowed the gallery's spread to inf: distances
    [0, 0] with a warning. Scaled by a power of two, they are those of the
    unit vectors; ordinary ones are unchanged."""
    import warnings

    from car_napari import rank

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        huge = rank(np.ones(15), [np.full(15, 1e200), np.full(15, -1e200)])
        unit = rank(np.ones(15) * 1e-200, [np.full(15, 1.0), np.full(15, -1.0)])
        np.testing.assert_array_equal(huge.distances, unit.distances)
        np.testing.assert_array_equal(huge.distances, [15.0, 15.0])
        np.testing.assert_array_equal(
            rank(np.ones(15), [np.full(15, 1.0), np.full(15, -1.0)]).distances, [0.0, 30.0])
        with pytest.raises(ValueError, match="distances overflow"):
            rank(np.full(15, 1e300), [np.full(15, 1.0), np.full(15, 1.0 + 1e-10)])


@pytest.mark.parametrize("estimator", ["windowed", "recursive"])
def test_restore_refuses_a_noise_whose_square_overflows(estimator):
    import warnings

    image = np.random.default_rng(12).random((32, 32, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # was "overflow encountered in square"
        with pytest.raises(ValueError, match="noise 1e\\+300 is too large: at most 1e\\+150"):
            restore(image, noise=1e300, estimator=estimator)
        with pytest.raises(ValueError, match="noise .* too large"):
            restore(image * 2.0**-40, noise=1e140, estimator=estimator)  # scaled for the work
        big = restore(image, noise=1e150, estimator=estimator)  # every pixel noise: finite
        assert np.isfinite(big).all()


def test_restore_tiled_refuses_a_huge_noise():
    from car_napari.restoration import restore_tiled

    with pytest.raises(ValueError, match="noise .* too large"):
        restore_tiled(np.random.default_rng(13).random((64, 64)), noise=1e300)


# --- constant input: refused clearly, or finite results ----------------------------------
_FLAT, _FLAT3 = np.full((48, 48), 0.5), np.full((48, 48, 3), 0.25)
_FLAT_CLIP = np.full((4, 48, 48), 0.5)
_TEXTURE = np.random.default_rng(14).random((48, 48))


def _constant_calls():
    import car_napari as car

    mask = np.zeros((48, 48), bool)
    mask[10:20, 20:22] = True
    grey_model, colour_model = fit_car(_TEXTURE, 2), fit_car(GOOD, 2)
    return {
        "fit_car": lambda im: car.fit_car(im, 2),
        "select_support": lambda im: car.select_support(im),
        "local_parameters": lambda im: car.local_parameters(im, 2),
        "illumination_invariants": lambda im: car.illumination_invariants(im),
        # NaN only where the neighbourhood leaves the image, as for any image
        "predict": lambda im: [a[2:, 2:-2] for a in car.predict(
            colour_model if im.ndim == 3 else grey_model, im)],
        "local_features": lambda im: car.local_features(im),
        "segment": lambda im: car.segment(im),
        "detect_breast": lambda im: car.detect_breast(im),
        "detect_mammogram_rois": lambda im: car.detect_mammogram_rois(im),
        "segment_breast": lambda im: car.segment_breast(im),
        "estimate_noise": lambda im: car.estimate_noise(im),
        "estimate_psf_observed": lambda im: car.estimate_psf(
            im, np.broadcast_to(_TEXTURE[..., None], im.shape) if im.ndim == 3 else _TEXTURE),
        "estimate_psf_restored": lambda im: car.estimate_psf(im, im),
        "restore": lambda im: car.restore(im),
        "restore_multichannel": lambda im: car.restore_multichannel(np.stack([im, im])),
        "detect_scratches": lambda im: car.detect_scratches(im),
        "detect_scratches_clip": lambda im: car.detect_scratches(
            np.stack([im] * 4), channel_axis=-1 if im.ndim == 3 else None),
        "estimate_motion": lambda im: car.estimate_motion(im, im),
        "compensate_motion": lambda im: car.compensate_motion(
            np.stack([im] * 3), channel_axis=-1 if im.ndim == 3 else None),
        "inpaint": lambda im: car.inpaint(im, mask),
        "inpaint_clip": lambda im: car.inpaint(
            np.stack([im] * 3), mask, channel_axis=-1 if im.ndim == 3 else None),
        "fit_texture": lambda im: car.TextureModel.fit(im, levels=1),
        "fit_dynamic_texture": lambda im: car.DynamicTextureModel.fit(
            np.stack([im] * 4), channel_axis=-1 if im.ndim == 3 else None),
        "rank": lambda im: car.rank(im, [im, GOOD if im.ndim == 3 else _TEXTURE]),
        "texture_features": lambda im: car.texture_features(im),
    }


def _finite(value):
    """Every float array or number in ``value`` (arrays, tuples, lists,
    dataclasses and other objects with a __dict__, dicts) finite."""
    if value is None or isinstance(value, (str, bool, int)):
        return True
    if isinstance(value, (float, np.floating)):
        return bool(np.isfinite(value))
    if isinstance(value, np.ndarray):
        return value.dtype.kind not in "fc" or bool(np.isfinite(value).all())
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, (tuple, list)):
        return all(_finite(v) for v in value)
    if hasattr(value, "__dict__"):
        return all(_finite(v) for v in vars(value).values())
    return True


_ACCEPTS_CONSTANT = {"predict", "estimate_noise", "estimate_psf_observed",
                     "detect_scratches", "detect_scratches_clip", "estimate_motion",
                     "compensate_motion", "inpaint", "inpaint_clip"}


@pytest.mark.parametrize("image", [_FLAT, _FLAT3], ids=["grey", "colour"])
@pytest.mark.parametrize("name", [
    "fit_car", "select_support", "local_parameters", "illumination_invariants", "predict",
    "local_features", "segment", "detect_breast", "detect_mammogram_rois", "segment_breast",
    "estimate_noise", "estimate_psf_observed", "estimate_psf_restored", "restore",
    "restore_multichannel", "detect_scratches", "detect_scratches_clip", "estimate_motion",
    "compensate_motion", "inpaint", "inpaint_clip", "fit_texture", "fit_dynamic_texture",
    "rank", "texture_features"])
def test_no_public_function_returns_nan_on_constant_input(name, image):
    """Constant input is refused with a message that says so, or accepted
    with finite results (predict, inpaint, detect_scratches, estimate_psf of
    a flat observation, ...: their Notes say what they give)."""
    import warnings

    if image.ndim == 3 and name in ("detect_breast", "detect_mammogram_rois",
                                    "segment_breast"):
        pytest.skip("mammograms are grey")
    before = image.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no 'invalid value' on the way
        try:
            result = _constant_calls()[name](image)
        except ValueError as exc:
            assert name not in _ACCEPTS_CONSTANT, f"{name} refused constant input: {exc}"
            assert re.search("constant|flat|no breast", str(exc)), str(exc)
        else:
            assert name in _ACCEPTS_CONSTANT, f"{name} now accepts constant input"
            assert _finite(result), f"{name} returned NaN or inf on constant input"
    np.testing.assert_array_equal(image, before)
