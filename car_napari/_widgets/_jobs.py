"""Run a core job (a generator of Progress records) in a napari worker thread.

The core's long computations are generators ``iter_<name>(...)`` that yield
:class:`car_napari._progress.Progress` records and return their result; a
:class:`Job` drives one in a worker (with BLAS limited to one thread, as
:func:`car_napari._progress.drain` runs it) and hands the records, the result
or the error to the widget, in the main thread. A cancelled job hands over
nothing more, and its worker stops at the core's next record. Plain functions
(a synthesis) run through :func:`call`.

The main thread does little per record: the progress records are handed
over at most every :data:`STATUS_INTERVAL` seconds and the previews (a layer
update each) at most every :data:`PREVIEW_INTERVAL` seconds, the latest one
each time; the last preview is always handed over before the result.
Showing a large result can be split across event-loop turns: when
``on_done`` returns a generator, the job runs one of its steps per turn (a
layer added, then the next one), so that the viewer draws and answers in
between; the job is done once the last step has run.

A control that re-cuts a finished result (a slider) asks for jobs faster
than they run: :class:`LatestWins` runs one at a time, the latest request
winning.
"""

from __future__ import annotations

import inspect
import math
import time

from napari.qt.threading import create_worker
from qtpy.QtCore import Qt, QTimer

from .._progress import Progress
from .._threads import limited_blas, lower_thread_priority

STATUS_INTERVAL = 0.05  # s: the progress bar and status line, at most 20 times a second
PREVIEW_INTERVAL = 0.15  # s from the end of one preview (a layer update) to the next


class _Failed(Exception):
    """Carries a RuntimeError out of the worker: superqt takes a RuntimeError
    in a generator for a deleted worker and swallows it."""


def _run(job, cancelled):
    """The worker's generator: ``job``'s records, with BLAS limited and the
    thread below the viewer's priority, until ``cancelled()``; the job is
    closed in the worker thread when it stops."""
    lower_thread_priority()
    with limited_blas():
        try:
            while not cancelled():  # once cancelled, the worker hands nothing over
                try:
                    record = next(job)
                except StopIteration as stop:
                    return stop.value
                if not cancelled():
                    yield record
            return None
        except RuntimeError as exc:
            raise _Failed(exc) from exc
        finally:
            job.close()


