"""What a command prints: ``--quiet``, notes and summary lines on stderr,
and the progress bar."""

from __future__ import annotations

import contextlib
import sys

_QUIET = {"on": False}


@contextlib.contextmanager
def quiet_mode(on):
    """Within: with ``on``, nothing but errors (no progress bar, notes or
    per-input lines; :func:`is_quiet`). What ``--quiet`` sets for a command."""
    before = _QUIET["on"]
    _QUIET["on"] = bool(on)
    try:
        yield
    finally:
        _QUIET["on"] = before


def is_quiet():
    """Whether the command runs with ``--quiet`` (:func:`quiet_mode`)."""
    return _QUIET["on"]


def say(text):
    """A line on stderr that is not an error (a summary, where the outputs
    went): above any bar, and not with ``--quiet``."""
    if not is_quiet():
        from tqdm import tqdm

        tqdm.write(text, file=sys.stderr)


class ProgressBar:
    """A tqdm bar on stderr, silent when stderr is not a terminal (and
    under :func:`quiet_mode`).

    ``begin(i, label)`` starts item ``i`` of ``total``; ``on_progress`` (the
    ``drain`` callback) moves the bar within ``span`` items from there by the
    job's fraction done.
    """

    def __init__(self, total, *, unit):
        from tqdm import tqdm

        self._tqdm = tqdm
        self._bar = tqdm(total=total, unit=unit, file=sys.stderr,
                         disable=True if is_quiet() else None,
                         dynamic_ncols=True,
                         bar_format="{percentage:3.0f}%|{bar}| {n:.1f}/{total} "
                                    "[{elapsed}<{remaining}, {rate_fmt}] {postfix}")
        self._total = total
        self._offset = 0
        self._start, self._span, self._label = 0, 1, ""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._bar.close()

    def begin(self, index, label, *, span=1):
        """Start the work on items ``index`` to ``index + span`` (with a span
        of several, the count follows the job's progress through them)."""
        self._start, self._span, self._label = index, span, label[:40]
        self._count(index)
        self._move(index)

    def position(self, index):
        """Where item ``index`` of the work to do starts, after the skipped ones."""
        return self._offset + index

    def skip(self, count):
        """``count`` items are already done (their outputs exist)."""
        self._offset = count
        self._move(count)

    def on_progress(self, record):
        """:func:`car_napari._progress.drain`'s callback: a job's Progress record."""
        position = self._start + self._span * min(max(float(record.fraction), 0.0), 1.0)
        if self._span > 1:  # the item being worked on moves with the percentage
            self._count(position)
        self._move(position)

    def write(self, text, *, err=False):
        """Print a line to stdout (stderr with ``err``) without breaking the bar."""
        self._tqdm.write(text, file=sys.stderr if err else sys.stdout)

    def _count(self, position):
        """The postfix: the item at ``position`` (1-based) of the total, and the label."""
        item = min(int(position) + 1, self._total)
        self._bar.set_postfix_str(f"{item}/{self._total} {self._label}", refresh=False)

    def _move(self, position):
        self._bar.update(position - self._bar.n)  # tqdm redraws at most every 0.1 s


def print_note(text):
    """A one-line note on stderr (``read_image``'s ``on_note``), above any
    bar; none with ``--quiet``."""
    say(f"note: {text}")
