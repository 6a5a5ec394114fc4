"""Every dock widget in a real napari viewer on a large image: how long the
viewer freezes, how fast Cancel stops the job, how much memory it takes.
Run by hand (not under ``nice``: it measures pauses):

    xvfb-run -a -s "-screen 0 1280x1024x24" .venv/bin/python benchmarks/bench_gui.py \
        [--size 4000] [--only NAME[,NAME]] [--cancel-after 3[,20]] [--complete]
        [--merge-regions NATS] [--stacks]

Each widget runs in a fresh Python process with its own ``napari.Viewer(show=True)``
and the widget docked, so that its memory peak is its own. In that process:

1. warm-up: the same widget, through the same entry point, on a small crop of
   the same data, run to its end (the Numba kernels loaded from the on-disk
   cache, so that what follows is what a user sees from the second run on);
   then the viewer is emptied;
2. the large input is opened as layers (uint8, as read from a file) and the
   viewer is left to draw it;
3. an event-loop monitor starts: a ``QTimer`` firing every 5 ms records the
   ``perf_counter`` gaps between its firings; a pause is a gap minus the 5 ms
   period. It also samples the process's resident memory (psutil) at every
   firing;
4. the job starts through the widget's own entry point (the method its button
   calls: ``start``, ``start_fit`` or ``detect``), as a click would, inside the
   event loop;
5. after ``--cancel-after`` seconds (a comma-separated list: one fresh run for
   each, to probe later stages of a job; ``shown``: at the first event-loop
   turn after the result has started to be shown, layer by layer) the
   Cancel button is clicked; the cancel
   latency is the time from the click to the worker's ``finished`` signal
   (``Job.done``); "Run back" is the time until the widget's action button is
   enabled again; "viewer as before" compares the layer list with the one
   before the run.

With ``--complete`` the job runs to its end instead (default size 1024) and
the table gives its seconds; the segmentation's "show K" / "min probability"
sliders, the restoration's kappa slider and the mammogram's "marks per image"
are then moved a few times (0.3 s apart) and the longest pause of those
re-cuts is reported. The segmentation's sliders are then dragged as a hand
does: "show K" through every value of the history and back, then "min
probability" 0.05 to 0.5 and back to 0, one value every 40 ms (``DRAG_MS``);
"drag" reports the longest pause of the drag, the longest single layer
assignment in it ("of which napari": ``RunRecord.put``, the viewer's own
cost of new layer data), the seconds from the last move until the re-cuts
have settled (its own work included), and whether the layer then shows
``result.labels_at`` at the sliders' last values. A ``PYTHONPATH`` given
comes first in the children's path: ``PYTHONPATH=../main`` measures that
checkout's car_napari with this script (a baseline).

Columns: longest pause, the main thread's CPU time within it ("its CPU": about
what the pause would be on an idle machine; the wall-clock pause grows with
the load of other processes, "load" is the 1-minute load average at the end)
and 99th percentile of the pauses (ms) over the whole
measured window (start, run, cancel, until the worker has gone); "in" says
where the longest pause fell: "start" (the entry point's own work on the main
thread, before the worker runs), "run", "cancel" (after the click) or
"result" (showing it); "ours" (ms): the longest pause left for the
brief's 100 ms bound, which puts napari's own cost of adding or removing a
layer outside it: the pause less the time napari spent adding or removing
layers in it and painting after that (:class:`NapariTimer`), with "(of P:
layer L, paint Q)" when something was taken off; cancel
latency (s); peak memory (GB): the largest resident memory of the process
during the window (sampled, or the kernel's high-water mark ``ru_maxrss``
when the run raised it) minus the resident memory just before the start; B/px
is that peak per input pixel (rows x columns x versions; a colour pixel
counts once).

Inputs, made once from real data and cached in ``--cache`` (``.npy``):

* RGB ``size x size``: a mosaic of four VisTex textures
  (``../shared/data/textures/vistex``, 640x640, mirror-tiled to the size, in
  four wavy quadrants): CAR model fit, texture segmentation, texture synthesis
  fit, texture retrieval (the query; the gallery: three other VisTex textures
  tiled to the same size, as open layers);
* the same mosaic with Gaussian noise (sigma 12 grey levels): restoration of
  one image; four versions blurred by 0.5, 1, 1.5, 2 px with independent
  noise, ``(4, size, size, 3)``: restoration of a burst;
* grey ``4096x4096`` (``1024 * round(size / 1000)``): the shipped mini-MIAS
  mammogram mdb001 upsampled (bilinear): Mammogram ROI;
* Texture synthesis / CAR model "Synthesize": a model fitted (beforehand, not
  measured) on the mosaic's top-left 256x256 corner (CAR: max order 2), then
  a ``size x size`` sample synthesised through the Synthesize button's method
  (``start_synthesis``); B/px per output pixel;
* the real damaged film scan ``film-damage/cinestill50d_half_1/damaged.jpg``
  resized to ``size x size`` with its real damage mask (``mask.png``,
  nearest-neighbour): scratch detection, and restoration with that mask as a
  Labels layer.

Before the table, one more fresh process measures napari's own floor with
no plugin docked: the longest pause when a layer is added over the input
(one like a large image's preview, 1000x1000 RGB float32 at scale 4; a
16x16 image, to show that the cost is not the data's; a Labels layer of the
input's size), and when it is removed (napari 0.9 runs a full
``gc.collect()`` on every removal). Any
widget that shows a result in a new layer, or undoes one on Cancel, meets
these pauses; they are printed below the table.

With ``--stacks`` a background thread samples the main thread's Python stack
every 2 ms while the viewer is paused, and each row's longest pause is
printed below the table with the stacks seen in it (where the time went).

A child that exceeds ``--mem-limit`` GB is killed (the row says so); one whose
worker is still running ``--cancel-timeout`` s after the click reports
``> timeout``.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
VISTEX = DATA / "textures" / "vistex"
MOSAIC_TEXTURES = ("VS50.png", "VS1.png", "VS120.png", "VS87.png")
GALLERY_TEXTURES = ("VS5.png", "VS18.png", "VS63.png")
FILM = DATA / "film-damage" / "cinestill50d_half_1"
MAMMOGRAM = ROOT / "resources" / "mammogram_mdb001.png"
PERIOD_MS = 5


# --- inputs ---------------------------------------------------------------------------

def _mirror_tile(texture, shape):
    """``texture`` repeated by reflection (no seams) and cropped to ``shape``."""
    block = np.concatenate([texture, texture[::-1]], axis=0)
    block = np.concatenate([block, block[:, ::-1]], axis=1)
    reps = (-(-shape[0] // block.shape[0]), -(-shape[1] // block.shape[1]))
    reps += (1,) * (block.ndim - 2)
    return np.tile(block, reps)[: shape[0], : shape[1]]


def _read_rgb(path):
    from skimage import io

    image = io.imread(path)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return np.ascontiguousarray(image[..., :3])


def _mosaic(size):
    """Four mirror-tiled VisTex textures in four quadrants with wavy borders."""
    rows = np.arange(size)
    wave_r = (size / 2 + size / 16 * np.sin(2 * np.pi * 3 * rows / size)).astype(int)
    wave_c = (size / 2 + size / 16 * np.sin(2 * np.pi * 2 * rows / size + 1.0)).astype(int)
    bottom = rows[:, None] >= wave_r[None, :]  # row below the wavy horizontal border
    right = rows[None, :] >= wave_c[:, None]  # column right of the wavy vertical border
    quadrant = 2 * bottom + right
    out = np.empty((size, size, 3), np.uint8)
    for k, name in enumerate(MOSAIC_TEXTURES):
        tiled = _mirror_tile(_read_rgb(VISTEX / name), (size, size))
        out[quadrant == k] = tiled[quadrant == k]
    return out


def _noisy(image, sigma, seed, blur=0.0):
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    out = image.astype(np.float32)
    if blur:
        out = ndimage.gaussian_filter(out, (blur, blur, 0))
    out += rng.normal(0.0, sigma, out.shape).astype(np.float32)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def make_inputs(size, cache):
    """Write the benchmark's inputs for ``size`` into ``cache`` (once); return the folder."""
    from skimage import io
    from skimage.transform import resize

    folder = Path(cache) / f"size{size}"
    folder.mkdir(parents=True, exist_ok=True)
    msize = 1024 * max(1, round(size / 1000))

    def cached(name, make):
        path = folder / f"{name}.npy"
        if not path.exists():
            t0 = time.perf_counter()
            array = make()
            np.save(path.with_suffix(".tmp.npy"), array)
            path.with_suffix(".tmp.npy").rename(path)
            print(f"  made {name} {array.shape} {array.dtype} in "
                  f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)

    cached("mosaic", lambda: _mosaic(size))
    mosaic = np.load(folder / "mosaic.npy")
    cached("noisy", lambda: _noisy(mosaic, 12.0, 0))
    cached("burst", lambda: np.stack([_noisy(mosaic, 12.0, 1 + k, blur=b)
                                      for k, b in enumerate((1.5, 0.5, 2.0, 1.0))]))
    for k, name in enumerate(GALLERY_TEXTURES):
        cached(f"gallery{k}", lambda name=name: _mirror_tile(_read_rgb(VISTEX / name),
                                                             (size, size)))

    def mammogram():
        image = io.imread(MAMMOGRAM)
        up = resize(image.astype(np.float32), (msize, msize), order=1, preserve_range=True,
                    anti_aliasing=False)
        return np.clip(np.round(up), 0, 255).astype(np.uint8)

    cached("mammogram", mammogram)

    def film():
        frame = _read_rgb(FILM / "damaged.jpg")
        up = resize(frame, (size, size), order=1, preserve_range=True, anti_aliasing=False)
        return np.clip(np.round(up), 0, 255).astype(np.uint8)

    def film_mask():
        mask = io.imread(FILM / "mask.png")
        mask = mask[..., :3].max(axis=2) if mask.ndim == 3 else mask
        rows = (np.arange(size) * mask.shape[0]) // size
        cols = (np.arange(size) * mask.shape[1]) // size
        return (mask[rows][:, cols] > 127).astype(np.uint8)

    cached("film", film)
    cached("film_mask", film_mask)
    return folder


