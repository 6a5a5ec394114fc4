"""Thread use: every job runs with BLAS limited (``drain``, nested, in several threads at
once), the limits found before come back, and ``CAR_NAPARI_BLAS_THREADS`` overrides."""

import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import car_napari as car
from car_napari._progress import Progress, drain
from car_napari._threads import (
    blas_threads,
    job_threads,
    limited_blas,
    lower_thread_priority,
    usable_cpus,
    worker_nice,
)


def _blas():
    """The thread counts of the BLAS libraries loaded (numpy's at least)."""
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def _probe(seen, inner=None):
    """A job that notes the BLAS thread counts it runs with (and runs ``inner`` as a stage)."""
    seen.append(_blas())
    yield Progress("probe", 0.5)
    if inner is not None:
        drain(inner)  # a plain core function called inside a job
    seen.append(_blas())
    return len(seen)


@pytest.fixture
def two_threads(monkeypatch):
    """BLAS at two threads around the test, so that a limit to one shows."""
    monkeypatch.delenv("CAR_NAPARI_BLAS_THREADS", raising=False)
    with threadpool_limits(limits=2, user_api="blas"):
        yield _blas()


def test_drain_limits_blas_and_puts_the_limits_back(two_threads):
    seen = []
    assert drain(_probe(seen, inner=_probe(seen))) == 4
    assert seen and all(counts and set(counts) == {1} for counts in seen)
    assert _blas() == two_threads
    with pytest.raises(ZeroDivisionError):
        with limited_blas():
            raise ZeroDivisionError("a job that fails")
    assert _blas() == two_threads


def test_the_limit_holds_until_the_last_job_in_any_thread_ends(two_threads):
    entered, release, seen = threading.Event(), threading.Event(), []

    def other():
        with limited_blas():
            entered.set()
            release.wait(30)
            seen.append(_blas())

    thread = threading.Thread(target=other)
    thread.start()
    assert entered.wait(30)
    with limited_blas() as limit:  # a second job starts and ends while the first runs
        assert limit == 1
    seen.append(_blas())
    release.set()
    thread.join(30)
    assert seen == [[1] * len(two_threads)] * 2
    assert _blas() == two_threads


def test_the_environment_overrides_the_limit(two_threads, monkeypatch):
    monkeypatch.setenv("CAR_NAPARI_BLAS_THREADS", "off")
    assert blas_threads() is None
    with limited_blas() as limit:
        assert limit is None and _blas() == two_threads
    monkeypatch.setenv("CAR_NAPARI_BLAS_THREADS", "64")
    assert blas_threads() == usable_cpus()
    monkeypatch.setenv("CAR_NAPARI_BLAS_THREADS", "many")
    with pytest.raises(ValueError, match="CAR_NAPARI_BLAS_THREADS"):
        blas_threads()
    monkeypatch.delenv("CAR_NAPARI_BLAS_THREADS")
    assert blas_threads() == 1


def test_usable_cpus_is_the_affinity():
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    assert usable_cpus() == (expected or os.cpu_count() or 1)


def test_a_core_job_runs_limited(two_threads):
    # the command line's way: a core job drained with a progress callback
    seen = []
    car.drain(car.iter_restore(np.random.default_rng(0).random((32, 32))),
              lambda record: seen.append(_blas()))
    assert seen and all(set(counts) == {1} for counts in seen)
    assert _blas() == two_threads


def test_jobs_in_one_thread_after_another_are_each_limited(two_threads):
    # threadpoolctl lets only the thread that set OpenBLAS's limits set them again: a job
    # started in a fresh thread (a napari worker) after one in another thread is limited too
    seen = []

    def job():
        probe = []
        drain(_probe(probe))
        seen.append(probe)

    for _ in range(3):
        thread = threading.Thread(target=job)
        thread.start()
        thread.join(30)
    assert len(seen) == 3 and all(set(counts) == {1} for probe in seen for counts in probe)
    assert _blas() == two_threads


def test_job_threads_default_and_environment(monkeypatch):
    monkeypatch.delenv("CAR_NAPARI_JOB_THREADS", raising=False)
    assert job_threads() == min(2, usable_cpus())
    monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", "1")
    assert job_threads() == 1
    for bad in ("0", "-2", "two"):
        monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", bad)
        with pytest.raises(ValueError, match="CAR_NAPARI_JOB_THREADS"):
            job_threads()


@pytest.mark.skipif(usable_cpus() < 2, reason="needs two CPUs to run side by side")
def test_segmentation_is_the_same_on_one_thread_and_two(monkeypatch):
    """The scans side by side, the smoothings two at a time and the E step's
    two halves on two threads give what one thread gives, bit for bit (a
    cluster worker runs on one thread, the in-process batch on two)."""
    from skimage import data as skdata

    from car_napari.segmentation import local_features, segment

    image = np.concatenate([skdata.brick()[:160, :90], skdata.grass()[:160, :90]], axis=1)
    results = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", threads)
        result = segment(image, n_segments=2, levels=2)
        results[threads] = (local_features(image, levels=2), result.labels)
    np.testing.assert_array_equal(results["1"][0], results["2"][0])
    np.testing.assert_array_equal(results["1"][1], results["2"][1])