def _relay(runner):
    return (yield from runner)


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

    The callbacks run in the main thread. ``on_progress(record)`` gets the
    latest :class:`Progress` record, at most every :data:`STATUS_INTERVAL`
    seconds (the first one at once); ``on_preview(record)`` the latest
    record with a preview, at most every :data:`PREVIEW_INTERVAL` seconds
    after the previous call returned, and the last one before the result;
    ``on_collect(record)``, when given, gets every record with a preview, at
    once (cheap bookkeeping only, such as keeping a clip's restored frames
    for the next preview); ``on_done(result)`` gets the generator's return
    value, ``on_error(exc)`` what it raised, ``on_cancel()`` is called by
    :meth:`cancel`, and ``on_finished(job)`` when the worker has stopped
    and the result is shown, whatever the outcome. After a cancel nothing
    more is handed over.

    When ``on_done(result)`` returns a generator, its steps are run one per
    event-loop turn (each one a piece of showing the result, such as one
    layer added); a :meth:`cancel` between two steps closes it (GeneratorExit
    at the step it stopped at) and calls ``on_cancel()``.

    Parameters
    ----------
    job : generator
        A generator of :class:`Progress` records that returns the result
        (an ``iter_<name>(...)`` call, not yet started).
    on_progress, on_done, on_error, on_cancel, on_finished : callable
        The callbacks.
    on_preview : callable, optional
        The preview callback; without it previews are not handed over.
    on_collect : callable, optional
        Called with every record that has a preview (no layer update in it).

    Attributes
    ----------
    cancelled : bool
        :meth:`cancel` was called before the job ended.
    done : bool
        The worker has finished (returned, failed or stopped) and the
        result's steps, if any, have all run.
    showing : bool
        The result's steps are running (see above).

    Examples
    --------
    >>> Job.__name__  # a worker needs a running Qt application; see the tests
    'Job'
    """

    def __init__(self, job, *, on_progress, on_done, on_error, on_cancel, on_finished,
                 on_preview=None, on_collect=None):
        self.cancelled = False
        self._worker_done = False
        self._steps = None  # the result's remaining steps (on_done returned a generator)
        self._settled = False  # a result or an error was handed over
        self._callbacks = on_progress, on_done, on_error, on_cancel, on_finished
        self._on_preview = on_preview
        self._on_collect = on_collect
        # the latest records not yet handed over, and when the last ones were
        self._record = self._preview = None
        self._record_at = self._preview_at = -math.inf
        self._timer = QTimer()
        self._timer.setSingleShot(True)
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.timeout.connect(self._hand_over)
        self._step_timer = QTimer()
        self._step_timer.setSingleShot(True)
        self._step_timer.setInterval(0)  # the next step on the next turn of the event loop
        self._step_timer.timeout.connect(self._step)
        # The worker's generator; closed at the end in case the worker was
        # stopped otherwise (that closes the job and lifts the BLAS limit).
        self._runner = _run(job, lambda: self.cancelled)
        # Errors are the widget's to show (one notification, no traceback):
        # nothing re-raised in the main thread, no second message from napari.
        self.worker = create_worker(_relay, self._runner, _start_thread=False,
                                    _ignore_errors=True)
        try:
            self.worker.errored.disconnect(self.worker._relay_error)
        except (AttributeError, TypeError, RuntimeError):
            pass  # this napari version does not relay worker errors
        self.worker.yielded.connect(self._yielded)
        self.worker.returned.connect(self._returned)
        self.worker.errored.connect(self._errored)
        self.worker.finished.connect(self._finished)
        self.worker.start()

    @property
    def _closed(self):
        return self.cancelled or self._settled

    @property
    def done(self):
        """The worker has finished and the result is shown (or the job ended otherwise)."""
        return self._worker_done and self._steps is None

    @property
    def showing(self):
        """The result is being shown, step by step."""
        return self._steps is not None

    def cancel(self):
        """Stop the job at its next record; nothing more is handed over.

        ``on_cancel()`` is called at once (the worker ends at the core's next
        record). Does nothing when the job has already ended or been handed
        over; while its result is being shown step by step, the steps stop
        and ``on_cancel()`` is called.
        """
        if self._steps is not None and not self.cancelled:
            self._step_timer.stop()
            steps, self._steps = self._steps, None
            self.cancelled = True
            steps.close()
            self._callbacks[3]()
            if self._worker_done:
                self._callbacks[4](self)
            return
        if self._closed or self.done:
            return
        # The worker's generator sees it at the job's next record and closes the
        # job there, in the worker thread (worker.quit() would leave the job
        # suspended, to be closed here, in the main thread).
        self.cancelled = True
        self._drop_pending()
        self._callbacks[3]()

    def _drop_pending(self):
        self._timer.stop()
        self._record = self._preview = None

    def _yielded(self, record):
        if self._closed:
            return
        self._record = record
        if record.preview is not None:
            if self._on_collect is not None:
                self._on_collect(record)
            if self._on_preview is not None and not self._closed:
                self._preview = record
        self._hand_over()

    def _hand_over(self):
        """Hand over the pending records that are due; wait for the others."""
        waits = []
        if self._record is not None and not self._closed:
            due = self._record_at + STATUS_INTERVAL - time.monotonic()
            if due <= 0:
                record, self._record = self._record, None
                self._record_at = time.monotonic()
                self._callbacks[0](record)
            else:
                waits.append(due)
        if self._preview is not None and not self._closed:
            due = self._preview_at + PREVIEW_INTERVAL - time.monotonic()
            if due <= 0:
                self._deliver_preview()
            else:
                waits.append(due)
        if waits and not self._closed:
            self._timer.start(max(1, math.ceil(1000 * min(waits))))

    def _deliver_preview(self):
        record, self._preview = self._preview, None
        self._on_preview(record)
        self._preview_at = time.monotonic()  # the next one an interval after this one's end

    def _returned(self, result):
        if self._closed:
            return
        self._timer.stop()
        self._record = None  # the result says more than the last status
        if self._preview is not None:
            self._deliver_preview()  # the last preview, before the result
            if self._closed:  # showing it failed (the widget cancelled)
                return
        self._settled = True
        steps = self._callbacks[1](result)
        if inspect.isgenerator(steps):
            self._steps = steps
            self._step()

    def _step(self):
        """Run the result's next step; the one after it on the next turn."""
        if self._steps is None:
            return
        try:
            next(self._steps)
        except StopIteration:
            self._steps = None
        except Exception as exc:  # showing the result failed: the widget's to show
            self._steps = None
            self._callbacks[2](exc)
        else:
            self._step_timer.start()
            return
        if self._worker_done:
            self._callbacks[4](self)

    def _errored(self, exc):
        if self._closed:
            return
        self._drop_pending()
        self._settled = True
        self._callbacks[2](exc.__cause__ if isinstance(exc, _Failed) else exc)

    def _finished(self):
        self._worker_done = True
        self._drop_pending()
        self._runner.close()  # a stopped generator runs its clean-up; the thread is done
        if self._steps is None:  # otherwise, once the last step has run
            self._callbacks[4](self)


