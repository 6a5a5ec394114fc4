"""Dock widget "Scratch restoration": paint or detect a damage mask, restore live."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox, ComboBox
from napari.layers import Image, Labels
from napari.utils.notifications import show_info

from .._frames import DEFAULT_BLOCK, lazy_output
from .._progress import Progress, map_previews
from ..inpainting import fit_mask, iter_detect_scratches, iter_inpaint, iter_inpaint_frames
from ._base import JobWidget, guarded

BRUSH_SIZE = 5
FRAME_OR_CLIP = "choose a frame (2-D) or a clip (frames, rows, columns)."
EMPTY_MASK = ("the scratch mask is empty: paint the damaged pixels (or detect them) first; "
              "nothing was changed.")


def _restore_job(frames, mask, *, shape, clip, channel_axis, mask_name, mask_rgb, temporal):
    """The restoration, in the worker, from the layers' data as they are
    (views: nothing is copied in the viewer's thread, nothing is modified):
    the mask fitted to the frames, then :func:`~car_napari.inpainting.iter_inpaint`.
    A clip's previews carry the whole clip restored so far (a buffer of the
    worker's, filled frame by frame). Returns the restored image, or None
    when the fitted mask is empty."""
    yield Progress("frames", 0.0, "fitting the mask")
    try:
        fitted = fit_mask(mask[..., :3] if mask_rgb else mask, shape,
                          channel_axis=-1 if mask_rgb else None)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"'scratch mask' ({mask_name!r}): {exc}") from exc
    if not fitted.any():
        return None
    job = iter_inpaint(frames, fitted, channel_axis=channel_axis, temporal=temporal)
    if not clip:
        return (yield from job)
    shown = np.array(frames)  # the clip as shown live

    def fill(preview):
        index, frame = preview
        shown[index] = frame
        return index, shown

    return (yield from map_previews(job, fill))


def _lazy(data):
    """Data not in memory (a dask or zarr array): processed by blocks of frames."""
    return not isinstance(data, np.ndarray)


def _lazy_mask(mask, mask_rgb):
    """A mask layer's data for :func:`~car_napari.inpainting.iter_inpaint_frames`:
    one frame's mask (an RGB one reduced to "any channel non-zero"), or a
    grey mask per frame as it is (read by blocks)."""
    if not mask_rgb:
        return mask
    if mask.ndim != 3:
        raise ValueError("a colour mask per frame cannot restore a lazy clip: use a Labels "
                         "layer (or one mask image for every frame).")
    return np.any(np.asarray(mask)[..., :3] != 0, axis=-1)


def _with_indices(job):
    """The scratch detection, then (in the worker too) the indices of the
    proposed pixels, so that the viewer only writes them into the mask."""
    proposal = yield from job
    return np.nonzero(np.asarray(proposal, bool))


class InpaintingWidget(JobWidget):
    """Restore scratched film frames or clips from a painted, detected or
    opened mask (section 14.7, docs/inpainting.md). The source layer is never
    modified.

    The mask is any Labels or Image layer (non-zero = damaged), by default
    the source's "scratch mask" layer; one of another size is resized
    (nearest neighbour) to the frame, with a note saying so.

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    control_labels = {"temporal": "use the previous frame", "mask": "scratch mask"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, image_label="image or clip",
                         image_tooltip="the damaged image, or a clip of frames (an alpha "
                                       "channel is not used)")
        self.updates = 0
        self._new_mask = self.action("New mask layer", self.mask_layer,
                                     tooltip="an empty 'scratch mask' Labels layer, ready to "
                                             "paint")
        self._detect = self.action("Detect scratches", self.detect,
                                   tooltip="add a proposal to the mask (Ctrl+Z undoes it)")
        self._mask = ComboBox(
            label="scratch mask", choices=self._mask_choices, nullable=True,
            tooltip="the damage: a Labels or Image layer, non-zero = damaged (a mask of "
                    "another size is resized to the frame)")
        self._temporal = CheckBox(value=True, text="use the previous frame (clips)",
                                  tooltip="a clip: fill the damage from the previous frame "
                                          "as well as from the frame itself")
        self._follow = CheckBox(value=False, text="follow progress (show each frame as "
                                                  "it is restored)",
                                tooltip="a clip: move the viewer to each frame as it is "
                                        "restored")
        self._run = self.action("Restore", self.start,
                                tooltip="fill in the damaged pixels of the mask")
        self.arrange([self._new_mask, self._detect, self._mask,
                      *self.folded([self._temporal, self._follow], "clip options"),
                      self._run])
        self._image.changed.connect(self._source_changed)
        self._default_mask()

    # --- the source and its mask -------------------------------------------------

    def _source(self):
        layer = self._image.value
        if layer is None:
            raise ValueError("no image layer selected: open a frame or a clip first.")
        rgb = bool(getattr(layer, "rgb", False))
        spatial = layer.data.ndim - rgb
        if spatial not in (2, 3):
            raise ValueError(f"layer {layer.name!r} has {spatial} non-colour axes; "
                             f"{FRAME_OR_CLIP}")
        return layer, rgb

    @staticmethod
    def _mask_name(layer):
        return f"{layer.name} scratch mask"

    def _mask_choices(self, _widget=None):
        return [(layer.name, layer) for layer in self._viewer.layers
                if isinstance(layer, (Labels, Image))]

    def _own_mask(self):
        """The source's "scratch mask" layer, or None."""
        layer = self._image.value
        if layer is None:
            return None
        name = self._mask_name(layer)
        return self._viewer.layers[name] if name in self._viewer.layers else None

    def _choose_mask(self, layer):
        self._mask.reset_choices()
        self._mask.value = layer

    def _default_mask(self, force=False):
        """Choose the source's scratch mask when there is one (when no mask is
        chosen, or with ``force``); with no mask chosen and none of its own,
        the newest other layer named like a mask (an opened ``mask.png``)."""
        own = self._own_mask()
        if own is not None and (force or self._mask.value is None):
            self._choose_mask(own)
        elif self._mask.value is None:
            named = [layer for _, layer in self._mask_choices()
                     if "mask" in layer.name.lower() and layer is not self._image.value]
            if named:
                self._choose_mask(named[-1])

    def _source_changed(self, *_):
        self._default_mask(force=True)

    def reset_choices(self, *args):
        """Refresh the layer pickers (napari calls this when layers change)."""
        super().reset_choices(*args)
        self._default_mask()

    @guarded
    def mask_layer(self, *_):
        """The source's mask layer, created empty (and selected for painting)
        when it does not exist yet.

        Returns
        -------
        napari.layers.Labels or None
            The mask layer; None without a usable source (notified).
        """
        return self._mask_layer()

    def _mask_layer(self, record=None):
        """:meth:`mask_layer`; a new layer goes through ``record`` when given."""
        layer, rgb = self._source()
        name = self._mask_name(layer)
        shape = layer.data.shape[:-1] if rgb else layer.data.shape
        layers = self._viewer.layers
        if name in layers and layers[name].data.shape == shape:
            mask = layers[name]
        else:
            def add(data, name):
                return self._viewer.add_labels(
                    data, name=name, opacity=0.6,
                    scale=layer.scale[-len(shape):], translate=layer.translate[-len(shape):])

            # a lazy clip's mask on disk (zarr, a chunk a frame): not the clip's size in memory
            empty = (lazy_output(shape, np.uint8, name="mask") if _lazy(layer.data)
                     and len(shape) == 3 else np.zeros(shape, np.uint8))
            if record is not None:
                mask = record.replace(name, empty, add)
            else:
                if name in layers:
                    layers.remove(name)
                mask = add(empty, name)
        mask.brush_size = BRUSH_SIZE
        mask.selected_label = 1
        layers.selection.active = mask
        mask.mode = "paint"
        self._choose_mask(mask)
        return mask

    @guarded
    def detect(self, *_):
        """Propose a damage mask in a worker; it is added to the mask layer
        as one undoable edit (Ctrl+Z on the mask layer takes it back).

        Returns
        -------
        Job or None
            The running job; None without a usable source (notified).
        """
        data, channel_axis = self.input_array(ndims=(2, 3), hint=FRAME_OR_CLIP, copy=False)
        return self.run(_with_indices(iter_detect_scratches(data, channel_axis=channel_axis)),
                        done=self._add_proposal)

    def _add_proposal(self, result):
        where = result  # the proposed pixels' indices, found in the worker
        mask = self._mask_layer(self.record)
        yield  # the viewer draws the mask layer before the proposal goes into it
        data = np.asarray(mask.data)
        if data.any():  # what is painted already stays: only the new pixels
            keep = data[where] == 0
            where = tuple(w[keep] for w in where)
        if where[0].size:
            # data_setitem records the change in the layer's undo history
            mask.data_setitem(where, 1)
        self._status.value = f"detector proposed {int(result[0].size)} pixels"

    # --- restoring -------------------------------------------------------------------

    def _chosen_mask(self, shape):
        """The chosen mask layer (the source's own by default) and whether
        it is RGB; a note, from the shapes alone, when it is resized to the
        frames ``shape``. Its data is read in the worker."""
        layer = self._mask.value
        if layer is None or layer not in self._viewer.layers:
            layer = self._own_mask()
        if layer is None:
            raise ValueError("there is no scratch mask yet: press 'New mask layer' and paint "
                             "the damage, or 'Detect scratches', or choose a mask layer "
                             "(an opened mask image) as 'scratch mask'.")
        rgb = bool(getattr(layer, "rgb", False))  # an RGBA mask: its alpha is not the damage
        data = layer.data
        drawn = data.shape[-3:-1] if rgb else data.shape[-2:]
        if tuple(drawn) != tuple(shape[-2:]):
            show_info(f"the mask {layer.name!r} is {drawn[0]}x{drawn[1]} pixels and the "
                      f"frames {shape[-2]}x{shape[-1]}: it is resized (nearest neighbour) to "
                      "fit them.")
        return layer, rgb

    def _start(self):
        """Restore the masked pixels of the source, frame by frame. The
        viewer's thread only picks the layers; the worker fits the mask,
        copies and restores (the source and the mask are never modified)."""
        layer, rgb = self._source()
        data = layer.data
        if data.size == 0:
            raise ValueError(f"layer {layer.name!r} is empty.")
        shape = data.shape[:-1] if rgb else data.shape
        mask_layer, mask_rgb = self._chosen_mask(shape)
        self._layer = layer
        self._rgb = rgb
        self._out_name = f"{layer.name} restored"
        self._clip = len(shape) == 3
        self._following = bool(self._follow.value)
        self.updates = 0
        if self._clip and _lazy(data):
            return self._start_lazy(data[..., :3] if rgb else data,
                                    _lazy_mask(mask_layer.data, mask_rgb))
        job = _restore_job(data[..., :3] if rgb else data, mask_layer.data, shape=shape,
                           clip=self._clip, channel_axis=-1 if rgb else None,
                           mask_name=mask_layer.name, mask_rgb=mask_rgb,
                           temporal=bool(self._temporal.value))
        return self.run(job, preview=self._show_frame, done=self._finished)

    def _start_lazy(self, data, mask):
        """A lazy clip (dask, zarr): restored by blocks of frames in the
        worker (:func:`~car_napari.inpainting.iter_inpaint_frames`) into a zarr
        store in a temporary folder, shown as a dask layer filling in."""
        self._store = lazy_output(data.shape, data.dtype, name="restored")
        self._written = []  # blocks written since the layer was last refreshed
        job = iter_inpaint_frames(data, mask, self._store, block=DEFAULT_BLOCK,
                                  temporal=bool(self._temporal.value),
                                  channel_axis=-1 if self._rgb else None)
        return self.run(job, collect=self._written.append, preview=self._show_block,
                        done=self._finished_lazy)

    def _put_lazy(self):
        """The output layer over the store: a fresh dask array (napari caches
        the chunks of a dask array it has read, by name)."""
        import dask.array as da

        self.updates += 1
        self._put(da.from_zarr(self._store, name=f"car-napari-restored-{id(self)}-"
                                                 f"{self.updates}"))

    def _show_block(self, _block):
        written, self._written[:] = list(self._written), []
        dims = self._viewer.dims
        if self._following and written:
            self.record.set_step(dims.ndim - 3, written[-1][1] - 1)
        step = dims.current_step[dims.ndim - 3]
        if self.updates == 0 or any(a <= step < b for a, b in written):
            self._put_lazy()
        self._status.value = f"frames 1-{written[-1][1]} restored" if written else ""

    def _finished_lazy(self, n_frames):
        self._put_lazy()
        root = getattr(self._store.store, "root", None)
        self._status.value = f"{n_frames} frames restored" + (
            "" if root is None else f" (zarr in {root.parent})")

    def _add_output(self, data, name):
        layer = self._layer
        kwargs = dict(rgb=self._rgb, scale=layer.scale, translate=layer.translate)
        if not self._rgb:
            kwargs.update(colormap=layer.colormap.name, contrast_limits=layer.contrast_limits)
        return self._viewer.add_image(data, name=name, **kwargs)

    def _put(self, data):
        self.record.put(self._out_name, data, self._add_output)

    def _show_frame(self, preview):
        index, shown = preview  # a clip: all of it as restored so far; a frame: itself
        if self._clip and self._following:  # only when asked: the viewer stays put
            self.record.set_step(0, index)
        self._put(shown)
        self.updates += 1
        self._status.value = f"frame {index + 1} restored"

    def _finished(self, restored):
        if restored is None:  # the mask, fitted to the frames, marks nothing
            show_info(EMPTY_MASK)
            self._status.value = "nothing restored: the scratch mask is empty"
            return
        self._put(restored)
        self._status.value = "restored"
