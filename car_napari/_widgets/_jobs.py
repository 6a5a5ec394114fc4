"""Run a core job (a generator of Progress records) in a napari worker thread.

The core's long computations are generators ``iter_<name>(...)`` that yield
:class:`car_napari._progress.Progress` records and return their result; a
:class:`Job` drives one in a worker and hands the records, the result or the
error to the widget, in the main thread. A cancelled job hands over nothing
more. Plain functions (a synthesis) run through :func:`call`.
"""

from __future__ import annotations

from napari.qt.threading import create_worker

from .._progress import Progress


class _Failed(Exception):
    """Carries a RuntimeError out of the worker: superqt takes a RuntimeError
    in a generator for a deleted worker and swallows it."""


def _run(job):
    try:
        return (yield from job)
    except RuntimeError as exc:
        raise _Failed(exc) from exc


def call(function, *args, stage="running", **kwargs):
    """A plain function call as a job: one record, then its result.

    Parameters
    ----------
    function : callable
        The core function (one without a generator form).
    *args
        Its positional arguments.
    stage : str, optional
        The stage word of the record shown while it runs.
    **kwargs
        Its keyword arguments.

    Yields
    ------
    Progress
        One record, at fraction 0, before the call.

    Returns
    -------
    object
        What ``function(*args, **kwargs)`` returns.

    Examples
    --------
    >>> from car_napari._progress import drain
    >>> drain(call(divmod, 7, 2))
    (3, 1)
    """
    yield Progress(stage, 0.0)
    return function(*args, **kwargs)


class Job:
    """One core generator running in a napari worker thread.

    The callbacks run in the main thread: ``on_progress(record)`` for every
    :class:`Progress` record, ``on_done(result)`` with the generator's return
    value, ``on_error(exc)`` when it raises, ``on_cancel()`` when
    :meth:`cancel` stops it, and ``on_finished(job)`` at the end, whatever
    the outcome. After a cancel no record, result or error is handed over.

    Parameters
    ----------
    job : generator
        A generator of :class:`Progress` records that returns the result
        (an ``iter_<name>(...)`` call, not yet started).
    on_progress, on_done, on_error, on_cancel, on_finished : callable
        The callbacks.

    Attributes
    ----------
    cancelled : bool
        :meth:`cancel` was called before the job ended.
    done : bool
        The worker has finished (returned, failed or stopped).

    Examples
    --------
    >>> Job.__name__  # a worker needs a running Qt application; see the tests
    'Job'
    """

    def __init__(self, job, *, on_progress, on_done, on_error, on_cancel, on_finished):
        self.cancelled = False
        self.done = False
        self._settled = False  # a result or an error was handed over
        self._gen = job
        self._callbacks = on_progress, on_done, on_error, on_cancel, on_finished
        # Errors are the widget's to show (one notification, no traceback):
        # nothing re-raised in the main thread, no second message from napari.
        self.worker = create_worker(_run, job, _start_thread=False, _ignore_errors=True)
        try:
            self.worker.errored.disconnect(self.worker._relay_error)
        except (AttributeError, TypeError, RuntimeError):
            pass  # this napari version does not relay worker errors
        self.worker.yielded.connect(self._yielded)
        self.worker.returned.connect(self._returned)
        self.worker.errored.connect(self._errored)
        self.worker.finished.connect(self._finished)
        self.worker.start()

    def cancel(self):
        """Stop the job at its next record; nothing more is handed over.

        Does nothing when the job has already ended or been handed over.
        """
        if self.cancelled or self._settled or self.done:
            return
        self.cancelled = True
        self.worker.quit()
        self._callbacks[3]()

    def _yielded(self, record):
        if not (self.cancelled or self._settled):
            self._callbacks[0](record)

    def _returned(self, result):
        if not (self.cancelled or self._settled):
            self._settled = True
            self._callbacks[1](result)

    def _errored(self, exc):
        if not (self.cancelled or self._settled):
            self._settled = True
            self._callbacks[2](exc.__cause__ if isinstance(exc, _Failed) else exc)

    def _finished(self):
        self.done = True
        self._gen.close()  # a stopped generator runs its clean-up; the thread is done
        self._callbacks[4](self)
