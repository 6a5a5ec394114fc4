"""Plain-NumPy reference generators for tests (independent of car_napari's kernels)."""

from pathlib import Path

import numpy as np

# The real data beside the repository (../shared/data); absent in some clones.
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

# The hierarchical neighbourhoods of SPEC 1.1, written out by hand.
ORDERS = {
    1: [(0, 1), (1, 0)],
    2: [(0, 1), (1, 0), (1, -1), (1, 1)],
    3: [(0, 1), (1, 0), (1, -1), (1, 1), (0, 2), (2, 0)],
    4: [(0, 1), (1, 0), (1, -1), (1, 1), (0, 2), (2, 0), (1, -2), (1, 2), (2, -1), (2, 1)],
    5: [(0, 1), (1, 0), (1, -1), (1, 1), (0, 2), (2, 0), (1, -2), (1, 2), (2, -1), (2, 1),
        (2, -2), (2, 2)],
}


def random_stable_model(order, d, seed, total_gain=0.9, min_share=0.5):
    """Matrices A_s with sum ||A_s||_2 = total_gain < 1 (a sufficient stability
    condition). The offsets that order adds over order-1 get at least
    ``min_share`` of an equal share, so the true order is identifiable."""
    rng = np.random.default_rng(seed)
    offsets = ORDERS[order]
    n_new = len(offsets) - (len(ORDERS[order - 1]) if order > 1 else 0)
    weights = rng.uniform(0.5, 1.0, len(offsets))
    weights[-n_new:] = np.maximum(weights[-n_new:], min_share)
    weights *= total_gain / weights.sum()
    A = []
    for wgt in weights:
        M = rng.standard_normal((d, d))
        M /= np.linalg.norm(M, 2)
        A.append(wgt * M * rng.choice([-1, 1]))
    Q = rng.standard_normal((d, d))
    sigma = Q @ Q.T / d + 0.5 * np.eye(d)
    return np.array(A), np.array(offsets), sigma


def car_field(A, offsets, sigma, shape, seed, burn=64):
    """Generate Y_r = sum_s A_s Y_{r-s} + e_r in raster order, e_r ~ N(0, sigma).

    Previous-row contributions are vectorised along the row; the in-row
    recursion (di == 0) runs pixel by pixel. A burn-in margin is cropped.
    """
    rng = np.random.default_rng(seed)
    H, W = shape
    d = A.shape[1]
    Hb, Wb = H + burn, W + 2 * burn
    pad = 4
    Y = np.zeros((Hb + pad, Wb + 2 * pad, d))
    E = rng.standard_normal((Hb, Wb, d)) @ np.linalg.cholesky(sigma).T
    prev = [(a, di, dj) for a, (di, dj) in zip(A, offsets, strict=True) if di > 0]
    same = [(a, dj) for a, (di, dj) in zip(A, offsets, strict=True) if di == 0]
    for i in range(Hb):
        r = i + pad
        row = E[i].copy()
        for a, di, dj in prev:
            row += Y[r - di, pad - dj : pad - dj + Wb] @ a.T
        for j in range(Wb):
            acc = row[j]
            for a, dj in same:
                acc = acc + a @ Y[r, pad + j - dj]
            Y[r, pad + j] = acc
    return Y[pad + burn :, pad + burn : pad + burn + W]


def gamma_of(A):
    """[A_1, ..., A_eta] as a (d, d*eta) matrix (SPEC 1.2)."""
    return np.concatenate(list(A), axis=1)
