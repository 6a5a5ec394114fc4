"""Property tests of the entry points ``tests/test_properties.py`` covers
only lightly: the texture models (:class:`BTFModel`,
:class:`DynamicTextureModel`), :func:`estimate_noise`, the mammogram breast
(:func:`detect_breast`, :func:`segment_breast`), :func:`local_features`, the
motion functions and :func:`fit_mask`. Each checks what the maths or the
docstring promises against an independent computation (SciPy, NumPy, exact
fractions) or an invariance: shapes and dtypes, finite values, inputs never
modified, the same result under the same seed, and grey-level, mirror and
transpose invariances where the function has them. Small examples, a few of
each (about 30 s in all on a 2-core machine)."""

from fractions import Fraction

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from scipy import ndimage  # noqa: E402

import car_napari as car  # noqa: E402
from car_napari.mammography import detect_breast, segment_breast  # noqa: E402
from car_napari.texture import BTFModel, DynamicTextureModel, temporal_context  # noqa: E402

FEW = settings(max_examples=8, deadline=None, derandomize=True,
               suppress_health_check=[HealthCheck.too_slow])
SOME = settings(FEW, max_examples=20)  # the cheap ones

_SEEDS = st.integers(0, 2**16)
_GAINS = st.sampled_from([1e-3, 0.25, 0.5, 2.0, 7.0, 1e3])
_OFFSETS = st.sampled_from([0.0, -3.0, 0.5, 10.0, 1e3])


@st.composite
def textures(draw, low=8, high=24, colour=None, scale=None,
             kinds=("noise", "blurred", "ramp")):
    """(H, W) or (H, W, C) float textures: noise, blurred noise, or noise on
    a ramp, ``low`` to ``high`` pixels a side, at various scales."""
    h, w = draw(st.integers(low, high)), draw(st.integers(low, high))
    c = draw(st.sampled_from([None, 2, 3])) if colour is None else (3 if colour else None)
    rng = np.random.default_rng(draw(_SEEDS))
    shape = (h, w) if c is None else (h, w, c)
    x = rng.random(shape)
    kind = draw(st.sampled_from(kinds))
    if kind == "blurred":
        x = ndimage.gaussian_filter(x, (1.5, 1.5, 0)[:x.ndim])
    elif kind == "ramp":
        i, j = np.indices((h, w)) / max(h, w)
        x = x * 0.2 + (i - 2 * j if c is None else (i - 2 * j)[..., None])
    return x * (draw(_GAINS) if scale is None else scale)


def _untouched(call, *inputs):
    """``call()``, checking that it leaves its inputs as they were."""
    before = [np.array(x, copy=True) for x in inputs]
    out = call()
    for x, b in zip(inputs, before, strict=True):
        np.testing.assert_array_equal(x, b)
    return out


# ------------------------------------------------------------- estimate_noise
def _immerkaer(plane):
    """The estimate from its definition: the median absolute response of the
    Laplacian-difference kernel over the interior, over 6 * 0.6745."""
    kernel = np.outer([1.0, -2.0, 1.0], [1.0, -2.0, 1.0])
    response = ndimage.correlate(plane, kernel)[1:-1, 1:-1]
    return np.median(np.abs(response)) / (6 * 0.6745)


@seed(15)
@SOME
@given(textures(3, 24))
def test_estimate_noise_is_immerkaers_median(image):
    sigma = _untouched(lambda: car.estimate_noise(image), image)
    planes = [image] if image.ndim == 2 else np.moveaxis(image, -1, 0)
    assert sigma.dtype == np.float64 and sigma.shape == (len(planes),)
    want = [_immerkaer(p) for p in planes]
    np.testing.assert_allclose(sigma, want, rtol=1e-9, atol=1e-12 * np.abs(image).max())
    # integers are scaled to [0, 1]: an 8-bit image is its float version / 255
    eight = np.round(np.clip(image / max(np.abs(image).max(), 1e-300), 0, 1) * 255)
    np.testing.assert_allclose(car.estimate_noise(eight.astype(np.uint8)),
                               car.estimate_noise(eight / 255), rtol=1e-12)


