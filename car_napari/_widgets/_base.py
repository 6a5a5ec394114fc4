"""The base of every dock widget: an image picker, the widget's controls, its
action buttons, Cancel, a progress bar and a status line, and the run of a
core job in a napari worker with everything it writes into the viewer
recorded, so that a Cancel or an error leaves the viewer as it was."""

from __future__ import annotations

import functools
import inspect
import re

from magicgui.widgets import Container, Label, ProgressBar, PushButton, SpinBox, create_widget
from napari.utils.notifications import show_error
from qtpy.QtCore import QEvent, QObject
from qtpy.QtWidgets import QFrame, QSizePolicy

from ._jobs import Job, LatestWins, NextTurn
from ._layers import RunRecord, layer_array


def guarded(method):
    """Decorate a widget method so that its ValueError or OSError (bad input,
    an unreadable file) becomes an error notification, and it returns None.

    Parameters
    ----------
    method : callable
        A method of a :class:`JobWidget`.

    Returns
    -------
    callable
        The method, guarded (see :meth:`JobWidget.launch`).

    Examples
    --------
    >>> guarded(lambda self: 1).__name__
    '<lambda>'
    """

    @functools.wraps(method)
    def guarded_method(self, *args, **kwargs):
        return self.launch(lambda: method(self, *args, **kwargs))

    return guarded_method


class _FitWidth(QObject):
    """Keeps a vertical scroll area as wide as its contents need (it never
    scrolls sideways): updated whenever the contents' layout changes."""

    def __init__(self, scroll):
        super().__init__(scroll)
        self._scroll = scroll
        scroll.widget().installEventFilter(self)

    def eventFilter(self, watched, event):
        if event.type() == QEvent.LayoutRequest:
            bar = self._scroll.verticalScrollBar()
            bar.ensurePolished()  # its width as styled (napari's theme)
            self._scroll.setMinimumWidth(watched.minimumSizeHint().width()
                                         + bar.sizeHint().width()
                                         + 2 * self._scroll.frameWidth())
        return False


