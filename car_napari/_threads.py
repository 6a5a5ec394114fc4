"""Thread use sized to the machine: BLAS limited to one thread while a job runs.

The core runs many small or tall-and-thin matrix products (the CAR
statistics, the Gaussian mixture's EM, the feature projections). A team of
BLAS threads on such a product spends its time waiting for its slowest
member, and when another process keeps the cores busy that member is often
descheduled: a job then runs 10 to 20 times slower than with one BLAS
thread. So every job runs with BLAS limited (:func:`limited_blas`, entered
by :func:`car_napari._progress.drain` and by the widgets' job runner); the
job's own work runs in its one thread (the Numba kernels are serial and
release the GIL, which keeps the napari viewer responsive), but for the
kernels a job runs side by side (the restorations' scans, strips and
chunks of rows, the inpainting's scans and solves, the segmentation
features' scans and smoothings, the mixture's E step halves) on the one
pool of :func:`job_pool`, sized by ``CAR_NAPARI_JOB_THREADS``
(:func:`job_threads`).

The limit is ``CAR_NAPARI_BLAS_THREADS`` when that is set (a number of
threads, at most the CPUs this process may use; ``0`` or ``off``: no limit),
else one thread. No code of car-napari sets Numba's thread count: its
kernels are serial (no ``parallel=True``), so Numba starts no thread pool.

A widget's job runs below the viewer (:func:`lower_thread_priority`): on
Linux its worker thread, and the threads it starts, run at a nice value
``CAR_NAPARI_WORKER_NICE`` (default 5) above the viewer's, so that when
they and the viewer's thread want the same core, the scheduler gives the
viewer about three times the job's share.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor

from threadpoolctl import OpenBLASController, threadpool_limits

from ._docstrings import raises_as, shared_sections
from ._validation import check_real

__all__ = ["blas_threads", "job_pool", "job_threads", "limited_blas", "lower_thread_priority",
           "pool_threads", "submit", "usable_cpus", "worker_nice"]

ENV = "CAR_NAPARI_BLAS_THREADS"
JOB_ENV = "CAR_NAPARI_JOB_THREADS"
NICE_ENV = "CAR_NAPARI_WORKER_NICE"
DEFAULT_WORKER_NICE = 5  # Linux's scheduler weight 1024 against 335: about 3 to 1

_lock = threading.Lock()
_depth = 0  # the jobs inside limited_blas(), in every thread
_limiter = None  # threadpoolctl's record of the limits before the outermost entry
_limit = None  # the limit in force (None: none)
_pools = {}  # job_threads() -> the shared pool of that size, made on first use
_pools_lock = threading.Lock()


def _release_blas_control():
    """Let any thread set OpenBLAS's limits next: threadpoolctl (3.8) lets only
    the first thread that set them set them again, and ours are set and put
    back in whichever thread starts and ends the jobs."""
    release = getattr(OpenBLASController, "clear_controlling_thread", None)
    if release is not None:
        release(force=True)


def usable_cpus():
    """The number of CPUs this process may run on.

    Returns
    -------
    int
        The CPUs of the process's affinity mask where the system has one
        (Linux: a container or ``taskset`` may allow fewer than the machine
        has), else ``os.cpu_count()``; at least 1.

    Examples
    --------
    >>> usable_cpus() >= 1
    True
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def blas_threads():
    """The BLAS thread limit a job runs with.

    Returns
    -------
    int or None
        ``CAR_NAPARI_BLAS_THREADS`` when set (clipped to
        :func:`usable_cpus`; None for ``0``, ``off`` or ``none``: no limit),
        else 1.

    Raises
    ------
    ValueError
        ``CAR_NAPARI_BLAS_THREADS`` is neither a number nor ``off``.

    Examples
    --------
    >>> threads = blas_threads()  # 1 unless CAR_NAPARI_BLAS_THREADS says otherwise
    >>> threads is None or 1 <= threads <= usable_cpus()
    True
    """
    value = os.environ.get(ENV, "").strip().lower()
    if not value:
        return 1
    if value in ("0", "off", "none"):
        return None
    try:
        threads = int(value)
    except ValueError:
        raise ValueError(f"{ENV} must be a number of threads or 'off'; got {value!r}.") from None
    if threads < 0:
        raise ValueError(f"{ENV} must be a number of threads or 'off'; got {value!r}.")
    return min(threads, usable_cpus()) if threads else None


