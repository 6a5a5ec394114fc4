"""What the commands share: the input walk (one failure per line, the batch
goes on), the progress bar, argument types and the conversion of results back
to file types."""

from __future__ import annotations

import argparse
import contextlib
import glob
import os
import sys
from pathlib import Path

import numpy as np

from .._validation import from_unit, unit_dtype  # noqa: F401 (the CLI's, from the core)
from ..io.images import IMAGE_SUFFIXES, WRITE_SUFFIXES, is_colour, write_image

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


def expand_inputs(items):
    """The image files named by files, folders and glob patterns, in order.

    Parameters
    ----------
    items : list of str
        File paths (taken as they are), folders (their files with a suffix
        in :data:`~car_napari.io.images.IMAGE_SUFFIXES`, sorted) and glob
        patterns (their matches, sorted).

    Returns
    -------
    paths : list of pathlib.Path
        Every item's files, in the order of the items.

    Raises
    ------
    ValueError
        If there is no file at all, or none of the files named exists (a
        command then stops before it creates its output folder; when only
        some are missing, the batch reports each on its line).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for name in ("b.png", "a.tif", "notes.txt"):
    ...     _ = (folder / name).write_bytes(b"")
    >>> [p.name for p in expand_inputs([str(folder), str(folder / "*.txt")])]
    ['a.tif', 'b.png', 'notes.txt']
    """
    paths = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            paths += sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        elif any(ch in item for ch in "*?["):
            paths += sorted(Path(f) for f in glob.glob(item))
        else:
            paths.append(p)
    if not paths:
        raise ValueError(f"no input images found in {list(items)}")
    if not any(p.is_file() for p in paths):
        shown = ", ".join(str(p) for p in paths[:3]) + (", ..." if len(paths) > 3 else "")
        raise ValueError(f"no such input file: {shown}")
    return paths


def output_file(output, paths, *, suffixes=WRITE_SUFFIXES, what="an image"):
    """The file ``-o`` names, or None when it names a folder: the one rule of
    every command's output.

    A path that is a folder, ends in a slash or has no suffix names a folder
    (the outputs go there, named after the inputs: :func:`output_folder`).
    A path with a suffix names one file, which the single input's result
    is written to; a suffix the command does not write is refused, and so is
    a file for several inputs, before any work.

    Parameters
    ----------
    output : str or path-like
        The ``-o`` argument.
    paths : list of pathlib.Path
        The inputs (from :func:`expand_inputs`).
    suffixes : collection of str, optional
        The file suffixes (lower case) the command writes.
    what : str, optional
        What the command writes, for the messages.

    Returns
    -------
    path : pathlib.Path or None
        The file (its folder created), or None for a folder.

    Raises
    ------
    ValueError
        If the suffix is not one of ``suffixes``, or a file is named for
        several inputs.

    Examples
    --------
    >>> output_file("out/", [Path("a.png")]) is None
    True
    >>> output_file("out/b.xyz", [Path("a.png")])
    Traceback (most recent call last):
    ...
    ValueError: -o out/b.xyz: .xyz is not a file type of an image; ...
    """
    if names_a_folder(output):
        return None
    path = Path(output)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"-o {output}: {path.suffix} is not a file type of {what}; use "
                         f"{', '.join(sorted(suffixes))} for one file, or a folder (a name "
                         "without a suffix, or ending in /).")
    if len(paths) != 1:
        raise ValueError(f"-o {output} names one file, but there are {len(paths)} inputs: "
                         "name a folder (without a suffix, or ending in /) for several.")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def names_a_folder(output):
    """Whether ``-o output`` names a folder: one that exists, a path ending
    in a slash or one without a suffix (else it names a file;
    :func:`output_file`)."""
    path = Path(output)
    return path.is_dir() or str(output).endswith(("/", os.sep)) or not path.suffix


