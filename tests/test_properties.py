"""Property-based tests of the model core: on any finite image in the
documented domain the result is finite and of the documented shape, otherwise
a ValueError or TypeError; the input is never modified; the same call gives
the same result. Seeded and bounded (a few seconds each), so CI stays short."""

import copy

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, event, given, seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra.numpy import arrays  # noqa: E402

from car_napari import (  # noqa: E402
    fit_car,
    illumination_invariants,
    local_parameters,
    predict,
    select_support,
)

PROPERTY = settings(max_examples=40, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])

# finite values of any magnitude the models accept, and a few they reject
_VALUES = st.one_of(
    st.floats(-1.0, 1.0, width=64),
    st.floats(-1e6, 1e6, width=64),
    st.sampled_from([0.0, 1.0, 1e-200, 1e200, -1e149, 5e-151]),
)


@st.composite
def images(draw, low=1, high=24):
    """Grey (H, W) or colour (H, W, C) float images, ``low`` to ``high``
    pixels a side, noise, ramps, constants, or a few distinct values."""
    h, w = draw(st.integers(low, high)), draw(st.integers(low, high))
    channels = draw(st.sampled_from([None, 1, 2, 3]))
    shape = (h, w) if channels is None else (h, w, channels)
    kind = draw(st.sampled_from(["noise", "values", "ramp", "constant"]))
    if kind == "values":
        return draw(arrays(np.float64, shape, elements=_VALUES))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    scale = draw(st.sampled_from([1.0, 255.0, 1e-3, 1e120]))
    if kind == "noise":
        return rng.random(shape) * scale
    if kind == "ramp":
        i, j = np.indices((h, w), dtype=float)
        ramp = (i * draw(st.floats(-2, 2)) + j) * scale
        return ramp if channels is None else np.repeat(ramp[..., None], channels, axis=2)
    return np.full(shape, scale)


def _check(call, image):
    """Finite result or a clear error; input untouched; deterministic."""
    before = image.copy()
    try:
        first = call(image)
    except (ValueError, TypeError) as exc:
        assert str(exc)  # a message, never a bare error
        assert not isinstance(exc, np.linalg.LinAlgError), exc  # the raw text of LAPACK
        np.testing.assert_array_equal(image, before)
        event(f"refused: {str(exc)[:50]}")
        return None
    event("accepted")
    np.testing.assert_array_equal(image, before)
    second = call(image)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    return first


def _finite(*arrays_):
    for a in arrays_:
        assert np.isfinite(np.asarray(a, dtype=float)).all()


def _channels(image):
    return 1 if image.ndim == 2 else image.shape[2]


@seed(15)
@PROPERTY
@given(images(), st.integers(1, 3))
def test_fit_car(image, order):
    out = _check(lambda im: (lambda m: (m.gamma, m.sigma, m.mean))(fit_car(im, order)), image)
    if out is not None:
        gamma, sigma, mean = out
        d = _channels(image)
        assert sigma.shape == (d, d) and gamma.shape[0] == d
        _finite(gamma, sigma, mean)


@seed(15)
@PROPERTY
@given(images())
def test_select_support(image):
    out = _check(lambda im: (lambda r: (np.array(list(r.scores.values())),))(
        select_support(im, [1, 2])), image)
    if out is not None:
        assert out[0].shape == (2,)
        _finite(out[0])


@seed(15)
@PROPERTY
@given(images())
def test_local_parameters(image):
    out = _check(lambda im: (local_parameters(im, 1),), image)
    if out is not None:
        gamma = out[0]
        assert gamma.shape[:3] == (*image.shape[:2], _channels(image))
        _finite(gamma)


@seed(15)
@PROPERTY
@given(images())
def test_predict(image):
    def call(im):
        pred = predict(fit_car(im, 1), im)
        return tuple(pred) if isinstance(pred, tuple) else (pred,)

    out = _check(call, image)
    if out is not None:
        mean = np.asarray(out[0])
        assert mean.shape[:2] == image.shape[:2]
        # the first rows/columns have no complete neighbourhood: NaN there by design
        assert np.isfinite(mean[1:, 1:]).all()