# --- the event-loop monitor -------------------------------------------------------------

class EventLoopMonitor:
    """Gaps between the firings of a 5 ms ``QTimer`` on the main thread, and
    the process's resident memory sampled at each firing."""

    def __init__(self, period_ms=PERIOD_MS):
        import psutil
        from qtpy.QtCore import Qt, QTimer

        self.period = period_ms / 1000.0
        self._process = psutil.Process()
        self._timer = QTimer()
        self._timer.setTimerType(Qt.PreciseTimer)
        self._timer.setInterval(period_ms)
        self._timer.timeout.connect(self._tick)
        self.gaps = []
        self.times = []  # perf_counter at the end of each gap
        self.cpu = []  # the main thread's CPU time in each gap (s)
        self.peak_rss = 0
        self._last = None
        self._last_cpu = None

    def start(self):
        self.gaps = []
        self.times = []
        self.cpu = []
        self.peak_rss = self._process.memory_info().rss
        self._last = time.perf_counter()
        self._last_cpu = time.thread_time()
        self._timer.start()

    def _tick(self):
        now, cpu = time.perf_counter(), time.thread_time()
        self.gaps.append(now - self._last)
        self.times.append(now)
        self.cpu.append(cpu - self._last_cpu)
        self._last, self._last_cpu = now, cpu
        rss = self._process.memory_info().rss
        if rss > self.peak_rss:
            self.peak_rss = rss

    def stop(self):
        self._timer.stop()
        self._tick()  # the gap up to now counts as well

    def pauses_ms(self):
        gaps = np.asarray(self.gaps, dtype=float)
        return np.maximum(gaps - self.period, 0.0) * 1000.0

    def longest_ms(self):
        pauses = self.pauses_ms()
        return float(pauses.max()) if pauses.size else 0.0

    def p99_ms(self):
        pauses = self.pauses_ms()
        return float(np.percentile(pauses, 99)) if pauses.size else 0.0

    def longest_cpu_ms(self):
        """The main thread's CPU time in the longest pause (ms): the pause on
        an idle machine, near enough, when other processes share the cores."""
        if not self.gaps:
            return 0.0
        return 1000.0 * self.cpu[int(np.argmax(self.gaps))]

    def longest_at(self):
        """(start, end) perf_counter times of the longest pause."""
        if not self.gaps:
            return None
        i = int(np.argmax(self.gaps))
        return self.times[i] - self.gaps[i], self.times[i]