def output_folder(path):
    """The output folder, created if needed: call it once the inputs are
    checked (:func:`expand_inputs`, the command's own files), so that a
    failed command leaves no empty folder behind."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


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
    with _client(workers, scheduler) as client:  # first: says what to install
        from dask.distributed import as_completed

        futures = {client.submit(_run_one, process, path, pure=False): path for path in paths}
        done = 0
        for future in as_completed(futures):
            done += 1
            bar.begin(bar.position(done - 1), futures[future].name)
            yield futures[future], future.result()


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


def _client(workers, scheduler):
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
    with _client(workers, scheduler) as client:
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


def add_cluster(parser, *, overwrite=True):
    """The --workers, --scheduler and (for commands that write a file per
    input) --overwrite options of a batch command."""
    parser.add_argument("--workers", type=positive_int, default=1,
                        help="worker processes on this machine (a dask LocalCluster when "
                             "more than 1; default 1: in this process)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="submit to a running dask scheduler (e.g. tcp://host:8786)")
    if overwrite:
        parser.add_argument("--overwrite", action="store_true",
                            help="redo inputs whose outputs exist (default: skip them)")


def one_image(image, path):
    """``image`` if it is one grey or colour image; a stack (a multi-page
    TIFF) is a ValueError that says what to do."""
    if image.ndim == 2 or is_colour(image):
        return image
    raise ValueError(
        f"{Path(path).name} holds a stack of shape {image.shape}, not one image; this "
        "command takes one image per file (split the stack into files, or for versions "
        "of one scene use 'car-napari restore --stack-axis 0').")


def image_suffix(image, source):
    """The file suffix of a batch's output ``image`` made from the file
    ``source``: .png for 8-bit; 16-bit stays in its container kind, .png
    from a 16-bit grey PNG and .tif from anything else (a TIFF, DICOM, a
    16-bit colour image, which PNG writers do not take); .tif for floats.

    Examples
    --------
    >>> import numpy as np
    >>> grey16 = np.zeros((2, 2), np.uint16)
    >>> image_suffix(grey16, Path("a.png")), image_suffix(grey16, Path("a.tif"))
    ('.png', '.tif')
    """
    if image.dtype == np.uint8:
        return ".png"
    if image.dtype == np.uint16 and image.ndim == 2 and Path(source).suffix.lower() == ".png":
        return ".png"
    return ".tif"


def positive_int(text):
    """argparse type: an integer >= 1."""
    return _number(text, int, 1, "a positive integer")


def non_negative_int(text):
    """argparse type: an integer >= 0."""
    return _number(text, int, 0, "an integer >= 0")


def non_negative_float(text):
    """argparse type: a finite number >= 0."""
    return _number(text, float, 0.0, "a finite number >= 0")


def _number(text, kind, lowest, what):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}; got {text!r}") from None
    if not np.isfinite(value) or value < lowest:
        raise argparse.ArgumentTypeError(f"must be {what}; got {text!r}")
    return value


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


def channel_axis(image, *, stack=False):
    """-1 for colour (a trailing channel axis), None for grey."""
    if not stack:
        return -1 if is_colour(image) else None
    return -1 if image.ndim == 4 else None


def order_type(text):
    """argparse type for --order: 'auto' or a positive integer (the core's
    ``neighbourhood`` argument)."""
    if text == "auto":
        return text
    try:
        order = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"order must be 'auto' or a positive integer; got {text!r}") from None
    if order < 1:
        raise argparse.ArgumentTypeError(f"order must be 'auto' or a positive integer; got {order}")
    return order


def add_order(parser, help="neighbourhood order, or 'auto' for the decision rule (default)"):
    """The --order option."""
    parser.add_argument("--order", default="auto", type=order_type, help=help)


def add_inputs(parser, help):
    """The inputs (files, folders, globs) and -o folder of a batch command."""
    parser.add_argument("inputs", nargs="+", help=help)
    add_output(parser, "output folder; or, for a single input, the output file")


def add_output(parser, help):
    """The required -o/--output option."""
    parser.add_argument("-o", "--output", required=True, help=help)


def add_quiet(parser):
    """The --quiet option: nothing but errors (:func:`quiet_mode`)."""
    parser.add_argument("--quiet", action="store_true",
                        help="print nothing but errors (no progress, notes or per-image lines)")


#: The files a label image is written to (lossless, 8 or 16-bit).
LABEL_SUFFIXES = frozenset({".png", ".tif", ".tiff"})


def write_labels(path, labels):
    """A label image as an 8-bit PNG (16-bit beyond 255 labels)."""
    write_image(path, labels.astype(np.uint8 if labels.max() < 256 else np.uint16))


def print_note(text):
    """A one-line note on stderr (``read_image``'s ``on_note``), above any
    bar; none with ``--quiet``."""
    say(f"note: {text}")