@seed(15)
@SOME
@given(textures(3, 20, colour=False, scale=1.0), st.floats(-5, 5), st.floats(-5, 5), _SEEDS)
def test_estimate_noise_ignores_gain_sign_offsets_and_profiles(image, gain, offset, seed_):
    # the kernel is an outer product of second differences: it cancels any
    # row profile plus column profile (planes, offsets, vignetting along an
    # axis), scales with the gain, and is blind to the sign and to mirrors
    sigma = car.estimate_noise(image)[0]
    rng = np.random.default_rng(seed_)
    rows, cols = rng.normal(0, 3, image.shape[0]), rng.normal(0, 3, image.shape[1])
    changed = gain * image + offset + rows[:, None] + cols[None, :]
    scale = np.abs(changed).max()
    np.testing.assert_allclose(car.estimate_noise(changed)[0], abs(gain) * sigma,
                               rtol=1e-6, atol=1e-12 * scale)
    for mirrored in (image[::-1], image[:, ::-1], image.T):
        np.testing.assert_allclose(car.estimate_noise(mirrored)[0], sigma, rtol=1e-12)


@seed(15)
@FEW
@given(st.floats(0.01, 0.2), _SEEDS)
def test_estimate_noise_finds_white_noise_on_a_smooth_image(sigma, seed_):
    rng = np.random.default_rng(seed_)
    i, j = np.indices((96, 96)) / 96
    smooth = np.sin(2 * i) + i * j
    found = car.estimate_noise(smooth + rng.normal(0, sigma, smooth.shape))[0]
    assert abs(found - sigma) < 0.1 * sigma  # 94**2 responses: a few % of spread


# -------------------------------------------------------------------- fit_mask
@st.composite
def masks(draw):
    """(h, w) or (t, h, w) bool masks, 1 to 12 pixels a side."""
    t = draw(st.sampled_from([None, 1, 3]))
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    rng = np.random.default_rng(draw(_SEEDS))
    shape = (h, w) if t is None else (t, h, w)
    return rng.random(shape) < draw(st.sampled_from([0.0, 0.2, 0.5, 1.0]))


@seed(15)
@SOME
@given(masks(), st.integers(1, 30), st.integers(1, 30), st.integers(1, 4))
def test_fit_mask_takes_the_pixel_under_each_centre(mask, H, W, factor):
    T = mask.shape[0] if mask.ndim == 3 else 2
    got = _untouched(lambda: car.fit_mask(mask, (T, H, W)), mask)
    h, w = mask.shape[-2:]
    # the mask pixel under frame pixel (i, j)'s centre, in exact fractions
    rows = [int(Fraction(2 * i + 1, 2 * H) * h) for i in range(H)]
    cols = [int(Fraction(2 * j + 1, 2 * W) * w) for j in range(W)]
    want = mask[..., rows, :][..., cols]
    assert got.dtype == bool and got.shape == want.shape
    np.testing.assert_array_equal(got, want)
    # an integer zoom is a block copy, and fitting it back gives the mask
    zoomed = np.kron(mask, np.ones((factor, factor), bool))
    np.testing.assert_array_equal(car.fit_mask(mask, (T, h * factor, w * factor)), zoomed)
    np.testing.assert_array_equal(car.fit_mask(zoomed, (T, h, w)), mask)
    # invert marks the zeros; numbers and colour channels: non-zero anywhere
    np.testing.assert_array_equal(car.fit_mask(mask, (T, H, W), invert=True), ~got)
    grey = mask * np.uint8(200)
    colour = np.stack([np.zeros_like(grey), grey, np.zeros_like(grey)], axis=-1)
    np.testing.assert_array_equal(car.fit_mask(grey, (T, H, W)), got)
    np.testing.assert_array_equal(car.fit_mask(colour, (T, H, W), channel_axis=-1), got)
    same = car.fit_mask(mask, (T, *mask.shape[-2:]))
    np.testing.assert_array_equal(same, mask)
    assert not np.shares_memory(same, mask)  # a new array


