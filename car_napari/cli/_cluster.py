"""The dask cluster a batch runs on with --workers or --scheduler."""

from __future__ import annotations


def _worker_config():
    """The dask config a LocalCluster's workers start under: what distributed
    does by default and our tasks pay for, off.

    * ``MALLOC_TRIM_THRESHOLD_=65536``, which dask sets in every worker, also
      fixes glibc's mmap threshold, so every array of more than 128 kB is a
      fresh mapping whose pages are faulted in and zeroed: on 8 mammograms
      38.7 s of CPU instead of 29.6 (9 s of it system time) in one process.
    * The worker's statistical profiler samples every thread's stack every
      10 ms: 4.5 s of CPU more on 16 mammograms with 2 workers (66.7 s
      against 62.2).

    And each worker's jobs run on one thread (``CAR_NAPARI_JOB_THREADS=1``):
    N single-threaded processes on N cores, not 2N threads."""
    import dask

    return dask.config.set({
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,  # None: unset
        "distributed.nanny.pre-spawn-environ.CAR_NAPARI_JOB_THREADS": 1,
        "distributed.worker.profile.enabled": False,
    })


def dask_client(workers, scheduler):
    """A context giving a dask Client: of ``scheduler``, or of a LocalCluster of
    ``workers`` single-threaded processes (closed on exit)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ValueError("--workers and --scheduler need dask.distributed: "
                         "pip install 'car-napari[cluster]'.") from None
    import contextlib
    import logging

    stack = contextlib.ExitStack()
    # a worker slow to stop under load is killed with a warning: not the user's concern
    quiet_log = logging.getLogger("distributed")
    stack.callback(quiet_log.setLevel, quiet_log.level)
    quiet_log.setLevel(logging.ERROR)
    try:
        if scheduler is not None:
            client = stack.enter_context(Client(scheduler))
        else:
            # one single-threaded process per core: the core's kernels are
            # serial and BLAS is limited to a thread, so N workers use N cores
            with _worker_config():
                cluster = stack.enter_context(LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=None))
            client = stack.enter_context(Client(cluster))
    except BaseException:
        stack.close()
        raise

    @contextlib.contextmanager
    def session():
        with stack:
            yield client

    return session()