def job_threads():
    """The threads a job may run its kernels on side by side.

    Returns
    -------
    int
        ``CAR_NAPARI_JOB_THREADS`` when set (at least 1, at most
        :func:`usable_cpus`), else 2 where two CPUs are usable, else 1. A
        dask worker of ``car-napari --workers N`` runs with 1: N processes
        on N cores, each one thread.

    Raises
    ------
    ValueError
        ``CAR_NAPARI_JOB_THREADS`` is not a positive number.

    Examples
    --------
    >>> 1 <= job_threads() <= 2 or "CAR_NAPARI_JOB_THREADS" in os.environ
    True
    """
    value = os.environ.get(JOB_ENV, "").strip()
    if not value:
        return min(2, usable_cpus())
    try:
        threads = int(value)
    except ValueError:
        threads = 0
    if threads < 1:
        raise ValueError(f"{JOB_ENV} must be a positive number of threads; got {value!r}.")
    return min(threads, usable_cpus())


def worker_nice():
    """How far below the viewer a widget's job runs.

    Returns
    -------
    int
        ``CAR_NAPARI_WORKER_NICE`` when set (0 to 19; 0: at the viewer's
        priority), else :data:`DEFAULT_WORKER_NICE`.

    Raises
    ------
    ValueError
        ``CAR_NAPARI_WORKER_NICE`` is not a whole number from 0 to 19.

    Examples
    --------
    >>> 0 <= worker_nice() <= 19
    True
    """
    value = os.environ.get(NICE_ENV, "").strip()
    if not value:
        return DEFAULT_WORKER_NICE
    try:
        nice = int(value)
    except ValueError:
        nice = -1
    if not 0 <= nice <= 19:
        raise ValueError(f"{NICE_ENV} must be a whole number from 0 to 19; got {value!r}.")
    return nice


def lower_thread_priority(nice=None):
    """Run the calling thread below the process's main thread (the viewer's).

    On Linux a thread has its own nice value, and the threads it starts
    inherit it: a widget's worker calls this once, so that it and the
    threads it starts (a solver's, and :func:`job_pool`'s when it grows the
    pool) get a smaller share of a core the viewer's thread also wants (about
    a third of the viewer's, at nice +5; not a strict priority). An
    unprivileged process cannot raise a priority again, so a thread is only
    ever lowered: a thread of napari's worker pool stays lowered for the
    later workers it runs, and :func:`job_pool`'s threads keep the nice value
    of the thread that started them, whoever submits to them later.
    Elsewhere it does nothing.

    Parameters
    ----------
    nice : int, optional
        The nice increment over the main thread's (0 to 19); default
        :func:`worker_nice`.

    Returns
    -------
    int or None
        The calling thread's nice value now; None where threads have no
        nice value of their own (not Linux) or the system refused.

    Examples
    --------
    >>> import threading
    >>> seen = []
    >>> worker = threading.Thread(target=lambda: seen.append(lower_thread_priority(3)))
    >>> worker.start(); worker.join()
    >>> seen[0] is None or seen[0] >= os.getpriority(os.PRIO_PROCESS, 0)
    True
    """
    if not sys.platform.startswith("linux"):  # no per-thread nice: the setting is moot
        return None
    nice = worker_nice() if nice is None else check_real(nice, "nice", low=0, high=19,
                                                          integer=True)
    thread = threading.get_native_id()
    try:
        current = os.getpriority(os.PRIO_PROCESS, thread)
        wanted = min(19, os.getpriority(os.PRIO_PROCESS, os.getpid()) + int(nice))
        if wanted > current:
            os.setpriority(os.PRIO_PROCESS, thread, wanted)
        return os.getpriority(os.PRIO_PROCESS, thread)
    except OSError:
        return None