# ------------------------------------------------------------ motion functions
@seed(15)
@SOME
@given(textures(2, 14), st.floats(-4, 4), st.floats(-4, 4), _SEEDS, _GAINS, _OFFSETS)
def test_warp_frame_is_bilinear_with_nearest_edges(frame, dy, dx, seed_, gain, offset):
    h, w = frame.shape[:2]
    rng = np.random.default_rng(seed_)
    flow = np.stack([np.full((h, w), dy), np.full((h, w), dx)]) + rng.normal(0, 1, (2, h, w))
    got = _untouched(lambda: car.warp_frame(frame, flow), frame, flow)
    assert got.dtype == np.float64 and got.shape == frame.shape
    i, j = np.indices((h, w))
    planes = [frame] if frame.ndim == 2 else np.moveaxis(frame, -1, 0)
    want = [ndimage.map_coordinates(p, [i + flow[0], j + flow[1]], order=1, mode="nearest")
            for p in planes]
    want = want[0] if frame.ndim == 2 else np.stack(want, axis=-1)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(frame).max())
    # interpolation weights sum to one: grey-level changes pass through
    np.testing.assert_allclose(car.warp_frame(gain * frame + offset, flow),
                               gain * got + offset, rtol=1e-9,
                               atol=1e-9 * (gain * np.abs(frame).max() + abs(offset)))
    # no motion: the frame itself, bit for bit
    np.testing.assert_array_equal(car.warp_frame(frame, np.zeros_like(flow)), frame)


def _smooth(h, w, seed_):
    rng = np.random.default_rng(seed_)
    return ndimage.gaussian_filter(rng.random((h + 16, w + 16)), 2.0)


@seed(15)
@FEW
@given(st.integers(40, 64), st.integers(40, 64), st.integers(-2, 2), st.integers(-2, 2),
       _SEEDS, st.floats(0.1, 10), st.floats(-1, 1), st.floats(-10, 10), st.booleans())
def test_estimate_motion_finds_a_shift_whatever_the_flicker(h, w, dy, dx, seed_, gain, offset,
                                                            sign, colour):
    scene = _smooth(h, w, seed_)
    reference = scene[8:8 + h, 8:8 + w]
    moving = scene[8 - dy:8 - dy + h, 8 - dx:8 - dx + w]  # the content moved (dy, dx)
    flow = _untouched(lambda: car.estimate_motion(reference, moving), reference, moving)
    assert flow.dtype == np.float32 and flow.shape == (2, h, w) and np.isfinite(flow).all()
    inner = flow[:, 6:-6, 6:-6]
    assert abs(np.median(inner[0]) - dy) < 0.25 and abs(np.median(inner[1]) - dx) < 0.25
    # each frame is normalised: a gain and offset per frame (flicker, a negative) is no motion
    s = -1.0 if sign < 0 else 1.0
    flicker = car.estimate_motion(s * gain * reference + offset, s * moving / gain - offset)
    np.testing.assert_allclose(flicker, flow, atol=0.02)
    # the same frame twice: no motion at all; transposed frames: the transposed flow
    np.testing.assert_array_equal(car.estimate_motion(reference, reference), 0.0)
    swapped = car.estimate_motion(reference.T, moving.T)
    np.testing.assert_allclose(swapped[::-1].transpose(0, 2, 1), flow, atol=1e-3)
    if colour:  # equal channels: the grey frames' flow
        rgb = car.estimate_motion(np.dstack([reference] * 3), np.dstack([moving] * 3))
        np.testing.assert_allclose(rgb, flow, atol=1e-5)


@seed(15)
@FEW
@given(st.lists(st.tuples(st.integers(-2, 2), st.integers(-2, 2)), min_size=2, max_size=3),
       _SEEDS, st.booleans())
def test_compensate_motion_is_estimate_then_warp(shifts, seed_, colour):
    h = w = 40
    scene = _smooth(h, w, seed_)
    clip = np.stack([scene[8 + a:8 + a + h, 8 + b:8 + b + w] for a, b in shifts])
    if colour:
        clip = np.stack([clip, 1 - clip, 0.5 * clip], axis=-1)
    previous, following = _untouched(lambda: car.compensate_motion(clip), clip)
    assert previous.shape == following.shape == clip.shape and previous.dtype == np.float64
    np.testing.assert_array_equal(previous[0], clip[0])  # no frame before the first
    np.testing.assert_array_equal(following[-1], clip[-1])
    for t in range(1, len(clip)):
        back = car.warp_frame(clip[t - 1], car.estimate_motion(clip[t], clip[t - 1]))
        np.testing.assert_allclose(previous[t], back, atol=1e-6)
        ahead = car.warp_frame(clip[t], car.estimate_motion(clip[t - 1], clip[t]))
        np.testing.assert_allclose(following[t - 1], ahead, atol=1e-6)
    # no damage marked is no mask; a still clip is its own neighbours
    clean = car.compensate_motion(clip, mask=np.zeros(clip.shape[:3], bool))
    np.testing.assert_array_equal(clean[0], previous)
    still = np.stack([clip[0]] * len(clip))
    for out in car.compensate_motion(still):
        np.testing.assert_array_equal(out, still)