class NapariTimer:
    """When napari itself adds or removes a layer, and when the canvas paints:
    napari's and vispy's own methods wrapped, in this process, before the
    viewer is made. An add is ``ViewerModel.add_<kind>`` (the layer's
    constructor included) or ``LayerList.insert``; a remove is the layer
    list's ``__delitem__`` (``remove``, ``pop`` and ``clear`` go through it);
    a paint is vispy's ``SceneCanvas.on_draw`` and napari's
    ``VispyCanvas.on_draw``. Nested calls count once, as the outermost.

    The brief puts napari's own cost of adding or removing a layer outside
    the 100 ms bound. :meth:`ours_ms` is what is left of each event-loop
    pause for the bound. A pause in which no layer was added or removed
    counts whole, its paints included (a layer's new data is ours to send),
    but for the first paint after a layer was added or removed (the new
    layer's first paint, its texture upload, when it falls in a later
    pause). A pause in which a layer was added or removed counts less the
    time in those adds and removes and in the paints of the same pause.
    """

    ADDS = ("add_layer", "add_image", "add_labels", "add_shapes", "add_points",
            "add_surface", "add_tracks", "add_vectors")

    def __init__(self):
        from napari._vispy.canvas import VispyCanvas
        from napari.components import LayerList, ViewerModel
        from vispy.scene import SceneCanvas

        self.intervals = []  # (start, end, kind): kind "layer" or "paint"
        self._depth = 0
        targets = [(ViewerModel, name, "layer") for name in self.ADDS
                   if hasattr(ViewerModel, name)]
        targets += [(LayerList, "insert", "layer"), (LayerList, "__delitem__", "layer"),
                    (SceneCanvas, "on_draw", "paint"), (VispyCanvas, "on_draw", "paint")]
        for owner, name, kind in targets:
            setattr(owner, name, self._timed(getattr(owner, name), kind))

    def _timed(self, method, kind):
        import functools

        @functools.wraps(method)
        def timed(*args, **kwargs):
            if self._depth:
                return method(*args, **kwargs)
            self._depth += 1
            start = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self._depth -= 1
                self.intervals.append((start, time.perf_counter(), kind))

        return timed

    def _within(self, a, b):
        """Seconds of layer adds/removes, of paints, and of first paints after
        a layer change, inside [a, b]."""
        spent = {"layer": 0.0, "paint": 0.0, "first paint": 0.0}
        changed = False  # a layer added or removed since the last paint
        for start, end, kind in sorted(self.intervals):
            overlap = max(min(end, b) - max(start, a), 0.0)
            spent[kind] += overlap
            if kind == "paint" and changed:
                spent["first paint"] += overlap
            changed = kind == "layer" or (changed and kind != "paint")
        return spent

    def ours_ms(self, monitor):
        """``(ours, pause, layer, paint)`` in ms, for the pause that leaves the
        most to ours: its share left for the bound (see the class), the whole
        pause, and napari's layer time and the paint time taken off it; and
        that pause's index in ``monitor.gaps`` (None: no pause)."""
        gaps = np.asarray(monitor.gaps, dtype=float)
        ends = np.asarray(monitor.times, dtype=float)
        if not gaps.size:
            return (0.0, 0.0, 0.0, 0.0), None
        ours = np.maximum(gaps - monitor.period, 0.0)
        layer, paint = np.zeros_like(ours), np.zeros_like(ours)
        starts = ends - gaps
        for i in np.flatnonzero(ours > 0.05):  # a pause over 50 ms: the others count whole
            spent = self._within(starts[i], ends[i])
            layer[i] = spent["layer"]
            paint[i] = spent["paint"] if layer[i] > 0 else spent["first paint"]
            ours[i] = max(ours[i] - layer[i] - paint[i], 0.0)
        i = int(np.argmax(ours))
        pause = max(gaps[i] - monitor.period, 0.0)
        return tuple(round(1000 * v, 1) for v in (ours[i], pause, layer[i], paint[i])), i


class StackSampler:
    """What the main thread was doing in a pause: a background thread looks at
    the main thread's Python stack every ``period`` s and keeps the samples
    taken while the event-loop monitor has not ticked for ``stale`` s (inside
    a pause). A sample is the innermost frames, innermost last. The sampler
    needs the GIL, so a long C call that holds it shows as the frame that
    made it."""

    def __init__(self, monitor, period=0.002, stale=0.02, depth=14):
        import threading

        self.monitor, self.period, self.stale, self.depth = monitor, period, stale, depth
        self.samples = []  # (perf_counter, frames)
        self._main = threading.main_thread().ident
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self):
        self._thread.start()

    def stop(self):
        self._stop.set()
        self._thread.join(1.0)

    def _run(self):
        import traceback

        while not self._stop.wait(self.period):
            last = self.monitor._last
            now = time.perf_counter()
            if last is None or now - last < self.stale:
                continue
            frame = sys._current_frames().get(self._main)
            if frame is None:
                continue
            stack = traceback.extract_stack(frame, limit=self.depth)
            self.samples.append((now, [f"{Path(f.filename).name}:{f.lineno} {f.name}"
                                       for f in stack]))

    def summary(self, start, end, top=6):
        """The most frequent stacks sampled between ``start`` and ``end``, as text
        lines: the count and the frames, outermost first."""
        from collections import Counter

        counts = Counter(" > ".join(frames) for t, frames in self.samples
                         if start <= t <= end)
        return [f"{n} x {stack}" for stack, n in counts.most_common(top)]


