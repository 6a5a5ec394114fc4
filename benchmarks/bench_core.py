"""Core benchmarks, run by hand (not part of the test suite).

    python benchmarks/bench_core.py            # timings of the core functions
    python benchmarks/bench_core.py --startup  # cold / warm process start to first result

Prints ns/pixel for ``local_parameters`` (1024x1024x3, order 2, one direction)
beside a plain (non-square-root, explicit-inverse) Numba RLS kernel doing the
same regression in the same process, and seconds for fit_car, predict and
synthesize.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def plain_rls(data, offsets, phi, prior, gamma_out):
    """Textbook exponentially weighted RLS with an explicit P = V_x^{-1}
    (the kernel the square-root form replaces), raster scan, intercept."""
    H, W, d = data.shape
    eta = offsets.shape[0]
    m = eta * d
    p = m + 1
    P = np.eye(p) / prior
    G = np.zeros((p, d))
    x = np.empty(p)
    Px = np.empty(p)
    phi2 = phi * phi
    inv_phi2 = 1.0 / phi2
    for i in range(H):
        for j in range(W):
            ok = True
            for s in range(eta):
                ii = i - offsets[s, 0]
                jj = j - offsets[s, 1]
                if ii < 0 or jj < 0 or jj >= W:
                    ok = False
            if ok:
                for s in range(eta):
                    for c in range(d):
                        x[s * d + c] = data[i - offsets[s, 0], j - offsets[s, 1], c]
                x[m] = 1.0
                denom = phi2
                for a in range(p):
                    acc = 0.0
                    for b in range(p):
                        acc += P[a, b] * x[b]
                    Px[a] = acc
                    denom += x[a] * acc
                inv_denom = 1.0 / denom
                for t in range(d):
                    e = data[i, j, t]
                    for a in range(p):
                        e -= G[a, t] * x[a]
                    for a in range(p):
                        G[a, t] += Px[a] * e * inv_denom
                for a in range(p):
                    ka = Px[a] * inv_denom
                    for b in range(p):
                        P[a, b] = (P[a, b] - ka * Px[b]) * inv_phi2
            for t in range(d):
                for k in range(m):
                    gamma_out[i, j, t, k] = G[k, t]


def best_of(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def timings():
    import car_napari as cn
    from car_napari.model.neighbourhood import causal_neighbourhood

    rng = np.random.default_rng(0)
    from skimage import data

    img = np.tile(data.astronaut() / 255.0, (2, 2, 1))  # 1024 x 1024 x 3
    img = img + 1e-3 * rng.standard_normal(img.shape)
    npx = img.shape[0] * img.shape[1]
    offsets = causal_neighbourhood(2)

    cn.local_parameters(img[:64, :64], 2)  # compile / load the kernel
    out = np.empty((1024, 1024, 3, 12))
    plain_rls(img[:64, :64].copy(), offsets, 0.99, 1e-6, out[:64, :64])

    # Interleaved, best of 5 each: the two see the same machine load. Both
    # allocate their (H, W, 3, 12) output, as a library call must.
    t_sqrt, t_plain = [], []
    for _ in range(5):
        t_sqrt.append(best_of(lambda: cn.local_parameters(img, 2, forgetting=0.99), 1))
        t_plain.append(
            best_of(lambda: plain_rls(img, offsets, 0.99, 1e-6, np.empty_like(out)), 1)
        )
    t_sqrt, t_plain = min(t_sqrt), min(t_plain)
    rows = [
        ("local_parameters 1024x1024x3 order 2 (square-root)", t_sqrt * 1e9 / npx, "ns/pixel"),
        ("plain RLS kernel, same data, same process", t_plain * 1e9 / npx, "ns/pixel"),
        ("ratio square-root / plain", t_sqrt / t_plain, ""),
    ]
    for label, value, unit in rows:
        print(f"{label:52s} {value:7.2f} {unit}")

    for order in (2, 5):
        t = best_of(lambda order=order: cn.fit_car(img, order))
        per_px = t * 1e9 / npx
        print(f"fit_car 1024x1024x3 order {order}:        {t:6.3f} s ({per_px:5.0f} ns/pixel)")
    t = best_of(lambda: cn.select_support(img))
    print(f"select_support 1024x1024x3 orders 1-5: {t:6.3f} s")
    model = cn.fit_car(img, 2)
    cn.predict(model, img[:32, :32])
    t = best_of(lambda: cn.predict(model, img))
    print(f"predict 1024x1024x3 order 2:          {t:6.3f} s ({t * 1e9 / npx:5.0f} ns/pixel)")
    cn.synthesize(model, (16, 16), seed=0)
    t = best_of(lambda: cn.synthesize(model, (1024, 1024), seed=0))
    print(f"synthesize 1024x1024x3 order 2:       {t:6.3f} s")
    t = best_of(lambda: cn.illumination_invariants(img[:512, :512], levels=3))
    print(f"illumination_invariants 512x512x3, 3 levels: {t:6.3f} s")


FIRST_RESULT = (
    "import time; t0 = time.perf_counter(); import numpy as np, car_napari as cn; "
    "img = np.random.default_rng(0).random((256, 256, 3)); "
    "g = cn.local_parameters(img, 2); m = cn.fit_car(img, 'auto'); "
    "s = cn.synthesize(m, (64, 64), seed=0); "
    "print(f'{time.perf_counter() - t0:.2f}')"
)


def startup():
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for label in ("cold (empty Numba cache)", "warm (cache filled)", "warm again"):
            t0 = time.perf_counter()
            inner = subprocess.run(
                [sys.executable, "-c", FIRST_RESULT], env=env, capture_output=True, text=True,
                check=True,
            ).stdout.strip()
            total = time.perf_counter() - t0
            print(f"{label:28s} process start to first result: {total:5.2f} s "
                  f"(after interpreter start: {inner} s)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--startup", action="store_true", help="only the start-up timings")
    args = parser.parse_args()
    if args.startup:
        startup()
    else:
        timings()
        startup()