# ------------------------------------------------------- the mammogram breast
@st.composite
def mammograms(draw):
    """(H, W) float phantoms on [0, 1]: a half-ellipse of noisy tissue
    against the left or right edge, with or without a bright triangular
    muscle in its top corner, on a dark noisy film."""
    h, w = draw(st.integers(48, 120)), draw(st.integers(48, 120))
    rng = np.random.default_rng(draw(_SEEDS))
    i, j = np.indices((h, w))
    depth = draw(st.floats(0.4, 0.8))
    inside = np.hypot((i - h / 2) / (0.45 * h), j / (depth * w)) < 1
    tissue = draw(st.floats(0.3, 0.6))
    image = np.where(inside, tissue + 0.1 * rng.random((h, w)), 0.03 * rng.random((h, w)))
    if draw(st.booleans()):  # a pectoral muscle: brighter, above a straight edge
        image[inside & (i / h + j / (0.5 * w) < 0.6)] += 0.25
    return image[:, ::-1] if draw(st.booleans()) else image


@seed(15)
@FEW
@given(mammograms(), st.floats(0.2, 1.3), st.floats(0.0, 0.05))
def test_detect_breast_mirrors_and_ignores_grey_scaling(image, gain, offset):
    mask, details = _untouched(lambda: detect_breast(image, return_details=True), image)
    assert mask.dtype == bool and mask.shape == image.shape
    assert details["side"] in ("left", "right") and 0 <= details["threshold"] <= 1
    assert not (details["pectoral"] & mask).any()  # the muscle is removed
    # the phantom's tissue: the mask lies on it (to the smoothing's reach) and covers most of it
    tissue = image > 0.25
    assert not (mask & ~ndimage.binary_dilation(tissue, iterations=2)).any()
    assert mask.sum() >= 0.5 * tissue.sum()
    wall = "left" if tissue[:, 0].sum() > tissue[:, -1].sum() else "right"
    assert details["side"] == wall
    # a mirrored film: the mirrored mask and the other side (working resolution 1:1)
    mirror, flipped = detect_breast(image[:, ::-1], return_details=True)
    np.testing.assert_array_equal(mirror, mask[:, ::-1])
    assert flipped["side"] != details["side"]
    upside = detect_breast(image[::-1], pectoral=False)
    np.testing.assert_array_equal(upside, detect_breast(image, pectoral=False)[::-1])
    # the threshold is relative to the film's percentiles: a gain and an offset change nothing
    np.testing.assert_array_equal(detect_breast(gain * image + offset), mask)
    # an 8-bit film is its float version / 255, and 16 bits (x 257) the same film
    eight = np.round(image * 255).astype(np.uint8)
    np.testing.assert_array_equal(detect_breast(eight), detect_breast(eight / 255.0))
    np.testing.assert_array_equal(detect_breast(eight.astype(np.uint16) * 257),
                                  detect_breast(eight))