def run_until(condition, timeout):
    """Run the Qt event loop until ``condition()`` or ``timeout`` seconds; returns
    ``condition()``."""
    from qtpy.QtCore import QEventLoop, QTimer

    deadline = time.perf_counter() + timeout
    loop = QEventLoop()
    check = QTimer()
    check.setInterval(5)
    check.timeout.connect(
        lambda: loop.quit() if condition() or time.perf_counter() > deadline else None)
    check.start()
    if not (condition() or time.perf_counter() > deadline):
        loop.exec_() if hasattr(loop, "exec_") else loop.exec()
    check.stop()
    return bool(condition())


def settle(quiet=1.0, timeout=30.0):
    """Let the viewer draw: until ``quiet`` s pass without a pause over 50 ms."""
    monitor = EventLoopMonitor()
    monitor.start()
    t0 = time.perf_counter()
    state = {"since": t0}

    def calm():
        now = time.perf_counter()
        if monitor.gaps and monitor.gaps[-1] > 0.05:
            state["since"] = now
        return now - state["since"] >= quiet

    run_until(calm, timeout)
    monitor.stop()


# --- the widgets --------------------------------------------------------------------------

@dataclass
class Case:
    key: str
    title: str
    module: str
    cls: str
    button: str  # the action button whose enabled state says "idle"


CASES = [
    Case("car", "CAR model fit", "car_model", "CARModelWidget", "_fit"),
    Case("segmentation", "Texture segmentation", "segmentation", "SegmentationWidget", "_run"),
    Case("mammogram", "Mammogram ROI", "mammography", "MammogramWidget", "_run"),
    Case("restoration", "Restoration (single image)", "restoration", "RestorationWidget",
         "_run"),
    Case("burst", "Restoration (burst)", "restoration", "RestorationWidget", "_run"),
    Case("detect", "Scratch restoration: Detect", "inpainting", "InpaintingWidget", "_detect"),
    Case("restore", "Scratch restoration: Restore", "inpainting", "InpaintingWidget", "_run"),
    Case("texture", "Texture synthesis fit", "texture", "TextureSynthesisWidget", "_fit"),
    Case("retrieval", "Texture retrieval", "retrieval", "TextureRetrievalWidget", "_run"),
    Case("synthesis", "Texture synthesis: Synthesize", "texture", "TextureSynthesisWidget",
         "_synth"),
    Case("car-synthesis", "CAR model: Synthesize", "car_model", "CARModelWidget", "_synth"),
]
SYNTHESIS_CROP = 256  # the synthesis cases fit their model on this corner of the mosaic


def _crop(array, n, stack=False):
    return array[:, :n, :n] if stack else array[:n, :n]


def _choose_mask(widget, layer):
    """Point a mask picker of the widget (if it has one) at ``layer``."""
    for child in widget:
        label = str(getattr(child, "label", "")).lower()
        choices = getattr(child, "choices", None)
        if "mask" in label and choices is not None and layer in choices:
            child.value = layer
            return


MERGE_REGIONS = [0.0]  # the segmentation widget's box (--merge-regions)


