"""The recursive scan in chunks of rows (issue 12): any chunking, streamed or not,
gives bit for bit the one-call kernel's outputs and final statistics; the job
forms yield between chunks and return what the plain calls return."""

import numpy as np
import pytest
from skimage import data as skdata

from car_fields import ORDERS
from car_napari import Context, local_parameters
from car_napari._progress import drain
from car_napari.model import iter_local_parameters
from car_napari.model.adaptive import adaptive_scanner
from car_napari.model.recursive import (
    OUTPUTS,
    RecursiveScan,
    default_prior,
    iter_scan,
    scan,
    scan_view,
)

STATS = ("T", "G", "lam", "beta", "count")


def _image(d, shape=(37, 29)):
    if d == 3:
        img = skdata.astronaut()[200 : 200 + shape[0], 180 : 180 + shape[1]] / 255.0
    else:
        img = skdata.camera()[300 : 300 + shape[0], 250 : 250 + shape[1], None] / 255.0
    return np.ascontiguousarray(img - img.mean(axis=(0, 1)))


def _same(a, b):
    assert set(a) == set(b)
    for key in a:
        np.testing.assert_array_equal(np.asarray(a[key]), np.asarray(b[key]), err_msg=key)


def _run(scanner, rows):
    """Advance to the end in chunks of ``rows`` (a list cycles); gather the
    chunks' outputs into image geometry."""
    rows = list(np.atleast_1d(rows))
    gathered = {k: None for k in scanner.outputs}
    h, w = scanner._shape
    k = 0
    while not scanner.done:
        chunk = scanner.advance(int(rows[k % len(rows)]))
        k += 1
        for name, arr in chunk.outputs.items():
            if gathered[name] is None:
                gathered[name] = np.empty((h, w) + arr.shape[2:])
            scan_view(gathered[name], scanner.direction)[chunk.start : chunk.stop] = arr
    result = scanner.result()
    if scanner.stream:
        result.update(gathered)
    else:
        for name in scanner.outputs:
            np.testing.assert_array_equal(gathered[name], result[name])
    return result


@pytest.mark.parametrize("direction", ["down", "up", "right", "left"])
@pytest.mark.parametrize("phi, warm", [(1.0, False), (0.99, False), (0.99, True), (0.7, True)])
@pytest.mark.parametrize("d", [1, 3])
def test_chunks_equal_one_call(direction, phi, warm, d):
    img = _image(d)
    ctx = Context.spatial(np.array(ORDERS[2]), d)
    kwargs = dict(forgetting=phi, direction=direction, warm_start=warm, outputs=OUTPUTS)
    whole = adaptive_scanner(img.copy(), ctx, img.var(axis=(0, 1)), **kwargs).run()
    assert whole["count"] > 0
    for rows in (1, 3, [2, 5, 1], 1000):
        for stream in (False, True):
            scanner = adaptive_scanner(img.copy(), ctx, img.var(axis=(0, 1)), stream=stream,
                                       **kwargs)
            _same(_run(scanner, rows), whole)


@pytest.mark.parametrize("direction", ["down", "left"])
@pytest.mark.parametrize("phi", [1.0, 0.95])
def test_chunked_fills_and_suspects_equal_one_call(direction, phi):
    img = _image(3, (40, 33))
    ctx = Context.spatial(np.array(ORDERS[2]), 3)
    rng = np.random.default_rng(1)
    codes = (rng.random(img.shape[:2]) < 0.06).astype(np.uint8)
    codes[(rng.random(img.shape[:2]) < 0.06) & (codes == 0)] = 2
    prior = default_prior(img.var(axis=(0, 1)), ctx.n_regressors, True, 3, 1e-4)
    kwargs = dict(direction=direction, forgetting=phi, intercept=True, prior=prior,
                  outputs=("mean", "logrel"), fill_range=(-0.3, 0.3), suspect_logrel=-3.0)
    work, missing = img.copy(), codes.copy()
    whole = scan(work, ctx, missing=missing, **kwargs)
    assert (missing != codes).any() and (work != img).any()  # fills happened
    for rows in (1, 4, 7):
        work_c, missing_c = img.copy(), codes.copy()
        res = drain(iter_scan(work_c, ctx, missing=missing_c, chunk_rows=rows, **kwargs))
        _same(res, whole)
        np.testing.assert_array_equal(work_c, work)
        np.testing.assert_array_equal(missing_c, missing)