@seed(15)
@PROPERTY
@given(images())
def test_illumination_invariants(image):
    out = _check(lambda im: (illumination_invariants(im, 1),), image)
    if out is not None:
        _finite(out[0])


# ------------------------------------------- synthesis, textures, restoration
SMALL = settings(max_examples=15, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow])


@seed(15)
@SMALL
@given(images(3, 24), st.integers(1, 30), st.integers(1, 30), st.integers(0, 2**32))
def test_synthesize(image, h, w, seed_):
    from car_napari import synthesize

    try:
        model = fit_car(image, 1)
    except (ValueError, TypeError):
        return
    out = _check(lambda _: (synthesize(model, (h, w), seed=seed_),), image)
    if out is not None:
        assert out[0].shape[:2] == (h, w)
        _finite(out[0])


@seed(15)
@SMALL
@given(images(16, 28), st.sampled_from([1, "auto"]), st.integers(1, 40), st.integers(1, 40),
       st.booleans())
def test_texture_model(image, neighbourhood, h, w, tileable):
    from car_napari.texture import TextureModel

    def call(im):
        model = TextureModel.fit(im, levels=1, neighbourhood=neighbourhood)
        params = [np.concatenate([m.gamma.ravel(), m.sigma.ravel()]) for m in model.models]
        return (*params, model.synthesize((h, w), seed=3, tileable=tileable))

    out = _check(call, image)
    if out is not None:
        texture = out[-1]
        assert texture.shape == ((h, w) if image.ndim == 2 else (h, w, image.shape[2]))
        _finite(*out)
        # the output stays within the texture's range (the histogram restore)
        assert texture.min() >= image.min() - 1e-6 * abs(image).max()
        assert texture.max() <= image.max() + 1e-6 * abs(image).max()


@st.composite
def stacks(draw):
    """(n, H, W) grey stacks of 2 or 3 noisy, blurred or scaled versions."""
    base = draw(images(6, 24))
    if base.ndim == 3:
        base = base[..., 0]
    n = draw(st.integers(2, 3))
    gains = draw(st.lists(st.sampled_from([1.0, 0.5, 2.0, 1e-3]), min_size=n, max_size=n))
    noise = np.random.default_rng(draw(st.integers(0, 99))).normal(0, 0.05, (n, *base.shape))
    return np.stack([base * g for g in gains]) + noise * np.abs(base).max()


@seed(15)
@SMALL
@given(stacks())
def test_restore_multichannel(stack):
    from car_napari import restore_multichannel

    out = _check(lambda s: tuple(restore_multichannel(s)), stack)
    if out is not None:
        restored, probability = out
        assert restored.shape == stack.shape[1:] and probability.shape[:2] == stack.shape[1:]
        _finite(restored, probability)


@seed(15)
@SMALL
@given(images(8, 24), st.sampled_from([1, 3, 5]))
def test_estimate_psf(image, size):
    from scipy import ndimage

    from car_napari import estimate_psf

    observed = ndimage.uniform_filter(image, 3, mode="nearest")
    before = observed.copy()
    out = _check(lambda im: (estimate_psf(observed, im, size=size),), image)
    np.testing.assert_array_equal(observed, before)
    if out is not None:
        assert out[0].shape == (size, size)
        _finite(out[0])


@seed(15)
@PROPERTY
@given(images())
def test_estimate_noise(image):
    from car_napari import estimate_noise

    out = _check(lambda im: (estimate_noise(im),), image)
    if out is not None:
        assert out[0].shape == (_channels(image),) and (out[0] >= 0).all()
        _finite(out[0])


@seed(15)
@SMALL
@given(images(12, 28), st.integers(1, 2))
def test_texture_features(image, levels):
    from car_napari.texture import texture_features

    out = _check(lambda im: (texture_features(im, levels=levels, neighbourhood=1),), image)
    if out is not None:
        assert out[0].ndim == 1
        _finite(out[0])


# ------------------------------------------------ the rest of the public API
# Light properties (a few small examples each) for every public function the
# ones above leave out, so that each one of car_napari.__all__ and of the
# subpackages' __all__ is called here (test_every_public_function_is_called
# lists them). The result types (Prediction, RestorationResult, ...) are
# checked through the functions that return them.
LIGHT = settings(max_examples=4, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow])
_NUMBERS = st.one_of(st.integers(-3, 40), st.sampled_from([np.nan, np.inf, -np.inf, 2.5, None,
                                                           "2", True, 10**30]))