def test_job_pool_is_one_shared_pool_sized_by_the_job_threads(monkeypatch):
    # the features' scans and the mixture's E step share it (they had a pool each)
    from car_napari import _threads
    from car_napari.segmentation import _features, _mixture

    monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", "1")
    assert _threads.job_pool() is None
    if usable_cpus() >= 2:
        monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", "2")
        pool = _threads.job_pool()
        assert pool is _threads.job_pool() and pool._max_workers == 2
    assert _features.job_pool is _threads.job_pool is _mixture.job_pool


def _nice():
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux's")
def test_a_lowered_thread_and_the_threads_it_starts_run_below_the_main_thread():
    main = os.getpriority(os.PRIO_PROCESS, os.getpid())
    seen = {}

    def child():
        seen["child"] = _nice()

    def worker():
        seen["returned"] = lower_thread_priority(3)
        seen["again"] = lower_thread_priority(1)  # never raised again: stays at +3
        seen["worker"] = _nice()
        started = threading.Thread(target=child)
        started.start()
        started.join()

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    want = min(19, main + 3)
    assert seen == {"returned": want, "again": want, "worker": want, "child": want}
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == main  # the main thread as it was


def test_worker_nice_default_and_environment(monkeypatch):
    monkeypatch.delenv("CAR_NAPARI_WORKER_NICE", raising=False)
    assert worker_nice() == 5
    monkeypatch.setenv("CAR_NAPARI_WORKER_NICE", "0")
    assert worker_nice() == 0
    for bad in ("-1", "20", "low"):
        monkeypatch.setenv("CAR_NAPARI_WORKER_NICE", bad)
        with pytest.raises(ValueError, match="CAR_NAPARI_WORKER_NICE"):
            worker_nice()
    with pytest.raises(ValueError, match="nice"):
        lower_thread_priority(25)


class _CountingPool(ThreadPoolExecutor):
    """A thread pool that counts the calls submitted to it."""

    def __init__(self, threads):
        super().__init__(threads, thread_name_prefix="car-job-test")
        self.calls = 0

    def submit(self, *args, **kwargs):
        self.calls += 1
        return super().submit(*args, **kwargs)


def _applications():
    """Every application's call on a small case: (name, run() -> array)."""
    from skimage import data as skdata

    from car_napari.inpainting import inpaint
    from car_napari.restoration import restore, restore_multichannel, restore_tiled
    from car_napari.segmentation import segment

    rng = np.random.default_rng(3)
    colour = skdata.astronaut()[100:164, 100:164] / 255.0
    noisy = colour + 0.05 * rng.standard_normal(colour.shape)
    versions = np.stack([colour + 0.05 * rng.standard_normal(colour.shape) for _ in range(3)])
    damaged = skdata.astronaut()[100:196, 100:196].copy()
    mask = np.zeros(damaged.shape[:2], bool)
    mask[:, 20:23] = mask[:, 60:62] = mask[40:43, :] = True
    damaged[mask] = 255
    texture = np.concatenate([skdata.brick()[:96, :64], skdata.grass()[:96, :64]], axis=1)
    return [
        ("restore windowed", lambda: restore(noisy, return_result=True).prediction),
        ("restore recursive",
         lambda: restore(noisy, estimator="recursive", return_result=True).restored()),
        ("restore_multichannel", lambda: restore_multichannel(versions).restored),
        ("restore_tiled", lambda: restore_tiled(noisy, tile=32)),
        ("inpaint conditional", lambda: inpaint(damaged, mask)),
        ("inpaint scans", lambda: inpaint(damaged, mask, method="scans")),
        ("segment", lambda: segment(texture, n_segments=2, levels=2).labels),
    ]


def test_every_application_runs_on_the_job_pool_sized_by_the_setting(monkeypatch):
    """CAR_NAPARI_JOB_THREADS sizes the one pool every application uses (the
    restorations and the inpainting had their own two threads): at 3 their
    kernels run on it, at 1 on no pool, and the results are the same bit for
    bit."""
    from car_napari import _threads
    from car_napari.inpainting import _solver

    monkeypatch.setattr(_threads, "usable_cpus", lambda: 4)  # 3 threads on any machine
    monkeypatch.setattr(_solver, "SOLVE_UNKNOWNS", 64)  # several solves a frame
    pool = _CountingPool(3)
    monkeypatch.setattr(_threads, "_pools", {3: pool})
    try:
        for name, run in _applications():
            monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", "1")
            before = pool.calls
            one = run()
            assert pool.calls == before, name
            monkeypatch.setenv("CAR_NAPARI_JOB_THREADS", "3")
            three = run()
            assert pool.calls > before, f"{name} does not use the job pool"
            np.testing.assert_array_equal(one, three, err_msg=name)
    finally:
        pool.shutdown()