class JobWidget(Container):
    """A dock widget that runs core jobs on an image layer.

    Subclasses create their controls, make their action buttons with
    :meth:`action`, lay them out with :meth:`arrange`, and define
    ``_start()``, which reads the input and the controls and starts the job
    with :meth:`run` (the "Run" button's :meth:`start`). While a job runs
    the action buttons are disabled and Cancel is enabled; every change to
    the viewer goes through :attr:`record`
    (:class:`~car_napari._widgets._layers.RunRecord`) and is undone by a
    Cancel or an error.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer the widget reads layers from and writes results to.
    image_label : str, optional
        The label of the image picker.
    image_tooltip : str, optional
        Its tooltip.
    region : bool, optional
        Add an optional Shapes picker: the job reads only the bounding box
        of its first shape.

    Attributes
    ----------
    control_labels : dict
        The core's argument names -> this widget's control labels, so that
        the core's validation messages speak of the controls.
    recuts_interrupt : bool
        A newer :meth:`recut` cancels the one running in a worker (see
        :class:`~._jobs.LatestWins`); False: the running one is shown first.

    Notes
    -----
    The docked widget is a scroll area holding the controls (:attr:`native`):
    napari docks ``widget.native``, so that every dock scrolls when the
    window is too short for all of them, and several docks open at once
    share the window's height instead of growing it beyond the screen.
    """

    control_labels: dict = {}
    recuts_interrupt = False
    #: The smallest height of a dock's scroll area, in lines of text.
    min_lines = 5

    def __init__(self, napari_viewer, *, image_label="image", region=False,
                 image_tooltip="the image layer to work on (grey or colour; an alpha "
                               "channel is not used)"):
        super().__init__(labels=True, scrollable=True)
        scroll = self.root_native_widget
        scroll.setFrameShape(QFrame.NoFrame)
        scroll.setMinimumHeight(self.min_lines * scroll.fontMetrics().height())
        _FitWidth(scroll)
        self._viewer = napari_viewer
        # undone one change per event-loop turn: napari's own 0.1-0.2 s per layer,
        # not the sum of them, is the longest pause a Cancel brings
        self.record = RunRecord(napari_viewer, later=NextTurn())
        self._job = None
        self._recuts = LatestWins(interrupt=self.recuts_interrupt)
        self._actions = []  # (button, when): enabled when idle and when()
        self._image = create_widget(annotation="napari.layers.Image", label=image_label,
                                    options={"tooltip": image_tooltip})
        self._region = None
        if region:
            self._region = create_widget(
                annotation="napari.layers.Shapes", label="rectangle",
                options={"nullable": True, "tooltip": "optional: only inside its first shape"},
            )
        self._cancel = PushButton(text="Cancel", enabled=False,
                                  tooltip="stop the running job: the layers are put back as "
                                          "they were before it")
        self._progress = ProgressBar(value=0, min=0, max=100)
        # one row for both (a compact dock): "progress  [Cancel] [====   ]"
        self._busy = Container(widgets=[self._cancel, self._progress], layout="horizontal",
                               labels=False, label="progress")
        self._busy.margins = (0, 0, 0, 0)
        self._status = Label(value="")
        self._cancel.changed.connect(self.cancel)

    @property
    def native(self):
        """The scroll area holding the controls: what napari docks.

        magicgui's ``native`` of a scrollable container is the widget inside
        the scroll area, and napari docks ``native``: the scroll area would
        be left behind. The controls' own widget is :attr:`body`.
        """
        return self.root_native_widget

    @property
    def body(self):
        """The Qt widget holding the controls (inside the scroll area)."""
        return self.root_native_widget.widget()

    # --- building -----------------------------------------------------------------

    def action(self, text, callback, *, when=None, tooltip=None):
        """An action button: starts ``callback``, disabled while a job runs.

        Parameters
        ----------
        text : str
            The button's text.
        callback : callable
            Called when the button is pressed.
        when : callable, optional
            ``when()`` says whether the button may be enabled when no job
            runs (e.g. only once there is a model).
        tooltip : str, optional
            The button's tooltip.

        Returns
        -------
        magicgui.widgets.PushButton
            The button.
        """
        when = when or (lambda: True)
        button = PushButton(text=text, enabled=when(), tooltip=tooltip)
        button.changed.connect(callback)
        self._actions.append((button, when))
        return button

    def folded(self, controls, text="more options"):
        """Options few need to change, folded away under a button.

        Parameters
        ----------
        controls : sequence of magicgui widgets
            The options: hidden until the button is pressed, shown until it
            is pressed again (their values are used all the same).
        text : str, optional
            What the button says, after a disclosure triangle.

        Returns
        -------
        list of magicgui widgets
            The button and the options, to put in :meth:`arrange`'s list.
        """
        controls = list(controls)
        names = ", ".join(str(control.label or getattr(control, "text", ""))
                          for control in controls)
        closed, opened = f"\u25b8 {text}", f"\u25be {text}"  # a disclosure triangle
        button = PushButton(text=closed, tooltip=f"show or hide: {names}")

        def toggle(*_):
            show = button.text == closed
            button.text = opened if show else closed
            for control in controls:
                control.visible = show

        for control in controls:
            control.visible = False
        button.changed.connect(toggle)
        return [button, *controls]

    def arrange(self, controls, after=(), fill=None):
        """Lay out the pickers, ``controls``, Cancel and progress, status, ``after``.

        Parameters
        ----------
        controls : sequence of magicgui widgets
            The widget's parameters and action buttons, in order.
        after : sequence of magicgui widgets, optional
            What comes below the status line.
        fill : QWidget, optional
            A Qt widget at the bottom (a table of results) that takes the
            dock's remaining height. Without it, and without a control that
            grows (a text box), the controls keep to the top of the dock.
        """
        pickers = [self._image] + ([self._region] if self._region is not None else [])
        self.extend([*pickers, *controls, self._busy, self._status, *after])
        for widget in self:
            if isinstance(widget, Label):  # a long text wraps: it does not widen the dock
                widget.native.setWordWrap(True)
        layout = self.body.layout()
        if fill is not None:
            layout.addWidget(fill)
            return
        grows = {QSizePolicy.Expanding, QSizePolicy.MinimumExpanding, QSizePolicy.Ignored}
        if not any(widget.native.sizePolicy().verticalPolicy() in grows for widget in self):
            layout.addStretch(1)

    def _running(self):
        """A run is under way. A cancelled job counts as ended: its worker
        stops at the core's next record and hands nothing over."""
        return self._job is not None and not (self._job.done or self._job.cancelled)

    def refresh_actions(self):
        """Enable the action buttons that may be enabled now (no job running)."""
        busy = self._running()
        for button, when in self._actions:
            button.enabled = not busy and bool(when())

    # --- input ----------------------------------------------------------------------

    def input_array(self, *, region=True, ndims=(2,), hint=None, copy=True):
        """The picked layer's data (a copy), cropped to the rectangle if any.

        Parameters
        ----------
        region : bool, optional
            Crop to the rectangle picker's first shape (when the widget has
            one and it is set).
        ndims : tuple of int, optional
            The accepted numbers of non-colour axes.
        hint : str, optional
            What to do when the layer has another number of axes.
        copy : bool, optional
            False: the layer's data itself, for a job that only reads it in
            its worker (the core never writes its input): no copy of a large
            layer in the viewer's thread.

        Returns
        -------
        data : ndarray
        channel_axis : int or None

        Raises
        ------
        ValueError
            No usable layer (see :func:`~car_napari._widgets._layers.layer_array`).
        """
        shapes = self._region.value if region and self._region is not None else None
        options = {} if hint is None else {"hint": hint}
        return layer_array(self._image.value, shapes, ndims=ndims, copy=copy, **options)

    # --- running --------------------------------------------------------------------

    def start(self, *_):
        """Start the widget's job on the picked layer, in a worker thread.

        Returns
        -------
        Job or None
            The running job; None when the input or a control is unusable
            (an error notification says why, and the viewer is unchanged).
        """
        return self.launch(self._start)

    def _start(self):
        raise NotImplementedError("a widget defines _start() to start its job")

    def launch(self, begin):
        """Call ``begin()``; its ValueError or OSError becomes a notification.

        Parameters
        ----------
        begin : callable
            Reads the input and starts a job (or acts at once).

        Returns
        -------
        object
            What ``begin()`` returns (the running job), or None when it
            raised (the error notification shown).
        """
        self.record.settle()  # the input is read from the viewer as the last undo left it
        try:
            return begin()
        except (ValueError, OSError) as exc:
            self.notify_error(exc)
            return None

    def run(self, job, *, preview=None, done=None, collect=None):
        """Start ``job`` in a worker; returns the :class:`~._jobs.Job`.

        Parameters
        ----------
        job : generator
            An ``iter_<name>(...)`` call (or :func:`~._jobs.call`).
        preview : callable, optional
            ``preview(partial)`` shows a record's preview live; it writes to
            the viewer only through :attr:`record`. Previews arriving faster
            than a few a second are skipped but for the latest
            (:data:`~._jobs.PREVIEW_INTERVAL`); the last one is shown before
            the result.
        collect : callable, optional
            ``collect(partial)`` is called with every preview, at once, when
            previews are pieces of the result (a clip's frames): it keeps
            them (no layer update) for the next ``preview`` to show.
        done : callable, optional
            ``done(result)`` shows the result (through :attr:`record`); it
            may set the status line, which otherwise says "done". A
            generator function shows a large result in steps, one per
            event-loop turn (``yield`` after each layer added, so that the
            viewer draws in between): the job is done, and the run complete,
            after its last step; Cancel in between undoes the run.

        Returns
        -------
        Job
            The running job.
        """
        if self._job is not None and not self._job.done:
            self._job.cancel()
        self._recuts.stop()  # a re-cut of an older result writes nothing any more
        self.record.commit()
        self._set_progress(0)
        self._status.value = "starting"
        self._job = None
        job_ = Job(
            job,
            on_progress=self._on_progress,
            on_preview=None if preview is None else (
                lambda record: self._on_preview(job_, record.preview, preview)),
            on_collect=None if collect is None else (
                lambda record: self._on_preview(job_, record.preview, collect)),
            on_done=lambda result: self._on_done(result, done),
            on_error=self._on_error,
            on_cancel=self._on_cancel,
            on_finished=lambda _job: self.refresh_actions(),
        )
        self._job = job_
        self._cancel.enabled = True
        self.refresh_actions()
        return job_

    def recut(self, show, job=None):
        """Show the last result anew at the controls' values (a re-cut, a
        re-threshold), the latest request winning; no run.

        ``show`` writes the layers through :attr:`record` as a run's
        ``done`` does, and is treated alike: its changes are committed, or
        undone when it fails (an error notification says why). Nothing is
        shown while a run is under way (it owns the layers, and a new run
        drops the re-cuts asked for before it).

        Parameters
        ----------
        show : callable
            ``show(value)`` with the job's result, or ``show()`` without a
            job; a generator function's steps are all run at once.
        job : generator, optional
            Computes the value in a worker (see :class:`~._jobs.LatestWins`
            and :attr:`recuts_interrupt`); None: ``show()`` runs now, and a
            re-cut running or waiting in a worker is dropped.
        """
        if job is not None:
            self._recuts.request(job, lambda value: self._show_recut(show, value),
                                 self._recut_failed)
            return
        self._recuts.stop()
        self._show_recut(show)

    @property
    def _recut_job(self):
        """The re-cut running in a worker, or None."""
        return self._recuts.job

    def _show_recut(self, show, *value):
        if self._running():
            return
        self.record.commit()  # what the re-cut changes, and nothing else, is undone
        try:
            shown = show(*value)
            if inspect.isgenerator(shown):
                for _step in shown:
                    pass
        except Exception as exc:  # a failure to show is the user's to see, as a run's
            self._recut_failed(exc)
            return
        self.record.commit()

    def _recut_failed(self, exc):
        self.record.undo()
        self._status.value = "re-cut failed"
        self.notify_error(exc)

    def cancel(self, *_):
        """Stop the running job; the viewer is put back as it was before it.

        The action buttons come back at once; the worker stops at the core's
        next record and anything it still produces is ignored.
        """
        if self._job is not None:
            self._job.cancel()

    # A job hands nothing over once cancelled, and starting a job cancels the
    # previous one: the callbacks below are always the current job's.

    def _on_progress(self, record):
        self._set_progress(int(round(100 * min(max(float(record.fraction), 0.0), 1.0))))
        self._status.value = f"{record.stage}: {record.message}" if record.message else record.stage

    def _set_progress(self, percent):
        """Set the progress bar, painted with the window's next paint.

        QProgressBar.setValue repaints at once, and a paint of any widget
        composes the whole window with napari's canvas (about 15 ms over a
        4000x4000 image here, at every percent). With the bar's updates off
        around it, re-enabling them asks for an ordinary (coalesced) paint.
        """
        bar = self._progress.native
        bar.setUpdatesEnabled(False)
        try:
            self._progress.value = percent
        finally:
            bar.setUpdatesEnabled(True)

    def _on_preview(self, job, partial, show):
        try:
            show(partial)
        except Exception as exc:  # a failure to display stops the run
            job.cancel()
            self._fail(exc)

    def _on_done(self, result, done):
        self._set_progress(100)
        self._status.value = "done"
        try:
            shown = done(result) if done is not None else None
        except Exception as exc:  # a failure applying results is the user's to see
            self._cancel.enabled = False
            self._fail(exc)
            return None
        if inspect.isgenerator(shown):
            return self._show_steps(shown)  # Cancel stays enabled until the last step
        self._cancel.enabled = False
        self.record.commit()
        return None

    def _show_steps(self, steps):
        """The steps of a ``done`` generator (run one per event-loop turn by
        the job), then the run is complete. A Cancel in between closes them
        here and undoes the run; a step's error undoes it too (``_on_error``)."""
        yield from steps
        self._cancel.enabled = False
        self.record.commit()

    def _on_error(self, exc):
        self._cancel.enabled = False
        self._fail(exc)

    def _on_cancel(self):
        self._cancel.enabled = False
        self.record.undo()
        self._set_progress(0)
        self._status.value = "cancelled"  # until the next run says "starting"
        self.refresh_actions()

    def _fail(self, exc):
        self.record.undo()
        self._set_progress(0)
        self._status.value = "failed"
        self.notify_error(exc)

    # --- messages -------------------------------------------------------------------

    def message(self, exc):
        """The text of ``exc`` in this widget's terms.

        A ValueError (the core's validation) is its message with the core's
        argument names replaced by the control labels of
        :attr:`control_labels` (``'n_segments (20) must ...'`` becomes
        ``'segments (20) must ...'``); anything else is prefixed by its type.

        Parameters
        ----------
        exc : Exception
            The error.

        Returns
        -------
        str
            The message to show.
        """
        text = str(exc)
        if not isinstance(exc, (ValueError, OSError)):
            return f"{type(exc).__name__}: {text}"
        for name, label in self.control_labels.items():
            # an argument name as the subject: "name must", "name (3) must", "name="
            pattern = rf"(?<![\w'\"]){re.escape(name)}(?=\s*(?:\(|must\b|=|is\b))"
            text = re.sub(pattern, f"'{label}'", text)
        return text

    def notify_error(self, exc):
        """Show ``exc`` as an error notification, in this widget's terms.

        Parameters
        ----------
        exc : Exception
            The error.
        """
        show_error(self.message(exc))


