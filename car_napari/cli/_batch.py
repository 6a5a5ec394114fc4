"""The batch runners: every input through a job, one failure per line (the
batch goes on), serially or on the cluster; a chain of blocks; one large
image tile by tile."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import from_unit
from ._cluster import dask_client
from ._console import ProgressBar, is_quiet, say


class BatchFailed(Exception):
    """Raised by :func:`run_batch` when no input succeeded (exit status 2)."""


#: What a failure of one input raises: reported on one line, the batch goes on.
INPUT_ERRORS = (ValueError, TypeError, OSError)


def run_batch(paths, process, *, outputs=None, on_done=None, options=None, quiet=False,
              unit="image"):
    """Run ``process(path, on_progress)`` on every input, each failure on one line.

    Parameters
    ----------
    paths : list of pathlib.Path
        The input files (from :func:`expand_inputs`, called first so that a
        command with no inputs fails before it writes anything). Any
        picklable items with a ``name`` (the bar's and the lines' label)
        will do: e.g. a clip's blocks of frames, one task each.
    process : callable
        ``process(path, on_progress)`` does one input (writing its outputs)
        and returns a short line on it, or ``(line, payload)``; a
        ValueError, TypeError or OSError it raises is that input's failure.
        ``on_progress`` takes the job's Progress records. On a cluster it
        runs in a worker process, so it must not hold open files.
    outputs : callable, optional
        ``outputs(path)``: the files the input writes. When all exist the
        input is skipped, unless ``options.overwrite``.
    on_done : callable, optional
        ``on_done(path, payload)`` in this process, in the order inputs
        finish (e.g. to write a shared table).
    options : argparse.Namespace, optional
        ``workers``, ``scheduler``, ``overwrite`` (:func:`add_cluster`); none:
        one input after another in this process.
    quiet : bool, optional
        Nothing but errors: no per-input lines, no line on skipped inputs
        (also under :func:`quiet_mode`).
    unit : str, optional
        What the progress bar counts.

    Returns
    -------
    status : int
        0 when every input succeeded (or was skipped), 1 when some failed.

    Raises
    ------
    BatchFailed
        When every input failed (the command's exit status is then 2).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for name in ("a.png", "b.png"):
    ...     _ = (folder / name).write_bytes(b"")
    >>> def size(path, on_progress):
    ...     if path.name == "b.png":
    ...         raise ValueError("not an image")
    ...     return "fine"
    >>> run_batch(expand_inputs([str(folder)]), size)
    a.png: fine
    1
    """
    quiet = quiet or is_quiet()
    overwrite = bool(getattr(options, "overwrite", False))
    todo = [p for p in paths
            if overwrite or outputs is None or not all(f.exists() for f in outputs(p))]
    skipped = len(paths) - len(todo)
    failed = 0
    with ProgressBar(len(paths), unit=unit) as bar:
        if skipped and not quiet:
            bar.write(f"{skipped} of {len(paths)} inputs skipped: their outputs exist "
                      "(--overwrite to redo them).", err=True)
        bar.skip(skipped)
        for path, result in _results(todo, process, options, bar):
            if isinstance(result, BaseException):
                failed += 1
                bar.write(f"{path.name}: failed: {result}", err=True)
                continue
            line, payload = result if isinstance(result, tuple) else (result, None)
            if on_done is not None:
                on_done(path, payload)
            if line and not quiet:
                bar.write(f"{path.name}: {line}")
        bar.begin(len(paths), "done")
    return _exit_status(failed, len(paths), len(todo), "input", bar)


def _results(paths, process, options, bar):
    """(path, result or the exception it raised), as the inputs finish."""
    workers = getattr(options, "workers", 1) or 1
    scheduler = getattr(options, "scheduler", None)
    if scheduler is None and workers <= 1:
        for i, path in enumerate(paths):
            bar.begin(bar.position(i), path.name)
            try:
                yield path, process(path, bar.on_progress)
            except INPUT_ERRORS as exc:
                yield path, exc
        return
    yield from _cluster_results(paths, process, workers, scheduler, bar)


def _run_one(process, path):
    """One input on a worker: its result, or the input error it raised (sent
    back as a value, so that the others go on)."""
    try:
        return process(path, _ignore)
    except INPUT_ERRORS as exc:
        return exc


def _ignore(record):
    """A worker's Progress records stay on the worker (the bar counts inputs)."""


def _cluster_results(paths, process, workers, scheduler, bar):
    with dask_client(workers, scheduler) as client:  # first: says what to install
        from dask.distributed import as_completed

        futures = {client.submit(_run_one, process, path, pure=False): path for path in paths}
        done = 0
        for future in as_completed(futures):
            done += 1
            bar.begin(bar.position(done - 1), futures[future].name)
            yield futures[future], future.result()


def run_blocks(blocks, prepare, finish, *, options=None, quiet=False, unit="block"):
    """Blocks of a sequence whose results chain: each block's ``prepare``
    (independent: e.g. detecting a clip's damage) runs on any worker, its
    ``finish`` (e.g. filling it from the previous block's last restored
    frame) after the previous block's, with what that one carried.

    Parameters
    ----------
    blocks : list
        Picklable items with a ``name`` (a block of frames), in order.
    prepare : callable
        ``prepare(block, on_progress)``: a picklable value for ``finish``.
    finish : callable
        ``finish(block, prepared, carried, on_progress)`` writes the block's
        outputs and returns ``(line, carry)``: a short line on it and what the
        next block's ``finish`` gets as ``carried`` (None for the first
        block, and after a block that failed).
    options : argparse.Namespace, optional
        ``workers``, ``scheduler`` (:func:`add_cluster`); none: in this process.
    quiet : bool, optional
        Nothing but errors: no per-block lines (also under :func:`quiet_mode`).
    unit : str, optional
        What the progress bar counts.

    Returns
    -------
    status : int
        0 when every block succeeded, 1 when some failed (each reported on
        one line; the chain goes on from nothing carried).

    Raises
    ------
    BatchFailed
        When every block failed.

    Examples
    --------
    >>> from types import SimpleNamespace as Block
    >>> blocks = [Block(name=f"frames {k}", start=k) for k in (0, 3, 6)]
    >>> def prepare(block, on_progress):
    ...     return block.start * 10
    >>> def finish(block, prepared, carried, on_progress):
    ...     total = prepared + (carried or 0)
    ...     return f"total {total}", total
    >>> run_blocks(blocks, prepare, finish)
    frames 0: total 0
    frames 3: total 30
    frames 6: total 90
    0
    """
    workers = getattr(options, "workers", 1) or 1
    scheduler = getattr(options, "scheduler", None)
    failed = 0
    with ProgressBar(len(blocks), unit=unit) as bar:
        if scheduler is None and workers <= 1:
            results = _serial_blocks(blocks, prepare, finish, bar)
        else:
            results = _cluster_blocks(blocks, prepare, finish, workers, scheduler, bar)
        for block, result in results:
            if isinstance(result, BaseException):
                failed += 1
                bar.write(f"{block.name}: failed: {result}", err=True)
            elif result[0] and not (quiet or is_quiet()):
                bar.write(f"{block.name}: {result[0]}")
        bar.begin(len(blocks), "done")
    return _exit_status(failed, len(blocks), len(blocks), "block", bar)


def _exit_status(failed, total, tried, what, bar):
    """0 when nothing failed, 1 (and a line on stderr) when some of the
    ``tried`` failed; :class:`BatchFailed` when every one of ``total`` did."""
    if failed and failed == total:
        raise BatchFailed(f"no {what} could be processed ({failed} failed; see above).")
    if failed:
        bar.write(f"{failed} of {tried} {what}s failed (see above).", err=True)
    return 1 if failed else 0


def _finish_one(finish, block, prepared, previous):
    """A block's ``finish`` on a worker: ``(line, carry)``, or the input error
    of its ``prepare`` or its own (the next block then carries nothing)."""
    if isinstance(prepared, BaseException):
        return prepared
    carried = None if previous is None or isinstance(previous, BaseException) else previous[1]
    try:
        return finish(block, prepared, carried, _ignore)
    except INPUT_ERRORS as exc:
        return exc


def _serial_blocks(blocks, prepare, finish, bar):
    previous = None
    for i, block in enumerate(blocks):
        bar.begin(i, block.name)
        try:
            prepared = prepare(block, bar.on_progress)
        except INPUT_ERRORS as exc:
            prepared = exc
        previous = _finish_one(finish, block, prepared, previous)
        yield block, previous


def _cluster_blocks(blocks, prepare, finish, workers, scheduler, bar):
    with dask_client(workers, scheduler) as client:
        prepared = [client.submit(_run_one, prepare, block, pure=False) for block in blocks]
        chain, previous = [], None
        for block, ready in zip(blocks, prepared, strict=True):
            # dask passes the previous block's result (not its future) once it is done
            previous = client.submit(_finish_one, finish, block, ready, previous, pure=False)
            chain.append(previous)
        for i, (block, future) in enumerate(zip(blocks, chain, strict=True)):
            result = future.result()
            bar.begin(i + 1, block.name)
            yield block, result


def run_large_job(inputs, output, job, *, verb):
    """One large image (zarr, TIFF) through ``job(image, out)`` (an
    ``iter_<name>`` generator writing ``out`` tile by tile), written to
    ``output`` (.zarr, .ome.zarr or .tif) in the input's dtype (8 and 16-bit
    stay so, anything else float32), with a progress bar."""
    import time

    from ..io.arrays import create_array, is_large_path, open_array

    if len(inputs) != 1 or not is_large_path(inputs[0]):
        raise ValueError(f"an output {Path(output).name} is one large image: give one input "
                         f".zarr, .ome.zarr or .tif (got {list(inputs)}); for a batch, -o "
                         "names a folder.")
    image = open_array(inputs[0])
    dtype = image.dtype if np.dtype(image.dtype) in (np.uint8, np.uint16) else np.float32
    out = create_array(output, image.shape, dtype)
    t0 = time.perf_counter()
    with ProgressBar(1, unit="image") as bar:
        bar.begin(0, Path(inputs[0]).name)
        from .._progress import drain

        drain(job(image, _Converted(out, np.dtype(dtype))), bar.on_progress)
    if hasattr(out, "flush"):
        out.flush()  # a TIFF memory map
    shape = "x".join(map(str, image.shape))
    say(f"{Path(inputs[0]).name}: {verb} ({shape}), {time.perf_counter() - t0:.1f} s "
        f"-> {output}")
    return 0


class _Converted:
    """An output array that takes values on the [0, 1] scale (:func:`from_unit`)."""

    def __init__(self, out, dtype):
        self.out, self.dtype, self.shape = out, dtype, out.shape

    def __setitem__(self, key, values):
        self.out[key] = from_unit(values, self.dtype)
