"""Run a core function or generator in a napari worker thread.

One place for the glue every widget needs: progress bar, Cancel button,
and results applied only when the job was not cancelled (so a cancelled run
leaves the viewer as it was). An exception in the job becomes one napari
error notification with its message (the core's messages say what to do).
"""

from __future__ import annotations

from napari.qt.threading import create_worker
from napari.utils.notifications import show_error


class Job:
    """A running worker with its progress and cancel controls.

    ``function`` may be a plain function or a generator function; a generator
    yields either a float in [0, 1] (progress) or any other object, passed to
    ``on_yield``. The return value goes to ``on_done``. ``cancel`` (a button)
    is enabled while the job runs and ``buttons`` are disabled; the widget
    connects its Cancel button to :meth:`cancel`.
    """

    def __init__(self, function, *args, progress=None, cancel=None, buttons=(),
                 on_yield=None, on_done=None, on_error=None, **kwargs):
        self.cancelled = False
        self.done = False  # set when the worker has finished, whatever the outcome
        self._progress = progress
        self._cancel = cancel
        self._buttons = buttons
        self._on_yield = on_yield
        self._on_done = on_done
        self._on_error = on_error
        # We show errors ourselves (the message, no traceback): no re-raise in
        # the main thread, and no second notification from napari's relay.
        self.worker = create_worker(function, *args, _start_thread=False,
                                    _ignore_errors=True, **kwargs)
        try:
            self.worker.errored.disconnect(self.worker._relay_error)
        except (AttributeError, TypeError, RuntimeError):
            pass  # this napari version does not relay worker errors
        if hasattr(self.worker, "yielded"):
            self.worker.yielded.connect(self._yielded)
        self.worker.returned.connect(self._returned)
        self.worker.errored.connect(self._errored)
        self.worker.finished.connect(self._finished)
        self._set_busy(True)
        self.worker.start()

    def cancel(self):
        self.cancelled = True
        self.worker.quit()
        if self._progress is not None:
            self._progress.label = "cancelled"

    def _set_busy(self, busy):
        if self._cancel is not None:
            self._cancel.enabled = busy
        for button in self._buttons:
            button.enabled = not busy
        if self._progress is not None and busy:
            self._progress.value = 0

    def _yielded(self, item):
        if self.cancelled:
            return
        if isinstance(item, float) and self._progress is not None:
            self._progress.value = int(round(100 * item))
        elif self._on_yield is not None:
            self._on_yield(item)

    def _returned(self, result):
        if self.cancelled:
            return
        if self._progress is not None:
            self._progress.value = 100
        if self._on_done is not None:
            try:
                self._on_done(result)
            except Exception as exc:  # a failure applying results is the user's to see
                show_error(f"{type(exc).__name__}: {exc}")

    def _errored(self, exc):
        if self._progress is not None:
            self._progress.value = 0
        show_error(f"{type(exc).__name__}: {exc}")
        if self._on_error is not None:
            self._on_error(exc)

    def _finished(self):
        self._set_busy(False)
        self.done = True
