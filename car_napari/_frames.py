"""Clips longer than memory, by blocks of frames (Qt-free).

A long clip (a dask- or zarr-backed napari layer, a folder of 100,000
numbered frames) is processed a block of frames at a time: the block is read
with the context frames its job needs (``before`` and ``after`` frames of the
source, the ``carry`` last output frames before it), the core ``iter_<name>``
job runs on it in memory, and the block's output is written (into a zarr
store, a memory map, an array or a file writer) before the next block is
read. Memory is then that of one block, whatever the clip's length (but
for a dask source's own task graph and the scheduler's pass over it at each
read, about a kilobyte a frame of the clip: :func:`auto_block` reads
several small frames at a time); the
output equals that of the in-memory call on the whole clip, because each
block sees exactly the context the whole-clip call gives its frames.

:func:`iter_frame_blocks` is the driver; the applications built on it,
which the widgets and the command line share, live with their subpackages:
:func:`~car_napari.restoration.iter_restore_frames`,
:func:`~car_napari.inpainting.iter_inpaint_frames` and
:func:`~car_napari.inpainting.iter_descratch_frames`. Every one is a job (a
generator of :class:`~car_napari._progress.Progress` records returning its
output) with records from the core jobs in between, so that closing it (a
Cancel) stops it within the core's next record. After each block written a
record carries ``preview=(start, stop)``, the frames now in the output.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ._progress import Progress, mapped, row_blocks, stage
from ._tiles import read_array
from ._validation import check_real

__all__ = ["FrameBlock", "auto_block", "check_clip", "iter_frame_blocks",
           "lazy_output"]

DEFAULT_BLOCK = 8  # frames a block of the scratch jobs (a few MB on a 512x512 clip)
# s between two records handed on from a block's job: a Cancel waits at most this
# (plus the core's own record interval), a GUI gets a signal per record
RECORD_INTERVAL = 0.05
READ_BUDGET = 1 << 24  # bytes of source a block of the frame-by-frame restoration reads


@dataclass(frozen=True)
class FrameBlock:
    """One block of a clip, in memory, with its context.

    Attributes
    ----------
    start, stop : int
        The block's frames ``[start, stop)`` of the clip.
    frames : ndarray
        The source's frames ``[start - lead, stop + trail)``.
    lead, trail : int
        The context frames of the source before and after the block in
        ``frames``.
    previous : ndarray or None
        The last output frames before ``start`` (up to ``carry``), None for
        the first block (or without ``carry``).
    total : int
        The clip's number of frames.

    Examples
    --------
    >>> block = FrameBlock(2, 4, np.zeros((3, 2, 2)), 1, 0, None, 4)
    >>> block.own.shape
    (2, 2, 2)
    """

    start: int
    stop: int
    frames: np.ndarray
    lead: int
    trail: int
    previous: np.ndarray | None
    total: int

    @property
    def own(self):
        """The block's own frames of the source (without the context).

        Returns
        -------
        ndarray
            ``frames[lead : len(frames) - trail]``.
        """
        return self.frames[self.lead:len(self.frames) - self.trail]


def _check_count(value, name, low):
    return check_real(value, name, low=low, integer=True)


def _writer(out):
    """``out`` as ``write(start, values)``: a callable as it is, an array
    (NumPy, zarr, a memory map) by slice assignment."""
    if out is None:
        return None
    if callable(out):
        return out

    def write(start, values):
        out[start:start + len(values)] = values

    return write


def iter_frame_blocks(source, job, out, *, block=1, before=0, after=0, carry=0,
                      stage_name="frames"):
    """Run a job on each block of frames of a clip, writing each block's output.

    The clip is read one block at a time (with its context): the memory
    used is that of one block, whatever the clip's length.

    Parameters
    ----------
    source : array_like
        The clip, frames along the first axis: a NumPy, dask or zarr array
        (anything sliceable that ``np.asarray`` reads); it is only read.
    job : callable
        ``job(block)`` with a :class:`FrameBlock`: a generator of
        :class:`~car_napari._progress.Progress` records (fractions of the
        block's work) returning the block's output, an array of
        ``stop - start`` frames, or a tuple of such arrays (one for each
        of ``out``).
    out : array_like, callable, tuple of them, or None
        Where the outputs go: an array written by slice
        (``out[start:stop] = output``), or ``write(start, output)``; a tuple
        of those for a job returning a tuple; None: nothing is written.
    block : int, optional
        Frames a block.
    before, after : int, optional
        Context frames of the source read before and after each block (fewer
        at the ends of the clip).
    carry : int, optional
        Output frames of the blocks before handed to the next block as
        :attr:`FrameBlock.previous` (the first output when a tuple).
    stage_name : str, optional
        The records' stage.

    Yields
    ------
    Progress
        The job's records (at most every :data:`RECORD_INTERVAL` seconds,
        their previews dropped), fractions of the whole
        clip, messages prefixed ``"frames a-b/T: "``; after each block is
        written, a record with ``preview=(start, stop)``.

    Returns
    -------
    int
        The number of frames written.

    Raises
    ------
    ValueError
        If the clip is empty or an option is out of range.

    Examples
    --------
    >>> from car_napari._progress import Progress, drain
    >>> clip = np.arange(5 * 2 * 2, dtype=float).reshape(5, 2, 2)
    >>> out = np.zeros_like(clip)
    >>> def double(block):
    ...     yield Progress("work", 1.0)
    ...     return 2 * block.own
    >>> drain(iter_frame_blocks(clip, double, out, block=2))
    5
    >>> bool(np.array_equal(out, 2 * clip))
    True
    """
    block = _check_count(block, "block", 1)
    before = _check_count(before, "before", 0)
    after = _check_count(after, "after", 0)
    carry = _check_count(carry, "carry", 0)
    shape = tuple(getattr(source, "shape", ()))
    if not shape or shape[0] == 0:
        raise ValueError(f"the clip must have frames along its first axis; got shape {shape}.")
    n = shape[0]
    outs = out if isinstance(out, tuple) else (out,)
    writers = [_writer(o) for o in outs]
    previous = None
    blocks = row_blocks(n, block)
    for a, b in blocks:
        lo, hi = max(a - before, 0), min(b + after, n)
        frames = read_array(source[lo:hi])
        here = FrameBlock(a, b, frames, a - lo, hi - b, previous, n)
        where = f"frames {a + 1}-{b}/{n}"
        result = yield from _thinned(stage(job(here), a / n, b / n, name=stage_name,
                                               prefix=f"{where}: "))
        results = result if isinstance(result, tuple) else (result,)
        if len(results) != len(writers):
            raise ValueError(f"the job returned {len(results)} outputs for {len(writers)} "
                             "targets.")
        for write, values in zip(writers, results, strict=True):
            if write is not None:
                write(a, values)
        if carry:
            keep = np.asarray(results[0])[-carry:]
            previous = keep if previous is None else np.concatenate([previous, keep])[-carry:]
        yield Progress(stage_name, b / n, where, (a, b))
    return n


def _thinned(job):
    """``job``'s records at most every :data:`RECORD_INTERVAL` seconds (the
    others dropped: a frame's many chunk records cost a GUI a signal each),
    without their previews (a block's frames are shown from the output once
    written), and its result."""
    last = -math.inf

    def thinned(record):
        nonlocal last
        now = time.monotonic()
        if now - last >= RECORD_INTERVAL:
            last = now
            return record if record.preview is None else replace(record, preview=None)
        return None

    return (yield from mapped(job, thinned))


def auto_block(clip, *, budget=READ_BUDGET, most=16):
    """Frames a block so that one block of ``clip`` is read in about
    ``budget`` bytes (1 to ``most``): fewer reads of a lazy clip (each costs
    its scheduler a pass over the clip's task graph) without holding much.

    Parameters
    ----------
    clip : array_like
        The clip (its shape and dtype are used).
    budget : int, optional
        Bytes of source a block.
    most : int, optional
        The largest block.

    Returns
    -------
    int
        Frames a block.

    Examples
    --------
    >>> auto_block(np.zeros((100, 4000, 4000, 3), np.uint8)), auto_block(np.zeros((9, 64, 64)))
    (1, 9)
    """
    shape = tuple(clip.shape)
    frame_bytes = int(np.prod(shape[1:], dtype=np.int64)) * np.dtype(clip.dtype).itemsize
    return int(max(1, min(most, shape[0], budget // max(frame_bytes, 1))))


def check_clip(clip, channel_axis):
    """Check that ``clip`` is ``(T, H, W)`` grey (``channel_axis=None``) or
    ``(T, H, W, C)`` colour (``channel_axis=-1``); its number of dimensions."""
    if channel_axis not in (None, -1):
        raise ValueError(f"channel_axis must be None (a grey clip) or -1 (a colour clip); "
                         f"got {channel_axis!r}.")
    ndim = len(getattr(clip, "shape", ()))
    want = 3 if channel_axis is None else 4
    if ndim != want:
        what = "(T, H, W) grey clip" if channel_axis is None else "(T, H, W, C) colour clip"
        raise ValueError(f"clip must be a {what} for channel_axis={channel_axis}; got shape "
                         f"{tuple(getattr(clip, 'shape', ()))}.")
    return ndim


def lazy_output(shape, dtype, *, chunk_frames=1, folder=None, name="output"):
    """A zarr array on disk for a lazy output (frames along the first axis).

    Parameters
    ----------
    shape : tuple of int
        The output's shape.
    dtype : dtype
        Its dtype.
    chunk_frames : int, optional
        Frames a chunk (a chunk is whole frames).
    folder : str or Path, optional
        Where the store goes (``<folder>/<name>.zarr``); default a new
        temporary folder.
    name : str, optional
        The store's name.

    Returns
    -------
    zarr.Array
        The array, unwritten (reads give zeros until written).

    Raises
    ------
    ValueError
        When zarr is not installed (it says what to install).

    Examples
    --------
    >>> out = lazy_output((3, 4, 4), np.float32)
    >>> out.shape, str(out.dtype)
    ((3, 4, 4), 'float32')
    """
    try:
        import zarr
    except ImportError:
        raise ValueError("a lazy output needs zarr: pip install 'car-napari[cluster]'.") from None
    folder = Path(tempfile.mkdtemp(prefix="car-napari-")) if folder is None else Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    chunks = (int(chunk_frames), *shape[1:])
    return zarr.open_array(str(folder / f"{name}.zarr"), mode="w", shape=tuple(shape),
                           chunks=chunks, dtype=np.dtype(dtype), fill_value=0)
