"""The pectoral muscle cut of detect_breast: the edge-step choice among
candidate levels (an option, not the default; benchmarks/bench_pectoral.py)."""

import numpy as np
import pytest
from skimage import io

from car_fields import SHARED_DATA
from car_napari.io.sample_data import resource_path
from car_napari.mammography import _breast
from car_napari.mammography._images import _grey01, _upsample_mask

LEVELS = (0.5, 0.4, 0.3, 0.2)  # bench_pectoral.py's "edge step" variant


def _working(grey):
    """The smoothed working image, the breast before the cut, its chest-wall
    side and the working factor, as detect_breast computes them."""
    factor, smooth, t = _breast._background(grey)
    mask, side = _breast._breast_with_muscle(smooth, t)
    return smooth, mask, side, factor


def _plain_edge_step(grey, breast, pect, width):
    inside, outside = [], []
    h, w = grey.shape
    for r in range(h):
        for c in range(w):
            ahead = range(c + 1, min(w, c + width + 1))
            behind = range(max(0, c - width), c)
            if pect[r, c] and any(breast[r, k] and not pect[r, k] for k in ahead):
                inside.append(grey[r, c])
            if breast[r, c] and not pect[r, c] and any(pect[r, k] for k in behind):
                outside.append(grey[r, c])
    return np.mean(inside) - np.mean(outside)


def test_edge_step_against_a_plain_computation():
    rng = np.random.default_rng(3)
    grey = rng.random((24, 32))
    breast = np.zeros((24, 32), bool)
    breast[2:22, 1:28] = True
    rows, cols = np.mgrid[0:24, 0:32]
    pect = breast & (cols < 20 - rows)  # a triangle in the top-left corner
    for width in (1, 3):
        assert _breast._edge_step(grey, breast, pect, width) == pytest.approx(
            _plain_edge_step(grey, breast, pect, width), rel=1e-12)
    assert _breast._edge_step(grey, breast, np.zeros_like(pect)) == -np.inf


def test_levels_keep_the_accepted_cut_of_largest_edge_step():
    """On the sample mammogram (mini-MIAS mdb001, chest wall on the right)."""
    smooth, mask, side, _ = _working(_grey01(io.imread(str(resource_path(
        "mammogram_mdb001.png")))))
    assert side == "right"
    grey, breast = smooth[:, ::-1], mask[:, ::-1]
    cuts = [_breast._pectoral(grey, breast, level=v) for v in LEVELS]
    cuts = [c for c in cuts if c.any()]
    assert len(cuts) >= 2
    best = max(cuts, key=lambda c: _breast._edge_step(grey, breast, c))
    np.testing.assert_array_equal(_breast._pectoral(grey, breast, level=LEVELS), best)
    # the default is the single level 0.5
    np.testing.assert_array_equal(_breast._pectoral(grey, breast),
                                  _breast._pectoral(grey, breast, level=0.5))


def test_edge_step_cuts_the_muscle_of_a_ddsm_tissue_film():
    """ddsm-tissue A_0589 (label 255: the pectoral muscle): the single level
    0.5 cuts the muscle's bright top only (Jaccard 0.38), the edge step
    follows its edge (0.75)."""
    folder = SHARED_DATA / "mammograms" / "ddsm-tissue"
    name = "A_0589_1.RIGHT_MLO"
    if not (folder / "fgt_seg" / f"{name}.png").exists():
        pytest.skip(f"real data not found at {folder} (clone with ../shared beside it)")
    grey = _grey01(io.imread(folder / "fgt_seg" / f"{name}.png"))
    truth = io.imread(folder / "fgt_seg_labels" / f"{name}_LI.png") == 255
    smooth, mask, side, factor = _working(grey)

    def jaccard(**options):
        cut = _breast._chest_wall_left(_breast._pectoral, smooth, mask, side, **options)
        cut = _upsample_mask(cut, grey.shape, factor)
        return (cut & truth).sum() / (cut | truth).sum()

    assert jaccard(level=0.5) < 0.45
    assert jaccard(level=LEVELS) > 0.7


def test_theil_sen_is_the_median_of_pairwise_slopes_as_in_scipy():
    """Slope: median of (y_j - y_i) / (x_j - x_i) over the pairs with
    x_j > x_i (tied x left out); intercept: median(y) - slope median(x), the
    'separate' intercept of scipy.stats.theilslopes."""
    from scipy import stats

    rng = np.random.default_rng(5)
    for n, ties in ((2, False), (7, False), (40, True), (41, True)):
        x = (rng.integers(0, n // 2 + 1, n) if ties else rng.permutation(n)).astype(float)
        y = 3.0 - 0.7 * x + rng.standard_normal(n)
        y[rng.random(n) < 0.2] += 25.0  # outliers
        slopes = [(y[j] - y[i]) / (x[j] - x[i])
                  for i in range(n) for j in range(n) if x[j] > x[i]]
        slope = np.median(slopes)
        b, a = _breast._theil_sen(y, x)
        assert b == pytest.approx(slope, rel=1e-12)
        assert a == pytest.approx(np.median(y) - slope * np.median(x), rel=1e-12, abs=1e-12)
        scipy_fit = stats.theilslopes(y, x, method="separate")
        assert (b, a) == pytest.approx((scipy_fit.slope, scipy_fit.intercept), rel=1e-12)
