"""Dock widget "Scratch restoration": paint or detect a damage mask, restore live."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox
from napari.utils.notifications import show_info

from ..inpainting import iter_detect_scratches, iter_inpaint
from ._base import JobWidget, guarded

BRUSH_SIZE = 5
FRAME_OR_CLIP = "choose a frame (2-D) or a clip (frames, rows, columns)."


class InpaintingWidget(JobWidget):
    """Restore scratched film frames or clips from a painted or detected mask
    (section 14.7, docs/inpainting.md). The source layer is never modified.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer.
    """

    control_labels = {"temporal": "use the previous frame", "mask": "scratch mask"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, image_label="image or clip")
        self.updates = 0
        self._new_mask = self.action("New mask layer", self.mask_layer,
                                     tooltip="an empty 'scratch mask' Labels layer, ready to "
                                             "paint")
        self._detect = self.action("Detect scratches", self.detect,
                                   tooltip="add a proposal to the mask (Ctrl+Z undoes it)")
        self._temporal = CheckBox(value=True, text="use the previous frame (clips)")
        self._run = self.action("Restore", self.start)
        self.arrange([self._new_mask, self._detect, self._temporal, self._run])

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
            def add(name):
                return self._viewer.add_labels(
                    np.zeros(shape, np.uint8), name=name, opacity=0.6,
                    scale=layer.scale[-len(shape):], translate=layer.translate[-len(shape):])

            if record is not None:
                mask = record.replace(name, add)
            else:
                if name in layers:
                    layers.remove(name)
                mask = add(name)
        mask.brush_size = BRUSH_SIZE
        mask.selected_label = 1
        layers.selection.active = mask
        mask.mode = "paint"
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
        data, channel_axis = self.input_array(ndims=(2, 3), hint=FRAME_OR_CLIP)
        return self.run(iter_detect_scratches(data, channel_axis=channel_axis),
                        done=self._add_proposal)

    def _add_proposal(self, proposal):
        mask = self._mask_layer(self.record)
        new = np.asarray(proposal, bool) & (np.asarray(mask.data) == 0)
        if new.any():
            # data_setitem records the change in the layer's undo history
            mask.data_setitem(np.nonzero(new), 1)
        self._status.value = f"detector proposed {int(np.count_nonzero(proposal))} pixels"

    # --- restoring -------------------------------------------------------------------

    def _start(self):
        """Restore the masked pixels of the source, frame by frame."""
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
        data, channel_axis = self.input_array(ndims=(2, 3), hint=FRAME_OR_CLIP)
        self._layer = layer
        self._rgb = rgb
        self._out_name = f"{layer.name} restored"
        self._frames = data.copy()  # the output, filled in frame by frame
        self._clip = data.ndim - rgb == 3
        self.updates = 0
        job = iter_inpaint(data, mask, channel_axis=channel_axis,
                           temporal=bool(self._temporal.value))
        return self.run(job, preview=self._show_frame, done=self._finished)

    def _add_output(self, data, name):
        layer = self._layer
        kwargs = dict(rgb=self._rgb, scale=layer.scale, translate=layer.translate)
        if not self._rgb:
            kwargs.update(colormap=layer.colormap.name, contrast_limits=layer.contrast_limits)
        return self._viewer.add_image(data, name=name, **kwargs)

    def _put(self, data):
        self.record.put(self._out_name, data, self._add_output)

    def _show_frame(self, preview):
        index, frame = preview
        if self._clip:
            self._frames[index] = frame
            self.record.set_step(0, index)
        else:
            self._frames = np.asarray(frame)
        self._put(self._frames)
        self.updates += 1
        self._status.value = f"frame {index + 1} restored"

    def _finished(self, restored):
        self._put(restored)
        self._status.value = "restored"
