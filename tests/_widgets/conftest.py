import time

import numpy as np
import pytest


@pytest.fixture
def docked(make_napari_viewer_proxy):
    """Factory: a viewer (its public side, as napari gives a plugin's dock
    widget) with ``widget_class`` docked; returns both. The proxy wraps each
    layer it hands out anew: compare layers with ``==``, not ``is``."""

    def make(widget_class, name):
        viewer = make_napari_viewer_proxy()
        widget = widget_class(viewer)
        viewer.window.add_dock_widget(widget, name=name)
        return viewer, widget

    return make


@pytest.fixture
def last_notification():
    """The message of napari's latest notification (errors the user sees)."""
    from napari.utils.notifications import notification_manager

    return lambda: str(notification_manager.records[-1].message)


class EventLoopMonitor:
    """The main thread's event-loop pauses: a ``QTimer`` fires every
    ``period_ms`` and records the ``perf_counter`` gap since its last firing;
    a pause is a gap minus the period (what the user sees as a frozen viewer).
    The same recorder as ``benchmarks/bench_gui.py``'s.

    Use as a context manager, or :meth:`start` and :meth:`stop`; the event
    loop must run in between (``qtbot.waitUntil``, ``qtbot.wait``).
    """

    def __init__(self, period_ms=5):
        from qtpy.QtCore import Qt, QTimer

        self.period = period_ms / 1000.0
        self._timer = QTimer()
        self._timer.setTimerType(Qt.PreciseTimer)
        self._timer.setInterval(period_ms)
        self._timer.timeout.connect(self._tick)
        self.gaps = []
        self._last = None

    def start(self):
        self.gaps = []
        self._last = time.perf_counter()
        self._timer.start()
        return self

    def _tick(self):
        now = time.perf_counter()
        self.gaps.append(now - self._last)
        self._last = now

    def stop(self):
        if self._timer.isActive():
            self._timer.stop()
            self._tick()  # the gap up to now counts as well
        return self

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    @property
    def pauses_ms(self):
        """Every pause (ms): the gaps minus the period, at least 0."""
        return np.maximum(np.asarray(self.gaps, dtype=float) - self.period, 0.0) * 1000.0

    @property
    def longest_ms(self):
        """The longest pause (ms)."""
        pauses = self.pauses_ms
        return float(pauses.max()) if pauses.size else 0.0

    @property
    def p99_ms(self):
        """The 99th percentile of the pauses (ms)."""
        pauses = self.pauses_ms
        return float(np.percentile(pauses, 99)) if pauses.size else 0.0

    def summary(self):
        """``'longest 12.3 ms, p99 4.5 ms over 200 ticks'``, for messages."""
        return (f"longest {self.longest_ms:.1f} ms, p99 {self.p99_ms:.1f} ms "
                f"over {len(self.gaps)} ticks")


@pytest.fixture
def event_loop_monitor(qtbot):
    """An :class:`EventLoopMonitor` (not started; stopped at the end of the test).

    >>> with event_loop_monitor:
    ...     job = widget.start()
    ...     qtbot.waitUntil(lambda: job.done, timeout=30000)
    >>> assert event_loop_monitor.longest_ms < 1000, event_loop_monitor.summary()
    """
    monitor = EventLoopMonitor()
    yield monitor
    monitor.stop()


@pytest.fixture
def cancel_latency(qtbot):
    """Click a widget's Cancel button; returns the seconds until the job's
    worker has finished (``job.done``), or None when it has not within
    ``timeout`` seconds. ``cancel_latency(widget, job, timeout=3.0)``."""

    def measure(widget, job, timeout=3.0):
        assert widget._cancel.enabled, "Cancel is not enabled: is the job running?"
        t0 = time.perf_counter()
        widget._cancel.native.click()  # as the user clicks it
        try:
            qtbot.waitUntil(lambda: job.done, timeout=int(timeout * 1000))
        except qtbot.TimeoutError:
            return None
        return time.perf_counter() - t0

    return measure