@shared_sections(raises=raises_as("job_threads", "ValueError"))
def job_pool():
    """The threads every job runs its side-by-side kernels on, shared.

    One pool for the whole process (per size), made on first use and kept:
    a job does not start and stop threads of its own, and two pools serving
    one purpose would run twice :func:`job_threads` threads when a
    segmentation's features and mixture overlap with another job's. How the
    work is split does not depend on the pool (the callers' pairs and halves
    are fixed), so the results are those of one thread, bit for bit.

    Returns
    -------
    concurrent.futures.ThreadPoolExecutor or None
        A pool of :func:`job_threads` threads; None where that is 1 (run the
        kernels one after the other). Never shut it down; a task run on it
        must not wait for another task of it.

    {raises}

    Examples
    --------
    >>> pool = job_pool()
    >>> pool is None or pool is job_pool()
    True
    """
    threads = job_threads()
    if threads < 2:
        return None
    with _pools_lock:
        pool = _pools.get(threads)
        if pool is None:
            pool = _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="car-job")
    return pool


def pool_threads(pool):
    """The threads of a job's pool.

    Parameters
    ----------
    pool : concurrent.futures.ThreadPoolExecutor or None
        A pool of :func:`job_pool` (or any thread pool); None: no pool.

    Returns
    -------
    int
        Its number of threads; 1 for None (the job's own thread).

    Examples
    --------
    >>> pool_threads(None)
    1
    >>> pool_threads(job_pool()) == job_threads()
    True
    """
    if pool is None:
        return 1
    return max(1, int(getattr(pool, "_max_workers", 1)))


def submit(pool, call, *args):
    """Run ``call(*args)`` on ``pool``, or here and now without one.

    Parameters
    ----------
    pool : concurrent.futures.Executor or None
        A pool of :func:`job_pool`; None: call it in this thread.
    call : callable
        What to run.
    *args
        Its arguments.

    Returns
    -------
    concurrent.futures.Future
        Its future (without a pool, done: its result or exception set).

    Examples
    --------
    >>> submit(None, max, 2, 3).result()
    3
    """
    if pool is not None:
        return pool.submit(call, *args)
    future = Future()
    try:
        future.set_result(call(*args))
    except Exception as error:  # raised by future.result(), as a pool would
        future.set_exception(error)
    return future


@contextlib.contextmanager
def limited_blas(threads=None):
    """Limit the BLAS libraries' threads while a job runs.

    Every job (``car.<name>(...)``, a widget's or the command line's run)
    runs inside it; use it too when a script steps an ``iter_<name>``
    generator itself. The limit is process-wide (BLAS has one thread pool):
    the first entry, in any thread, sets it and the last exit puts back the
    limits found before, so jobs may nest and run in several threads at once.
    Entering it inside a job costs a lock and a counter.

    Parameters
    ----------
    threads : int, optional
        The BLAS thread limit (at most :func:`usable_cpus`); default
        :func:`blas_threads`: ``CAR_NAPARI_BLAS_THREADS``, else 1. Only the
        outermost entry's limit applies.

    Yields
    ------
    limit : int or None
        The limit in force (None: none, ``CAR_NAPARI_BLAS_THREADS=off``).

    Examples
    --------
    >>> import numpy as np
    >>> import car_napari as car
    >>> with limited_blas() as limit:  # car.limited_blas
    ...     job = car.iter_restore(np.random.default_rng(0).random((32, 32)))
    ...     for record in job:
    ...         pass
    >>> limit is None or limit >= 1
    True
    """
    global _depth, _limiter, _limit
    if threads is not None:  # an int (below 1 means 1): no float, bool or string
        threads = check_real(threads, "threads", integer=True)
    with _lock:
        if _depth == 0:
            limit = blas_threads() if threads is None else max(1, min(int(threads), usable_cpus()))
            _limiter = None
            if limit is not None:
                _release_blas_control()
                _limiter = threadpool_limits(limits=limit, user_api="blas")
                _release_blas_control()
            _limit = limit
        _depth += 1
        limit = _limit
    try:
        yield limit
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                if _limiter is not None:
                    _release_blas_control()
                    _limiter.restore_original_limits()
                    _release_blas_control()
                _limiter = _limit = None
