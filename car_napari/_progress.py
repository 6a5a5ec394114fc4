"""The job protocol of every long computation (Qt-free).

A long computation is a generator ``iter_<name>(...)`` that yields
:class:`Progress` records and *returns* its result; ``<name>(...)`` is the
same call run to its end by :func:`drain`. A napari worker drives the
generator directly (its ``yielded`` and ``returned`` signals), the command
line turns the records into a progress bar, and closing the generator (a
Cancel) stops the work at the next yield: kernels run in chunks (rows, tiles,
EM iterations) with a yield between them.

Generators that run another one as a stage use :func:`stage`, which maps
the inner fractions into a part of the outer range (other inner generators,
such as kernel loops yielding units of work, go through :func:`mapped`, or
:func:`result_of` where nobody watches them); a job of several stages
gives each its :class:`Span` of [0, 1] by :func:`spans`; a front end that
shows a job's previews otherwise (converted, decimated) runs it through
:func:`map_previews`. Work split into
calls between records goes by :func:`row_blocks`, and runs side by side on
the job pool (:mod:`car_napari._threads`) by :func:`iter_chains` (or, whole
jobs, :func:`side_by_side`). Every job runs with BLAS limited to one thread
(:mod:`car_napari._threads`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

from ._threads import limited_blas

__all__ = ["Progress", "Span", "drain", "iter_chains", "map_previews", "mapped", "result_of",
           "row_blocks", "side_by_side", "spans", "stage"]


@dataclass(frozen=True)
class Progress:
    """One progress record of a long computation.

    Attributes
    ----------
    stage : str
        What the computation is doing, in a word or two ("features",
        "merging", "rows").
    fraction : float
        The fraction of the whole work done, in [0, 1], proportional to the
        work (not to the stages).
    message : str
        A short human-readable status line ("K = 7", "rows 128/512").
    preview : object, optional
        A partial result for live display (an image filling in, the labels
        after a merge), or None.

    Examples
    --------
    >>> import numpy as np
    >>> import car_napari as car
    >>> job = car.iter_restore(np.random.default_rng(0).random((64, 64)))
    >>> first = next(job)
    >>> isinstance(first, car.Progress) and 0.0 <= first.fraction <= 1.0
    True
    >>> job.close()
    """

    stage: str
    fraction: float
    message: str = ""
    preview: Any = None


class Span(NamedTuple):
    """A stage's part ``[start, stop)`` of a job's [0, 1] progress range.

    A tuple: ``lo, hi = span`` and ``stage(job, *span)`` work.

    Attributes
    ----------
    start, stop : float
        The stage's first and last fraction.

    Examples
    --------
    >>> Span(0.2, 0.6).at(1, 4)
    0.3
    """

    start: float
    stop: float

    def at(self, done, total=1):
        """The job's fraction when ``done`` of the stage's ``total`` is done.

        Parameters
        ----------
        done : float
            The work of the stage done.
        total : float, optional
            The stage's whole work (default 1: ``done`` is a fraction).

        Returns
        -------
        float
            ``start + (stop - start) * done / total``.
        """
        return self.start + (self.stop - self.start) * done / total


def spans(work):
    """The stages' spans of [0, 1], in proportion to their work.

    Parameters
    ----------
    work : dict
        ``{stage name: work}`` in the order the stages run (a stage of no
        work gets an empty span).

    Returns
    -------
    callable
        ``span(name) -> Span``.

    Examples
    --------
    >>> span = spans({"reading": 1.0, "scans": 3.0})
    >>> span("scans")
    Span(start=0.25, stop=1.0)
    >>> span("scans").at(1, 2)
    0.625
    """
    total = sum(work.values())
    bounds, at = {}, 0.0
    for name, value in work.items():
        bounds[name] = Span(at / total, (at + value) / total)
        at += value
    return bounds.__getitem__


def row_blocks(stop, size, *, start=0, merge_tail=False):
    """Consecutive ``(a, b)`` ranges of at most ``size`` over ``[start, stop)``.

    The one chunking of every job's work into calls between records (rows
    of an image, frames of a clip, rows of a feature array).

    Parameters
    ----------
    stop : int
        The end of the range covered.
    size : int or float
        The most a range holds (its integer part, at least 1).
    start : int, optional
        The first index covered.
    merge_tail : bool, optional
        Merge a last range shorter than ``size // 2`` into the one before
        it (a BLAS product over the blocks then sees the shapes one call
        would, up to its tiles).

    Returns
    -------
    list of (int, int)
        The ranges, in order (none for an empty range).

    Examples
    --------
    >>> row_blocks(7, 3)
    [(0, 3), (3, 6), (6, 7)]
    >>> row_blocks(9, 4, merge_tail=True)
    [(0, 4), (4, 9)]
    >>> row_blocks(9, 4.5, start=2)
    [(2, 6), (6, 9)]
    """
    size = max(1, int(size))
    blocks = [(a, min(a + size, stop)) for a in range(start, stop, size)]
    if merge_tail and len(blocks) > 1 and blocks[-1][1] - blocks[-1][0] < size // 2:
        blocks[-2:] = [(blocks[-2][0], stop)]
    return blocks


def drain(job, on_progress=None):
    """Run a job to its end and return its result.

    The job runs with the BLAS libraries limited to one thread
    (:func:`car_napari._threads.limited_blas`: many small matrix products
    run faster so, and do not fight a busy machine's other processes).

    Parameters
    ----------
    job : generator
        An ``iter_<name>(...)`` generator yielding :class:`Progress` records.
    on_progress : callable, optional
        Called with every :class:`Progress` record (a progress bar, a log).

    Returns
    -------
    result : object
        The generator's return value: what ``<name>(...)`` returns.

    Raises
    ------
    TypeError
        If ``job`` is not a generator (an iterator) or ``on_progress`` is not
        callable.

    Examples
    --------
    >>> import numpy as np
    >>> import car_napari as car
    >>> image = np.random.default_rng(0).random((64, 64))
    >>> stages = []
    >>> restored = car.drain(car.iter_restore(image), lambda p: stages.append(p.stage))
    >>> restored.shape, stages[0]
    ((64, 64), 'start')
    """
    if not hasattr(job, "__next__"):
        raise TypeError(f"job must be a generator (an iter_<name>(...) call); got "
                        f"{type(job).__name__}.")
    if on_progress is not None and not callable(on_progress):
        raise TypeError(f"on_progress must be None or a callable taking a Progress; got "
                        f"{on_progress!r}.")
    with limited_blas():
        while True:
            try:
                record = next(job)
            except StopIteration as stop:
                return stop.value
            if on_progress is not None:
                on_progress(record)


def stage(job, start, stop, *, name=None, prefix="", previews=True):
    """Run a job as one stage of another: its fractions mapped into a range.

    Use as ``result = yield from stage(iter_other(...), 0.1, 0.9)``.

    Parameters
    ----------
    job : generator
        The inner ``iter_<name>(...)`` generator.
    start, stop : float
        The part of the outer job's [0, 1] range the inner job covers.
    name : str, optional
        A stage name for the inner records (default: keep theirs).
    prefix : str, optional
        Put before each inner message (for example ``"subspace 2/4: "``).
    previews : bool, optional
        Keep the inner records' previews (default); False drops them (the
        inner job's partial result is not the outer one's: a tile of a
        frame).

    Yields
    ------
    record : Progress
        The inner records, rescaled.

    Returns
    -------
    result : object
        The inner job's return value.

    Examples
    --------
    >>> def inner():
    ...     yield Progress("work", 0.5, "half")
    ...     return 42
    >>> def outer():
    ...     value = yield from stage(inner(), 0.2, 0.6, prefix="inner: ")
    ...     return value + 1
    >>> records = []
    >>> drain(outer(), records.append)
    43
    >>> records[0].fraction, records[0].message
    (0.4, 'inner: half')
    """
    span = stop - start
    return (yield from mapped(job, lambda record: Progress(
        record.stage if name is None else name,
        start + span * min(max(float(record.fraction), 0.0), 1.0),
        prefix + record.message,
        record.preview if previews else None,
    )))


def mapped(job, convert):
    """Run a generator inside a job: what it yields converted, its result
    returned.

    The one place a job steps another generator by hand: a stage's records
    rescaled (:func:`stage`), or the units of work a kernel loop yields
    turned into :class:`Progress` records.

    Parameters
    ----------
    job : generator
        The inner generator.
    convert : callable
        Called with each item the inner generator yields; what it returns is
        yielded, unless it is None (the item is then only counted, or
        dropped).

    Yields
    ------
    object
        The converted items.

    Returns
    -------
    result : object
        The inner generator's return value.

    Examples
    --------
    >>> def rows():
    ...     yield 10
    ...     yield 20
    ...     return "done"
    >>> def job():
    ...     result = yield from mapped(rows(), lambda n: Progress("rows", n / 20, f"{n} rows"))
    ...     return result
    >>> records = []
    >>> drain(job(), records.append), [r.message for r in records]
    ('done', ['10 rows', '20 rows'])
    """
    while True:
        try:
            item = next(job)
        except StopIteration as stop:
            return stop.value
        converted = convert(item)
        if converted is not None:
            yield converted


def result_of(job):
    """Run a generator to its end, dropping what it yields; its return value.

    For a sub-step run inside a job or a plain function, where nobody
    watches its progress (:func:`drain` is the entry point of a whole job).

    Parameters
    ----------
    job : generator
        The generator.

    Returns
    -------
    result : object
        Its return value.

    Examples
    --------
    >>> def rows():
    ...     yield 10
    ...     return "done"
    >>> result_of(rows())
    'done'
    """
    while True:
        try:
            next(job)
        except StopIteration as stop:
            return stop.value


def map_previews(job, transform):
    """Run a job with each record's preview replaced by ``transform(preview)``.

    Use as ``result = yield from map_previews(iter_other(...), convert)``:
    the records' stages, fractions and messages are kept, records without a
    preview pass as they are, and the result is the job's. Closing the
    generator closes ``job`` (a Cancel stops it at its next record).

    Parameters
    ----------
    job : generator
        An ``iter_<name>(...)`` generator.
    transform : callable
        ``transform(preview)`` is what a record's preview becomes (called
        where the job runs: in a widget's worker, not in the viewer's thread).

    Yields
    ------
    record : Progress
        The job's records, their previews transformed.

    Returns
    -------
    result : object
        The job's return value.

    Examples
    --------
    >>> def job():
    ...     yield Progress("rows", 0.5, "half", preview=[1, 2])
    ...     yield Progress("rows", 1.0, "done")
    ...     return "result"
    >>> records = []
    >>> drain(map_previews(job(), sum), records.append)
    'result'
    >>> [(record.message, record.preview) for record in records]
    [('half', 3), ('done', None)]
    """
    try:
        return (yield from mapped(job, lambda record: record if record.preview is None else
                                  replace(record, preview=transform(record.preview))))
    finally:
        job.close()


def iter_chains(pool, chains):
    """Run chains of calls, the chains side by side on ``pool``, each chain's
    calls one after the other: the one scheduler of every job's threads.

    The calls gain where they release the GIL (Numba ``nogil`` kernels,
    NumPy). How the work is split into calls must not depend on ``pool``
    (the callers' splits are fixed), so that a job's results are the same
    on any number of threads (``CAR_NAPARI_JOB_THREADS``).

    Parameters
    ----------
    pool : concurrent.futures.Executor or None
        Threads to run the chains on (:func:`car_napari._threads.job_pool`);
        None: one chain after the other, here.
    chains : list of iterable
        Iterables of zero-argument callables, drawn lazily: the next call of
        a chain is drawn when its previous call has finished, so it may
        depend on it.

    Yields
    ------
    value : object
        Each call's return value as it finishes (calls finishing together:
        in the order of their chains).

    Notes
    -----
    Closing the generator early starts no more calls, and returns once the
    running ones have finished (they may write into the job's arrays).

    Examples
    --------
    >>> list(iter_chains(None, [[lambda: 1, lambda: 2], [lambda: 3]]))
    [1, 2, 3]
    """
    from concurrent.futures import FIRST_COMPLETED, wait

    chains = [iter(chain) for chain in chains]
    if pool is None:
        for chain in chains:
            for call in chain:
                yield call()
        return
    pending = {}

    def submit(k):
        call = next(chains[k], None)
        if call is not None:
            pending[pool.submit(call)] = k

    try:
        for k in range(len(chains)):
            submit(k)
        while pending:
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for future in sorted(done, key=pending.get):
                k = pending.pop(future)
                value = future.result()
                submit(k)
                yield value
    finally:  # closing early: do not start what is queued, let the running end
        for future in pending:
            future.cancel()
        wait(list(pending))


def side_by_side(jobs, pool):
    """Run jobs side by side, each stepped to its next record in a thread of
    ``pool``: their records, as they come, then the list of their results.

    Use as ``results = yield from side_by_side([iter_a(...), iter_b(...)], pool)``.
    The jobs gain where their work between records releases the GIL (Numba
    ``nogil`` kernels, NumPy); they must not share state they write. Closing
    early lets each job's running step end (a record's work) and closes them.
    Scheduled by :func:`iter_chains`: each job a chain of steps.

    Parameters
    ----------
    jobs : list of generator
        ``iter_<name>(...)`` generators.
    pool : concurrent.futures.Executor or None
        Threads to run them on; None: one after the other, here.

    Yields
    ------
    record : Progress
        The jobs' records as they come, a fraction that would fall (a record
        made before one that came first) raised to the one before it.

    Returns
    -------
    results : list
        The jobs' return values, in the order of ``jobs``.

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> def count(n):
    ...     for k in range(n):
    ...         yield Progress("count", (k + 1) / n)
    ...     return n
    >>> with ThreadPoolExecutor(2) as pool:
    ...     records = []
    ...     drain(side_by_side([count(2), count(3)], pool), records.append)
    ...     len(records)
    [2, 3]
    5
    """
    jobs = list(jobs)
    results = [None] * len(jobs)
    if pool is None:
        for k, job in enumerate(jobs):
            results[k] = yield from job
        return results
    finished = [False] * len(jobs)

    def steps(k):
        def step():
            try:
                return next(jobs[k])
            except StopIteration as stop:
                finished[k] = True
                results[k] = stop.value
                return None

        while not finished[k]:
            yield step

    highest = -float("inf")
    try:
        for record in iter_chains(pool, [steps(k) for k in range(len(jobs))]):
            if record is None:
                continue
            if record.fraction < highest:  # made before one that came first
                record = replace(record, fraction=highest)
            highest = record.fraction
            yield record
    finally:  # a job can be closed only once its running step has returned
        for job in jobs:
            job.close()
    return results
