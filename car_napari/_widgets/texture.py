"""Dock widget "Texture synthesis": a texture becomes a model of a few kB, from
which any amount of it is synthesised (section 14.8, docs/texture.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from magicgui.widgets import CheckBox, ComboBox, Label, SpinBox
from napari.utils.notifications import show_info

from ..texture import (
    BTFModel,
    DynamicTextureModel,
    TextureModel,
    iter_fit_btf,
    iter_fit_dynamic_texture,
    iter_fit_texture,
)
from ._base import ModelWidget, guarded
from ._layers import beside

SINGLE, BTF, DYNAMIC = "single texture", "BTF: stack of illuminations", "dynamic: frames"
NOT_A_STACK = "it is not a stack (images along the first axis); choose 'single texture'."
MODEL_FILTER = "Texture model (*.npz)"


def ask_model_path(parent, start, *, save):
    """Ask for a model file: a save dialog (``save=True``) or an open one.

    Parameters
    ----------
    parent : QWidget or None
        The dialog's parent.
    start : str
        The proposed path, or the folder to start in.
    save : bool
        Ask where to save (True) or what to load (False).

    Returns
    -------
    str or None
        The chosen path; None when the user closed the dialog.
    """
    from qtpy.QtWidgets import QFileDialog

    if save:
        path, _ = QFileDialog.getSaveFileName(parent, "Save texture model", start, MODEL_FILTER)
    else:
        path, _ = QFileDialog.getOpenFileName(parent, "Load texture model", start, MODEL_FILTER)
    return path or None


def ask_save_path(parent, start):
    """The save dialog of :func:`ask_model_path` (tests replace it)."""
    return ask_model_path(parent, start, save=True)


def ask_open_path(parent, start):
    """The open dialog of :func:`ask_model_path` (tests replace it)."""
    return ask_model_path(parent, start, save=False)


def _for_display(job):
    """``job``'s synthesis as float32 and its (min, max), both taken in the
    worker: napari converts float64 to float32 on the main thread before
    drawing it, and without contrast limits it scans a large image there
    (0.43 s for a 4000x4000 RGB synthesis)."""
    synthesis = yield from job
    lo, hi = float(np.nanmin(synthesis)), float(np.nanmax(synthesis))
    return synthesis.astype(np.float32), (lo, hi if hi > lo else lo + 1.0)


def _fallback_notes(model):
    """What the fit did with unstable fitted models (a sentence each)."""
    if isinstance(model, BTFModel):
        return tuple(f"subspace {k + 1}, {note}" for k, m in enumerate(model.models)
                     for note in m.fallbacks)
    return tuple(getattr(model, "fallbacks", ()))


class TextureSynthesisWidget(ModelWidget):
    """Fit a multiresolution CAR texture model to an image layer (or a
    rectangle on it), save or load it, and synthesise textures of any size.

    A stack is a BTF (one material under many illuminations) or a dynamic
    texture (the frames of a video).

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    no_model = "fit a model first (or load one)."
    control_labels = {"levels": "pyramid levels", "n_subspaces": "BTF subspaces",
                      "n_frames": "frames (dynamic)"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, size=512)
        self._source_name = "texture"
        self._source_layer = None  # the fitted layer: the syntheses go to its right
        self._input_shape = None
        self._mode = ComboBox(value=SINGLE, choices=[SINGLE, BTF, DYNAMIC], label="input",
                              tooltip="a stack is a BTF (one material, many illuminations) "
                                      "or a dynamic texture (frames of a video)")
        self._levels = SpinBox(value=5, min=1, max=6, label="pyramid levels",
                               tooltip="resolution levels of the model: more levels "
                                       "reproduce larger structures (at most as many as "
                                       "the image's size allows: the coarsest level "
                                       "keeps 16 pixels a side)")
        self._subspaces = SpinBox(value=4, min=1, max=64, label="BTF subspaces",
                                  tooltip="a BTF: groups of similar illuminations, one model "
                                          "each (at most the number of images)")
        self._frames = SpinBox(value=10, min=1, max=1000, label="frames (dynamic)",
                               tooltip="a dynamic texture: number of frames to synthesise")
        self._fit = self.action("Fit", self.start_fit,
                                tooltip="fit a texture model to the image (or inside the "
                                        "rectangle), or to the stack")
        self._model_info = Label(value="no model")
        self._tileable = CheckBox(value=False, text="tileable (wraps seamlessly)",
                                  tooltip="a single texture: copies placed side by side "
                                          "show no seam")
        self._folder = Path.cwd()  # where the model dialogs start
        self._save = self.action("Save model...", self.save_model_as,
                                 when=lambda: isinstance(self.model, TextureModel),
                                 tooltip="write the single-texture model to an .npz file")
        self._load = self.action("Load model...", self.load_model_from,
                                 tooltip="read a model saved by 'Save model...'")
        self.arrange([self._mode, self._levels, self._subspaces, self._fit, self._model_info,
                      self._height, self._width, self._frames, self._seed, self._tileable,
                      self._synth],
                     after=[self._save, self._load])
        self._image.changed.connect(self._guess_mode)

    def _guess_mode(self, *_):
        layer = self._image.value
        if layer is None:
            return
        stack = layer.data.ndim - bool(getattr(layer, "rgb", False)) == 3
        if stack and self._mode.value == SINGLE:
            self._mode.value = BTF
        elif not stack:
            self._mode.value = SINGLE

    def _start(self):
        """Fit the model of the chosen input kind to the picked layer."""
        mode = self._mode.value
        levels = int(self._levels.value)
        # the layer's data itself, read in the worker only (the core never writes
        # its input): no copy of a large image in the viewer's thread
        if mode == SINGLE:
            data, channel_axis = self.input_array(copy=False)
            plane = data.shape if data.ndim == 2 or channel_axis is None else [
                n for axis, n in enumerate(data.shape) if axis != channel_axis % data.ndim]
            levels = TextureModel.levels_for(plane, levels)  # fewer for a small image
            job = iter_fit_texture(data, levels=levels, channel_axis=channel_axis)
        else:
            data, channel_axis = self.input_array(region=False, ndims=(3,), hint=NOT_A_STACK,
                                                  copy=False)
            if mode == BTF:
                job = iter_fit_btf(data, n_subspaces=min(int(self._subspaces.value), len(data)),
                               levels=levels, channel_axis=channel_axis)
            else:
                job = iter_fit_dynamic_texture(data, channel_axis=channel_axis)
        self._fitting = self._image.value, data.shape
        return self.run(job, done=self._fitted)

    def _fitted(self, model):
        self._source_layer, self._input_shape = self._fitting
        self._source_name = self._source_layer.name
        self._set_model(model)

    def _set_model(self, model):
        self.model = model
        self.refresh_actions()
        self._describe()

    def _describe(self):
        model = self.model
        notes = _fallback_notes(model)
        if not isinstance(model, TextureModel):
            kind = ("BTF, " + f"{len(model.models)} subspaces"
                    if isinstance(model, BTFModel) else "dynamic 3.5D")
            text = (f"{kind}, {model.nbytes} bytes, "
                    f"{model.compression_ratio(self._input_shape):.0f}:1")
        else:
            text = f"orders {list(model.orders)} per band, {model.nbytes} bytes"
            if self._input_shape is not None:
                text += f", {model.compression_ratio(self._input_shape):.0f}:1"
        if notes:
            what = "band(s)" if isinstance(model, TextureModel) else "model(s)"
            text += f"; {len(notes)} unstable {what} made stable"
        self._model_info.value = text
        self._model_info.tooltip = "\n".join(notes) if notes else None
        if notes:  # the synthesis would have failed: say what was done instead
            show_info("The fitted model was unstable (its synthesis would grow without "
                      "bound), so the fit made it stable: " + "; ".join(notes) + ".")

    def _synthesis(self, shape, seed):
        model = self.model
        # the synthesis as a job: progress, and Cancel stops it at its next record
        if isinstance(model, DynamicTextureModel):
            job = model.iter_synthesize(int(self._frames.value), shape, seed=seed)
        elif isinstance(model, BTFModel):
            job = model.iter_synthesize(shape, seed=seed)
        else:
            job = model.iter_synthesize(shape, seed=seed, tileable=bool(self._tileable.value))
        self._target = f"{self._source_name} synthesis", not isinstance(model, TextureModel)
        return self.run(_for_display(job), done=self._show)

    def _show(self, result):
        """Show the synthesis (a generator: the job runs it a step per event-loop turn)."""
        synthesis, limits = result
        name, stacked = self._target
        # a single texture is (H, W[, C]); a BTF or dynamic synthesis has a leading axis
        rgb = synthesis.ndim == (4 if stacked else 3)
        layers = self._viewer.layers
        if name in layers and layers[name].data.shape == synthesis.shape:
            self.record.put(name, synthesis, None)
        else:
            # beside the fitted layer, not over it (while it is in the viewer)
            source = self._source_layer if self._source_layer in self._viewer.layers else None
            place = beside(source, synthesis.ndim - rgb)
            self.record.replace(name, synthesis, lambda data, name: self._viewer.add_image(
                data, name=name, rgb=rgb, contrast_limits=limits, **place))
        # the layer made or updated in this turn, its first paint (the texture
        # upload, growing with the size) on the next one
        yield

    def save_model_as(self, *_):
        """Ask for a file name (a save dialog) and write the model there.

        Returns
        -------
        pathlib.Path or None
            The file written; None when the dialog was closed or the model
            could not be written (an error notification says why).
        """
        if self.model is None:
            return self.save_model(None)  # says there is nothing to save
        start = self._folder / f"{self._source_name}.npz"
        path = ask_save_path(self.native, str(start))
        if path is None:
            return None
        return self.save_model(path)

    def load_model_from(self, *_):
        """Ask for a model file (an open dialog) and load it.

        Returns
        -------
        TextureModel or None
            The model loaded; None when the dialog was closed or the file is
            not a model (an error notification says why).
        """
        path = ask_open_path(self.native, str(self._folder))
        if path is None:
            return None
        return self.load_model(path)

    @guarded
    def save_model(self, path):
        """Write the texture model to ``path`` (an ``.npz`` file).

        ``.npz`` is added to a name without it; a folder (or no name) is
        refused with a notification.

        Parameters
        ----------
        path : str or Path
            The file to write.

        Returns
        -------
        pathlib.Path or None
            The file written; None when nothing was written (an error
            notification says why).
        """
        if self.model is None:
            raise ValueError("there is no model to save: fit one first.")
        if not isinstance(self.model, TextureModel):
            raise ValueError("only a single-texture model can be saved; this one is a "
                             "BTF or dynamic model.")
        if path is None or not str(path).strip():
            raise ValueError("choose a file name to save the model to.")
        target = Path(path).expanduser()
        if target.is_dir() or str(path).endswith(("/", "\\")):
            raise ValueError(f"{target} is a folder: choose a file name for the model "
                             "(an .npz file).")
        if not target.name.endswith(".npz"):
            target = target.with_name(target.name + ".npz")  # what numpy would write
        try:
            self.model.save(str(target))
        except OSError as exc:
            raise OSError(f"cannot write {target}: {exc}") from exc
        self._folder = target.parent
        show_info(f"model saved to {target} ({self.model.nbytes} bytes of parameters)")
        return target

    @guarded
    def load_model(self, path):
        """Read a texture model from ``path`` (written by :meth:`save_model`).

        Parameters
        ----------
        path : str or Path
            The ``.npz`` file.

        Returns
        -------
        TextureModel or None
            The model; None when the file is not one (an error notification
            says why).
        """
        model = TextureModel.load(str(path))
        self._folder = Path(path).expanduser().parent
        self._input_shape = None
        self._source_name = "texture model"
        self._source_layer = None
        self._set_model(model)
        return model