def test_fixed_model_and_given_start_in_chunks():
    img = _image(3)
    ctx = Context.spatial(np.array(ORDERS[1]), 3)
    n = ctx.n_regressors + 3
    rng = np.random.default_rng(2)
    A = rng.standard_normal((n, n))
    U0 = np.linalg.cholesky(A @ A.T + n * np.eye(n)).T
    for update in (False, True):
        kwargs = dict(direction="up", initial=(U0, 20.0), update=update, forgetting=0.98,
                      outputs=("mean", "logp", "q", "maha"))
        whole = scan(img.copy(), ctx, **kwargs)
        _same(drain(iter_scan(img.copy(), ctx, chunk_rows=5, **kwargs)), whole)


def test_many_rescales_and_injections_across_chunks():
    # phi = 0.7: tau passes the rescaling threshold every ~130 learned pixels and
    # the prior's round robin wraps every few pixels; chunks of one row cut
    # through both schedules at every row.
    img = _image(3, (60, 50))
    ctx = Context.spatial(np.array(ORDERS[3]), 3)
    kwargs = dict(forgetting=0.7, direction="right", outputs=("gamma",))
    whole = adaptive_scanner(img.copy(), ctx, img.var(axis=(0, 1)), **kwargs).run()
    chunked = drain(adaptive_scanner(img.copy(), ctx, img.var(axis=(0, 1)),
                                     **kwargs).iter_run(chunk_rows=1))
    _same(chunked, whole)


def test_iter_local_parameters_is_local_parameters():
    image = skdata.astronaut()[:90, :70]
    records = []
    gamma = drain(iter_local_parameters(image, 2, direction="right", chunk_rows=9),
                  records.append)
    np.testing.assert_array_equal(gamma, local_parameters(image, 2, direction="right"))
    assert [r.stage for r in records] == ["scan"] * 8  # 70 scan rows in chunks of 9
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert records[0].message == "right scan: rows 9/70"
    # the default chunking too
    np.testing.assert_array_equal(drain(iter_local_parameters(image, 2, direction="right")),
                                  gamma)


def test_closing_the_job_stops_the_scan():
    image = np.random.default_rng(0).random((120, 50))
    job = iter_local_parameters(image, 1, chunk_rows=10)
    first = next(job)
    assert first.fraction == pytest.approx(10 / 120)
    job.close()
    with pytest.raises(StopIteration):
        next(job)


def test_default_chunks_are_a_fraction_of_a_second_of_work():
    # An order-2 RGB scan writing its gamma to a new array costs up to ~0.5-1
    # us/pixel (random data, page faults; ~0.1-0.3 on 8-bit images): a chunk
    # of at most ~0.25 s is 0.1-0.5 M pixels; grey costs less per pixel, so
    # more pixels; a 4000x4000 image is never one chunk. (Time itself is
    # measured in benchmarks/bench_core.py.)
    big = np.zeros((4000, 4000, 3))
    rgb = RecursiveScan(big, Context.spatial(np.array(ORDERS[2]), 3), intercept=True,
                        prior=np.ones(16))
    assert 1e5 <= rgb.chunk_rows * 4000 <= 5e5
    grey = RecursiveScan(big[..., :1], Context.spatial(np.array(ORDERS[2]), 1),
                         intercept=True, prior=np.ones(6))
    assert rgb.chunk_rows < grey.chunk_rows < 4000
    streamed = RecursiveScan(big, Context.spatial(np.array(ORDERS[2]), 3), intercept=True,
                             prior=np.ones(16), stream=True)
    assert streamed.stream_rows * 4000 * 36 * 8 <= 16 * 2**20  # the buffer: a few MB
    assert streamed.pixel_work < rgb.pixel_work


def test_bad_outputs():
    img = _image(1)
    with pytest.raises(ValueError, match="unknown outputs"):
        RecursiveScan(img, Context.spatial([[0, 1]], 1), prior=np.ones(2), outputs=("nope",))