def _same(a, b):
    """Equal results (arrays bit for bit, NaN equal to NaN), recursively."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    elif hasattr(a, "__dict__") and not callable(a):
        _same(vars(a), vars(b))
    elif isinstance(a, float) and np.isnan(a):
        assert np.isnan(b)
    else:
        assert a == b


def _call(call, *inputs):
    """``call()``'s result, the same twice with the inputs untouched, or None
    for a ValueError / TypeError with a message."""
    before = [np.array(x, copy=True) for x in inputs]
    try:
        first = call()
    except (ValueError, TypeError) as exc:
        assert str(exc) and not isinstance(exc, np.linalg.LinAlgError), exc
        event(f"refused: {str(exc)[:50]}")
        first = None
    else:
        event("accepted")
        _same(first, call())
    for x, b in zip(inputs, before, strict=True):
        np.testing.assert_array_equal(x, b)
    return first


@seed(15)
@LIGHT
@given(_NUMBERS, _NUMBERS)
def test_small_options(a, b):
    from car_napari import causal_neighbourhood, limited_blas
    from car_napari.mammography import score_threshold
    from car_napari.restoration import psf_width, tile_halo
    from car_napari.texture import minimum_size

    offsets = _call(lambda: causal_neighbourhood(a))
    if offsets is not None:
        assert offsets.ndim == 2 and offsets.shape[1] == 2 and offsets.dtype == np.int64
        assert ((offsets[:, 0] > 0) | ((offsets[:, 0] == 0) & (offsets[:, 1] > 0))).all()
    halo = _call(lambda: tile_halo(a, b))
    assert halo is None or (isinstance(halo, int) and halo > 0)
    size = _call(lambda: minimum_size(levels=a, neighbourhood=b))
    assert size is None or size >= 1
    cut = _call(lambda: score_threshold(a))
    assert cut is None or np.isfinite(cut)

    def blas():
        with limited_blas(a) as limit:
            return limit
    _call(blas)
    i, j = np.indices((9, 9)) - 4
    width = _call(lambda: psf_width(np.exp(-(i**2 + j**2) / 2.0) * (a if isinstance(
        a, (int, float)) and not isinstance(a, bool) else 1.0)))
    assert width is None or np.isfinite(width)


@st.composite
def offset_arrays(draw):
    """(eta, 2) offsets, causal or not, sometimes malformed."""
    kind = draw(st.sampled_from(["order", "causal", "any", "bad"]))
    if kind == "order":
        return draw(st.integers(-1, 4))
    if kind == "bad":
        return draw(st.sampled_from([[1, 2, 3], "x", [[1.5, 0]], [[1e300, 0]], None]))
    rows = draw(st.lists(st.tuples(st.integers(-2, 3), st.integers(-3, 3)),
                         min_size=1, max_size=5))
    if kind == "causal":
        rows = [(abs(i), abs(j) + (i == 0)) for i, j in rows]
    return rows


@seed(15)
@settings(LIGHT, max_examples=20)  # cheap: enough for every kind of offsets
@given(offset_arrays(), st.integers(1, 3))
def test_offsets_and_contexts(offsets, d):
    from car_napari import Context
    from car_napari.model import as_offsets
    from car_napari.restoration import multichannel_context
    from car_napari.texture import temporal_context

    got = _call(lambda: as_offsets(offsets))
    for context in (_call(lambda: temporal_context(offsets, d)),
                    _call(lambda: multichannel_context(offsets, d, d - 1))):
        assert (got is None) == (context is None)  # the same offsets rule
        if context is not None:
            assert isinstance(context, Context) and context.taps.shape[1] == 3
    if got is not None:
        spatial = _call(lambda: Context.spatial(got[0], d))
        assert spatial.n_regressors == len(got[0]) * d


@seed(15)
@LIGHT
@given(images(8, 24))
def test_restore_and_restore_large(image):
    from car_napari import restore
    from car_napari.restoration import restore_large

    out = _call(lambda: restore(image), image)
    tiled = _call(lambda: restore_large(image, tile=16), image)
    if out is not None:
        assert out.shape == image.shape and out.dtype == np.float64
        _finite(out)
    if tiled is not None:
        assert tiled.shape == image.shape
        _finite(tiled)


@seed(15)
@LIGHT
@given(images(12, 24))
def test_features_segment_and_scratches(image):
    from car_napari import detect_scratches, local_features, segment

    feats = _call(lambda: local_features(image, levels=1, smoothing=1.0), image)
    if feats is not None:
        assert feats.shape[:2] == image.shape[:2]
        _finite(feats)
    result = _call(lambda: segment(image, levels=1, n_segments=2, n_init=2), image)
    if result is not None:
        assert result.labels.shape == image.shape[:2]
    scratches = _call(lambda: detect_scratches(image), image)
    if scratches is not None:
        assert scratches.shape == image.shape[:2] and scratches.dtype == bool


@seed(15)
@LIGHT
@given(images(8, 20), st.integers(0, 2**16))
def test_inpaint_and_fit_mask(image, seed_):
    from car_napari import fit_mask, inpaint

    mask = np.random.default_rng(seed_).random(image.shape[:2]) > 0.9
    out = _call(lambda: inpaint(image, mask), image, mask)
    if out is not None:
        assert out.shape == image.shape
        _finite(out)
        np.testing.assert_array_equal(out[~mask], np.asarray(image, float)[~mask])
    small = mask[::2, ::2]
    fitted = _call(lambda: fit_mask(small, image.shape[:2]), small)
    if fitted is not None:
        assert fitted.shape == image.shape[:2] and fitted.dtype == bool


@st.composite
def clips(draw):
    """(T, H, W) grey clips of 2 or 3 frames, each a shifted copy."""
    base = draw(images(12, 20))
    base = base if base.ndim == 2 else base[..., 0]
    shifts = draw(st.lists(st.integers(-2, 2), min_size=2, max_size=3))
    return np.stack([np.roll(base, s, axis=1) for s in shifts])


@seed(15)
@LIGHT
@given(clips())
def test_motion_and_frames(clip):
    from car_napari import compensate_motion, estimate_motion, warp_frame
    from car_napari.inpainting import descratch_frames, inpaint_frames, inpaint_large
    from car_napari.restoration import restore_frames

    flow = _call(lambda: estimate_motion(clip[0], clip[1]), clip)
    if flow is not None:
        assert flow.shape == (2, *clip.shape[1:])
        _finite(flow)
        warped = _call(lambda: warp_frame(clip[1], flow), clip, flow)
        assert warped.shape == clip.shape[1:]
    still = _call(lambda: warp_frame(clip[0], np.zeros((2, *clip.shape[1:]))), clip)
    if still is not None:
        np.testing.assert_array_equal(still, clip[0])  # no motion: the frame itself
    _call(lambda: compensate_motion(clip, iterations=1), clip)
    mask = np.zeros(clip.shape[1:], bool)
    mask[3:5, 4:7] = True

    def into(run):  # the frame functions write into `restored`: a fresh one per call
        def call():
            restored = np.zeros(clip.shape)
            return run(restored), restored
        return call
    _call(into(lambda out: restore_frames(clip, out)), clip)
    _call(into(lambda out: inpaint_frames(clip, mask, out)), clip, mask)
    _call(into(lambda out: descratch_frames(clip, out)), clip)
    large = _call(lambda: inpaint_large(clip, mask), clip, mask)
    if large is not None:
        assert large.shape == clip.shape


@seed(15)
@LIGHT
@given(images(16, 28))
def test_texture_helpers(image):
    from car_napari import fit_car, spectral_radius
    from car_napari.restoration import sharpness
    from car_napari.segmentation import pseudo_colour
    from car_napari.texture import collapse_pyramid, cumulative_histograms, laplacian_pyramid

    bands = _call(lambda: laplacian_pyramid(image, levels=2), image)
    if bands is not None:
        back = collapse_pyramid(bands)
        np.testing.assert_allclose(back, image, atol=1e-9 * max(1.0, np.abs(image).max()))
    grey = image if image.ndim == 2 else image[..., 0]
    stack = np.stack([grey, grey[::-1]])
    hist = _call(lambda: cumulative_histograms(stack, bins=8), stack)
    if hist is not None:
        assert hist.shape == (2, 8) and (np.diff(hist, axis=1) >= 0).all()
    sharp = _call(lambda: sharpness(stack), stack)
    if sharp is not None:
        assert sharp.shape == (2,)
    colour = _call(lambda: pseudo_colour(np.abs(grey)), grey)
    if colour is not None:
        assert colour.shape == (*grey.shape, 3)
    try:
        model = fit_car(image, 1)
    except (ValueError, TypeError):
        return
    radius = _call(lambda: spectral_radius(model))
    assert radius is None or (np.isfinite(radius) and radius >= 0)


@seed(15)
@settings(LIGHT, max_examples=2)
@given(images(20, 28))
def test_texture_models_and_rank(image):
    from car_napari import rank
    from car_napari.texture import BTFModel, DynamicTextureModel

    btf = _call(lambda: BTFModel.fit([image, image[::-1]], levels=1, n_subspaces=1), image)
    if btf is not None:
        assert np.isfinite(btf.synthesize((8, 8), seed=0)).all()
    clip = np.stack([image, 0.9 * image, 0.8 * image])
    _call(lambda: DynamicTextureModel.fit(clip, neighbourhood=1), clip)
    ranking = _call(lambda: rank(image, [image, image[::-1]], levels=1), image)
    if ranking is not None:
        indices, distances = ranking
        assert sorted(indices.tolist()) == [0, 1] and (np.diff(distances) >= 0).all()


@seed(15)
@settings(LIGHT, max_examples=2)
@given(st.integers(0, 2**16))
def test_mammography(seed_):
    from car_napari import detect_breast, detect_mammogram_rois, segment_breast
    from car_napari.mammography import (
        bit_depth,
        filter_regions,
        operating_point,
        region_outlines,
        roi_overlay,
        select_marks,
    )

    rng = np.random.default_rng(seed_)
    image = np.zeros((96, 96))
    image[:, :60] = 0.5 + 0.05 * rng.random((96, 60))  # the breast, against black
    image[30:50, 20:40] += 0.2
    _call(lambda: detect_breast(image), image)
    segments = _call(lambda: segment_breast(image, levels=1, n_segments=3, n_init=3,
                                            work_side=96), image)
    if segments is not None:
        assert segments.segments.shape == image.shape
    rois = _call(lambda: detect_mammogram_rois(image, levels=1, n_segments=3, n_init=3,
                                               work_side=96, pool=(3,)), image)
    labels = np.ones(image.shape, np.int32)
    labels[30:50, 20:40] = 2
    found = _call(lambda: filter_regions(image, labels, reference=0.7, tolerance=0.2),
                  image, labels)
    for got in (rois, found):
        if got is not None:
            assert got.labels.shape == image.shape
            outlines = _call(lambda got=got: region_outlines(got.labels), got.labels)
            assert len(outlines) == len(np.unique(got.labels[got.labels > 0]))
            _call(lambda got=got: select_marks(got, 1.0))
            rgb = _call(lambda got=got: roi_overlay(image, got.labels), image, got.labels)
            if rgb is not None:
                assert rgb.shape == (*image.shape, 3) and rgb.dtype == np.uint8
    depth = _call(lambda: bit_depth(np.round(image * rng.integers(1, 70000)).astype(np.uint32)))
    assert depth is None or depth in (12, 32)
    rate = float(rng.uniform(0.1, 12))
    point = _call(lambda: operating_point(rate))
    assert point is None or 0 <= point["threshold"] <= 1


@seed(15)
@LIGHT
@given(images(4, 12), st.sampled_from(["png", "tif"]))
def test_write_and_read_image(image, suffix):
    import tempfile
    from pathlib import Path

    from car_napari.cli import build_parser, expand_inputs, main
    from car_napari.io import read_dicom, read_image, write_image

    grey = np.clip(image if image.ndim == 2 else image[..., 0], 0, 1)
    # the file's type (write_image writes the pixels as they are)
    grey = (grey * 255).astype(np.uint8) if suffix == "png" else grey.astype(np.float32)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"out.{suffix}"
        try:
            write_image(path, grey)
        except (ValueError, TypeError) as exc:
            assert str(exc)
            return
        back = _call(lambda: read_image(path))
        assert back.shape[:2] == grey.shape
        assert [p.name for p in _call(lambda: expand_inputs([folder]))] == [path.name]
        with pytest.raises((ValueError, TypeError, OSError)):
            read_dicom(path)  # not a DICOM file: refused
    assert build_parser().prog
    with pytest.raises(SystemExit):
        main(["--no-such-option"])


_ITER = ["iter_compensate_motion", "iter_detect_mammogram_rois", "iter_detect_scratches",
         "iter_estimate_motion", "iter_fit_btf", "iter_fit_car", "iter_fit_dynamic_texture",
         "iter_fit_texture", "iter_inpaint", "iter_local_features", "iter_local_parameters",
         "iter_rank", "iter_restore", "iter_restore_multichannel", "iter_segment",
         "iter_segment_breast", "iter_segment_tissue", "iter_select_support", "iter_synthesize",
         "iter_analyse_mammogram"]
# the frame functions write into `restored` (and return the frames done)
_ITER_FRAMES = ["iter_descratch_frames", "iter_inpaint_frames", "iter_inpaint_large",
                "iter_restore_frames", "iter_restore_large"]


def test_every_public_function_is_called():
    """Each function and class of the public API appears in a call in this
    file (the iter_ forms: a test of drain(iter_x) == x below)."""
    import importlib
    import inspect
    import pkgutil
    import re
    from pathlib import Path

    import car_napari

    source = Path(__file__).read_text()
    modules = ["car_napari"] + [f"car_napari.{m.name}" for m in
                                pkgutil.iter_modules(car_napari.__path__)
                                if not m.name.startswith("_")]
    missing = set()
    results = {"BreastDetection", "BreastSegmentation", "MammogramROIs", "Mixture",
               "MultichannelRestoration", "Prediction", "Progress", "Ranking",
               "RestorationResult", "SegmentationResult", "SupportSelection", "CARModel",
               "TissueResult", "MammogramAnalysis"}
    for name in modules:
        module = importlib.import_module(name)
        for attr in getattr(module, "__all__", []):
            obj = getattr(module, attr)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)) or attr in results:
                continue
            if attr in _ITER + _ITER_FRAMES or re.search(rf"(?<![\w.]){attr}[(.]", source):
                continue
            missing.add(f"{name}.{attr}")
    assert not missing, sorted(missing)


def _progress_records(records):
    """Well-formed records: Progress with a stage and a message, fractions
    finite in [0, 1] and never going back."""
    from car_napari import Progress

    assert records
    fractions = []
    for r in records:
        assert isinstance(r, Progress), r
        assert isinstance(r.stage, str) and r.stage and isinstance(r.message, str), r
        assert isinstance(r.fraction, (float, int)) and not isinstance(r.fraction, bool), r
        assert 0.0 <= r.fraction <= 1.0, r  # (a NaN fails this too)
        fractions.append(float(r.fraction))
    assert fractions == sorted(fractions), fractions


def _drained_and_direct(job, direct, *inputs):
    """``drain(job())`` and ``direct()``, each leaving the inputs as they
    were, the records checked; both results."""
    from car_napari import drain

    def public(x):  # an object's public fields (a private cache may fill in)
        if hasattr(x, "__dict__") and not isinstance(x, np.ndarray):
            return {k: v for k, v in vars(x).items() if not k.startswith("_")}
        return x

    before = [copy.deepcopy(public(x)) for x in inputs]
    records = []
    got = drain(job(), records.append)
    _progress_records(records)
    for x, b in zip(inputs, before, strict=True):
        _same(public(x), b)
    want = direct()
    for x, b in zip(inputs, before, strict=True):
        _same(public(x), b)
    return got, want


@pytest.mark.parametrize("name", _ITER)
@seed(15)
@settings(LIGHT, max_examples=2)
@given(st.integers(28, 40), st.integers(28, 40), st.integers(0, 2**16))
def test_iter_forms_drain_to_the_function(name, h, w, seed_):
    """drain(iter_x(...)) == x(...), bit for bit (models: every field), with
    well-formed, non-decreasing progress records and the inputs untouched."""
    import car_napari as car

    rng = np.random.default_rng(seed_)
    img = rng.random((h, w))
    clip = np.stack([img, np.roll(img, 1, axis=1), np.roll(img, 2, axis=1)])
    breast = np.zeros((96, 96))
    breast[:, :60] = 0.5 + 0.05 * rng.random((96, 60))
    model = car.fit_car(img, 1)
    stack = [img, img[::-1]]
    mask = img > 0.95
    args = {
        "compensate_motion": ((clip,), {"iterations": 1}),
        "detect_mammogram_rois": ((breast,), dict(levels=1, n_segments=3, n_init=3,
                                                  work_side=96, pool=(3,))),
        "detect_scratches": ((img,), {}),
        "estimate_motion": ((img, clip[1]), {"iterations": 1}),
        "fit_btf": ((stack,), dict(levels=1, n_subspaces=1)),
        "fit_car": ((img, 1), {}),
        "fit_dynamic_texture": ((clip,), {"neighbourhood": 1}),
        "fit_texture": ((img,), {"levels": 1}),
        "inpaint": ((img, mask), {}),
        "local_features": ((img,), {"levels": 1}),
        "local_parameters": ((img, 1), {}),
        "rank": ((img, stack), {"levels": 1}),
        "restore": ((img,), {}),
        "restore_multichannel": ((clip,), {}),
        "segment": ((img,), dict(levels=1, n_segments=2, n_init=2)),
        "segment_breast": ((breast,), dict(levels=1, n_segments=3, n_init=3, work_side=96)),
        "segment_tissue": ((breast,), dict(n_init=3, work_side=96, pool=(2, 3))),
        "analyse_mammogram": ((breast,), dict(n_init=3, work_side=96, pool=(2, 3))),
        "select_support": ((img, [1, 2]), {}),
        "synthesize": ((model, (8, 8)), {"seed": 0}),
    }
    base = name[len("iter_"):]
    positional, options = args[base]
    direct = getattr(car, base, None) or getattr(car.mammography, base)
    job = getattr(car, name, None) or getattr(car.mammography, name)
    got, want = _drained_and_direct(lambda: job(*positional, **options),
                                    lambda: direct(*positional, **options),
                                    positional, options)
    _same(got, want)


@pytest.mark.parametrize("name", _ITER_FRAMES)
@seed(15)
@settings(LIGHT, max_examples=2)
@given(st.integers(20, 28), st.integers(20, 28), st.integers(0, 2**16))
def test_frame_iter_forms_drain_to_the_function(name, h, w, seed_):
    from car_napari import inpainting, restoration

    rng = np.random.default_rng(seed_)
    img = rng.random((h, w))
    clip = np.stack([img, np.roll(img, 1, axis=1)])
    mask = np.zeros(img.shape, bool)
    mask[5:7, 5:9] = True
    module = inpainting if hasattr(inpainting, name) else restoration
    base = name[len("iter_"):]
    make = {"descratch_frames": lambda f, out: f(clip, out),
            "inpaint_frames": lambda f, out: f(clip, mask, out),
            "restore_frames": lambda f, out: f(clip, out),
            "inpaint_large": lambda f, out: f(clip, mask),
            "restore_large": lambda f, out: f(img, tile=16)}[base]
    out_iter, out_direct = np.zeros(clip.shape), np.zeros(clip.shape)
    got, want = _drained_and_direct(lambda: make(getattr(module, name), out_iter),
                                    lambda: make(getattr(module, base), out_direct),
                                    img, clip, mask)
    _same(got, want)
    _same(out_iter, out_direct)


# the public classes' job methods: (class, method) -> its plain form
_ITER_METHODS = ["BTFModel.iter_synthesize", "DynamicTextureModel.iter_synthesize",
                 "SegmentationResult.iter_labels_at", "TextureModel.iter_synthesize"]


@pytest.mark.parametrize("name", _ITER_METHODS)
def test_iter_methods_drain_to_the_method(name):
    import car_napari as car

    rng = np.random.default_rng(0)
    img = rng.random((32, 32))
    make = {
        "BTFModel": lambda: car.BTFModel.fit([img, 0.5 * img[::-1]], levels=1,
                                             n_subspaces=2),
        "DynamicTextureModel": lambda: car.DynamicTextureModel.fit(
            np.stack([img, np.roll(img, 1, axis=1), img.T]), neighbourhood=1),
        "SegmentationResult": lambda: car.segment(img, levels=1, n_init=4),
        "TextureModel": lambda: car.TextureModel.fit(img, levels=1),
    }
    calls = {
        "BTFModel": ((9, 11),), "DynamicTextureModel": (2, (9, 11)),
        "SegmentationResult": (3,), "TextureModel": ((9, 11),),
    }
    options = {"SegmentationResult": {"threshold": 0.9}}
    cls, method = name.split(".")
    obj, other = make[cls](), make[cls]()  # two: a re-cut is cached in its result
    positional = calls[cls]
    keywords = options.get(cls, {"seed": 3})
    got, want = _drained_and_direct(
        lambda: getattr(obj, method)(*positional, **keywords),
        lambda: getattr(other, method[len("iter_"):])(*positional, **keywords),
        obj, other)
    _same(got, want)


@pytest.mark.parametrize("name", ["fit_btf", "fit_texture", "fit_dynamic_texture"])
def test_model_constructors_are_the_fit_functions(name):
    """TextureModel.fit, BTFModel.fit and DynamicTextureModel.fit give, field
    for field, what fit_texture, fit_btf and fit_dynamic_texture give."""
    import car_napari as car
    from car_napari import fit_btf, fit_dynamic_texture, fit_texture

    rng = np.random.default_rng(3)
    img = rng.random((32, 32))
    stack, clip = [img, img[::-1]], np.stack([img, img.T, img[::-1]])
    pairs = {"fit_btf": (lambda: car.BTFModel.fit(stack, levels=1, n_subspaces=1),
                         lambda: fit_btf(stack, levels=1, n_subspaces=1)),
             "fit_texture": (lambda: car.TextureModel.fit(img, levels=1),
                             lambda: fit_texture(img, levels=1)),
             "fit_dynamic_texture": (lambda: car.DynamicTextureModel.fit(clip, neighbourhood=1),
                                     lambda: fit_dynamic_texture(clip, neighbourhood=1))}
    constructor, function = pairs[name]
    _same(constructor(), function())


def test_every_public_job_is_checked_above():
    """Every public iter_ function and method has its drain test above."""
    import importlib
    import inspect
    import pkgutil

    import car_napari

    modules = ["car_napari"] + [f"car_napari.{m.name}" for m in
                                pkgutil.iter_modules(car_napari.__path__)
                                if not m.name.startswith("_")]
    functions, methods = set(), set()
    for name in modules:
        module = importlib.import_module(name)
        for attr in getattr(module, "__all__", []):
            obj = getattr(module, attr)
            if attr.startswith("iter_"):
                functions.add(attr)
            if inspect.isclass(obj):
                methods |= {f"{attr}.{m}" for m in vars(obj) if m.startswith("iter_")}
    assert functions == set(_ITER + _ITER_FRAMES)
    assert methods == set(_ITER_METHODS)


@seed(16)
@settings(LIGHT, max_examples=2)
@given(st.integers(0, 2**16))
def test_tissue_density_is_the_masks_share_of_the_breast(seed_):
    """segment_tissue: the mask inside the breast, the density its share in
    percent, class probabilities summing to 1; analyse_mammogram gives the
    same tissue and the ROIs of detect_mammogram_rois."""
    from car_napari.mammography import (
        analyse_mammogram,
        detect_mammogram_rois,
        segment_tissue,
    )

    rng = np.random.default_rng(seed_)
    image = np.zeros((96, 96))
    image[:, :60] = 0.5 + 0.05 * rng.random((96, 60))
    image[30:50, 20:40] += 0.2 * rng.random((20, 20))
    options = dict(n_init=3, work_side=96, pool=(2, 3))
    tissue = segment_tissue(image, **options)
    assert not (tissue.fibroglandular & ~tissue.breast).any()
    assert tissue.density == pytest.approx(
        100.0 * tissue.fibroglandular.sum() / tissue.breast.sum())
    assert sum(tissue.probabilities.values()) == pytest.approx(1.0)
    rois, again = analyse_mammogram(image, **options)
    _same(again, tissue)
    _same(rois, detect_mammogram_rois(image, **options))