class ModelWidget(JobWidget):
    """A :class:`JobWidget` that fits a model and synthesises from it.

    Adds the synthesis controls (height, width, seed) and its Synthesize
    button, enabled once there is a model. A subclass defines ``_start()``
    (the fit, which sets :attr:`model`) and ``_synthesis(shape, seed)``
    (which starts the synthesis job with :meth:`run`; there is no default).

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer.
    size : int, optional
        The default height and width of a synthesis.
    min_size : int, optional
        The smallest height and width.

    Attributes
    ----------
    model : object or None
        The fitted (or loaded) model.
    """

    no_model = "fit a model first."

    def __init__(self, napari_viewer, *, size=256, min_size=1):
        super().__init__(napari_viewer, region=True)
        self.model = None
        self._height = SpinBox(value=size, min=min_size, max=8192, label="height",
                               tooltip="rows of the synthesised image, in pixels")
        self._width = SpinBox(value=size, min=min_size, max=8192, label="width",
                              tooltip="columns of the synthesised image, in pixels")
        self._seed = SpinBox(value=0, min=0, max=2**31 - 1, label="seed",
                             tooltip="the random seed: the same seed gives the same image, "
                                     "another seed another one")
        self._synth = self.action("Synthesize", self.start_synthesis,
                                  when=lambda: self.model is not None,
                                  tooltip="make a new image from the fitted model; it is "
                                          "placed beside the fitted layer")

    start_fit = JobWidget.start

    def start_synthesis(self, *_):
        """Synthesise from the model at the chosen size and seed, in a worker.

        Returns
        -------
        Job or None
            The running job; None without a model (an error notification says so).
        """
        return self.launch(self._start_synthesis)

    def _start_synthesis(self):
        if self.model is None:
            raise ValueError(self.no_model)
        shape = (int(self._height.value), int(self._width.value))
        return self._synthesis(shape, int(self._seed.value))
