"""Dock widget "Scratch restoration": paint or detect a damage mask, restore live."""

from __future__ import annotations

import numpy as np
from magicgui.widgets import CheckBox, ComboBox
from napari.layers import Image, Labels
from napari.utils.notifications import show_info

from ..inpainting import fit_mask, iter_detect_scratches, iter_inpaint
from ._base import JobWidget, guarded

BRUSH_SIZE = 5
FRAME_OR_CLIP = "choose a frame (2-D) or a clip (frames, rows, columns)."


class InpaintingWidget(JobWidget):
    """Restore scratched film frames or clips from a painted, detected or
    opened mask (section 14.7, docs/inpainting.md). The source layer is never
    modified.

    The mask is any Labels or Image layer (non-zero = damaged), by default
    the source's "scratch mask" layer; one of another size is resized
    (nearest neighbour) to the frame, with a note saying so.

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
        self._mask = ComboBox(
            label="scratch mask", choices=self._mask_choices, nullable=True,
            tooltip="the damage: a Labels or Image layer, non-zero = damaged (a mask of "
                    "another size is resized to the frame)")
        self._temporal = CheckBox(value=True, text="use the previous frame (clips)")
        self._follow = CheckBox(value=False, text="follow progress (show each frame as "
                                                  "it is restored)")
        self._run = self.action("Restore", self.start)
        self.arrange([self._new_mask, self._detect, self._mask, self._temporal,
                      self._follow, self._run])
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

    def _chosen_mask(self, shape):
        """The chosen mask layer's data fitted to the source's frames
        ``shape``, as bool; a note when it had to be resized."""
        layer = self._mask.value
        if layer is None or layer not in self._viewer.layers:
            layer = self._own_mask()
        if layer is None:
            raise ValueError("there is no scratch mask yet: press 'New mask layer' and paint "
                             "the damage, or 'Detect scratches', or choose a mask layer "
                             "(an opened mask image) as 'scratch mask'.")
        data = np.asarray(layer.data)
        rgb = bool(getattr(layer, "rgb", False))
        if rgb:
            data = data[..., :3]  # an RGBA mask: its alpha is not the damage
        try:
            mask = fit_mask(data, shape, channel_axis=-1 if rgb else None)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"'scratch mask' ({layer.name!r}): {exc}") from exc
        drawn = data.shape[-3:-1] if rgb else data.shape[-2:]
        if tuple(drawn) != tuple(shape[-2:]):
            show_info(f"the mask {layer.name!r} is {drawn[0]}x{drawn[1]} pixels and the "
                      f"frames {shape[-2]}x{shape[-1]}: it was resized (nearest neighbour) to "
                      "fit them.")
        return mask

    def _start(self):
        """Restore the masked pixels of the source, frame by frame."""
        layer, rgb = self._source()
        shape = layer.data.shape[:-1] if rgb else layer.data.shape
        mask = self._chosen_mask(shape)
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
        self._following = bool(self._follow.value)
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
            if self._following:  # only when asked: the viewer stays on the user's frame
                self.record.set_step(0, index)
        else:
            self._frames = np.asarray(frame)
        self._put(self._frames)
        self.updates += 1
        self._status.value = f"frame {index + 1} restored"

    def _finished(self, restored):
        self._put(restored)
        self._status.value = "restored"