def setup(case, viewer, widget, inputs, small=None):
    """Open the case's layers and set the widget's controls; returns
    ``(entry point, input pixels)``. ``small`` crops every input to that size."""
    def load(name, stack=False):
        array = np.load(inputs / f"{name}.npy")
        return np.ascontiguousarray(_crop(array, small, stack)) if small else array

    w = widget
    key = case.key
    if key in ("synthesis", "car-synthesis"):
        return _fitted_synthesis(case, viewer, w, load("mosaic"), small)
    if key in ("car", "segmentation", "texture", "retrieval"):
        image = load("mosaic")
        layer = viewer.add_image(image, name="mosaic", rgb=True)
        w._image.value = layer
        pixels = image.shape[0] * image.shape[1]
        if key == "car":
            return w.start_fit, pixels
        if key == "texture":
            w._mode.value = w._mode.choices[0]  # a single texture
            return w.start_fit, pixels
        if key == "segmentation":
            w._merge_regions.value = MERGE_REGIONS[0]  # --merge-regions (0: off)
            return w.start, pixels
        for k in range(len(GALLERY_TEXTURES)):
            viewer.add_image(load(f"gallery{k}"), name=f"gallery {k}", rgb=True)
        w._image.value = layer
        return w.start, pixels * (1 + len(GALLERY_TEXTURES))
    if key == "mammogram":
        image = load("mammogram")
        if small:  # the whole breast, block-averaged, rather than a corner of it
            full = np.load(inputs / "mammogram.npy")
            step = max(1, full.shape[0] // small)
            n = (full.shape[0] // step) * step
            image = full[:n, :n].reshape(n // step, step, n // step, step).mean(axis=(1, 3))
            image = image.astype(np.uint8)
        w._image.value = viewer.add_image(image, name="mammogram")
        return w.start, image.size
    if key == "restoration":
        image = load("noisy")
        w._image.value = viewer.add_image(image, name="noisy", rgb=True)
        choices = list(w._axis.choices)
        single = next((c for c in choices if "single" in str(c)), None)
        if single is not None:
            w._axis.value = single
        return w.start, image.shape[0] * image.shape[1]
    if key == "burst":
        stack = load("burst", stack=True)
        w._image.value = viewer.add_image(stack, name="burst", rgb=True)
        if "axis 0" not in list(w._axis.choices) and hasattr(w, "_guess_axis"):
            w._guess_axis()  # the picker took the new layer without offering its axes
            setup.notes.append("burst: 'axis 0' offered only after re-picking the layer")
        if "axis 0" in list(w._axis.choices):
            w._axis.value = "axis 0"
        return w.start, stack.shape[0] * stack.shape[1] * stack.shape[2]
    frame = load("film")
    layer = viewer.add_image(frame, name="film", rgb=True)
    w._image.value = layer
    if key == "detect":
        return w.detect, frame.shape[0] * frame.shape[1]
    mask = viewer.add_labels(load("film_mask"), name="film scratch mask", opacity=0.6)
    _choose_mask(w, mask)
    w._image.value = layer
    return w.start, frame.shape[0] * frame.shape[1]


setup.notes = []


def _fitted_synthesis(case, viewer, w, mosaic, small):
    """Fit the widget's model on a corner of the mosaic (run to its end, not
    measured), set the synthesis size to the input's; returns Synthesize."""
    n = min(SYNTHESIS_CROP, mosaic.shape[0])
    layer = viewer.add_image(np.ascontiguousarray(mosaic[:n, :n]), name="mosaic corner",
                             rgb=True)
    w._image.value = layer
    if case.key == "synthesis":
        w._mode.value = w._mode.choices[0]  # a single texture
    else:
        w._max_order.value = 2
    job = w.start_fit()
    _wait_job(job, 600)
    if w.model is None:
        setup.notes.append(f"{case.key}: the fit gave no model ({w._status.value})")
    size = small or mosaic.shape[0]
    w._height.value = w._width.value = size
    w._seed.value = 1
    return w.start_synthesis, size * size


def recut(case, widget):
    """Move the re-cut sliders of a finished run; returns the moves made."""
    moves = []
    if case.key == "segmentation" and getattr(widget, "result", None) is not None:
        cut = widget._cut
        for value in (cut.min, cut.max, (cut.min + cut.max) // 2):
            moves.append(lambda value=value: setattr(cut, "value", value))
        for value in (0.3, 0.6, 0.0):
            moves.append(lambda value=value: setattr(widget._threshold, "value", value))
    if case.key in ("restoration", "burst") and getattr(widget, "result", None) is not None:
        for value in (0.2, 0.5, 0.8, 0.1):
            moves.append(lambda value=value: setattr(widget._kappa, "value", value))
    if case.key == "mammogram" and getattr(widget, "_found", None) is not None:
        for value in (0.25, 4.0, 12.0, 1.0):
            moves.append(lambda value=value: setattr(widget._marks, "value", value))
    return moves


DRAG_MS = 40  # a hand dragging a slider: one value every 40 ms


def drag(case, widget):
    """Moves of a quick drag of the segmentation's sliders (see the module's
    docstring); empty for the other widgets."""
    if case.key != "segmentation" or getattr(widget, "result", None) is None:
        return []
    cut, threshold = widget._cut, widget._threshold
    ks = list(range(cut.max, cut.min - 1, -1)) + [widget.result.n_segments]
    moves = [lambda k=k: setattr(cut, "value", k) for k in ks]
    return moves + [lambda t=t: setattr(threshold, "value", t)
                    for t in (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.3, 0.0)]


def _timed_puts(record, longest):
    """Wrap ``record.put`` to keep its longest call (ms) in ``longest[0]``."""
    put = record.put

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return put(*args, **kwargs)
        finally:
            longest[0] = max(longest[0], 1000 * (time.perf_counter() - t0))

    record.put = timed
    return put


def _wait_job(job, timeout):
    return run_until(lambda: job is None or job.done, timeout)


def child(args):
    """Run one case in this process; print its figures as a ``RESULT`` JSON line."""
    import importlib

    import napari
    import psutil

    case = next(c for c in CASES if c.key == args.child)
    inputs = Path(args.inputs)
    module = importlib.import_module(f"car_napari._widgets.{case.module}")
    napari_timer = NapariTimer()  # before the viewer: its canvas connects on_draw
    viewer = napari.Viewer(show=True)
    widget = getattr(module, case.cls)(viewer)
    viewer.window.add_dock_widget(widget, name=case.title)
    settle()
    out = {"key": case.key, "title": case.title}
    process = psutil.Process()

    if not args.no_warmup:
        t0 = time.perf_counter()
        entry, _ = setup(case, viewer, widget, inputs, small=args.warmup_size)
        if case.key == "restore":  # a crop of a sparse mask may be empty
            viewer.layers["film scratch mask"].data[:, args.warmup_size // 2] = 1
        job = entry()
        if not _wait_job(job, args.warmup_timeout):
            widget.cancel()
            _wait_job(job, args.cancel_timeout)
        out["warmup_s"] = round(time.perf_counter() - t0, 1)
        viewer.layers.clear()
        settle()

    entry, pixels = setup(case, viewer, widget, inputs)
    settle()
    gc.collect()
    before = [layer.name for layer in viewer.layers]
    baseline = process.memory_info().rss
    maxrss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    monitor = EventLoopMonitor()
    monitor.start()
    sampler = StackSampler(monitor) if args.stacks else None
    if sampler:
        sampler.start()
    run_until(lambda: False, 0.2)
    marks = {}
    holder = {}

    def begin():
        marks["start"] = time.perf_counter()
        holder["job"] = entry()
        job = holder["job"]
        if job is not None:
            job.worker.finished.connect(
                lambda: marks.setdefault("finished", time.perf_counter()))

    from qtpy.QtCore import QTimer

    QTimer.singleShot(0, begin)  # as a click: inside the event loop
    run_until(lambda: "start" in marks, 30)
    job = holder.get("job")
    button = getattr(widget, case.button)
    from napari.utils.notifications import notification_manager

    def last_message():
        records = notification_manager.records
        return str(records[-1].message) if records else ""

    if job is None:
        out["error"] = last_message() or "no job started"
    elif args.complete:
        done = _wait_job(job, args.timeout)
        end = marks.get("finished", time.perf_counter())
        out["seconds"] = round(end - marks["start"], 2) if done else None
        out["status"] = str(widget._status.value)
        if done:
            moves = recut(case, widget)
            if moves:
                run_until(lambda: False, 0.3)
                recuts = EventLoopMonitor()
                recuts.start()
                for move in moves:
                    QTimer.singleShot(0, move)
                    run_until(lambda: False, 0.3)
                recuts.stop()
                out["recut_longest_ms"] = round(recuts.longest_ms(), 1)
            moves = drag(case, widget)
            if moves:
                run_until(lambda: widget._recut_job is None, 120)
                run_until(lambda: False, 0.3)
                put_ms = [0.0]
                plain_put = _timed_puts(widget.record, put_ms)
                dragged = EventLoopMonitor()
                dragged.start()
                fired = []  # when each move ran (a blocked event loop delays them)

                def played(move):
                    start = time.perf_counter()
                    move()
                    fired.append(start)

                for i, move in enumerate(moves):
                    QTimer.singleShot(DRAG_MS * i, lambda move=move: played(move))
                run_until(lambda: len(fired) == len(moves), 120)
                run_until(lambda: widget._recut_job is None, 120)
                out["drag_settle_s"] = round(time.perf_counter() - fired[-1], 2)
                run_until(lambda: False, 0.3)
                dragged.stop()
                widget.record.put = plain_put
                out["drag_longest_ms"] = round(dragged.longest_ms(), 1)
                out["drag_put_longest_ms"] = round(put_ms[0], 1)
                expected = widget.result.labels_at(int(widget._cut.value),
                                                   threshold=float(widget._threshold.value))
                shown = np.asarray(widget._layer.data)
                out["drag_shows_last"] = bool(np.array_equal(shown, expected))
        else:
            widget.cancel()
            _wait_job(job, args.cancel_timeout)
    else:
        if args.cancel_after == SHOWN:  # at the first turn of showing the result
            run_until(lambda: job.done or job.showing, args.timeout)
            # a turn for the monitor: the click is its own event, as a user's is, not
            # part of the turn that showed the first layer
            run_until(lambda: False, 0.01)
        else:
            _wait_job(job, args.cancel_after)
        if job.done:
            out["finished_before_cancel_s"] = round(marks.get("finished", time.perf_counter())
                                                    - marks["start"], 2)
            out["status_after"] = str(widget._status.value)
            if "fail" in out["status_after"]:
                out["error"] = last_message()
        else:
            out["status_at_cancel"] = str(widget._status.value)
            out["progress_at_cancel"] = int(widget._progress.value)
            marks["click"] = time.perf_counter()
            widget._cancel.native.click()  # the Cancel button, as the user clicks it
            gone = _wait_job(job, args.cancel_timeout)
            if gone:
                end = marks.get("finished", time.perf_counter())
                out["cancel_s"] = round(end - marks["click"], 3)
                run_until(lambda: bool(button.enabled), 5)
                out["button_back_s"] = round(time.perf_counter() - marks["click"], 3) \
                    if button.enabled else None
            else:
                out["cancel_s"] = None  # still running after the timeout
            out["status_after"] = str(widget._status.value)
        # an undo taken one change per event-loop turn is measured to its end
        run_until(lambda: not getattr(widget.record, "undoing", False), 10)
        run_until(lambda: False, 0.2)
        out["viewer_as_before"] = [layer.name for layer in viewer.layers] == before
    monitor.stop()
    at = monitor.longest_at()
    if sampler:
        sampler.stop()
        if at is not None:
            out["stacks"] = sampler.summary(*at)
    if at is not None and "start" in marks:
        out["longest_from_s"] = round(at[0] - marks["start"], 2)
        if at[0] <= marks["start"] <= at[1]:
            out["longest_in"] = "start"  # the entry point's own work, on the main thread
        elif "click" in marks and at[1] >= marks["click"]:
            out["longest_in"] = "cancel"
        elif "finished" in marks and at[1] >= marks["finished"]:
            out["longest_in"] = "result"
        else:
            out["longest_in"] = "run"
    if setup.notes:
        out["notes"] = setup.notes
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    peak = max(monitor.peak_rss, maxrss if maxrss > maxrss_before else 0)
    (ours, pause, layer, paint), i = napari_timer.ours_ms(monitor)
    out.update(ours_ms=ours, ours_pause_ms=pause, ours_layer_ms=layer, ours_paint_ms=paint)
    if i is not None and "start" in marks:  # where that pause fell, and what ran in it
        end = monitor.times[i]
        out.update(ours_from_s=round(end - monitor.gaps[i] - marks["start"], 2),
                   ours_cpu_ms=round(1000 * monitor.cpu[i], 1))
        if sampler:
            out["ours_stacks"] = sampler.summary(end - monitor.gaps[i], end)
    if at is not None:  # what napari took of the longest pause
        spent = napari_timer._within(*at)
        out.update(longest_layer_ms=round(1000 * spent["layer"], 1),
                   longest_paint_ms=round(1000 * spent["paint"], 1))
    out.update(
        longest_ms=round(monitor.longest_ms(), 1), p99_ms=round(monitor.p99_ms(), 1),
        longest_cpu_ms=round(monitor.longest_cpu_ms(), 1),
        load=round(os.getloadavg()[0], 1),
        ticks=len(monitor.gaps), peak_gb=round((peak - baseline) / 1e9, 3),
        bytes_per_pixel=round((peak - baseline) / pixels, 1), pixels=int(pixels),
        baseline_gb=round(baseline / 1e9, 3),
    )
    print("RESULT " + json.dumps(out), flush=True)
    sys.stdout.flush()
    os._exit(0)  # a worker that would not stop dies with the process


def floor_child(args):
    """napari's own cost, no plugin docked: the longest event-loop pause when
    a layer is added over the large input, and when it is removed (napari
    runs a full ``gc.collect()`` on every removal). The layers: one like a
    preview (1000x1000 RGB float32 at scale 4), a 16x16 image (what adding
    costs whatever the size) and a Labels layer of the input's size (a
    mask, regions). Printed as ``RESULT`` JSON."""
    import napari
    from qtpy.QtCore import QTimer

    viewer = napari.Viewer(show=True)
    mosaic = np.load(Path(args.inputs) / "mosaic.npy")
    viewer.add_image(mosaic, name="mosaic", rgb=True)
    settle()
    out = {"key": "floor", "title": "napari itself: add / remove a layer"}
    rng = np.random.default_rng(0)
    preview = rng.random((1000, 1000, 3), np.float32)  # made before, not timed
    tiny = rng.random((16, 16), np.float32)
    labels = (rng.random(mosaic.shape[:2]) < 0.001).astype(np.uint8)
    layers = {
        "add_ms": lambda: viewer.add_image(preview, name="added", rgb=True, scale=(4, 4),
                                           contrast_limits=(0.0, 1.0)),
        "add_tiny_ms": lambda: viewer.add_image(tiny, name="added"),
        "add_labels_ms": lambda: viewer.add_labels(labels, name="added"),
    }
    remove = []
    for key, add in layers.items():
        pauses = out[key] = []
        removals = []
        for _ in range(4):
            for action, into in ((add, pauses), (lambda: viewer.layers.remove("added"), removals)):
                monitor = EventLoopMonitor()
                monitor.start()
                run_until(lambda: False, 0.1)
                QTimer.singleShot(0, action)
                run_until(lambda: False, 0.5)
                monitor.stop()
                into.append(round(monitor.longest_ms(), 1))
        del pauses[0], removals[0]  # the first add of a kind compiles its shaders
        remove += removals
    out["remove_ms"] = remove
    print("RESULT " + json.dumps(out), flush=True)
    os._exit(0)


# --- the parent --------------------------------------------------------------------------

SHOWN = "shown"  # --cancel-after: Cancel as soon as the result is being shown


def _delay(text):
    text = str(text).strip()
    return SHOWN if text == SHOWN else float(text)


def run_child(case, args, inputs, cancel_after):
    """Run one case in a fresh process, killed above the memory limit."""
    import psutil

    command = [sys.executable, __file__, "--child", case.key, "--inputs", str(inputs),
               "--cancel-after", str(cancel_after),
               "--cancel-timeout", str(args.cancel_timeout), "--timeout", str(args.timeout),
               "--warmup-size", str(args.warmup_size),
               "--warmup-timeout", str(args.warmup_timeout)]
    command += ["--complete"] * args.complete + ["--no-warmup"] * args.no_warmup
    command += ["--merge-regions", str(args.merge_regions)] + ["--stacks"] * args.stacks
    # a PYTHONPATH given first (another checkout's car_napari: a baseline)
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH", "") + os.pathsep + str(ROOT))
    with tempfile.TemporaryFile("w+") as stdout, tempfile.TemporaryFile("w+") as stderr:
        proc = subprocess.Popen(command, stdout=stdout, stderr=stderr, env=env, cwd=ROOT)
        ps = psutil.Process(proc.pid)
        limit = args.mem_limit * 1e9
        deadline = time.perf_counter() + args.warmup_timeout + args.timeout + 300
        killed = None
        while proc.poll() is None:
            try:
                rss = ps.memory_info().rss
            except psutil.NoSuchProcess:
                break
            if rss > limit:
                killed = f"killed above {args.mem_limit:g} GB"
            elif time.perf_counter() > deadline:
                killed = "killed: no result in time"
            if killed:
                proc.kill()
                break
            time.sleep(0.2)
        proc.wait()
        stdout.seek(0)
        stderr.seek(0)
        lines = [line for line in stdout.read().splitlines() if line.startswith("RESULT ")]
        if lines:
            return json.loads(lines[-1][len("RESULT "):])
        tail = stderr.read().strip().splitlines()[-8:]
        return {"key": case.key, "title": case.title,
                "error": killed or f"exit {proc.returncode}: " + " | ".join(tail)}


def _fmt(value, digits=1, none="-"):
    return none if value is None else f"{value:.{digits}f}"


def _ours(r):
    """The longest pause left for the 100 ms bound (:class:`NapariTimer`),
    with what napari's layer changes and paints took off it."""
    if "ours_ms" not in r:
        return "-"
    if not (r["ours_layer_ms"] or r["ours_paint_ms"]):
        return _fmt(r["ours_ms"])
    return (f"{r['ours_ms']:.1f} (of {r['ours_pause_ms']:.0f}: layer "
            f"{r['ours_layer_ms']:.0f}, paint {r['ours_paint_ms']:.0f})")


def table(results, args):
    if args.complete:
        lines = ["| widget | seconds | longest pause (ms) | in | its CPU (ms) | p99 (ms) "
                 "| ours (ms) | peak memory (GB) | B/px | re-cut longest pause (ms) "
                 "| drag: longest pause, of which napari (ms), settled (s), last shown "
                 "| load |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    else:
        lines = ["| widget | longest pause (ms) | in | its CPU (ms) | p99 (ms) | ours (ms) "
                 "| cancel latency (s) | Run back (s) | peak memory (GB) | B/px "
                 "| viewer as before | load |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        if "error" in r:
            cells = [r["title"], f"error: {r['error']}"]
            if "longest_ms" in r:
                cells.append(f"(longest pause {r['longest_ms']:.0f} ms)")
            lines.append("| " + " | ".join(cells) + " |")
            continue
        common = [_fmt(r["longest_ms"]), r.get("longest_in", "-"),
                  _fmt(r.get("longest_cpu_ms")), _fmt(r["p99_ms"]), _ours(r)]
        memory = [_fmt(r["peak_gb"], 2), _fmt(r["bytes_per_pixel"], 0)]
        if args.complete:
            seconds = _fmt(r.get("seconds"), 1, none=f"> {args.timeout:g}")
            dragged = "-" if "drag_longest_ms" not in r else (
                f"{r['drag_longest_ms']:.1f}, {r['drag_put_longest_ms']:.1f}, "
                f"{r['drag_settle_s']:.2f}, {'yes' if r['drag_shows_last'] else 'NO'}")
            cells = [r["title"], seconds, *common, *memory, _fmt(r.get("recut_longest_ms")),
                     dragged, _fmt(r.get("load"))]
        else:
            if "finished_before_cancel_s" in r:
                cancel = f"finished in {r['finished_before_cancel_s']:.2f} s"
                back = before = "-"
            else:
                cancel = _fmt(r.get("cancel_s"), 2, none=f"> {args.cancel_timeout:g}")
                back = _fmt(r.get("button_back_s"), 2, none="no")
                before = "yes" if r.get("viewer_as_before") else "NO"
            cells = [r["title"], *common, cancel, back, *memory, before, _fmt(r.get("load"))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=None,
                        help="height and width of the inputs (default 4000; 1024 with "
                             "--complete)")
    parser.add_argument("--only", default=None,
                        help="comma-separated keys or words of titles: "
                             + ", ".join(c.key for c in CASES))
    parser.add_argument("--complete", action="store_true", help="run each job to its end")
    parser.add_argument("--cancel-after", default="3",
                        help="seconds before Cancel; several (3,20): one run each; "
                             "'shown': as soon as the result is being shown")
    parser.add_argument("--cancel-timeout", type=float, default=60.0)
    parser.add_argument("--timeout", type=float, default=600.0, help="--complete: per job")
    parser.add_argument("--mem-limit", type=float, default=8.0, help="GB; the child is killed")
    parser.add_argument("--warmup-size", type=int, default=160)
    parser.add_argument("--warmup-timeout", type=float, default=120.0)
    parser.add_argument("--no-warmup", action="store_true")
    parser.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "car_bench_gui"))
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument("--merge-regions", type=float, default=0.0,
                        help="the segmentation widget's 'merge similar regions' (0: off)")
    parser.add_argument("--stacks", action="store_true",
                        help="sample the main thread's stack in pauses; print what it did "
                             "in each row's longest pause")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--inputs", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    MERGE_REGIONS[0] = args.merge_regions
    if args.child == "floor":
        return floor_child(args)
    if args.child:
        args.cancel_after = _delay(args.cancel_after)
        return child(args)
    delays = [_delay(t) for t in str(args.cancel_after).split(",") if t.strip()]
    if args.complete:
        delays = delays[:1]
    size = args.size or (1024 if args.complete else 4000)
    cases = CASES
    if args.only:
        words = [w.strip().lower() for w in args.only.split(",") if w.strip()]
        keys = {c.key for c in CASES}
        cases = [c for c in CASES
                 if any(w == c.key or (w not in keys and w in c.title.lower()) for w in words)]
    print(f"inputs {size}x{size} in {args.cache}", file=sys.stderr)
    inputs = make_inputs(size, args.cache)
    results = []
    for case in cases:
        for delay in delays:
            t0 = time.perf_counter()
            result = run_child(case, args, inputs, delay)
            if len(delays) > 1:
                result["title"] += f" @ {delay:g} s" if delay != SHOWN else " @ shown"
            print(f"  {result['title']}: {json.dumps(result)} ({time.perf_counter() - t0:.0f} s)",
                  file=sys.stderr, flush=True)
            results.append(result)
    mode = ("run to completion" if args.complete
            else "Cancel clicked after " + ", ".join(
                "the result began to be shown" if t == SHOWN else f"{t:g} s" for t in delays))
    floor = run_child(Case("floor", "napari itself", "", "", ""), args, inputs, 0)
    print(f"  napari itself: {json.dumps(floor)}", file=sys.stderr, flush=True)
    print(f"\nGUI benchmark, {size}x{size} (mammogram {1024 * max(1, round(size / 1000))}"
          f"x{1024 * max(1, round(size / 1000))} grey), {mode}, {os.cpu_count()} cores\n")
    print(table(results, args))
    if "add_ms" in floor:
        def span(key):
            return f"{min(floor[key]):.0f}-{max(floor[key]):.0f} ms"

        print(f"\nnapari's own floor in the same run (no plugin docked; over the input): longest "
              f"pause adding a 1000x1000 RGB float32 layer {span('add_ms')}, a 16x16 image "
              f"{span('add_tiny_ms')}, a {size}x{size} Labels layer {span('add_labels_ms')}; "
              f"removing one {span('remove_ms')}.")
    split = [r for r in results if r.get("longest_layer_ms")]
    if split:
        print("\nThe longest pauses in which napari added or removed a layer: the time in "
              "napari's adds and removes, in the canvas's paints, and the rest (ms):")
        for r in split:
            rest = r["longest_ms"] - r["longest_layer_ms"] - r["longest_paint_ms"]
            print(f"  {r['title']}: {r['longest_ms']:.0f} = layer {r['longest_layer_ms']:.0f}"
                  f" + paint {r['longest_paint_ms']:.0f} + rest {rest:.0f}")
    for r in results:
        if r.get("ours_stacks") and r.get("ours_ms", 0) > 50:
            print(f"\n{r['title']}, the pause of ours ({r['ours_ms']:.0f} ms, its CPU "
                  f"{r['ours_cpu_ms']:.0f} ms, {r['ours_from_s']:.2f} s after the start), "
                  "its stacks:")
            print("\n".join("  " + line for line in r["ours_stacks"]))
    for r in results:
        if r.get("stacks"):
            print(f"\n{r['title']}, its longest pause ({r['longest_ms']:.0f} ms), the main "
                  "thread's stacks sampled every 2 ms (count x frames, outermost first):")
            print("\n".join("  " + line for line in r["stacks"]))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