def _ignore(*_):
    """A callback with nothing to do (a re-cut shows no progress)."""


class NextTurn:
    """``next_turn(function)`` calls ``function()`` on a later turn of the
    event loop, one call per turn, in order.

    A zero-interval timer, as the job's result steps: a call posted with
    ``QTimer.singleShot(0, ...)`` would run before the viewer has drawn or
    taken the input waiting, so two long calls would pause it as one.

    Examples
    --------
    >>> NextTurn.__name__  # a timer needs a running Qt application; see the tests
    'NextTurn'
    """

    def __init__(self):
        self._calls = []
        self._timer = QTimer()
        self._timer.setSingleShot(True)
        self._timer.setInterval(0)
        self._timer.timeout.connect(self._next)

    def __call__(self, function):
        self._calls.append(function)
        self._timer.start()

    def _next(self):
        if self._calls:
            self._calls.pop(0)()
        if self._calls:
            self._timer.start()


class LatestWins:
    """Jobs asked for faster than they run (a slider dragged), the latest
    request winning: one runs at a time, and a request made while it runs
    waits, replacing any older waiting one.

    Parameters
    ----------
    interrupt : bool, optional
        A new request cancels the running job and starts at once (for jobs
        whose stale result is long to wait for). False (default): the
        running job ends and is shown, then the latest request runs, so
        that a dragged control shows values on the way.

    Attributes
    ----------
    job : Job or None
        The running job (None when none runs).

    Examples
    --------
    >>> LatestWins().job is None  # a job needs a running Qt application; see the tests
    True
    """

    def __init__(self, *, interrupt=False):
        self.interrupt = interrupt
        self.job = None
        self._wanted = None  # (job, on_done, on_error): the latest request not yet started

    def request(self, job, on_done, on_error):
        """Run ``job`` now, or when the running one has ended (see above).

        Parameters
        ----------
        job : generator
            The job (not yet started; a request replaced while it waits
            never starts it).
        on_done : callable
            ``on_done(result)``, in the main thread, unless a newer request
            or :meth:`stop` came first.
        on_error : callable
            ``on_error(exc)`` when the job raised.
        """
        self._wanted = job, on_done, on_error
        if self.job is not None and self.interrupt:
            self.job.cancel()  # it hands nothing over any more
            self.job = None
        if self.job is None:
            self._next()

    def _next(self):
        wanted, self._wanted = self._wanted, None
        if wanted is None:
            self.job = None
            return
        job, on_done, on_error = wanted
        self.job = Job(job, on_progress=_ignore, on_done=on_done, on_error=on_error,
                       on_cancel=_ignore, on_finished=self._finished)

    def _finished(self, job):
        if job is self.job:  # not one cancelled since
            self._next()

    def stop(self):
        """Cancel the running job and forget the waiting request."""
        self._wanted = None
        if self.job is not None:
            self.job.cancel()
            self.job = None