@seed(15)
@settings(FEW, max_examples=5)
@given(mammograms(), st.integers(2, 3), st.floats(0.3, 1.2), st.booleans())
def test_segment_breast_labels_the_breast_only(image, k, gain, given_breast):
    options = dict(levels=1, n_segments=k, n_init=3, work_side=64)
    breast = None
    if given_breast:  # a hand-drawn breast: a rectangle inside the film
        h, w = image.shape
        breast = np.zeros(image.shape, bool)
        breast[h // 8:-h // 8, w // 4:-w // 4] = True
    seg = _untouched(lambda: segment_breast(image, breast=breast, **options), image)
    assert seg.segments.dtype == np.int32 and seg.segments.shape == image.shape
    want = detect_breast(image) if breast is None else breast
    np.testing.assert_array_equal(seg.breast, want)
    # 0 outside the breast, segments 1..k in it: everywhere at the working
    # resolution (1:1 here), else all but the edge blocks mostly off the breast
    labelled = seg.segments > 0
    assert not (labelled & ~want).any()
    assert set(np.unique(seg.segments[labelled])) <= set(range(1, k + 1))
    assert seg.factor >= 1 and max(image.shape) / seg.factor < 2 * 64
    if seg.factor == 1:
        np.testing.assert_array_equal(labelled, want)
    assert labelled.sum() >= 0.8 * want.sum()
    # the features are standardised: a gain on the film gives the same segments
    again = segment_breast(gain * image, breast=breast, **options)
    np.testing.assert_array_equal(again.segments, seg.segments)
    # the same seed, the same segments; pooled labellings keep the breast too
    np.testing.assert_array_equal(segment_breast(image, breast=breast, **options).segments,
                                  seg.segments)
    pooled = segment_breast(image, breast=breast, levels=1, n_init=4, work_side=64,
                            pool=(2, 3)).pooled
    for labels, n in zip(pooled, (2, 3), strict=True):
        np.testing.assert_array_equal(labels > 0, labelled)
        assert labels.max() <= n


# ------------------------------------------------------------- local_features
@seed(15)
@FEW
@given(textures(20, 28, scale=1.0), st.integers(1, 3), st.booleans(), _GAINS, _OFFSETS)
def test_local_features_are_standardised_and_grey_scale_free(image, components, energy, gain,
                                                             offset):
    options = dict(levels=1, components=components, energy=energy)
    features = _untouched(lambda: car.local_features(image, **options), image)
    c = 1 if image.ndim == 2 else image.shape[2]
    # per level: components + 1 parameter values, the log energy, the local mean spectrum
    assert features.dtype == np.float32
    assert features.shape == (*image.shape[:2], components + 1 + energy + c)
    assert np.isfinite(features).all()
    flat = features.reshape(-1, features.shape[2]).astype(np.float64)
    np.testing.assert_allclose(flat.mean(axis=0), 0.0, atol=1e-4)
    np.testing.assert_allclose(flat.std(axis=0), 1.0, atol=1e-3)
    # every feature is standardised: one gain and offset on all channels change nothing
    scaled = car.local_features(gain * image + offset, **options)
    np.testing.assert_allclose(scaled, features, atol=2e-3)
    # the four scan directions are symmetric: a transposed image, transposed features
    swapped = car.local_features(np.swapaxes(image, 0, 1), **options)
    np.testing.assert_allclose(np.swapaxes(swapped, 0, 1), features, atol=2e-3)
    # the same seed, the same features
    np.testing.assert_array_equal(car.local_features(image, **options), features)


@seed(15)
@settings(FEW, max_examples=3)
@given(textures(32, 40, colour=False, scale=1.0), st.integers(1, 2))
def test_local_features_stack_their_levels(image, components):
    features = car.local_features(image, levels=2, components=components)
    assert features.shape == (*image.shape, 2 * (components + 1 + 1 + 1))
    assert np.isfinite(features).all()


# --------------------------------------------------------------- texture models
# stationary textures: a ramp's model is unstable, and the search for a
# stable fallback takes seconds (tests/texture cover it)
_STATIONARY = ("noise", "blurred")


@st.composite
def lit_stacks(draw):
    """(n, H, W[, C]) stacks of one texture under 2 to 5 gains and offsets,
    each image with its own noise; sometimes an image repeated."""
    n = draw(st.integers(2, 5))
    base = draw(textures(16, 22, scale=1.0, kinds=_STATIONARY))
    rng = np.random.default_rng(draw(_SEEDS))
    lights = draw(st.lists(st.tuples(st.floats(0.1, 1.0), st.floats(0.0, 0.3)),
                           min_size=n, max_size=n))
    stack = np.stack([g * base + o + 0.05 * rng.random(base.shape) for g, o in lights])
    if draw(st.booleans()):
        stack[-1] = stack[0]
    return stack


@seed(15)
@settings(FEW, max_examples=5)
@given(lit_stacks(), st.integers(1, 3), st.floats(0.5, 20), st.floats(-5, 5), _SEEDS)
def test_btf_model_keeps_each_image_and_ignores_the_stack_scale(stack, k, gain, offset, seed_):
    n = len(stack)
    k = min(k, n)
    btf = _untouched(lambda: BTFModel.fit(stack, n_subspaces=k, levels=1), stack)
    c = 1 if stack.ndim == 3 else stack.shape[3]
    # the per-image statistics the synthesis restores
    flat = stack.reshape(n, -1, c)
    np.testing.assert_allclose(btf.image_mean, flat.mean(axis=1), rtol=1e-12)
    np.testing.assert_allclose(btf.image_std, flat.std(axis=1), rtol=1e-9)
    np.testing.assert_array_equal(btf.image_range,
                                  np.stack([flat.min(axis=1), flat.max(axis=1)], axis=1))
    # subspaces 0..k'-1, each with a model fitted to one of its own images
    found = len(btf.models)
    assert 1 <= found <= k and sorted(set(btf.assignment.tolist())) == list(range(found))
    assert [btf.assignment[r] for r in btf.representatives] == list(range(found))
    if np.array_equal(stack[-1], stack[0]):
        assert btf.assignment[-1] == btf.assignment[0]  # the same image, the same subspace
    assert btf.compression_ratio(stack.shape) == 4 * stack.size / btf.nbytes
    out = btf.synthesize((9, 11), seed=seed_)
    assert out.shape == (n, 9, 11) + stack.shape[3:] and np.isfinite(out).all()
    for image, (low, high) in zip(out, btf.image_range, strict=True):
        assert (image >= low).all() and (image <= high).all()  # each image's own range
    np.testing.assert_array_equal(btf.synthesize((9, 11), seed=seed_), out)
    # a gain and an offset on the whole stack: the same subspaces, the images scaled
    scaled = BTFModel.fit(gain * stack + offset, n_subspaces=k, levels=1)
    np.testing.assert_array_equal(scaled.assignment, btf.assignment)
    np.testing.assert_allclose(scaled.image_mean, gain * btf.image_mean + offset, rtol=1e-9,
                               atol=1e-9 * (gain + abs(offset)))
    # (the models' parameters are float32, and the histogram restore moves a
    # value that their rounding takes past a quantile a little further)
    spread = gain * (btf.image_range[:, 1] - btf.image_range[:, 0]).max()
    error = np.abs(scaled.synthesize((9, 11), seed=seed_) - (gain * out + offset))
    assert error.max() <= 1e-2 * spread and error.mean() <= 1e-4 * spread


@st.composite
def clips(draw):
    """(T, H, W[, C]) clips of 2 or 3 frames: a drifting texture plus fresh noise."""
    t = draw(st.integers(2, 3))
    base = draw(textures(16, 22, scale=1.0, kinds=_STATIONARY))
    rng = np.random.default_rng(draw(_SEEDS))
    step = draw(st.integers(0, 2))
    return np.stack([np.roll(base, step * k, axis=1) + 0.3 * rng.random(base.shape)
                     for k in range(t)])


@seed(15)
@FEW
@given(clips(), st.sampled_from([1, 2]), st.floats(0.1, 30), st.floats(-5, 5), _SEEDS)
def test_dynamic_texture_model_is_affine_equivariant(clip, order, gain, offset, seed_):
    model = _untouched(lambda: DynamicTextureModel.fit(clip, neighbourhood=order), clip)
    d = 1 if clip.ndim == 3 else clip.shape[3]
    m = temporal_context(model.offsets, d).n_regressors
    assert model.gamma.shape == (d, m) and model.sigma.shape == (d, d)
    assert model.n_channels == d and model.grey == (clip.ndim == 3)
    np.testing.assert_allclose(model.sigma, model.sigma.T, rtol=1e-12)
    assert np.linalg.eigvalsh(model.sigma).min() >= -1e-12 * np.abs(model.sigma).max()
    flat = clip.reshape(-1, d)
    np.testing.assert_allclose(model.mean, flat.mean(axis=0), rtol=1e-12)
    np.testing.assert_array_equal(model.value_range, [flat.min(axis=0), flat.max(axis=0)])
    out = model.synthesize(3, (7, 9), seed=seed_)
    assert out.shape == (3, 7, 9) + clip.shape[4:] + clip.shape[3:] and np.isfinite(out).all()
    assert (out >= model.value_range[0]).all() and (out <= model.value_range[1]).all()
    np.testing.assert_array_equal(model.synthesize(3, (7, 9), seed=seed_), out)
    # the least-squares model of a*Y + b: the same gamma and fallbacks, sigma
    # times a^2, and with the same seed the clip a*Y + b
    scaled = DynamicTextureModel.fit(gain * clip + offset, neighbourhood=order)
    assert scaled.fallbacks == model.fallbacks
    np.testing.assert_allclose(scaled.gamma, model.gamma, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(scaled.sigma, gain**2 * model.sigma, rtol=1e-6,
                               atol=1e-12 * gain**2)
    span = gain * float(np.ptp(clip))
    np.testing.assert_allclose(scaled.synthesize(3, (7, 9), seed=seed_), gain * out + offset,
                               atol=1e-6 * span)
