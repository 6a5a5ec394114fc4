"""Dock widget "Scratch restoration": paint or detect a damage mask, restore live."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox, Container, Label, ProgressBar, PushButton, create_widget
from napari.utils.notifications import show_error, show_info

from ..inpainting import detect_scratches, iter_inpaint
from .._progress import relay
from ._jobs import Job
from ._layers import RunLayers

BRUSH_SIZE = 5


def _inpaint_job(data, mask, channel_axis, temporal):
    """Relay the core generator: progress, each restored frame; returns all."""
    return (yield from relay(iter_inpaint(data, mask, channel_axis=channel_axis,
                                          temporal=temporal)))


class InpaintingWidget(Container):
    """Restore scratched film frames or clips from a painted or detected mask
    (SPEC section 6). The source layer is never modified."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self._job = None
        self._run_layers = RunLayers(napari_viewer)  # undone if a run is cancelled
        self.updates = 0
        self._image = create_widget(annotation="napari.layers.Image", label="image or clip")
        self._new_mask = PushButton(text="New mask layer",
                                    tooltip="an empty 'scratch mask' Labels layer, ready to "
                                            "paint")
        self._detect = PushButton(text="Detect scratches",
                                  tooltip="add a proposal to the mask (Ctrl+Z undoes it)")
        self._temporal = CheckBox(value=True, text="use the previous frame (clips)")
        self._run = PushButton(text="Restore")
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._status = Label(value="")
        self.extend([self._image, self._new_mask, self._detect, self._temporal, self._run,
                     self._cancel, self._progress, self._status])
        self._new_mask.changed.connect(self.mask_layer)
        self._detect.changed.connect(self.detect)
        self._run.changed.connect(self.start)
        self._cancel.changed.connect(self.cancel)

    # --- the source and its mask -------------------------------------------------

    def _source(self):
        layer = self._image.value
        if layer is None:
            raise ValueError("no image layer selected: open a frame or a clip first.")
        rgb = bool(getattr(layer, "rgb", False))
        spatial = layer.data.ndim - rgb
        if spatial not in (2, 3):
            raise ValueError(f"layer {layer.name!r} has {spatial} non-colour axes; choose a "
                             "frame (2-D) or a clip (frames, rows, columns).")
        return layer, rgb

    def _mask_name(self, layer):
        return f"{layer.name} scratch mask"

    def mask_layer(self, *_):
        """The source's mask layer, created empty (and selected for painting)
        when it does not exist yet."""
        try:
            layer, rgb = self._source()
        except ValueError as exc:
            show_error(str(exc))
            return None
        name = self._mask_name(layer)
        shape = layer.data.shape[:-1] if rgb else layer.data.shape
        if name in self._viewer.layers and self._viewer.layers[name].data.shape == shape:
            mask = self._viewer.layers[name]
        else:
            if name in self._viewer.layers:
                self._viewer.layers.remove(name)
            mask = self._viewer.add_labels(np.zeros(shape, np.uint8), name=name, opacity=0.6,
                                           scale=layer.scale[-len(shape):],
                                           translate=layer.translate[-len(shape):])
        mask.brush_size = BRUSH_SIZE
        mask.selected_label = 1
        self._viewer.layers.selection.active = mask
        mask.mode = "paint"
        return mask

    def detect(self, *_):
        """Add the detector's proposal to the mask, undoably."""
        try:
            layer, rgb = self._source()
            proposal = detect_scratches(np.asarray(layer.data), channel_axis=-1 if rgb else None)
        except ValueError as exc:
            show_error(str(exc))
            return None
        mask = self.mask_layer()
        new = proposal & (np.asarray(mask.data) == 0)
        if new.any():
            # data_setitem records the change in the layer's undo history
            mask.data_setitem(np.nonzero(new), 1)
        self._status.value = f"detector proposed {int(proposal.sum())} pixels"
        return mask

    # --- restoring -------------------------------------------------------------------

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()
            self._run_layers.undo()

    def start(self, *_):
        try:
            layer, rgb = self._source()
            name = self._mask_name(layer)
            if name not in self._viewer.layers:
                raise ValueError("there is no scratch mask yet: press 'New mask layer' and "
                                 "paint the damage, or 'Detect scratches'.")
            mask = np.asarray(self._viewer.layers[name].data) != 0
            if not mask.any():
                show_info("the scratch mask is empty: paint the damaged pixels (or detect "
                          "them) first; nothing was changed.")
                return None
            data = np.array(layer.data, copy=True)  # the source layer stays untouched
        except ValueError as exc:
            show_error(str(exc))
            return None
        self._layer = layer
        self._rgb = rgb
        self._out_name = f"{layer.name} restored"
        self._run_layers.commit()
        self._frames = data.copy()  # the output, filled in frame by frame
        self._clip = data.ndim - rgb == 3
        self.updates = 0
        self._job = Job(_inpaint_job, data, mask, -1 if rgb else None,
                        bool(self._temporal.value), progress=self._progress,
                        cancel=self._cancel, buttons=(self._run, self._detect),
                        on_yield=self._show_frame, on_done=self._finished,
                        on_error=lambda exc: self._run_layers.undo())
        return self._job

    def _add_output(self, data, name):
        layer = self._layer
        kwargs = dict(rgb=self._rgb, scale=layer.scale, translate=layer.translate)
        if not self._rgb:
            kwargs.update(colormap=layer.colormap.name, contrast_limits=layer.contrast_limits)
        return self._viewer.add_image(data, name=name, **kwargs)

    def _put(self, data):
        self._run_layers.put(self._out_name, data, self._add_output)

    def _show_frame(self, state):
        if self._clip:
            self._frames[state.frame] = state.restored
            self._viewer.dims.set_current_step(0, state.frame)
        else:
            self._frames = state.restored
        self._put(self._frames)
        self.updates += 1
        self._status.value = f"frame {state.frame + 1} restored"

    def _finished(self, restored):
        self._put(restored)
        self._run_layers.commit()
        self._status.value = "restored"
